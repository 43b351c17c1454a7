"""benchmarks.bench_band refuses a malformed or missing --set before it builds anything (exit 2, one
line naming it)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("spec, says", [("seed5", "give NAME=BUILDS:PARAMS"),
                                         ("seed5=/nonexistent/builds:/nonexistent/p.yaml", "/nonexistent/builds does not exist")])
def test_a_bad_set_is_refused_in_one_line(tmp_path, spec, says):
    r = subprocess.run([sys.executable, "-m", "benchmarks.bench_band", "--set", spec, "--work", str(tmp_path / "w")],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    assert says in r.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "w").exists()
