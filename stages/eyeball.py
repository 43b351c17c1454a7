"""Stage ``eyeball``: the shared parametric eyeball asset.

    python -m stages.eyeball rigged_assets/eyeball --metrics build/eyeball.metrics.json

Builds the eyeball (pipeline/eyeball; the asset: pipeline/usd/eyeball_asset.py), writes ``eyeball.usda`` and
``textures/*.png`` (4 iris colours, 2 veins layers, sclera bump height + normal map), validates the asset
(pipeline/usd/validate.py; any error fails the stage). No Blender here: the contact sheet is
the next step, ``stages/eyeball_preview.py``. Settings: the ``eyeball:`` block of params.yaml.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.eyeball import geometry as geo
from pipeline.io.atomic import atomic_dir
from pipeline.usd.eyeball_asset import build_eyeball_asset
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def main(argv):
    ap = stage_parser(__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="output folder (rigged_assets/eyeball)")
    args = ap.parse_args(argv)
    settings = load_settings(geo.EyeballSettings, args.params)   # checked before anything is written
    with atomic_dir(args.out) as tmp:
        result = build_eyeball_asset(tmp, settings)
    return result.at(args.metrics or default_metrics_path(args.out))


if __name__ == "__main__":
    stage_exit(main)
