"""Benchmark the per-scan chain ingest -> remove_eyeballs -> retopo -> bake -> snap -> rig -> usd on a big synthetic head.

    .venv/bin/python -m benchmarks.bench_chain [--triangles 1400000] [--repeats 3] [--texture-size 1024]
                                               [--eyeball DIR] [--keep DIR]

Generates the synthetic head once (``make_synthetic_head`` + ``write_scan_folder`` into a temp folder),
builds the eyeball asset once (preview off) unless ``--eyeball`` names one, then runs each stage exactly as
dvc.yaml does (``python -m stages.<stage> ... --metrics ...``, params from ./params.yaml with the usd
stage's preview off: a scan to a validated USD asset) as a subprocess, timing its wall time. Repeated ``--repeats`` times; writes benchmarks/results/chain.json with the median per
stage and of the total, every run's times, and the last run's stage metrics (internal timings, accuracy)
plus accuracy against the ground truth (eye centre/radius error, loop-to-margin distance).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.eyes_file import read_eyes
from stages._common import read_stage_metrics

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "usd")


def stage_commands(scan, build, eyeball) -> dict:
    """``python -m`` arguments of each per-scan stage up to ``usd``, as dvc.yaml runs them
    (without ``--metrics`` / ``--params``), for a scan folder, a build folder and an eyeball asset."""
    b = Path(build)
    return {
        "ingest": ["stages.ingest", scan, b / "ingest"],
        "remove_eyeballs": ["stages.remove_eyeballs", b / "ingest", b / "remove_eyeballs"],
        "retopo": ["stages.retopo", b / "remove_eyeballs", b / "retopo"],
        "bake": ["stages.bake", b / "retopo", b / "remove_eyeballs", b / "bake"],
        "snap": ["stages.snap", b / "bake", b / "remove_eyeballs", eyeball, b / "snap"],
        "rig": ["stages.rig", b / "snap", b / "rig", "--eyeball", eyeball],
        # the asset beside the eyeball, as rigged_assets/ holds them (usdz packs the eyeball with it)
        "usd": ["stages.usd", b / "snap", b / "bake", b / "rig", b / "ingest", eyeball,
                Path(eyeball).parent / f"{Path(scan).name}_asset"],
    }


def timed_run(cmd):
    """Run ``cmd`` in the repository root; its wall time (s), or exit naming it and its stderr."""
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr[-3000:]}")
    return dt


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--triangles", type=int, default=1_400_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--texture-size", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--noise", type=float, default=0.02)
    ap.add_argument("--eyeball", default=None, help="existing eyeball asset folder (else built once)")
    ap.add_argument("--keep", default=None, help="work folder to use/keep (default: a temp folder)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "chain.json"))
    args = ap.parse_args()

    from pipeline.synthetic_head import make_synthetic_head, write_scan_folder

    tmp_ctx = None
    if args.keep:
        work = Path(args.keep)
        work.mkdir(parents=True, exist_ok=True)
    else:
        tmp_ctx = tempfile.TemporaryDirectory(prefix="bench_chain_")
        work = Path(tmp_ctx.name)
    py = [sys.executable, "-m"]
    scan = work / "scan"
    t0 = time.perf_counter()
    if not (scan / "ground_truth.json").exists():      # --keep: reuse a head written before
        head = make_synthetic_head(seed=args.seed, target_triangles=args.triangles, noise_mm=args.noise,
                                   texture_size=args.texture_size)
        scan.mkdir(parents=True, exist_ok=True)
        write_scan_folder(head, scan)
        del head
    gt = json.loads((scan / "ground_truth.json").read_text())
    gen_s = time.perf_counter() - t0
    print(f"synthetic head ready in {gen_s:.1f} s", flush=True)

    eyeball = work / "eyeball"
    if args.eyeball and not eyeball.exists():             # beside the asset, as rigged_assets/ holds them
        import shutil

        shutil.copytree(args.eyeball, eyeball)
    if not (eyeball / "eyeball.usda").exists():
        pfile = work / "eyeball_params.yaml"
        pfile.write_text("eyeball: {preview: false}\n")
        timed_run(py + ["stages.eyeball", str(eyeball), "--params", str(pfile),
                   "--metrics", str(work / "eyeball.metrics.json")])

    b = work / "build"
    cmds = stage_commands(scan, b, eyeball)
    import yaml

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params.setdefault("usd", {})["preview"] = False      # scan to validated USD (the preview is item 2's)
    pfile = work / "chain_params.yaml"
    pfile.write_text(yaml.safe_dump(params, sort_keys=False))
    runs = []
    for rep in range(args.repeats):
        times = {}
        for st in STAGES:
            cmd = py + [str(c) for c in cmds[st]] + ["--metrics", str(b / f"{st}.metrics.json"),
                                                     "--params", str(pfile)]
            times[st] = timed_run(cmd)
        times["total"] = sum(times[s] for s in STAGES)
        runs.append(times)
        print(f"run {rep + 1}: " + "  ".join(f"{k} {v:.2f}" for k, v in times.items()), flush=True)

    metrics = {st: read_stage_metrics(b / f"{st}.metrics.json") for st in STAGES}   # + timings
    eyes = {s: e.doc for s, e in read_eyes(b / "remove_eyeballs" / "eyes.json").items()}
    accuracy = {}
    for s in ("left", "right"):
        g, e = gt["eyes"][s], eyes[s]
        accuracy[s] = {
            "center_error_mm": float(np.linalg.norm(np.array(e["center"]) - g["eyeball_sphere"]["center_mm"])),
            "radius_error_mm": float(e["radius"] - g["eyeball_sphere"]["radius_mm"]),
            "loop_to_margin_mean_mm": float(closed_polyline_distance(
                np.array(e["loop_points"]), np.array(g["eyelid_margin"]["points_mm"])).mean()),
        }
    result = {
        "triangles": int(metrics["ingest"].get("n_faces", args.triangles)), "texture_size": args.texture_size, "repeats": args.repeats,
        "generate_s": gen_s,
        "median_s": {k: float(np.median([r[k] for r in runs])) for k in list(STAGES) + ["total"]},
        "runs_s": runs,
        "accuracy": accuracy,
        "stage_metrics": metrics,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print("median s: " + "  ".join(f"{k} {v:.2f}" for k, v in result["median_s"].items()))
    print("accuracy: " + json.dumps(accuracy))
    for st in STAGES:
        m = {k: v for k, v in metrics[st].items() if k.endswith("_s") or "error" in k or "removed" in k}
        print(f"  {st}: {json.dumps(m)}")
    if tmp_ctx is not None:
        tmp_ctx.cleanup()


if __name__ == "__main__":
    main()
