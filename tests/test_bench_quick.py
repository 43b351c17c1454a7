"""make bench-quick (benchmarks.bench_quick) reads benchmarks/budget.yaml before it measures anything:
the committed budget is well formed, and a malformed one exits naming the file and the problem.
Run as ``python -m benchmarks.bench_quick`` (a test imports no benchmark)."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def test_committed_budget_covers_every_chain_stage_and_the_render():
    from tests.fixtures.chain import stage_commands

    b = yaml.safe_load((ROOT / "benchmarks" / "budget.yaml").read_text())
    stages = set(stage_commands("scan", "build", "eyeball", "asset"))
    assert set(b["chain_cpu_s"]) == stages | {"total"}
    assert b["chain_cpu_s"]["total"] == pytest.approx(sum(b["chain_cpu_s"][s] for s in stages), abs=0.05)
    assert set(b["render"]) == {"cpu_s_per_image", "s_per_image"}
    assert 0 < b["tolerance"] < 1


@pytest.mark.parametrize("text, problem", [
    ("chain_cpu_s: {ingest: 1}\n", "needs the mappings chain_cpu_s and render"),
    ("chain_cpu_s: {ingest: -1}\nrender: {s_per_image: 0.5}\n", "budget ingest must be a positive number"),
    ("chain_cpu_s: {ingest: 1}\nrender: {s_per_image: 0.5}\ntolerance: 2\n", "tolerance must be a number in [0, 1)"),
    ("chain_cpu_s: [\n", "cannot read the budget"),
])
def test_bad_budget_exits_naming_the_file(tmp_path, text, problem):
    bad = tmp_path / "budget.yaml"
    bad.write_text(text)
    r = subprocess.run([sys.executable, "-m", "benchmarks.bench_quick", "--budget", str(bad)],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode != 0
    assert str(bad) in r.stderr and problem in r.stderr
