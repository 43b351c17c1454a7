"""Stage ``snap``: move the eyelid margin (and a smooth falloff zone) onto the placed eyeballs.

    python -m stages.snap build/<scan>/bake build/<scan>/remove_eyeballs rigged_assets/eyeball \
        build/<scan>/snap --metrics build/<scan>/snap.metrics.json

Reads ``bake/mesh.npz`` (V, F, loop_left, loop_right, UV/FUV...), ``remove_eyeballs/eyes.json``
(centre, radius, forward per eye) and the eyeball geometry settings from
``eyeball/eyeball.usda`` (customData eyerig.params: r1, r2, apex, seam_blend_mm). Writes
``snap/mesh.npz`` (same arrays, V snapped) and ``snap/eyes.json`` (carried over; the loop
fields re-point at the snapped mesh's loops; pipeline/io/eyes_file.py). See
pipeline/snap/snap.py (``snap_eyes``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.fork import fork_call, fork_result
from pipeline.io.atomic import atomic_dir
from pipeline.io.eyes_file import read_eyes, write_eyes
from pipeline.io.meshfile import read_stage_mesh, save_mesh
from pipeline.usd.eyeball import read_eyeball_params
from pipeline.results import StageResult
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def main(argv) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("bake", type=Path, help="build/<scan>/bake (mesh.npz with loop_left/right)")
    parser.add_argument("remove_eyeballs", type=Path, help="build/<scan>/remove_eyeballs (eyes.json)")
    parser.add_argument("eyeball", type=Path, help="rigged_assets/eyeball (eyeball.usda)")
    parser.add_argument("out", type=Path, help="build/<scan>/snap")
    args = parser.parse_args(argv)
    # pxr's import and the read (0.1 s) run in a child beside this process's scipy imports and
    # reading; a failed read is rerun here, so its error is the reader's own
    params_job = fork_call(read_eyeball_params, args.eyeball)
    from pipeline.snap import snap as sn    # imports scipy: after the fork, beside the child

    st = load_settings(sn.SnapSettings, args.params)
    mesh_path = args.bake / "mesh.npz"
    mesh = read_stage_mesh(mesh_path)
    eyes = read_eyes(args.remove_eyeballs / "eyes.json")
    graph = sn.edge_graph(np.asarray(mesh.V, float), np.asarray(mesh.F, np.int64))
    params, _ = fork_result(params_job)
    res = sn.snap_eyes(mesh, eyes, params, st, source=str(mesh_path), graph=graph)
    with atomic_dir(args.out) as tmp:
        save_mesh(tmp / "mesh.npz", **res.mesh)
        write_eyes(tmp / "eyes.json", res.eyes)
    return res.result.at(args.metrics or default_metrics_path(args.out))

if __name__ == "__main__":
    stage_exit(main)
