"""Stage ``retopo``: crop the dense head to the eye region and remesh it low-poly, keeping the eyelid loops.

    python -m stages.retopo REMOVE_EYEBALLS_DIR OUT_DIR [--metrics PATH] [--params params.yaml]

Reads ``REMOVE_EYEBALLS_DIR/mesh.npz`` (V, F) and ``eyes.json`` (per eye: center,
loop_indices); writes ``OUT_DIR/mesh.npz`` (V, F [, poly_counts, poly_indices],
loop_left, loop_right [, lateral_index_left, lateral_index_right: position of the
lateral canthus in each loop, when eyes.json gives lateral_canthus_index;
band_left, band_right: (band_rings + 1, loop_points) vertex ids with ``band: grid``]) atomically.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_dir
from pipeline.io.eyes_file import read_eye_loops
from pipeline.io.meshfile import read_stage_mesh, save_mesh
from pipeline.results import StageResult
from pipeline.retopo.eye_band import band_warnings
from pipeline.retopo.retopo import RetopoSettings, retopologize
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def main(argv) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("in_dir", help="build/<scan>/remove_eyeballs")
    parser.add_argument("out_dir", help="build/<scan>/retopo")
    args = parser.parse_args(argv)
    settings = load_settings(RetopoSettings, args.params)
    in_dir = Path(args.in_dir)
    mesh_path = in_dir / "mesh.npz"
    mesh = read_stage_mesh(mesh_path)
    eyes = read_eye_loops(in_dir / "eyes.json", len(mesh.V))
    try:
        result = retopologize(mesh.V, mesh.F, eyes, settings)
    except ValueError as exc:
        raise ScanError(mesh_path, str(exc)) from None
    out = Path(args.out_dir)
    arrays = {"V": result.V, "F": result.F, "loop_left": result.loops["left"],
              "loop_right": result.loops["right"]}
    for side in ("left", "right"):
        # position of the lateral canthus in the resampled loop (for rig)
        if result.lateral.get(side) is not None:
            arrays[f"lateral_index_{side}"] = np.array([int(result.lateral[side])], dtype=np.int64)
    for side, ids in (result.band or {}).items():
        # the grid band's vertex ids, ring by ring (ring 0 is loop_<side>): carried to rig and usd
        arrays[f"band_{side}"] = np.asarray(ids, dtype=np.int64)
    if result.poly_counts is not None:
        arrays.update(poly_counts=result.poly_counts, poly_indices=result.poly_indices)
    with atomic_dir(out) as tmp:
        save_mesh(tmp / "mesh.npz", **arrays)
    for line in band_warnings(result.result.metrics.get("band") or {}):
        print(f"warning: {in_dir}: {line}", file=sys.stderr)
    for h in result.result.metrics.get("scan_holes_left_open") or []:
        print(f"warning: {in_dir}: a hole of the scan {h['perimeter_mm']:g} mm round at "
              f"{h['centre_mm']} mm is left open ({h['why']}): renders see through it",
              file=sys.stderr)
    for h in result.result.metrics.get("scan_holes_filled_folded") or []:
        print(f"warning: {in_dir}: a hole of the scan {h['perimeter_mm']:g} mm round at "
              f"{h['centre_mm']} mm is closed by a grid with {h['faces_turned']} faces turned over "
              f"(no plane closes it without): the skin may dent there", file=sys.stderr)
    return result.result.at(args.metrics or default_metrics_path(out))


def _keep_freed_memory() -> None:
    """glibc's malloc keeps the memory this process frees for its next arrays instead of handing
    it back to the kernel. Left to itself it maps each large array afresh and returns it when
    freed (or trims the heap top), and the next one's pages are faulted in and zeroed again:
    ~128k page faults and ~0.45 s of system time on the 1.4M-triangle chain's head, against ~92k
    and ~0.3 s (the peak memory ~18 MiB higher). Both limits are needed: setting either one alone
    turns glibc's adaptive threshold off and faulted more. Only the process's own arrays'
    placement changes, never a value. Elsewhere (another libc) nothing is done."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
    mallopt(M_MMAP_THRESHOLD, 1 << 30)
    mallopt(M_TRIM_THRESHOLD, 1 << 30)


if __name__ == "__main__":
    _keep_freed_memory()         # the stage's own process only, not a caller that imports it
    stage_exit(main)
