"""How well could any fit to the scanned sclera place the eyeball? An oracle bound on the unseen scans.

    .venv/bin/python -m benchmarks.bench_unseen_oracle [--work benchmarks/out/unseen] [--margin-mm 0 0.5 1]
        [--set all|dev|heldout] [--results benchmarks/results]

For every open-eyed ``--ideal-eyes`` ICT-FaceKit case of ``bench_unseen_scans``, dev and held out
(scans generated there with ``--generate-only``; filled openings have no sclera left to fit),
the sphere is fitted to the scan vertices that the truth says are exposed sclera: labelled
eyeball by scanify's ``--write-labels``, more than 33 deg from the true gaze (outside the limbus,
about 27-28 deg, with a seam margin), and more than ``margin`` mm from any skin vertex (away from
the lid fillet). The fit is a robust (soft-L1, 0.1 mm) geometric sphere fit started
0.9 mm off the truth. No pipeline code takes part: the segmentation, the gaze and the start come
from the truth, so no eye finder that reads the scanned eye surface can be expected to do better on
these scans. Writes ``<results>/unseen_oracle.json``: the summary over all cases, per set and per
family (``bench_unseen_scans --markdown`` puts the per-family figures beside its own).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from benchmarks.bench_unseen_scans import PLACE_MAX_MM, PLACE_MM, RESULTS, ROOT, SETS, SIDES, select

CONE_DEG = 33.0


def _read_ply(path):
    import trimesh

    m = trimesh.load(path, process=False)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def oracle_fit(P, center, radius):
    """Robust sphere fit to ``P`` (n, 3) started next to the truth; ``(center (3,), radius)``."""
    from scipy.optimize import least_squares

    def res(x):
        return np.linalg.norm(P - x[:3], axis=1) - x[3]

    x0 = np.append(np.asarray(center) + 0.5, radius + 0.5)  # 0.87 mm and 0.5 mm off
    x = least_squares(res, x0, loss="soft_l1", f_scale=0.1).x
    return x[:3], float(x[3])


def evaluate(folder: Path, margins) -> dict:
    from scipy.spatial import cKDTree

    V, _ = _read_ply(folder / "scan.ply")
    labels = np.load(folder / "scan_labels.npy")
    truth = json.loads((folder / "ground_truth.json").read_text())
    skin = cKDTree(V[labels == 0])
    row = {"faces": int(truth["mesh"]["n_faces"])}
    for side, lab in zip(SIDES, (1, 2)):
        eye = truth["eyes"][side]
        c = np.asarray(eye["eyeball_sphere"]["center_mm"])
        r = float(eye["eyeball_sphere"]["radius_mm"])
        g = np.asarray(eye["gaze_direction"], dtype=np.float64)
        P = V[labels == lab]
        w = P - c
        ang = np.degrees(np.arccos(np.clip(w @ g / np.linalg.norm(w, axis=1), -1, 1)))
        d_skin, _ = skin.query(P)
        row[side] = {"eye_vertices": int(len(P))}
        for m in margins:
            sclera = P[(ang > CONE_DEG) & (d_skin > m)]
            key = f"margin_{m:g}mm"
            if len(sclera) < 5:
                row[side][key] = {"sclera_vertices": int(len(sclera)), "center_error_mm": None,
                                  "radius_error_mm": None}
                continue
            cf, rf = oracle_fit(sclera, c, r)
            row[side][key] = {"sclera_vertices": int(len(sclera)),
                              "center_error_mm": round(float(np.linalg.norm(cf - c)), 4),
                              "radius_error_mm": round(rf - r, 4)}
    return row


def summary(rows, margins) -> dict:
    out = {}
    for m in margins:
        key = f"margin_{m:g}mm"
        errs = [max(abs(e[key]["center_error_mm"]), abs(e[key]["radius_error_mm"]))
                if e[key]["center_error_mm"] is not None else np.inf
                for r in rows.values() for e in (r["left"], r["right"])]
        errs = np.array(errs)
        if not len(errs):
            continue
        out[key] = {"eyes": int(len(errs)),
                    f"within_{PLACE_MM}mm": int((errs <= PLACE_MM).sum()),
                    f"within_{PLACE_MAX_MM}mm": int((errs <= PLACE_MAX_MM).sum()),
                    "too_few_sclera_vertices": int(np.isinf(errs).sum()),
                    "median_sclera_vertices": float(np.median(
                        [e[key]["sclera_vertices"] for r in rows.values() for e in (r["left"], r["right"])]))}
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "out" / "unseen"))
    ap.add_argument("--margin-mm", type=float, nargs="+", default=[0.0, 0.5, 1.0])
    ap.add_argument("--set", default="all", choices=("all",) + SETS, dest="set_name")
    ap.add_argument("--results", default=str(RESULTS), type=Path)
    a = ap.parse_args()
    rows, missing = {}, []
    for case in select(a.set_name):
        if case["kind"] != "scanify" or not case.get("ideal", True) or case["expect"] != "asset":
            continue
        folder = Path(a.work) / "scans" / case["name"]
        if not (folder / "scan_labels.npy").is_file():   # listed in the results, never silent
            missing.append(case["name"])
            print(f"{folder}: not generated (skipped; python -m benchmarks.bench_unseen_scans "
                  f"--generate-only makes it)", file=sys.stderr)
            continue
        rows[case["name"]] = {"family": case["family"], "set": case["set"],
                              **evaluate(folder, a.margin_mm)}
        print(case["name"], json.dumps({s: rows[case["name"]][s] for s in SIDES}), flush=True)
    res = {"cone_deg": CONE_DEG, "summary": summary(rows, a.margin_mm),
           "sets": {s: summary({k: r for k, r in rows.items() if r["set"] == s}, a.margin_mm)
                    for s in SETS},
           "families": {f: summary({k: r for k, r in rows.items() if r["family"] == f}, a.margin_mm)
                        for f in dict.fromkeys(r["family"] for r in rows.values())},
           "cases": rows, "not_generated": missing}
    a.results.mkdir(parents=True, exist_ok=True)
    (a.results / "unseen_oracle.json").write_text(json.dumps(res, indent=1) + "\n")
    print(json.dumps({"all": res["summary"], **res["sets"]}, indent=1))


if __name__ == "__main__":
    main()
