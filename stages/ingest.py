"""Stage ``ingest``: load, validate, repair and convert one scan folder to the head frame (mm).

    python -m stages.ingest RAW_SCAN_DIR OUT_DIR [--metrics PATH] [--params params.yaml]

Writes ``OUT_DIR/mesh.npz`` (V, F[, UV, FUV][, VC]), ``OUT_DIR/texture.png`` when the
scan has a texture, and ``OUT_DIR/scan.json``, all at once through ``atomic_dir``:
a rejected scan exits 2 with one line on stderr and leaves no output folder.

Run as a program, the stage bounds its own address space (``ingest.max_memory_mb``,
``RLIMIT_AS``), so a hostile file that slips past the header checks ends in a
MemoryError, which (like an OverflowError) becomes one line and exit 2. numpy's
RuntimeWarnings and PIL's / trimesh's log records are silenced: a bad value is reported
by the check that refuses it.
"""

from __future__ import annotations

import functools
import logging
import resource
import warnings
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.ingest.ingest import IngestSettings, ingest_scan
from pipeline.io.atomic import atomic_dir
from pipeline.io.meshfile import save_mesh
from pipeline.io.scan import one_line
from pipeline.io.scan_file import write_scan_record
from pipeline.results import StageResult
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def bound_memory(max_mb: float) -> None:
    """Lower this process's address-space limit (soft ``RLIMIT_AS``) to ``max_mb`` MiB; 0 leaves it.

    The modules ingest imports lazily once a mesh is in memory are imported first: mapping a
    shared library near the bound could fail with an ImportError instead of a MemoryError.
    (trimesh, 0.6 s to import, is left lazy: GLB and STL import it right after their header checks,
    with little memory in use.)
    """
    if not max_mb or max_mb <= 0:
        return
    import scipy.sparse.csgraph  # noqa: F401
    from PIL import Image

    import pipeline.geometry.frame  # noqa: F401
    import pipeline.ingest.repair  # noqa: F401

    Image.init()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    want = int(max_mb * 2**20)
    if hard != resource.RLIM_INFINITY:
        want = min(want, hard)
    if soft == resource.RLIM_INFINITY or want < soft:
        resource.setrlimit(resource.RLIMIT_AS, (want, hard))


def quiet_library_logs() -> None:
    """Keep PIL's and trimesh's log records (e.g. a hostile TIFF's "More samples per pixel than can be
    decoded") off stderr: the refusal that follows is the one line. Without a handler anywhere on a
    logger's chain, Python prints warnings and errors to stderr."""
    for name in ("PIL", "trimesh"):
        logging.getLogger(name).addHandler(logging.NullHandler())


def main(argv, bound: bool = False) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0], scan_arg="scan_dir")
    parser.add_argument("scan_dir", help="raw_scans/<name>: scan.yaml + mesh [+ texture]")
    parser.add_argument("out_dir", help="build/<name>/ingest")
    args = parser.parse_args(argv)
    settings = load_settings(IngestSettings, args.params)
    quiet_library_logs()
    if bound:
        bound_memory(settings.max_memory_mb)
    out = Path(args.out_dir)
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = ingest_scan(args.scan_dir, settings)
            with atomic_dir(out) as tmp:
                save_mesh(tmp / "mesh.npz", **result.mesh)
                if result.texture_png_bytes is not None:
                    (tmp / "texture.png").write_bytes(result.texture_png_bytes)
                elif result.texture is not None:
                    result.texture.save(tmp / "texture.png", format="PNG", compress_level=3)
                write_scan_record(tmp / "scan.json", result.scan, args.scan_dir)
    except MemoryError:
        raise ScanError(args.scan_dir, f"ran out of memory (ingest is bounded to {settings.max_memory_mb:g} MiB, "
                                       "ingest.max_memory_mb); a file in the folder is over the limits") from None
    except OverflowError as exc:
        raise ScanError(args.scan_dir, f"a number in the scan is too large ({one_line(exc)[:80]})") from None
    return StageResult(result.metrics).at(args.metrics or default_metrics_path(out))   # all determined by the scan


if __name__ == "__main__":
    stage_exit(functools.partial(main, bound=True))
