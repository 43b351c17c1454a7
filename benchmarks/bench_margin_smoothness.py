"""Saw-teeth of the eyelid margin, stage by stage: the cut, retopo's loop, the snapped loop.

    .venv/bin/python -m benchmarks.bench_margin_smoothness BUILD_DIR... [--params params.yaml]
        [--out benchmarks/results/margin_smoothness.json]

Each ``BUILD_DIR`` is one scan's ``build/<scan>`` (``remove_eyeballs/`` done; the home scans'
``dvc repro`` or ``bench_unseen_scans``' ``benchmarks/out/unseen/build/<scan>``). Per scan and
eye, with the params.yaml ``retopo:`` settings as given and with ``margin_smooth_mm: 0`` (the
former loop), retopo's library call and snap's (onto the eyeball of
``BUILD_DIR/../../{rigged_assets/eyeball,eyeball}``; bake is skipped: snap reads V, F and the
loops only):

- ``jag_p95_mm``: p95 of :func:`pipeline.retopo.eyelid_loop.margin_jag` (distance of each
  loop vertex to the mean of itself and its +-1, +-2 neighbours, 6 vertices either side of
  each canthus left out) for ``cut`` (remove_eyeballs' loop), ``retopo`` and ``snap``;
  and ``truth_floor`` (the true margin resampled like retopo's loop: what a smooth lid scores);
- ``teeth_p95_mm``: p95 of :func:`~pipeline.retopo.eyelid_loop.margin_teeth` (distance to
  the cubic through the +-1, +-2 neighbours: 0 on a smooth curve whatever its curvature, 2.67 a
  on a zigzag of amplitude a), retopo and snap;
- ``spacing_mm``: the mean loop edge of the retopo loop;
- ``to_truth_mean_mm``: where ``BUILD_DIR/../../{raw_scans,scans}/<scan>/ground_truth.json``
  has the margin (``eyelid_margin.points_mm``), the mean distance of the retopo and snap loops
  to it;
- ``canthus_shift_mm``: how far each canthus vertex (loop 0, lateral index) of the smoothed
  loop lies from the former one (retopo and snap);
- ``canthus_to_truth_mm``: the snapped canthi (medial, lateral) to the true ones, before and after;
- ``flipped_faces`` after snap.

Writes the JSON and prints one line per scan and eye.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.atomic import write_json
from pipeline.io.eyes_file import read_eye_loops
from pipeline.io.meshfile import read_stage_mesh
from pipeline.retopo.eyelid_loop import margin_jag, margin_teeth, polyline_arclength
from pipeline.retopo.retopo import RetopoSettings, retopologize
from pipeline.snap import snap as sn
from pipeline.usd.eyeball import read_eyeball_params
from stages._common import load_settings

ROOT = Path(__file__).resolve().parents[1]
SIDES = ("left", "right")


def _p95(P, corners, fn=margin_jag):
    j = fn(P, corners)
    return float(np.percentile(j, 95)) if len(j) else None    # a coarse cut (james: 11 points)


def truth_floor(T, medial, lateral, n, lat_pos):
    """Jag p95 of the true margin ``T`` (k, 3) resampled to the loop's ``n`` vertices, evenly
    per lid with the lateral canthus at ``lat_pos`` like retopo's loop: what a smooth lid scores."""
    T = np.roll(np.asarray(T, dtype=np.float64), -int(medial), axis=0)
    li = (int(lateral) - int(medial)) % len(T)
    s, Q = polyline_arclength(T)
    t = np.concatenate([np.linspace(0, s[li], lat_pos, endpoint=False),
                        np.linspace(s[li], s[-1], n - lat_pos, endpoint=False)])
    P = np.stack([np.interp(t, s, Q[:, d]) for d in range(3)], axis=1)
    return _p95(P, (0, lat_pos))


def _first(*paths):
    return next((p for p in paths if p.exists()), None)


def measure(build: Path, rs: RetopoSettings, ss: sn.SnapSettings) -> dict:
    name = build.name
    root = build.parents[1]
    re_dir = build / "remove_eyeballs"
    mesh = read_stage_mesh(re_dir / "mesh.npz")
    eyes = read_eye_loops(re_dir / "eyes.json", len(mesh["V"]))
    eyeball = _first(root / "rigged_assets" / "eyeball", root / "eyeball")
    params = read_eyeball_params(eyeball)
    gt_path = _first(root / "raw_scans" / name / "ground_truth.json",
                     root / "scans" / name / "ground_truth.json")
    truth = {}
    if gt_path is not None:
        gt = json.loads(gt_path.read_text())
        for s in SIDES:
            m = gt.get("eyes", {}).get(s, {}).get("eyelid_margin", {})
            if "points_mm" in m:
                truth[s] = (np.asarray(m["points_mm"], dtype=np.float64),
                            m.get("medial_canthus_index"), m.get("lateral_canthus_index"))
    runs = {}
    for label, st in (("before", dataclasses.replace(rs, margin_smooth_mm=0.0)), ("after", rs)):
        r = retopologize(mesh["V"], mesh["F"], eyes, st)
        m = {"V": r.V, "F": r.F, **{f"loop_{s}": r.loops[s] for s in SIDES}}
        m.update({f"lateral_index_{s}": np.array([r.lateral[s]]) for s in SIDES
                  if r.lateral.get(s) is not None})
        snapped, _, met = sn.snap_mesh(m, {s: (e.center, e.radius, e.unit_forward)
                                           for s, e in eyes.items()}, params, ss)
        runs[label] = (r, snapped["V"], met)
    out = {"scan": name, "truth": str(gt_path) if gt_path else None}
    for s in SIDES:
        cut = mesh["V"][eyes[s].loop_indices]
        row = {"jag_p95_mm": {"cut": _p95(cut, (0, eyes[s].lateral_canthus_index))}}
        for label, (r, Vs, met) in runs.items():
            loop, lat = r.loops[s], r.lateral.get(s)
            row["jag_p95_mm"][f"retopo_{label}"] = _p95(r.V[loop], (0, lat))
            row["jag_p95_mm"][f"snap_{label}"] = _p95(Vs[loop], (0, lat))
            row.setdefault("teeth_p95_mm", {})[f"retopo_{label}"] = _p95(r.V[loop], (0, lat),
                                                                         margin_teeth)
            row["teeth_p95_mm"][f"snap_{label}"] = _p95(Vs[loop], (0, lat), margin_teeth)
            if s in truth:
                row.setdefault("to_truth_mean_mm", {})[f"retopo_{label}"] = float(
                    closed_polyline_distance(r.V[loop], truth[s][0]).mean())
                row["to_truth_mean_mm"][f"snap_{label}"] = float(
                    closed_polyline_distance(Vs[loop], truth[s][0]).mean())
            row.setdefault("flipped_faces", {})[label] = int(met["flipped_faces"])
            row.setdefault("gap_max_mm", {})[label] = float(met[s]["gap_max_mm"])
        (rb, Vb, _), (ra, Va, _) = runs["before"], runs["after"]
        lb, la = rb.loops[s], ra.loops[s]
        P = ra.V[la]
        row["spacing_mm"] = float(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1).mean())
        if rb.lateral.get(s) is not None and ra.lateral.get(s) is not None:
            ib, ia = [0, rb.lateral[s]], [0, ra.lateral[s]]
            row["canthus_shift_mm"] = {
                "retopo": np.linalg.norm(rb.V[lb[ib]] - ra.V[la[ia]], axis=1).round(3).tolist(),
                "snap": np.linalg.norm(Vb[lb[ib]] - Va[la[ia]], axis=1).round(3).tolist()}
        T, med, lat = truth.get(s, (None, None, None))
        if med is not None and lat is not None:
            # the snapped canthi against the true corners (snap moves them 0.3-2 mm onto the eye,
            # along a line that depends on their neighbours)
            row["canthus_to_truth_mm"] = {
                label: np.linalg.norm(Vs[r.loops[s][[0, r.lateral[s]]]] - T[[med, lat]],
                                      axis=1).round(3).tolist()
                for label, (r, Vs, _) in runs.items() if r.lateral.get(s) is not None}
        if med is not None and lat is not None and ra.lateral.get(s) is not None:
            row["jag_p95_mm"]["truth_floor"] = truth_floor(T, med, lat, len(la), ra.lateral[s])
        out[s] = row
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("builds", nargs="+", type=Path)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "margin_smoothness.json")
    a = ap.parse_args(argv)
    rs = load_settings(RetopoSettings, a.params)
    ss = load_settings(sn.SnapSettings, a.params)
    rows = []
    for b in a.builds:
        row = measure(b, rs, ss)
        rows.append(row)
        for s in SIDES:
            r = row[s]
            j, t = {k: (float("nan") if v is None else v) for k, v in r["jag_p95_mm"].items()}, \
                r.get("to_truth_mean_mm", {})
            tt = (f" truth {t['snap_before']:.2f}->{t['snap_after']:.2f}" if t else "")
            print(f"{row['scan']:24s} {s:5s} spacing {r['spacing_mm']:.2f} jag p95 cut {j['cut']:.2f} "
                  f"retopo {j['retopo_before']:.2f}->{j['retopo_after']:.2f} "
                  f"snap {j['snap_before']:.2f}->{j['snap_after']:.2f} teeth snap "
                  f"{r['teeth_p95_mm']['snap_before']:.2f}->{r['teeth_p95_mm']['snap_after']:.2f} floor {j.get('truth_floor', float('nan')):.2f}{tt} "
                  f"canthi {r.get('canthus_shift_mm')} to truth {r.get('canthus_to_truth_mm')} flips {r['flipped_faces']} "
                  f"gap {r['gap_max_mm']['before']:.2f}->{r['gap_max_mm']['after']:.2f}", flush=True)
    write_json(a.out, {"params": a.params, "scans": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
