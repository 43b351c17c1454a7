"""The one door to Blender: every Blender worker process starts here, and nowhere else.

A worker is a module of this package run as ``python -m pipeline.blender.<worker> ...`` (it
imports bpy, so it never runs inside a stage's own process). The callers name the worker they
start, as a string (``"pipeline.blender.render_worker"``), so each stage's code deps and the
render fingerprint (pipeline/sources.py) hold exactly the workers it runs; this module builds
the command line, sets the environment and starts the child, which dies with its parent
(pipeline/io/scratch.py).

It imports no bpy and nothing of render, usd or the workers: it sits on a floor of its own just
above io (tests/test_layers.py), so render's shards and the preview step reach Blender through it
while the workers stay above render. ``tests/test_layers.py`` counts a ``-m pipeline.x`` command
line as an import, and only this module may build one for a Blender worker.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from pipeline.io.scratch import die_with_parent, run_child

__all__ = ["ROOT", "PACKAGE", "command", "environment", "run", "start"]

#: The repository root (the workers run from it, the project importable).
ROOT = Path(__file__).resolve().parents[2]
#: Where every worker lives.
PACKAGE = "pipeline.blender"
_WORKER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def command(worker: str, args=(), python: str | None = None) -> list[str]:
    """``[python, "-m", worker, *args]`` for the worker module ``worker`` (``pipeline.blender.<name>``;
    anything else raises ValueError: the door opens on Blender only)."""
    prefix = PACKAGE + "."
    if not (isinstance(worker, str) and worker.startswith(prefix) and _WORKER.fullmatch(worker[len(prefix):])):
        raise ValueError(f"{worker!r} is not a Blender worker ({prefix}<module>)")
    return [python or sys.executable, "-m", worker, *(str(a) for a in args)]


def environment() -> dict:
    """This process's environment with the repository root first on ``PYTHONPATH``, so the worker
    imports this checkout's ``pipeline`` whatever folder or dask worker starts it."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p])
    return env


def run(worker: str, args=(), python: str | None = None) -> subprocess.CompletedProcess:
    """Run a one-shot worker (a preview, a round trip) to its end from the repository root; its
    stdout and stderr captured as text. The caller reads the return code and the worker's report."""
    return run_child(command(worker, args, python), capture_output=True, text=True, cwd=ROOT, env=environment())


def start(worker: str, args=(), stderr=subprocess.DEVNULL, python: str | None = None) -> subprocess.Popen:
    """Start a persistent worker (the render worker) from the repository root, its stdin and stdout
    pipes for the caller's protocol, its stderr to ``stderr`` (a log file or DEVNULL)."""
    return subprocess.Popen(command(worker, args, python), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=stderr, cwd=str(ROOT), env=environment(), preexec_fn=die_with_parent)
