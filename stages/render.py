"""Stage ``render``: labelled close-up eye images of one scan (Cycles, sharded with Dask).

    python -m stages.render rigged_assets/<scan> build/<scan>/rig renders/<scan> \
        --metrics build/<scan>/render.metrics.json [--scheduler ADDRESS] [--workers N] [--n-images N]

Sample ``i`` is a pure function of ``(seed, i)`` (pipeline/render/sampling.py), so sharding and
resuming never change labels. Per image: ``NNNNNN.png`` + ``NNNNNN.json`` (label, written
last = done); at the end ``index.jsonl`` (sorted, every index 0..n-1 exactly once),
``contact_sheet.png`` (landmarks drawn) and ``config.json`` (the hash of everything that changes
images or labels: the ``render`` params except n_images / worker settings, and the asset files).
Re-running resumes: finished images are skipped; a config change deletes the stale images first.
Images are rendered by persistent Blender processes (pipeline/blender/render_worker.py), one per
dask worker (pipeline/render/shard.py): a ``LocalCluster`` of ``workers`` processes by default,
or the cluster at ``--scheduler`` / params ``scheduler`` (its workers must see the same paths).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from collections import Counter
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_json, write_text
from stages._common import default_metrics_path, load_params, stage_exit, stage_parser

RUN_KEYS = {"workers", "scheduler", "shard_size", "threads", "tile_size", "sheet_images", "image_timeout_s",
            "progress", "connect_timeout_s"}


# Cycles given one thread still keeps a second one busy (about a quarter of an image's CPU
# time wasted), so two Blenders sharing two cores are slower than one Blender using both:
# 0.53 s/image with 2 workers x 1 thread against 0.43 s/image with 1 worker x 2 threads on
# 2 cores (benchmarks/bench_render.py, scaling); two threads per Blender is the floor.
MIN_THREADS = 2


def auto_workers(cores: int) -> int:
    """Local Blender workers for ``cores`` CPU cores: one per :data:`MIN_THREADS` cores."""
    return max(1, int(cores) // MIN_THREADS)


def config_hash(settings, fingerprint: str) -> str:
    blob = json.dumps({"settings": settings.hashed(), "asset": fingerprint}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _image_files(out: Path):
    for p in out.iterdir():
        stem = p.name.split(".")[0]
        if p.suffix in (".png", ".json") and stem.isdigit() and len(stem) == 6:
            yield int(stem), p


def prepare_out(out: Path, chash: str, n_images: int) -> dict:
    """Create/clean the output folder: stale images of another config, extra indices, temp files."""
    out.mkdir(parents=True, exist_ok=True)
    cfg = out / "config.json"
    removed = 0
    old = None
    if cfg.is_file():
        try:
            old = json.loads(cfg.read_text()).get("config_hash")
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
            old = None
    stale = old != chash
    for i, p in list(_image_files(out)):
        if stale or i >= n_images:
            p.unlink()
            removed += 1
    for name in ("index.jsonl", "contact_sheet.png"):
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / ".tmp", ignore_errors=True)
    (out / ".tmp").mkdir()
    for p in out.glob("*.png"):                       # a PNG without its JSON is unfinished
        stem = p.stem
        if stem.isdigit() and not (out / f"{stem}.json").is_file():
            p.unlink()
    return {"stale_config": bool(stale and old is not None), "removed_files": removed}


def main(argv) -> dict:
    ap = stage_parser(__doc__.splitlines()[0])
    ap.add_argument("asset", type=Path, help="rigged_assets/<scan> (holds <scan>.usda)")
    ap.add_argument("rig", type=Path, help="build/<scan>/rig (holds rig.npz)")
    ap.add_argument("out", type=Path, help="renders/<scan>")
    ap.add_argument("--scheduler", default=None, help="dask scheduler address (default: a LocalCluster)")
    ap.add_argument("--workers", type=int, default=None, help="LocalCluster worker processes")
    ap.add_argument("--n-images", type=int, default=None, help="override params render.n_images")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)

    from pipeline.render import asset as ra
    from pipeline.render import labels as lb
    from pipeline.render import sampling as sp
    from pipeline.render import shard as sh
    from pipeline.render.sheet import contact_sheet

    t0 = time.perf_counter()
    params = load_params("render", args.params)
    if args.n_images is not None:
        params["n_images"] = args.n_images
    unknown = sorted(set(params) - set(sp.RenderSettings.__dataclass_fields__) - RUN_KEYS)
    if unknown:
        raise ScanError(Path(args.params), f"render: unknown key(s) {unknown}")
    try:
        settings = sp.RenderSettings.from_dict(params)
    except (ValueError, TypeError) as exc:
        raise ScanError(Path(args.params), f"render: {exc}") from None
    workers = args.workers if args.workers is not None else int(params.get("workers") or 0)
    if workers < 0:
        raise ScanError(Path(args.params), "render: workers must be >= 0 (0 = auto)")
    workers = workers or auto_workers(os.cpu_count() or 1)
    scheduler = args.scheduler or params.get("scheduler") or None
    asset = ra.load_render_asset(args.asset, args.rig)
    out = args.out
    chash = config_hash(settings, asset.fingerprint())
    prep = prepare_out(out, chash, settings.n_images)
    write_json(out / "config.json", {"config_hash": chash, "scan": asset.name,
                                     "asset": str(asset.usda), "settings": settings.hashed()})

    n = settings.n_images
    pending = [i for i in range(n) if not sh.done(out, i)]
    items, attempts = [], {}
    for i in pending:
        try:
            smp = sp.make_sample(asset, settings, i, sp.tmp_png(out, i))
        except sp.RejectionError as exc:
            raise ScanError(args.asset, str(exc)) from None
        attempts[i] = smp.attempts
        label = lb.make_label(smp, settings, asset.name)
        if asset.eyes[smp.side].eyeball_params:
            label["_apparent_job"] = lb.apparent_job(smp, asset.eyes[smp.side], settings)
        items.append((smp.spec, label))
    t_sample = time.perf_counter() - t0

    # shards: one HDRI each (the worker switches maps rarely), at most shard_size images
    shard_size = max(1, int(params.get("shard_size", 8)))
    by_hdri: dict = {}
    for spec, lab in items:
        by_hdri.setdefault(spec["lighting"]["hdri"], []).append((spec, lab))
    shards = [grp[k:k + shard_size] for _, grp in sorted(by_hdri.items())
              for k in range(0, len(grp), shard_size)]
    threads = int(params.get("threads", 0) or 0)
    if not threads and not scheduler:
        threads = max(1, (os.cpu_count() or 1) // workers)
    opts = {"threads": threads, "tile_size": params.get("tile_size"),
            "tolerance_mm": settings.landmark_tolerance_mm, "log_dir": str((out / ".tmp").resolve()),
            "image_timeout_s": float(params.get("image_timeout_s", 600))}
    t1 = time.perf_counter()
    run = {"results": [], "workers": 0, "blender": {}}
    if shards:
        run = sh.run_shards(shards, asset.usda, asset.rig_npz, out.resolve(), opts, workers=workers,
                            scheduler=scheduler, progress=not args.no_progress and params.get("progress", True),
                            connect_timeout_s=float(params.get("connect_timeout_s", 10)))
    t_render = time.perf_counter() - t1
    res = [r for r in run["results"] if not r.get("skipped")]
    failed = [r for r in res if not r.get("ok")]
    if failed:
        raise ScanError(out, f"{len(failed)} of {len(res)} images failed; first: image "
                             f"{failed[0]['index']}: {failed[0].get('error')}")

    # index, contact sheet
    lines, labels = [], {}
    for i in range(n):
        if not sh.done(out, i):
            raise ScanError(out, f"image {i} missing after the run")
        lab = json.loads((out / f"{i:06d}.json").read_text())
        labels[i] = lab
        lines.append(json.dumps({"index": i, "png": f"{i:06d}.png", "json": f"{i:06d}.json",
                                 "eye": lab["gaze"]["eye"], "gaze_camera_deg": [lab["gaze"]["camera"]["pitch_deg"],
                                                                                 lab["gaze"]["camera"]["yaw_deg"]],
                                 "landmark_check_mm": lab.get("landmark_check_mm")}))
    write_text(out / "index.jsonl", "".join(x + "\n" for x in lines))
    n_sheet = min(n, int(params.get("sheet_images", 16)))
    sheet_px = None
    if n_sheet:
        sheet_px = contact_sheet([(out / f"{i:06d}.png", labels[i]) for i in range(n_sheet)],
                                 out / "contact_sheet.png")
    shutil.rmtree(out / ".tmp", ignore_errors=True)

    wall = time.perf_counter() - t0
    rs = [r["render_s"] for r in res if r.get("render_s") is not None]
    rss = [r["rss_mib"] for r in res if r.get("rss_mib") is not None]
    cpu = [r["total_cpu_s"] for r in res if r.get("total_cpu_s") is not None]
    checks = [lab.get("landmark_check_mm") or 0.0 for lab in labels.values()]
    all_attempts = [lab["seed"]["attempts"] for lab in labels.values()]
    return {"_path": args.metrics or default_metrics_path(out),
            "n_images": n, "rendered": len(res), "skipped_done": n - len(res),
            "stale_config": prep["stale_config"], "removed_files": prep["removed_files"],
            "workers": run["workers"], "scheduler": scheduler or "LocalCluster",
            "threads_per_blender": threads, "shards": len(shards),
            "blender_starts": int(sum(v.get("starts", 0) for v in run["blender"].values())),
            "sampling_s": round(t_sample, 3), "render_wall_s": round(t_render, 3),
            "s_per_image": round(t_render / len(res), 4) if res else None,
            "images_per_s": round(len(res) / t_render, 4) if res and t_render > 0 else None,
            "render_s_median": round(float(np.median(rs)), 4) if rs else None,
            "blender_cpu_s_per_image_median": (round(float(np.median(cpu)), 4) if cpu else None),
            "worker_rss_max_mib": max(rss) if rss else None,
            "landmark_check_max_mm": float(max(checks)) if checks else None,
            "rejections": int(sum(a - 1 for a in all_attempts)),
            "attempts_max": int(max(all_attempts)) if all_attempts else 0,
            "skin_detail": dict(Counter(lab["render"]["skin_detail"] for lab in labels.values())),
            "hdri": dict(Counter(lab["lighting"]["hdri"] for lab in labels.values())),
            "contact_sheet_px": list(sheet_px) if sheet_px else None,
            "samples": settings.samples, "size": [settings.width, settings.height],
            "preset": settings.preset, "seed": settings.seed, "stage_wall_s": round(wall, 3)}


if __name__ == "__main__":
    stage_exit(main)
