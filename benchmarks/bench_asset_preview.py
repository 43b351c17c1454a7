"""Cost of the rigged asset's Cycles contact sheet (usd stage, ``preview: true``; target <= 5 s wall on 2 cores).

    .venv/bin/python -m benchmarks.bench_asset_preview [ASSET.usda [RIG.npz]] [--runs 5] [--split]
        [--split-runs 3] [--compare] [--quality] [--reference-samples 256] [--keep DIR]

Defaults: rigged_assets/synthetic_head/synthetic_head.usda and build/synthetic_head/rig/rig.npz
(from `dvc repro usd@synthetic_head`). Every measurement runs the Blender worker
(``python -m pipeline.blender.asset_preview``) as the usd stage does: a fresh process, tile size and
samples from the ``usd:`` block of params.yaml, into a temporary folder.

* always: ``--runs`` runs of the stage's configuration; medians of the wall time seen here
  (process start to exit: what the stage pays) and of each phase the worker reports -- Python
  start-up and imports (the process wall time minus the worker's own), Blender start (``import
  bpy``), USD import, scene setup (shape keys, materials, framing, Cycles scene), posing + checks
  of the four tiles, the first render (it also loads kernels and textures, builds the BVH and the
  world's importance map), the other three renders, composing the sheet -- and the process CPU
  seconds (all threads: what a preview costs on a busy machine, where the wall time swings 2-3x
  with other people's load).
* ``--split``: what made the preview slow. The worker's former settings (480 x 240 px tiles,
  8 spp, Blender's default random-walk subsurface, automatic world importance map, the HIGH
  denoiser, 64-px Cycles tiles), then one change after another up to the stage's configuration,
  for the first and last, the same without the denoiser and at 1 spp without
  it, which splits a tile into path tracing per sample, the denoiser and the per-render overhead
  (``--split-runs`` runs each).
* ``--compare``: the former settings (:data:`BEFORE`: pixel-identical to the worker at 595996b)
  and the stage's configuration alternately, ``--split-runs`` times each, so both see the same load;
  medians of wall and CPU seconds.
* ``--quality``: PSNR of the four tiles against a ``--reference-samples`` render without the
  denoiser (same size; adaptive sampling down to a 0.002 noise threshold), for 1, 2, 4, 8 and 16
  spp with the denoiser; ``benchmarks/results/asset_preview_quality.csv`` (samples, cpu_s, wall_s,
  psnr_db) is a DVC plot.

Writes benchmarks/results/asset_preview.json (sections ``stage``, ``split``, ``compare``, ``quality``; a section
not run this time is kept from the last run) and prints a summary. ``--keep DIR`` copies each
configuration's PNG there (for looking at them side by side).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_render_quality import psnr
from pipeline.io.atomic import write_json
from stages._common import load_params

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
# the worker as it was before the preview was made fast (commit 595996b): its defaults, as options
BEFORE = {"size": 240, "samples": 8,
          "options": {"subsurface_method": "RANDOM_WALK", "world_map_resolution": 0, "denoise_quality": "HIGH",
                      "tile_size": 64}}


def run_worker(asset: Path, rig: Path, out_png: Path, size: int, samples: int, options: dict) -> dict:
    """One fresh worker process; its JSON report plus ``process_s`` (wall seen here)."""
    js = out_png.with_suffix(".json")
    from pipeline.blender import launch

    cmd = launch.command("pipeline.blender.asset_preview", [asset, rig, out_png, "--size", size, "--samples",
                                                            samples, "--json", js])
    for k, v in options.items():
        cmd += ["--option", f"{k}={v}"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"worker failed ({' '.join(cmd[2:])}):\n{r.stderr[-2000:]}")
    info = json.loads(js.read_text())
    info["process_s"] = wall
    return info


def phases(info: dict) -> dict:
    """The phases of one run (seconds; see the module docstring)."""
    r = info["render_s"]
    return {"wall_s": info["process_s"],
            "python_s": info["process_s"] - info["sheet_s"],
            "blender_start_s": info["blender_start_s"],
            "usd_import_s": info["import_s"],
            "scene_setup_s": info["setup_s"] - info["import_s"],
            "pose_and_checks_s": info["pose_s_total"],
            "first_render_s": r[0],
            "other_renders_s": float(np.sum(r[1:])),
            "render_per_tile_s": float(np.median(r[1:])) if len(r) > 1 else r[0],
            "render_cpu_per_tile_s": float(np.median(info["render_cpu_s"][1:])),
            "compose_s": info["compose_s"],
            "cpu_s": info["cpu_s"]}


def medians(infos: list[dict]) -> dict:
    ph = [phases(i) for i in infos]
    return {k: round(float(np.median([p[k] for p in ph])), 3) for k in ph[0]}


def measure(asset, rig, td: Path, name: str, size: int, samples: int, options: dict, runs: int,
            keep: Path | None) -> dict:
    infos = []
    for i in range(runs):
        png = td / f"{name}_{i}.png"
        infos.append(run_worker(asset, rig, png, size, samples, options))
        if keep is not None and i == 0:
            shutil.copy(png, keep / f"{name}.png")
    m = medians(infos)
    out = {"size": size, "tile_px": infos[0]["tile_px"], "samples": samples, "options": infos[0]["render_options"],
           "runs": runs, **m, "wall_s_all": [round(i["process_s"], 2) for i in infos],
           "lid_max_error_mm": max(max(i["lid_max_error_mm"].values()) for i in infos)}
    print(f"  {name:<28} {size * 2}x{size} {samples:>2} spp: wall {m['wall_s']:6.2f} s  cpu {m['cpu_s']:6.2f} s  "
          f"first render {m['first_render_s']:5.2f} s  per tile {m['render_per_tile_s']:5.2f} s "
          f"({m['render_cpu_per_tile_s']:5.2f} cpu-s)  runs {out['wall_s_all']}", flush=True)
    return out


def tile_pixels(png: Path, size: int) -> np.ndarray:
    """The four rendered tiles of a sheet (labels and gaps left out), stacked: (4 * size, 2 * size, 3)."""
    from PIL import Image

    from pipeline.blender.asset_preview import tile_boxes

    a = np.asarray(Image.open(png).convert("RGB"))
    return np.concatenate([a[y:y + h, x:x + w] for x, y, w, h in tile_boxes(size)])


def split(asset, rig, td, size, samples, runs, keep) -> dict:
    steps = [("before", dict(BEFORE["options"]), BEFORE["size"], BEFORE["samples"]),
             ("+ burley subsurface", {k: v for k, v in BEFORE["options"].items() if k != "subsurface_method"},
              BEFORE["size"], BEFORE["samples"]),
             ("+ world map 256", {"denoise_quality": "HIGH", "tile_size": 64}, BEFORE["size"], BEFORE["samples"]),
             ("+ denoiser balanced", {"tile_size": 64}, BEFORE["size"], BEFORE["samples"]),
             ("+ one cycles tile", {}, BEFORE["size"], BEFORE["samples"]),
             (f"+ {samples} spp", {}, BEFORE["size"], samples),
             (f"+ {2 * size}x{size} px (now)", {}, size, samples)]
    rows = [dict(step=n, **measure(asset, rig, td, slug(n), s, sp, o, runs, keep)) for n, o, s, sp in steps]
    per_tile = {}
    for label, opts, s, sp, full in (("before", dict(BEFORE["options"]), BEFORE["size"], BEFORE["samples"], rows[0]),
                                     ("now", {}, size, samples, rows[-1])):
        nod = measure(asset, rig, td, f"{label}_no_denoiser", s, sp, {**opts, "denoise": False}, runs, None)
        one = measure(asset, rig, td, f"{label}_1spp_no_denoiser", s, 1, {**opts, "denoise": False}, runs, None)
        px = 2 * s * s
        per_sample = (nod["render_cpu_per_tile_s"] - one["render_cpu_per_tile_s"]) / max(sp - 1, 1)
        per_tile[label] = {
            "tile_px": [2 * s, s], "samples": sp,
            "tile_cpu_s": full["render_cpu_per_tile_s"],
            "path_tracing_cpu_s": round(per_sample * sp, 3),
            "path_tracing_cpu_us_per_sample_px": round(per_sample / px * 1e6, 2),
            "denoiser_cpu_s": round(full["render_cpu_per_tile_s"] - nod["render_cpu_per_tile_s"], 3),
            "denoiser_cpu_us_per_px": round((full["render_cpu_per_tile_s"] - nod["render_cpu_per_tile_s"]) / px * 1e6, 2),
            "overhead_cpu_s": round(one["render_cpu_per_tile_s"] - per_sample, 3),
            "tile_wall_s": full["render_per_tile_s"], "no_denoiser_wall_s": nod["render_per_tile_s"],
            "one_spp_no_denoiser_wall_s": one["render_per_tile_s"]}
    return {"steps": rows, "per_tile": per_tile}


def slug(name: str) -> str:
    return "_".join("".join(c if c.isalnum() else " " for c in name).split())


def compare(asset, rig, td, size, samples, runs) -> dict:
    before, now = [], []
    for i in range(runs):
        before.append(run_worker(asset, rig, td / f"cmp_before_{i}.png", BEFORE["size"], BEFORE["samples"],
                                 BEFORE["options"]))
        now.append(run_worker(asset, rig, td / f"cmp_now_{i}.png", size, samples, {}))
    out = {}
    for name, infos in (("before", before), ("now", now)):
        out[name] = {"wall_s": round(float(np.median([i["process_s"] for i in infos])), 3),
                     "cpu_s": round(float(np.median([i["cpu_s"] for i in infos])), 3),
                     "wall_s_all": [round(i["process_s"], 2) for i in infos]}
    out["speed_up_wall"] = round(out["before"]["wall_s"] / out["now"]["wall_s"], 2)
    out["speed_up_cpu"] = round(out["before"]["cpu_s"] / out["now"]["cpu_s"], 2)
    print(f"  before {out['before']['wall_s']} s wall ({out['before']['cpu_s']} cpu-s), now {out['now']['wall_s']} s "
          f"({out['now']['cpu_s']} cpu-s): {out['speed_up_wall']}x wall, {out['speed_up_cpu']}x cpu", flush=True)
    return out


def quality(asset, rig, td, size, ref_samples, keep) -> dict:
    ref_png = td / "reference.png"
    t0 = time.perf_counter()
    run_worker(asset, rig, ref_png, size, ref_samples, {"denoise": False, "adaptive_threshold": 0.002,
                                                        "world_map_resolution": 0})
    ref_s = time.perf_counter() - t0
    if keep is not None:
        shutil.copy(ref_png, keep / "reference.png")
    ref = tile_pixels(ref_png, size)
    print(f"  reference {ref_samples} spp without the denoiser: {ref_s:.0f} s", flush=True)
    rows = []
    for s in (1, 2, 4, 8, 16):
        png = td / f"q{s}.png"
        info = run_worker(asset, rig, png, size, s, {})
        rows.append({"samples": s, "cpu_s": round(info["cpu_s"], 2), "wall_s": round(info["process_s"], 2),
                     "psnr_db": round(psnr(tile_pixels(png, size), ref), 2)})
        print(f"  {s:>2} spp + denoiser: PSNR {rows[-1]['psnr_db']:5.2f} dB, cpu {rows[-1]['cpu_s']:5.2f} s, "
              f"wall {rows[-1]['wall_s']:5.2f} s", flush=True)
    with open(RESULTS / "asset_preview_quality.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["samples", "cpu_s", "wall_s", "psnr_db"])
        for r in rows:
            wr.writerow([r["samples"], r["cpu_s"], r["wall_s"], r["psnr_db"]])
    return {"size": size, "reference_samples": ref_samples, "reference_s": round(ref_s, 1), "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", nargs="?", type=Path,
                    default=ROOT / "rigged_assets" / "synthetic_head" / "synthetic_head.usda")
    ap.add_argument("rig", nargs="?", type=Path, default=ROOT / "build" / "synthetic_head" / "rig" / "rig.npz")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--split", action="store_true", help="also measure what each setting costs (see above)")
    ap.add_argument("--split-runs", type=int, default=3, help="runs of each --split configuration")
    ap.add_argument("--compare", action="store_true", help="also the former settings and these, alternately")
    ap.add_argument("--quality", action="store_true", help="also PSNR against a many-sample reference")
    ap.add_argument("--reference-samples", type=int, default=256)
    ap.add_argument("--keep", type=Path, default=None, help="copy the PNGs here")
    args = ap.parse_args(argv)
    for p in (args.asset, args.rig):
        if not p.is_file():
            print(f"error: {p}: missing (run `dvc repro usd@synthetic_head` first)", file=sys.stderr)
            return 2
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    p = load_params("usd", ROOT / "params.yaml")
    size, samples = int(p.get("preview_px", 180)), int(p.get("preview_samples", 4))
    out_path = RESULTS / "asset_preview.json"
    try:
        res = json.loads(out_path.read_text())
        if "stage" not in res:
            res = {}                     # the file of an older version of this benchmark
    except (OSError, ValueError):
        res = {}
    asset_name = str(args.asset.resolve())
    if args.asset.resolve().is_relative_to(ROOT):
        asset_name = str(args.asset.resolve().relative_to(ROOT))
    res.update({"asset": asset_name, "cpu_count": os.cpu_count(),
                "load_avg_before": [round(x, 2) for x in os.getloadavg()]})
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        print("stage configuration:", flush=True)
        res["stage"] = measure(args.asset, args.rig, td, "stage", size, samples, {}, args.runs, args.keep)
        if args.split:
            print("split (one change after another):", flush=True)
            res["split"] = split(args.asset, args.rig, td, size, samples, args.split_runs, args.keep)
        if args.compare:
            print("before / now, alternately:", flush=True)
            res["compare"] = compare(args.asset, args.rig, td, size, samples, args.split_runs)
        if args.quality:
            print("quality:", flush=True)
            res["quality"] = quality(args.asset, args.rig, td, size, args.reference_samples, args.keep)
    res["load_avg_after"] = [round(x, 2) for x in os.getloadavg()]
    write_json(out_path, res)
    st = res["stage"]
    print(f"asset preview {st['tile_px'][0]}x{st['tile_px'][1]} px tiles, {samples} spp + OIDN: median "
          f"{st['wall_s']} s wall, {st['cpu_s']} cpu-s over {args.runs} runs "
          f"(Blender start {st['blender_start_s']} s, USD import {st['usd_import_s']} s, first render "
          f"{st['first_render_s']} s, {st['render_per_tile_s']} s per further tile)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
