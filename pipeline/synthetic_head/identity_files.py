"""The files behind ``stages.identities``: the new identities' entries in params.yaml and which
dvc runs their chain (the venv's), and an identity's removal (its params entries, its dvc.lock
stages and its output folders), every refusal before the first change."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.io.atomic import refuse_link, write_text
from pipeline.synthetic_head.identities import (add_identities, draw_identity, drop_lock_stages, identity_name,
                                                remove_identities)

OUTPUT_FOLDERS = ("raw_scans", "build", "rigged_assets", "renders")
#: An identity's outputs that are files, not folders: the preview stage's picture lies beside the
#: asset folder (DVC keeps one stage's outputs out of another's).
OUTPUT_FILES = ("rigged_assets/{}.preview.png",)


def repro_command(names) -> list[str]:
    """``dvc repro usd@<name> ...``: each asset and what it needs, not the renders."""
    return ["dvc", "repro", *[f"usd@{n}" for n in names]]


def repro_env(exe=None, environ=None) -> dict:
    """``environ`` (default os.environ) with the folder of ``exe`` (default this Python) first on
    PATH: dvc.yaml's commands say ``python``, and dvc runs the first one on PATH, which outside an
    activated venv has none of the pipeline's packages. The folder is not resolved: a venv's
    ``python`` is a link to the base interpreter, whose folder is not the venv's."""
    env = dict(os.environ if environ is None else environ)
    first = str(Path(sys.executable if exe is None else exe).parent)
    env["PATH"] = os.pathsep.join([first, *[p for p in env.get("PATH", "").split(os.pathsep) if p]])
    return env


def repro_invocation(names, exe=None, environ=None) -> tuple[list[str], dict]:
    """(argv, env) that run :func:`repro_command`: the dvc first on :func:`repro_env`'s PATH (the
    venv's when it has one). ScanError naming the bin folder when there is no dvc at all."""
    env = repro_env(exe, environ)
    dvc = shutil.which("dvc", path=env["PATH"])
    if dvc is None:
        raise ScanError(env["PATH"].split(os.pathsep)[0], "has no dvc and PATH has none either: install "
                        "it into this venv (pip install dvc) or pass --no-repro (params.yaml was not changed)")
    return [dvc, *repro_command(names)[1:]], env


def add(params: Path, n: int, seed: int, triangles: int, checked_params,
        repro: bool = True) -> tuple[dict, tuple | None]:
    """Add identities ``0..n-1`` of ``seed`` to ``params`` (stages/identities.py's docstring).

    Returns ``({name: synthetic_head keys}, (argv, env) of their dvc repro)``, the second None
    without ``repro``. ``checked_params(text, source)``: params.yaml's whole check, as for
    :func:`remove`. Everything is checked (the numbers, the edited text, a dvc to run) before
    ``params`` is replaced; ScanError otherwise, with the file unchanged."""
    if n < 1 or seed < 0:
        raise ScanError(params, f"--n must be >= 1 and --seed >= 0 (got {n}, {seed})")
    entries = {identity_name(seed, i): draw_identity(seed, i, triangles) for i in range(n)}
    text = add_identities(params.read_text(encoding="utf-8"), entries, params)
    checked_params(text, params)                       # before anything is written
    run = repro_invocation(entries) if repro else None     # no dvc: params.yaml unchanged
    write_text(params, text)
    return entries, run


def check_folder(path) -> None:
    """ScanError for a link or a file at ``path``: the command deletes only folders the pipeline
    wrote, and never follows a link out of the project (pipeline/io/atomic.py refuse_link)."""
    refuse_link(path)
    if Path(path).exists() and not Path(path).is_dir():
        raise ScanError(path, "is not a folder (an identity's outputs are folders); nothing was changed")


def remove_folder(path) -> bool:
    """Delete the folder ``path`` (True) or nothing when there is none (False); a link or a file
    there is refused (:func:`check_folder`). The folder is renamed to a hidden temporary sibling
    first, so it vanishes whole even if the delete is killed (what is left is a
    ``.<name>.tmp-<pid>-*`` folder, which git, dvc and the next atomic write of that name clear)."""
    path = Path(path)
    check_folder(path)
    if not path.exists():
        return False
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-{os.getpid()}-", dir=path.parent))
    tmp.rmdir()
    os.replace(path, tmp)
    shutil.rmtree(tmp)
    return True


def check_file(path) -> None:
    """ScanError for a link or a folder at ``path`` (:func:`check_folder`'s rule for a file)."""
    refuse_link(path)
    if Path(path).exists() and not Path(path).is_file():
        raise ScanError(path, "is not a file (an identity's preview is one); nothing was changed")


def remove(params: Path, names, checked_params) -> str:
    """Remove the identities ``names`` (stages/identities.py's docstring); returns the line that
    reports it. ``checked_params(text, source)``: params.yaml's whole check (pipeline.params_check
    sits above this package), raising ScanError."""
    names = list(dict.fromkeys(names))
    root = params.resolve().parent
    text = remove_identities(params.read_text(encoding="utf-8"), names, params)
    data = checked_params(text, params)
    scans = [n for n in names if n in (data.get("scans") or [])]
    if scans:
        raise ScanError(params, f"scans: {scans[0]!r} is listed outside the '# >>> identities' marks too "
                                "(a scan of that name: its folders are not an identity's); nothing was changed")
    lock, lock_text, dropped = root / "dvc.lock", None, []
    if lock.is_file():
        lock_text, dropped = drop_lock_stages(lock.read_bytes().decode("utf-8"), names, lock)
    folders = [root / d / n for n in names for d in OUTPUT_FOLDERS]
    files = [root / f.format(n) for n in names for f in OUTPUT_FILES]
    for f in folders:                    # every refusal before the first change
        check_folder(f)
    for f in files:
        check_file(f)
    removed = [f for f in folders if remove_folder(f)]
    removed_files = [f for f in files if f.is_file()]
    for f in removed_files:
        f.unlink()
    if dropped:
        write_text(lock, lock_text)
    write_text(params, text)             # last: until here a rerun of the same command finishes the job
    return (f"{params}: removed {', '.join(names)} from identities: and scans:, {len(dropped)} stage(s) "
            f"from {lock.name}, {len(removed)} folder(s)"
            + (f", {len(removed_files)} preview(s)" if removed_files else ""))
