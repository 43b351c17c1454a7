"""Benchmark remove_eyeballs: time and accuracy vs mesh density on the synthetic head.

    .venv/bin/python -m benchmarks.bench_remove_eyeballs [--repeats 3] [--triangles 100000 350000 1000000]

Writes benchmarks/results/remove_eyeballs.json (median wall time of the library call, and
per-eye centre/radius error, loop-to-margin mean distance, forward error) and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pipeline.geometry.eyes import EyeSettings, remove_eyeballs
from pipeline.synthetic_head import make_synthetic_head


def _polyline_distance(P, M):
    M2 = np.roll(M, -1, axis=0)
    best = np.full(len(P), np.inf)
    for a, b in zip(M, M2):
        ab = b - a
        t = np.clip(((P - a) @ ab) / (ab @ ab), 0, 1)
        best = np.minimum(best, np.linalg.norm(P - (a + t[:, None] * ab), axis=1))
    return best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--triangles", type=int, nargs="+", default=[100_000, 350_000, 1_000_000])
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--noise", type=float, default=0.02)
    args = ap.parse_args()
    rows = []
    for tri in args.triangles:
        h = make_synthetic_head(seed=args.seed, target_triangles=tri, noise_mm=args.noise, texture_size=16)
        mesh = {"V": h.V, "F": h.F}
        hints = {s: np.asarray(h.hints[s]) for s in ("left", "right")}
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = remove_eyeballs(mesh, hints, EyeSettings(), source="synthetic")
            times.append(time.perf_counter() - t0)
        row = {"triangles": int(len(h.F)), "median_s": float(np.median(times)), "runs_s": times}
        for s in ("left", "right"):
            g, e = h.ground_truth["eyes"][s], res.eyes[s]
            row[s] = {
                "center_error_mm": float(np.linalg.norm(np.array(e["center"]) - g["eyeball_sphere"]["center_mm"])),
                "radius_error_mm": float(e["radius"] - g["eyeball_sphere"]["radius_mm"]),
                "loop_to_margin_mean_mm": float(_polyline_distance(
                    np.array(e["loop_points"]), np.array(g["eyelid_margin"]["points_mm"])).mean()),
                "forward_error_deg": float(np.degrees(np.arccos(np.clip(
                    np.dot(e["forward"], g["gaze_direction"]), -1, 1)))),
            }
        rows.append(row)
        print(f"{row['triangles']:>8} tris  {row['median_s']:6.2f} s  " + "  ".join(
            f"{s}: c {row[s]['center_error_mm']:.3f} r {row[s]['radius_error_mm']:+.3f} "
            f"loop {row[s]['loop_to_margin_mean_mm']:.3f} fwd {row[s]['forward_error_deg']:.1f}"
            for s in ("left", "right")))
    out = Path(__file__).resolve().parent / "results" / "remove_eyeballs.json"
    out.write_text(json.dumps({"seed": args.seed, "noise_mm": args.noise, "repeats": args.repeats,
                               "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
