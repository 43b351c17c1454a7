"""UnityEyes labels through GazeML's loader: iris centre and gaze against our labels.

    .venv/bin/python -m benchmarks.bench_label_formats [--scan synthetic_head] [--images 24]
        [--asset rigged_assets/<scan>] [--rig build/<scan>/rig]

Needs rigged_assets/<scan> and build/<scan>/rig (``dvc repro usd@<scan>``). Renders ``--images``
images with the ``render`` params of params.yaml (less the keys the preset fills) plus
``preset: unityeyes`` and every label format (``python -m stages.render``, into benchmarks/out/label_formats/<scan>), then reads each
``unityeyes/NNNNNN.json`` with the transcription of GazeML's UnityEyes loader
(tests/fixtures/gazeml_unityeyes.py; the image size from the JPEG, as GazeML reads it) and compares:

* iris centre: GazeML's (image centre + 71.7593 px along the look vector) against the centre
  of our 8 iris landmarks (pixels), and against our pupil centre label;
* gaze: GazeML's training gaze (pitch, yaw) as a vector against our camera-frame gaze (degrees);
* eyeball centre: the image centre GazeML assumes against where our eyeball centre projects;
* kept: the images GazeML's head-pose filter keeps (|pitch|, |yaw - 180| <= 20);
* the .pts files reopened against our landmarks.

For contrast, the same through the ``generic`` framing at the same image size (labels sampled,
not rendered: the loader reads only the JSON and the image size). Writes
benchmarks/results/label_formats.json and a picture of the first 4 images with the UnityEyes
points and GazeML's eye crop drawn (benchmarks/results/unityeyes_<scan>.png).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from pipeline.io.atomic import write_json
from pipeline.io.labels_file import read_label
from pipeline.io.pts_file import read_pts
from pipeline.io.unityeyes_file import read_unityeyes
from stages._common import read_stage_metrics
from tests.fixtures.gazeml_unityeyes import gaze_to_camera, read_entry

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
FORMATS = ["eyerig", "unityeyes", "pts"]


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.acos(min(1.0, max(-1.0, a @ b / np.linalg.norm(a) / np.linalg.norm(b)))))


def compare(label: dict, doc: dict, ih: int, iw: int, center_px) -> dict | None:
    """GazeML's reading of one UnityEyes ``doc`` against our ``label`` (None: filtered out)."""
    e = read_entry(doc, ih, iw)
    if e is None:
        return None
    px = np.asarray(label["landmarks"]["px"])
    return {"iris_px": float(np.linalg.norm(e["iris_centre"] - px[12:20].mean(axis=0))),
            "pupil_px": float(np.linalg.norm(e["iris_centre"] - label["landmarks"]["pupil_center_px"])),
            "gaze_deg": _angle_deg(gaze_to_camera(e["gaze"]), label["gaze"]["vector_camera"]),
            "centre_px": float(np.linalg.norm(e["eyeball_centre"] - np.asarray(center_px))),
            "crop_px": [float(e["eye_width"]), float(e["eye_width"] * 36 / 60)]}


def summary(rows: list, n: int) -> dict:
    kept = [r for r in rows if r is not None]
    out = {"images": n, "kept_by_head_pose_filter": len(kept)}
    for k in ("iris_px", "pupil_px", "gaze_deg", "centre_px"):
        v = np.array([r[k] for r in kept])
        out[k] = {"median": round(float(np.median(v)), 5), "max": round(float(v.max()), 5)}
    return out


def _center_px(asset, label) -> list:
    from pipeline.render.formats import unityeyes as uef

    x, y, _ = uef.unity_screen([asset.eyes[label["gaze"]["eye"]].center], label)[0]
    return [float(x), float(label["image"]["height"] - y)]


def generic_contrast(asset, params: dict, n: int) -> dict:
    """The loader on labels of the generic framing at the preset's size (no render)."""
    from pipeline.render.formats import unityeyes as uef
    from pipeline.render import labels as lb
    from pipeline.render.settings import RenderSettings
    from pipeline.render import sampling as sp

    s = RenderSettings.from_params({**params, "preset": "generic", "width": 512, "height": 384,
                                       "eyes": ["left"], "label_formats": ["eyerig"], "n_images": n})   # refused with unityeyes
    rows = []
    for i in range(n):
        smp = sp.make_sample(asset, s, i, "/x.png")
        label = json.loads(json.dumps(lb.make_label(smp, s, asset.name)))
        doc = uef.unityeyes_document(label, uef.points_job(asset, smp))
        rows.append(compare(label, doc, s.height, s.width, _center_px(asset, label)))
    return summary(rows, n)


def picture(out: Path, n: int, path: Path) -> None:
    """The first ``n`` UnityEyes JPEGs, half size, with the points and GazeML's crop drawn."""
    from PIL import Image, ImageDraw

    tiles = []
    for i in range(n):
        doc = read_unityeyes(out / "unityeyes" / f"{i:06d}.json").doc
        im = Image.open(out / "unityeyes" / f"{i:06d}.jpg").convert("RGB")
        ih, iw = im.height, im.width
        d = ImageDraw.Draw(im)

        def pts(key):
            return [(float(x), ih - float(y)) for x, y, _ in
                    (map(float, t.strip("()").split(", ")) for t in doc[key])]

        interior, caruncle, iris = pts("interior_margin_2d"), pts("caruncle_2d"), pts("iris_2d")
        d.line(interior + interior[:1], fill=(0, 255, 0), width=2)
        d.line(iris + iris[:1], fill=(0, 255, 255), width=2)
        for x, y in caruncle:
            d.ellipse([x - 3, y - 3, x + 3, y + 3], fill=(255, 0, 255))
        e = read_entry(doc, ih, iw)
        if e is not None:
            A, b = e["transform"][:2, :2], e["transform"][:2, 2]     # GazeML uses the top two rows
            box = [tuple(np.linalg.solve(A, np.array([x, y]) - b)) for x, y in
                   ((0, 0), (60, 0), (60, 36), (0, 36), (0, 0))]
            d.line(box, fill=(255, 255, 0), width=2)
            cx, cy = e["iris_centre"]
            d.ellipse([cx - 4, cy - 4, cx + 4, cy + 4], outline=(255, 0, 0), width=2)
        tiles.append(im.resize((iw // 2, ih // 2), Image.LANCZOS))
    sheet = Image.new("RGB", (sum(t.width for t in tiles), tiles[0].height))
    x = 0
    for t in tiles:
        sheet.paste(t, (x, 0))
        x += t.width
    sheet.save(path)


def main(argv=None) -> int:
    from PIL import Image

    from pipeline.render import asset as ra

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan", default="synthetic_head")
    ap.add_argument("--images", type=int, default=24)
    ap.add_argument("--asset", type=Path, default=None, help="default rigged_assets/<scan>")
    ap.add_argument("--rig", type=Path, default=None, help="default build/<scan>/rig")
    args = ap.parse_args(argv)
    asset_dir = args.asset or ROOT / "rigged_assets" / args.scan
    rig_dir = args.rig or ROOT / "build" / args.scan / "rig"
    from pipeline.render.settings import PRESETS

    # params.yaml's render block without the keys the preset fills (as the README says to switch)
    params = {k: v for k, v in yaml.safe_load((ROOT / "params.yaml").read_text())["render"].items()
              if k not in PRESETS["unityeyes"]}
    params = {**params, "preset": "unityeyes", "label_formats": FORMATS, "n_images": args.images,
              "progress": False}
    out = ROOT / "benchmarks" / "out" / "label_formats" / args.scan
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    pfile = out.parent / f"{args.scan}.params.yaml"
    pfile.write_text(yaml.safe_dump({"render": params}))
    metrics = out.parent / f"{args.scan}.metrics.json"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "stages.render", str(asset_dir), str(rig_dir), str(out),
                        "--metrics", str(metrics), "--params", str(pfile), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"stage failed:\n{r.stderr[-3000:]}")
    m = read_stage_metrics(metrics)
    asset = ra.load_render_asset(asset_dir, rig_dir)
    rows, pts_err = [], 0.0
    for i in range(args.images):
        label = read_label(out / f"{i:06d}.json").doc
        ue = read_unityeyes(out / "unityeyes" / f"{i:06d}.json")
        with Image.open(out / "unityeyes" / f"{i:06d}.jpg") as im:
            iw, ih = im.size
        rows.append(compare(label, ue.doc, ih, iw, _center_px(asset, label)))
        pts_err = max(pts_err, float(np.abs(read_pts(out / f"{i:06d}.pts") - 0.5 - label["landmarks"]["px"]).max()))
    crops = np.array([r["crop_px"] for r in rows if r is not None])
    res = {"scan": args.scan, "cpu_count": os.cpu_count(),
           "settings": {k: params.get(k) for k in ("preset", "samples", "denoise", "label_formats")},
           "size": m["size"], "stage_wall_s": round(wall, 2), "s_per_image": round(wall / args.images, 3),
           "unityeyes_preset": summary(rows, args.images),
           "gazeml_crop_px": {"width": [round(float(crops[:, 0].min()), 1), round(float(crops[:, 0].max()), 1)],
                              "height": [round(float(crops[:, 1].min()), 1), round(float(crops[:, 1].max()), 1)]},
           "pts_max_abs_error_px": pts_err,
           "generic_framing_same_size_sampled": generic_contrast(asset, params, args.images),
           "what": "GazeML UnityEyes loader (tests/fixtures/gazeml_unityeyes.py) on our unityeyes JSON vs our labels"}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_json(RESULTS / "label_formats.json", res)
    picture(out, min(4, args.images), RESULTS / f"unityeyes_{args.scan}.png")
    print(json.dumps({k: res[k] for k in ("unityeyes_preset", "generic_framing_same_size_sampled",
                                          "s_per_image")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
