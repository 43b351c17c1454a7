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
with stages.check_params before it is replaced. Then ``dvc repro usd@<name> ...`` runs for the
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

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_text

#: Marks around the lines this command owns, in ``scans:`` and in ``identities:`` (2-space indent).
BEGIN, END = "  # >>> identities", "  # <<< identities"
#: A lighter default mesh than the home head's 350k triangles: ~2x faster through the per-scan
#: stages with the same retopologised asset (docs/synthetic_head.md, "Identities").
DEFAULT_TRIANGLES = 150_000
#: 1 / golden ratio: tone i = frac(u0 + i * this) spreads any N tones evenly over [0, 1).
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def identity_name(seed: int, i: int) -> str:
    return f"ident_s{seed}_{i:03d}"


def draw_identity(seed: int, i: int, triangles: int) -> dict:
    """Identity ``i`` of ``seed``: the ``synthetic_head`` keys it sets (plain YAML scalars).

    The skin tones follow a golden-ratio sequence from a seeded start, so any first N of them
    cover [0, 1] evenly; an age-like draw sets both wrinkles (0.3-2.2) and pores (0.7-1.6)."""
    rng = np.random.default_rng([0x1D, int(seed), int(i)])
    u0 = float(np.random.default_rng([0x1D, int(seed)]).uniform())
    age = float(rng.uniform())
    return {
        "seed": int(rng.integers(0, 2**31 - 1)),
        "eye_shape": round(float(rng.uniform()), 2),          # hoodedness: 0 round .. 1 hooded
        "skin_tone": round((u0 + i * _GOLDEN) % 1.0, 3),
        "wrinkle_scale": round(0.3 + 1.9 * age, 2),
        "pore_scale": round(0.7 + 0.9 * age, 2),
        "eye_spacing_mm": round(float(np.clip(rng.normal(63.0, 3.0), 57.0, 69.0)), 1),
        "target_triangles": int(triangles),
    }


def _flow(entry: dict) -> str:
    return "{" + ", ".join(f"{k}: {v}" for k, v in entry.items()) + "}"


def _marked(lines: list[str], top: str, source) -> tuple[int, int]:
    """(begin, end) line indices of the marks inside the top-level key ``top:``."""
    try:
        start = lines.index(f"{top}:")
    except ValueError:
        raise ScanError(source, f"has no top-level '{top}:' list") from None
    stop = next((k for k in range(start + 1, len(lines)) if lines[k] and not lines[k][0].isspace()
                 and not lines[k].startswith("#")), len(lines))
    b = next((k for k in range(start, stop) if lines[k].startswith(BEGIN)), None)
    e = next((k for k in range(start, stop) if lines[k].startswith(END)), None)
    if b is None or e is None or e < b:
        raise ScanError(source, f"'{top}:' has no '{BEGIN.strip()}' ... '{END.strip()}' marks "
                                "(add the two comment lines where the generated entries go)")
    return b, e


def add_identities(text: str, entries: dict, source="params.yaml") -> str:
    """``text`` (params.yaml) with ``entries`` ({name: keys}) between the marks of ``scans:`` and
    ``identities:``; the entries already there are kept, those of the same names replaced.
    Every line outside the marks is unchanged."""
    import yaml

    lines = text.split("\n")
    b, e = _marked(lines, "identities", source)
    have = {}
    for ln in lines[b + 1:e]:
        if ln.strip() and not ln.strip().startswith("#"):
            one = yaml.safe_load(ln)
            if not isinstance(one, dict):
                raise ScanError(source, f"identities: cannot read the generated line {ln.strip()!r}")
            have.update(one)
    have.update(entries)
    lines[b + 1:e] = [f"  {n}: {_flow(have[n])}" for n in sorted(have)]
    b, e = _marked(lines, "scans", source)
    names = [ln.strip()[2:].strip() for ln in lines[b + 1:e] if ln.strip().startswith("- ")]
    names += [n for n in sorted(entries) if n not in names]
    lines[b + 1:e] = [f"  - {n}" for n in names]
    return "\n".join(lines)


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
        import yaml

        from stages.check_params import check_params

        check_params(yaml.safe_load(text), source=str(args.params))    # before anything is written
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
