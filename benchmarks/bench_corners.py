"""Corner strips and the caruncle on built heads: what the snap closes, and where the cornea meets it.

    .venv/bin/python -m benchmarks.bench_corners --work W [--work W2 ...] [--scratch DIR]
        [--results benchmarks/results] [--out corners] [--only CASE ...]   (scratch: benchmarks/out/corners)

For every case of a ``bench_unseen_scans --work W`` run that reached a bake
(``W/build/<case>/bake``), this checkout's snap and rig run again (W's params.yaml and eyeball)
into ``--scratch``, and per head it reports:

* ``caruncle_faces``, ``strip_vertices`` and ``mound_vertices`` (the caruncle's rows between the
  lid margin and the strip's inner edge, :func:`pipeline.geometry.corners.close_corners`);
* the faces the snap left turned over (``snap_flipped_faces``), whether the rig took it, its
  sweep's flipped faces and ``strip_max_mm`` (the inner edge's
  largest distance outside the eye over the pitch sweep: negative, it stays inside);
* ``cornea_at_rest_mm``: the deepest point of a strip inside the eye's outer surface where that
  surface is the cornea's bulge (outside the sphere), at rest: each segment from a loop vertex to
  its inner edge sampled at 19 points, and every mound vertex (0 when none is);
* ``cornea_at_yaw_mm``: the same for the strip's vertices with the eye turned in yaw over
  +-``max_yaw_deg`` (15 steps): the strip is fixed to the lids, the cornea turns under it.

Writes ``<results>/<out>.json`` (per head and a summary).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from tests.fixtures.corners import TOUCH_MM, measure_head

ROOT = Path(__file__).resolve().parents[1]


def run_head(work: Path, case: str, scratch: Path) -> dict:
    """Snap and rig of ``case`` with this checkout; its figures."""
    from pipeline.io.eyes_file import read_eyes
    from pipeline.io.meshfile import load_mesh
    from stages import rig as rig_stage
    from stages import snap as snap_stage
    from stages._common import run_stage

    b, o = work / "build" / case, scratch / f"{work.name}_{case}"
    params, eyeball = work / "params.yaml", work / "assets" / "eyeball"
    rc = run_stage(snap_stage.main, [str(b / "bake"), str(b / "remove_eyeballs"), str(eyeball), str(o / "snap"),
                                     "--params", str(params), "--metrics", str(o / "snap.json")])
    if rc != 0:
        return {"case": case, "set": work.name, "snap_ok": False}
    res = {"case": case, "set": work.name, "snap_ok": True,
           "snap_flipped_faces": json.loads((o / "snap.json").read_text()).get("flipped_faces"),
           **measure_head(dict(load_mesh(o / "snap" / "mesh.npz")), read_eyes(o / "snap" / "eyes.json"))}
    rc = run_stage(rig_stage.main, [str(o / "snap"), str(o / "rig"), "--eyeball", str(eyeball),
                                    "--params", str(params), "--metrics", str(o / "rig.json")])
    res["rig_ok"] = rc == 0
    if rc == 0:
        m = json.loads((o / "rig.json").read_text())
        res["sweep_flipped_faces"] = m.get("sweep_flipped_faces")
        res["strip_max_mm"] = m.get("sweep_strip_max_mm")
    return res


def summary(rows: list[dict]) -> dict:
    ok = [r for r in rows if r.get("snap_ok")]
    strips = [r for r in ok if r["strip_vertices"]]
    edge = [r["strip_max_mm"] for r in strips if r.get("strip_max_mm") is not None]
    return {"heads": len(rows), "snapped": len(ok), "rigged": sum(bool(r.get("rig_ok")) for r in ok),
            "with_strips": len(strips), "with_caruncle": sum(r["caruncle_faces"] > 0 for r in ok),
            "mound_vertices": sum(r["mound_vertices"] for r in ok),
            "flipped_in_snap": sum((r.get("snap_flipped_faces") or 0) > 0 for r in ok),
            "flipped_in_sweep": sum((r.get("sweep_flipped_faces") or 0) > 0 for r in ok),
            "strip_edge_max_mm": max(edge) if edge else None,
            "cornea_at_rest": sum(r["cornea_at_rest_mm"] > TOUCH_MM for r in strips),
            "cornea_at_rest_max_mm": max((r["cornea_at_rest_mm"] for r in strips), default=0.0),
            "cornea_at_yaw": sum(r["cornea_at_yaw_mm"] > TOUCH_MM for r in strips),
            "cornea_at_yaw_max_mm": max((r["cornea_at_yaw_mm"] for r in strips), default=0.0)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, action="append", required=True,
                    help="a bench_unseen_scans work dir (repeat for several)")
    ap.add_argument("--scratch", type=Path, default=ROOT / "benchmarks" / "out" / "corners",
                    help="where the heads are snapped and rigged again")
    ap.add_argument("--results", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--out", default="corners")
    ap.add_argument("--only", nargs="*", default=None, help="these cases only")
    args = ap.parse_args(argv)
    rows = []
    for work in args.work:
        for b in sorted((work / "build").glob("*/bake")):
            if args.only and b.parent.name not in args.only:
                continue
            rows.append(run_head(work, b.parent.name, args.scratch))
            print(json.dumps(rows[-1]), flush=True)
    doc = {"summary": summary(rows), "heads": rows}
    args.results.mkdir(parents=True, exist_ok=True)
    (args.results / f"{args.out}.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(doc["summary"], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
