"""Synthetic head generation speed vs density (median of repeated runs).

    .venv/bin/python -m benchmarks.bench_synthetic_head [--repeats 3]

Times ``make_synthetic_head`` (surface, ground-truth margin tracing and the
texture) at 100k, 350k and 1.4M triangles with a 1024 px texture, plus the
params.yaml default (350k triangles, 2048 px texture), and writing the scan
folder (binary PLY + PNG) at 1.4M. Target: 1.4M
triangles generated in <= 10 s on the 2-core dev machine. Writes
benchmarks/results/synthetic_head.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from pipeline.io.atomic import write_json
from pipeline.synthetic_head import make_synthetic_head, write_scan_folder

ROOT = Path(__file__).resolve().parents[1]

TARGET_S = 10.0


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--texture-size", type=int, default=1024)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "synthetic_head.json"))
    args = ap.parse_args(argv)
    make_synthetic_head(target_triangles=2_000, texture_size=32, noise_mm=0.0)   # warm up imports
    rows = []
    cases = [(100_000, args.texture_size), (350_000, args.texture_size), (350_000, 2048),
             (1_400_000, args.texture_size)]
    for target, tex in cases:
        times, head = [], None
        for _ in range(args.repeats):
            head = None
            t0 = time.perf_counter()
            head = make_synthetic_head(seed=7, target_triangles=target, texture_size=tex, noise_mm=0.0)
            times.append(time.perf_counter() - t0)
        row = {"target_triangles": target, "n_faces": int(len(head.F)), "n_vertices": int(len(head.V)),
               "texture_size": tex, "generate_s_median": round(statistics.median(times), 3),
               "generate_s_all": [round(t, 3) for t in times]}
        if target == 1_400_000:
            wt = []
            for _ in range(args.repeats):
                with tempfile.TemporaryDirectory() as tmp:
                    t0 = time.perf_counter()
                    write_scan_folder(head, tmp)
                    wt.append(time.perf_counter() - t0)
                    row["ply_mb"] = round(os.path.getsize(Path(tmp) / "scan.ply") / 2**20, 1)
            row["write_s_median"] = round(statistics.median(wt), 3)
        rows.append(row)
        extra = (f", write {row['write_s_median']:.2f} s, PLY {row['ply_mb']} MB"
                 if "write_s_median" in row else "")
        print(f"{target:>9,d} tris, {tex} px texture: generate {row['generate_s_median']:6.2f} s "
              f"(median of {args.repeats}){extra}")
    big = rows[-1]
    result = {
        "benchmark": "synthetic_head generation",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "platform": platform.platform()},
        "repeats": args.repeats,
        "target_s_at_1_4M": TARGET_S,
        "meets_target": big["generate_s_median"] <= TARGET_S,
        "rows": rows,
    }
    write_json(args.out, result)
    print(f"1.4M triangles: {big['generate_s_median']:.2f} s (target <= {TARGET_S} s): "
          f"{'OK' if result['meets_target'] else 'MISSED'}; wrote {args.out}")
    return result


if __name__ == "__main__":
    main()
