"""One thin script per DVC stage: parse paths, load, call the library, save."""

import os as _os
import sys as _sys
from pathlib import Path as _Path

# a stage run by `dvc repro` is `python -m stages.<stage>` with whatever `python` comes first on
# PATH: without the project's .venv/bin there, another interpreter runs it (a traceback halfway,
# or, worse, other package versions and other bytes)
PYTHON_OK_ENV = "EYERIG_ANY_PYTHON"


def interpreter_problem(root, prefix, env=None):
    """The one-line reason why the interpreter at ``prefix`` (``sys.prefix``) must not run the
    stages of the project at ``root``, or None: the project has a ``.venv`` and this is another
    interpreter (``EYERIG_ANY_PYTHON=1`` in ``env`` allows it)."""
    env = _os.environ if env is None else env
    venv = _Path(root) / ".venv"
    if env.get(PYTHON_OK_ENV) == "1" or not (venv / "bin" / "python").exists():
        return None
    if _Path(prefix).resolve() == venv.resolve():
        return None
    return (f"{_Path(prefix)} runs this stage, not the project's {venv}: put .venv/bin first on PATH "
            f"(`make run` does; or `. .venv/bin/activate`), or set {PYTHON_OK_ENV}=1")


if _sys.argv[:1] == ["-m"]:
    _why = interpreter_problem(_Path(__file__).resolve().parent.parent, _sys.prefix)
    if _why is not None:
        print(f"error: {_why}", file=_sys.stderr)
        raise SystemExit(2)

import pipeline  # noqa: E402,F401 -- before numpy: a stage pins its numeric kernels (pipeline/kernels.py)
