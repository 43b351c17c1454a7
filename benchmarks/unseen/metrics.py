"""Per-eye measurements of ``bench_unseen_scans`` against a scan's truth (``ground_truth.json``).

What each figure compares (mm, head frame):

- ``center_error_mm`` / ``radius_error_mm``: the placed sclera sphere (``eyes.json``) against
  the truth's ``eyeball_sphere``.
- ``visible_rms_mm``: what a camera sees. The true eye surface is the outer envelope of the true
  ``eyeball_sphere`` and ``cornea_sphere`` (their union's front along the true gaze); it is
  sampled on a 0.2 mm grid over the true opening (the true ``eyelid_margin`` polygon seen along
  the true gaze). Each sample's distance to the placed eye, RMS over the samples: ``sclera``
  against the placed sclera sphere alone, ``asset`` against the eye as the asset builds it (the
  parametric eye placed by ``pipeline.eyeball.geometry.placed_params`` at the rig's centre,
  radius and forward, as the usd stage authors it; ``pipeline.snap.snap.PlacedEye``).
  ``visible_rms_floor_mm`` is the ``asset`` figure with the eye placed exactly at the truth: what
  the asset's eye model costs by itself (a human-sized cornea on ICT-FaceKit's larger one).
- ``margin_mean_mm``: the asset's lid margin after ``snap`` (``snap/eyes.json`` ``loop_points``:
  the eye-region mesh's opening loop, which the rig's eyelid landmarks are sampled from) against
  the true margin polyline: mean distance from the asset's loop (resampled every 0.25 mm) to the
  truth; ``margin_symmetric_mm`` the mean of both directions (a loop that covers only half the
  opening is close to the truth one way, not the other).
- ``canthus_medial_mm`` / ``canthus_lateral_mm``: eyelid landmarks 0 and 6 of ``rig.npz`` at rest
  (weight 0) against the true corners: margin index 0 (the medial canthus by the truth's
  definition) and the margin point farthest lateral in the true eye's rest frame (the rule
  ``eyes.json`` uses for its own loops). ``truth_order_ok``: that point is the truth's own
  ``lateral_canthus_index`` or its neighbour, index 0 is the most medial point (within 1 mm) and
  the upper lid runs above the lower.
- ``convex_fill`` / ``remnant_mm2``: the cut's opening loop area over its convex hull's, and the
  scanned eyeball surface (scanify's labels) left on the head outside a 1 mm band along the loop.
- calibration: ``within_2sigma`` = centre error <= 2 x the stated 1-sigma ``uncertainty_mm.center``
  (None when the stage states none); ``doubted`` = the eye carries a doubt.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.geometry.frame import eye_basis
from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.eyes_file import lateral_canthus_index, read_eyes
from pipeline.remove_eyeballs.eye_checks import convex_fill

SIDES = ("left", "right")
GRID_MM = 0.2          # visible-surface sampling step in the image plane of the true gaze
RESAMPLE_MM = 0.25     # margin polylines resampled this finely before distances are averaged


# ----------------------------------------------------------------------------- truth geometry
def _inside_polygon(Q, P):
    """Even-odd test of points ``Q`` (n, 2) against the closed polygon ``P`` (k, 2); (n,) bool."""
    x, y = Q[:, 0][:, None], Q[:, 1][:, None]
    a, b = P[None, :, :], np.roll(P, -1, axis=0)[None, :, :]
    crosses = (a[..., 1] > y) != (b[..., 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[..., 0] + (y - a[..., 1]) * (b[..., 0] - a[..., 0]) / (b[..., 1] - a[..., 1])
    return (crosses & (x < xi)).sum(axis=1) % 2 == 1


def true_visible_surface(truth_eye: dict, step: float = GRID_MM) -> np.ndarray:
    """Points (n, 3) of the true eye's outer surface that show inside the true opening.

    The eye is the union of ``eyeball_sphere`` and ``cornea_sphere``; a sample is the front-most
    point of that union on a ray along the true gaze through a grid point inside the true margin
    polygon (projected onto the plane normal to the gaze).
    """
    c1 = np.asarray(truth_eye["eyeball_sphere"]["center_mm"], float)
    B = eye_basis(truth_eye["gaze_direction"])
    margin = np.asarray(truth_eye["eyelid_margin"]["points_mm"], float)
    uv = (margin - c1) @ B[:2].T
    lo, hi = uv.min(0), uv.max(0)
    u, v = np.meshgrid(np.arange(lo[0], hi[0] + step, step), np.arange(lo[1], hi[1] + step, step))
    Q = np.stack([u.ravel(), v.ravel()], 1)
    Q = Q[_inside_polygon(Q, uv)]
    front = np.full(len(Q), -np.inf)
    for key in ("eyeball_sphere", "cornea_sphere"):
        s = truth_eye.get(key)
        if not s:
            continue
        ck = (np.asarray(s["center_mm"], float) - c1) @ B.T
        disc = s["radius_mm"] ** 2 - ((Q - ck[:2]) ** 2).sum(1)
        h = np.where(disc >= 0, ck[2] + np.sqrt(np.maximum(disc, 0)), -np.inf)
        front = np.maximum(front, h)
    keep = np.isfinite(front)
    return c1 + Q[keep] @ B[:2] + front[keep, None] * B[2]


def rest_forward(truth_eye: dict, rotation=None) -> np.ndarray:
    """The eye's forward at rest: the true gaze with scanify's rigid eye rotation (``source.
    eye_rotation.<side>.rotation_matrix``, None: none) undone. The canthi belong to the lids, which
    do not turn with the eye: an eye looking 30 deg in would otherwise move the "farthest lateral"
    margin point 3 mm along the lid."""
    g = np.asarray(truth_eye["gaze_direction"], float)
    return g if rotation is None else np.asarray(rotation, float).T @ g


def true_canthi(truth_eye: dict, side: str, rotation=None) -> tuple[np.ndarray, np.ndarray, bool]:
    """(medial (3,), lateral (3,), ordering agrees) of the true margin, in the eye's rest frame
    (:func:`rest_forward`); see the module docstring."""
    margin = np.asarray(truth_eye["eyelid_margin"]["points_mm"], float)
    c = np.asarray(truth_eye["eyeball_sphere"]["center_mm"], float)
    g = rest_forward(truth_eye, rotation)
    lat = lateral_canthus_index(margin, c, g, side)
    own = truth_eye["eyelid_margin"].get("lateral_canthus_index", lat)
    B = eye_basis(g)
    xy = (margin - c) @ B[:2].T
    medial_x = -xy[:, 0] if side == "left" else xy[:, 0]   # left eye: medial is head -X
    upper, lower = xy[1:lat, 1], xy[lat + 1:, 1]
    # the truth's own corner (ICT: a fixed vertex) may be the farthest point's neighbour
    ok = bool(0 < lat < len(margin) - 1 and abs(lat - own) <= 1
              and medial_x.max() - medial_x[0] <= 1.0
              and len(upper) and len(lower) and upper.mean() > lower.mean())
    return margin[0], margin[lat], ok


def resample_closed(P, step: float = RESAMPLE_MM) -> np.ndarray:
    """A closed polyline (k, 3) resampled every ``step`` mm along its length (its vertices kept
    where they fall on the spacing; (m, 3))."""
    P = np.asarray(P, float)
    Q = np.vstack([P, P[:1]])
    seg = np.linalg.norm(np.diff(Q, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.arange(0.0, s[-1], step)
    return np.stack([np.interp(t, s, Q[:, k]) for k in range(3)], 1)


# ----------------------------------------------------------------------------- per eye
def _placement(e: dict) -> list:
    """Cue names: ``placement`` as a list (today a string; the rewrite writes a list)."""
    p = e.get("placement", e.get("method"))
    if p is None:
        return []
    return [p] if isinstance(p, str) else [str(x) for x in p]


def placement_metrics(e: dict, g: dict, visible: np.ndarray, asset_eye, params) -> dict:
    """Centre/radius error, visible RMS and calibration of one placed eye (``eyes.json`` entry
    ``e``) against its truth ``g``. ``asset_eye``: (centre, radius, forward) the asset places the
    eye at (the rig's), ``params``: the eyeball asset's EyeballParams (None: skip the asset RMS)."""
    from pipeline.snap.snap import PlacedEye

    c, r = np.asarray(e["center"], float), float(e["radius"])
    err = float(np.linalg.norm(c - g["eyeball_sphere"]["center_mm"]))
    unc = e.get("uncertainty_mm") if isinstance(e.get("uncertainty_mm"), dict) else {}
    s_c, s_r = unc.get("center"), unc.get("radius")
    rms_sclera = float(np.sqrt(np.mean((np.linalg.norm(visible - c, axis=1) - r) ** 2)))
    rms_asset = None
    if params is not None and len(visible):
        ac, ar, af = asset_eye
        d = PlacedEye(np.asarray(ac, float), float(ar), np.asarray(af, float), params).closest(visible)[2]
        rms_asset = round(float(np.sqrt(np.mean(d ** 2))), 4)
    rerr = float(r - g["eyeball_sphere"]["radius_mm"])
    return {
        "center_error_mm": round(err, 4),
        "radius_error_mm": round(rerr, 4),
        "visible_samples": int(len(visible)),
        "visible_rms_sclera_mm": round(rms_sclera, 4),
        "visible_rms_mm": rms_asset,
        "placement": _placement(e),
        "doubts": list(e.get("doubts") or []),
        "doubted": bool(e.get("doubts")),
        "uncertainty_mm": {"center": s_c, "radius": s_r} if unc else None,
        "within_2sigma": None if not s_c else bool(err <= 2.0 * float(s_c)),
        "radius_within_2sigma": None if not s_r else bool(abs(rerr) <= 2.0 * float(s_r)),
        "checks_failed": sorted(k for k, v in (e.get("checks") or {}).items()
                                if isinstance(v, dict) and v.get("ok") is False),
    }


def margin_metrics(loop_points, g: dict) -> dict:
    """The asset's opening loop after snap against the true margin (module docstring)."""
    truth = np.asarray(g["eyelid_margin"]["points_mm"], float)
    loop = np.asarray(loop_points, float)
    to_truth = closed_polyline_distance(resample_closed(loop), truth)
    to_asset = closed_polyline_distance(resample_closed(truth), loop)
    return {"margin_mean_mm": round(float(to_truth.mean()), 4),
            "margin_symmetric_mm": round(float(0.5 * (to_truth.mean() + to_asset.mean())), 4),
            "margin_max_mm": round(float(max(to_truth.max(), to_asset.max())), 4)}


def canthus_metrics(landmarks, g: dict, side: str, rotation=None) -> dict:
    """Eyelid landmarks 0 and 6 (rest) against the true corners."""
    med, lat, ok = true_canthi(g, side, rotation)
    L = np.asarray(landmarks, float)
    return {"canthus_medial_mm": round(float(np.linalg.norm(L[0] - med)), 4),
            "canthus_lateral_mm": round(float(np.linalg.norm(L[6] - lat)), 4),
            "truth_order_ok": ok}


def remnant(folder: Path, build: Path, eyes: dict):
    """Per side: area (mm²) of kept faces whose vertices the scan labels as that eyeball, outside
    a 1 mm band along the opening loop."""
    from scipy.spatial import cKDTree
    from pipeline.io.meshfile import read_stage_mesh
    lab_path = folder / "scan_labels.npy"
    if not lab_path.is_file():
        return {}
    labels = np.load(lab_path)
    ingest = read_stage_mesh(build / "ingest" / "mesh.npz")
    cut = read_stage_mesh(build / "remove_eyeballs" / "mesh.npz")
    if len(labels) != len(ingest["V"]):   # ingest merged/removed vertices: match by position
        import trimesh
        src = trimesh.load(folder / "scan.ply", process=False, maintain_order=True)
        d, j = cKDTree(np.asarray(src.vertices)).query(ingest["V"])
        lab_in = labels[j]
    else:
        lab_in = labels
    d, j = cKDTree(ingest["V"]).query(cut["V"])
    lab = np.where(d < 1e-6, lab_in[j], 0)    # moved loop vertices count as not eyeball
    V, F = cut["V"], cut["F"]
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    cen = V[F].mean(axis=1)
    out = {}
    for code, s in ((1, "left"), (2, "right")):
        if s not in eyes:
            continue
        onlab = (lab[F] == code).all(axis=1)
        band = closed_polyline_distance(cen[onlab], np.asarray(eyes[s]["loop_points"])) <= 1.0
        out[s] = float(A[onlab][~band].sum())
    return out


def _eyeball_params(eyeball: Path):
    if not (eyeball / "eyeball.usda").is_file():
        return None
    from pipeline.usd.eyeball import read_eyeball_params
    return read_eyeball_params(eyeball)


def visible_floor(truth: dict, eyeball: Path) -> dict:
    """Per side, ``visible_rms_mm`` of the asset's eye placed exactly at the truth (centre, radius,
    gaze): what the asset's eye model alone costs (its cornea keeps human size, placed_params),
    whatever the placement. None without the eyeball asset."""
    params = _eyeball_params(eyeball)
    out = {}
    for s in SIDES:
        g = truth[s]
        c, r = g["eyeball_sphere"]["center_mm"], g["eyeball_sphere"]["radius_mm"]
        exact = {"center": c, "radius": r}
        out[s] = placement_metrics(exact, g, true_visible_surface(g), (c, r, g["gaze_direction"]),
                                   params)["visible_rms_mm"]
    return out


def eye_rows(folder: Path, build: Path, eyeball: Path) -> dict:
    """Per side, every measurement the build so far allows (no side when no eye was placed), and
    ``visible_rms_floor_mm`` (truth only, every case)."""
    doc = json.loads((folder / "ground_truth.json").read_text())
    truth = doc["eyes"]
    rotations = {s: r.get("rotation_matrix") for s, r in
                 ((doc.get("source") or {}).get("eye_rotation") or {}).items() if isinstance(r, dict)}
    out = {"visible_rms_floor_mm": visible_floor(truth, eyeball)}
    eyes_p = build / "remove_eyeballs" / "eyes.json"
    if not eyes_p.is_file():
        return out
    eyes = {s: e.doc for s, e in read_eyes(eyes_p).items()}
    rig = None
    if (build / "rig" / "rig.json").is_file():
        from pipeline.io.rig_file import read_rig
        rig = read_rig(build / "rig")
    params = _eyeball_params(eyeball)
    snap_p = build / "snap" / "eyes.json"
    snapped = {s: e.doc for s, e in read_eyes(snap_p).items()} if snap_p.is_file() else {}
    rem = remnant(folder, build, eyes)
    for s in SIDES:
        e, g = eyes[s], truth[s]
        # the asset places the eye where the rig says (the usd stage reads rig.json's eyes)
        src = rig.eyes[s] if rig is not None else None
        asset_eye = ((src.center, src.radius, src.forward) if src is not None
                     else (e["center"], e["radius"], e["forward"]))
        row = placement_metrics(e, g, true_visible_surface(g), asset_eye, params)
        if e.get("loop_points"):     # the cut's loop: does it close the opening, what is left
            row["convex_fill"] = round(convex_fill(e["loop_points"], e["center"], e["forward"]), 4)
            row["remnant_mm2"] = round(rem.get(s, float("nan")), 3)
        if s in snapped and snapped[s].get("loop_points"):
            row.update(margin_metrics(snapped[s]["loop_points"], g))
        if rig is not None and s in rig.npz.curves:
            row.update(canthus_metrics(rig.npz.curves[s][0], g, s, rotations.get(s)))
        out[s] = row
    return out
