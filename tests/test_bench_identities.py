"""benchmarks.bench_identities refuses bad arguments before it builds anything (exit 2, one line)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("args, problem", [
    (["--n", "0"], "--n must be >= 1 and --seed >= 0"),
    (["--seed", "-1"], "--n must be >= 1 and --seed >= 0"),
    (["--n", "3", "--only", "3"], "--only: indices must lie in 0 .. 2"),
])
def test_bad_arguments_exit_2_naming_the_problem(tmp_path, args, problem):
    r = subprocess.run([sys.executable, "-m", "benchmarks.bench_identities", "--work", str(tmp_path / "w"), *args],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2
    assert problem in r.stderr
    assert not (tmp_path / "w").exists()          # nothing built, nothing written
