"""Stage ``rig``: eyelid blend shapes and eye-region landmarks for one scan.

    python -m stages.rig build/<scan>/snap build/<scan>/rig --metrics build/<scan>/rig.metrics.json

Reads ``snap/mesh.npz`` (V, F, loop_left, loop_right) and ``snap/eyes.json``;
writes ``rig/rig.npz`` (blend shapes with inbetweens, eyelid landmark curves and
their shapes) and ``rig/rig.json`` (pitch-to-weight rule, shapes, eye joints,
landmark order), through pipeline/io/rig_file.py. See pipeline/rig/build.py and lids.py for the
method. A lid that notches an opening seen from the front by more than 1 mm (toothed, spiked or
split) is named in a warning line on stderr.
"""

from __future__ import annotations

import sys
from pathlib import Path

from pipeline.fork import fork_call, fork_result
from pipeline.io.atomic import atomic_dir
from pipeline.io.eyes_file import read_eyes
from pipeline.io.meshfile import read_stage_mesh
from pipeline.io.rig_file import write_rig
from pipeline.usd.eyeball import read_eyeball_params
from pipeline.results import StageResult
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def _read_inputs(snap: Path):
    mesh_path, eyes_path = snap / "mesh.npz", snap / "eyes.json"
    mesh = read_stage_mesh(mesh_path)
    eyes = read_eyes(eyes_path)
    return mesh, eyes, mesh_path, eyes_path


def main(argv) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("snap", type=Path, help="build/<scan>/snap")
    parser.add_argument("out", type=Path, help="build/<scan>/rig")
    parser.add_argument("--eyeball", type=Path, default=None,
                        help="rigged_assets/eyeball: follow its outer surface (sphere + cornea), "
                             "as snap does; without it the margin follows the fitted sphere")
    args = parser.parse_args(argv)
    # pxr's import and the read (0.1 s) run in a child beside this process's imports and reading;
    # a failed read is rerun here, so its error is the reader's own
    profile_job = None if args.eyeball is None else fork_call(read_eyeball_params, args.eyeball)
    from pipeline.rig import lids               # with scipy: after the fork, beside the child
    from pipeline.rig.build import build_rig

    params = load_settings(lids.RigSettings, args.params)
    mesh, eyes, mesh_path, eyes_path = _read_inputs(args.snap)
    profile = None if profile_job is None else fork_result(profile_job)[0]
    rig = build_rig(mesh, eyes, params, mesh_path, eyes_path, profile)
    for line in rig.warnings:
        print(f"warning: {args.snap}: {line}", file=sys.stderr)
    with atomic_dir(args.out) as tmp:
        write_rig(tmp, rig.arrays, rig.doc)
    return rig.result.at(args.metrics or default_metrics_path(args.out))


if __name__ == "__main__":
    stage_exit(main)
