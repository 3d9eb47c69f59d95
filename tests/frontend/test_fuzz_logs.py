"""Fuzzed logs through `info`, `scan` and `slam`: byte flips, truncations and length-field edits of a small MCAP,
ROS 1 bag and CARMEN log (tests/frontend/fuzzlogs.py). Every case ends in success (with warnings) or in one line
of error with exit 2, never a traceback, within its time bound. The explicit examples are reported failures kept
as regressions; the rest are drawn (derandomized, so every run checks the same cases)."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from tests.frontend.fuzzlogs import Mutation, check_outcome, laser_logs, run_cli

pytestmark = pytest.mark.slow

SECONDS = 60  # a case's time bound: one slam of 30 scans takes ~0.3 s, a first scan compiles its kernels (~3 s)
EXAMPLES = 15

mutations = st.builds(Mutation, st.sampled_from(["flip", "cut", "length"]), st.floats(0.0, 1.0, exclude_max=True),
                      st.integers(0, 63))


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz")
    out = laser_logs(folder)
    # the first scan and slam of a process compile (or load) their numba kernels: done here, outside the cases'
    # time bound (a cold cache on a busy machine takes minutes)
    for cmd, fmt in (("scan", "depth"), ("slam", "mcap")):
        assert run_cli(_argv(cmd, out[fmt], folder / f"warm_{cmd}"), 3600).code == 0
    return out


def _argv(cmd: str, path, out) -> list[str]:
    extra = {"info": [], "slam": ["--out", str(out), "--no-map"], "scan": ["--out", str(out), "--figures", "0"]}
    return [cmd, str(path), *extra[cmd]]


def _fuzz(logs, tmp_path_factory, fmt: str, cmd: str):
    src = logs[fmt]
    data = src.read_bytes()
    layout = {"clf": "clf", "bag": "bag"}.get(fmt, "mcap")
    folder = tmp_path_factory.mktemp(f"{fmt}_{cmd}")
    n = [0]

    # one flipped byte in the middle of a bz2 chunk (the reported `OSError: Invalid data stream`), a chunk index
    # length of 2^60 and a chunk claiming 2^40 bytes (the reported MemoryErrors), a cut at half the file (the
    # reported "no message can be read" of a one-chunk bag), timestamps and counts of inf, NaN, −1
    @settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow])
    @given(m=mutations)
    @example(m=Mutation("flip", 0.5, 6))
    @example(m=Mutation("cut", 0.5))
    @example(m=Mutation("length", 0.9, 6))
    @example(m=Mutation("length", 0.5, 5))
    @example(m=Mutation("length", 0.3, 1))
    @example(m=Mutation("length", 0.1, 0))
    @example(m=Mutation("length", 0.6, 3))
    def case(m: Mutation):
        n[0] += 1
        path = folder / f"case{n[0]}{src.suffix}"
        path.write_bytes(m.apply(data, layout))
        argv = _argv(cmd, path, folder / f"out{n[0]}")
        check_outcome(run_cli(argv, SECONDS), argv)

    case()


@pytest.mark.parametrize("fmt,cmd", [("mcap", "info"), ("mcap", "slam"), ("bag", "info"), ("bag", "slam"),
                                     ("clf", "info"), ("clf", "slam"), ("depth", "info"), ("depth", "scan")])
def test_fuzzed_log_ends_in_success_or_one_line(logs, tmp_path_factory, fmt, cmd):
    _fuzz(logs, tmp_path_factory, fmt, cmd)


def test_unmutated_logs_succeed(logs, tmp_path):
    """The fuzz suite's starting points are whole logs that every command reads without an error or a warning."""
    for fmt, cmd in [("mcap", "slam"), ("bag", "slam"), ("clf", "slam"), ("depth", "scan")]:
        argv = _argv(cmd, logs[fmt], tmp_path / fmt)
        o = run_cli(argv, SECONDS)
        assert o.code == 0 and "warning" not in o.out + o.err, (argv, o.out, o.err)
