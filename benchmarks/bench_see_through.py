"""See-through and hidden irises in assets, from geometry: no render, every view of the previews.

    .venv/bin/python -m benchmarks.bench_see_through [NAME=ASSET_DIR:RIG_DIR ...] [--home]
        [--unseen WORK] [--results benchmarks/results] [--out see_through]

Issue 29 asks that no render see through an opening and that no asset's iris be hidden behind
the lids or turned into a corner at rest. A render sees through where a ray crossing the opening
meets neither the eyeball nor skin: the eye-region crop is one open sheet, so past the opening
lies background. Per asset and eye this rasterises (``pipeline.render.coverage``, the sampler's
own coverage test: posed skin triangles, back faces included, and the eyeball's silhouette) what
orthographic cameras see of the posed opening (the corneal cap, turned with the gaze,
included: a margin may rest on it), for

* gaze pitch -25, 0 and +25 deg, the lids following (the rig's pitch-to-weight rule), and
* five views: the head's front, 35 deg to either side (the preview's three-quarter view) and
  20 deg above and below,

and reports the uncovered area (mm^2) inside the opening (the loop's polygon in that view),
which the globe, the cornea or the lids must cover. Above ``SEE_THROUGH_MM2`` (a quarter of a
default render's pixel) a view sees through. Past the loop an uncovered pixel is the crop's
edge seen at a grazing angle, which the sampler keeps out of every render; it is not counted. The iris at rest, seen from the head's front: the share of its disc (pupil centre to
the iris landmarks, 3 rings of 8 points and the centre) that skin nearer the camera than the iris
covers; an iris more than half hidden is counted.

``--home`` adds the three home scans' assets (rigged_assets/<scan>, build/<scan>/rig);
``--unseen WORK`` every asset a ``bench_unseen_scans --work WORK`` run left
(``WORK/assets/<case>_asset``, ``WORK/build/<case>/rig``). Writes ``<results>/<out>.json``.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from matplotlib.path import Path as Polygon

from pipeline.render import asset as ra
from pipeline.render.camera import direction_from_angles, look_at, project, rotation_between, to_camera
from pipeline.render.coverage import covered_points, sphere_silhouette, uncovered_area
from pipeline.rig.lids import lid_weights

ROOT = Path(__file__).resolve().parents[1]
HOME = ("synthetic_head", "ict_neutral", "james")
PITCHES = (-25.0, 0.0, 25.0)
VIEWS = {"front": (0.0, 0.0), "yaw+35": (35.0, 0.0), "yaw-35": (-35.0, 0.0),
         "above": (0.0, 20.0), "below": (0.0, -20.0)}
PX = 160                       # the rasteriser's image: PX x PX over the opening's box
# the eyeball's silhouette as a 720-gon: the sampler's 48-gon leaves slivers up to 0.03 mm deep
# inside the true circle, where a snapped margin meets the globe
SILHOUETTE_SEGMENTS = 720
HIDDEN_SHARE = 0.5
# uncovered area counted as see-through: a quarter of a default render's pixel (30-36 mm over
# 120 px: 0.06-0.09 mm^2); the inscribed silhouettes and cap leave up to 0.006 mm^2 where a
# margin rests exactly on the eye
SEE_THROUGH_MM2 = 0.02


def view_direction(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(3,) unit vector from the head toward the camera (head frame: +Z out of the face, +Y up)."""
    y, p = math.radians(yaw_deg), math.radians(pitch_deg)
    return np.array([math.sin(y) * math.cos(p), math.sin(p), math.cos(y) * math.cos(p)])


def _camera(target, towards, scale_mm):
    M = look_at(np.asarray(target) + 300.0 * towards, target, (0.0, 1.0, 0.0))
    return M, (lambda P: project(P, scale_mm, PX, PX))


def cornea_cap(eye, pitch_deg: float, n_theta: int = 32, n_phi: int = 360) -> np.ndarray:
    """(T, 3, 3) head-frame triangles inscribed in the corneal cap that bulges past the globe
    (the paper's eyeball: a sphere of radius r2 whose centre lies ``apex - r2`` in front of the
    globe's), the eye turned by ``pitch_deg``. Left out, the cornea's bulge would read as a gap
    beside a margin that rests on it."""
    p = eye.eyeball_params
    k = eye.radius / float(p["r1"])
    r1, r2, d = eye.radius, k * float(p["r2"]), k * (float(p["apex"]) - float(p["r2"]))
    n = rotation_between(eye.forward, direction_from_angles(pitch_deg, 0.0, eye.basis)) @ eye.forward
    cos_max = np.clip((r1 * r1 - d * d - r2 * r2) / (2 * d * r2), -1.0, 1.0)
    th = np.linspace(0.0, math.acos(cos_max), n_theta + 1)
    ph = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    pts = (eye.center + (d + r2 * np.cos(T))[..., None] * n
           + (r2 * np.sin(T))[..., None] * (np.cos(P)[..., None] * e1 + np.sin(P)[..., None] * e2))
    a, b = pts[:-1], np.roll(pts, -1, axis=1)[:-1]
    c, e = np.roll(pts, -1, axis=1)[1:], pts[1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3),
                           np.stack([a, c, e], -2).reshape(-1, 3, 3)])


def opening_uncovered(asset, side: str, pitch: float, towards, step_px: float = 0.5) -> float:
    """mm^2 of the posed opening (the lid loop's polygon seen from ``towards``) that neither skin
    nor either eyeball covers: what a ray through the opening would pass. Past the loop, an
    uncovered pixel is the asset's edge (the crop seen at a grazing angle), which the render's
    sampler keeps out of frame; it is not counted here."""
    lw = lid_weights(pitch, asset.max_pitch_deg)
    loop = ra.posed_lid_polygon(asset, side, lw)
    centre = loop.mean(axis=0)
    scale = 1.6 * float(np.ptp(loop, axis=0).max())
    M, proj = _camera(centre, towards, scale)
    V = to_camera(ra.posed_skin(asset, lw), M)
    tris = np.concatenate([V[asset.skin_faces]] + [
        sphere_silhouette(to_camera(e.center[None], M)[0], e.radius, n=SILHOUETTE_SEGMENTS)
        for e in asset.eyes.values()] + [
        to_camera(cornea_cap(e, pitch).reshape(-1, 3), M).reshape(-1, 3, 3) for e in asset.eyes.values()])
    T = proj(tris.reshape(-1, 3)).reshape(-1, 3, 2)
    poly = proj(to_camera(loop, M))
    (x0, y0), (x1, y1) = poly.min(axis=0), poly.max(axis=0)
    xs = np.arange(x0, x1 + step_px, step_px)
    ys = np.arange(y0, y1 + step_px, step_px)
    gx, gy = np.meshgrid(xs, ys)
    inside = Polygon(poly).contains_points(np.column_stack([gx.ravel(), gy.ravel()])).reshape(gx.shape)
    hole = inside & ~covered_points(T, xs, ys)
    px_mm = scale / PX
    return float(hole.sum()) * step_px * step_px * px_mm * px_mm


def iris_hidden_share(asset, side: str) -> float:
    """Share of the rest iris disc that skin nearer the camera covers, seen from the head's front."""
    eye = asset.eyes[side]
    lw = lid_weights(0.0, asset.max_pitch_deg)
    rot = np.eye(3)
    ring = ra.inner_points(eye, {}, rot, eye.iris)
    c = ra.pupil_center(asset, side, {}, rot)
    pts = [c] + [c + f * (q - c) for f in (1 / 3, 2 / 3, 0.95) for q in ring]
    pts = np.asarray(pts)
    towards = view_direction(0.0, 0.0)
    scale = 40.0
    M, proj = _camera(pts.mean(axis=0), towards, scale)
    skin = to_camera(ra.posed_skin(asset, lw), M)[asset.skin_faces]
    hidden = 0
    for p in pts:
        pc = to_camera(p[None], M)[0]
        near = skin[skin[:, :, 2].max(axis=1) > pc[2]]       # a vertex nearer the camera than p
        if not len(near):
            continue
        T = proj(near.reshape(-1, 3)).reshape(-1, 3, 2)
        u, v = proj(pc[None])[0]
        hidden += bool(covered_points(T, np.array([u]), np.array([v]))[0, 0])
    return hidden / len(pts)


def measure(name: str, asset_dir: Path, rig_dir: Path) -> dict:
    asset = ra.load_render_asset(asset_dir, rig_dir)
    row = {"asset": name, "eyes": {}}
    for side in ra.SIDES:
        worst = {"mm2": 0.0, "view": None, "pitch_deg": None}
        per = {}
        for view, (yaw, pitch_v) in VIEWS.items():
            for pitch in PITCHES:
                a = opening_uncovered(asset, side, pitch, view_direction(yaw, pitch_v))
                per[f"{view}@{pitch:+.0f}"] = round(a, 3)
                if a > worst["mm2"]:
                    worst = {"mm2": round(a, 3), "view": view, "pitch_deg": pitch}
        hid = iris_hidden_share(asset, side)
        row["eyes"][side] = {"see_through_mm2": worst,
                             "views_with_see_through": sum(v > SEE_THROUGH_MM2 for v in per.values()),
                             "views": len(per), "iris_hidden_share": round(hid, 3),
                             "iris_hidden": hid > HIDDEN_SHARE, "per_view_mm2": per}
    return row


def collect(args) -> list[tuple[str, Path, Path]]:
    items = []
    if args.home:
        items += [(s, ROOT / "rigged_assets" / s, ROOT / "build" / s / "rig") for s in HOME]
    if args.unseen:
        w = Path(args.unseen)
        for a in sorted((w / "assets").glob("*_asset")):
            case = a.name[: -len("_asset")]
            if (w / "build" / case / "rig" / "rig.npz").is_file() and any(a.glob("*.usda")):
                items.append((case, a, w / "build" / case / "rig"))
    for spec in args.assets:
        name, rest = spec.split("=", 1)
        a, r = rest.split(":", 1)
        items.append((name, Path(a), Path(r)))
    return items


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("assets", nargs="*", help="NAME=ASSET_DIR:RIG_DIR")
    ap.add_argument("--home", action="store_true")
    ap.add_argument("--unseen", help="a bench_unseen_scans --work folder")
    ap.add_argument("--results", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--out", default="see_through")
    args = ap.parse_args(argv)
    rows = []
    for name, a, r in collect(args):
        row = measure(name, a, r)
        rows.append(row)
        for side, e in row["eyes"].items():
            print(f"{name:28s} {side:5s} see-through {e['see_through_mm2']['mm2']:7.2f} mm2 "
                  f"({e['views_with_see_through']}/{e['views']} views"
                  f"{'; worst ' + e['see_through_mm2']['view'] + ' at pitch ' + format(e['see_through_mm2']['pitch_deg'], '+.0f') if e['see_through_mm2']['mm2'] > SEE_THROUGH_MM2 else ''})"
                  f"  iris hidden {100 * e['iris_hidden_share']:.0f} %")
    eyes = [e for r in rows for e in r["eyes"].values()]
    summary = {"assets": len(rows), "eyes": len(eyes),
               "assets_with_see_through": sum(any(e["see_through_mm2"]["mm2"] > SEE_THROUGH_MM2
                                                  for e in r["eyes"].values()) for r in rows),
               "eyes_with_see_through": sum(e["see_through_mm2"]["mm2"] > SEE_THROUGH_MM2 for e in eyes),
               "see_through_mm2": SEE_THROUGH_MM2,
               "irises_hidden": sum(e["iris_hidden"] for e in eyes),
               "views": {"pitches_deg": list(PITCHES), "cameras": VIEWS}, "hidden_share": HIDDEN_SHARE}
    print(json.dumps({k: v for k, v in summary.items() if k != "views"}))
    out = Path(args.results) / f"{args.out}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
