"""See-through and hidden irises in assets, from geometry: no render, every view of the previews.

    .venv/bin/python -m benchmarks.bench_see_through [NAME=ASSET_DIR:RIG_DIR ...] [--home]
        [--unseen WORK] [--results benchmarks/results] [--out see_through]

Issue 29 asks that no render see through an opening and that no asset's iris be hidden behind
the lids or turned into a corner at rest. A render sees through where a ray crossing the opening
meets neither the eyeball nor skin: the eye-region crop is one open sheet, so past the opening
lies background. Per asset and eye this rasterises (``pipeline.render.coverage``, the sampler's
own coverage test: posed skin triangles, back faces included, and the eyeball's silhouette) what
orthographic cameras see of the posed opening (the corneal cap, turned with the gaze,
included: a margin may rest on it), for

* gaze pitch -25, 0 and +25 deg, the lids following (the rig's pitch-to-weight rule), and
* five views: the head's front, 35 deg to either side (the preview's three-quarter view) and
  20 deg above and below,

and reports the uncovered area (mm^2) inside the opening (the loop's polygon in that view),
which the globe, the cornea or the lids must cover. Above ``SEE_THROUGH_MM2`` (a quarter of a
default render's pixel) a view sees through. Past the loop an uncovered pixel is the crop's
edge seen at a grazing angle, which the sampler keeps out of every render; it is not counted. The iris at rest, seen from the head's front: the share of its disc (pupil centre to
the iris landmarks, 3 rings of 8 points and the centre) that skin nearer the camera than the iris
covers; an iris more than half hidden is counted. Where the scan has a ground truth in the asset's frame
(``ground_truth.json`` beside a scan.yaml in mm, +Y up, +Z forward: the folder ingest recorded in
``build/<case>/ingest/scan.json``), the true iris under the same lids too: a look down, a squint or
a half blink hides more than half of the scanned person's own iris, so an asset's share is read
against it.

Seen from the head's front at gaze pitch 0 and +25 deg, the shape of what the lids leave open:
its solidity (area over its convex hull's) and its deepest notch (mm, the greatest distance of a
hull point outside it from the hull's border). An almond fissure is near convex; a lid spiked or
split where the band meets the margin notches it, and a notch over ``JAGGED_MM`` counts the eye
as jagged (``id302_up``'s toothed lower lids, ``id309_squint_up``'s lid flap: the previews).

``--home`` adds the three home scans' assets (rigged_assets/<scan>, build/<scan>/rig);
``--unseen WORK`` every asset a ``bench_unseen_scans --work WORK`` run left
(``WORK/assets/<case>_asset``, ``WORK/build/<case>/rig``). Writes ``<results>/<out>.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from tests.fixtures.see_through import HIDDEN_SHARE, JAGGED_MM, PITCHES, SEE_THROUGH_MM2, SHAPE_PITCHES, VIEWS, measure
from tests.fixtures.truth import truth_eyes

ROOT = Path(__file__).resolve().parents[1]
HOME = ("synthetic_head", "ict_neutral", "james")


def collect(args) -> list[tuple[str, Path, Path]]:
    items = []
    if args.home:
        for s in HOME:      # make run builds synthetic_head; the real scans' assets are the user's
            if (ROOT / "rigged_assets" / s).is_dir():
                items.append((s, ROOT / "rigged_assets" / s, ROOT / "build" / s / "rig"))
            else:
                print(f"skipped {s}: no rigged_assets/{s}")
    if args.unseen:
        w = Path(args.unseen)
        for a in sorted((w / "assets").glob("*_asset")):
            case = a.name[: -len("_asset")]
            if (w / "build" / case / "rig" / "rig.npz").is_file() and any(a.glob("*.usda")):
                items.append((case, a, w / "build" / case / "rig"))
    for spec in args.assets:
        name, rest = spec.split("=", 1)
        a, r = rest.split(":", 1)
        items.append((name, Path(a), Path(r)))
    return items


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("assets", nargs="*", help="NAME=ASSET_DIR:RIG_DIR")
    ap.add_argument("--home", action="store_true")
    ap.add_argument("--unseen", help="a bench_unseen_scans --work folder")
    ap.add_argument("--results", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--out", default="see_through")
    args = ap.parse_args(argv)
    rows = []
    for name, a, r in collect(args):
        row = measure(name, a, r, truth_eyes(r.parent / "ingest" / "scan.json"))
        rows.append(row)
        for side, e in row["eyes"].items():
            print(f"{name:28s} {side:5s} see-through {e['see_through_mm2']['mm2']:7.2f} mm2 "
                  f"({e['views_with_see_through']}/{e['views']} views"
                  f"{'; worst ' + e['see_through_mm2']['view'] + ' at pitch ' + format(e['see_through_mm2']['pitch_deg'], '+.0f') if e['see_through_mm2']['mm2'] > SEE_THROUGH_MM2 else ''})"
                  f"  iris hidden {100 * e['iris_hidden_share']:.0f} %"
                  + (f" (truth's {100 * e['truth_iris_hidden_share']:.0f} %)" if "truth_iris_hidden_share" in e else "")
                  + f"  opening notch {e['opening_concavity_mm']:.2f} mm{' (jagged)' if e['jagged'] else ''}")
    eyes = [e for r in rows for e in r["eyes"].values()]
    summary = {"assets": len(rows), "eyes": len(eyes),
               "assets_with_see_through": sum(any(e["see_through_mm2"]["mm2"] > SEE_THROUGH_MM2
                                                  for e in r["eyes"].values()) for r in rows),
               "eyes_with_see_through": sum(e["see_through_mm2"]["mm2"] > SEE_THROUGH_MM2 for e in eyes),
               "see_through_mm2": SEE_THROUGH_MM2,
               "irises_hidden": sum(e["iris_hidden"] for e in eyes),
               # against the scanned person's own iris, where the truth is known
               "eyes_with_truth": len(tr := [e for e in eyes if "truth_iris_hidden_share" in e]),
               "true_irises_hidden": sum(e["truth_iris_hidden_share"] > HIDDEN_SHARE for e in tr),
               "irises_hidden_beyond_truth": sum(e["iris_hidden"] and e["iris_hidden_share"] > e["truth_iris_hidden_share"]
                                                 for e in tr),
               "most_hidden_beyond_truth": max((round(e["iris_hidden_share"] - e["truth_iris_hidden_share"], 3)
                                                for e in tr), default=None),
               # the lids' shape seen from the front: a notch deeper than JAGGED_MM is a spiked or split lid
               "jagged_mm": JAGGED_MM, "jagged_eyes": sum(e["jagged"] for e in eyes),
               "jagged": sorted(f"{r['asset']} {s} {e['opening_concavity_mm']:.2f}" for r in rows
                                for s, e in r["eyes"].items() if e["jagged"]),
               "median_opening_concavity_mm": float(np.median([e["opening_concavity_mm"] for e in eyes])) if eyes else None,
               "views": {"pitches_deg": list(PITCHES), "cameras": VIEWS, "shape_pitches_deg": list(SHAPE_PITCHES)},
               "hidden_share": HIDDEN_SHARE}
    print(json.dumps({k: v for k, v in summary.items() if k != "views"}))
    out = Path(args.results) / f"{args.out}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
