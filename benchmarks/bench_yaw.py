"""The lids against the eye turned in yaw, with and without the rig's yaw channels
(``pipeline/rig/yaw_shapes.py``), on built heads.

For every ``<builds>/<head>/snap`` (a snapped head, as ``bench_band`` leaves them) this process
makes the head's lid rig as the rig stage does (``build_lid_shapes``, ``relax_folds``) and poses it
at every pitch of -25..25 deg in 5 deg steps and every yaw of -35..35 deg in 2.5 deg steps (both
eyes turned alike: the stored poses every 5 deg and the midpoints between them): once with the
pitch channels alone (*before*), once with the yaw channels too (*after*). Per head:
``yaw_sweep``'s figures (the margin inside / off the turned eye, the deepest other point outside
the eye at rest that the turned eye takes in, the caruncle's rows, faces turned over) and the yaw
channels' fold rounds, damped vertices and build time.

    .venv/bin/python -m benchmarks.bench_yaw --set heldout=<builds>:<params.yaml> [--set ...]
        [--eyeball rigged_assets/eyeball] [--out yaw]

Writes ``benchmarks/results/<out>.json`` (summary per set and per head).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import yaml

from benchmarks.bench_band import parse_sets
from benchmarks.results_files import write_results

PITCHES = np.arange(-25.0, 25.1, 5.0)
YAWS = np.arange(-35.0, 35.1, 2.5)
KEYS = ("max_penetration_mm", "max_gap_mm", "max_sink_mm", "max_strip_sink_mm", "flipped_faces")


def head(snap: Path, settings, profile) -> dict:
    """Before / after figures of one snapped head."""
    from pipeline.io.eyes_file import read_eyes
    from pipeline.io.meshfile import load_mesh
    from pipeline.rig import yaw_shapes as ys
    from pipeline.rig.eye_frame import eye_frames
    from pipeline.rig.folds import relax_folds
    from pipeline.rig.lid_shapes import build_lid_shapes

    lp = settings.lid_params()
    mesh = dict(load_mesh(snap / "mesh.npz"))
    eyes = eye_frames(read_eyes(snap / "eyes.json"), mesh, eyes_source=str(snap / "eyes.json"),
                      mesh_source=str(snap / "mesh.npz"), max_rest_gap_mm=settings.max_rest_gap_mm,
                      profile=profile)
    V, F = np.asarray(mesh["V"], float), np.asarray(mesh["F"], np.int64)
    pitches = np.arange(-lp.max_pitch_deg, lp.max_pitch_deg + 1e-9, settings.sweep_step_deg)
    lid = build_lid_shapes(V, F, eyes, lp).shapes
    lid, _, _ = relax_folds(V, F, lid, eyes, pitches, lp.max_pitch_deg)
    t0 = time.perf_counter()
    yaw = ys.build_yaw_shapes(V, eyes, lp.surface_follow_mm, lid, lp.max_pitch_deg)
    yaw, rounds, damped, _ = ys.settle_yaw_folds(V, F, eyes, lid, yaw, lp.max_pitch_deg)
    t_build = time.perf_counter() - t0
    before = ys.yaw_sweep(V, F, eyes, lid, PITCHES, YAWS, lp.max_pitch_deg)
    after = ys.yaw_sweep(V, F, eyes, lid + yaw, PITCHES, YAWS, lp.max_pitch_deg)
    return {"head": snap.parent.name, **{f"before_{k}": before[k] for k in KEYS},
            **{f"after_{k}": after[k] for k in KEYS},
            "after_max_penetration_at": after["max_penetration_mm_at"],
            "fold_rounds": rounds, "damped_vertices": damped, "build_s": round(t_build, 3)}


def summary(rows: list[dict]) -> dict:
    out = {"heads": len(rows)}
    for when in ("before", "after"):
        for k in KEYS:
            v = np.array([r[f"{when}_{k}"] for r in rows], float)
            out[f"{when}_{k}_max"] = round(float(v.max()), 3)
            out[f"{when}_{k}_median"] = round(float(np.median(v)), 3)
    out["after_heads_with_flips"] = int(sum(r["after_flipped_faces"] > 0 for r in rows))
    out["heads_damped"] = int(sum(r["damped_vertices"] > 0 for r in rows))
    out["build_s_median"] = round(float(np.median([r["build_s"] for r in rows])), 3)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", action="append", required=True, metavar="NAME=BUILDS:PARAMS")
    ap.add_argument("--eyeball", type=Path, default=Path("rigged_assets/eyeball"))
    ap.add_argument("--out", default="yaw")
    args = ap.parse_args(argv)
    sets = parse_sets(ap, args.set)
    from pipeline.rig.lids import RigSettings
    from pipeline.usd.eyeball import read_eyeball_params

    profile = read_eyeball_params(args.eyeball)
    res = {}
    for name, builds, params in sets:
        settings = RigSettings.from_params(yaml.safe_load(params.read_text())["rig"])
        rows = []
        for snap in sorted(builds.glob("*/snap")):
            if not (snap / "mesh.npz").is_file():
                continue
            rows.append(head(snap, settings, profile))
            r = rows[-1]
            print(f"{name} {r['head']:34s} penetration {r['before_max_penetration_mm']:.2f} -> "
                  f"{r['after_max_penetration_mm']:.2f} mm, sink {r['before_max_sink_mm']:.2f} -> "
                  f"{r['after_max_sink_mm']:.2f}, gap {r['before_max_gap_mm']:.2f} -> {r['after_max_gap_mm']:.2f}, "
                  f"flips {r['after_flipped_faces']}, damped {r['damped_vertices']}", flush=True)
        res[name] = {"summary": summary(rows), "heads": rows}
    write_results(args.out, res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
