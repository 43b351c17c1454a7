"""The band round each eye on heads already placed: ``retopo -> bake -> snap -> rig`` from each
head's cached ``remove_eyeballs`` output, then per band (each eye) its smallest angle (each quad
as its two triangles), its faces turned against the scan at rest, and whether the head rigs (the
lid sweep refuses a fold). Issue 30 asks for 20 deg everywhere in the band.

    .venv/bin/python -m benchmarks.bench_band --set seed5=<builds>:<params.yaml> \\
        [--set heldout=<builds>:<params.yaml> ...] --work <dir> [--out band_angles]

``<builds>`` holds ``<head>/remove_eyeballs`` (``bench_identities --work``'s ``build``,
``bench_unseen_scans --work``'s ``build``); ``<params.yaml>`` the params they were built with.
A head whose ``rig.metrics.json`` is already in ``<dir>/<set>/<head>`` is not built again, so
the same call only reports on a finished work dir. Writes ``benchmarks/results/<out>.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.results_files import write_results

ROOT = Path(__file__).resolve().parents[1]
EYEBALL = ROOT / "rigged_assets" / "eyeball"


def parse_sets(parser: argparse.ArgumentParser, specs: list[str]) -> list[tuple[str, Path, Path]]:
    """``(name, builds, params)`` of each ``NAME=BUILDS:PARAMS``; a malformed or missing one ends
    the run through ``parser.error`` (exit 2, one line naming it) before anything is built."""
    sets = []
    for spec in specs:
        name, _, rest = spec.partition("=")
        builds, _, params = rest.rpartition(":")
        if not name or not builds or not params:
            parser.error(f"--set {spec}: give NAME=BUILDS:PARAMS")
        if not Path(builds).is_dir() or not Path(params).is_file():
            parser.error(f"--set {spec}: {builds if not Path(builds).is_dir() else params} does not exist")
        sets.append((name, Path(builds), Path(params)))
    return sets


def build(re_dir: Path, params: Path, out: Path) -> str | None:
    """Retopo to rig for one head into ``out``; None, or the refusing stage's last line."""
    out.mkdir(parents=True, exist_ok=True)
    args = {"retopo": [re_dir, out / "retopo"],
            "bake": [out / "retopo", re_dir, out / "bake"],
            "snap": [out / "bake", re_dir, EYEBALL, out / "snap"],
            "rig": [out / "snap", out / "rig", "--eyeball", EYEBALL]}
    for stage, a in args.items():
        r = subprocess.run([sys.executable, "-m", f"stages.{stage}", *map(str, a), "--params", str(params),
                            "--metrics", str(out / f"{stage}.metrics.json")], cwd=ROOT, capture_output=True, text=True)
        if r.returncode != 0:
            return f"{stage}: " + (r.stderr.strip().splitlines() or ["?"])[-1]
    return None


def row(out: Path, refused: str | None) -> dict:
    m = json.loads((out / "retopo.metrics.json").read_text()) if (out / "retopo.metrics.json").is_file() else {}
    bands = {side: {"min_angle_deg": b["min_angle_deg"], "flipped_faces": b["flipped_faces"],
                    "flipped_at_ring_spoke": b["flipped_at_ring_spoke"]}
             for side, b in m.get("band", {}).items() if isinstance(b, dict) and "min_angle_deg" in b}
    return {"head": out.name, "rigs": refused is None and (out / "rig.metrics.json").is_file(),
            "refused": refused, "bands": bands}


def summary(rows: list[dict]) -> dict:
    angles = [b["min_angle_deg"] for r in rows for b in r["bands"].values()]
    return {"heads": len(rows), "rig": sum(r["rigs"] for r in rows), "bands": len(angles),
            "bands_under_20_deg": sum(a < 20.0 for a in angles),
            "bands_with_a_flipped_face": sum(b["flipped_faces"] > 0 for r in rows for b in r["bands"].values()),
            "smallest_angle_deg": round(min(angles), 2) if angles else None,
            "median_band_smallest_deg": round(float(np.median(angles)), 2) if angles else None,
            "under_20": sorted(f"{r['head']} {s} {b['min_angle_deg']:.1f}" for r in rows
                               for s, b in r["bands"].items() if b["min_angle_deg"] < 20.0)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--set", action="append", required=True, metavar="NAME=BUILDS:PARAMS")
    p.add_argument("--work", type=Path, required=True)
    p.add_argument("--out", default="band_angles")
    a = p.parse_args(argv)
    result = {}
    for name, builds, params in parse_sets(p, a.set):
        rows = []
        for re_dir in sorted(builds.glob("*/remove_eyeballs")):
            out = a.work / name / re_dir.parent.name
            refused = None
            if not (out / "rig.metrics.json").is_file():
                refused = build(re_dir, params, out)
            rows.append(row(out, refused))
            print(name, out.name, "rigs" if rows[-1]["rigs"] else f"refused ({refused})",
                  {s: b["min_angle_deg"] for s, b in rows[-1]["bands"].items()}, flush=True)
        result[name] = {"summary": summary(rows), "rows": rows}
        print(name, json.dumps(result[name]["summary"]))
    write_results(a.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
