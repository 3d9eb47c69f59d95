"""Every benchmark script imports: they are not run in CI (too slow), so a renamed helper must not break them
unnoticed (bench_slam once imported a function that had been removed)."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

BENCHES = sorted(p.stem for p in (Path(__file__).resolve().parents[2] / "tools").glob("bench_*.py"))


def test_there_are_benchmarks():
    assert {"bench_slam", "bench_kos", "bench_pipeline", "bench_planes"} <= set(BENCHES)


@pytest.mark.parametrize("name", BENCHES)
def test_benchmark_imports_and_has_main(name):
    mod = importlib.import_module(f"tools.{name}")
    assert callable(getattr(mod, "main", None)), f"tools/{name}.py has no main()"


def test_pipeline_bench_reads_the_hosts_steal():
    from tools.bench_pipeline import _cpu_times, _steal_pct

    assert _steal_pct([0] * 8, [10, 0, 5, 60, 0, 0, 5, 20]) == pytest.approx(20.0)
    assert _steal_pct([], [1] * 8) is None and _steal_pct([3] * 8, [3] * 8) is None
    a = _cpu_times()
    if Path("/proc/stat").is_file():
        assert len(a) == 8 and all(x >= 0 for x in a)
