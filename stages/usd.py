"""Stage ``usd``: assemble and validate the rigged USD asset of one scan.

    python -m stages.usd build/<scan>/snap build/<scan>/bake build/<scan>/rig build/<scan>/ingest \
        rigged_assets/eyeball rigged_assets/<scan> --metrics build/<scan>/usd.metrics.json

Reads snap/mesh.npz (V, F, UV, FUV), bake/color.png + bake/displacement.exr (+ bake.json),
rig/rig.npz + rig/rig.json, ingest/scan.json and rigged_assets/eyeball/eyeball.usda; writes
<out>/{<scan>.usda, <scan>.usdz, textures/color.png, textures/displacement.exr, eyeball/} where
the output argument says (``rigged_assets/<scan>`` in dvc.yaml; the scan is its folder's name).
The asset folder is self-contained: it holds a copy of the eyeball asset (eyeball/eyeball.usda
and its textures, ~3 MB), which the eyes reference as ./eyeball/eyeball.usda, so a copied or
moved folder keeps its eyes; the usdz packages the same files.
Every asset is checked with pipeline.usd.validate; any error refuses the build (exit 2).
No Blender here: the asset's Cycles contact sheet is the next step, ``stages/preview.py``.
The work is in pipeline/usd/build.py.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.atomic import atomic_dir
from pipeline.usd.build import build, read_inputs
from stages._common import (default_metrics_path, load_params, load_settings, scan_folder_name, stage_exit,
                            stage_parser)

PARAM_BLOCKS = ("ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "eyeball", "usd")


def _all_params(path) -> dict:
    out = {}
    for b in PARAM_BLOCKS:
        out[b] = load_params(b, path)       # each block required where the file is there
    return out


def main(argv):
    parser = stage_parser(__doc__.splitlines()[0], scan_arg="out")
    for a in ("snap", "bake", "rig", "ingest", "eyeball", "out"):
        parser.add_argument(a, type=Path)
    args = parser.parse_args(argv)
    from pipeline.usd.asset import UsdSettings

    settings = load_settings(UsdSettings, args.params)
    all_params = _all_params(args.params)       # a missing block refused before anything is written
    inp = read_inputs(args.snap, args.bake, args.rig, args.ingest, args.eyeball)
    name = scan_folder_name(args.out)
    with atomic_dir(args.out) as tmp:
        result = build(inp, Path(tmp), name, all_params, package=settings.usdz)
    return result.at(args.metrics or default_metrics_path(args.out))


if __name__ == "__main__":
    stage_exit(main)
