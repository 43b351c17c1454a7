"""Atomic writes: every file or folder a stage produces appears whole or not at all.

Everything is written to a temporary sibling (same folder, so the final
``os.replace`` is a rename on one filesystem), flushed to disk (``fsync`` of every
file, then of the folder after the rename; a file written atomically inside an
``atomic_dir`` folder is flushed once, with that folder's tree) and renamed into place. A killed
stage leaves at most a ``.<name>.tmp-<pid>-*`` sibling, which git and DVC ignore,
and never a half-written output; other scans' outputs are never touched. The
next write of the same output removes such siblings once their process
``<pid>`` is gone (:func:`remove_stale_siblings`). No writer writes through a symbolic link
(:func:`refuse_link`): a link where an output goes is refused in one line.
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


def refuse_link(path, root=None) -> None:
    """Refuse (ScanError) a symbolic link at ``path``, or at any folder between ``root`` (excluded)
    and ``path``: a command writes and deletes only its own files, so it never writes through a
    link, nor follows one out of its folder. ``root`` None: ``path`` itself only (the folders above
    an output are the user's to link as they like)."""
    from pipeline.errors import ScanError

    path = Path(path)
    chain = [path]
    if root is not None:
        rel = Path(os.path.relpath(os.path.abspath(path), os.path.abspath(root)))
        if rel.parts and rel.parts[0] != "..":
            chain = [Path(root).joinpath(*rel.parts[:k]) for k in range(1, len(rel.parts) + 1)]
    for p in chain:
        if p.is_symlink():
            raise ScanError(p, "is a symbolic link where this command writes or deletes; it follows no "
                               "link out of its folder (remove the link; nothing was changed)")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _tmp_prefix(path: Path) -> str:
    return f".{path.name}.tmp-"


def remove_stale_siblings(path) -> list[Path]:
    """Remove temporary siblings of ``path`` (``.<name>.tmp-<pid>-*``) whose process is gone.

    Siblings of live processes (another run writing the same output) are kept; a sibling
    without a pid (older naming) is stale by definition. Returns the removed paths.
    """
    from pipeline.io.scratch import pid_alive

    path = Path(path)
    prefix = _tmp_prefix(path)
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for e in entries:
        if not e.name.startswith(prefix):
            continue
        head = e.name[len(prefix):].split("-", 1)[0]
        if head.isdigit() and pid_alive(int(head)):
            continue
        _remove(Path(e.path))
        removed.append(Path(e.path))
    return removed


# temporary folders of the atomic_dir calls now open in this process (absolute paths): a file
# written atomically inside one need not be flushed itself, since the folder's tree is flushed
# before it is published, and an unpublished folder is garbage after a crash anyway
_OPEN_DIRS: set[str] = set()


def _inside_open_dir(path: Path) -> bool:
    parent = Path(os.path.abspath(path)).parent
    return any(str(p) in _OPEN_DIRS for p in (parent, *parent.parents))


def _fsync_path(path: Path, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if directory else 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """fsync every file and folder under ``root`` (so a rename publishes only durable data)."""
    if root.is_symlink():
        return
    if root.is_file():
        _fsync_path(root)
        return
    for dirpath, _dirs, files in os.walk(root):
        for f in files:
            p = Path(dirpath, f)
            if not p.is_symlink() and p.is_file():
                _fsync_path(p)
        _fsync_path(Path(dirpath), directory=True)


def _tmp_sibling(path: Path, directory: bool) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_siblings(path)
    prefix = f"{_tmp_prefix(path)}{os.getpid()}-"
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


def _files(root: Path) -> set[str]:
    """Relative paths of the files (and links) under ``root``, not following links."""
    out = set()
    for dirpath, dirs, files in os.walk(root):
        rel = Path(dirpath).relative_to(root)
        out.update((rel / f).as_posix() for f in files)
        out.update((rel / d).as_posix() for d in dirs if Path(dirpath, d).is_symlink())
    return out


def foreign_files(old, new) -> list[str]:
    """Files under the folder ``old`` that the folder ``new`` has no file of the same path for
    (sorted relative paths): what replacing ``old`` with ``new`` would delete that an earlier
    write of the same output would not have held."""
    return sorted(_files(Path(old)) - _files(Path(new)))


@contextlib.contextmanager
def atomic_dir(path) -> Iterator[Path]:
    """Build a folder in a temporary sibling and rename it to ``path`` on success.

    An existing ``path`` is replaced only after the new folder is complete, and only when every
    file in it has a namesake in the new folder (an earlier write of this output): a folder that
    holds anything else (:func:`foreign_files`), or a file at ``path``, is someone else's work
    and is refused with a ScanError. On any exception the temporary folder is removed and
    ``path`` is left as it was.

    Yields
    ------
    pathlib.Path
        The temporary folder to write into.
    """
    from pipeline.errors import ScanError

    path = Path(path)
    refuse_link(path)
    if path.exists() and not path.is_dir():
        raise ScanError(path, "exists and is not a folder: it was left as it was")
    tmp = _tmp_sibling(path, directory=True)
    key = os.path.abspath(tmp)
    _OPEN_DIRS.add(key)
    try:
        yield tmp
        _OPEN_DIRS.discard(key)
        foreign = foreign_files(path, tmp) if path.is_dir() and not path.is_symlink() else []
        if foreign:
            more = f" and {len(foreign) - 1} more file(s)" if len(foreign) > 1 else ""
            raise ScanError(path, f"holds {foreign[0]!r}{more} that this run does not write: move them or "
                                  "choose another folder (it was left as it was)")
        _fsync_tree(tmp)
        if path.exists() or path.is_symlink():
            old = _tmp_sibling(path, directory=True)
            old.rmdir()
            os.replace(path, old)
            os.replace(tmp, path)
            _remove(old)
        else:
            os.replace(tmp, path)
        _fsync_path(path.parent, directory=True)
    except BaseException:
        _OPEN_DIRS.discard(key)
        _remove(tmp)
        raise


@contextlib.contextmanager
def atomic_file(path, root=None) -> Iterator[Path]:
    """Write one file through a temporary sibling path; rename on success. A symbolic link at
    ``path`` (or at a folder between ``root`` and it) is refused (:func:`refuse_link`).

    Yields
    ------
    pathlib.Path
        Temporary path to write to (it exists, empty). Keeps ``path``'s suffix so
        writers that choose a format by extension still work.
    """
    path = Path(path)
    refuse_link(path, root)
    tmp = _tmp_sibling(path, directory=False)
    tmp_with_suffix = tmp.with_name(tmp.name + "".join(path.suffixes))
    os.replace(tmp, tmp_with_suffix)
    try:
        yield tmp_with_suffix
        flush = not _inside_open_dir(path)     # else the enclosing atomic_dir flushes it
        if flush:
            _fsync_path(tmp_with_suffix)
        os.replace(tmp_with_suffix, path)
        if flush:
            _fsync_path(path.parent, directory=True)
    except BaseException:
        _remove(tmp_with_suffix)
        raise


def write_bytes(path, data: bytes, root=None) -> None:
    """Atomically write ``data`` to ``path`` (no link at it, nor between ``root`` and it)."""
    with atomic_file(path, root) as tmp:
        tmp.write_bytes(data)


def write_text(path, text: str, root=None) -> None:
    """Atomically write UTF-8 ``text`` to ``path``."""
    write_bytes(path, text.encode("utf-8"), root)


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


def write_json(path, obj, root=None) -> None:
    """Atomically write ``obj`` as indented JSON (numpy arrays become lists)."""
    write_text(path, dumps_json(obj), root)
