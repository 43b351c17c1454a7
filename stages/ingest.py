"""Stage ``ingest``: load, validate, repair and convert one scan folder to the head frame (mm).

    python -m stages.ingest RAW_SCAN_DIR OUT_DIR [--metrics PATH] [--params params.yaml]

Writes ``OUT_DIR/mesh.npz`` (V, F[, UV, FUV][, VC]), ``OUT_DIR/texture.png`` when the
scan has a texture, and ``OUT_DIR/scan.json``, all at once through ``atomic_dir``:
a rejected scan exits 2 with one line on stderr and leaves no output folder.
"""

from __future__ import annotations

from pathlib import Path

from pipeline.io.atomic import atomic_dir, write_json
from pipeline.io.load import IngestSettings, ingest_scan
from pipeline.io.meshfile import save_mesh
from stages._common import default_metrics_path, load_params, stage_exit, stage_parser


def main(argv) -> dict:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("scan_dir", help="raw_scans/<name>: scan.yaml + mesh [+ texture]")
    parser.add_argument("out_dir", help="build/<name>/ingest")
    args = parser.parse_args(argv)
    settings = IngestSettings.from_params(load_params("ingest", args.params))
    result = ingest_scan(args.scan_dir, settings)
    out = Path(args.out_dir)
    with atomic_dir(out) as tmp:
        save_mesh(tmp / "mesh.npz", **result.mesh)
        if result.texture_png_bytes is not None:
            (tmp / "texture.png").write_bytes(result.texture_png_bytes)
        elif result.texture is not None:
            result.texture.save(tmp / "texture.png", format="PNG", compress_level=3)
        write_json(tmp / "scan.json", result.scan)
    return {"_path": args.metrics or default_metrics_path(out), **result.metrics}


if __name__ == "__main__":
    stage_exit(main)
