"""Atomic writes: every file or folder a stage produces appears whole or not at all.

Everything is written to a temporary sibling (same folder, so the final
``os.replace`` is a rename on one filesystem) and renamed into place. A killed
stage leaves at most a ``*.tmp-*`` sibling, which git and DVC ignore, and never
a half-written output; other scans' outputs are never touched.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _tmp_sibling(path: Path, directory: bool) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    prefix = f".{path.name}.tmp-"
    # mkdtemp/mkstemp create 0700/0600; outputs are shared data, so honour the umask
    # like an ordinary open() would.
    if directory:
        tmp = Path(tempfile.mkdtemp(prefix=prefix, dir=path.parent))
        os.chmod(tmp, 0o777 & ~_umask())
        return tmp
    fd, name = tempfile.mkstemp(prefix=prefix, dir=path.parent)
    os.close(fd)
    os.chmod(name, 0o666 & ~_umask())
    return Path(name)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


@contextlib.contextmanager
def atomic_dir(path) -> Iterator[Path]:
    """Build a folder in a temporary sibling and rename it to ``path`` on success.

    An existing ``path`` is replaced only after the new folder is complete. On any
    exception the temporary folder is removed and ``path`` is left as it was.

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.
    """
    path = Path(path)
    tmp = _tmp_sibling(path, directory=True)
    try:
        yield tmp
        if path.exists() or path.is_symlink():
            old = _tmp_sibling(path, directory=True)
            old.rmdir()
            os.replace(path, old)
            os.replace(tmp, path)
            _remove(old)
        else:
            os.replace(tmp, path)
    except BaseException:
        _remove(tmp)
        raise


@contextlib.contextmanager
def atomic_file(path) -> Iterator[Path]:
    """Write one file through a temporary sibling path; rename on success.

    Yields
    ------
    pathlib.Path
        Temporary path to write to (it exists, empty). Keeps ``path``'s suffix so
        writers that choose a format by extension still work.
    """
    path = Path(path)
    tmp = _tmp_sibling(path, directory=False)
    tmp_with_suffix = tmp.with_name(tmp.name + "".join(path.suffixes))
    os.replace(tmp, tmp_with_suffix)
    try:
        yield tmp_with_suffix
        os.replace(tmp_with_suffix, path)
    except BaseException:
        _remove(tmp_with_suffix)
        raise


def write_bytes(path, data: bytes) -> None:
    """Atomically write ``data`` to ``path``."""
    with atomic_file(path) as tmp:
        tmp.write_bytes(data)


def write_text(path, text: str) -> None:
    """Atomically write UTF-8 ``text`` to ``path``."""
    write_bytes(path, text.encode("utf-8"))


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def dumps_json(obj) -> str:
    """JSON text with numpy arrays and scalars converted; NaN is refused."""
    return json.dumps(obj, indent=1, default=_json_default, allow_nan=False) + "\n"


def write_json(path, obj) -> None:
    """Atomically write ``obj`` as indented JSON (numpy arrays become lists)."""
    write_text(path, dumps_json(obj))
