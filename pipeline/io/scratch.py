"""Scratch space and child processes that do not outlive their stage.

* :func:`stage_scratch` gives a stage its own folder under ``$TMPDIR``
  (``eyerig-<stage>-<pid>-XXXX``), makes it the ``TMPDIR`` of the stage and of every child
  it starts (Blender, Dask workers and their ``dask-scratch-space``), and removes it at exit.
  Folders left by a killed stage (its pid is gone) are removed when the next stage starts.
* :func:`die_with_parent` is a ``preexec_fn`` that asks Linux to SIGTERM a child when the
  process that started it dies (``prctl(PR_SET_PDEATHSIG)``), so a Blender preview or render
  worker never outlives a killed stage; :func:`run_child` is ``subprocess.run`` with it.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path
from typing import Iterator

_PR_SET_PDEATHSIG = 1
_SCRATCH = re.compile(r"eyerig-[A-Za-z0-9_]+-(\d+)-[A-Za-z0-9_]+")


def die_with_parent() -> None:
    """``preexec_fn``: the child gets SIGTERM when its parent dies (Linux; a no-op elsewhere)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def run_child(cmd, **kwargs) -> subprocess.CompletedProcess:
    """:func:`subprocess.run` whose child dies with this process (see :func:`die_with_parent`)."""
    return subprocess.run(cmd, preexec_fn=die_with_parent, **kwargs)


def pid_alive(pid: int) -> bool:
    """Is a process ``pid`` running (any owner)? A zombie (exited, not yet reaped by its parent)
    is not: it writes nothing more, and a dask worker SIGKILLed mid-write stays one until its
    parent waits for it, so the sibling it left would otherwise be kept as another run's."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:         # gone since, or no /proc (not Linux)
        return not os.path.exists("/proc/self/stat")
    return stat[stat.rfind(")") + 2:][:1] not in ("Z", "X")


def remove_stale_scratch(base) -> list[Path]:
    """Remove ``eyerig-*-<pid>-*`` folders in ``base`` whose process is gone; returns them."""
    removed = []
    try:
        entries = list(os.scandir(base))
    except OSError:
        return removed
    for e in entries:
        m = _SCRATCH.fullmatch(e.name)
        if m and e.is_dir(follow_symlinks=False) and not pid_alive(int(m.group(1))):
            shutil.rmtree(e.path, ignore_errors=True)
            removed.append(Path(e.path))
    return removed


@contextlib.contextmanager
def stage_scratch(stage: str) -> Iterator[Path]:
    """This process's scratch folder, the ``TMPDIR`` of it and its children while inside.

    The previous ``TMPDIR`` (environment and :mod:`tempfile`) is restored on exit and the
    folder removed, whatever happened inside.
    """
    base = tempfile.gettempdir()
    remove_stale_scratch(base)
    tag = re.sub(r"[^A-Za-z0-9_]", "_", stage) or "stage"
    folder = Path(tempfile.mkdtemp(prefix=f"eyerig-{tag}-{os.getpid()}-", dir=base))
    old_env, old_tempdir = os.environ.get("TMPDIR"), tempfile.tempdir
    os.environ["TMPDIR"] = str(folder)
    tempfile.tempdir = str(folder)
    try:
        yield folder
    finally:
        if old_env is None:
            os.environ.pop("TMPDIR", None)
        else:
            os.environ["TMPDIR"] = old_env
        tempfile.tempdir = old_tempdir
        shutil.rmtree(folder, ignore_errors=True)
