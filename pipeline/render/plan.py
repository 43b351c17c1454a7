"""A dataset folder's plan: what its ``config.json`` records, how a new plan differs, what goes.

The plan of a dataset (pipeline/render/dataset.py) is everything that decides its images: the
seed, the assets in order with their weights and config hashes (render settings, asset files
and renderer code: :func:`pipeline.render.run.config_hash`), the mix (pipeline/render/mix.py)
and the render settings. The number of images is not part of it: image ``i`` is the same in
every length of the plan, so another ``--n`` is the same plan grown (images ``n..m-1`` added)
or shrunk (the tail's files removed), with no ``--overwrite``. :func:`inspect_dataset` compares
the plan recorded in a folder with a new one and lists the files a run of the new plan would
remove; it changes nothing. Only the files a
render writes are ever listed (:func:`pipeline.render.run.doomed_files` and the dataset's own
card files); any other file in the folder stays.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.render import mix
from pipeline.render import run as rr

SCHEMA = 1
#: The dataset's own files besides the images, rewritten at the end of every run.
OWN_FILES = ("dataset.json", "README.md", "timings.json", "splits/train.txt", "splits/val.txt", "splits/test.txt",
             "splits/splits.json", "card/lighting.png", "card/eye_configuration.png")


def plan_doc(assets, n: int, settings) -> dict:
    """The plan as ``config.json`` records it (``"dataset"``; asset paths are for reading, not
    compared: the config hash covers the files)."""
    return {"schema": SCHEMA, "n": int(n), "seed": int(settings.seed), "mix": mix.MIX,
            "assets": [{"name": a.name, "weight": a.weight, "config_hash": a.config_hash,
                        "asset": os.path.relpath(a.asset.usda), "rig": os.path.relpath(a.asset.rig_npz)}
                       for a in assets]}


def _short(v, width: int = 24) -> str:
    text = json.dumps(v, sort_keys=True) if not isinstance(v, str) else repr(v)
    return text if len(text) <= width else text[: width - 3] + "..."


def plan_differences(old_cfg: dict, plan: dict, settings: dict) -> list[str]:
    """What differs between the plan in ``old_cfg`` (an earlier ``config.json``) and ``plan`` with
    its hashed ``settings``, each as a few words (``"n 48 -> 2"``); empty when they are the same."""
    ds = old_cfg.get("dataset")
    if not isinstance(ds, dict) or not isinstance(ds.get("assets"), list):
        return ["its config.json records no readable plan"]
    old_assets = [a if isinstance(a, dict) else {} for a in ds["assets"]]
    # not n: a plan's image i is the same at any length (growing or shrinking is the same plan)
    diff = [f"{k} {_short(ds.get(k))} -> {_short(plan[k])}" for k in ("seed",) if ds.get(k) != plan[k]]
    if ds.get("mix") != plan["mix"]:       # plans before the quota mix record none
        diff.append(f"mix {ds.get('mix') or 'largest remainder, n-dependent'} -> {plan['mix']}")
    names = [a.get("name") for a in old_assets], [a["name"] for a in plan["assets"]]
    weights = [a.get("weight") for a in old_assets], [a["weight"] for a in plan["assets"]]
    if names[0] != names[1]:
        diff.append(f"assets {', '.join(map(str, names[0]))} -> {', '.join(names[1])}")
    elif weights[0] != weights[1]:
        diff.append(f"weights {_short(weights[0])} -> {_short(weights[1])}")
    old_set = old_cfg.get("settings") if isinstance(old_cfg.get("settings"), dict) else {}
    keys = sorted(k for k in set(old_set) | set(settings) if old_set.get(k, ...) != settings.get(k, ...))
    if keys:
        shown = ", ".join(f"{k} {_short(old_set.get(k))} -> {_short(settings.get(k))}" for k in keys[:3])
        diff.append(f"settings {shown}" + (f" and {len(keys) - 3} more" if len(keys) > 3 else ""))
    elif names[0] == names[1]:
        changed = [b["name"] for a, b in zip(old_assets, plan["assets"]) if a.get("config_hash") != b["config_hash"]]
        if changed:
            diff.append(f"asset files or renderer code of {', '.join(changed)} (config hash)")
    return diff


def _old_assignment(ds: dict) -> tuple[list[str], np.ndarray] | None:
    """``(asset keys, asset position of every index)`` of an earlier plan; None when unusable."""
    try:
        keys = [f"{a['name']}\0{a['config_hash']}" for a in ds["assets"]]
        how = mix.assign if ds.get("mix") == mix.MIX else mix.assign_legacy
        return keys, how(int(ds["n"]), [float(a["weight"]) for a in ds["assets"]], int(ds["seed"]))
    except (KeyError, TypeError, ValueError, IndexError):
        return None


@dataclass
class FolderPlan:
    """What a dataset folder holds against a new plan (:func:`inspect_dataset`).

    ``state``: ``"new"`` (absent or empty), ``"same"`` (a dataset of this plan: a run continues it)
    or ``"other"`` (a dataset of another plan, ``differences`` say how). ``remove``: the files a run
    of the new plan removes (stale and unfinished images, the tail beyond ``n``, the index, sheet
    and card); ``stale_images``: the finished images among them below ``n`` (their index now shows
    another asset); ``old_n``: the number of images the folder's plan had.
    """

    state: str
    differences: list = field(default_factory=list)
    remove: list = field(default_factory=list)
    stale_images: int = 0
    old_n: int | None = None


def check_out(out: Path) -> None:
    """``out`` is new, empty, or an earlier dataset with no symbolic link where a run writes or
    deletes (:func:`pipeline.render.run.check_no_links`); else a ScanError (and nothing is touched)."""
    rr.check_out_folder(out, "dataset")
    rr.check_no_links(out, OWN_FILES)


def inspect_dataset(out: Path, assets, assign: np.ndarray, settings) -> FolderPlan:
    """Compare the dataset folder ``out`` (:func:`check_out`) with the plan of ``assets`` over
    ``assign`` (the asset of every index) and ``settings``; changes nothing."""
    out = Path(out)
    check_out(out)
    if rr.folder_state(out) == "new":
        return FolderPlan("new")
    n = len(assign)
    old_cfg = rr.read_config(out) or {}
    diff = plan_differences(old_cfg, plan_doc(assets, n, settings), settings.hashed())
    old = _old_assignment(old_cfg.get("dataset") or {})
    new_keys = [f"{a.name}\0{a.config_hash}" for a in assets]

    def keep(i: int) -> bool:
        """Image i of the old plan shows what image i of the new one would (same asset, same config)."""
        return old is not None and i < n and i < len(old[1]) and old[0][old[1][i]] == new_keys[assign[i]]

    remove = rr.doomed_files(out, keep)
    stale = sum(1 for p in remove if p.parent == out and p.suffix == ".json" and p.stem.isdigit() and int(p.stem) < n)
    remove += [out / name for name in OWN_FILES if (out / name).is_file()]
    old_n = (old_cfg.get("dataset") or {}).get("n")
    return FolderPlan("other" if diff else "same", diff, remove, stale, old_n if isinstance(old_n, int) else None)


def resize_note(out: Path, fp: FolderPlan, n: int) -> str | None:
    """One line saying how a run of the same plan at another length changes ``out``; None when the
    length is the same (or the folder new or of another plan)."""
    if fp.state != "same" or fp.old_n is None or fp.old_n == n:
        return None
    if n > fp.old_n:
        return f"note: {out}: n {fp.old_n} -> {n}: the same plan grown, images {fp.old_n}..{n - 1} are added"
    from pipeline.render.formats import image_files

    gone = sum(1 for i, _ in image_files(out) if i >= n)
    return f"note: {out}: n {fp.old_n} -> {n}: the same plan shrunk, images {n}..{fp.old_n - 1} go ({gone} files)"


def run_notes(out: Path, fp: FolderPlan, n: int, overwrite: bool = False) -> list[str]:
    """The lines a run into ``out`` (inspected as ``fp``) prints before it renders: how another
    length changes the same plan, and what ``--overwrite`` removes."""
    notes = [line for line in (resize_note(out, fp, n),) if line]
    if overwrite and fp.state == "new":
        notes.append(f"note: --overwrite: no earlier dataset in {out}, nothing goes")
    elif overwrite:
        what = "; ".join(fp.differences) or "the same plan"
        notes.append(f"note: --overwrite: {len(fp.remove)} files of the earlier dataset in {out} go ({what})")
    return notes


def refusal(out: Path, fp: FolderPlan, overwrite: bool = False, resume: bool = False) -> ScanError | None:
    """The error that refuses a run into ``out`` (inspected as ``fp``), None when it may go:
    ``--resume`` continues only a dataset of the same plan; another plan needs ``overwrite``."""
    if resume and fp.state == "new":
        return ScanError(out, "--resume: holds no dataset to resume (leave out --resume to start one)")
    if fp.state != "other" or (overwrite and not resume):
        return None
    what = f"holds a dataset of another plan ({'; '.join(fp.differences)})"
    if resume:
        return ScanError(out, f"{what}: --resume continues only the same plan")
    return ScanError(out, f"{what}: --overwrite replaces it ({len(fp.remove)} files go; the images the "
                          "new plan shares are kept), or use another folder (nothing was changed)")
