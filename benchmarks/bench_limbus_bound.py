"""How close to scanify's limbus a perfect reader of the scan's iris could place the eye.

The placement benchmark's bound (``bench_placement``, *ICT disc*) reads ICT-FaceKit's iris disc
perfectly and puts the limbus on the disc's axis line at the truth's own limbus depth. That depth
is not in the scan: the scan samples the iris disc (through the clear cornea) and the sclera
round it, and the surface shows no edge where ICT's limbus ring lies. This benchmark measures
what the depth costs. Per open eye of every generated scanify head (its ``ground_truth.json``
and ICT-FaceKit rebuilt by ``tests.fixtures.unseen.iris_truth.visible_iris``):

- ``beside_mm``: how far the truth's limbus centre lies off the disc's axis line (the *ICT disc*
  bound's error);
- ``height_mm``: how far the disc's centre stands in front of the truth's limbus centre, along the
  disc's normal.

A reader who knows the disc exactly and one height for every head (the best one: the median of
these heads' heights, chosen on them) misses the limbus by ``hypot(beside, height - median)``.
No scan-read height can do better unless the scan shows the limbus's depth, which it does not.

    .venv/bin/python -m benchmarks.bench_limbus_bound --work W1 [W2 ...]

``W``: work folders of ``bench_unseen_scans`` / ``bench_placement`` (``W/scans/<case>/``); only the
cases already generated count. Writes ``benchmarks/results/limbus_bound.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from tests.fixtures.unseen.cases import ALL_CASES
from tests.fixtures.unseen.iris_truth import visible_iris

ROOT = Path(__file__).resolve().parents[1]


def eye_heights(doc: dict, scanify: Path, ict: Path) -> dict:
    """side -> ``(height_mm, beside_mm)`` of one scanify head's ``ground_truth.json`` ``doc``."""
    vi = visible_iris(doc, scanify, ict)
    out = {}
    for side in ("left", "right"):
        lt = np.asarray(doc["eyes"][side]["limbus"]["center_mm"], float)
        v = vi[side]
        out[side] = (float((v["center"] - lt) @ v["normal"]), float(np.linalg.norm(v["limbus_center"] - lt)))
    return out


def bound_summary(height, beside) -> dict:
    """The two bounds over eyes ``height`` (k,) and ``beside`` (k,) (mm): at the truth's depth
    and at one height for all (the median)."""
    height, beside = np.asarray(height, float), np.asarray(beside, float)
    h0 = float(np.median(height))
    one = np.hypot(beside, height - h0)
    pct = (lambda m: round(100.0 * float(np.mean(m)), 1))
    return {"eyes": int(len(height)),
            "height_median_mm": round(h0, 3), "height_sd_mm": round(float(np.std(height)), 3),
            "height_range_mm": [round(float(height.min()), 3), round(float(height.max()), 3)],
            "truth_depth_within_0_5mm_pct": pct(beside <= 0.5), "truth_depth_within_1mm_pct": pct(beside <= 1.0),
            "one_height_within_0_5mm_pct": pct(one <= 0.5), "one_height_within_1mm_pct": pct(one <= 1.0),
            "one_height_err_median_mm": round(float(np.median(one)), 3)}


def page(doc: dict) -> str:
    cols = [("eyes", "eyes"), ("height_median_mm", "disc height median mm"), ("height_sd_mm", "SD mm"),
            ("truth_depth_within_0_5mm_pct", "at the truth's depth: ≤ 0.5 mm %"),
            ("one_height_within_0_5mm_pct", "one height: ≤ 0.5 mm %"),
            ("one_height_within_1mm_pct", "one height: ≤ 1 mm %"),
            ("one_height_err_median_mm", "one height: median mm")]
    out = ["# The limbus a perfect reader of the scan's iris could place", "",
           "`python -m benchmarks.bench_limbus_bound --work W ...` over every generated scanify head "
           "with open eyes (module doc). *Disc height*: how far ICT-FaceKit's iris disc stands in "
           "front of scanify's limbus centre, by identity and gaze. *At the truth's depth*: the disc's "
           "axis line at the truth's limbus depth (`bench_placement`'s *ICT disc* bound). *One "
           "height*: the same line at the median height for every eye, the best a reader can do "
           "when the scan shows no edge at the limbus.", "",
           "| set | " + " | ".join(t for _, t in cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for name, sm in [("all", doc["summary"])] + sorted(doc["per_set"].items()):
        out.append(f"| {name} | " + " | ".join(str(sm[k]) for k, _ in cols) + " |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", nargs="+", type=Path, required=True)
    ap.add_argument("--scanify", default=str(ROOT.parent / "shared" / "tools" / "scanify" / "scanify.py"), type=Path)
    ap.add_argument("--ict", default=str(ROOT.parent / "shared" / "scans" / "ict_facekit"), type=Path)
    ap.add_argument("--results", default=str(ROOT / "benchmarks" / "results"), type=Path)
    a = ap.parse_args(argv)
    if not a.scanify.is_file() or not a.ict.is_dir():
        print(f"error: {a.scanify} or {a.ict} not found: the bound rebuilds ICT-FaceKit's eyes", file=sys.stderr)
        return 2
    rows = []
    for case in ALL_CASES:
        if case.get("kind") != "scanify" or case.get("expect", "asset") != "asset":
            continue
        gt = next((w / "scans" / case["name"] / "ground_truth.json" for w in a.work
                   if (w / "scans" / case["name"] / "ground_truth.json").is_file()), None)
        if gt is None:
            continue
        for side, (h, b) in eye_heights(json.loads(gt.read_text()), a.scanify, a.ict).items():
            rows.append({"case": case["name"], "set": case["set"], "family": case["family"], "side": side,
                         "height_mm": round(h, 4), "beside_mm": round(b, 4)})
    if not rows:
        print("error: no generated scanify head with open eyes under " + ", ".join(map(str, a.work)), file=sys.stderr)
        return 2
    group = (lambda s: "dev" if s == "dev" else "heldout" if s == "heldout" else "fresh")
    per_set = {}
    for g in sorted({group(r["set"]) for r in rows}):
        sel = [r for r in rows if group(r["set"]) == g]
        per_set[g] = bound_summary([r["height_mm"] for r in sel], [r["beside_mm"] for r in sel])
    doc = {"summary": {**bound_summary([r["height_mm"] for r in rows], [r["beside_mm"] for r in rows]),
                       "heads": len({r["case"] for r in rows})},
           "per_set": per_set, "eyes": rows}
    a.results.mkdir(parents=True, exist_ok=True)
    (a.results / "limbus_bound.json").write_text(json.dumps(doc, indent=1) + "\n")
    (a.results / "limbus_bound.md").write_text(page(doc))
    print(json.dumps(doc["summary"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
