"""Stage ``eyeball``: the shared parametric eyeball asset.

    python -m stages.eyeball rigged_assets/eyeball --metrics build/eyeball.metrics.json

Builds the eyeball (pipeline/eyeball; the asset: pipeline/usd/eyeball_asset.py), writes ``eyeball.usda`` and
``textures/*.png`` (4 iris colours, 2 veins layers, sclera bump height + normal map), validates the asset
(pipeline/usd/validate.py; any error fails the stage), and, unless
``preview: false``, renders ``preview.png`` (Cycles contact sheet) in a Blender
worker subprocess. Settings: the ``eyeball:`` block of params.yaml.
"""

from __future__ import annotations

import time
from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.io.atomic import atomic_dir
from pipeline.io.png import strip_png_metadata
from pipeline.usd.eyeball_asset import build_eyeball_asset, render_eyeball_preview
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def main(argv) -> dict:
    import json
    import tempfile

    ap = stage_parser(__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="output folder (rigged_assets/eyeball)")
    args = ap.parse_args(argv)
    settings = load_settings(geo.EyeballSettings, args.params)   # checked before anything is written
    with atomic_dir(args.out) as tmp:
        metrics = build_eyeball_asset(tmp, settings)
        if settings.preview:
            with tempfile.TemporaryDirectory() as td:
                tj = Path(td) / "preview.json"
                t = time.perf_counter()
                render_eyeball_preview(tmp, settings, tj)
                strip_png_metadata(tmp / "preview.png")     # Blender's time/text chunks: same pixels, same bytes
                metrics["preview"] = json.loads(tj.read_text())
                metrics["preview"]["wall_s"] = round(time.perf_counter() - t, 3)
    return {"_path": args.metrics or default_metrics_path(args.out), **metrics}


if __name__ == "__main__":
    stage_exit(main)
