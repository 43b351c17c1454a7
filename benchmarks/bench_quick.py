"""The speed budget: the 1.4M-triangle chain once and 50 renders, each figure against benchmarks/budget.yaml.

    .venv/bin/python -m benchmarks.bench_quick [--images 50] [--triangles 1400000] [--keep DIR]
                                               [--out benchmarks/results/bench_quick.json]

``make bench-quick`` runs this (under 5 minutes on two cores). It runs

1. ``benchmarks.bench_chain --repeats 1`` on the synthetic head of ``--triangles`` (each stage as
   dvc.yaml runs it, timed in wall and CPU seconds), and
2. the render stage (``python -m stages.render`` at params.yaml's ``render`` settings) on
   ``--images`` images of ``rigged_assets/synthetic_head`` (``make run`` builds it; without it the
   render line is skipped and says so),

then prints one line per figure: measured, budget, ratio, and ``OVER`` where the ratio exceeds
``1 + tolerance`` (the budget's ``tolerance``, 10 %). The stages are budgeted in CPU seconds (user
+ system of the stage's process and its children), which hardly move with other jobs on a shared
machine; wall seconds are printed beside them. The render is budgeted in CPU seconds per image
and in wall seconds per image (the README's figure). Exit status 1 when a figure is over, so a
change that slows a stage cannot land unseen; say so in its closing note with the side-by-side
ratio (``bench_chain --compare CHECKOUT``), or raise the budget in the same commit, with the reason.

Writes the figures, budgets and ratios to ``--out`` (JSON; not a DVC metrics file: ``dvc metrics
show`` keeps to the stages' headlines, 120 columns).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from pipeline.io.atomic import write_json

ROOT = Path(__file__).resolve().parents[1]
BUDGET = ROOT / "benchmarks" / "budget.yaml"
OUT = ROOT / "benchmarks" / "results" / "bench_quick.json"


def load_budget(path=BUDGET) -> dict:
    """``budget.yaml`` as ``{"tolerance": float, "chain_cpu_s": {stage: s}, "render": {...}}``;
    a missing or malformed file exits naming it and the problem."""
    path = Path(path)
    try:
        b = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise SystemExit(f"{path}: cannot read the budget ({e})")
    if not isinstance(b, dict) or not isinstance(b.get("chain_cpu_s"), dict) or not isinstance(b.get("render"), dict):
        raise SystemExit(f"{path}: needs the mappings chain_cpu_s and render")
    for k, v in list(b["chain_cpu_s"].items()) + list(b["render"].items()):
        if not isinstance(v, (int, float)) or not v > 0:
            raise SystemExit(f"{path}: budget {k} must be a positive number, got {v!r}")
    tol = b.get("tolerance", 0.10)
    if not isinstance(tol, (int, float)) or not 0 <= tol < 1:
        raise SystemExit(f"{path}: tolerance must be a number in [0, 1), got {tol!r}")
    b["tolerance"] = float(tol)
    return b


def compare(figures: dict, budget: dict) -> list[dict]:
    """One row per budgeted figure present in ``figures`` (``{"chain_cpu_s": {...}, "render":
    {...}}``): name, measured, budget, ratio (measured / budget) and ``over`` (ratio above 1 +
    tolerance). Figures without a budget are left out; budgets without a figure appear with
    ``measured`` None."""
    rows = []
    for group in ("chain_cpu_s", "render"):
        for name, limit in budget[group].items():
            got = figures.get(group, {}).get(name)
            ratio = None if got is None else got / limit
            rows.append({"figure": f"{group}.{name}", "measured": got, "budget": float(limit), "ratio": ratio,
                         "over": ratio is not None and ratio > 1.0 + budget["tolerance"]})
    return rows


def format_rows(rows: list[dict], wall: dict | None = None) -> str:
    wall = wall or {}
    lines = [f"{'figure':<34}{'measured':>10}{'budget':>10}{'ratio':>8}   wall s"]
    for r in rows:
        got = "-" if r["measured"] is None else f"{r['measured']:.3f}"
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.2f}"
        w = wall.get(r["figure"])
        lines.append(f"{r['figure']:<34}{got:>10}{r['budget']:>10.3f}{ratio:>8}   "
                     + ("" if w is None else f"{w:.2f}") + ("   OVER" if r["over"] else ""))
    return "\n".join(lines)


def run_chain(work: Path, triangles: int) -> dict:
    out = work / "chain.json"
    cmd = [sys.executable, "-m", "benchmarks.bench_chain", "--repeats", "1", "--triangles", str(triangles),
           "--keep", str(work / "chain"), "--out", str(out)]
    r = subprocess.run(cmd, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"bench_chain failed (exit {r.returncode})")
    return json.loads(out.read_text())


def run_render(work: Path, images: int) -> dict | None:
    from benchmarks.bench_render import _stage

    scan = "synthetic_head"
    if not (ROOT / "rigged_assets" / scan / f"{scan}.usda").is_file():
        print(f"render skipped: rigged_assets/{scan} is missing (make run builds it)", flush=True)
        return None
    params = yaml.safe_load((ROOT / "params.yaml").read_text())["render"]
    pfile = work / "render_params.yaml"
    pfile.write_text(yaml.safe_dump({"render": params}))
    return _stage(scan, work / "renders", pfile, images)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=50)
    ap.add_argument("--triangles", type=int, default=1_400_000)
    ap.add_argument("--keep", default=None, help="work folder to keep (the head is reused when it is there)")
    ap.add_argument("--budget", default=str(BUDGET))
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    budget = load_budget(args.budget)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_quick_") as td:
        work = Path(args.keep) if args.keep else Path(td)
        work.mkdir(parents=True, exist_ok=True)
        chain = run_chain(work, args.triangles)
        render = run_render(work, args.images)
    figures = {"chain_cpu_s": dict(chain["median_cpu_s"]), "render": {}}
    wall = {f"chain_cpu_s.{k}": v for k, v in chain["median_s"].items()}
    if render is not None:
        figures["render"] = {"cpu_s_per_image": render["cpu_s_per_image"], "s_per_image": render["s_per_image"]}
        wall["render.cpu_s_per_image"] = render["wall_s"]
    rows = compare(figures, budget)
    print(format_rows(rows, wall))
    result = {"triangles": chain["triangles"], "images": args.images, "tolerance": budget["tolerance"],
              "figures": figures, "wall_s": chain["median_s"], "rows": rows,
              "over": [r["figure"] for r in rows if r["over"]],
              "accuracy": chain.get("accuracy"), "render": render,
              "bench_quick_s": round(time.perf_counter() - t0, 1),
              "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    write_json(Path(args.out), result)
    print(f"bench-quick took {result['bench_quick_s']:.0f} s; "
          + (f"OVER budget: {', '.join(result['over'])}" if result["over"] else "every figure within budget"))
    return 1 if result["over"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
