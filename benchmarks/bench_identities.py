"""Procedural identities through the whole chain: how many of ``--n`` identities of a seed become assets.

    .venv/bin/python -m benchmarks.bench_identities --seed 0 --n 20 --work /tmp/ident_run [--only 3 7]

Identity ``i`` is what ``python -m stages.identities --n N --seed S`` adds (``draw_identity(S, i,
DEFAULT_TRIANGLES)``); its head is built by ``python -m stages.synthetic_head <scan> --identity
<name>`` (dvc.yaml's command), then ``ingest -> remove_eyeballs -> retopo -> bake -> snap -> rig ->
usd`` run as dvc.yaml runs them (``benchmarks.bench_unseen_scans.run_chain``: subprocesses, one head
at a time) with ./params.yaml plus the identities and ``BENCH_PARAMS`` (a 512 px bake, no usdz;
nothing eye-related changed) written to ``WORK/params_seed<S>.yaml``. No dvc: everything lives
under ``--work``. Writes ``<results>/identities_seed<S>.json``: per identity the outcome (``asset``
or the stage that refused), each stage's exit code, wall time and one-line message, and the CPU
seconds (user + system of the subprocesses). Rewritten after every identity, so a cut-short run
keeps what it finished (``"complete": false``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def write_params(work: Path, seed: int, entries: dict) -> Path:
    """./params.yaml with ``entries`` as its identities: and bench_unseen_scans' BENCH_PARAMS."""
    import yaml

    from benchmarks.bench_unseen_scans import BENCH_PARAMS

    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    for block, vals in BENCH_PARAMS.items():
        base.setdefault(block, {}).update(vals)
    base["identities"] = json.loads(json.dumps(entries))      # plain floats (a draw may hold numpy ones)
    path = work / f"params_seed{seed}.yaml"
    path.write_text(yaml.safe_dump(base, sort_keys=False))
    return path


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--work", type=Path, required=True, help="scratch folder (scans, builds, assets)")
    ap.add_argument("--only", type=int, nargs="*", default=None, help="identity indices (default all of --n)")
    ap.add_argument("--results", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.n < 1 or args.seed < 0:
        ap.error(f"--n must be >= 1 and --seed >= 0 (got {args.n}, {args.seed})")
    if args.only is not None and any(not 0 <= i < args.n for i in args.only):
        ap.error(f"--only: indices must lie in 0 .. {args.n - 1}")
    return args


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    from benchmarks.bench_unseen_scans import BENCH_PARAMS, STAGES, asset_dir, run_chain
    from pipeline.synthetic_head.identities import DEFAULT_TRIANGLES, draw_identity, identity_name

    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    entries = {identity_name(args.seed, i): draw_identity(args.seed, i, DEFAULT_TRIANGLES) for i in range(args.n)}
    params = write_params(work, args.seed, entries)
    eyeball = work / "assets" / "eyeball"
    if not (eyeball / "eyeball.usda").is_file():
        subprocess.run([sys.executable, "-m", "stages.eyeball", str(eyeball), "--params", str(params),
                        "--metrics", str(work / "eyeball.metrics.json")], cwd=ROOT, check=True)
    out = args.results / f"identities_seed{args.seed}.json"
    rows = []
    todo = range(args.n) if args.only is None else args.only
    t_all, c_all = time.perf_counter(), _cpu()
    for k, i in enumerate(todo):
        name = identity_name(args.seed, i)
        scan, build = work / "scans" / name, work / "build" / name
        shutil.rmtree(build, ignore_errors=True)
        shutil.rmtree(asset_dir(eyeball, name), ignore_errors=True)
        build.mkdir(parents=True)
        t0, c0 = time.perf_counter(), _cpu()
        r = subprocess.run([sys.executable, "-m", "stages.synthetic_head", str(scan), "--identity", name,
                            "--params", str(params), "--metrics", str(build / "synthetic_head.metrics.json")],
                           cwd=ROOT, capture_output=True, text=True)
        lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
        stages = {"synthetic_head": {"rc": r.returncode, "time_s": round(time.perf_counter() - t0, 2),
                                     "message": lines[-1] if (r.returncode and lines) else ""}}
        if r.returncode == 0:
            stages.update(run_chain(scan, build, eyeball, params))
        failed = next((st for st, v in stages.items() if v["rc"] != 0), None)
        row = {"identity": name, "index": i, "draw": json.loads(json.dumps(entries[name])),
               "outcome": "asset" if failed is None and "usd" in stages else (failed or "incomplete"),
               "refusal": stages[failed]["message"] if failed else "",
               "wall_s": round(time.perf_counter() - t0, 1), "cpu_s": round(_cpu() - c0, 1), "stages": stages}
        rows.append(row)
        print(f"[{k + 1}/{len(todo)}] {name}: {row['outcome']} {row['wall_s']} s"
              + (f"  {row['refusal']}" if failed else ""), flush=True)
        done = len(rows) == len(todo)
        summary = {"seed": args.seed, "n": args.n, "complete": done, "run": len(rows),
                   "assets": sum(r["outcome"] == "asset" for r in rows),
                   "failures": {r["identity"]: {"stage": r["outcome"], "message": r["refusal"]}
                                for r in rows if r["outcome"] != "asset"},
                   "wall_s": round(time.perf_counter() - t_all, 1), "cpu_s": round(_cpu() - c_all, 1),
                   "params": {"triangles": DEFAULT_TRIANGLES, "bench_params": BENCH_PARAMS,
                              "stages": ["synthetic_head", *STAGES]},
                   "rows": rows}
        args.results.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"seed {args.seed}: {summary['assets']} assets of {len(rows)} run ({args.n} drawn); {out}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
