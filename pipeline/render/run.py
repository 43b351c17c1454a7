"""The render stage's work: one resumable, sharded render of a scan's asset into its folder.

:func:`render_scan` checks the output folder is new, empty or an earlier render
(:func:`check_render_out`: someone else's folder is refused), prepares it (:func:`prepare_out`:
a changed config deletes the stale images, unfinished ones are dropped), writes ``config.json``,
samples the pending images a window at a time into shards of one HDRI each (:func:`pending_shards`),
renders them through dask (pipeline/render/shard.py), then writes ``index.jsonl`` and the
contact sheet from the labels (pipeline/io/labels_file.py) and returns the metrics.

Sample ``i`` is a pure function of ``(seed, i)`` (pipeline/render/sampling.py), so sharding and
resuming never change labels. An image is done when its label (written last) exists.
``config.json`` holds the hash of everything that changes images or labels: the ``render``
settings except n_images / worker settings, and the asset fingerprint
(:meth:`pipeline.render.asset.RenderAsset.fingerprint`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import time
from array import array
from collections import Counter
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_file, write_json
from pipeline.io.labels_file import index_line, label_name, read_label
from pipeline.render.formats import dataset_files, finish_formats, format_job, image_files
from pipeline.results import StageResult

# Cycles given one thread still keeps a second one busy (about a quarter of an image's CPU
# time wasted), so two Blenders sharing two cores are slower than one Blender using both:
# 0.53 s/image with 2 workers x 1 thread against 0.43 s/image with 1 worker x 2 threads on
# 2 cores (benchmarks/bench_render.py, scaling); two threads per Blender is the floor.
MIN_THREADS = 2
CONFIG = "config.json"


def auto_workers(cores: int) -> int:
    """Local Blender workers for ``cores`` CPU cores: one per :data:`MIN_THREADS` cores."""
    return max(1, int(cores) // MIN_THREADS)


def run_options(settings, out: Path, scheduler: str | None = None) -> dict:
    """How a run of ``settings`` into ``out`` goes.

    Returns
    -------
    dict  ``workers`` (LocalCluster processes), ``scheduler`` (an address, or None for a
          LocalCluster), ``threads`` (Cycles threads per Blender), ``window`` (images sampled at
          a time: a few shards per HDRI) and ``opts`` (the shard task's options).
    """
    workers = settings.workers or auto_workers(os.cpu_count() or 1)
    scheduler = scheduler or settings.scheduler or None
    threads = settings.threads
    if not threads and not scheduler:
        threads = max(1, (os.cpu_count() or 1) // workers)
    opts = {"threads": threads, "tile_size": settings.tile_size,
            "tolerance_mm": settings.landmark_tolerance_mm, "log_dir": str((Path(out) / ".tmp").resolve()),
            "image_timeout_s": settings.image_timeout_s, "masks": settings.masks}
    return {"workers": workers, "scheduler": scheduler, "threads": threads, "opts": opts,
            "window": max(64, settings.shard_size * len(settings.hdris) * 4)}


def config_hash(settings, fingerprint: str) -> str:
    """sha256 of the hashed render settings and the asset fingerprint."""
    blob = json.dumps({"settings": settings.hashed(), "asset": fingerprint}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def read_config(out: Path) -> dict | None:
    """``out/config.json`` of an earlier run (None when absent or unreadable: a folder of
    unknown config is treated as stale)."""
    try:
        doc = json.loads((Path(out) / CONFIG).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return None
    return doc if isinstance(doc, dict) else None


#: The dataset card's plots (pipeline/render/plots.py draws them at the end of a dataset run).
CARD_PLOTS = ("card/gaze.png", "card/head_pose.png", "card/assets.png", "card/eye.png", "card/visibility.png")
#: Files a run rebuilds from the labels at its end (removed first, so a killed run leaves none stale).
DERIVED_FILES = ("index.jsonl", "contact_sheet.png") + CARD_PLOTS


def folder_state(out: Path) -> str:
    """What ``out`` is to a render: ``"new"`` (absent, or holding nothing but hidden entries other
    than ``.tmp``), ``"render"`` or ``"dataset"`` (its ``config.json`` is a render stage's or a
    dataset command's), ``"file"`` (not a folder) or ``"other"`` (someone else's folder).

    Only a ``"render"`` or ``"dataset"`` folder is ever cleaned, and then only of the files a
    render writes (:func:`doomed_files`): every other file in it stays."""
    out = Path(out)
    if not out.exists():
        return "file" if out.is_symlink() else "new"
    if not out.is_dir():
        return "file"
    cfg = read_config(out)
    if cfg is not None and isinstance(cfg.get("config_hash"), str):
        return "dataset" if "dataset" in cfg else "render"
    # hidden files (.DS_Store, a killed write's temp sibling) do not make a folder someone's work;
    # a .tmp does: a render would empty it
    if all(e.name.startswith(".") and e.name != ".tmp" for e in os.scandir(out)):
        return "new"
    return "other"


#: Why a folder in each state is refused, by the kind of folder a command writes.
_REFUSED = {
    "render": {"dataset": "holds a dataset of python -m stages.dataset, not a scan's renders: "
                          "use another folder",
               "other": "exists, is not empty and holds no renders (no render config.json): "
                        "use a new or empty folder"},
    "dataset": {"render": "holds a scan's renders (the render stage's), not a dataset: use another folder",
                "other": "exists, is not empty and is not a dataset folder (no dataset config.json): "
                         "use a new or empty folder"},
}


def check_out_folder(out: Path, kind: str) -> None:
    """``out`` is new, empty or an earlier folder of ``kind`` (``"render"``: the render stage's,
    ``"dataset"``); else a ScanError saying why, and nothing in it is touched."""
    state = folder_state(out)
    if state == "file":
        raise ScanError(out, "exists and is not a folder")
    why = _REFUSED[kind].get(state)
    if why is not None:
        raise ScanError(out, f"{why} (nothing was changed)")


def check_render_out(out: Path) -> None:
    """:func:`check_out_folder` for the render stage."""
    check_out_folder(out, "render")
    check_no_links(out)


def _owned(rel: str, own=()) -> bool:
    """Is ``rel`` (a path relative to a render or dataset folder) one a run writes or deletes?"""
    from pipeline.render.formats import INDEX, _matches, dataset_file_table, file_table

    if rel in (CONFIG, ".tmp", *DERIVED_FILES, *own) or rel.startswith(".tmp/"):
        return True
    folder, _, name = rel.rpartition("/")
    for pattern in file_table():
        pf, _, base = pattern.rpartition("/")
        if pf == folder and _matches(name, base.replace(INDEX, "SSSSSS")):
            return True
    return any(pf == folder and _matches(name, base)
               for pf, _, base in (p.rpartition("/") for p in dataset_file_table()))


def check_no_links(out: Path, own=()) -> None:
    """Refuse (ScanError naming it) a symbolic link in the folder ``out`` where a run writes or
    deletes: ``.tmp``, a folder its files go in (``card/``, a format's), or a file of its own
    (``own``: more names the caller writes). A run never follows a link out of its folder; a link
    of the user's under another name is left alone. Nothing is touched."""
    from pipeline.io.atomic import refuse_link
    from pipeline.render.formats import dataset_file_table, file_table

    out = Path(out)
    if not out.is_dir():
        return
    folders = {".tmp"} | {p.rpartition("/")[0] for p in (*file_table(), *dataset_file_table(), *DERIVED_FILES, *own)}
    folders.discard("")
    for f in sorted(folders):
        refuse_link(out / f, out)
    for d in [out] + [out / f for f in sorted(folders) if (out / f).is_dir()]:
        with os.scandir(d) as it:
            for e in it:
                rel = Path(e.path).relative_to(out).as_posix()
                if e.is_symlink() and _owned(rel, own):
                    refuse_link(e.path)


def doomed_files(out: Path, keep) -> list[Path]:
    """The files a run into the render folder ``out`` removes before rendering: every file of image
    ``i`` unless ``keep(i)`` and its label exists (an image without its label is unfinished), and
    :data:`DERIVED_FILES`. Only names a render writes; nothing else in ``out``."""
    out = Path(out)
    files = list(image_files(out)) if out.is_dir() else []   # every format's files (pipeline/render/formats)
    gone = [p for i, p in files if not (keep(i) and (out / label_name(i)).is_file())]
    return gone + [out / n for n in DERIVED_FILES if (out / n).is_file()] + [p for _, p in dataset_files(out)]


def prepare_out(out: Path, chash: str, n_images: int) -> dict:
    """Clean the render folder ``out`` for a run of config ``chash`` (:func:`doomed_files`: images of
    another config, extra indices, unfinished images; the scratch folder ``.tmp``). The caller
    checked ``out`` (:func:`check_render_out`) and writes ``config.json``, then ``.tmp``."""
    out.mkdir(parents=True, exist_ok=True)
    old = (read_config(out) or {}).get("config_hash")
    stale = old != chash
    gone = doomed_files(out, lambda i: not stale and i < n_images)
    for p in gone:
        p.unlink(missing_ok=True)
    shutil.rmtree(out / ".tmp", ignore_errors=True)
    return {"stale_config": bool(stale and old is not None), "removed_files": len(gone)}


def pending_shards(asset, settings, out: Path, pending, window: int, stats: dict, source):
    """Shards of ``(spec, label)`` pairs, sampled lazily ``window`` images at a time (memory stays
    flat for any n_images): within a window, one HDRI per shard, at most ``shard_size`` images.
    A sample that cannot be drawn is a ScanError naming ``source``."""
    from pipeline.render import labels as lb
    from pipeline.render import sampling as sp

    it = iter(pending)
    while True:
        chunk = [i for _, i in zip(range(window), it)]
        if not chunk:
            return
        t0 = time.perf_counter()
        by_hdri: dict = {}
        for i in chunk:
            try:
                smp = sp.make_sample(asset, settings, i, sp.tmp_png(out, i))
            except sp.RejectionError as exc:
                raise ScanError(source, str(exc)) from None
            label = lb.make_label(smp, settings, asset.name)
            if asset.eyes[smp.side].eyeball_params:
                label["_apparent_job"] = lb.apparent_job(smp, asset.eyes[smp.side], settings)
            formats = format_job(asset, smp, settings.label_formats, settings)
            if formats is not None:                  # unityeyes / pts files (written before the label)
                label["_formats"] = formats
            by_hdri.setdefault(smp.spec.lighting.hdri, []).append((smp.spec, label))
        stats["sampling_s"] += time.perf_counter() - t0
        k = settings.shard_size
        for _, grp in sorted(by_hdri.items()):
            for j in range(0, len(grp), k):
                stats["shards"] += 1
                yield grp[j:j + k]


class Progress:
    """One tqdm bar (on stderr) over all the images a run renders, whatever the asset: its
    description names the asset of the latest finished image, its postfix the failures so far.
    Disabled (silent) when ``enabled`` is false or there is nothing to render."""

    def __init__(self, total: int, enabled: bool, file=None):
        from tqdm import tqdm

        self.failed, self.name = 0, None
        self.bar = tqdm(total=total, unit="img", desc="render", disable=not enabled or total == 0,
                        file=file if file is not None else sys.stderr, dynamic_ncols=True, smoothing=0.1)

    def of(self, name: str, on_result):
        """The ``on_result`` callback of pipeline/render/shard.py ``run_shards`` for asset ``name``:
        calls ``on_result`` and advances the bar."""
        def result(r: dict) -> None:
            on_result(r)
            if not r.get("skipped") and not r.get("ok"):
                self.failed += 1
                self.bar.set_postfix(failed=self.failed, refresh=False)
            if self.name != name:
                self.name = name
                self.bar.set_description_str(name, refresh=False)
            self.bar.update(1)
        return result

    def close(self) -> None:
        self.bar.close()


class Results:
    """Per-image results of the run, aggregated as they come (no list of every image)."""

    def __init__(self):
        self.n = 0
        self.failed = 0
        self.first_failure = None
        self.render_s = array("d")
        self.cpu_s = array("d")
        self.rss_max = None

    def __call__(self, r: dict) -> None:
        if r.get("skipped"):
            return
        self.n += 1
        if not r.get("ok"):
            self.failed += 1
            self.first_failure = self.first_failure or r
        if r.get("render_s") is not None:
            self.render_s.append(r["render_s"])
        if r.get("total_cpu_s") is not None:
            self.cpu_s.append(r["total_cpu_s"])
        if r.get("rss_mib") is not None:
            self.rss_max = max(self.rss_max or 0.0, r["rss_mib"])


def index_and_sheet(out: Path, n: int, n_sheet: int) -> dict:
    """index.jsonl (streamed), the contact sheet, and label statistics, reading each label once."""
    from pipeline.render import shard as sh
    from pipeline.render.sheet import contact_sheet

    sheet = []
    skin, hdri = Counter(), Counter()
    check_max, rejections, attempts_max = None, 0, 0
    with atomic_file(out / "index.jsonl") as tmp, open(tmp, "w", encoding="utf-8") as fh:
        for i in range(n):
            if not sh.done(out, i):
                raise ScanError(out, f"image {i} missing after the run")
            lab = read_label(out / label_name(i))
            if lab.index != i:
                raise ScanError(lab.path, f"holds the label of image {lab.index}")
            fh.write(index_line(lab))
            d = lab.doc
            c = float(d.get("landmark_check_mm") or 0.0)
            check_max = c if check_max is None else max(check_max, c)
            a = int(d["seed"]["attempts"])
            rejections += a - 1
            attempts_max = max(attempts_max, a)
            skin[d["render"]["skin_detail"]] += 1
            hdri[d["lighting"]["hdri"]] += 1
            if i < n_sheet:
                sheet.append((out / f"{i:06d}.png", d))
    sheet_px = contact_sheet(sheet, out / "contact_sheet.png") if sheet else None
    return {"landmark_check_max_mm": check_max, "rejections": rejections, "attempts_max": attempts_max,
            "skin_detail": dict(skin), "hdri": dict(hdri),
            "contact_sheet_px": list(sheet_px) if sheet_px else None}


def render_scan(asset, settings, out, source, scheduler: str | None = None, progress: bool = True,
                on_dashboard=None) -> StageResult:
    """Render ``settings.n_images`` labelled images of ``asset`` into ``out`` (resuming).

    Parameters
    ----------
    asset : pipeline.render.asset.RenderAsset
    settings : pipeline.render.settings.RenderSettings
    out : path            ``renders/<scan>``
    source : path         what a sampling failure names (the asset folder)
    scheduler : str, optional
        A dask scheduler address (default: ``settings.scheduler``, else a LocalCluster of
        ``settings.workers`` or :func:`auto_workers` Blender processes).
    progress : bool       show a progress bar (and ``settings.progress``)
    on_dashboard : callable, optional
        Serve a LocalCluster's dask dashboard (on 127.0.0.1) and call this with its URL.

    Returns
    -------
    StageResult  what the renders are (metrics) and what this run measured (timings)

    Raises
    ------
    ScanError  an image failed, a sample could not be drawn, the scheduler is unreachable.
    """
    from pipeline.render import shard as sh

    t0 = time.perf_counter()
    out = Path(out)
    how = run_options(settings, out, scheduler)
    workers, scheduler, threads, opts = how["workers"], how["scheduler"], how["threads"], how["opts"]
    chash = config_hash(settings, asset.fingerprint())
    check_render_out(out)
    prep = prepare_out(out, chash, settings.n_images)
    # the asset as a path from the working directory (the repository under DVC): an absolute
    # path would make config.json, and so dvc.lock, depend on where the clone lives
    write_json(out / CONFIG, {"config_hash": chash, "scan": asset.name,
                              "asset": os.path.relpath(asset.usda), "settings": settings.hashed()})
    (out / ".tmp").mkdir()              # after config.json: a folder holding only .tmp is not ours

    n = settings.n_images
    n_pending = sum(1 for i in range(n) if not sh.done(out, i))
    pending = (i for i in range(n) if not sh.done(out, i))
    stats = {"sampling_s": 0.0, "shards": 0}
    shards = pending_shards(asset, settings, out, pending, how["window"], stats, source)
    t1 = time.perf_counter()
    res = Results()
    run = {"workers": 0, "blender": {}}
    if n_pending:
        bar = Progress(n_pending, progress and settings.progress)
        try:
            run = sh.run_shards(shards, asset.usda, asset.rig_npz, out.resolve(), opts, workers=workers,
                                scheduler=scheduler, progress=False, connect_timeout_s=settings.connect_timeout_s,
                                total=n_pending, on_result=bar.of(asset.name, res), on_dashboard=on_dashboard)
        finally:
            bar.close()
    t_render = time.perf_counter() - t1 - stats["sampling_s"]
    if res.failed:
        f = res.first_failure
        raise ScanError(out, f"{res.failed} of {res.n} images failed; first: image "
                             f"{f['index']}: {f.get('error')}")

    summary = index_and_sheet(out, n, min(n, settings.sheet_images))
    finish_formats(out, n, settings)                 # coco.json, webdataset shards (pipeline/render/formats)
    shutil.rmtree(out / ".tmp", ignore_errors=True)

    wall = time.perf_counter() - t0
    rs, cpu = np.asarray(res.render_s), np.asarray(res.cpu_s)
    metrics = {"n_images": n, "landmark_check_max_mm": summary.pop("landmark_check_max_mm"), **summary,
               "samples": settings.samples, "size": [settings.width, settings.height],
               "preset": settings.preset, "seed": settings.seed}
    timings = {"rendered": res.n, "skipped_done": n - res.n,     # this run, not the renders
               "stale_config": prep["stale_config"], "removed_files": prep["removed_files"],
               "workers": run["workers"], "scheduler": scheduler or "LocalCluster",
               "threads_per_blender": threads, "shards": stats["shards"],
               "blender_starts": int(sum(v.get("starts", 0) for v in run["blender"].values())),
               "sampling_s": round(stats["sampling_s"], 3), "render_wall_s": round(t_render, 3),
               "s_per_image": round(t_render / res.n, 4) if res.n else None,
               "images_per_s": round(res.n / t_render, 4) if res.n and t_render > 0 else None,
               "render_s_median": round(float(np.median(rs)), 4) if rs.size else None,
               "blender_cpu_s_per_image_median": round(float(np.median(cpu)), 4) if cpu.size else None,
               "worker_rss_max_mib": res.rss_max, "stage_wall_s": round(wall, 3)}
    return StageResult(metrics, timings)
