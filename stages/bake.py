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


def _no_huge_pages() -> None:
    """Stop numpy asking for transparent huge pages for its arrays over 4 MiB (madvise).

    The bake makes and drops dozens of 25-150 MB temporaries (3.2M texels on a 1.4M-triangle
    head): on the farm's machines each new one faulted in as huge pages cost ~8 s of system time
    of the stage's ~26 s CPU (kernel page zeroing and compaction), with 4 KiB pages ~3 s; the
    arrays and so the bytes written are the same either way. The setting is the process's
    (the forked helpers inherit it)."""
    import importlib

    # numpy 2 names it numpy._core; 1.26 has numpy.core, and a numpy._core whose attributes
    # appear only once its submodules are imported (what another import did decides which)
    for name in ("numpy._core.multiarray", "numpy.core.multiarray"):
        try:
            setter = getattr(importlib.import_module(name), "_set_madvise_hugepage", None)
        except ImportError:
            continue
        if setter is not None:
            setter(False)
            return


def main(argv):
    _no_huge_pages()
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
