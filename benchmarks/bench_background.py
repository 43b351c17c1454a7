"""Background (segmentation class 0) in renders, before and after the coverage rejection.

    python -m benchmarks.bench_background predict [--n 200] [--scans synthetic_head james ict_neutral]
        [--assets rigged_assets] [--build build]
    python -m benchmarks.bench_background render --tag after [--n 12] [--presets generic targeted unityeyes]
    python -m benchmarks.bench_background crop --pairs NAME ASSET_DIR RIG_DIR [NAME ASSET_DIR RIG_DIR ...] [--n 30]
    python -m benchmarks.bench_background report

``predict`` (CPU only, no render): for every preset and home scan, samples 0..n-1 drawn as
before (the pupil-in-lids rule alone) and as now (:func:`pipeline.render.sampling.make_sample`,
which also redraws a camera that sees past the asset): how many of the old samples leave part
of the frame uncovered (:func:`pipeline.render.coverage.sample_uncovered`, the rasteriser's
uncovered area including its safety margin) and how much, the GazeML crop's uncovered area for
``unityeyes`` (GazeML's UnityEyes loader crop: 1.5 x the eye width between the caruncle and
interior margin point 8, centred on the interior margin's box, aspect 36 x 60, from the
``unityeyes`` writer's own points), and, now, the attempts per sample, the samples refused
(no camera of ``max_attempts`` covers the frame) and the rasteriser's time per attempt.
Writes ``benchmarks/results/background_predict.json``.

``render``: renders ``n`` images per preset and scan through the render stage
(``python -m stages.render``; ``--samples`` per pixel (default 1), no denoising, masks on, label formats eyerig +
unityeyes for the unityeyes preset) into ``/tmp/bench_background/<tag>/<preset>/<scan>`` and
counts class-0 pixels per image (``NNNNNN_seg.png``) and, for unityeyes images, inside the
GazeML crop (from the written ``unityeyes/NNNNNN.json`` through the transcription of GazeML's
loader, tests/fixtures/gazeml_unityeyes.py: the crop's full-image rectangle, pixels whose centre lies
in it). A scan whose preset refuses every sample is recorded with the stage's one-line message.
Writes ``benchmarks/results/background_<tag>.json``. Run it on main's checkout with
``--tag before --code <main checkout>`` (its ``stages.render`` renders) and with ``--tag after``.

``crop``: how far a wider eye region goes: for each ``--assets``/``--build`` pair given as
``--pairs NAME ASSETS_DIR BUILD_DIR ...`` (e.g. the home synthetic_head and one rebuilt with wider
``retopo.margin_*``), the first attempts (pupil rule only) of ``n`` samples per preset whose
frame is covered, and for ``unityeyes`` whose GazeML crop is, also at 320 x 240. Writes
``benchmarks/results/background_crop.json``. The wider synthetic_head of the results: params.yaml
with ``retopo.margin_lateral_mm 36, margin_above_mm 32, margin_below_mm 30``, then stages retopo,
bake, snap, rig and usd on build/synthetic_head/remove_eyeballs as dvc.yaml runs them (--params).

``report``: ``background.json`` and ``background.md`` from the predict, crop and render results.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.results_files import RESULTS, write_results

SCANS = ("synthetic_head", "james", "ict_neutral")
PRESETS = ("generic", "targeted", "unityeyes", "near_eye", "webcam")
ROOT = Path(__file__).resolve().parents[1]


def gazeml_crop(interior_px, caruncle_px, eye_image_shape=(36, 60)) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1) full-image pixels of GazeML's UnityEyes crop (tests/fixtures/gazeml_unityeyes.py
    step 3 without augmentation): width ``1.5 |mean(caruncle).x - interior[8].x|``, centred on the
    interior margin's bounding box, height = width * oh / ow. Points (n, 2) in our pixels (y down,
    the same as GazeML's after its flip)."""
    oh, ow = eye_image_shape
    interior, caruncle = np.asarray(interior_px, float), np.asarray(caruncle_px, float)
    w = 1.5 * abs(caruncle[:, 0].mean() - interior[8, 0])
    mid = 0.5 * (interior.min(0) + interior.max(0))
    h = w * oh / ow
    return mid[0] - w / 2, mid[0] + w / 2, mid[1] - h / 2, mid[1] + h / 2


def _old_sample(asset, s, i):
    """The sample as drawn before the coverage rule: the first attempt with the pupil inside the lids."""
    from pipeline.render import sampling as sp

    for attempt in range(int(s.max_attempts)):
        smp = sp.pose_sample(asset, s, i, attempt, "/tmp/bench_background.png")
        if sp.pupil_in_lids(smp):
            return smp
    return None


def _crop_uncovered(asset, smp, s) -> float:
    from pipeline.render import coverage as cov
    from pipeline.render.camera import project, to_camera
    from pipeline.render.formats import unityeyes as ue

    job = ue.job(asset, smp)
    W2C = smp.camera["world_to_camera"]
    scale = smp.camera["ortho_scale_mm"]

    def px(P):
        return project(to_camera(np.asarray(P), W2C), scale, s.width, s.height)

    x0, x1, y0, y1 = gazeml_crop(px(job["interior_head_mm"]), px(job["caruncle_head_mm"]))
    tris = cov.scene_triangles(asset, smp.spec.lid_weights, W2C)
    P = project(tris.reshape(-1, 3), scale, s.width, s.height).reshape(-1, 3, 2)
    m = cov.MARGIN_PX
    return cov.uncovered_area(P, x0 - m, x1 + m, y0 - m, y1 + m), (x1 - x0) * (y1 - y0)


def predict(args) -> dict:
    from pipeline.render import coverage as cov
    from pipeline.render import sampling as sp
    from pipeline.render.asset import load_render_asset
    from pipeline.render.settings import RenderSettings

    out = {"n": args.n, "margin_px": cov.MARGIN_PX, "row_step_px": cov.ROW_STEP_PX, "cases": []}
    for scan in args.scans:
        asset = load_render_asset(Path(args.assets) / scan, Path(args.build) / scan / "rig")
        for preset in args.presets:
            s = RenderSettings.from_params({"preset": preset})
            area = s.width * s.height
            before, crop, crop_area = [], [], []
            for i in range(args.n):
                smp = _old_sample(asset, s, i)
                if smp is None:
                    continue
                before.append(cov.sample_uncovered(asset, smp, s.width, s.height))
                if preset == "unityeyes":
                    u, a = _crop_uncovered(asset, smp, s)
                    crop.append(u)
                    crop_area.append(a)
            before = np.array(before)
            attempts, refused, msg = [], 0, None
            t0 = time.perf_counter()
            for i in range(args.n):
                try:
                    attempts.append(sp.make_sample(asset, s, i, "/tmp/bench_background.png").attempts)
                except sp.RejectionError as exc:
                    refused += 1
                    msg = str(exc)
            dt = time.perf_counter() - t0
            smp = _old_sample(asset, s, 0)
            t1 = time.perf_counter()
            for _ in range(20):
                cov.sample_uncovered(asset, smp, s.width, s.height)
            t_cov = (time.perf_counter() - t1) / 20
            case = {"scan": scan, "preset": preset, "size": [s.width, s.height],
                    "before_images_uncovered": int((before > 0).sum()), "before_images": int(len(before)),
                    "before_uncovered_frac_median": float(np.median(before) / area),
                    "before_uncovered_frac_max": float(before.max() / area),
                    "after_refused": refused, "after_attempts_mean": float(np.mean(attempts)) if attempts else None,
                    "after_attempts_max": int(max(attempts)) if attempts else None,
                    "after_sampling_ms_per_image": 1000 * dt / args.n, "coverage_ms_per_attempt": 1000 * t_cov,
                    "refusal_message": msg}
            if crop:
                c = np.array(crop) / np.array(crop_area)
                case.update({"before_gazeml_crops_uncovered": int((c > 0).sum()),
                             "before_gazeml_crop_uncovered_frac_median": float(np.median(c)),
                             "before_gazeml_crop_uncovered_frac_max": float(c.max())})
            print(json.dumps({k: v for k, v in case.items() if k != "refusal_message"}), flush=True)
            out["cases"].append(case)
    write_results("background_predict", out)
    return out


def crop(args) -> dict:
    from pipeline.render import coverage as cov
    from pipeline.render.asset import load_render_asset
    from pipeline.render.settings import RenderSettings

    cases = [("generic", {}), ("webcam", {}), ("near_eye", {}), ("unityeyes", {}),
             ("unityeyes", {"width": 320, "height": 240})]
    out = {"n": args.n, "rows": []}
    p = args.pairs
    for name, adir, bdir in zip(p[0::3], p[1::3], p[2::3]):
        asset = load_render_asset(adir, bdir)
        for preset, kw in cases:
            s = RenderSettings.from_params({"preset": preset, **kw})
            ok = crop_ok = 0
            for i in range(args.n):
                smp = _old_sample(asset, s, i)
                ok += cov.sample_uncovered(asset, smp, s.width, s.height) == 0
                if preset == "unityeyes":
                    crop_ok += _crop_uncovered(asset, smp, s)[0] == 0
            row = {"asset": name, "preset": preset, "size": [s.width, s.height], "covered": ok,
                   "gazeml_crop_covered": crop_ok if preset == "unityeyes" else None,
                   "skin_edge_mm": asset.skin_faces_edge_mm}
            print(json.dumps(row), flush=True)
            out["rows"].append(row)
    write_results("background_crop", out)
    return out


def _count_render(folder: Path, preset: str) -> list[dict]:
    from PIL import Image

    from tests.fixtures import gazeml_unityeyes as gz

    rows = []
    for seg_path in sorted(folder.glob("*_seg.png")):
        seg = np.asarray(Image.open(seg_path))
        i = seg_path.name[:6]
        row = {"image": i, "background_px": int((seg == 0).sum()), "pixels": int(seg.size)}
        ue = folder / "unityeyes" / f"{i}.json"
        if preset == "unityeyes" and ue.is_file():
            doc = json.loads(ue.read_text())
            ih, iw = seg.shape
            e = gz.read_entry(doc, ih, iw)
            if e is None:                       # GazeML's head-pose filter: use the crop anyway
                doc = dict(doc, head_pose="(0.0, 180.0, 0.0)")
                e = gz.read_entry(doc, ih, iw)
            w = e["eye_width"]
            mid = e["eye_middle"]
            h = w * 36 / 60
            x0, x1, y0, y1 = mid[0] - w / 2, mid[0] + w / 2, mid[1] - h / 2, mid[1] + h / 2
            u = np.arange(iw) + 0.5
            v = np.arange(ih) + 0.5
            inside = ((v[:, None] >= y0) & (v[:, None] <= y1)) & ((u[None] >= x0) & (u[None] <= x1))
            row.update({"crop_background_px": int(((seg == 0) & inside).sum()), "crop_pixels": int(inside.sum()),
                        "crop_inside_image": bool(x0 >= 0 and y0 >= 0 and x1 <= iw and y1 <= ih)})
        rows.append(row)
    return rows


def render(args) -> dict:
    import yaml

    base = Path(args.tmp) / args.tag
    out = {"tag": args.tag, "n_per_case": args.n, "cases": []}
    for preset in args.presets:
        for scan in args.scans:
            folder = base / preset / scan
            params = base / f"{preset}_{scan}.yaml"
            params.parent.mkdir(parents=True, exist_ok=True)
            r = {"preset": preset, "n_images": args.n, "seed": args.seed, "samples": args.samples, "denoise": False,
                 "masks": True, "workers": 1, "threads": args.threads, "progress": False}
            if preset == "unityeyes":
                r["label_formats"] = ["eyerig", "unityeyes"]
            params.write_text(yaml.safe_dump({"render": r}))
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "stages.render", str(Path(args.assets) / scan),
                                str(Path(args.build) / scan / "rig"), str(folder), "--metrics",
                                str(base / f"{preset}_{scan}.metrics.json"), "--params", str(params),
                                "--no-progress"], capture_output=True, text=True, timeout=3600, cwd=args.code,
                               env={**os.environ, "PYTHONPATH": str(args.code)})
            case = {"preset": preset, "scan": scan, "rc": p.returncode, "wall_s": time.perf_counter() - t0,
                    "samples": args.samples}
            if p.returncode != 0:
                case["message"] = (p.stderr.strip().splitlines() or [""])[-1]
            rows = _count_render(folder, preset) if folder.is_dir() else []
            case["images"] = len(rows)
            case["images_with_background"] = sum(r["background_px"] > 0 for r in rows)
            case["background_px"] = sum(r["background_px"] for r in rows)
            if any("crop_pixels" in r for r in rows):
                crops = [r for r in rows if "crop_pixels" in r]
                case["crops_with_background"] = sum(r["crop_background_px"] > 0 for r in crops)
                case["crop_background_px"] = sum(r["crop_background_px"] for r in crops)
                case["crop_background_frac_median"] = float(np.median([r["crop_background_px"] / max(r["crop_pixels"], 1)
                                                                       for r in crops]))
                case["crops_inside_image"] = sum(r["crop_inside_image"] for r in crops)
            case["rows"] = rows
            print(json.dumps({k: v for k, v in case.items() if k != "rows"}), flush=True)
            out["cases"].append(case)
    write_results(f"background_{args.tag}", out)
    return out


def report(args) -> None:
    def load(name):
        p = RESULTS / f"{name}.json"
        return json.loads(p.read_text()) if p.is_file() else None

    def merged(tag):
        # ``render --tag before`` and ``--tag before_<more>`` runs of other presets join one table
        parts = [json.loads(p.read_text()) for p in sorted(RESULTS.glob(f"background_{tag}*.json"))]
        if not parts:
            return None
        return {"n_per_case": sorted({x["n_per_case"] for x in parts}), "cases": [c for x in parts for c in x["cases"]]}

    def spp(cases):
        return ", ".join(str(s) for s in sorted({c.get("samples", 1) for c in cases}))

    pred, before, after = load("background_predict"), merged("before"), merged("after")
    wide = load("background_crop")
    summary = {"predict": pred, "before": None, "after": None}
    lines = ["# Background (segmentation class 0) in renders", "",
             "`python -m benchmarks.bench_background predict|render|report` (module doc). Class-0 pixels per",
             "image from the seg masks; the GazeML crop is its UnityEyes loader's (tests/fixtures/gazeml_unityeyes.py).", ""]
    for tag, res in (("before", before), ("after", after)):
        if not res:
            continue
        cases = [{k: v for k, v in c.items() if k != "rows"} for c in res["cases"]]
        summary[tag] = {"n_per_case": res["n_per_case"], "cases": cases,
                        "images": sum(c["images"] for c in cases),
                        "images_with_background": sum(c["images_with_background"] for c in cases),
                        "background_px": sum(c["background_px"] for c in cases)}
        lines += [f"## Rendered, {tag} ({summary[tag]['images']} images, samples {spp(cases)}, no denoising)", "",
                  "| preset | scan | samples | images | with background | class-0 px | GazeML crops with bg | crop bg px | note |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for c in cases:
            lines.append(f"| {c['preset']} | {c['scan']} | {c.get('samples', 1)} | {c['images']} | {c['images_with_background']} | "
                         f"{c['background_px']} | {c.get('crops_with_background', '')} | {c.get('crop_background_px', '')} | "
                         f"{c.get('message', '')[:160]} |")
        lines.append("")
    if pred:
        lines += ["## Predicted by the coverage rasteriser (no render)", "",
                  f"{pred['n']} samples per case; uncovered = the rasteriser's area including its "
                  f"{pred['margin_px']} px safety margin.", "",
                  "| preset | scan | before: images uncovered | median / max frac | GazeML crops uncovered (median frac) "
                  "| after: refused | mean / max attempts | coverage ms/attempt |",
                  "|---|---|---|---|---|---|---|---|"]
        for c in pred["cases"]:
            crop = ""
            if "before_gazeml_crops_uncovered" in c:
                crop = f"{c['before_gazeml_crops_uncovered']} ({c['before_gazeml_crop_uncovered_frac_median']:.3f})"
            att = (f"{c['after_attempts_mean']:.2f} / {c['after_attempts_max']}" if c["after_attempts_mean"] is not None
                   else "-")
            lines.append(f"| {c['preset']} | {c['scan']} | {c['before_images_uncovered']} of {c['before_images']} | "
                         f"{c['before_uncovered_frac_median']:.4f} / {c['before_uncovered_frac_max']:.4f} | {crop} | "
                         f"{c['after_refused']} | {att} | {c['coverage_ms_per_attempt']:.1f} |")
        lines.append("")
    if wide:
        summary["crop"] = wide
        lines += ["## A wider eye region (first attempts whose frame is covered)", "",
                  f"{wide['n']} samples per row, the pupil rule alone (`crop` mode; margins lateral / above / below "
                  "the eye centres, mm; the same 9,000-polygon retopo target, so the skin's edges grow).", "",
                  "| asset | preset | size | frame covered | GazeML crop covered | median skin edge mm |",
                  "|---|---|---|---|---|---|"]
        for r in wide["rows"]:
            g = "" if r["gazeml_crop_covered"] is None else r["gazeml_crop_covered"]
            lines.append(f"| {r['asset']} | {r['preset']} | {r['size'][0]} x {r['size'][1]} | {r['covered']} | {g} | "
                         f"{r['skin_edge_mm']:.2f} |")
        lines.append("")
    write_results("background", summary)
    (RESULTS / "background.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {RESULTS / 'background.md'}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("predict", "render", "crop", "report"))
    ap.add_argument("--n", type=int, default=None)
    ap.add_argument("--scans", nargs="+", default=list(SCANS))
    ap.add_argument("--presets", nargs="+", default=list(PRESETS))
    ap.add_argument("--assets", default=str(ROOT / "rigged_assets"))
    ap.add_argument("--build", default=str(ROOT / "build"))
    ap.add_argument("--tag", default="after")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--samples", type=int, default=1, help="render mode: Cycles samples per pixel")
    ap.add_argument("--tmp", default="/tmp/bench_background")
    ap.add_argument("--pairs", nargs="+", default=[], help="crop mode: NAME ASSETS_DIR BUILD_DIR, repeated")
    ap.add_argument("--code", type=Path, default=ROOT, help="checkout whose stages.render renders (main for --tag before)")
    args = ap.parse_args(argv)
    if args.mode == "predict":
        args.n = args.n or 200
        predict(args)
    elif args.mode == "crop":
        args.n = args.n or 30
        crop(args)
    elif args.mode == "render":
        args.n = args.n or 12
        render(args)
    else:
        report(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
