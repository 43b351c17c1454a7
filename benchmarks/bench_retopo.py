"""Benchmark retopo: time vs error for each method and polygon count, plus the stage chain at 1.4M faces.

    .venv/bin/python -m benchmarks.bench_retopo [--triangles 1400000] [--runs 3]
        [--methods quadric isotropic] [--targets 2000 4500 9000 18000] [--input DIR]

Input: the synthetic head (``pipeline.synthetic_head``, seed 7, ``--triangles``
faces) run once through ``stages.ingest`` and ``stages.remove_eyeballs`` into a
cached temp folder (or ``--input build/<scan>/remove_eyeballs``). For each method
and target polygon count ``retopologize`` runs ``--runs`` times in-process (median
time). Writes ``benchmarks/results/retopo.json`` (summary + rows) and
``benchmarks/results/retopo.csv`` (one row per method x target; DVC plot:
x = polygons, y = mean_mm or time_s, grouped by method).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.results_files import write_results

ROOT = Path(__file__).resolve().parents[1]


def prepare_input(triangles: int, seed: int = 7) -> tuple[Path, dict]:
    """Synthetic head -> ingest -> remove_eyeballs (cached); returns the folder and stage wall times."""
    from stages._common import read_stage_metrics

    cache = Path(tempfile.gettempdir()) / f"eyerig_bench_head_{triangles}_{seed}"
    times = {}
    if not (cache / "remove_eyeballs" / "mesh.npz").exists():
        from pipeline.synthetic_head import make_synthetic_head, write_scan_folder

        (cache / "raw").mkdir(parents=True, exist_ok=True)
        write_scan_folder(make_synthetic_head(seed=seed, target_triangles=triangles, noise_mm=0.0,
                                              texture_size=1024), cache / "raw")
        for stage, args in (("ingest", [cache / "raw", cache / "ingest"]),
                            ("remove_eyeballs", [cache / "ingest", cache / "remove_eyeballs"])):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", f"stages.{stage}", *map(str, args), "--metrics",
                            str(cache / f"{stage}.metrics.json")], check=True, cwd=str(ROOT))
            times[stage] = time.perf_counter() - t0
    for stage in ("ingest", "remove_eyeballs"):
        p = cache / f"{stage}.metrics.json"
        if p.exists():
            times.setdefault(stage, read_stage_metrics(p).get("wall_time_s"))
    return cache / "remove_eyeballs", times


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=1_400_000)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["quadric", "isotropic"])
    ap.add_argument("--targets", nargs="+", type=int, default=[2000, 4500, 9000, 18000])
    ap.add_argument("--input", default=None, help="a remove_eyeballs folder instead of the synthetic head")
    args = ap.parse_args(argv)

    from pipeline.io.meshfile import load_mesh
    from pipeline.io.eyes_file import read_eye_loops
    from pipeline.retopo.retopo import RetopoSettings, retopologize

    if args.input:
        folder, chain = Path(args.input), {}
    else:
        folder, chain = prepare_input(args.triangles)
    mesh = load_mesh(folder / "mesh.npz")
    eyes = read_eye_loops(folder / "eyes.json", len(mesh["V"]))
    rows = []
    for method in args.methods:
        for target in args.targets:
            times, res = [], None
            for _ in range(args.runs):
                t0 = time.perf_counter()
                res = retopologize(mesh["V"], mesh["F"], eyes, RetopoSettings(method=method, target_polygons=target))
                times.append(time.perf_counter() - t0)
            m = res.metrics
            row = {"method": method, "target_polygons": target, "polygons": m["polygons"],
                   "quads": m["quads"], "time_s": round(statistics.median(times), 4),
                   "mean_mm": round(m["distance_symmetric_mean_mm"], 5),
                   "lowpoly_to_scan_mean_mm": round(m["distance_lowpoly_to_scan"]["mean_mm"], 5),
                   "lowpoly_to_scan_p95_mm": round(m["distance_lowpoly_to_scan"]["p95_mm"], 5),
                   "lowpoly_to_scan_max_mm": round(m["distance_lowpoly_to_scan"]["max_mm"], 5),
                   "scan_to_lowpoly_mean_mm": round(m["distance_scan_to_lowpoly"]["mean_mm"], 5),
                   "scan_to_lowpoly_p95_mm": round(m["distance_scan_to_lowpoly"]["p95_mm"], 5),
                   "scan_to_lowpoly_max_mm": round(m["distance_scan_to_lowpoly"]["max_mm"], 5),
                   "min_angle_p5_deg": round(m["angles"]["min_angle_p5_deg"], 2),
                   "min_angle_min_deg": round(m["angles"]["min_angle_min_deg"], 2),
                   "manifold": m["mesh"]["manifold"], "flipped_faces": m["flipped_faces"],
                   "crop_faces": m["crop_faces"]}
            rows.append(row)
            print(f"{method:9s} target {target:6d}: {row['polygons']:6d} polys  {row['time_s']:6.2f} s  "
                  f"mean {row['mean_mm']:.4f} mm  p95 {row['lowpoly_to_scan_p95_mm']:.3f}/"
                  f"{row['scan_to_lowpoly_p95_mm']:.3f} mm  min-angle p5 {row['min_angle_p5_deg']:.1f} deg  "
                  f"flipped {row['flipped_faces']}", flush=True)
    summary = {"input": str(folder) if args.input else f"synthetic_head seed 7, {args.triangles} triangles",
               "input_faces": int(len(mesh["F"])), "runs": args.runs,
               "chain_wall_s": {k: (round(v, 3) if v is not None else None) for k, v in chain.items()},
               "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
               "rows": rows}
    write_results("retopo", summary, rows)
    return summary


if __name__ == "__main__":
    main()
