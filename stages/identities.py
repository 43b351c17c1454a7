"""Add N procedural identities (heads with no scan) to ``params.yaml`` and build their assets, or
remove identities again.

    python -m stages.identities --n 20 [--seed 0] [--triangles 150000] [--params params.yaml] [--no-repro]
    python -m stages.identities --remove ident_s0_001 [ident_s0_002 ...] [--params params.yaml]

Each identity is an entry ``ident_s<seed>_<i>`` of ``identities:`` (the ``synthetic_head:`` keys
that differ: seed, eye_shape, skin_tone, wrinkle_scale, pore_scale, eye_spacing_mm,
target_triangles) and the same name under ``scans:``, so the one DAG builds it like a scan:
the ``synthetic_head`` stage writes ``raw_scans/<name>``, the per-scan stages its asset
``rigged_assets/<name>``. Entry ``i`` depends only on ``(seed, i)``: ``--n 5`` gives the first
five of ``--n 20``, and a second run replaces the entries of the same names (same values).

``params.yaml`` is edited as text between the ``# >>> identities`` and ``# <<< identities``
marks of each list (written there by hand once; its comments stay as they are), then checked
with pipeline.params_check before it is replaced. Then ``dvc repro usd@<name> ...`` runs for the
new names (each one pass of the per-scan stages; ``--no-repro`` prints the command instead).
The dataset command mixes them with the scans: ``python -m stages.dataset --assets rigged_assets/*``.

dvc runs with this Python's bin folder first on PATH (:func:`repro_env`), so the ``python`` of
dvc.yaml's commands is the one running this command (the venv's), not the first on the user's
PATH. The environment is checked before params.yaml is edited only as far as it is cheap and
certain (a dvc to run); a repro that fails later leaves the new entries listed, and says so
with the command to rerun. That is what a pipeline TD expects of a DVC project: params.yaml
says what should exist and ``dvc repro`` builds it, so a failed build (a missing package, a
bad scan, Ctrl-C) is fixed and rerun like any other; the entries are valid, rerunning this
command is idempotent, and rolling them back would lose the stages that did finish.

``--remove`` takes names out of both marked lists (checked the same way), deletes their stages
``<stage>@<name>`` from ``dvc.lock`` (cut out as text: every other stage keeps its bytes) and
their folders ``raw_scans/<name>``, ``build/<name>``, ``rigged_assets/<name>`` and
``renders/<name>`` beside params.yaml. Everything is checked before anything changes (a name
not between the marks, a folder that is a symbolic link, a dvc.lock not laid out as dvc
writes it); then the folders go first and params.yaml last, so an interrupted removal still
lists the identity and the same command finishes it. A folder is renamed to a hidden
``.<name>.tmp-<pid>-*`` sibling before it is deleted, so ``rigged_assets/*`` never sees half an
asset. dvc's cache keeps the outputs until ``dvc gc``.

Bad input (no marks, a bad option, an unknown name): exit 2 with one line naming the file and the
problem.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.io.atomic import refuse_link, write_text
from pipeline.synthetic_head.identities import (DEFAULT_TRIANGLES, add_identities, draw_identity,
                                                drop_lock_stages, identity_name, remove_identities)

#: The folders (beside params.yaml) that hold an identity's outputs, one ``<folder>/<name>`` each.
OUTPUT_FOLDERS = ("raw_scans", "build", "rigged_assets", "renders")


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


def checked_params(text: str, source) -> dict:
    """``text`` read as params.yaml is read (no repeated key) and checked whole; ScanError otherwise."""
    from pipeline.io.strict_yaml import DuplicateKeyError, load_strict
    from pipeline.params_check import check_params

    try:
        data = load_strict(text)       # params.yaml's rules: no repeated key
    except DuplicateKeyError as exc:
        raise ScanError(source, f"{exc}: each key may appear once") from None
    check_params(data, source=str(source), complete=True)
    return data


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


def remove(params: Path, names) -> str:
    """Remove the identities ``names`` (module docstring); returns the line that reports it."""
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
    for f in folders:                    # every refusal before the first change
        check_folder(f)
    removed = [f for f in folders if remove_folder(f)]
    if dropped:
        write_text(lock, lock_text)
    write_text(params, text)             # last: until here a rerun of the same command finishes the job
    return (f"{params}: removed {', '.join(names)} from identities: and scans:, {len(dropped)} stage(s) "
            f"from {lock.name}, {len(removed)} folder(s)")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--n", type=int, help="identities to add (>= 1)")
    what.add_argument("--remove", nargs="+", metavar="NAME",
                      help="identities to remove: their params.yaml entries, dvc.lock stages and folders")
    ap.add_argument("--seed", type=int, default=0, help="draws every identity (default 0)")
    ap.add_argument("--triangles", type=int, default=DEFAULT_TRIANGLES,
                    help=f"raw head mesh triangles (default {DEFAULT_TRIANGLES})")
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--no-repro", action="store_true", help="print the dvc repro command, do not run it")
    args = ap.parse_args(argv)
    try:
        if not args.params.is_file():
            raise ScanError(args.params, "not found")
        if args.remove:
            print(remove(args.params, args.remove))
            return 0
        if args.n < 1 or args.seed < 0:
            raise ScanError(args.params, f"--n must be >= 1 and --seed >= 0 (got {args.n}, {args.seed})")
        entries = {identity_name(args.seed, i): draw_identity(args.seed, i, args.triangles) for i in range(args.n)}
        text = add_identities(args.params.read_text(encoding="utf-8"), entries, args.params)
        checked_params(text, args.params)                       # before anything is written
        run = None if args.no_repro else repro_invocation(entries)   # no dvc: params.yaml unchanged
        write_text(args.params, text)
    except ScanError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cmd = repro_command(entries)
    print(f"{args.params}: {len(entries)} identities ({', '.join(list(entries)[:3])}"
          f"{', ...' if len(entries) > 3 else ''}) in identities: and scans:")
    if args.no_repro:
        print(shlex.join(cmd))
        return 0
    print("running: " + shlex.join(cmd), flush=True)
    rc = subprocess.call(run[0], cwd=args.params.resolve().parent, env=run[1])
    if rc != 0:
        again = shlex.join([sys.executable, "-m", "stages.identities", *argv])
        print(f"error: {args.params}: dvc repro exited {rc}; the {len(entries)} identities stay listed there "
              f"(valid entries): fix the error above and rerun `{again}` (it builds only what is missing), "
              "or take them out with --remove", file=sys.stderr)
    return rc


if __name__ == "__main__":
    sys.exit(main())
