"""COCO files: run-length encoded masks as pycocotools writes them, and the dataset's ``coco.json``.

RLE (pycocotools ``mask.encode``, ``maskApi.c``): the (H, W) binary mask read in column-major
(Fortran) order, as alternating run lengths starting with a run of 0s (0 when the first pixel is
set). ``{"size": [H, W], "counts": [...]}`` is COCO's uncompressed RLE; the compressed form,
``counts`` as a string, is ``rleToString``: each count after the second is stored as its
difference from the count two before, in 5-bit groups, least significant first, ``+ 48`` per
character, bit ``0x20`` meaning "more groups follow" and bit ``0x10`` of the last group the sign.
:func:`rle_encode` / :func:`rle_decode` are transcriptions of those C functions (no pycocotools
needed to write or read); tests hold them against pycocotools itself.

Written by the ``coco`` label format (pipeline/render/formats/coco.py): one fragment per image
(``coco/NNNNNN.json``) and the assembled ``coco.json``; read by tests and anyone's COCO tools.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError


def rle_counts(mask) -> list[int]:
    """Uncompressed RLE counts of an (H, W) mask (non-zero = set), column-major, 0-run first."""
    m = np.asarray(mask).astype(bool).ravel(order="F")
    if m.size == 0:
        return []
    change = np.flatnonzero(m[1:] != m[:-1]) + 1
    bounds = np.concatenate([[0], change, [m.size]])
    runs = np.diff(bounds).tolist()
    return ([0] + runs) if m[0] else runs


def counts_to_string(counts) -> str:
    """pycocotools' ``rleToString``: compressed RLE counts (see the module doc)."""
    out = []
    cnts = [int(c) for c in counts]
    for i, x in enumerate(cnts):
        if i > 2:
            x -= cnts[i - 2]
        more = True
        while more:
            c = x & 0x1F
            x >>= 5                      # arithmetic shift, as C's on a signed long
            more = (x != -1) if (c & 0x10) else (x != 0)
            if more:
                c |= 0x20
            out.append(chr(c + 48))
    return "".join(out)


def string_to_counts(s: str) -> list[int]:
    """pycocotools' ``rleFrString``: the counts of a compressed RLE string."""
    cnts: list[int] = []
    p = 0
    while p < len(s):
        x, k, more = 0, 0, True
        while more:
            c = ord(s[p]) - 48
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(cnts) > 2:
            x += cnts[-2]
        cnts.append(x)
    return cnts


def rle_encode(mask) -> dict:
    """COCO compressed RLE of an (H, W) mask: ``{"size": [H, W], "counts": str}``."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be 2D (got shape {m.shape})")
    return {"size": [int(m.shape[0]), int(m.shape[1])], "counts": counts_to_string(rle_counts(m))}


def rle_decode(rle: dict) -> np.ndarray:
    """(H, W) uint8 0/1 mask of a COCO RLE, compressed (``counts`` a string) or not (a list)."""
    h, w = (int(v) for v in rle["size"])
    counts = rle["counts"]
    cnts = string_to_counts(counts) if isinstance(counts, str) else [int(c) for c in counts]
    if sum(cnts) != h * w or any(c < 0 for c in cnts):
        raise ValueError(f"RLE counts cover {sum(cnts)} pixels, size {h} x {w} has {h * w}")
    flat = np.repeat(np.arange(len(cnts)) % 2, cnts).astype(np.uint8)
    return flat.reshape((h, w), order="F")


def mask_bbox(mask) -> list[float]:
    """``[x, y, width, height]`` in pixels of the set pixels (pycocotools ``toBbox``; zeros when empty)."""
    m = np.asarray(mask).astype(bool)
    if not m.any():
        return [0.0, 0.0, 0.0, 0.0]
    ys, xs = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    return [float(xs[0]), float(ys[0]), float(xs[-1] - xs[0] + 1), float(ys[-1] - ys[0] + 1)]


def fragment_name(index: int) -> str:
    """``NNNNNN.json``: the COCO fragment of image ``index`` (inside the ``coco/`` folder)."""
    return f"{int(index):06d}.json"


def read_fragment(path) -> dict:
    """One image's fragment ``{"image": {...}, "annotations": [...]}``; ScanError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "missing: the image has no COCO fragment (render it with label format coco)")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ScanError(path, f"is not a COCO fragment: {exc}") from None
    if not (isinstance(doc, dict) and isinstance(doc.get("image"), dict)
            and isinstance(doc.get("annotations"), list)):
        raise ScanError(path, "is not a COCO fragment (needs an image object and an annotations list)")
    return doc
