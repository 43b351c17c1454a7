"""A stage run by another interpreter than the project's .venv is refused in one line (`dvc repro`
runs `python -m stages.<stage>` with the first `python` on PATH)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from stages import PYTHON_OK_ENV, interpreter_problem

ROOT = Path(__file__).resolve().parent.parent


def _project(tmp_path):
    (tmp_path / ".venv" / "bin").mkdir(parents=True)
    (tmp_path / ".venv" / "bin" / "python").write_text("")
    return tmp_path


def test_other_interpreter_named_with_the_venv(tmp_path):
    root = _project(tmp_path)
    why = interpreter_problem(root, "/usr", env={})
    assert why is not None and "/usr runs this stage" in why and str(root / ".venv") in why
    assert "\n" not in why


def test_the_venv_itself_and_a_link_to_it_pass(tmp_path):
    root = _project(tmp_path)
    assert interpreter_problem(root, root / ".venv", env={}) is None
    (tmp_path / "link").symlink_to(root / ".venv")
    assert interpreter_problem(root, tmp_path / "link", env={}) is None


def test_no_venv_or_the_override_passes(tmp_path):
    assert interpreter_problem(tmp_path, "/usr", env={}) is None          # a clone run by another env
    root = _project(tmp_path)
    assert interpreter_problem(root, "/usr", env={PYTHON_OK_ENV: "1"}) is None
    assert interpreter_problem(root, "/usr", env={PYTHON_OK_ENV: "0"}) is not None


@pytest.mark.skipif(not (ROOT / ".venv" / "bin" / "python").exists() or Path(sys.prefix).resolve()
                    != (ROOT / ".venv").resolve(), reason="the tests do not run in this checkout's .venv")
def test_base_interpreter_refused_before_any_work(tmp_path):
    base = Path(sys.base_prefix) / "bin" / f"python{sys.version_info[0]}.{sys.version_info[1]}"
    if not base.exists():
        pytest.skip(f"no base interpreter at {base}")
    out = tmp_path / "snap"
    r = subprocess.run([str(base), "-m", "stages.snap", "a", "b", "c", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "put .venv/bin first on PATH" in lines[0]
    assert not out.exists()
