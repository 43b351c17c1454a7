"""Add N procedural identities (heads with no scan) to ``params.yaml`` and build their assets.

    python -m stages.identities --n 20 [--seed 0] [--triangles 150000] [--params params.yaml] [--no-repro]

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

Bad input (no marks, a bad option): exit 2 with one line naming the file and the problem.
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
from pathlib import Path

from pipeline.errors import ScanError
from pipeline.io.atomic import write_text
from pipeline.synthetic_head.identities import DEFAULT_TRIANGLES, add_identities, draw_identity, identity_name

def repro_command(names) -> list[str]:
    """``dvc repro usd@<name> ...``: each asset and what it needs, not the renders."""
    return ["dvc", "repro", *[f"usd@{n}" for n in names]]


def _dvc() -> str:
    """The dvc beside this Python (the project's venv) when there is one, else the PATH's."""
    here = Path(sys.executable).parent / "dvc"
    return str(here) if here.is_file() else "dvc"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, required=True, help="identities to add (>= 1)")
    ap.add_argument("--seed", type=int, default=0, help="draws every identity (default 0)")
    ap.add_argument("--triangles", type=int, default=DEFAULT_TRIANGLES,
                    help=f"raw head mesh triangles (default {DEFAULT_TRIANGLES})")
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--no-repro", action="store_true", help="print the dvc repro command, do not run it")
    args = ap.parse_args(argv)
    try:
        if args.n < 1 or args.seed < 0:
            raise ScanError(args.params, f"--n must be >= 1 and --seed >= 0 (got {args.n}, {args.seed})")
        if not args.params.is_file():
            raise ScanError(args.params, "not found")
        entries = {identity_name(args.seed, i): draw_identity(args.seed, i, args.triangles) for i in range(args.n)}
        text = add_identities(args.params.read_text(encoding="utf-8"), entries, args.params)
        from pipeline.io.strict_yaml import DuplicateKeyError, load_strict
        from pipeline.params_check import check_params

        try:
            data = load_strict(text)       # params.yaml's rules: no repeated key
        except DuplicateKeyError as exc:
            raise ScanError(args.params, f"{exc}: each key may appear once") from None
        check_params(data, source=str(args.params), complete=True)    # before anything is written
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
    return subprocess.call([_dvc(), *cmd[1:]], cwd=args.params.resolve().parent)


if __name__ == "__main__":
    sys.exit(main())
