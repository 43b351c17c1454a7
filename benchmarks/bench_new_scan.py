"""Benchmark adding one new scan: its stages through ``dvc repro``, preview and 16 renders included.

    .venv/bin/python -m benchmarks.bench_new_scan [--triangles 350000] [--repeats 3] [--source synthetic|scanify]
                                                  [--seed 11] [--clone DIR] [--keep]

What a user waits for after step 4 of README "Adding a scan". In a clone of this repository
(``git clone`` of HEAD into a temporary folder, or ``--clone DIR`` to reuse one prepared by an
earlier run), the shared inputs are built first and not timed: ``dvc repro check_params
eyeball``. Then, for each repeat, a fresh 350k-triangle head is added as
``raw_scans/new_scan_<i>/`` and to ``scans:`` in the clone's params.yaml (replacing the
previous repeat's name, so every repeat is a scan DVC has never seen: no run-cache hit), and
``dvc repro render@new_scan_<i> preview@new_scan_<i>`` is timed: check_params (the scan list
changed), then that scan's ingest, remove_eyeballs, retopo, bake, snap, rig, usd, render
(``render.n_images`` images, 16 in params.yaml) and the asset's preview.

The head is procedural (``make_synthetic_head`` with ``--seed``, not the home scan's seed 7) or,
with ``--source scanify``, an ICT-FaceKit identity from scanify (``../shared/tools/scanify``,
about a minute to generate; remove_eyeballs' self-checks still refuse unseen ICT-FaceKit heads,
docs/remove_eyeballs.md "Unseen scans", so that run stops there with DVC's error); generating it is not timed,
and the head is kept beside the clone for later runs with ``--clone``. Per stage the result has the wall
time between DVC's ``Running stage`` lines (DVC's own hashing and lock writing included) and
the stage's own ``wall_time_s`` and ``cpu_time_s`` (build/<scan>/<stage>.timings.json; the CPU
time hardly moves with other jobs on the machine, the wall times do). Writes
benchmarks/results/new_scan.json: medians over the repeats, every repeat, the load average
before each, and the clone's commit.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from tests.fixtures.chain import RUNNING, stage_walls
from tests.fixtures.params import set_scans

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
STAGES = ("check_params", "ingest", "remove_eyeballs", "retopo", "bake", "snap", "rig", "usd", "render", "preview")


def run_env() -> dict:
    """The environment DVC's stage commands need: this interpreter's ``python`` and ``dvc`` first on PATH."""
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def check(cmd, cwd, what):
    """Run ``cmd`` in ``cwd``; exit naming ``what`` and the end of its output when it fails."""
    r = subprocess.run(cmd, cwd=cwd, env=run_env(), capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{what} failed ({r.returncode}): {' '.join(map(str, cmd))}\n"
                         f"{(r.stdout + r.stderr)[-3000:]}")
    return r


def make_scan(source: str, triangles: int, seed: int, folder: Path, scanify: Path) -> None:
    """Write a scan folder (scan.yaml + mesh [+ texture]) of about ``triangles`` triangles into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    if source == "synthetic":
        from pipeline.synthetic_head import make_synthetic_head, write_scan_folder

        head = make_synthetic_head(seed=seed, target_triangles=triangles, noise_mm=0.02, texture_size=2048)
        write_scan_folder(head, folder)
        return
    if not scanify.is_file():
        raise SystemExit(f"{scanify}: scanify not found (--source scanify needs it)")
    check([sys.executable, str(scanify), "--ict-dir", str(SHARED / "scans" / "ict_facekit"), "--out", str(folder),
           "--identity-seed", str(seed), "--seed", str(seed), "--faces", str(triangles)], ROOT, "scanify")


def timed_repro(clone: Path, *targets: str):
    """``dvc repro target`` in ``clone``, reading its output as it comes: (total wall s, [(stage, scan or
    None, start s)], output text). Exits with the output's end when DVC fails."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(["dvc", "repro", *targets], cwd=clone, env=run_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, bufsize=1)
    starts, text = [], []
    for line in proc.stdout:
        text.append(line)
        m = RUNNING.match(line)
        if m:
            starts.append((m.group(1), m.group(2), time.perf_counter() - t0))
    rc = proc.wait()
    total = time.perf_counter() - t0
    if rc != 0:
        raise SystemExit(f"dvc repro {' '.join(targets)} failed ({rc}):\n{''.join(text)[-3000:]}")
    return total, starts, "".join(text)


def own_timings(clone: Path, scan: str) -> dict:
    """Each stage's own timings file (build/<scan>/<stage>.timings.json), where present."""
    out = {}
    for st in STAGES[1:]:
        p = clone / "build" / scan / f"{st}.timings.json"
        if p.is_file():
            out[st] = json.loads(p.read_text(encoding="utf-8"))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=350_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--source", choices=("synthetic", "scanify"), default="synthetic")
    ap.add_argument("--seed", type=int, default=11, help="head seed (the home synthetic_head uses 7)")
    ap.add_argument("--scanify", default=str(SHARED / "tools" / "scanify" / "scanify.py"))
    ap.add_argument("--clone", default=None, help="clone to use (made with git clone of this repo when absent)")
    ap.add_argument("--keep", action="store_true", help="keep the temporary clone")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "new_scan.json"))
    args = ap.parse_args()

    tmp = None
    if args.clone:
        clone = Path(args.clone).resolve()
    else:
        tmp = Path(tempfile.mkdtemp(prefix="bench_new_scan_"))
        clone = tmp / "eyerig"
    if not (clone / "dvc.yaml").is_file():
        check(["git", "clone", "-q", str(ROOT), str(clone)], ROOT, "git clone")
    commit = check(["git", "rev-parse", "HEAD"], clone, "git rev-parse").stdout.strip()
    dvc_version = check(["dvc", "--version"], clone, "dvc --version").stdout.strip()

    t0 = time.perf_counter()
    scan_src = clone.parent / f"new_scan_{args.source}_{args.seed}_{args.triangles}"
    if not (scan_src / "scan.yaml").is_file():
        make_scan(args.source, args.triangles, args.seed, scan_src, Path(args.scanify))
    generate_s = time.perf_counter() - t0
    params_file = clone / "params.yaml"
    home = [n for n in yaml.safe_load(params_file.read_text(encoding="utf-8"))["scans"]
            if not n.startswith("new_scan_")]
    set_scans(params_file, home)
    t0 = time.perf_counter()
    check(["dvc", "repro", "check_params", "eyeball"], clone, "dvc repro check_params eyeball")
    prepare_s = time.perf_counter() - t0
    print(f"clone {clone} at {commit[:10]}; scan generated in {generate_s:.1f} s; "
          f"shared inputs ready in {prepare_s:.1f} s", flush=True)

    # a checkout from before the preview was a stage of its own (the code issue 32 measured) renders
    # it inside usd: its chain is the same work without a preview stage to run
    stages = [st for st in STAGES if st in yaml.safe_load((clone / "dvc.yaml").read_text(encoding="utf-8"))["stages"]]
    runs = []
    for rep in range(1, args.repeats + 1):
        name = f"new_scan_{rep}"
        for old in (clone / "raw_scans").glob("new_scan_*"):
            shutil.rmtree(old)
        shutil.copytree(scan_src, clone / "raw_scans" / name)
        set_scans(params_file, home + [name])
        load = os.getloadavg()[0]
        targets = [f"{st}@{name}" for st in ("render", "preview") if st in stages]
        total, starts, text = timed_repro(clone, *targets)
        ran = [s[0] for s in starts]
        missing = [st for st in stages if st not in ran]
        if missing:
            raise SystemExit(f"dvc repro {' '.join(targets)} did not run {', '.join(missing)}:\n{text[-3000:]}")
        index = clone / "renders" / name / "index.jsonl"
        images = sum(1 for line in index.read_text(encoding="utf-8").splitlines() if line.strip())
        own = own_timings(clone, name)
        preview = own.get("preview", {})
        run = {"scan": name, "load_average_1min": round(load, 2), "total_s": round(total, 3),
               "dvc_stage_s": {k: round(v, 3) for k, v in stage_walls(starts, total).items()},
               "stage_wall_time_s": {k: v.get("wall_time_s") for k, v in own.items()},
               "stage_cpu_time_s": {k: v.get("cpu_time_s") for k, v in own.items()},
               "preview_s": preview.get("preview_s"), "images": images,
               "render_timings": own.get("render", {})}
        runs.append(run)
        print(f"repeat {rep}: {total:.1f} s (load {load:.1f}): "
              + "  ".join(f"{k} {v:.2f}" for k, v in run["dvc_stage_s"].items()), flush=True)

    ingest_metrics = json.loads((clone / "build" / runs[-1]["scan"] / "ingest.metrics.json").read_text())

    def med(key, sub=None):
        vals = [r[key] if sub is None else r[key].get(sub) for r in runs]
        vals = [v for v in vals if v is not None]
        return round(float(np.median(vals)), 3) if vals else None

    result = {
        "source": args.source, "seed": args.seed, "triangles": int(ingest_metrics.get("faces_out", args.triangles)),
        "repeats": args.repeats, "commit": commit, "dvc": dvc_version,
        "generate_s": round(generate_s, 2), "prepare_s": round(prepare_s, 2),
        "median_total_s": med("total_s"),
        "median_dvc_stage_s": {st: med("dvc_stage_s", st) for st in STAGES},
        "median_stage_wall_time_s": {st: med("stage_wall_time_s", st) for st in STAGES[1:]},
        "median_stage_cpu_time_s": {st: med("stage_cpu_time_s", st) for st in STAGES[1:]},
        "median_preview_s": med("preview_s"),
        "images": runs[-1]["images"],
        "runs": runs,
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"median total {result['median_total_s']:.1f} s for {result['triangles']} triangles, "
          f"{result['images']} images; per stage (dvc): "
          + "  ".join(f"{k} {v:.2f}" for k, v in result["median_dvc_stage_s"].items() if v is not None))
    if tmp is not None and not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    elif tmp is not None:
        print(f"kept {clone}")


if __name__ == "__main__":
    main()
