"""make bench (benchmarks.run_all) runs every benchmark module; bench_new_scan's helpers (in
tests/fixtures: the scan list swap and DVC's stage lines).

run_all is run as ``python -m benchmarks.run_all`` (a test imports no benchmark)."""

from __future__ import annotations

import subprocess
import sys

from fixtures import ROOT
from fixtures.chain import RUNNING, stage_walls
from fixtures.params import set_scans


def _run_all(*args):
    return subprocess.run([sys.executable, "-m", "benchmarks.run_all", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)


def test_every_benchmark_module_is_listed():
    r = _run_all("--list")          # exits 2 naming the modules BENCHMARKS does not list
    assert r.returncode == 0, r.stderr + "\n(add them to benchmarks/run_all.py BENCHMARKS)"
    names = r.stdout.split()
    assert names and len(set(names)) == len(names)
    assert all((ROOT / "benchmarks" / f"{n}.py").is_file() for n in names), names


def test_every_requirement_is_known():
    """A dry run checks every benchmark's requirements (an unknown name raises ValueError) and
    runs nothing: each benchmark is either a command it would run or a skip saying why."""
    r = _run_all("--dry-run")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr[-2000:]
    listed = _run_all("--list").stdout.split()
    said = []
    for line in r.stdout.splitlines():
        if line.startswith("--- skip "):                      # --- skip NAME: why
            said.append(line.split()[2].rstrip(":"))
        elif line.startswith("--- would run: "):              # --- would run: python -m benchmarks.NAME ...
            said.append(line.split()[5].removeprefix("benchmarks."))
    assert sorted(said) == sorted(listed)


def test_bench_new_scan_edits_only_the_scan_list_and_reads_dvc_stage_lines(tmp_path):
    """bench_new_scan swaps the names under ``scans:`` (comments and other blocks kept as written)
    and times each stage from DVC's "Running stage" lines."""
    p = tmp_path / "params.yaml"
    p.write_text("# head\nscans:\n  - synthetic_head\n  - old_scan\n\nbake:\n  resolution: 2048   # texels\n")
    set_scans(p, ["synthetic_head", "new_scan_2"])
    assert p.read_text() == ("# head\nscans:\n  - synthetic_head\n  - new_scan_2\n\n"
                             "bake:\n  resolution: 2048   # texels\n")
    at = {"Running stage 'check_params':": 0.0, "Running stage 'ingest@new_scan_2':": 1.0}
    starts = [(*RUNNING.match(line).groups(), t) for line, t in at.items()]
    assert [s[:2] for s in starts] == [("check_params", None), ("ingest", "new_scan_2")]
    assert RUNNING.match("Updating lock file 'dvc.lock'") is None
    assert stage_walls(starts, 3.5) == {"check_params": 1.0, "ingest": 2.5}
