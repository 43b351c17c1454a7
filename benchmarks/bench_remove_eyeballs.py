"""Benchmark remove_eyeballs: time and accuracy vs mesh density on the synthetic head.

    .venv/bin/python -m benchmarks.bench_remove_eyeballs [--repeats 3] [--triangles 100000 350000 1000000]
    .venv/bin/python -m benchmarks.bench_remove_eyeballs --sweep [--seeds 1 2 ... 8] \
        [--triangles 100000 150000 350000] [--shapes round hooded] [--scans /work/shared/scans] \
        [--out NAME]

Default mode writes benchmarks/results/remove_eyeballs.json (median wall time of the library
call, and per-eye centre/radius error, loop-to-margin mean distance, forward error) and prints a
summary. ``--sweep`` runs every seed x density x eye shape once (plus ``ict_neutral`` from
``--scans`` when given, whose ground truth has two valid spheres: the smaller error counts),
prints a table with the bounds checked (centre <= 0.5 mm, radius <= 0.5 mm, loop <= 0.5 mm) and
writes benchmarks/results/remove_eyeballs_sweep.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.remove_eyeballs.remove_eyeballs import remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings
from pipeline.synthetic_head import make_synthetic_head

BOUND_MM = 0.5
SETTINGS = RemoveEyeballsSettings()
RESULTS = Path(__file__).resolve().parent / "results"


def eye_errors(e, g, spheres=("eyeball_sphere",)):
    """Per-eye errors of an eyes.json entry ``e`` against a ground-truth eye ``g``.

    The sphere (of ``spheres``) with the smaller centre error counts.
    """
    c = np.array(e["center"])
    errs = sorted((float(np.linalg.norm(c - g[k]["center_mm"])), float(e["radius"] - g[k]["radius_mm"]))
                  for k in spheres if k in g)
    cerr, rerr = errs[0]
    return {
        "center_error_mm": cerr,
        "radius_error_mm": rerr,
        "loop_to_margin_mean_mm": float(closed_polyline_distance(
            np.array(e["loop_points"]), np.array(g["eyelid_margin"]["points_mm"])).mean()),
        "forward_error_deg": float(np.degrees(np.arccos(np.clip(
            np.dot(e["forward"], g["gaze_direction"]), -1, 1)))),
        "method": e.get("method", "geometry"),
    }


def _ok(r):
    return (r["center_error_mm"] <= BOUND_MM and abs(r["radius_error_mm"]) <= BOUND_MM
            and r["loop_to_margin_mean_mm"] <= BOUND_MM)


def _fmt(r):
    if "error" in r:
        return f"FAILED: {r['error']}"
    return (f"c {r['center_error_mm']:.2f} r {r['radius_error_mm']:+.2f} "
            f"loop {r['loop_to_margin_mean_mm']:.2f}{'' if _ok(r) else ' *'}")


def sweep(args):
    rows = []
    cases = [(shape, seed, tri) for shape in args.shapes for seed in args.seeds for tri in args.triangles]
    for shape, seed, tri in cases:
        h = make_synthetic_head(seed=seed, target_triangles=tri, eye_shape=shape, noise_mm=args.noise,
                                texture_size=16)
        hints = {s: np.asarray(h.hints[s]) for s in ("left", "right")}
        row = {"case": f"synthetic {shape} seed {seed}", "triangles": int(len(h.F))}
        t0 = time.perf_counter()
        try:
            res = remove_eyeballs({"V": h.V, "F": h.F}, hints, SETTINGS, source="synthetic")
            for s in ("left", "right"):
                row[s] = eye_errors(res.eyes[s].to_doc(), h.ground_truth["eyes"][s])
        except ScanError as exc:
            row["left"] = row["right"] = {"error": str(exc)}
        row["time_s"] = time.perf_counter() - t0
        rows.append(row)
        print(f"{row['case']:<28} {row['triangles']:>7}  {row['time_s']:5.1f} s  "
              f"L: {_fmt(row['left'])}   R: {_fmt(row['right'])}", flush=True)
    if args.scans:
        from pipeline.ingest.ingest import IngestSettings, ingest_scan

        for name in ("ict_neutral",):
            folder = Path(args.scans) / name
            if not (folder / "ground_truth.json").is_file():
                continue
            gt = json.loads((folder / "ground_truth.json").read_text())["eyes"]
            r = ingest_scan(folder, IngestSettings())
            hints = {s: r.scan["eyes"][s]["hint"] for s in ("left", "right")}
            row = {"case": name, "triangles": int(len(r.mesh["F"]))}
            t0 = time.perf_counter()
            res = remove_eyeballs(r.mesh, hints, SETTINGS, source=name)
            row["time_s"] = time.perf_counter() - t0
            for s in ("left", "right"):
                row[s] = eye_errors(res.eyes[s].to_doc(), gt[s], ("eyeball_sphere", "anterior_sclera_sphere"))
            rows.append(row)
            print(f"{row['case']:<28} {row['triangles']:>7}  {row['time_s']:5.1f} s  "
                  f"L: {_fmt(row['left'])}   R: {_fmt(row['right'])}", flush=True)
    n_bad = sum(1 for r in rows for s in ("left", "right") if "error" in r[s] or not _ok(r[s]))
    print(f"{n_bad} of {2 * len(rows)} eyes over a bound (* = over {BOUND_MM} mm)")
    out = RESULTS / (args.out or "remove_eyeballs_sweep.json")
    out.write_text(json.dumps({"noise_mm": args.noise, "bound_mm": BOUND_MM, "eyes_over_bound": n_bad,
                               "rows": rows}, indent=1))
    print(f"wrote {out}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--triangles", type=int, nargs="+", default=None)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--sweep", action="store_true")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 9)))
    ap.add_argument("--shapes", nargs="+", default=["round", "hooded"])
    ap.add_argument("--scans", default=None, help="folder holding ict_neutral (sweep only)")
    ap.add_argument("--out", default=None, help="result file name under benchmarks/results/")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="RemoveEyeballsSettings overrides (YAML values), e.g. shared_radius=false")
    args = ap.parse_args()
    import yaml
    global SETTINGS
    SETTINGS = RemoveEyeballsSettings.from_params({k: yaml.safe_load(v) for k, v in (a.split("=", 1) for a in args.set)})
    if args.sweep:
        args.triangles = args.triangles or [100_000, 150_000, 350_000]
        sweep(args)
        return
    args.triangles = args.triangles or [100_000, 350_000, 1_000_000]
    rows = []
    for tri in args.triangles:
        h = make_synthetic_head(seed=args.seed, target_triangles=tri, noise_mm=args.noise, texture_size=16)
        mesh = {"V": h.V, "F": h.F}
        hints = {s: np.asarray(h.hints[s]) for s in ("left", "right")}
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = remove_eyeballs(mesh, hints, SETTINGS, source="synthetic")
            times.append(time.perf_counter() - t0)
        row = {"triangles": int(len(h.F)), "median_s": float(np.median(times)), "runs_s": times}
        for s in ("left", "right"):
            row[s] = eye_errors(res.eyes[s].to_doc(), h.ground_truth["eyes"][s])
        rows.append(row)
        print(f"{row['triangles']:>8} tris  {row['median_s']:6.2f} s  " + "  ".join(
            f"{s}: c {row[s]['center_error_mm']:.3f} r {row[s]['radius_error_mm']:+.3f} "
            f"loop {row[s]['loop_to_margin_mean_mm']:.3f} fwd {row[s]['forward_error_deg']:.1f}"
            for s in ("left", "right")))
    out = RESULTS / (args.out or "remove_eyeballs.json")
    out.write_text(json.dumps({"seed": args.seed, "noise_mm": args.noise, "repeats": args.repeats,
                               "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
