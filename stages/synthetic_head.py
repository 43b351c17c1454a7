"""Stage ``synthetic_head``: write the procedural test head as a scan folder.

    python -m stages.synthetic_head raw_scans/<name> [--identity <name>] --metrics build/<name>/synthetic_head.metrics.json

Reads the ``synthetic_head:`` block of ``params.yaml`` (seed, target_triangles, eye_shape,
eye_spacing_mm, noise_mm, texture_size, eye_radius_mm, skin_tone, wrinkle_scale, pore_scale),
with ``--identity`` the entry ``identities.<name>`` over it (dvc.yaml runs one per identity),
and writes, atomically,
``scan.ply`` (binary PLY with per-vertex UVs ``s``/``t``), ``texture.png``,
``scan.yaml`` and ``ground_truth.json``. See pipeline/synthetic_head/.
"""

from __future__ import annotations

import time
from pathlib import Path

from pipeline.io.atomic import atomic_dir
from pipeline.results import StageResult
from pipeline.synthetic_head import (SyntheticHeadSettings, identity_settings, make_synthetic_head,
                                     write_scan_folder)
from stages._common import default_metrics_path, load_params, load_settings, stage_exit, stage_parser


def main(argv) -> StageResult:
    parser = stage_parser(__doc__.splitlines()[0], scan_arg="out_dir")
    parser.add_argument("out_dir", help="scan folder to write (replaced atomically)")
    parser.add_argument("--identity", default=None,
                        help="an identities: entry of params.yaml over the synthetic_head block")
    args = parser.parse_args(argv)
    out = Path(args.out_dir)
    if args.identity is None:
        settings = load_settings(SyntheticHeadSettings, args.params)
    else:
        blocks = {b: load_params(b, args.params) for b in ("synthetic_head", "identities")}   # both required
        settings = identity_settings(blocks, args.identity, source=str(args.params))
    t0 = time.perf_counter()
    head = make_synthetic_head(settings)
    t1 = time.perf_counter()
    with atomic_dir(out) as tmp:
        write_scan_folder(head, tmp, eye_size=settings.asset_eye_size)
    t2 = time.perf_counter()
    gt = head.ground_truth
    metrics = {
        "n_vertices": int(len(head.V)),
        "n_faces": int(len(head.F)),
        "target_triangles": settings.target_triangles,
        "texture_size": settings.texture_size,
        "skin_detail_amplitude_mm": gt["skin_detail_amplitude_mm"],
    }
    for side, eye in gt["eyes"].items():
        metrics[f"{side}_eyeball_radius_mm"] = eye["eyeball_sphere"]["radius_mm"]
        margin = eye["eyelid_margin"]
        metrics[f"{side}_margin_to_sphere_max_mm"] = margin["distance_to_eyeball_sphere_mm"]["max"]
        metrics[f"{side}_opening_height_mm"] = margin["height_mm"]
    timings = {"generate_s": round(t1 - t0, 4), "write_s": round(t2 - t1, 4)}
    return StageResult(metrics, timings, Path(args.metrics or default_metrics_path(out)))


if __name__ == "__main__":
    stage_exit(main)
