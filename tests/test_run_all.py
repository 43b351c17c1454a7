"""make bench (benchmarks.run_all) runs every benchmark module."""

from __future__ import annotations

from benchmarks import run_all


def test_every_benchmark_module_is_listed():
    assert run_all.unlisted() == [], "add them to benchmarks/run_all.py BENCHMARKS"


def test_every_requirement_is_known():
    for b in run_all.BENCHMARKS:
        for need in b.needs:
            run_all.missing(need)       # raises ValueError on an unknown requirement name


def test_bench_new_scan_edits_only_the_scan_list_and_reads_dvc_stage_lines(tmp_path):
    """bench_new_scan swaps the names under ``scans:`` (comments and other blocks kept as written)
    and times each stage from DVC's "Running stage" lines."""
    from benchmarks import bench_new_scan as bn

    p = tmp_path / "params.yaml"
    p.write_text("# head\nscans:\n  - synthetic_head\n  - old_scan\n\nbake:\n  resolution: 2048   # texels\n")
    bn.set_scans(p, ["synthetic_head", "new_scan_2"])
    assert p.read_text() == ("# head\nscans:\n  - synthetic_head\n  - new_scan_2\n\n"
                             "bake:\n  resolution: 2048   # texels\n")
    at = {"Running stage 'check_params':": 0.0, "Running stage 'ingest@new_scan_2':": 1.0}
    starts = [(*bn.RUNNING.match(line).groups(), t) for line, t in at.items()]
    assert [s[:2] for s in starts] == [("check_params", None), ("ingest", "new_scan_2")]
    assert bn.RUNNING.match("Updating lock file 'dvc.lock'") is None
    assert bn.stage_walls(starts, 3.5) == {"check_params": 1.0, "ingest": 2.5}
