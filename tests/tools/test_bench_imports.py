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
    mod = importlib.import_module(f"kosmap.tools.{name}")
    assert callable(getattr(mod, "main", None)), f"tools/{name}.py has no main()"


def test_pipeline_bench_reads_the_hosts_steal():
    from kosmap.tools.bench_pipeline import _cpu_times, _steal_pct

    assert _steal_pct([0] * 8, [10, 0, 5, 60, 0, 0, 5, 20]) == pytest.approx(20.0)
    assert _steal_pct([], [1] * 8) is None and _steal_pct([3] * 8, [3] * 8) is None
    a = _cpu_times()
    if Path("/proc/stat").is_file():
        assert len(a) == 8 and all(x >= 0 for x in a)


def test_pipeline_bench_repeat_keeps_the_median_build_and_the_range(monkeypatch):
    import kosmap.tools.bench_pipeline as bp

    rtfs = iter([9.0, 12.5, 10.0])

    def fake_run(log, blueprint, workers, sets):
        f = next(rtfs)
        return {"wall_s": 600.0 / f, "cpu_main_s": 10.0, "cpu_workers_s": 50.0,
                "metrics": {"timing": {"realtime_factor": f, "log_s": 600.0}}}

    monkeypatch.setattr(bp, "run", fake_run)
    r = bp.repeated(Path("log.mcap"), Path("bp.yaml"), 2, [], 3)
    assert r["metrics"]["timing"]["realtime_factor"] == 10.0
    assert r["repeats"]["realtime_factor"] == [9.0, 10.0, 12.5]
    assert r["repeats"]["cpu_per_log_s"] == pytest.approx([0.1] * 3)


def test_bench_slam_keeps_the_sections_it_does_not_write():
    """docs/benchmarks.md holds bench_slam's tables and the KOS SLAM section of bench_kos_slam's runs: rewriting
    the first keeps the second, in place of nothing, and replaces bench_slam's own sections."""
    from kosmap.tools.bench_slam import with_other_sections

    generated = "# Benchmarks\n\n## Intel\nnew\n\n## Notes\nnew notes\n"
    existing = "# Benchmarks\nold\n## Intel\nold\n## KOS SLAM with harsh wheel odometry\nrow 1\nrow 2\n"
    page = with_other_sections(generated, existing)
    assert page.startswith(generated.rstrip("\n")) and page.count("## Intel") == 1 and "old" not in page
    assert page.endswith("## KOS SLAM with harsh wheel odometry\nrow 1\nrow 2\n")
    assert with_other_sections(generated, "") == generated
