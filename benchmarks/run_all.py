"""Run every benchmark, one after another, and report what ran, what was skipped and how long each took.

    .venv/bin/python -m benchmarks.run_all [--only NAME ...] [--skip NAME ...] [--full] [--dry-run] [--list]

``make bench`` runs this. Each benchmark runs as ``python -m benchmarks.<name>`` in the project
root, in the order of :data:`BENCHMARKS` (generator, then the stages in DAG order, the whole
chain, the unseen scans, then what needs a ``dvc repro`` output, rendering last), and writes its
own ``benchmarks/results/<name>.json`` as usual. By default each gets modest arguments: the
problem sizes the README publishes, with one run or repeat instead of 3-5 (the medians are
noisier, the accuracy figures are the same); ``--full`` uses each benchmark's own defaults.

A benchmark whose inputs are missing is skipped with one printed line saying what it needs:

* the extra scans (``EYERIG_EXTRA_SCANS``, else ``../shared/scans``), passed on to the child in
  ``EYERIG_EXTRA_SCANS``;
* scanify (``../shared/tools/scanify/scanify.py``) for the unseen scans;
* the synthetic head's build products (``make run``, i.e. ``dvc repro``) for usd, the asset
  preview, the renders and the rig view.

A failing benchmark does not stop the others. At the end a table lists every benchmark with
``ok``, ``FAILED (exit N)`` or ``skipped`` and its wall time; the same goes to
``benchmarks/out/run_all.json`` (git-ignored). Exit status 1 when one failed, else 0.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SYNTH_BUILD = ROOT / "build" / "synthetic_head"
SYNTH_ASSET = ROOT / "rigged_assets" / "synthetic_head" / "synthetic_head.usda"
EYEBALL = ROOT / "rigged_assets" / "eyeball" / "eyeball.usda"
SYNTH_RENDERS = ROOT / "renders" / "synthetic_head"
UNSEEN_WORK = ROOT / "benchmarks" / "out" / "unseen"
REPORT = ROOT / "benchmarks" / "out" / "run_all.json"
NOT_BENCHMARKS = {"__init__", "run_all", "results_files",   # the runner and what benchmarks share
                  "derive_eye_prior",                    # a tool: derives the shipped eye-region prior
                  "bench_dataset_presets",               # compares with another checkout: needs --base
                  "bench_placement_ab",                  # compares two source trees: needs --a and --b
                  "bench_quick"}                         # make bench-quick: bench_chain + render vs budget.yaml


@dataclass(frozen=True)
class Benchmark:
    """One ``python -m benchmarks.<name>`` run.

    ``args`` are always passed (``{scans}``, ``{scanify}`` are filled in); ``modest`` only without
    ``--full``; ``needs`` names the inputs checked in :func:`missing` just before it runs.
    """

    name: str
    args: tuple[str, ...] = ()
    modest: tuple[str, ...] = ()
    needs: tuple[str, ...] = ()


BENCHMARKS = (
    Benchmark("bench_synthetic_head", modest=("--repeats", "1")),
    Benchmark("bench_synthetic_anatomy", modest=("--n", "6")),
    Benchmark("view_synthetic_head"),
    Benchmark("bench_ingest", modest=("--runs", "1")),
    Benchmark("bench_hostile"),
    Benchmark("bench_holes"),
    Benchmark("bench_eyeball", modest=("--repeats", "1")),
    Benchmark("bench_remove_eyeballs", modest=("--repeats", "1")),
    Benchmark("bench_textured_only", modest=("--cases", "7", "3:hooded", "11:dark")),
    Benchmark("bench_eyelid_margin", args=("--scans", "{scans}"), needs=("scans",)),
    Benchmark("bench_retopo", modest=("--runs", "1")),
    Benchmark("bench_bake", modest=("--runs", "1")),
    Benchmark("compare_ict_lids", needs=("scans",)),
    Benchmark("bench_rig", needs=("scans",)),
    Benchmark("bench_chain", modest=("--repeats", "1")),
    # all 20 even when modest: a shorter run would overwrite the page's 20-identity counts
    Benchmark("bench_identities", args=("--work", str(ROOT / "benchmarks" / "out" / "identities"))),
    Benchmark("bench_unseen_scans", args=("--scanify", "{scanify}", "--ict", "{scans}/ict_facekit"),
              needs=("scans", "scanify")),
    Benchmark("view_eye_sections", needs=("unseen_work",)),
    Benchmark("bench_unseen_oracle", needs=("unseen_work",)),
    Benchmark("bench_placement", args=("--set", "all", "--skip-missing"), needs=("unseen_work",)),
    # what a perfect reader of the scan's iris could do against the same truth (the heads it left)
    Benchmark("bench_limbus_bound", args=("--work", str(UNSEEN_WORK), "--scanify", "{scanify}",
                                          "--ict", "{scans}/ict_facekit"), needs=("unseen_work", "scans", "scanify")),
    # the bands of the held-out heads the unseen run left (its own page: band_angles.json also
    # holds seed 5 and the fresh set, built by hand)
    Benchmark("bench_band", args=("--set", f"heldout={UNSEEN_WORK / 'build'}:{UNSEEN_WORK / 'params.yaml'}",
                                  "--work", str(ROOT / "benchmarks" / "out" / "band"), "--out", "band_angles_heldout"),
              needs=("unseen_work",)),
    # ... and how much their bands turn on the last bits (each grid raised again moved by 1e-9 mm)
    Benchmark("bench_band_jitter", args=("--set", f"heldout={UNSEEN_WORK / 'build'}:{UNSEEN_WORK / 'params.yaml'}",
                                         "--out", "band_jitter_heldout"), needs=("unseen_work",)),
    # ... and their lids against the eye turned in yaw, with and without the yaw channels
    Benchmark("bench_yaw", args=("--set", f"heldout={UNSEEN_WORK / 'build'}:{UNSEEN_WORK / 'params.yaml'}",
                                 "--out", "yaw_heldout"), needs=("unseen_work",)),
    Benchmark("bench_usd", needs=("synthetic_build",)),
    # the home asset, and every asset the unseen run above left
    Benchmark("bench_see_through", args=(f"synthetic_head={SYNTH_ASSET.parent}:{SYNTH_BUILD / 'rig'}",
                                         "--unseen", str(UNSEEN_WORK)), needs=("synthetic_asset",)),
    # the corner strips and the caruncle of every head the unseen run left, snapped again
    Benchmark("bench_corners", args=("--work", str(UNSEEN_WORK)), needs=("unseen_work",)),
    # the README's figures come from the three home scans and six procedural heads (its command)
    Benchmark("bench_margin_smoothness", args=(str(SYNTH_BUILD), "--out", str(
        ROOT / "benchmarks" / "out" / "margin_smoothness_synthetic_head.json")),
              needs=("synthetic_build",)),
    Benchmark("view_rig", args=(str(SYNTH_BUILD / "snap"), str(SYNTH_BUILD / "rig"),
                                str(ROOT / "benchmarks" / "out" / "view_rig_synthetic_head.png")),
              needs=("synthetic_build",)),
    Benchmark("bench_asset_preview", modest=("--runs", "1"), needs=("synthetic_asset",)),
    Benchmark("bench_new_scan", modest=("--repeats", "1")),        # its own clone: dvc repro of one new scan
    Benchmark("bench_dispatch", modest=("--settings", "native,npy_no_avx2")),   # fresh clones: dvc repro per setting
    Benchmark("bench_render", needs=("synthetic_asset",)),
    Benchmark("bench_tls_render", modest=("--repeats", "1"), needs=("synthetic_asset",)),
    Benchmark("bench_render_quality", modest=("--repeats", "1"), needs=("synthetic_asset",)),
    Benchmark("bench_render_split", modest=("--images", "6"), needs=("synthetic_asset",)),
    Benchmark("bench_render_curves", modest=("--images", "4"), needs=("synthetic_asset",)),
    Benchmark("bench_proportions", needs=("synthetic_asset",)),
    Benchmark("bench_label_formats", modest=("--images", "8"), needs=("synthetic_asset",)),
    Benchmark("bench_masks", args=(str(SYNTH_ASSET.parent), str(SYNTH_BUILD / "rig")),
              modest=("--n", "6"), needs=("synthetic_asset",)),
    Benchmark("bench_background", args=("predict",), modest=("--n", "10", "--scans", "synthetic_head"),
              needs=("synthetic_asset",)),
    Benchmark("bench_gazeml_presets", modest=("--scans", "synthetic_head"), needs=("synthetic_asset",)),
    Benchmark("bench_dataset", args=("--assets", str(SYNTH_ASSET.parent), "--out", str(ROOT / "benchmarks" / "out" / "dataset"),
                                     "--name", "dataset_synthetic_head"), modest=("--n", "20"), needs=("synthetic_asset",)),
    Benchmark("view_masks", args=(str(SYNTH_RENDERS), str(ROOT / "benchmarks" / "out" / "masks_synthetic_head.png")),
              needs=("synthetic_renders",)),
    Benchmark("bench_dataset_lab", args=("--assets", str(SYNTH_ASSET.parent), "--rigs", str(SYNTH_BUILD / "rig"),
                                         "--name", "dataset_lab_synthetic_head"),
              modest=("--sample-generic", "60", "--sample-targeted", "20"), needs=("synthetic_asset",)),
    Benchmark("view_normalized", args=(str(SYNTH_RENDERS), str(ROOT / "benchmarks" / "out" / "normalized.png")),
              needs=("synthetic_renders",)),
)


def scans_dir() -> Path | None:
    """The extra scans: ``EYERIG_EXTRA_SCANS`` when set, else ``../shared/scans``; None when absent."""
    value = os.environ.get("EYERIG_EXTRA_SCANS")
    path = Path(value) if value else SHARED / "scans"
    return path if path.is_dir() else None


def missing(need: str) -> str | None:
    """Why the input ``need`` is not there (one phrase), or None when it is."""
    if need == "scans":
        if scans_dir() is None:
            where = os.environ.get("EYERIG_EXTRA_SCANS") or f"{SHARED / 'scans'} (EYERIG_EXTRA_SCANS unset)"
            return f"needs the extra scans: {where} not found"
        return None
    if need == "scanify":
        path = SHARED / "tools" / "scanify" / "scanify.py"
        return None if path.is_file() else f"needs scanify: {path} not found"
    if need == "unseen_work":
        return None if UNSEEN_WORK.is_dir() else f"needs {UNSEEN_WORK} (run bench_unseen_scans first)"
    if need == "synthetic_build":
        parts = [SYNTH_BUILD / d for d in ("ingest", "bake", "snap", "rig")] + [EYEBALL]
        gone = [p for p in parts if not p.exists()]
        return f"needs {gone[0].relative_to(ROOT)} (run `make run` first)" if gone else None
    if need == "synthetic_asset":
        gone = [p for p in (SYNTH_ASSET, SYNTH_BUILD / "rig" / "rig.npz") if not p.exists()]
        return f"needs {gone[0].relative_to(ROOT)} (run `make run` first)" if gone else None
    if need == "synthetic_renders":
        index = SYNTH_RENDERS / "index.jsonl"
        return None if index.is_file() else f"needs {index.relative_to(ROOT)} (run `make run` first)"
    raise ValueError(f"unknown requirement {need!r}")


def command(b: Benchmark, full: bool) -> list[str]:
    scans = scans_dir()
    fill = {"scans": str(scans) if scans else "", "scanify": str(SHARED / "tools" / "scanify" / "scanify.py")}
    args = [a.format(**fill) for a in b.args] + ([] if full else list(b.modest))
    return [sys.executable, "-m", f"benchmarks.{b.name}", *args]


def unlisted() -> list[str]:
    """Modules in benchmarks/ that :data:`BENCHMARKS` does not run (keeps the list complete)."""
    names = {b.name for b in BENCHMARKS} | NOT_BENCHMARKS
    return sorted(p.stem for p in (ROOT / "benchmarks").glob("*.py") if p.stem not in names)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    names = [b.name for b in BENCHMARKS]
    ap.add_argument("--only", nargs="+", choices=names, metavar="NAME", help="run only these (in the usual order)")
    ap.add_argument("--skip", nargs="+", choices=names, metavar="NAME", default=[], help="leave these out")
    ap.add_argument("--full", action="store_true", help="each benchmark's own default arguments (slower)")
    ap.add_argument("--dry-run", action="store_true", help="print the commands and the skips; run nothing")
    ap.add_argument("--list", action="store_true", help="print the benchmarks in order and exit")
    args = ap.parse_args(argv)

    extra = unlisted()
    if extra:
        print(f"run_all: benchmarks/ has modules that BENCHMARKS does not list: {', '.join(extra)}",
              file=sys.stderr)
        return 2
    if args.list:
        for b in BENCHMARKS:
            print(b.name)
        return 0

    env = dict(os.environ)
    if scans_dir() is not None:
        env["EYERIG_EXTRA_SCANS"] = str(scans_dir())
    rows = []
    t_all = time.perf_counter()
    for b in BENCHMARKS:
        if (args.only and b.name not in args.only) or b.name in args.skip:
            continue
        why = next((w for w in map(missing, b.needs) if w), None)
        if why:
            print(f"--- skip {b.name}: {why}", flush=True)
            rows.append({"name": b.name, "status": "skipped", "reason": why, "wall_s": 0.0})
            continue
        cmd = command(b, args.full)
        shown = " ".join(["python", *cmd[1:]])
        if args.dry_run:
            print(f"--- would run: {shown}", flush=True)
            rows.append({"name": b.name, "status": "dry-run", "command": shown, "wall_s": 0.0})
            continue
        print(f"--- run {b.name}: {shown}", flush=True)
        t = time.perf_counter()
        rc = subprocess.run(cmd, cwd=ROOT, env=env).returncode
        wall = round(time.perf_counter() - t, 1)
        status = "ok" if rc == 0 else f"FAILED (exit {rc})"
        print(f"--- {b.name}: {status} in {wall:.1f} s", flush=True)
        rows.append({"name": b.name, "status": status, "command": shown, "wall_s": wall})

    total = round(time.perf_counter() - t_all, 1)
    width = max((len(r["name"]) for r in rows), default=10)
    print()
    print("benchmark".ljust(width + 2) + "status".ljust(20) + "   wall")
    for r in rows:
        detail = r.get("reason", "")
        print(f"{r['name']:<{width + 2}}{r['status']:<20}{r['wall_s']:>7.1f} s  {detail}".rstrip())
    ran = [r for r in rows if r["status"] == "ok" or r["status"].startswith("FAILED")]
    failed = [r for r in ran if r["status"] != "ok"]
    skipped = [r for r in rows if r["status"] == "skipped"]
    print(f"ran {len(ran)} ({len(failed)} failed), skipped {len(skipped)}, total {total:.1f} s")
    if not args.dry_run:
        REPORT.parent.mkdir(parents=True, exist_ok=True)
        REPORT.write_text(json.dumps({"full": args.full, "total_s": total, "benchmarks": rows}, indent=1) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
