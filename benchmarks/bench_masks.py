"""Cost and agreement of the masks, depth maps and landmark visibility (render.masks).

    python -m benchmarks.bench_masks rigged_assets/<scan> build/<scan>/rig [--n 12] [--params params.yaml]
        [--out benchmarks/results/masks_<scan>.json]

One persistent Blender worker renders the render stage's samples 0..n-1 (params.yaml's render
settings) twice each, with and without the seg/depth outputs, in ABBA order so that drift on a
shared machine cancels; after a warm-up image of each kind. Reported:

* time per image: the worker's whole-sample wall and CPU seconds with and without masks (medians),
  the overhead (median of the per-image ratios - 1) and, separately, the pass read-back and file
  writing (``passes_s``) and the shard's visibility computation (mask and depth read back);
* the images are identical with and without masks (pixels compared);
* agreement: distance (px) of each visible apparent pupil landmark (through the cornea) from the
  boundary of the pupil mask, and of each visible apparent iris landmark from the boundary of
  the iris + pupil mask (max, 95th percentile, median);
* visibility counts per reason.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.blender.render_worker import Worker
from pipeline.io import seg_file as sf
from pipeline.io.seg_file import read_depth, read_seg
from pipeline.render import labels as lb
from pipeline.render import shard as sh
from pipeline.render import visibility as vis
from pipeline.render.asset import load_render_asset
from pipeline.render.sampling import make_sample
from pipeline.render.settings import RenderSettings


def main(argv=None) -> int:
    import yaml
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path)
    ap.add_argument("rig", type=Path)
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--params", type=Path, default=Path("params.yaml"))
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    params = (yaml.safe_load(args.params.read_text()) or {}).get("render", {})
    s = RenderSettings.from_params(params)
    asset = load_render_asset(args.asset, args.rig)
    tmp = Path(tempfile.mkdtemp(prefix="bench_masks_"))
    w = Worker(asset.usda, asset.rig_npz, threads=args.threads)

    def render(smp, masks: bool, tag: str) -> dict:
        spec = replace(smp.spec, png=str(tmp / f"{smp.index:06d}_{tag}.png"))
        if masks:
            spec = spec.with_masks(tmp / f"{smp.index:06d}_seg.png", tmp / f"{smp.index:06d}_depth.exr")
        r = w.render(spec)
        return {**r, "png": spec.png}

    samples = [make_sample(asset, s, i, tmp / "x.png") for i in range(args.n)]
    render(samples[0], False, "warm")
    render(samples[0], True, "warm")
    rows, dist_pupil, dist_iris, reasons = [], [], [], Counter()
    for k, smp in enumerate(samples):
        order = (False, True) if k % 2 == 0 else (True, False)
        rep = {m: render(smp, m, "on" if m else "off") for m in order}
        same = bool(np.array_equal(np.asarray(Image.open(rep[True]["png"])), np.asarray(Image.open(rep[False]["png"]))))
        label = lb.make_label(smp, s, asset.name)
        job = label.pop("_apparent_job", None) or lb.apparent_job(smp, asset.eyes[smp.side], s)
        app = sh.apparent_landmarks(job)["apparent_px"]
        t0 = time.perf_counter()
        segm = read_seg(tmp / f"{smp.index:06d}_seg.png", (s.width, s.height))
        depth = read_depth(tmp / f"{smp.index:06d}_depth.exr", (s.width, s.height))
        v = vis.landmark_visibility(smp.landmarks_px, app, -smp.landmarks_cam[:, 2], segm, depth,
                                    smp.camera["mm_per_px"])
        t_vis = time.perf_counter() - t0
        reasons.update(o or "visible" for o in v["occlusion"])
        for j in range(16):
            k_lm = 12 + j
            if app[j] is None or not v["visible"][k_lm]:
                continue
            mask = segm == sf.PUPIL if j >= 8 else np.isin(segm, (sf.IRIS, sf.PUPIL))
            d = vis.boundary_distance_px(app[j], mask)
            (dist_pupil if j >= 8 else dist_iris).append(d)
        rows.append({"index": smp.index, "identical_image": same,
                     "off_total_s": rep[False]["total_s"], "on_total_s": rep[True]["total_s"],
                     "off_cpu_s": rep[False]["total_cpu_s"], "on_cpu_s": rep[True]["total_cpu_s"],
                     "on_render_s": rep[True]["render_s"], "off_render_s": rep[False]["render_s"],
                     "passes_s": rep[True]["passes_s"], "visibility_s": round(t_vis, 4)})
        print(rows[-1], flush=True)

    def med(key):
        return round(float(np.median([r[key] for r in rows])), 4)

    def stats(d):
        d = np.asarray(d, float)
        return {"n": int(d.size), "max_px": round(float(d.max()), 3), "p95_px": round(float(np.percentile(d, 95)), 3),
                "median_px": round(float(np.median(d)), 3)} if d.size else {"n": 0}

    ratio = [r["on_total_s"] / r["off_total_s"] for r in rows]
    ratio_cpu = [r["on_cpu_s"] / r["off_cpu_s"] for r in rows]
    res = {"asset": asset.name, "n_images": len(rows), "size": [s.width, s.height], "samples": s.samples,
           "threads": args.threads,
           "images_identical": all(r["identical_image"] for r in rows),
           "median_total_s": {"without": med("off_total_s"), "with": med("on_total_s")},
           "median_cpu_s": {"without": med("off_cpu_s"), "with": med("on_cpu_s")},
           "overhead_wall": round(float(np.median(ratio)) - 1, 4),
           "overhead_cpu": round(float(np.median(ratio_cpu)) - 1, 4),
           "median_passes_s": med("passes_s"), "median_visibility_s": med("visibility_s"),
           "pupil_landmark_to_pupil_mask_boundary": stats(dist_pupil),
           "iris_landmark_to_iris_mask_boundary": stats(dist_iris),
           "visibility": dict(reasons), "rows": rows}
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
