"""Eye-region anatomy of the procedural identities against the population (issue 29).

    .venv/bin/python -m benchmarks.bench_synthetic_anatomy [--n 20] [--seed 0] [--triangles 150000]

Generates the heads that ``python -m stages.identities --n N --seed S`` lists (identity ``i`` drawn
by :func:`pipeline.synthetic_head.identities.draw_identity`, over params.yaml's
``synthetic_head:`` block) and measures, per eye, from the generated head's ground truth: the
eyeball radius r1, the fissure's width (canthus to canthus) and height, each canthus in front of
the centre along the gaze and off the globe, and the lid margin's standoff off the globe between
the canthi (20-95 % of the way from the medial canthus). Writes
benchmarks/results/synthetic_head_anatomy.json and prints a table; the page is
benchmarks/results/synthetic_head_anatomy.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from pipeline.io.atomic import write_json
from pipeline.synthetic_head import SyntheticHeadSettings, make_synthetic_head
from pipeline.synthetic_head.identities import draw_identity, identity_name

ROOT = Path(__file__).resolve().parents[1]
#: The population figures (UnityEyes' eight registered regions; adult fissures): (lo, hi) ranges.
TARGETS = {"radius_mm": (11.7 - 3 * 0.45, 11.7 + 3 * 0.45), "width_mm": (27 - 2 * 1.7, 27 + 2 * 1.7),
           "height_mm": (9.5 - 2 * 1.5, 9.5 + 2 * 1.5), "medial_in_front_mm": (7.0, 10.0),
           "lateral_in_front_mm": (2.0, 6.0), "standoff_min_mm": (0.35, 2.1), "standoff_max_mm": (0.35, 2.1)}


def eye_row(gt_eye) -> dict:
    m = gt_eye["eyelid_margin"]
    st = m["distance_to_eyeball_sphere_mm"]["between_canthi"]
    return {"radius_mm": gt_eye["eyeball_sphere"]["radius_mm"], "width_mm": m["width_mm"],
            "height_mm": m["height_mm"],
            "medial_in_front_mm": m["medial_canthus"]["in_front_mm"],
            "medial_off_globe_mm": m["medial_canthus"]["off_globe_mm"],
            "lateral_in_front_mm": m["lateral_canthus"]["in_front_mm"],
            "lateral_off_globe_mm": m["lateral_canthus"]["off_globe_mm"],
            "standoff_min_mm": st["min"], "standoff_mean_mm": st["mean"], "standoff_max_mm": st["max"]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--triangles", type=int, default=150_000)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "synthetic_head_anatomy.json"))
    args = ap.parse_args(argv)
    base = yaml.safe_load((ROOT / "params.yaml").read_text())["synthetic_head"]
    rows = []
    for i in range(args.n):
        entry = draw_identity(args.seed, i, args.triangles)
        s = SyntheticHeadSettings.from_params({**base, **entry, "texture_size": 16})
        gt = make_synthetic_head(s).ground_truth
        for side in ("left", "right"):
            rows.append({"identity": identity_name(args.seed, i), "side": side,
                         "hoodedness": entry["eye_shape"], **eye_row(gt["eyes"][side])})
    keys = [k for k in rows[0] if k.endswith("_mm")]
    summary = {}
    for k in keys:
        v = np.array([r[k] for r in rows], float)
        summary[k] = {"min": round(float(v.min()), 3), "mean": round(float(v.mean()), 3),
                      "sd": round(float(v.std(ddof=1)), 3), "max": round(float(v.max()), 3)}
        if k in TARGETS:
            lo, hi = TARGETS[k]
            summary[k]["target"] = [round(lo, 3), round(hi, 3)]
            summary[k]["outside_target"] = int(((v < lo) | (v > hi)).sum())
    same = all(rows[j]["radius_mm"] == rows[j + 1]["radius_mm"] for j in range(0, len(rows), 2))
    out = {"n_identities": args.n, "seed": args.seed, "triangles": args.triangles,
           "both_eyes_one_radius": bool(same), "summary": summary, "eyes": rows}
    write_json(args.out, out)
    print(f"{'measure':22s} {'min':>7s} {'mean':>7s} {'sd':>6s} {'max':>7s}  target     outside")
    for k, s in summary.items():
        t = s.get("target")
        print(f"{k:22s} {s['min']:7.2f} {s['mean']:7.2f} {s['sd']:6.2f} {s['max']:7.2f}  "
              + (f"{t[0]:.2f}-{t[1]:.2f} {s['outside_target']:3d}" if t else ""))
    print("both eyes one radius:", same)
    return out


if __name__ == "__main__":
    main()
