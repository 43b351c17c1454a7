"""One run at a time in a folder: an exclusive lock file holding the holder's PID and host.

:func:`folder_lock` creates ``<folder>/.eyerig.lock`` (never through a symbolic link), takes an
exclusive ``fcntl.flock`` on it and writes ``{"pid", "host", "started"}`` into it; the lock goes
(the file is removed) when the ``with`` block ends, by return or by exception, and the kernel drops
the ``flock`` of a killed process. A second run is refused with a ScanError naming the holder:

* the ``flock`` is held: a live run (named from the file);
* the file names a process on another host: never taken over (that host's run may be alive; its
  ``flock`` may not reach this one over a network file system);
* the file names a process on this host that is still running (or that this process may not
  signal): refused too, a PID is reused only once the holder is provably gone.

A lock whose holder is provably gone on this host (``os.kill(pid, 0)`` raises
``ProcessLookupError``), or that names no holder (a run killed between creating and writing it),
is taken over; the ``with`` value then says so (the caller prints it: library code never prints).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
from pathlib import Path
from typing import Iterator

from pipeline.errors import ScanError
from pipeline.io.scratch import pid_alive

LOCK_NAME = ".eyerig.lock"


def _holder(fd: int) -> dict | None:
    os.lseek(fd, 0, os.SEEK_SET)
    raw = os.read(fd, 4096)
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not (isinstance(doc, dict) and isinstance(doc.get("pid"), int) and isinstance(doc.get("host"), str)):
        return None
    return doc


def _who(doc: dict | None) -> str:
    if doc is None:
        return "another process (it has not written its pid yet)"
    return f"pid {doc['pid']} on host {doc['host']!r}" + (f", since {doc['started']}" if doc.get("started") else "")


def _gone(pid: int) -> bool:
    """Is ``pid`` provably not running on this host (``os.kill(pid, 0)``: ProcessLookupError)?"""
    return pid > 0 and not pid_alive(pid)


def _open_locked(lock: Path, what: str) -> tuple[int, str | None]:
    """The lock file's fd, flock'd, and the note of a takeover (None: the lock was free)."""
    for _ in range(20):       # the file may be removed by its holder between open and flock: retry
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            if lock.is_symlink():
                raise ScanError(lock, "is a symbolic link: the lock is refused, nothing was changed") from None
            raise ScanError(lock, f"cannot create the lock file ({exc.strerror})") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise ScanError(lock.parent, f"is in use by another {what} run ({_who(_holder(fd))}; lock file "
                                             f"{LOCK_NAME}): wait for it or use another folder") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(lock, follow_symlinks=False).st_ino
            except FileNotFoundError:
                same = False
            if not same:                        # the holder removed it as we opened it: take the new one
                os.close(fd)
                continue
            doc = _holder(fd)
            if os.fstat(fd).st_size == 0:
                return fd, None
            host = socket.gethostname()
            if doc is None:
                return fd, f"took over {lock}: it named no holder (a run killed as it started)"
            if doc["host"] != host:
                raise ScanError(lock.parent, f"is locked by {_who(doc)}, another host: a lock from another host "
                                             f"is never taken over (remove {LOCK_NAME} if that run is gone)")
            if doc["pid"] == os.getpid() or not _gone(doc["pid"]):
                raise ScanError(lock.parent, f"is in use by another {what} run ({_who(doc)}, running; lock "
                                             f"file {LOCK_NAME}): wait for it or use another folder")
            return fd, f"took over the stale lock {lock} of {_who(doc)}: that process is gone"
        except BaseException:
            with contextlib.suppress(OSError):
                os.close(fd)
            raise
    raise ScanError(lock, "could not be taken: it keeps being replaced")


@contextlib.contextmanager
def folder_lock(folder, what: str = "dataset") -> Iterator[str | None]:
    """Hold the lock of ``folder`` (created when absent, and removed again at the end if still
    empty) for the ``with`` block.

    Yields
    ------
    str or None
        A one-line note when a stale lock was taken over (the caller shows it), else None.

    Raises
    ------
    ScanError  another run holds the folder (named), or the lock file is a link or cannot be made.
    """
    folder = Path(folder)
    made = []
    if not folder.exists() and not folder.is_symlink():
        for p in reversed([folder, *folder.parents]):
            if not p.exists():
                made.append(p)
        try:
            folder.mkdir(parents=True)
        except OSError as exc:
            raise ScanError(folder, f"cannot be created ({exc.strerror})") from None
    lock = folder / LOCK_NAME
    try:
        fd, note = _open_locked(lock, what)
    except BaseException:
        _remove_made(made)
        raise
    try:
        doc = {"pid": os.getpid(), "host": socket.gethostname(),
               "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(doc).encode() + b"\n", 0)
        os.fsync(fd)
        yield note
    finally:
        with contextlib.suppress(OSError):
            os.unlink(lock)                    # while still holding the flock
        os.close(fd)
        _remove_made(made)


def _remove_made(made: list) -> None:
    """Remove the folders this lock created, deepest first, where nothing else was put in them."""
    for p in reversed(made):
        with contextlib.suppress(OSError):
            p.rmdir()
