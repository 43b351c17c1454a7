"""Stage ``bake``: UV-unwrap the low-poly eye region and bake displacement and colour maps from the scan.

    python -m stages.bake RETOPO_DIR REMOVE_EYEBALLS_DIR OUT_DIR [--metrics PATH] [--params params.yaml]

Reads ``RETOPO_DIR/mesh.npz`` (V, F, loops [, polygons]) and the dense scan
``REMOVE_EYEBALLS_DIR/mesh.npz`` (+ ``texture.png`` when present); writes
``OUT_DIR/{mesh.npz, displacement.exr, displacement_preview.png, color.png, bake.json}``
(pipeline/io/bake_file.py). The work is in pipeline/bake/build.py (``bake_scan``).
"""

from __future__ import annotations

from pathlib import Path

from pipeline.bake.bake import BakeSettings
from pipeline.bake.build import bake_scan
from pipeline.io.atomic import atomic_dir
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def main(argv):
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("retopo_dir", type=Path, help="build/<scan>/retopo")
    parser.add_argument("dense_dir", type=Path, help="build/<scan>/remove_eyeballs")
    parser.add_argument("out_dir", type=Path, help="build/<scan>/bake")
    args = parser.parse_args(argv)
    settings = load_settings(BakeSettings, args.params)
    with atomic_dir(args.out_dir) as tmp:
        result = bake_scan(args.retopo_dir, args.dense_dir, settings, tmp)
    return result.at(args.metrics or default_metrics_path(args.out_dir))


if __name__ == "__main__":
    stage_exit(main)
