"""Render time against image size and against eye-region polygon count (issue 15, item 4).

    .venv/bin/python -m benchmarks.bench_render_curves [--scan synthetic_head] [--images 10]

One persistent Blender worker (the stage's thread count) renders ``--images`` specs of the
stage's own sampler at the default settings (samples, denoiser, masks) in every variant:

* image size 120 x 80 (the default), 240 x 160 and 480 x 320: the same framing (the
  orthographic width is unchanged), 4x the pixels per step;
* eye-region polygon count: the asset's EyeRegion mesh as imported, and Catmull-Clark
  subdivided once and twice after the rig's deformation (4x the polygons per level; spec
  key ``skin_subdivision``, benchmarks only), at 120 x 80.

The variants run in blocks (a size or mesh change makes Cycles rebuild its film or BVH once,
which a stage at that setting pays once; each block starts with one uncounted warm-up image),
A B C ... then A B C ... again on the other half of the specs.

Per point: the median over the specs of the worker's wall seconds per image (``time_s``:
posing, eyelash rebuild, render, passes) and of its CPU seconds (``cpu_s``, all threads: the
robust figure on a shared machine). Writes benchmarks/results/render_time_vs_size.csv
(``pixels,width,height,time_s,cpu_s``), render_time_vs_polygons.csv
(``polygons,time_s,cpu_s``) and render_curves.json; ``dvc plots show`` draws both.
"""

from __future__ import annotations

import argparse
import csv
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SIZES = ((120, 80), (240, 160), (480, 320))
SUBDIVISIONS = (0, 1, 2)


def main(argv=None) -> int:
    from pipeline.io.seg_file import depth_name, seg_name
    from pipeline.render import asset as ra
    from pipeline.render.settings import RenderSettings
    from pipeline.render import sampling as sp
    from pipeline.render.run import run_options
    from pipeline.render.shard import BlenderProcess
    from stages._common import load_params

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan", default="synthetic_head")
    ap.add_argument("--images", type=int, default=10)
    args = ap.parse_args(argv)
    rig_dir = ROOT / "build" / args.scan / "rig"
    if not (rig_dir / "rig.npz").is_file():
        raise SystemExit(f"error: {rig_dir / 'rig.npz'}: missing (run `dvc repro usd@{args.scan}` first)")
    asset = ra.load_render_asset(ROOT / "rigged_assets" / args.scan, rig_dir)
    settings = RenderSettings.from_dict(load_params("render", ROOT / "params.yaml"))
    threads = run_options(settings, ROOT / "renders" / args.scan)["threads"]
    variants = [("size", (w, h), {"width": w, "height": h, "skin_subdivision": 0}) for w, h in SIZES]
    variants += [("polygons", lv, {"width": settings.width, "height": settings.height, "skin_subdivision": lv})
                 for lv in SUBDIVISIONS]
    rows = {(kind, key): [] for kind, key, _ in variants}
    load0 = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        bp = BlenderProcess(asset.usda, asset.rig_npz, threads=threads)
        try:
            specs = []
            for i in range(args.images + 1):
                smp = sp.make_sample(asset, settings, i, td / f"{i:06d}.png")
                specs.append(dict(smp.spec.to_dict(), seg_png=str(td / seg_name(i)), depth_exr=str(td / depth_name(i))))
            half = (args.images + 1) // 2
            for part in (specs[1:1 + half], specs[1 + half:]):     # A B C ... A B C: load drifts alike
                for kind, key, over in variants:
                    # a new size or mesh makes Cycles rebuild film / BVH once (what a stage at that
                    # setting pays once): one warm-up image, not counted
                    for j, spec in enumerate([specs[0]] + part):
                        r = bp.render(dict(spec, **over))
                        if not r.get("ok"):
                            raise SystemExit(f"image {spec['index']} ({kind} {key}) failed: {r.get('error')}")
                        if j > 0:
                            rows[(kind, key)].append(r)
        finally:
            bp.close()
    med = {k: {"time_s": round(float(np.median([r["total_s"] for r in v])), 4),
               "cpu_s": round(float(np.median([r["total_cpu_s"] for r in v])), 4)} for k, v in rows.items()}
    size_rows = [{"pixels": w * h, "width": w, "height": h, **med[("size", (w, h))]} for w, h in SIZES]
    poly_rows = [{"polygons": int(np.median([r["skin_polygons"] for r in rows[("polygons", lv)]])),
                  "subdivision": lv, **med[("polygons", lv)]} for lv in SUBDIVISIONS]
    RESULTS.mkdir(parents=True, exist_ok=True)
    for name, table, cols in (("render_time_vs_size.csv", size_rows, ["pixels", "width", "height", "time_s", "cpu_s"]),
                              ("render_time_vs_polygons.csv", poly_rows, ["polygons", "time_s", "cpu_s"])):
        with open(RESULTS / name, "w", newline="") as fh:
            wr = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
            wr.writeheader()
            wr.writerows(table)
    res = {"scan": args.scan, "images": args.images, "threads": threads, "samples": settings.samples,
           "denoise": settings.denoise, "masks": settings.masks, "size": size_rows, "polygons": poly_rows,
           "loadavg_before": round(load0, 2), "loadavg_after": round(os.getloadavg()[0], 2),
           "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    write_json(RESULTS / "render_curves.json", res)
    for r in size_rows:
        print(f"{r['width']:4d} x {r['height']:3d}: {r['time_s']:.3f} s/image, {r['cpu_s']:.3f} CPU-s")
    for r in poly_rows:
        print(f"{r['polygons']:7d} skin polygons: {r['time_s']:.3f} s/image, {r['cpu_s']:.3f} CPU-s")
    print(f"load average {res['loadavg_before']} -> {res['loadavg_after']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
