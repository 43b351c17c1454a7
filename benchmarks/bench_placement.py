"""Eye placement on unseen heads: ``ingest`` + ``remove_eyeballs`` (with the eye-region prior)
on the cases of ``bench_unseen_scans`` (dev or held-out set), each eye against its truth.

Per eye: the centre and radius errors against scanify's ``eyeball_sphere``, the stated 1-sigma
``uncertainty_mm`` and whether the eye is doubted. Per set: how many eyes land within 1 / 2 mm,
how often the truth lies within 2 sigma, how many eyes are doubted, and the silent ones (off by
more than 1 or 2 mm with no doubt: the figure the stage's contract is about). A case expected
closed counts as right when refused as closed.

    .venv/bin/python -m benchmarks.bench_placement --set heldout [--work benchmarks/out/unseen]
        [--skip-missing]      # only the cases already generated (bench_unseen_scans --generate-only)

Writes ``benchmarks/results/placement_<set>.json`` (summary + per-eye rows).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.unseen.cases import generate, select
from benchmarks.unseen.report import says_closed

ROOT = Path(__file__).resolve().parents[1]


def _stage(*args):
    return subprocess.run([sys.executable, "-m", *map(str, args)], cwd=ROOT, capture_output=True, text=True)


def place(scan: Path, build: Path) -> dict:
    """Run ingest (kept) and remove_eyeballs (fresh) on ``scan``; the stage's outcome."""
    if not (build / "ingest" / "mesh.npz").is_file():
        r = _stage("stages.ingest", scan, build / "ingest", "--metrics", build / "ingest.metrics.json")
        if r.returncode != 0:
            return {"refused": (r.stderr.strip().splitlines() or ["?"])[-1], "stage": "ingest"}
    shutil.rmtree(build / "remove_eyeballs", ignore_errors=True)
    r = _stage("stages.remove_eyeballs", build / "ingest", build / "remove_eyeballs",    # the shipped prior
               "--metrics", build / "remove_eyeballs.metrics.json")
    if r.returncode != 0:
        return {"refused": (r.stderr.strip().splitlines() or ["?"])[-1], "stage": "remove_eyeballs"}
    return {"eyes": json.loads((build / "remove_eyeballs" / "eyes.json").read_text())}


def eye_rows(case, truth: dict, eyes: dict) -> list:
    rows = []
    for side in ("left", "right"):
        e, g = eyes[side], truth[side]["eyeball_sphere"]
        u = e.get("uncertainty_mm") or {}
        rows.append({"case": case["name"], "family": case["family"], "side": side,
                     "center_err_mm": float(np.linalg.norm(np.asarray(e["center"]) - g["center_mm"])),
                     "radius_err_mm": float(e["radius"] - g["radius_mm"]),
                     "sigma_center_mm": u.get("center"), "doubts": list(e.get("doubts") or []),
                     "placement": e.get("placement")})
    return rows


def summary(rows: list, outcomes: list) -> dict:
    e = np.array([r["center_err_mm"] for r in rows])
    dr = np.abs([r["radius_err_mm"] for r in rows])
    s = np.array([r["sigma_center_mm"] if r["sigma_center_mm"] is not None else np.nan for r in rows])
    d = np.array([bool(r["doubts"]) for r in rows])
    closed_ok = sum(o["expect"] == "closed" and o["closed"] for o in outcomes)
    pct = (lambda m: round(100.0 * float(np.mean(m)), 1) if len(rows) else None)
    return {"cases": len(outcomes), "refused": sum("refused" in o for o in outcomes),
            "closed_refused_as_closed": closed_ok,
            "closed_cases": sum(o["expect"] == "closed" for o in outcomes),
            "open_refused": sum("refused" in o and o["expect"] != "closed" for o in outcomes),
            "eyes": len(rows), "center_within_1mm_pct": pct(e <= 1), "center_within_2mm_pct": pct(e <= 2),
            "radius_within_1mm_pct": pct(dr <= 1),
            "truth_within_2sigma_pct": pct(e[np.isfinite(s)] <= 2 * s[np.isfinite(s)]) if np.isfinite(s).any() else None,
            "doubted_pct": pct(d), "silent_over_1mm": int(np.sum((e > 1) & ~d)),
            "silent_over_2mm": int(np.sum((e > 2) & ~d)),
            "center_err_median_mm": round(float(np.median(e)), 3) if len(rows) else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="heldout", choices=("dev", "heldout", "all"), dest="set_name")
    ap.add_argument("--work", default=str(ROOT / "benchmarks" / "out" / "unseen"), type=Path)
    ap.add_argument("--scanify", default=str(ROOT.parent / "shared" / "tools" / "scanify" / "scanify.py"))
    ap.add_argument("--ict", default=str(ROOT.parent / "shared" / "scans" / "ict_facekit"))
    ap.add_argument("--skip-missing", action="store_true", help="only the cases already generated")
    ap.add_argument("--results", default=str(ROOT / "benchmarks" / "results"), type=Path)
    a = ap.parse_args(argv)
    rows, outcomes = [], []
    for case in select(a.set_name):
        folder = a.work / "scans" / case["name"]
        if not (folder / ".case").is_file():
            if a.skip_missing:
                print(f"{case['name']:28s} not generated, skipped", flush=True)
                continue
            folder = generate(case, a.work, Path(a.scanify), Path(a.ict))
        res = place(folder, a.work / "placement" / case["name"])
        o = {"case": case["name"], "family": case["family"], "expect": case.get("expect", "asset")}
        if "refused" in res:
            res["refused"] = res["refused"].replace(f"{a.work}/", "")      # no machine's paths in results
            o.update(refused=res["refused"], closed=says_closed(res["refused"]))
            print(f"{case['name']:28s} refused: {res['refused'][:110]}", flush=True)
        else:
            o["closed"] = False
            truth = json.loads((folder / "ground_truth.json").read_text())["eyes"]
            r = eye_rows(case, truth, res["eyes"])
            rows += r
            print(f"{case['name']:28s} " + " | ".join(
                f"{x['side'][0]}: {x['center_err_mm']:.2f} mm (sigma {x['sigma_center_mm'] or 0:.2f}) "
                f"r {x['radius_err_mm']:+.2f} d{len(x['doubts'])}" for x in r), flush=True)
        outcomes.append(o)
    ict = [r for r in rows if r["family"] != "synthetic"]
    doc = {"set": a.set_name, "summary": summary(rows, outcomes),
           "summary_ict": summary(ict, [o for o in outcomes if o["family"] != "synthetic"]),
           "outcomes": outcomes, "eyes": rows}
    a.results.mkdir(parents=True, exist_ok=True)
    out = a.results / f"placement_{a.set_name}.json"
    out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc["summary"]), f"\n-> {out.relative_to(ROOT) if out.is_relative_to(ROOT) else out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
