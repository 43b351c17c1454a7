"""Where the true eyelid margin of ``ict_neutral`` lies relative to the scan and the fitted eye.

    .venv/bin/python -m benchmarks.bench_eyelid_margin --scans /work/shared/scans

Diagnostic for the loop-to-margin gap of ``remove_eyeballs`` on ``ict_neutral`` (issue 4). Runs
the stage's library call with the params.yaml defaults and, per eye, measures against
``ground_truth.json`` (``eyelid_margin.points_mm``):

- ``margin_depth_under_scan_mm``: distance from each true margin point to the scan surface
  (dense samples on the faces), and ``margin_height_above_fitted_eye_mm``;
- ``lid_line``: in the cross-section through each margin point (plane through the fitted centre,
  the margin point and the outward normal of the margin polyline on the eye), where the scanned
  lid face lying 1.5-3 mm above the fitted eye, extended as a straight line, meets the eye, and
  where the scan itself comes down to 0.3 mm above the eye (the foot of the lid face); signed
  along the outward normal, negative = toward the opening;
- ``shift_curve``: the mean loop-to-margin distance after moving every loop vertex a constant
  distance away from the opening along the fitted eye (0-3 mm), i.e. the best a constant
  "hidden margin" offset could do.

Writes benchmarks/results/eyelid_margin_ict.json (or ``--out``) and prints a summary.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import yaml

from benchmarks.bench_remove_eyeballs import eye_errors
from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.remove_eyeballs.remove_eyeballs import SIDES, remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _surface_samples(V, F, near, radius, n=6):
    """Points on the faces within ``radius`` of ``near``: (k, 3), ``n`` x ``n`` barycentric grid."""
    c = V[F].mean(axis=1)
    Fs = F[np.linalg.norm(c - near, axis=1) < radius]
    a, b = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    keep = a + b <= 1
    bary = np.stack([a[keep], b[keep], 1 - a[keep] - b[keep]], axis=1)
    return np.einsum("sk,fkd->fsd", bary, V[Fs]).reshape(-1, 3)


def _section(V, F, origin, normal):
    """Points where the edges of ``F`` cross the plane (origin, normal): (k, 3)."""
    sd = (V - origin) @ normal
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    a, b = sd[E[:, 0]], sd[E[:, 1]]
    cr = a * b < 0
    t = a[cr] / (a[cr] - b[cr])
    return V[E[cr, 0]] + t[:, None] * (V[E[cr, 1]] - V[E[cr, 0]])


def _outward_normals(M, center):
    """(n, 3) unit tangents of the eye at each margin point, perpendicular to the closed polyline
    ``M`` (n, 3) and pointing away from its centroid (under the lid)."""
    T = np.roll(M, -1, axis=0) - np.roll(M, 1, axis=0)
    U = (M - center) / np.linalg.norm(M - center, axis=1)[:, None]
    N = np.cross(T, U)
    N /= np.linalg.norm(N, axis=1)[:, None]
    away = ((M - M.mean(axis=0)) * N).sum(axis=1) < 0
    N[away] *= -1
    return N


def lid_line_offsets(V, F, center, radius, M, band=(1.5, 3.0), foot_mm=0.3, reach=8.0):
    """Per margin point: where the extended lid face and the foot of the scanned lid meet the eye.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        Uncut scan near the eye.
    center : (3,) float64
    radius : float
        Fitted eyeball sphere.
    M : (k, 3) float64
        True margin (closed polyline).
    band : (2,) float
        Heights above the eye of the lid face used for the line.
    foot_mm : float
        Height below which the scan counts as on the eye.

    Returns
    -------
    line, foot : (k,) float64
        Signed arc length along the eye from the margin point to the extended line's meeting
        point / to the foot of the lid face (negative = toward the opening; NaN where none).
    """
    N = _outward_normals(M, center)
    line, foot = np.full(len(M), np.nan), np.full(len(M), np.nan)
    for i, (m, t) in enumerate(zip(M, N)):
        u = (m - center) / np.linalg.norm(m - center)
        pn = np.cross(u, t)                      # section plane: radius and outward normal
        P = _section(V, F, center, pn)
        P = P[np.linalg.norm(P - m, axis=1) < reach]
        w = P - center
        arc = np.arctan2(w @ t, w @ u) * radius  # along the eye, 0 at the margin point
        h = np.linalg.norm(w, axis=1) - radius
        lifted = np.flatnonzero(h >= band[0])
        if len(lifted) == 0:
            continue
        a0 = arc[lifted].min()                   # the lid face nearest the opening
        on = np.flatnonzero((h < foot_mm) & (arc < a0))
        if len(on):
            foot[i] = arc[on].max()
        sel = (h >= band[0]) & (h <= band[1]) & (arc < a0 + 2.5)
        if sel.sum() < 2:
            continue
        X = np.column_stack([arc[sel], h[sel]])
        mu = X.mean(axis=0)
        d = np.linalg.svd(X - mu)[2][0]
        if abs(d[1]) > 1e-6:
            line[i] = mu[0] - mu[1] * d[0] / d[1]
    return line, foot


def shift_curve(loop, center, radius, M, shifts):
    """Mean loop-to-margin distance after moving the loop ``s`` mm away from the opening along
    the eye, for each ``s`` of ``shifts``: (len(shifts),) float64."""
    u = (loop - center) / np.linalg.norm(loop - center, axis=1)[:, None]
    axis = loop.mean(axis=0) - center
    axis /= np.linalg.norm(axis)
    out = []
    for s in shifts:
        # rotate each radius away from the opening axis by s / radius
        k = np.cross(axis, u)
        k /= np.linalg.norm(k, axis=1)[:, None]
        a = s / radius
        un = u * np.cos(a) + np.cross(k, u) * np.sin(a) + k * (k * u).sum(axis=1)[:, None] * (1 - np.cos(a))
        out.append(float(closed_polyline_distance(center + radius * un, M).mean()))
    return np.array(out)


def _stats(a):
    a = a[np.isfinite(a)]
    return {"mean": float(a.mean()), "min": float(a.min()), "max": float(a.max()), "n": int(len(a))}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", required=True, help="folder holding ict_neutral")
    ap.add_argument("--out", default="eyelid_margin_ict.json")
    args = ap.parse_args()
    from pipeline.ingest.ingest import IngestSettings, ingest_scan

    folder = Path(args.scans) / "ict_neutral"
    gt = json.loads((folder / "ground_truth.json").read_text())["eyes"]
    r = ingest_scan(folder, IngestSettings())
    hints = {s: r.scan["eyes"][s]["hint"] for s in SIDES}
    params = yaml.safe_load((ROOT / "params.yaml").read_text())["remove_eyeballs"]
    res = remove_eyeballs(r.mesh, hints, RemoveEyeballsSettings.from_params(params), source="ict_neutral")
    V, F = np.asarray(r.mesh["V"], float), np.asarray(r.mesh["F"], np.int64)
    shifts = np.arange(0.0, 3.01, 0.25)
    rows = {}
    from scipy.spatial import cKDTree

    for s in SIDES:
        e, g = res.eyes[s].to_doc(), gt[s]
        M = np.asarray(g["eyelid_margin"]["points_mm"], float)
        c, rad = np.asarray(e["center"]), float(e["radius"])
        near = np.linalg.norm(V[F].mean(axis=1) - M.mean(axis=0), axis=1) < 20.0
        Fl = F[near]
        depth = cKDTree(_surface_samples(V, F, M.mean(axis=0), 20.0)).query(M)[0]
        line, foot = lid_line_offsets(V, Fl, c, rad, M)
        curve = shift_curve(np.asarray(e["loop_points"]), c, rad, M, shifts)
        rows[s] = {
            **eye_errors(e, g, ("eyeball_sphere", "anterior_sclera_sphere")),
            "margin_height_above_fitted_eye_mm": _stats(np.linalg.norm(M - c, axis=1) - rad),
            "margin_depth_under_scan_mm": _stats(depth),
            "lid_line_meets_eye_mm": _stats(line),
            "lid_foot_mm": _stats(foot),
            "shift_curve": {f"{x:.2f}": round(float(y), 4) for x, y in zip(shifts, curve)},
        }
        b = int(np.argmin(curve))
        print(f"{s}: loop {rows[s]['loop_to_margin_mean_mm']:.2f} mm; margin "
              f"{rows[s]['margin_depth_under_scan_mm']['mean']:.2f} mm under the scan "
              f"(max {rows[s]['margin_depth_under_scan_mm']['max']:.2f}); extended lid face meets "
              f"the eye {rows[s]['lid_line_meets_eye_mm']['mean']:+.2f} mm from it "
              f"(range {rows[s]['lid_line_meets_eye_mm']['min']:+.2f}..{rows[s]['lid_line_meets_eye_mm']['max']:+.2f}), "
              f"lid foot {rows[s]['lid_foot_mm']['mean']:+.2f} mm; best constant shift "
              f"{shifts[b]:.2f} mm -> {curve[b]:.2f} mm")
    out = RESULTS / args.out
    out.write_text(json.dumps({"scan": "ict_neutral", "params": "params.yaml defaults",
                               "eyes": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
