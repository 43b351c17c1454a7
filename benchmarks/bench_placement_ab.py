"""Two versions of the placement side by side on every cached unseen head, against the truth.

    .venv/bin/python -m benchmarks.bench_placement_ab --a TREE_A --b TREE_B WORK [WORK ...]
        [--only NAME,...] [--results benchmarks/results] [--out placement_ab]

A change to the placement is measured on heads it was not made for: every head that a
``bench_unseen_scans --work WORK`` run left (``WORK/build/<case>/ingest`` and the truth in
``WORK/scans/<case>/ground_truth.json``) goes through ``stages.remove_eyeballs`` once with each
source tree first on ``PYTHONPATH`` (``TREE_A`` before, ``TREE_B`` after; the run's own
``WORK/params.yaml``). Per head: whether each published or refused (the refusal's last line),
whether ``eyes.json`` and ``mesh.npz`` are byte-identical, and per eye the limbus centre's and
the axis's errors and sigmas (:func:`benchmarks.bench_placement.eye_rows`). The summary counts
the heads changed, refusals gained and lost, and the eye figures over the eyes both placed.
Writes ``<results>/<out>.json``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.bench_placement import eye_rows

SIDES = ("left", "right")


def _digest(p: Path):
    return hashlib.sha1(p.read_bytes()).hexdigest()[:16] if p.is_file() else None


def run(tree: Path, work: Path, case: str, out: Path) -> dict:
    """``stages.remove_eyeballs`` on ``case``'s ingest with ``tree`` first on the path."""
    r = subprocess.run([sys.executable, "-m", "stages.remove_eyeballs", str(work / "build" / case / "ingest"),
                        str(out), "--params", str(work / "params.yaml"), "--metrics", str(out) + ".metrics.json"],
                       cwd=tempfile.gettempdir(), capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(tree)})
    if r.returncode:
        return {"refused": (r.stderr.strip().splitlines() or ["?"])[-1]}
    return {"eyes": json.loads((out / "eyes.json").read_text()), "digest": [_digest(out / "eyes.json"),
                                                                            _digest(out / "mesh.npz")]}


def compare(a: dict, b: dict, truth: dict, case: str) -> dict:
    row = {"case": case, "same": a.get("digest") == b.get("digest") and a.get("refused") == b.get("refused")}
    for tag, res in (("a", a), ("b", b)):
        if "refused" in res:
            row[tag] = {"refused": res["refused"]}
            continue
        rows = eye_rows({"name": case, "family": ""}, truth, res["eyes"])
        row[tag] = {r["side"]: {k: r[k] for k in ("limbus_err_mm", "axis_err_deg", "sigma_limbus_mm",
                                                  "sigma_axis_deg", "limbus_source")} for r in rows}
    return row


def _within_2sigma(e: dict) -> bool:
    return (e["limbus_err_mm"] <= 2.0 * (e["sigma_limbus_mm"] or 0.0)
            and e["axis_err_deg"] <= 2.0 * (e["sigma_axis_deg"] or 0.0))


def summary(rows: list) -> dict:
    both = [r for r in rows if "refused" not in r["a"] and "refused" not in r["b"]]
    out = {"heads": len(rows), "changed": sum(not r["same"] for r in rows),
           "published_only_a": [r["case"] for r in rows if "refused" in r["b"] and "refused" not in r["a"]],
           "published_only_b": [r["case"] for r in rows if "refused" in r["a"] and "refused" not in r["b"]],
           "eyes_both": 2 * len(both)}
    for tag in ("a", "b"):
        eyes = [r[tag][s] for r in both for s in SIDES]
        le = np.array([e["limbus_err_mm"] for e in eyes])
        ae = np.array([e["axis_err_deg"] for e in eyes])
        out[tag] = {"limbus_within_0_5mm_pct": round(100 * float(np.mean(le <= 0.5)), 1) if len(eyes) else None,
                    "limbus_within_1mm_pct": round(100 * float(np.mean(le <= 1.0)), 1) if len(eyes) else None,
                    "axis_within_2deg_pct": round(100 * float(np.mean(ae <= 2.0)), 1) if len(eyes) else None,
                    "truth_within_2sigma_pct": round(100 * float(np.mean([_within_2sigma(e) for e in eyes])), 1)
                    if len(eyes) else None}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path, nargs="+", help="bench_unseen_scans --work folders")
    ap.add_argument("--a", type=Path, required=True, help="the source tree before (on PYTHONPATH)")
    ap.add_argument("--b", type=Path, required=True, help="the source tree after")
    ap.add_argument("--only", default="", help="comma-separated case names")
    ap.add_argument("--results", type=Path, default=Path("benchmarks/results"))
    ap.add_argument("--out", default="placement_ab")
    args = ap.parse_args(argv)
    only = {s for s in args.only.split(",") if s}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for work in args.work:
            for scan in sorted((work / "scans").iterdir()):
                case = scan.name
                if (only and case not in only) or not (work / "build" / case / "ingest" / "mesh.npz").is_file() \
                        or not (scan / "ground_truth.json").is_file():
                    continue
                truth = json.loads((scan / "ground_truth.json").read_text())["eyes"]
                a = run(args.a, work, case, Path(tmp) / f"{case}_a")
                b = run(args.b, work, case, Path(tmp) / f"{case}_b")
                row = compare(a, b, truth, case)
                rows.append(row)
                print(f"{case:36s} {'same' if row['same'] else 'CHANGED'}", flush=True)
    res = {"a": str(args.a), "b": str(args.b), "work": [str(w) for w in args.work], "summary": summary(rows),
           "rows": rows}
    args.results.mkdir(parents=True, exist_ok=True)
    (args.results / f"{args.out}.json").write_text(json.dumps(res, indent=1))
    print(json.dumps(res["summary"]))
    print(f"-> {args.results / args.out}.json")


if __name__ == "__main__":
    main()
