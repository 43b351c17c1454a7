"""rig + usd time for one eye region (target: at most 3 s together for ~9k polygons).

    .venv/bin/python -m benchmarks.bench_usd [BUILD_DIR [EYEBALL_DIR]]

BUILD_DIR defaults to build/synthetic_head (needs snap/, bake/, ingest/ from `dvc repro
snap@synthetic_head`), EYEBALL_DIR to rigged_assets/eyeball. Runs the two stage commands
exactly as dvc.yaml does (fresh Python processes, so interpreter start-up and imports count)
into a temporary folder, 5 times; reports the median wall time of each and of the pair, plus
the usd stage's own phase times (write / validate / usdz) from its metrics. Writes
benchmarks/results/usd.json and prints a summary.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from benchmarks.bench_chain import timed_run
from pipeline.io.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]

RUNS = 5


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("build", nargs="?", type=Path, default=ROOT / "build" / "synthetic_head", metavar="BUILD_DIR")
    ap.add_argument("eyeball", nargs="?", type=Path, default=ROOT / "rigged_assets" / "eyeball",
                    metavar="EYEBALL_DIR")
    args = ap.parse_args(argv)
    build, eyeball = args.build, args.eyeball
    py = sys.executable
    rows = []
    with tempfile.TemporaryDirectory() as td:
        td = Path(td)
        shutil.copytree(eyeball, td / "rigged_assets" / "eyeball")
        # The asset itself, not the optional Cycles contact sheet (benchmarks/bench_asset_preview.py).
        params = yaml.safe_load((ROOT / "params.yaml").read_text())
        (td / "params.yaml").write_text(yaml.safe_dump(params))
        common = ["--params", str(td / "params.yaml")]
        for i in range(RUNS):
            rig_out, usd_out = td / f"rig{i}", td / "rigged_assets" / f"scan{i}"
            t_rig = timed_run([py, "-m", "stages.rig", str(build / "snap"), str(rig_out), "--eyeball",
                          str(td / "rigged_assets" / "eyeball"), "--metrics", str(td / f"rig{i}.json"), *common])
            t_usd = timed_run([py, "-m", "stages.usd", str(build / "snap"), str(build / "bake"), str(rig_out),
                          str(build / "ingest"), str(td / "rigged_assets" / "eyeball"), str(usd_out),
                          "--metrics", str(td / f"usd{i}.json"), *common])
            m = json.loads((td / f"usd{i}.json").read_text())
            rows.append({"rig_s": t_rig, "usd_s": t_usd, "total_s": t_rig + t_usd,
                         **{k: m[k] for k in ("write_s", "validate_s", "usdz_s", "wall_time_s")}})
        mesh = np.load(build / "snap" / "mesh.npz")
        n_faces = int(len(mesh["F"]))
        usdz_mib = (usd_out / f"{usd_out.name}.usdz").stat().st_size / 2**20
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
    res = {"build": str(build), "n_faces": n_faces, "runs": RUNS, "median": med,
           "usdz_mib": usdz_mib, "target_total_s": 3.0, "rows": rows}
    write_json(ROOT / "benchmarks" / "results" / "usd.json", res)
    print(f"{n_faces} triangles, median of {RUNS} runs (fresh processes):")
    print(f"  rig stage {med['rig_s']:.2f} s + usd stage {med['usd_s']:.2f} s = {med['total_s']:.2f} s "
          f"(target <= 3 s: {'OK' if med['total_s'] <= 3.0 else 'MISSED'})")
    print(f"  usd phases: write {med['write_s']:.3f} s, validate {med['validate_s']:.3f} s, "
          f"usdz {med['usdz_s']:.3f} s (in-stage wall {med['wall_time_s']:.2f} s); usdz {usdz_mib:.1f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
