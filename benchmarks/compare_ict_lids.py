"""Compare our automatic eyelid shapes with ICT-FaceKit's eyeLookUp/eyeLookDown on the ICT head.

    EYERIG_EXTRA_SCANS=/work/shared/scans .venv/bin/python -m benchmarks.compare_ict_lids

Builds our lid rig on the neutral ICT-FaceKit skin (face + head_neck parts, mm),
with the eyeball spheres and eyelid-margin loops of ``ict_neutral/ground_truth.json``
(margin vertices projected radially onto the eyeball sphere first, as the snap stage
does), and compares the displacement of the upper- and lower-lid margin points at
pitch +25 deg (lids_up, weight 1) and -25 deg (lids_down, weight 1) with ICT's
``eyeLookUp_<L|R>`` / ``eyeLookDown_<L|R>`` at weight 1, taking weight 1 = 25 deg
(the assumption stated in the task; ICT/ARKit do not define an angle).
Writes benchmarks/results/ict_lids.json and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json
from pipeline.rig import lids
from pipeline.rig.eye_frame import EyeFrame, rotate_about_axis
from pipeline.rig.lid_shapes import build_lid_shapes, canthus_taper
from pipeline.rig.sweep import sweep_check

ROOT = Path(__file__).resolve().parents[1]

SIDES = {"left": "L", "right": "R"}


def load_ict(scans: Path):
    import trimesh

    kit = scans / "ict_facekit"
    modes = np.load(kit / "ict_shape_modes.npz")
    names = [str(n) for n in modes["expression_names"]]
    neutral = modes["neutral"].astype(np.float64) * 10.0
    parts = json.loads((kit / "ict_parts_vertex_ranges_inclusive.json").read_text())
    last_skin = parts["head_neck"][1]
    tri = trimesh.load(kit / "ict_neutral_full_tri.ply", process=False)
    F = np.asarray(tri.faces, np.int64)
    F = F[(F <= last_skin).all(axis=1)]
    used = np.unique(F)
    remap = np.full(len(neutral), -1)
    remap[used] = np.arange(len(used))
    gt = json.loads((scans / "ict_neutral" / "ground_truth.json").read_text())
    deltas = {}
    for side, s in SIDES.items():
        for kind in ("Up", "Down"):
            deltas[(side, kind)] = modes["expression_deltas"][names.index(f"eyeLook{kind}_{s}")][used] * 10.0
    return neutral[used], remap[F], remap, gt, deltas


def stats(a):
    a = np.asarray(a, float)
    return {"mean": float(a.mean()), "max": float(a.max())}


def margin_motion(V, eye, gain_upper, gain_lower, pitch_deg, width, exponent):
    """Margin displacement of one eye for given gains (what the rig does at the margin)."""
    loop, li = eye.loop, eye.lateral_index
    x = (V[loop] - eye.center) @ eye.basis()[0]
    u = np.clip((x - x[0]) / (x[li] - x[0]), 0, 1)
    taper = canthus_taper(u, width, exponent)
    taper[[0, li]] = 0.0
    gain = np.full(len(loop), float(gain_lower))
    gain[1:li] = gain_upper
    th = np.radians(pitch_deg) * gain * taper
    return rotate_about_axis(V[loop], eye.center, eye.axis, th) - V[loop]


def fit_gains(V, eyes, deltas):
    """Gains and canthus width that best match ICT's margin motion (grid search, mean |diff|)."""
    best = None
    gains = np.round(np.arange(0.0, 1.0001, 0.02), 2)
    for width in (0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5):
        fitted, total = {}, 0.0
        for key, pitch, kind, lid in (("gain_upper_up", 25, "Up", "upper"),
                                      ("gain_upper_down", -25, "Down", "upper"),
                                      ("gain_lower_up", 25, "Up", "lower"),
                                      ("gain_lower_down", -25, "Down", "lower")):
            errs = []
            for g in gains:
                err = 0.0
                for e in eyes:
                    li = e.lateral_index
                    sel = np.arange(1, li) if lid == "upper" else np.arange(li + 1, len(e.loop))
                    ours = margin_motion(V, e, g, g, pitch, width, 1.0)[sel]
                    err += np.linalg.norm(ours - deltas[(e.side, kind)][e.loop[sel]], axis=1).mean()
                errs.append(err / len(eyes))
            k = int(np.argmin(errs))
            fitted[key] = float(gains[k])
            total += errs[k]
        if best is None or total < best[0]:
            best = (total, width, fitted)
    return {"canthus_width": best[1], **best[2]}


def compare(Vs, F, eyes, deltas, params, corneas=None):
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        rig = build_lid_shapes(Vs, F, eyes, params)
        times.append(time.perf_counter() - t0)
    pitches = np.arange(-25.0, 25.0 + 1e-9, 0.5)
    sweep = sweep_check(Vs, F, eyes, rig.shapes, pitches, corneas=corneas)
    result = {"n_segments": rig.n_segments, "build_s_median": float(np.median(times)),
              "sweep": sweep, "params": {k: getattr(params, k) for k in params.__dataclass_fields__},
              "eyes": {}}
    for e in eyes:
        li = e.lateral_index
        lids_idx = {"upper": e.loop[1:li], "lower": e.loop[li + 1:]}
        up_axis = e.basis()[1]
        per = {}
        for pitch, name, kind in ((25.0, lids.SHAPE_UP, "Up"), (-25.0, lids.SHAPE_DOWN, "Down")):
            ours = lids.evaluate_shapes(Vs, rig.shapes, lids.lid_weights(pitch)) - Vs
            ict = deltas[(e.side, kind)]
            for lid, idx in lids_idx.items():
                diff = np.linalg.norm(ours[idx] - ict[idx], axis=1)
                per[f"{pitch:+.0f}deg_{lid}"] = {
                    "ours_displacement_mm": stats(np.linalg.norm(ours[idx], axis=1)),
                    "ict_displacement_mm": stats(np.linalg.norm(ict[idx], axis=1)),
                    "ours_vertical_mean_mm": float((ours[idx] @ up_axis).mean()),
                    "ict_vertical_mean_mm": float((ict[idx] @ up_axis).mean()),
                    "difference_mm": stats(diff),
                }
            moved = (np.linalg.norm(ours, axis=1) > 1e-3) | (np.linalg.norm(ict, axis=1) > 1e-3)
            near = np.linalg.norm(Vs - e.center, axis=1) < 40.0
            m = moved & near
            per[f"{pitch:+.0f}deg_region_rms_difference_mm"] = float(
                np.sqrt(np.mean(np.sum((ours[m] - ict[m]) ** 2, axis=1))))
        result["eyes"][e.side] = per
    return result


def report(title, result):
    sw = result["sweep"]
    print(f"== {title}: build {result['build_s_median']:.2f} s (median of 3), {result['n_segments']} "
          f"poses/direction; sweep -25..25 step 0.5: gap {sw['max_gap_mm']:.3f} mm, penetration "
          f"{sw['max_penetration_mm']:.3f} mm, flipped {sw['flipped_faces']}, min opening "
          f"{sw['min_opening_mm']:.2f} mm; cornea pokes past the margin by up to "
          f"{sw['max_cornea_intrusion_mm']:.2f} mm (rest {sw['rest_cornea_intrusion_mm']:.2f} mm)")
    for side, per in result["eyes"].items():
        for key, v in per.items():
            if isinstance(v, dict):
                print(f"{side:5s} {key:14s} |d| mean/max ours {v['ours_displacement_mm']['mean']:.2f}/"
                      f"{v['ours_displacement_mm']['max']:.2f} ICT {v['ict_displacement_mm']['mean']:.2f}/"
                      f"{v['ict_displacement_mm']['max']:.2f}; dy ours {v['ours_vertical_mean_mm']:+.2f} "
                      f"ICT {v['ict_vertical_mean_mm']:+.2f}; |ours-ICT| mean/max "
                      f"{v['difference_mm']['mean']:.2f}/{v['difference_mm']['max']:.2f} mm")
            else:
                print(f"{side:5s} {key}: {v:.2f} mm")


def draw_figure(path, Vs, F, eyes, deltas, params):
    """Front view of the left eye's margin: rest, ours and ICT at +-25 deg (PNG)."""
    from PIL import Image, ImageDraw

    e = next(e for e in eyes if e.side == "left")
    rig = build_lid_shapes(Vs, F, eyes, params)
    B = e.basis()
    curves = {"rest": Vs[e.loop]}
    for pitch, name, kind in ((25.0, lids.SHAPE_UP, "Up"), (-25.0, lids.SHAPE_DOWN, "Down")):
        curves[f"ours {pitch:+.0f}"] = lids.evaluate_shapes(Vs, rig.shapes, {name: 1.0})[e.loop]
        curves[f"ICT {pitch:+.0f}"] = Vs[e.loop] + deltas[(e.side, kind)][e.loop]
    colours = {"rest": (90, 90, 90), "ours +25": (30, 90, 220), "ICT +25": (120, 190, 255),
               "ours -25": (210, 40, 40), "ICT -25": (255, 160, 60)}
    Q = {k: (v - e.center) @ B[:2].T for k, v in curves.items()}
    allq = np.concatenate(list(Q.values()))
    lo, hi = allq.min(0) - 2, allq.max(0) + 2
    scale = 760 / (hi[0] - lo[0])
    W, H = 800, int((hi[1] - lo[1]) * scale) + 80
    img = Image.new("RGB", (W, H), "white")
    d = ImageDraw.Draw(img)
    for k, q in Q.items():
        xy = [(20 + (x - lo[0]) * scale, 60 + (hi[1] - y) * scale) for x, y in q]
        d.line(xy + xy[:1], fill=colours[k], width=3 if k.startswith("ours") or k == "rest" else 2)
    for i, k in enumerate(Q):
        d.text((20 + 150 * i, 10), k, fill=colours[k])
    d.text((20, 30), "left eye margin, front view (eye frame), 1 px = %.3f mm" % (1 / scale),
           fill=(0, 0, 0))
    img.save(path)


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    scans = Path(os.environ.get("EYERIG_EXTRA_SCANS", ROOT.parent / "shared" / "scans"))
    V, F, remap, gt, deltas = load_ict(scans)
    eyes = []
    Vs = V.copy()
    for side in SIDES:
        e = gt["eyes"][side]
        loop = remap[np.asarray(e["eyelid_margin"]["ict_vertex_ids"])]
        assert (loop >= 0).all()
        c = np.asarray(e["eyeball_sphere"]["center_mm"], float)
        r = float(e["eyeball_sphere"]["radius_mm"])
        w = Vs[loop] - c
        Vs[loop] = c + r * w / np.linalg.norm(w, axis=1, keepdims=True)
        eyes.append(EyeFrame(side=side, center=c, radius=r,
                             forward=np.asarray(e["gaze_direction"], float), loop=loop,
                             lateral_index=int(e["eyelid_margin"]["lateral_canthus_index"])))
    corneas = {side: (np.asarray(gt["eyes"][side]["cornea_sphere"]["center_mm"], float),
                      float(gt["eyes"][side]["cornea_sphere"]["radius_mm"])) for side in SIDES}
    default = compare(Vs, F, eyes, deltas, lids.LidParams(), corneas)
    fitted_params = fit_gains(Vs, eyes, deltas)
    fitted = compare(Vs, F, eyes, deltas, lids.LidParams(**fitted_params), corneas)
    result = {"assumption": "ICT eyeLook weight 1 = 25 deg pitch", "n_vertices": int(len(V)),
              "default_params": default, "ict_fitted_params": {"fitted": fitted_params, **fitted}}
    out = ROOT / "benchmarks" / "results" / "ict_lids.json"
    write_json(out, result)
    draw_figure(out.with_suffix(".png"), Vs, F, eyes, deltas, lids.LidParams())
    report("default params", default)
    report(f"gains fitted to ICT {fitted_params}", fitted)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
