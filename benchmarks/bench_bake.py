"""Benchmark bake: time vs reconstruction error for map resolutions 256..4096.

    .venv/bin/python -m benchmarks.bench_bake [--triangles 1400000] [--runs 3]
        [--resolutions 256 512 1024 2048 4096] [--input DIR]

Input: the synthetic head's remove_eyeballs folder prepared by
``bench_retopo.prepare_input`` (or ``--input``), retopologised once with the
default settings. For each resolution ``bake_maps`` runs ``--runs`` times
(median; UV unwrap timed separately since it does not depend on the map) and
the subdivided + displaced mesh is compared with the scan.
Writes ``benchmarks/results/bake.json`` and ``benchmarks/results/bake.csv``
(DVC plot: x = resolution, y = mean_with_mm or time_s).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

from benchmarks.results_files import write_results

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=1_400_000)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--resolutions", nargs="+", type=int, default=[256, 512, 1024, 2048, 4096])
    ap.add_argument("--input", default=None)
    args = ap.parse_args(argv)

    from PIL import Image
    import numpy as np

    from benchmarks.bench_retopo import prepare_input
    from pipeline.bake.bake import BakeSettings, bake_maps, reconstruction_error
    from pipeline.bake.uv import unwrap
    from pipeline.io.meshfile import load_mesh
    from pipeline.io.eyes_file import read_eye_loops
    from pipeline.retopo.retopo import RetopoSettings, retopologize

    folder = Path(args.input) if args.input else prepare_input(args.triangles)[0]
    dense = load_mesh(folder / "mesh.npz")
    eyes = read_eye_loops(folder / "eyes.json", len(dense["V"]))
    texture = None
    if (folder / "texture.png").exists():
        texture = np.asarray(Image.open(folder / "texture.png").convert("RGB"))
    t0 = time.perf_counter()
    low = retopologize(dense["V"], dense["F"], eyes, RetopoSettings())
    t_retopo = time.perf_counter() - t0
    rows = []
    for res in args.resolutions:
        tu = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            UV, FUV = unwrap(low.V, low.F, res, 8)
            tu.append(time.perf_counter() - t0)
        times, ray, b = [], [], None
        for _ in range(args.runs):
            t0 = time.perf_counter()
            b = bake_maps(low.V, low.F, low.loops, dense, texture, BakeSettings(resolution=res), UV=UV, FUV=FUV)
            times.append(time.perf_counter() - t0)
            ray.append(b.timings_s["raycast_s"])
        e = reconstruction_error(low.V, low.F, UV, FUV, b.displacement, dense["V"], dense["F"], levels=2)
        row = {"resolution": res, "texels": b.metrics["texels"],
               "unwrap_s": round(statistics.median(tu), 4), "time_s": round(statistics.median(times), 4),
               "raycast_s": round(statistics.median(ray), 4),
               "missed_texel_fraction": round(b.metrics["missed_texel_fraction"], 6),
               "mean_without_mm": round(e["without_displacement"]["symmetric_mean_mm"], 5),
               "mean_with_mm": round(e["with_displacement"]["symmetric_mean_mm"], 5),
               "p95_with_lowpoly_to_scan_mm": round(e["with_displacement"]["lowpoly_to_scan"]["p95_mm"], 5),
               "mean_error_removed": round(e["mean_error_removed"], 4)}
        rows.append(row)
        print(f"{res:5d}^2: bake {row['time_s']:6.2f} s (rays {row['raycast_s']:.2f} s, unwrap "
              f"{row['unwrap_s']:.2f} s)  error {row['mean_without_mm']:.4f} -> {row['mean_with_mm']:.4f} mm "
              f"({100 * row['mean_error_removed']:.0f} % removed)  missed {row['missed_texel_fraction']:.4%}",
              flush=True)
    summary = {"input": str(folder), "input_faces": int(len(dense["F"])), "runs": args.runs,
               "lowpoly_polygons": low.metrics["polygons"], "retopo_s": round(t_retopo, 3), "rows": rows}
    write_results("bake", summary, rows)
    return summary


if __name__ == "__main__":
    main()
