"""Stage ``remove_eyeballs``: fit each scanned eyeball and cut it out of the head mesh.

    python -m stages.remove_eyeballs build/<scan>/ingest build/<scan>/remove_eyeballs \
        --prior pipeline/placement/data/eye_region_prior.npz \
        --metrics build/<scan>/remove_eyeballs.metrics.json

Reads ``ingest/mesh.npz``, ``ingest/scan.json`` (eye hints; its ``folder`` is the scan folder
a refusal names) and ``ingest/texture.png`` when present; writes ``mesh.npz`` (head with the two
eye openings, UV/FUV/VC carried), ``eyes.json`` (per eye: center, radius, forward,
residual_rms_mm, n_inliers, placement (the cues that carried the fit), uncertainty_mm,
checks, loop_indices, loop_points, lateral_canthus_index, texture_fissure, doubts) and copies
``texture.png``. ``--prior`` names the eye-region prior file (default: the one eyerig ships,
pipeline/placement/data/eye_region_prior.npz; missing or corrupt: an error naming it,
never a placement without it). Each
doubt (an eye placed from little evidence, a failed self-check, a texture-placed opening
narrower than the texture's fissure) is also printed to stderr as a warning; the eye is still
published. A loop that misses the fitted sphere and lies inside the eye the asset would carry
(``loop_on_eye``) follows no eye: the scan is refused in one line naming it. See pipeline/placement/ (place.py, fit.py, prior.py) and pipeline/remove_eyeballs/remove_eyeballs.py.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.eyeball.geometry import EyeballSettings
from pipeline.io.atomic import atomic_dir
from pipeline.io.eyes_file import write_eyes
from pipeline.io.meshfile import read_stage_mesh, save_mesh
from pipeline.io.scan_file import read_scan_record
from pipeline.placement.prior import PRIOR_FILE, EyeRegionPrior
from pipeline.remove_eyeballs.remove_eyeballs import remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings
from pipeline.results import StageResult
from stages._common import default_metrics_path, load_settings, stage_exit, stage_parser


def _read(ingest: Path):
    mesh_path = ingest / "mesh.npz"
    if not mesh_path.is_file():
        raise ScanError(mesh_path, "not found")
    scan = read_scan_record(ingest / "scan.json")
    mesh = read_stage_mesh(mesh_path)
    texture = None
    tex_path = ingest / "texture.png"
    if tex_path.is_file():
        from PIL import Image
        with Image.open(tex_path, formats=["PNG"]) as im:   # ingest writes a PNG; nothing else is decoded
            texture = np.asarray(im.convert("RGB"))
    return mesh, scan, texture, scan.folder or str(mesh_path), tex_path


def main(argv) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0])
    parser.add_argument("ingest", type=Path, help="build/<scan>/ingest")
    parser.add_argument("out", type=Path, help="build/<scan>/remove_eyeballs")
    parser.add_argument("--prior", type=Path, default=PRIOR_FILE,
                        help="the eye-region prior file (default: the one eyerig ships, "
                             "pipeline/placement/data/eye_region_prior.npz)")
    args = parser.parse_args(argv)
    st = load_settings(RemoveEyeballsSettings, args.params)
    eyeball = load_settings(EyeballSettings, args.params).geometry   # the eye the asset carries
    mesh, scan, texture, source, tex_path = _read(args.ingest)
    hints = scan.hints
    if scan.eye_size is not None:            # the scan's own (scan.yaml eye_size) over the project's
        st = dataclasses.replace(st, eye_size=scan.eye_size)
    prior = EyeRegionPrior.load(args.prior)
    res = remove_eyeballs(mesh, hints, st, source=source, texture=texture,
                          prior=prior.register, eyeball=eyeball, declared_open=scan.open_eyes)
    for side in ("left", "right"):      # published, but not sure: say so where the user looks
        for doubt in res.eyes[side].doubts:
            print(f"warning: {source}: {side} eye: {doubt}", file=sys.stderr)
    with atomic_dir(args.out) as tmp:
        save_mesh(tmp / "mesh.npz", **res.mesh)
        write_eyes(tmp / "eyes.json", res.eyes)
        if texture is not None:
            shutil.copyfile(tex_path, tmp / "texture.png")
    return res.result.at(args.metrics or default_metrics_path(args.out))


if __name__ == "__main__":
    stage_exit(main)
