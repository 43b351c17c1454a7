"""Issue 33's measurements: framing, stable growth, the normalised export and the splits.

    python -m benchmarks.bench_dataset_lab --assets A ... --rigs R ... \\
        [--generic DIR] [--targeted DIR] [--grown-from-sha SHA.txt] [--sample-generic 1000] [--sample-targeted 200]

* **Framing, from the sampler** (no render; the labels a render writes are these samples, and
  the render's landmark check holds them to the image within ``landmark_tolerance_mm``): the
  first ``--sample-generic`` / ``--sample-targeted`` images of a dataset of the assets, with
  ``frame_margin_px`` 3 (now) and unset (before): images with a landmark outside the frame, the
  lateral (6) and medial (0) canthus outside, the smallest margin.
* **The mix before and after**: of ``n`` images, how many keep their asset when ``n`` changes
  (60 -> 50, 60 -> 1,000) under the old n-dependent mix and the quota sequence.
* **Rendered datasets** (``--generic``, ``--targeted``, ``--webcam``: folders the dataset command wrote with
  label formats ``eyerig, normalized``): landmarks outside in the labels, the card's count,
  every normalised label's warped landmarks against the virtual camera's formula (max px; for a
  pinhole camera also against ETH-XGaze's ``normalizeData`` lines transcribed here), and
  the splits (no identity twice). ``--grown-from-sha``: ``sha256sum`` lines of the generic
  folder's image files taken before it grew; the same files now must be byte-identical.

Writes ``benchmarks/results/dataset_lab.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.results_files import write_results


def _margin(px, w, h) -> np.ndarray:
    px = np.asarray(px, float)
    return np.min([px[:, 0], w - px[:, 0], px[:, 1], h - px[:, 1]], axis=0)


def sampled_framing(assets, preset: str, n: int, margin) -> dict:
    from pipeline.render import mix
    from pipeline.render import sampling as sp
    from pipeline.render.settings import RenderSettings

    s = RenderSettings.from_params({"preset": preset, "frame_margin_px": margin})
    assign = mix.assign(n, [1.0] * len(assets), s.seed)
    bad, lateral, medial, worst = 0, 0, 0, np.inf
    t0 = time.perf_counter()
    for i in range(n):
        smp = sp.make_sample(assets[int(assign[i])], s, i, "/x.png")
        m = _margin(smp.landmarks_px, s.width, s.height)
        bad += bool((m < 0).any())
        lateral += bool(m[6] < 0)
        medial += bool(m[0] < 0)
        worst = min(worst, float(m.min()))
    return {"images": n, "with_a_landmark_outside": bad, "lateral_canthus_outside": lateral,
            "medial_canthus_outside": medial, "min_margin_px": round(worst, 3),
            "sampling_s_per_image": round((time.perf_counter() - t0) / n, 4)}


def mix_kept(n0: int, n1: int, k: int = 5) -> dict:
    from pipeline.render import mix

    w = [1.0] * k
    old0, old1 = mix.assign_legacy(n0, w, 0), mix.assign_legacy(n1, w, 0)
    new0, new1 = mix.assign(n0, w, 0), mix.assign(n1, w, 0)
    m = min(n0, n1)
    return {"from": n0, "to": n1, "kept_before": int(np.count_nonzero(old0[:m] == old1[:m])),
            "kept_after": int(np.count_nonzero(new0[:m] == new1[:m])), "of": m}


def eth_xgaze_warp(label: dict, e_cv, focal_norm: float, distance_norm: float, roi) -> np.ndarray:
    """ETH-XGaze's ``normalizeData`` W (xucong-zhang/data-preprocessing-gaze), its lines in numpy,
    for a pinhole label: an independent check of pipeline/render/normalize.py."""
    hR = np.asarray(label["conventions"]["eth_xgaze"]["head_rotation_opencv"])
    cam = np.asarray(label["camera"]["intrinsics"]["K_pixel_centres_at_integers"])
    distance = np.linalg.norm(e_cv)
    cam_norm = np.array([[focal_norm, 0, roi[0] / 2], [0, focal_norm, roi[1] / 2], [0, 0, 1.0]])
    S = np.diag([1.0, 1.0, distance_norm / distance])
    forward = (np.asarray(e_cv) / distance).reshape(3)
    down = np.cross(forward, hR[:, 0])
    down /= np.linalg.norm(down)
    right = np.cross(down, forward)
    right /= np.linalg.norm(right)
    R = np.c_[right, down, forward].T
    return cam_norm @ S @ R @ np.linalg.inv(cam)


def rendered(folder: Path) -> dict:
    from pipeline.render import normalize as nz

    index = folder / "index.jsonl"
    if index.is_file():
        rows = [json.loads(line) for line in index.read_text().splitlines()]
    else:                                    # a run still going (or killed): its finished labels
        rows = [{"json": p.name, "asset": json.loads(p.read_text())["asset"]["name"]}
                for p in sorted(folder.glob("[0-9]" * 6 + ".json"))]
    outside, worst, norm_err, n_norm, centred, eth_err = 0, np.inf, 0.0, 0, None, None
    for r in rows:
        lab = json.loads((folder / r["json"]).read_text())
        m = _margin(lab["landmarks"]["px"], lab["image"]["width"], lab["image"]["height"])
        outside += int((m < 0).sum())
        worst = min(worst, float(m.min()))
        p = folder / "normalized" / r["json"]
        if p.is_file():
            doc = json.loads(p.read_text())
            n = nz.normalization(lab, (doc["image"]["width"], doc["image"]["height"]),
                                 doc["virtual_camera"]["focal_px"], doc["virtual_camera"]["distance_mm"])
            want = nz.project_normalized(lab["landmarks"]["camera_mm"], n)
            norm_err = max(norm_err, float(np.abs(np.asarray(doc["landmarks"]["px"]) - want).max()))
            n_norm += 1
            if lab["camera"]["type"] == "pinhole":       # ETH-XGaze's own lines, cv2.perspectiveTransform
                W = eth_xgaze_warp(lab, doc["center"]["opencv_mm"], doc["virtual_camera"]["focal_px"],
                                   doc["virtual_camera"]["distance_mm"], (doc["image"]["width"], doc["image"]["height"]))
                P = np.c_[np.asarray(lab["landmarks"]["px"]) - 0.5, np.ones(28)] @ W.T
                eth_err = max(eth_err or 0.0, float(np.abs(P[:, :2] / P[:, 2:] + 0.5 - np.asarray(doc["landmarks"]["px"])).max()))
            # the most nearly centred gaze: its pupil centre's distance from the crop's principal point
            ang = float(np.degrees(np.arccos(-doc["gaze"]["vector_opencv"][2])))
            if centred is None or ang < centred["gaze_off_axis_deg"]:
                pupil = np.asarray(doc["landmarks"]["px"])[20:28].mean(0)
                centred = {"image": r["json"][:6], "gaze_off_axis_deg": round(ang, 3),
                           "pupil_centre_px": [round(float(x), 3) for x in pupil],
                           "principal_point_px": doc["center"]["px"],
                           "offset_px": round(float(np.linalg.norm(pupil - doc["center"]["px"])), 3)}
    out = {"images": len(rows), "finished": index.is_file(), "landmarks_outside": outside,
           "min_margin_px": round(worst, 3), "normalized_labels": n_norm, "normalized_max_error_px": norm_err,
           "eth_xgaze_formula_max_error_px": eth_err, "most_centred_gaze": centred}
    if not index.is_file():
        return out
    info = json.loads((folder / "dataset.json").read_text())
    sp = json.loads((folder / "splits" / "splits.json").read_text())
    owners = {}
    for s in ("train", "val", "test"):
        for line in (folder / "splits" / f"{s}.txt").read_text().splitlines():
            owners.setdefault(rows[int(line[:6])]["asset"], set()).add(s)
    timings = json.loads((folder / "timings.json").read_text())
    return {**out, "card_landmarks_inside": info["statistics"]["landmarks_inside"],
            "splits": {"assets": sp["assets"], "images": sp["images"],
                       "identities_in_two_splits": sorted(a for a, s in owners.items() if len(s) > 1)},
            "per_asset": timings.get("counts"), "last_run": {k: timings.get(k) for k in
                                                            ("rendered", "skipped_done", "removed_files",
                                                             "s_per_image", "wall_s")}}


def grown(folder: Path, sha_file: Path) -> dict:
    before = dict(reversed(line.split(None, 1)) for line in sha_file.read_text().splitlines())
    same = sum(1 for name, h in before.items()
               if hashlib.sha256((folder / name.strip()).read_bytes()).hexdigest() == h)
    n_imgs = len({Path(name).name[:6] for name in before})
    return {"files_before": len(before), "byte_identical_now": same, "images_before": n_imgs}


def main(argv=None) -> int:
    from pipeline.render.asset import load_render_asset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--assets", nargs="+", required=True)
    ap.add_argument("--rigs", nargs="+", required=True)
    ap.add_argument("--generic", type=Path)
    ap.add_argument("--targeted", type=Path)
    ap.add_argument("--webcam", type=Path, help="a pinhole dataset: its warps against ETH-XGaze's own lines")
    ap.add_argument("--grown-from-sha", type=Path)
    ap.add_argument("--sample-generic", type=int, default=1000)
    ap.add_argument("--sample-targeted", type=int, default=200)
    ap.add_argument("--name", default="dataset_lab")
    args = ap.parse_args(argv)
    assets = [load_render_asset(a, r) for a, r in zip(args.assets, args.rigs)]
    out = {"assets": [a.name for a in assets], "framing_sampled": {}}
    for preset, n in (("generic", args.sample_generic), ("targeted", args.sample_targeted)):
        if n <= 0:                          # 0: only the rendered folders
            continue
        out["framing_sampled"][preset] = {"after": sampled_framing(assets, preset, n, 3.0),
                                          "before": sampled_framing(assets, preset, n, None)}
        print(preset, out["framing_sampled"][preset], flush=True)
    out["mix_kept"] = [mix_kept(60, 50), mix_kept(60, 1000), mix_kept(200, 300)]
    for name in ("generic", "targeted", "webcam"):
        folder = getattr(args, name)
        if folder is not None:
            out[f"rendered_{name}"] = rendered(folder)
            print(name, out[f"rendered_{name}"], flush=True)
    if args.grown_from_sha is not None:
        out["growth"] = grown(args.generic, args.grown_from_sha)
        print(out["growth"])
    write_results(args.name, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
