"""Eye proportions in the render labels: visible iris diameter / canthus distance, per scan.

    .venv/bin/python -m benchmarks.bench_proportions [--scans synthetic_head ict_neutral james]
        [--samples 400] [--params params.yaml]

On real portraits the iris is about 0.39 of the corner-to-corner eye width (0.35-0.40; the
iris about 11.7 mm across, the opening about 28-30 mm). For every scan with an asset
(``rigged_assets/<s>/`` and ``build/<s>/rig/``), in pixels of each label:

* iris diameter: the major axis of the ellipse through the 8 iris landmarks (landmark k at
  45 deg * k on the iris circle, so the ellipse is exact: an orthographic image of a circle;
  its major axis is the diameter whatever the view);
* canthus distance: landmark 0 (medial canthus) to landmark 6 (lateral canthus);

the ratio's median and 5-95 % range over ``--samples`` samples drawn exactly as the render
stage draws its images (``pipeline.render.sampling.make_sample`` with the ``render:`` settings,
sample i = image i, no Blender needed), and over the labels of the stage's own images in
``renders/<s>/`` when they exist. Also in mm: the iris diameter and the canthus distance in the
image (px times mm per px), the eye's fitted radius and the rest canthus distance in 3D.
Target (issue 14): the median ratio in 0.35-0.43 on every home scan.

Where the scan folder (``raw_scans/<s>/``) holds the truth of its eye corners, the rest canthus
landmarks are compared with it, per eye, in mm (``truth`` in the JSON): ``ground_truth.json``
``eyes.<side>.eyelid_margin`` (synthetic heads and scanify heads: the margin loop's
``medial_canthus_index`` / ``lateral_canthus_index`` points), or 68-point annotations
``*_landmarks68.npy`` + ``*_landmarks68_groups.json`` (menpo's groups, as ``james`` ships them:
``reye`` = the subject's left eye; its corners are the group's points farthest toward and away
from the midline). Only a scan whose ``scan.yaml`` already is in mm and the head frame is compared
(the truth is in scan coordinates). ``iris_over_true_corners`` is the median iris diameter over
the true corner distance: the ratio the labels would give with exact canthus landmarks. The
asset's own doubts (``eyes.<side>.doubts`` in its metadata, from remove_eyeballs) are listed
beside its figures (``doubts`` in the JSON). Writes
``benchmarks/results/proportions.json`` and prints a table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json
from tests.fixtures.truth import iris_diameter, truth_corners

ROOT = Path(__file__).resolve().parents[1]
TARGET = (0.35, 0.43)

def measure(px, mm_per_px: float) -> dict:
    """Ratio, iris diameter and canthus distance (px and mm) of one label's 28 landmarks."""
    px = np.asarray(px, float)
    iris = iris_diameter(px[12:20])
    canthus = float(np.linalg.norm(px[0] - px[6]))
    return {"ratio": iris / canthus, "iris_mm": iris * mm_per_px, "canthus_mm": canthus * mm_per_px}


def stats(rows: list[dict]) -> dict:
    out = {"n": len(rows)}
    for key in ("ratio", "iris_mm", "canthus_mm"):
        a = np.array([r[key] for r in rows])
        out[key] = {"median": float(np.median(a)), "p5": float(np.percentile(a, 5)),
                    "p95": float(np.percentile(a, 95)), "min": float(a.min()), "max": float(a.max())}
    out["meets_target"] = bool(TARGET[0] <= out["ratio"]["median"] <= TARGET[1])
    return out


def sampled(asset, settings, n: int) -> list[dict]:
    from pipeline.render import camera as cam
    from pipeline.render import sampling as sp

    rows = []
    for i in range(n):
        smp = sp.make_sample(asset, settings, i, sp.png_name(i))
        ow, _ = cam.ortho_size(smp.camera["ortho_scale_mm"], settings.width, settings.height)
        rows.append(measure(smp.landmarks_px, ow / settings.width))
    return rows


def rendered(folder: Path) -> list[dict]:
    from pipeline.io.labels_file import read_label

    rows = []
    for path in sorted(folder.glob("[0-9]" * 6 + ".json")):
        lab = read_label(path)
        rows.append(measure(lab.px, float(lab.doc["camera"]["mm_per_px"])))
    return rows


def rest_geometry(asset) -> dict:
    """Per eye: fitted radius, rest iris diameter and rest canthus distance in 3D (mm)."""
    from pipeline.render import asset as ra

    out = {}
    for side, eye in asset.eyes.items():
        lm = ra.posed_landmarks(asset, side, {}, {}, np.eye(3))
        B = eye.basis
        out[side] = {"radius_mm": eye.radius,
                     "iris_diameter_mm": iris_diameter((lm[12:20] - eye.center) @ B[:2].T),
                     "canthus_distance_mm": float(np.linalg.norm(lm[0] - lm[6]))}
    return out


def truth_errors(asset, corners: dict, iris_mm: float) -> dict:
    """Per eye: rest landmarks 0 / 6 against the true corners (mm) and the true corner distance."""
    from pipeline.render import asset as ra

    out = {"source": corners["source"]}
    for side in asset.eyes:
        lm = ra.posed_landmarks(asset, side, {}, {}, np.eye(3))
        med, lat = corners[side]["medial"], corners[side]["lateral"]
        true_d = float(np.linalg.norm(med - lat))
        out[side] = {"medial_error_mm": float(np.linalg.norm(lm[0] - med)),
                     "lateral_error_mm": float(np.linalg.norm(lm[6] - lat)),
                     "true_canthus_distance_mm": true_d,
                     "rest_canthus_distance_mm": float(np.linalg.norm(lm[0] - lm[6])),
                     "iris_over_true_corners": iris_mm / true_d}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", nargs="+", default=["synthetic_head", "ict_neutral", "james"])
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--params", type=Path, default=ROOT / "params.yaml")
    args = ap.parse_args(argv)
    import yaml

    from pipeline.render.asset import load_render_asset
    from pipeline.render.settings import RenderSettings

    params = yaml.safe_load(args.params.read_text(encoding="utf-8")) or {}
    settings = RenderSettings.from_params(params.get("render"), source=str(args.params))
    result = {"target_median_ratio": list(TARGET), "samples": args.samples,
              "definition": "iris diameter = major axis of the ellipse through the 8 iris landmarks; "
                            "canthus distance = landmark 0 to landmark 6; both in pixels of a label",
              "scans": {}}
    print(f"{'scan':16s} {'ratio median (p5-p95)':>24s} {'renders':>8s} {'iris mm':>8s} {'canthus mm':>10s}"
          f"  fitted radius, rest canthus 3D")
    for scan in args.scans:
        asset_dir, rig_dir = ROOT / "rigged_assets" / scan, ROOT / "build" / scan / "rig"
        if not (asset_dir.is_dir() and rig_dir.is_dir()):
            print(f"{scan:16s} skipped: no {asset_dir.relative_to(ROOT)} or {rig_dir.relative_to(ROOT)}")
            continue
        asset = load_render_asset(asset_dir, rig_dir)
        entry = {"sampled": stats(sampled(asset, settings, args.samples)), "rest": rest_geometry(asset)}
        labels = rendered(ROOT / "renders" / scan)
        if labels:
            entry["renders"] = stats(labels)
        corners = truth_corners(ROOT / "raw_scans" / scan)
        if corners is not None:
            entry["truth"] = truth_errors(asset, corners, entry["sampled"]["iris_mm"]["median"])
        eyes_meta = asset.metadata.get("eyes") or {}
        entry["doubts"] = {side: list((eyes_meta.get(side) or {}).get("doubts") or []) for side in asset.eyes}
        result["scans"][scan] = entry
        s, r = entry["sampled"], entry.get("renders")
        rest = ", ".join(f"{k[0].upper()} {v['radius_mm']:.1f} / {v['canthus_distance_mm']:.1f}"
                         for k, v in entry["rest"].items())
        print(f"{scan:16s} {s['ratio']['median']:>8.3f} ({s['ratio']['p5']:.2f}-{s['ratio']['p95']:.2f}) "
              f"{'':5s}{r['ratio']['median'] if r else float('nan'):>8.3f} {s['iris_mm']['median']:>8.2f} "
              f"{s['canthus_mm']['median']:>10.2f}  {rest} mm")
        if "truth" in entry:
            t = entry["truth"]
            print(f"{'':16s} vs {t['source']}: " + "; ".join(
                f"{k[0].upper()} medial {v['medial_error_mm']:.2f} / lateral {v['lateral_error_mm']:.2f} mm off, "
                f"true {v['true_canthus_distance_mm']:.1f} mm (iris / true {v['iris_over_true_corners']:.3f})"
                for k, v in t.items() if k != "source"))
        for side, doubts in entry["doubts"].items():
            for d in doubts:
                print(f"{'':16s} doubted by the pipeline, {side} eye: {d}")
    out = ROOT / "benchmarks" / "results" / "proportions.json"
    write_json(out, result)
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
