"""Rig trade-off: chord-sag target -> stored poses (inbetweens), accuracy, size and time.

    EYERIG_EXTRA_SCANS=/work/shared/scans .venv/bin/python -m benchmarks.bench_rig

On the ICT-FaceKit eye region (r = 15.4 mm eyes, margins projected onto the eyeball
spheres, as snap does) for each ``max_chord_sag_mm``: number of stored poses per
direction, the measured worst margin penetration over a 0.1-degree pitch sweep,
the size of the shape data (float32 offsets, as in USD) and the build time
(median of 5). Writes benchmarks/results/rig.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from benchmarks.compare_ict_lids import load_ict
from pipeline.io.atomic import write_json
from pipeline.rig import lids
from pipeline.rig.eye_frame import EyeFrame
from pipeline.rig.lid_shapes import build_lid_shapes
from pipeline.rig.sweep import sweep_check

ROOT = Path(__file__).resolve().parents[1]


def ict_eyes(V, remap, gt):
    eyes = []
    for side in ("left", "right"):
        g = gt["eyes"][side]
        loop = remap[np.asarray(g["eyelid_margin"]["ict_vertex_ids"])]
        c = np.asarray(g["eyeball_sphere"]["center_mm"], float)
        r = float(g["eyeball_sphere"]["radius_mm"])
        w = V[loop] - c
        V[loop] = c + r * w / np.linalg.norm(w, axis=1, keepdims=True)
        eyes.append(EyeFrame(side, c, r, np.asarray(g["gaze_direction"], float), loop,
                             int(g["eyelid_margin"]["lateral_canthus_index"])))
    return eyes


def main(argv=None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    scans = Path(os.environ.get("EYERIG_EXTRA_SCANS", ROOT.parent / "shared" / "scans"))
    V, F, remap, gt, _ = load_ict(scans)
    eyes = ict_eyes(V, remap, gt)
    pitches = np.arange(-25.0, 25.0 + 1e-9, 0.1)
    rows = []
    for target in (1.0, 0.1, 0.05, 0.03, 0.01, 0.005):
        params = lids.LidParams(max_chord_sag_mm=target, max_segments=64)
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            rig = build_lid_shapes(V, F, eyes, params)
            times.append(time.perf_counter() - t0)
        res = sweep_check(V, F, eyes, rig.shapes, pitches)
        n_floats = sum(s.offsets.size + s.inbetween_offsets.size for s in rig.shapes)
        rows.append({"max_chord_sag_mm": target, "poses_per_direction": rig.n_segments,
                     "predicted_sag_mm": rig.predicted_sag_mm,
                     "measured_max_penetration_mm": res["max_penetration_mm"],
                     "measured_max_gap_mm": res["max_gap_mm"],
                     "flipped_faces": res["flipped_faces"],
                     "offsets_mib_float32": n_floats * 4 / 2**20,
                     "build_s_median": float(np.median(times))})
    write_json(ROOT / "benchmarks" / "results" / "rig.json",
               {"mesh": "ICT-FaceKit face+head_neck", "n_vertices": int(len(V)),
                "sweep_step_deg": 0.1, "rows": rows})
    print("sag target  poses  predicted  measured pen  gap     MiB(f32)  build s")
    for r in rows:
        print(f"{r['max_chord_sag_mm']:10.3f}  {r['poses_per_direction']:5d}  "
              f"{r['predicted_sag_mm']:9.4f}  {r['measured_max_penetration_mm']:12.4f}  "
              f"{r['measured_max_gap_mm']:.1e}  {r['offsets_mib_float32']:8.3f}  "
              f"{r['build_s_median']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
