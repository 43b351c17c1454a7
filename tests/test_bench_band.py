"""benchmarks.bench_band, bench_band_jitter and bench_yaw refuse a malformed or missing --set before they build
anything (exit 2, one line naming it)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("bench", ["bench_band", "bench_band_jitter", "bench_yaw"])
@pytest.mark.parametrize("spec, says", [("seed5", "give NAME=BUILDS:PARAMS"),
                                         ("seed5=/nonexistent/builds:/nonexistent/p.yaml", "/nonexistent/builds does not exist")])
def test_a_bad_set_is_refused_in_one_line(tmp_path, spec, says, bench):
    work = ["--work", str(tmp_path / "w")] if bench == "bench_band" else ["--out", str(tmp_path / "w")]
    r = subprocess.run([sys.executable, "-m", f"benchmarks.{bench}", "--set", spec, *work],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    assert says in r.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "w").exists()
