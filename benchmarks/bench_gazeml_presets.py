"""GazeML's UnityEyes loader on each preset's labels (no render): why only ``unityeyes`` is allowed.

    .venv/bin/python -m benchmarks.bench_gazeml_presets [--images 24] [--scans synthetic_head ict_neutral james]
        [--root .]

For each scan (``rigged_assets/<scan>``, ``build/<scan>/rig`` under ``--root``) and preset, samples
``--images`` labels, builds their UnityEyes documents (:func:`pipeline.render.formats.unityeyes.points_job`:
the writer's points without its crop check) and reads them with the transcription of GazeML's
loader (tests/fixtures/gazeml_unityeyes.py, head-pose filter off so every sample counts). Prints, per
preset, the loader's iris centre against ours (px; a right eye mirrored, as the export writes
it), its gaze against ours (deg) and how many of its crops leave the image.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    from tests.fixtures import gazeml_unityeyes as gz
    from pipeline.render import asset as ra
    from pipeline.render import labels as lb
    from pipeline.render import sampling as sp
    from pipeline.render.formats import unityeyes as uef
    from pipeline.render.settings import RenderSettings

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=24)
    ap.add_argument("--scans", nargs="+", default=["synthetic_head", "ict_neutral", "james"])
    ap.add_argument("--root", type=Path, default=ROOT)
    args = ap.parse_args(argv)
    assets = {s: ra.load_render_asset(args.root / "rigged_assets" / s, args.root / "build" / s / "rig")
              for s in args.scans}
    out = {}
    for preset in ("generic", "targeted", "unityeyes"):
        s = RenderSettings.from_params({"preset": preset, "eyes": ["left", "right"]})
        rows = []
        for name, a in assets.items():
            for i in range(args.images):
                smp = sp.make_sample(a, s, i, "/x.png", cover=False)   # labels only: the home scans cannot fill unityeyes
                label = json.loads(json.dumps(lb.make_label(smp, s, name)))
                doc = uef.unityeyes_document(label, uef.points_job(a, smp))
                e = gz.read_entry({**doc, "head_pose": "(0.0, 180.0, 0.0)"}, s.height, s.width)
                pts = {k: np.array([[float(v) for v in t.strip("()").split(", ")] for t in doc[k]])
                       for k in ("interior_margin_2d", "caruncle_2d")}
                x0, y0, x1, y1 = uef.gazeml_crop(pts["interior_margin_2d"], pts["caruncle_2d"])
                flip = label["gaze"]["eye"] == "right"
                iris = np.asarray(label["landmarks"]["px"])[12:20].mean(0)
                g = np.asarray(label["gaze"]["vector_camera"])
                if flip:
                    iris, g = np.array([s.width - iris[0], iris[1]]), g * [-1, 1, 1]
                v = gz.gaze_to_camera(e["gaze"])
                rows.append((np.linalg.norm(e["iris_centre"] - iris), np.degrees(np.arccos(min(1.0, v @ g))),
                             x0 < 0 or y0 < 0 or x1 > s.width or y1 > s.height, x1 - x0))
        r = np.array(rows, float)
        out[preset] = {"samples": len(r), "iris_px_median": round(float(np.median(r[:, 0])), 4),
                       "iris_px_max": round(float(r[:, 0].max()), 4), "gaze_deg_max": round(float(r[:, 1].max()), 4),
                       "crop_outside": int(r[:, 2].sum()),
                       "crop_width_px": [round(float(r[:, 3].min()), 1), round(float(r[:, 3].max()), 1)]}
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
