"""Seconds per image of the dataset command for each preset, this checkout against another one,
run in turn on one machine (issue 33: the framing rule must not cost render time).

    python -m benchmarks.bench_dataset_presets --base /tmp/base-ds --assets A [--rigs R] \\
        [--n 24] [--pairs 3] [--presets generic targeted] [--out benchmarks/results/dataset_presets.json]

For each pair and preset: the dataset command of this checkout, then the same command in
``--base`` (a worktree of the commit to compare, e.g. ``git worktree add --detach /tmp/base-ds
7b5ab0a``, its ``.venv`` linked), each into a fresh folder, one worker. The figure is each run's
``timings.json`` ``s_per_image`` (render wall over rendered images: Blender start-ups inside,
sampling outside) and the whole command's wall seconds; the JSON keeps every run and the medians.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_once(root: Path, assets, rigs, n: int, preset: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench-ds-") as tmp:
        out = Path(tmp) / "ds"
        cmd = [sys.executable, "-m", "stages.dataset", "--assets", *assets, "--n", str(n), "--preset", preset,
               "--out", str(out), "--no-progress", "--workers", "1"] + (["--rigs", *rigs] if rigs else [])
        t0 = time.perf_counter()
        r = subprocess.run(cmd, cwd=root, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode:
            raise SystemExit(f"{root}: {r.stderr.strip()}")
        t = json.loads((out / "timings.json").read_text())
        return {"s_per_image": t["s_per_image"], "command_wall_s": round(wall, 3), "rejections": t.get("rejections")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--assets", nargs="+", required=True)
    ap.add_argument("--rigs", nargs="+", default=None)
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--presets", nargs="+", default=["generic", "targeted"])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/dataset_presets.json")
    args = ap.parse_args(argv)
    assets = [str(Path(a).resolve()) for a in args.assets]
    rigs = [str(Path(r).resolve()) for r in args.rigs] if args.rigs else None
    runs = {p: {"after": [], "before": []} for p in args.presets}
    for k in range(args.pairs):
        for p in args.presets:
            for which, root in (("after", ROOT), ("before", args.base.resolve())):
                runs[p][which].append(run_once(root, assets, rigs, args.n, p))
                print(p, which, k, runs[p][which][-1], flush=True)
    med = {p: {w: {key: statistics.median(r[key] for r in rs) for key in ("s_per_image", "command_wall_s")}
               for w, rs in v.items()} for p, v in runs.items()}
    doc = {"n_images": args.n, "pairs": args.pairs, "assets": [Path(a).name for a in assets],
           "base": subprocess.run(["git", "-C", str(args.base), "rev-parse", "--short", "HEAD"],
                                  capture_output=True, text=True).stdout.strip(),
           "after": subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                   capture_output=True, text=True).stdout.strip(),
           "median": med, "runs": runs}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    for p, v in med.items():
        print(f"{p}: {v['after']['s_per_image']:.3f} s/image after, {v['before']['s_per_image']:.3f} before")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
