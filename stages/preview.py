"""Stage ``preview``: the Cycles contact sheet of one scan's rigged asset.

    python -m stages.preview rigged_assets/<scan> build/<scan>/rig rigged_assets/<scan>.preview.png \
        --metrics build/<scan>/preview.metrics.json

Reads the usd stage's asset ``<asset>/<scan>.usda`` (the scan is its folder's name) and
rig/rig.npz (the lid shapes' inbetweens, which Blender's USD import leaves out) and writes one
PNG: front views at gaze pitch +25/0/-25 deg and a three-quarter view, rendered by the Blender
worker pipeline/blender/asset_preview.py (``preview_px`` tile height, ``preview_samples`` Cycles
samples + OpenImageDenoise, from the ``usd:`` block). A step of its own after ``usd`` so that
writing the asset never starts Blender; the picture lies beside the asset folder, not in it (DVC
keeps one stage's outputs out of another's). The work is in pipeline/preview/asset.py.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.atomic import atomic_file
from pipeline.preview.asset import render_preview
from stages._common import load_settings, scan_folder_name, stage_exit, stage_parser


def main(argv):
    parser = stage_parser(__doc__.splitlines()[0], scan_arg="asset")
    parser.add_argument("asset", type=Path, help="the asset folder (rigged_assets/<scan>)")
    parser.add_argument("rig", type=Path, help="the rig stage's folder (build/<scan>/rig)")
    parser.add_argument("out", type=Path, help="the sheet to write (rigged_assets/<scan>.preview.png)")
    args = parser.parse_args(argv)
    from pipeline.usd.asset import UsdSettings

    settings = load_settings(UsdSettings, args.params)
    usda = args.asset / f"{scan_folder_name(args.asset)}.usda"
    with atomic_file(args.out) as tmp:
        result = render_preview(usda, args.rig / "rig.npz", tmp, settings.preview_px, settings.preview_samples)
    return result.at(args.metrics or args.out.with_name(args.out.name + ".metrics.json"))


if __name__ == "__main__":
    stage_exit(main)
