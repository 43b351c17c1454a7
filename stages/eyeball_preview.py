"""Stage ``eyeball_preview``: the Cycles contact sheet of the eyeball asset.

    python -m stages.eyeball_preview rigged_assets/eyeball rigged_assets/eyeball.preview.png \
        --metrics build/eyeball_preview.metrics.json

Renders ``<eyeball>/eyeball.usda`` with the Blender worker pipeline/blender/eyeball_preview.py
into one PNG (``preview_px`` tile size, ``preview_samples`` Cycles samples + OpenImageDenoise,
from the ``eyeball:`` block). A step of its own after ``eyeball``, so that the stages that read
the eyeball never wait on Blender; the picture lies beside the asset folder, not in it. The work
is in pipeline/preview/eyeball.py.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.io.atomic import atomic_file
from pipeline.preview.eyeball import render_eyeball_preview
from stages._common import load_settings, stage_exit, stage_parser


def main(argv):
    ap = stage_parser(__doc__.splitlines()[0])
    ap.add_argument("eyeball", type=Path, help="the eyeball asset folder (rigged_assets/eyeball)")
    ap.add_argument("out", type=Path, help="the sheet to write (rigged_assets/eyeball.preview.png)")
    args = ap.parse_args(argv)
    settings = load_settings(geo.EyeballSettings, args.params)   # checked before anything is written
    with atomic_file(args.out) as tmp:
        result = render_eyeball_preview(args.eyeball / "eyeball.usda", tmp, settings.preview_px,
                                        settings.preview_samples)
    return result.at(args.metrics or args.out.with_name(args.out.name + ".metrics.json"))


if __name__ == "__main__":
    stage_exit(main)
