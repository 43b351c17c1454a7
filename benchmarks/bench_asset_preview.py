"""Cost of the rigged asset's Cycles contact sheet (usd stage, ``preview: true``; target ~60 s on 2 cores).

    .venv/bin/python -m benchmarks.bench_asset_preview [ASSET.usda [RIG.npz]] [--runs 3]

Defaults: rigged_assets/synthetic_head/synthetic_head.usda and build/synthetic_head/rig/rig.npz
(from `dvc repro usd@synthetic_head`). Runs the Blender worker exactly as the stage does (fresh
process, tile size and samples from the ``usd:`` block of params.yaml) into a temporary folder,
``--runs`` times; reports the median wall time, render time and per-tile time. Writes
benchmarks/results/asset_preview.json and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json
from stages._common import load_params

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", nargs="?", type=Path,
                    default=ROOT / "rigged_assets" / "synthetic_head" / "synthetic_head.usda")
    ap.add_argument("rig", nargs="?", type=Path, default=ROOT / "build" / "synthetic_head" / "rig" / "rig.npz")
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    p = load_params("usd", ROOT / "params.yaml")
    size, samples = int(p.get("preview_px", 240)), int(p.get("preview_samples", 8))
    walls, infos = [], []
    with tempfile.TemporaryDirectory() as td:
        for i in range(args.runs):
            js = Path(td) / f"{i}.json"
            cmd = [sys.executable, "-m", "pipeline.blender.asset_preview", str(args.asset), str(args.rig),
                   str(Path(td) / f"{i}.png"), "--size", str(size), "--samples", str(samples), "--json", str(js)]
            t0 = time.perf_counter()
            r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
            walls.append(time.perf_counter() - t0)
            if r.returncode != 0:
                raise SystemExit(f"worker failed:\n{r.stderr[-2000:]}")
            infos.append(json.loads(js.read_text()))
    res = {"asset": os.path.relpath(args.asset, ROOT), "runs": args.runs, "tile_px": infos[0]["tile_px"],
           "sheet_px": infos[0]["sheet_px"], "samples": samples, "denoiser": infos[0]["denoiser"],
           "cpu_count": os.cpu_count(),
           "wall_s_median": round(float(np.median(walls)), 2),
           "render_s_median": round(float(np.median([i["render_s_total"] for i in infos])), 2),
           "per_tile_s_median": round(float(np.median([i["render_s_per_tile_median"] for i in infos])), 2),
           "lid_max_error_mm": max(max(i["lid_max_error_mm"].values()) for i in infos),
           "wall_s_all": [round(w, 2) for w in walls]}
    write_json(ROOT / "benchmarks" / "results" / "asset_preview.json", res)
    print(f"asset preview {res['sheet_px'][0]}x{res['sheet_px'][1]} px, {samples} samples + OIDN: "
          f"median {res['wall_s_median']} s wall ({res['render_s_median']} s rendering, "
          f"{res['per_tile_s_median']} s/tile) over {args.runs} runs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
