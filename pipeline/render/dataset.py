"""Datasets across many identities: one resumable, sharded render over several rigged assets.

The library of the dataset command (``python -m stages.dataset``, stages/dataset.py, which reads
the settings and says what happens); here nothing reads params.yaml or prints.

Image ``i`` (global index ``0..n-1``) shows asset ``assign(n, weights, seed)[i]``
(pipeline/render/mix.py: the quota method's sequence, which does not depend on ``n``: every
prefix within one image of the weights' proportions, interleaved) and is
sample ``i`` of the render stage's sampler for that asset (``default_rng([seed, i, attempt])``,
pipeline/render/sampling.py), so it is a pure function of the settings, the asset and ``i``.
The render machinery is the render stage's (pipeline/render/run.py, shard.py): shards of one
HDRI each go to a Dask ``LocalCluster`` or ``--scheduler``, one persistent Blender per worker,
asset after asset; labels are written last (pipeline/io/labels_file.py), so an image is done
when its JSON exists. Each label carries ``"asset": {"name", "id"}``.

DIR holds ``NNNNNN.png`` + ``NNNNNN.json``; ``config.json`` (written first: the plan and the
hashes a resumed run compares); at the end ``index.jsonl`` (every index once, with its asset),
``contact_sheet.png``, ``dataset.json`` (the machine-readable description), ``card/*.png`` (the
card's plots, pipeline/render/plots.py), ``README.md`` (the dataset card, pipeline/render/card.py)
and ``timings.json`` (what the last run measured). One progress bar covers the whole run.

The folder (pipeline/render/plan.py): a re-run of the same plan (the number of images, seed,
assets, weights, render settings and each asset's config hash: render settings, asset files and
renderer source, :func:`pipeline.render.run.config_hash`) continues it, skipping finished images;
``--resume`` does only that. A dataset of another plan is refused with one line naming what
differs, unless ``--overwrite``: then the command says how many files go, keeps every image
whose index the new plan gives the same asset under the same config hash and deletes the other
images first, so a changed weight or asset re-renders only the images whose asset changed.
Another ``--n`` is the same plan: a larger one adds images ``n..m-1`` and touches no other, a
smaller one removes the tail. Only the files a render writes are ever deleted; a folder that is neither new, empty
nor a dataset is refused, ``--overwrite`` or not. Settings come from the ``render:`` block of
``--params`` (image size, samples, ranges, label formats, workers, ...); ``--set KEY=VALUE``,
``--n``, ``--preset`` and ``--seed`` override it.

Bad input (a missing or invalid asset or rig, a weight count that does not match, an output
folder that is not a dataset or holds another plan) is a ScanError raised before anything is
written.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_json, write_text
from pipeline.io.folder_lock import folder_lock
from pipeline.io.labels_file import SCHEMA as LABEL_SCHEMA
from pipeline.io.labels_file import label_name, read_index, read_label
from pipeline.io.scratch import stage_scratch
from pipeline.render import formats, mix, plots, splits
from pipeline.render import plan as pl
from pipeline.render import run as rr
from pipeline.render.plan import SCHEMA
from pipeline.render.settings import MAX_IMAGES, RenderSettings, parse_overrides

INFO, CARD, TIMINGS = pl.OWN_FILES[:3]
#: ``rigged_assets/eyeball`` holds the eyeball every asset references, not a head: skipped.
SHARED_EYEBALL = "eyeball"
SEG_FILE = "NNNNNN_seg.png"
FILES = {
    "index.jsonl": "one line per image, every index 0..n-1 once: index, png, json, asset, asset_id, eye, "
                   "gaze_camera_deg, landmark_check_mm",
    "dataset.json": "this card as data: image size, assets (id, name, weight, count, licence), "
                    "conventions, settings",
    "contact_sheet.png": "the first images with their landmarks drawn, each tile naming its asset",
    "card/*.png": "the card's plots: " + "; ".join(f"`{k}` {v}" for k, v in plots.PLOTS.items()),
    "splits/{train,val,test}.txt": "the images (NNNNNN.png, one a line) of each split by identity: no asset in "
                                   "two splits (render.splits, render.split_seed; pipeline/render/splits.py)",
    "splits/splits.json": "which asset went to which split, the proportions, the seed, images per split",
    "config.json": "the plan and hashes a resumed run compares (not data)",
    "timings.json": "what the last run measured (not data)",
    "README.md": "this card",
}


@dataclass
class DatasetAsset:
    """One identity of the dataset: its position ``id`` in ``--assets``, weight and render inputs."""

    id: int
    name: str
    folder: Path
    rig: Path
    weight: float
    asset: object                   # pipeline.render.asset.RenderAsset
    config_hash: str

    def meta(self, key: str) -> str:
        return str(self.asset.metadata.get(key) or "")

    def doubts(self) -> list[str]:
        """The asset's doubts (:meth:`pipeline.render.asset.RenderAsset.doubts`)."""
        return self.asset.doubts()


def is_shared_eyeball(folder: Path) -> bool:
    """``rigged_assets/eyeball``: the parametric eye the scan assets reference."""
    return folder.name == SHARED_EYEBALL and (folder / f"{SHARED_EYEBALL}.usda").is_file()


def asset_inputs(paths, rigs=None) -> tuple[list[tuple[Path, Path]], list[Path]]:
    """``(asset folder, rig folder)`` of each ``--assets`` path, and the skipped shared eyeball.

    Without ``rigs`` the rig of ``<root>/rigged_assets/<name>`` is ``<root>/build/<name>/rig``
    (where the rig stage writes it).

    Raises
    ------
    ScanError  a path that is not a folder, no scan asset left, a rig count that does not match.
    """
    pairs, skipped = [], []
    folders = [Path(p) for p in paths]
    if rigs is not None and len(rigs) != len(folders):
        raise ScanError("--rigs", f"{len(rigs)} rig folder(s) for {len(folders)} asset(s): give one per asset")
    for k, f in enumerate(folders):
        if not f.is_dir():
            raise ScanError(f, "rigged asset folder not found")
        if rigs is None and is_shared_eyeball(f):
            skipped.append(f)
            continue
        rig = Path(rigs[k]) if rigs is not None else f.resolve().parent.parent / "build" / f.name / "rig"
        if not (rig / "rig.npz").is_file():
            raise ScanError(rig, f"no rig.npz for the asset {f} (the rig stage's output; --rigs names it)")
        pairs.append((f, rig))
    if not pairs:
        raise ScanError(" ".join(map(str, folders)) or "--assets", "no scan asset given (rigged_assets/"
                        f"{SHARED_EYEBALL} is the shared eyeball, not a head)")
    return pairs, skipped


def load_assets(pairs, weights, settings) -> list[DatasetAsset]:
    """Read every asset and rig (pipeline/render/asset.py) and hash its render config.

    Raises
    ------
    ScanError  an asset or rig the render cannot use, two assets with one name, bad weights.
    """
    from pipeline.render.asset import load_render_asset

    try:
        w = mix.check_weights(weights, len(pairs))
    except ValueError as exc:
        raise ScanError("--weights", str(exc)) from None
    out, seen = [], {}
    for k, ((folder, rig), wk) in enumerate(zip(pairs, w)):
        a = load_render_asset(folder, rig)
        if a.name in seen:
            raise ScanError(folder, f"asset name '{a.name}' is also the name of {seen[a.name]} "
                                    "(labels and index name images by their asset)")
        seen[a.name] = folder
        out.append(DatasetAsset(id=k, name=a.name, folder=folder, rig=rig, weight=wk, asset=a,
                                config_hash=rr.config_hash(settings, a.fingerprint())))
    return out


def dataset_settings(block: dict, n: int, overrides=(), preset: str | None = None, seed: int | None = None,
                     workers: int | None = None, progress: bool = True, source="params.yaml") -> RenderSettings:
    """The dataset command's settings: the ``render:`` settings ``block`` (of ``source``) with the
    ``--set`` ``overrides`` (``KEY=VALUE`` strings), ``n`` images, and each option that is not
    None over the block's value (``progress`` False turns the bar off).

    Raises
    ------
    ScanError  ``n`` out of 1..MAX_IMAGES, a bad ``--set`` item, a bad setting.
    """
    if not 1 <= n <= MAX_IMAGES:
        raise ScanError("--n", f"must be between 1 and {MAX_IMAGES} (got {n})")
    params = {**block, **parse_overrides(overrides or ())}
    params["n_images"] = n
    for key, value in (("preset", preset), ("seed", seed), ("workers", workers)):
        if value is not None:
            params[key] = value
    if not progress:
        params["progress"] = False
    return RenderSettings.from_params(params, source=source)


def prepare_dataset(out: Path, assets, assign: np.ndarray, settings, overwrite: bool = False,
                    resume: bool = False) -> dict:
    """Clean ``out`` for the plan (see the module docstring) and write its ``config.json``.

    Raises
    ------
    ScanError  ``out`` is not a dataset folder, holds another plan without ``overwrite``, or holds
               no dataset or another plan with ``resume`` (:func:`pipeline.render.plan.refusal`).
    """
    n = len(assign)
    fp = pl.inspect_dataset(out, assets, assign, settings)
    err = pl.refusal(out, fp, overwrite=overwrite, resume=resume)
    if err is not None:
        raise err
    plan = pl.plan_doc(assets, n, settings)
    chash = hashlib.sha256(json.dumps({"settings": settings.hashed(), "plan": plan},
                                      sort_keys=True).encode()).hexdigest()
    out.mkdir(parents=True, exist_ok=True)
    for p in fp.remove:
        p.unlink(missing_ok=True)
    shutil.rmtree(out / ".tmp", ignore_errors=True)
    write_json(out / rr.CONFIG, {"config_hash": chash, "dataset": plan, "settings": settings.hashed()})
    (out / ".tmp").mkdir()              # after config.json: a folder holding only .tmp is not ours
    return {"stale_images": fp.stale_images, "removed_files": len(fp.remove), "stale_config": fp.state == "other"}


def _tagged(shards, a: DatasetAsset):
    """The shards of :func:`pipeline.render.run.pending_shards` with the asset in every label."""
    for shard in shards:
        for _, label in shard:
            label["asset"] = {"name": a.name, "id": a.id}
        yield shard


def image_files(out: Path) -> dict:
    """``{"NNNNNN<rest>": what it holds}`` for the files image 0 has (every image has the same
    files), described by the label writers (pipeline/render/formats)."""
    names = sorted(p.relative_to(out).as_posix().replace("000000", "NNNNNN", 1)
                   for i, p in formats.image_files(out) if i == 0)
    return {**{k: formats.describe(k) for k in names}, **formats.dataset_table(out)}


def masks_info(out: Path) -> dict | None:
    """What ``dataset.json`` says of the segmentation masks: None when image 0 has none."""
    if not (Path(out) / SEG_FILE.replace("NNNNNN", "000000")).is_file():
        return None
    from pipeline.io.seg_file import CLASSES          # the masks' class table (written with them)

    return {"file": SEG_FILE, "format": "8-bit indexed PNG (mode P), one class id per pixel",
            "classes": {str(i): name for i, (name, _) in sorted(CLASSES.items())}}


def dataset_info(out: Path, assets, counts, settings, n: int) -> dict:
    """The ``dataset.json`` description (also what the card is written from)."""
    import pipeline
    from pipeline.render.labels import FRAMES, LANDMARK_ORDER

    total_w = sum(a.weight for a in assets)
    return {
        "schema": SCHEMA, "name": Path(out).resolve().name, "pipeline_version": pipeline.__version__,
        "n_images": int(n), "seed": int(settings.seed), "preset": settings.preset,
        "label_schema": LABEL_SCHEMA,
        "image": {"width": settings.width, "height": settings.height, "channels": 3, "dtype": "uint8",
                  "format": "PNG, 8-bit RGB", "pixels": "origin at the top-left pixel corner, x right, "
                                                       "y down, pixel centres at +0.5"},
        "files": {**image_files(out), **FILES},
        "mixing": "Image i shows asset assign(n, weights, seed)[i] (pipeline/render/mix.py): the first n terms "
                  "of Balinski and Young's quota method, a sequence that does not depend on n (growing the "
                  "dataset adds images, changes none), every prefix within one image of n * weight / sum of "
                  "weights, ties in a seeded order; images are drawn with numpy.random.default_rng([seed, i, "
                  "attempt]) over the global index i, so no two images share a random stream.",
        "assets": [{"id": a.id, "name": a.name, "weight": a.weight, "share": a.weight / total_w,
                    "count": int(counts[a.id]), "licence": a.meta("licence"),
                    "source_sha256": a.meta("source_sha256"), "pipeline_version": a.meta("pipeline_version"),
                    "doubts": a.doubts(),
                    "asset": os.path.relpath(a.asset.usda), "rig": os.path.relpath(a.asset.rig_npz)}
                   for a in assets],
        "frames": FRAMES, "units": "mm", "angles": "degrees",
        "landmarks": {"n": 28, "order": LANDMARK_ORDER},
        "masks": masks_info(out),
        "settings": settings.hashed(),
    }


def _check_index(out: Path, assets, assign: np.ndarray) -> np.ndarray:
    """Every index once, from its planned asset (index.jsonl against the plan); counts per asset."""
    rows = read_index(out / "index.jsonl")
    if [r["index"] for r in rows] != list(range(len(assign))):
        raise ScanError(out / "index.jsonl", "does not list every index 0..n-1 once in order")
    for r in rows:
        a = assets[int(assign[r["index"]])]
        if r.get("asset_id") != a.id or r.get("asset") != a.name:
            raise ScanError(out / r["json"], f"is an image of {r.get('asset')!r}, planned: {a.name!r}")
    return np.bincount(assign, minlength=len(assets))


def render_dataset(assets, settings, n: int, out, scheduler: str | None = None, progress: bool = True,
                   overwrite: bool = False, resume: bool = False, on_dashboard=None, security=None) -> dict:
    """Render (resuming) the ``n``-image dataset of ``assets`` into ``out``; returns the run's measures.

    Parameters
    ----------
    assets : list of DatasetAsset   (:func:`load_assets`)
    settings : pipeline.render.settings.RenderSettings   (its n_images is not used)
    n : int                          images in the dataset
    out : path                       the dataset folder (new, empty or an earlier dataset)
    scheduler : str, optional        a dask scheduler address (default: a LocalCluster)
    overwrite : bool                 replace a dataset of another plan (its images the new plan
                                     shares are kept); without it such a folder is refused
    resume : bool                    only continue a dataset of this plan
    on_dashboard : callable, optional  serve a LocalCluster's dashboard (127.0.0.1), called with its URL
    security : distributed.security.Security, optional  the client's TLS credentials for ``scheduler``
                                     (None: Dask's config; a LocalCluster makes its own)

    Raises
    ------
    ScanError  ``out`` refused (:func:`prepare_dataset`), an image failed, a sample could not be
               drawn, the scheduler is unreachable.
    """
    from pipeline.render import shard as sh
    from pipeline.render.card import dataset_card

    t0 = time.perf_counter()
    out = Path(out)
    assign = mix.assign(n, [a.weight for a in assets], settings.seed)
    prep = prepare_dataset(out, assets, assign, settings, overwrite=overwrite, resume=resume)
    how = rr.run_options(settings, out, scheduler)
    res = rr.Results()
    stats = {"sampling_s": 0.0, "shards": 0}
    per_asset, starts, t_render = {}, 0, 0.0
    todo = {a.id: [int(i) for i in np.flatnonzero(assign == a.id) if not sh.done(out, int(i))] for a in assets}
    bar = rr.Progress(sum(map(len, todo.values())), progress and settings.progress)   # one bar, all assets
    try:
        for a in assets:
            pending = todo[a.id]
            per_asset[a.name] = {"pending": len(pending)}
            if not pending:
                continue
            t1, s0 = time.perf_counter(), stats["sampling_s"]
            shards = _tagged(rr.pending_shards(a.asset, settings, out, pending, how["window"], stats, a.folder), a)
            run = sh.run_shards(shards, a.asset.usda, a.asset.rig_npz, out.resolve(), how["opts"],
                                workers=how["workers"], scheduler=how["scheduler"], progress=False,
                                connect_timeout_s=settings.connect_timeout_s, total=len(pending),
                                on_result=bar.of(a.name, res), on_dashboard=on_dashboard, security=security)
            dt = time.perf_counter() - t1 - (stats["sampling_s"] - s0)
            t_render += dt
            starts += int(sum(v.get("starts", 0) for v in run["blender"].values()))
            per_asset[a.name]["render_wall_s"] = round(dt, 3)
            if res.failed:
                f = res.first_failure
                raise ScanError(out, f"{res.failed} of {res.n} images failed; first: image "
                                     f"{f['index']} ({a.name}): {f.get('error')}")
    finally:
        bar.close()

    summary = rr.index_and_sheet(out, n, min(n, settings.sheet_images))
    counts = _check_index(out, assets, assign)
    formats.finish_formats(out, n, settings)         # coco.json, webdataset shards (pipeline/render/formats)
    info = dataset_info(out, assets, counts, settings, n)
    info["splits"] = splits.write_splits(out, [a.name for a in assets], assign, settings.splits, settings.split_seed)
    info["statistics"] = plots.label_stats((read_label(out / label_name(i)).doc for i in range(n)),
                                           [a.name for a in assets])
    info["plots"] = plots.write_plots(out, info["statistics"])
    write_json(out / INFO, info)
    write_text(out / CARD, dataset_card(info, read_label(out / label_name(0)).doc))
    shutil.rmtree(out / ".tmp", ignore_errors=True)
    wall = time.perf_counter() - t0
    timings = {"n_images": n, "rendered": res.n, "skipped_done": n - res.n, **prep,
               "workers": how["workers"], "scheduler": how["scheduler"] or "LocalCluster",
               "threads_per_blender": how["threads"], "shards": stats["shards"], "blender_starts": starts,
               "sampling_s": round(stats["sampling_s"], 3), "render_wall_s": round(t_render, 3),
               "images_per_s": round(res.n / t_render, 4) if res.n and t_render > 0 else None,
               "s_per_image": round(t_render / res.n, 4) if res.n else None,
               "landmark_check_max_mm": summary["landmark_check_max_mm"], "rejections": summary["rejections"],
               "per_asset": per_asset, "counts": {a.name: int(counts[a.id]) for a in assets},
               "wall_s": round(wall, 3)}
    write_json(out / TIMINGS, timings)
    return timings


def run_line(out, timings: dict, n_assets: int) -> str:
    """The line the dataset command ends with: what :func:`render_dataset`'s run (its ``timings``)
    made of ``out`` with ``n_assets`` assets."""
    rate = f", {timings['images_per_s']:.2f} images/s" if timings["images_per_s"] else ""
    return (f"{out}: {timings['n_images']} images of {n_assets} assets ({timings['rendered']} rendered, "
            f"{timings['skipped_done']} kept{rate}, {timings['wall_s']:.1f} s)")


def make_dataset(out, pairs, skipped, weights, settings, n: int, overwrite: bool = False, resume: bool = False,
                 note=None, **render) -> tuple[list[DatasetAsset], dict]:
    """The dataset command's run of ``n`` images of ``pairs`` (:func:`asset_inputs`) into ``out``;
    returns the assets and the run's measures (:func:`render_dataset`).

    ``out`` is checked and locked first (one run at a time in it, until the run ends:
    pipeline/io/folder_lock.py), the assets read and the plan checked against ``out``
    (:func:`pipeline.render.plan.refusal`), all before anything is written; then the images are
    rendered (``render``: :func:`render_dataset`'s scheduler, progress, on_dashboard, security)
    with Blender's and Dask's ``TMPDIR`` a scratch folder removed at exit (pipeline/io/scratch.py).
    ``note(line)`` hears each line the command says on the way, as it comes (so the lines before a
    refusal are said too): a lock taken over from a dead run, the ``skipped`` shared eyeball, each
    asset's doubts (it is rendered all the same), what another ``n`` or ``overwrite`` changes.

    Raises
    ------
    ScanError  ``out`` refused or held by another run, an asset or rig the render cannot use, bad
               weights (:func:`load_assets`), or what :func:`render_dataset` raises.
    """
    note = note or (lambda line: None)
    out = Path(out)
    pl.check_out(out)
    with folder_lock(out) as took_over:
        if took_over:
            note(f"warning: {took_over}")
        for f in skipped:
            note(f"note: skipped {f} (the shared eyeball, not a head)")
        assets = load_assets(pairs, weights, settings)
        for a in assets:                      # rendered all the same; the card lists them too
            for d in a.doubts():
                note(f"warning: {a.folder}: {d}")
        assign = mix.assign(n, [a.weight for a in assets], settings.seed)
        fp = pl.inspect_dataset(out, assets, assign, settings)
        err = pl.refusal(out, fp, overwrite=overwrite, resume=resume)
        if err is not None:
            raise err
        for line in pl.run_notes(out, fp, n, overwrite=overwrite):
            note(line)
        with stage_scratch("dataset"):
            return assets, render_dataset(assets, settings, n, out, overwrite=overwrite, resume=resume, **render)
