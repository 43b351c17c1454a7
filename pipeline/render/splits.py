"""Train / validation / test splits of a dataset by identity: no asset in two splits.

``DIR/splits/{train,val,test}.txt`` list the images (``NNNNNN.png``, one a line, in index order)
of the assets each split holds; ``DIR/splits/splits.json`` says which asset went where, with the
proportions, the seed and the image counts. Rewritten at the end of every run (a grown dataset's
new images join their asset's split).

Which assets: ``render.splits`` gives the proportions (train, val, test; they need not sum to
1) and ``render.split_seed`` the order. The assets are sorted by name and permuted by
``numpy.random.default_rng([split_seed, SPLIT_TAG])``, so the split of an asset depends on the
set of asset names and the split seed, not on ``--assets``' order, the render seed or ``n``:
datasets of the same identities under other presets or seeds share their test identities. The
counts of assets per split: every split of positive proportion gets one asset while there are
enough, the rest by largest remainder of ``k * p / sum(p)`` (5 assets at 0.8 / 0.1 / 0.1: 3 / 1 / 1).
Identities, not images, are split: a split's share of images follows its assets' weights.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pipeline.io.atomic import write_json, write_text

NAMES = ("train", "val", "test")
FOLDER = "splits"
FILES = tuple(f"{FOLDER}/{s}.txt" for s in NAMES) + (f"{FOLDER}/splits.json",)
#: Second word of the split stream's key (the bytes of ``"split"``, above any image index).
SPLIT_TAG = 2**32 + 0x73706C6974


def split_counts(k: int, proportions) -> list[int]:
    """Assets per split: one for each positive proportion while ``k`` allows (in split order), the
    rest by largest remainder of the quotas (earlier split on ties)."""
    p = np.asarray(proportions, float)
    counts = np.zeros(len(p), int)
    for j in np.flatnonzero(p > 0)[:k]:
        counts[j] = 1
    left = k - counts.sum()
    if left > 0:
        quota = k * p / p.sum() - counts
        base = np.floor(np.maximum(quota, 0)).astype(int)
        base = np.minimum(base, left)
        counts += base
        rest = left - base.sum()
        frac = np.where(p > 0, quota - np.floor(np.maximum(quota, 0)), -math.inf)
        for j in np.argsort(-frac, kind="stable")[:rest]:
            counts[j] += 1
    return counts.tolist()


def split_assets(names, proportions, seed: int) -> dict:
    """``{asset name: split name}`` (module doc)."""
    order = sorted(names)
    perm = np.random.default_rng([int(seed), SPLIT_TAG]).permutation(len(order))
    counts = split_counts(len(order), proportions)
    out, at = {}, 0
    for s, c in zip(NAMES, counts):
        for j in perm[at:at + c]:
            out[order[int(j)]] = s
        at += c
    return out


def write_splits(out: Path, asset_names, asset_of_index, proportions, seed: int) -> dict:
    """Write the split files of a dataset whose image ``i`` shows ``asset_names[asset_of_index[i]]``;
    returns what ``splits.json`` holds."""
    out = Path(out)
    where = split_assets(asset_names, proportions, seed)
    lists = {s: [] for s in NAMES}
    for i, a in enumerate(asset_of_index):
        lists[where[asset_names[int(a)]]].append(f"{i:06d}.png")
    (out / FOLDER).mkdir(exist_ok=True)
    for s in NAMES:
        write_text(out / FOLDER / f"{s}.txt", "".join(f"{x}\n" for x in lists[s]))
    doc = {"rule": "by identity: no asset in two splits (pipeline/render/splits.py)",
           "proportions": dict(zip(NAMES, map(float, proportions))), "split_seed": int(seed),
           "assets": {s: sorted(a for a, v in where.items() if v == s) for s in NAMES},
           "images": {s: len(v) for s, v in lists.items()}}
    write_json(out / FOLDER / "splits.json", doc)
    return doc
