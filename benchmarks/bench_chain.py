"""Benchmark the per-scan chain ingest -> remove_eyeballs -> retopo -> bake -> snap -> rig -> usd on a big synthetic head.

    .venv/bin/python -m benchmarks.bench_chain [--triangles 1400000] [--repeats 3] [--texture-size 1024]
                                               [--eyeball DIR] [--keep DIR] [--compare CHECKOUT]

Generates the synthetic head once (``make_synthetic_head`` + ``write_scan_folder`` into a temp folder),
builds the eyeball asset once unless ``--eyeball`` names one, then runs each stage exactly as
dvc.yaml does (``python -m stages.<stage> ... --metrics ...``, params from ./params.yaml: a scan to a
validated USD asset, the previews being stages of their own) as a subprocess, timing its wall time and its
CPU time (user + system; hardly moved by other jobs on the machine). Repeated ``--repeats`` times;
writes benchmarks/results/chain.json with the median per stage and of the total, every run's times,
the load average before each run, each stage's import time (one more run with ``-X importtime``,
the imports done lazily inside functions included), and the last run's stage metrics (internal timings, accuracy)
plus accuracy against the ground truth (eye centre/radius error, loop-to-margin distance).

``--compare CHECKOUT`` runs another checkout's stages too (``git clone`` of the commit before a
change), alternating with this one's stage by stage, on the same head: the result gains both
medians, their ratios, and the files whose bytes differ between the two build folders and
assets (sha256; the timings files left out). The other checkout's usd runs without the preview it
rendered before the preview became a stage (``usd.preview: false`` where its params.yaml has the key).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.eyes_file import read_eyes
from stages._common import read_stage_metrics
from tests.fixtures.chain import stage_commands as chain_commands

ROOT = Path(__file__).resolve().parents[1]
STAGES = tuple(chain_commands("scan", "build", "eyeball", "asset"))    # ingest .. usd, dvc.yaml's order


def stage_commands(scan, build, eyeball) -> dict:
    """``python -m`` arguments of each per-scan stage up to ``usd``, as dvc.yaml runs them
    (without ``--metrics`` / ``--params``; tests/fixtures/chain.py reads them from dvc.yaml), for a
    scan folder, a build folder and an eyeball asset; the asset goes beside the eyeball, as
    rigged_assets/ holds them (usdz packs the eyeball with it)."""
    return chain_commands(scan, build, eyeball, Path(eyeball).parent / f"{Path(scan).name}_asset")


def timed_run(cmd, cwd=ROOT):
    """Run ``cmd`` in the repository root; (wall s, CPU s: user + system of it and its children),
    or exit naming it and its stderr. The CPU time hardly moves with other jobs on the machine,
    the wall time does: both are kept."""
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr[-3000:]}")
    return dt, (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)


def import_seconds(cmd, cwd=ROOT) -> float:
    """Seconds a run of ``cmd`` (``python -m stages.<stage> ...``) spends importing modules, the
    lazy imports inside functions included: the top-level entries of ``-X importtime``."""
    r = subprocess.run([cmd[0], "-X", "importtime", *cmd[1:]], cwd=cwd, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"failed ({r.returncode}): {' '.join(map(str, cmd))}\n{r.stderr[-3000:]}")
    total_us = 0
    for line in r.stderr.splitlines():
        parts = line.split("|")
        # "import time: self [us] | cumulative | name": a top-level import's name has one leading space
        if line.startswith("import time:") and len(parts) == 3 and parts[1].strip().isdigit() \
                and parts[2].startswith(" ") and not parts[2].startswith("  "):
            total_us += int(parts[1])
    return total_us / 1e6


def output_hashes(folders: dict) -> dict:
    """sha256 of every file under each of ``folders`` (label -> folder), keyed ``label/relative
    path``; the timings files (wall times) are left out."""
    import hashlib

    out = {}
    for label, folder in folders.items():
        for p in sorted(Path(folder).rglob("*")):
            if p.is_file() and not p.name.endswith(".timings.json"):
                out[f"{label}/{p.relative_to(folder)}"] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


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
    ap.add_argument("--compare", default=None,
                    help="another checkout (e.g. a clone at the commit before a change): its stages run "
                         "alternately with this one's, on the same head, into WORK/compare; reports both "
                         "medians, their ratios and which outputs differ (sha256)")
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
        pfile.write_text("eyeball: {}\n")
        timed_run(py + ["stages.eyeball", str(eyeball), "--params", str(pfile),
                   "--metrics", str(work / "eyeball.metrics.json")])

    b = work / "build"
    cmds = stage_commands(scan, b, eyeball)
    import yaml

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    pfile = work / "chain_params.yaml"
    pfile.write_text(yaml.safe_dump(params, sort_keys=False))
    sides = {"this": (ROOT, b, cmds)}
    pfiles = {"this": pfile}
    if args.compare:
        import shutil

        cw = work / "compare"
        if not (cw / "eyeball" / "eyeball.usda").exists():
            shutil.copytree(eyeball, cw / "eyeball", dirs_exist_ok=True)
        other = Path(args.compare).resolve()
        sides["compare"] = (other, cw / "build", stage_commands(scan, cw / "build", cw / "eyeball"))
        # each checkout with the params.yaml it ships (an older one knows fewer keys), its preview
        # off: before the preview became a stage of its own, `usd` rendered it when the usd block
        # said `preview: true` (its default), about 6 s that this chain's usd does not do
        other_params = yaml.safe_load((other / "params.yaml").read_text())
        if "preview" in (other_params.get("usd") or {}):
            other_params["usd"]["preview"] = False
        pfiles["compare"] = work / "compare_params.yaml"
        pfiles["compare"].write_text(yaml.safe_dump(other_params, sort_keys=False))
    runs, cpu_runs, loads = {k: [] for k in sides}, {k: [] for k in sides}, []
    for rep in range(args.repeats):
        times = {k: {} for k in sides}
        cpu = {k: {} for k in sides}
        loads.append(round(os.getloadavg()[0], 2))
        # stage by stage, the two sides alternate (ABBA over the repeats), so load drifts hit both
        order = list(sides) if rep % 2 == 0 else list(sides)[::-1]
        for st in STAGES:
            for side in order:
                cwd, bb, cc = sides[side]
                cmd = py + [str(c) for c in cc[st]] + ["--metrics", str(bb / f"{st}.metrics.json"),
                                                       "--params", str(pfiles[side])]
                times[side][st], cpu[side][st] = timed_run(cmd, cwd)
        for side in sides:
            times[side]["total"] = sum(times[side][s] for s in STAGES)
            cpu[side]["total"] = sum(cpu[side][s] for s in STAGES)
            runs[side].append(times[side])
            cpu_runs[side].append(cpu[side])
            print(f"run {rep + 1} {side} (load {loads[-1]:.1f}): "
                  + "  ".join(f"{k} {v:.2f}" for k, v in times[side].items())
                  + f"  (CPU {cpu[side]['total']:.1f} s)", flush=True)
    # the profile's start-up share: one more run of each stage with -X importtime
    imports = {}
    (work / "importtime").mkdir(exist_ok=True)
    for st in STAGES:
        cwd, bb, cc = sides["this"]
        # its metrics elsewhere: the timed runs' timings files are the ones reported
        imports[st] = import_seconds(py + [str(c) for c in cc[st]]
                                     + ["--metrics", str(work / "importtime" / f"{st}.metrics.json"),
                                        "--params", str(pfile)], cwd)
    print("imports s: " + "  ".join(f"{k} {v:.2f}" for k, v in imports.items()), flush=True)
    compare = None
    if args.compare:
        def med(rs, k):
            return float(np.median([r[k] for r in rs]))

        keys = list(STAGES) + ["total"]
        ha = output_hashes({"build": b, "asset": eyeball.parent / f"{scan.name}_asset"})
        hb = output_hashes({"build": sides["compare"][1], "asset": work / "compare" / f"{scan.name}_asset"})
        compare = {
            "checkout": str(sides["compare"][0]),
            "median_s": {k: med(runs["compare"], k) for k in keys},
            "median_cpu_s": {k: med(cpu_runs["compare"], k) for k in keys},
            "wall_ratio_this_over_compare": {k: med(runs["this"], k) / med(runs["compare"], k) for k in keys},
            "cpu_ratio_this_over_compare": {k: med(cpu_runs["this"], k) / med(cpu_runs["compare"], k)
                                            for k in keys},
            "runs_s": runs["compare"], "runs_cpu_s": cpu_runs["compare"],
            "files_compared": len(set(ha) | set(hb)),
            "files_differing": sorted(k for k in set(ha) | set(hb) if ha.get(k) != hb.get(k)),
        }
        print("compare median s: " + "  ".join(f"{k} {v:.2f}" for k, v in compare["median_s"].items()))
        print("wall ratio this/compare: " + "  ".join(
            f"{k} {v:.2f}" for k, v in compare["wall_ratio_this_over_compare"].items()))
        print("CPU ratio this/compare: " + "  ".join(
            f"{k} {v:.2f}" for k, v in compare["cpu_ratio_this_over_compare"].items()))
        print(f"outputs: {len(compare['files_differing'])} of {compare['files_compared']} files differ"
              + (": " + ", ".join(compare["files_differing"]) if compare["files_differing"] else ""))
    runs, cpu_runs = runs["this"], cpu_runs["this"]

    metrics = {st: read_stage_metrics(b / f"{st}.metrics.json") for st in STAGES}   # + timings
    eyes = {s: e.to_doc() for s, e in read_eyes(b / "remove_eyeballs" / "eyes.json").items()}
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
        "median_cpu_s": {k: float(np.median([r[k] for r in cpu_runs])) for k in list(STAGES) + ["total"]},
        "runs_cpu_s": cpu_runs,
        "load_average_1min": loads,
        "imports_s": imports,
        "accuracy": accuracy,
        "stage_metrics": metrics,
    }
    if compare is not None:
        result["compare"] = compare
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print("median s: " + "  ".join(f"{k} {v:.2f}" for k, v in result["median_s"].items()))
    print("median CPU s: " + "  ".join(f"{k} {v:.2f}" for k, v in result["median_cpu_s"].items()))
    print("accuracy: " + json.dumps(accuracy))
    for st in STAGES:
        m = {k: v for k, v in metrics[st].items() if k.endswith("_s") or "error" in k or "removed" in k}
        print(f"  {st}: {json.dumps(m)}")
    if tmp_ctx is not None:
        tmp_ctx.cleanup()


if __name__ == "__main__":
    main()
