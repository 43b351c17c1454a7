"""Derive the eye-region prior that eyerig ships from the UnityEyes shape model (MIT).

    .venv/bin/python -m benchmarks.derive_eye_prior \
        [--source ../shared/reference/unityeyes_eye_region] \
        [--out pipeline/placement/data/eye_region_prior.npz] [--modes 10] [--check]

Not a benchmark (benchmarks/run_all.py leaves it out): a tool run once, whose output is committed.
The placement (pipeline/placement/prior.py) needs the mean eye region, the first
``--modes`` principal components and their coefficients' mean and sd; the file also keeps the
region's 414 triangles (from ``eye_region.3ds``, whose 229 vertices are in the order of
``mesh_mean.txt``) for the tests and pictures. Metres become millimetres here (x 1000, the scale
the loader applied to the text files before), float64 throughout, so the placement is the one the
text files gave. The same source gives the same bytes; ``--check`` derives into memory and
compares with ``--out`` instead of writing (exit 1 when they differ).

Source files (alexanderdsmith/UnityEyes2 at 156a24a, ``Assets/Resources/ShapePCA/*.txt`` and
``Assets/eye_region.3ds``): ``mesh_mean.txt``, ``pca_components.txt``, ``transformed_mean.txt``,
``transformed_std.txt``, ``eye_region.3ds``. Their licence (MIT, Erroll Wood 2018; A. D. Smith and
B. Muthumanickam 2025) is kept beside the output as ``LICENSE-unityeyes.txt``.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from pipeline.io.eye_prior_file import N_VERTICES, EyePriorArrays, read_eye_prior, write_eye_prior  # noqa: E402

SOURCE = ROOT.parent / "shared" / "reference" / "unityeyes_eye_region"
OUT = ROOT / "pipeline" / "remove_eyeballs" / "data" / "eye_region_prior.npz"
TEXT = ("mesh_mean.txt", "pca_components.txt", "transformed_mean.txt", "transformed_std.txt")


def derive(source: Path, modes: int) -> EyePriorArrays:
    """The prior's arrays from the UnityEyes folder ``source``."""
    import pymeshlab

    t = {f: np.loadtxt(source / f, dtype=np.float64, ndmin=1) for f in TEXT}
    mean, comp = t["mesh_mean.txt"], t["pca_components.txt"]
    mu, sd = t["transformed_mean.txt"], t["transformed_std.txt"]
    if mean.shape != (N_VERTICES, 3) or comp.shape[0] != 3 * N_VERTICES or comp.shape[1] < modes:
        raise SystemExit(f"{source}: not the 229-vertex UnityEyes model with {modes} modes "
                         f"({mean.shape}, {comp.shape})")
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(source / "eye_region.3ds"))
    m = ms.current_mesh()
    Vr, F = np.asarray(m.vertex_matrix(), np.float64), np.asarray(m.face_matrix(), np.int64)
    # the same 229 vertices in the same order: an individual's region, a few mm off the mean
    off = np.linalg.norm(Vr - mean, axis=1) if Vr.shape == mean.shape else None
    if off is None or np.median(off) > 0.005:
        raise SystemExit(f"{source / 'eye_region.3ds'}: its vertices are not in mesh_mean.txt's order")
    return EyePriorArrays(mean_mm=mean * 1000.0, components_mm=comp[:, :modes] * 1000.0,
                          coef_mean=mu[:modes].copy(), coef_sd=sd[:modes].copy(), faces=F)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", type=Path, default=SOURCE, help="the UnityEyes eye-region folder")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--modes", type=int, default=10, help="principal components kept (the placement uses 10)")
    ap.add_argument("--check", action="store_true", help="compare with --out instead of writing it")
    args = ap.parse_args(argv)
    prior = derive(args.source, args.modes)
    if args.check:
        old = read_eye_prior(args.out)
        same = all(np.array_equal(getattr(old, k), getattr(prior, k)) for k in
                   ("mean_mm", "components_mm", "coef_mean", "coef_sd", "faces"))
        print(f"{args.out}: {'the same arrays' if same else 'DIFFERS from'} {args.source}")
        return 0 if same else 1
    write_eye_prior(args.out, prior)
    data = args.out.read_bytes()
    buf = io.BytesIO()          # the same arrays written again: the same bytes
    np.savez(buf, **dict(np.load(args.out)))
    print(f"wrote {args.out}: {len(data)} bytes, sha256 {hashlib.sha256(data).hexdigest()[:16]}, "
          f"{args.modes} modes, rewritten identically: {buf.getvalue() == data}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
