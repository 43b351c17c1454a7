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
``renders/<name>`` beside params.yaml, and the asset's picture ``rigged_assets/<name>.preview.png``. Everything is checked before anything changes (a name
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
import shlex
import subprocess
import sys
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.params_check import check_params_text
from pipeline.synthetic_head.identities import DEFAULT_TRIANGLES
from pipeline.synthetic_head.identity_files import add, remove, repro_command


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
            print(remove(args.params, args.remove, check_params_text))
            return 0
        entries, run = add(args.params, args.n, args.seed, args.triangles, check_params_text,
                           repro=not args.no_repro)
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
