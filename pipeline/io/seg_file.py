"""The per-image segmentation mask and depth map of a render: one writer and one reader each.

* ``NNNNNN_seg.png``: 8-bit indexed PNG (mode ``P``), one class id per pixel, palette
  :func:`pipeline.render.seg.palette` (classes in :data:`pipeline.render.seg.CLASSES`); no
  time or text chunks, so the same mask gives the same bytes.
* ``NNNNNN_depth.exr``: one float32 channel ``Z``, zip-compressed; z-depth in camera mm
  (convention in :mod:`pipeline.render.seg`), ``inf`` where the camera sees nothing.

Written by the Blender render worker (pipeline/blender/seg_passes.py), moved into place by the
render stage's shard task, read by the shard task (visibility), tests and benchmarks. The
readers check size, mode, palette, class range and values, and refuse anything else with one
line naming the file.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import atomic_file, write_bytes

DEPTH_CHANNEL = "Z"


def seg_name(index: int) -> str:
    """``NNNNNN_seg.png``: the mask of image ``index``."""
    return f"{int(index):06d}_seg.png"


def depth_name(index: int) -> str:
    """``NNNNNN_depth.exr``: the depth map of image ``index``."""
    return f"{int(index):06d}_depth.exr"


def write_seg(path, seg) -> None:
    """Write an (H, W) array of class ids as an indexed PNG with the class palette, atomically."""
    from PIL import Image

    from pipeline.render.seg import CLASSES, palette

    a = np.asarray(seg)
    if a.ndim != 2 or a.size == 0 or a.min() < 0 or a.max() >= len(CLASSES):
        raise ValueError(f"seg must be a non-empty 2D array of class ids 0..{len(CLASSES) - 1}")
    img = Image.fromarray(a.astype(np.uint8), mode="P")
    img.putpalette(palette())
    buf = io.BytesIO()
    img.save(buf, format="PNG", optimize=False, compress_level=6)
    write_bytes(path, buf.getvalue())


def read_seg(path, size: tuple[int, int] | None = None) -> np.ndarray:
    """The (H, W) uint8 class ids of a seg PNG, validated (``size`` = (width, height) to expect).

    Raises
    ------
    ScanError  missing, not a PNG, not indexed, another palette, a class id out of range, another size.
    """
    from PIL import Image, UnidentifiedImageError

    from pipeline.render.seg import CLASSES, palette

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        with Image.open(path) as img:
            img.load()
            mode, pal, a = img.mode, img.getpalette(), np.asarray(img)
    except (OSError, UnidentifiedImageError) as exc:
        raise ScanError(path, f"is not a readable PNG ({type(exc).__name__})") from None
    if mode != "P":
        raise ScanError(path, f"must be an indexed PNG (mode P), got mode {mode}")
    n = len(CLASSES)
    if pal is None or list(pal[:3 * n]) != palette()[:3 * n]:
        raise ScanError(path, "palette is not the eyerig class palette (pipeline/render/seg.py)")
    if a.size and int(a.max()) >= n:
        raise ScanError(path, f"holds class id {int(a.max())}; classes are 0..{n - 1}")
    if size is not None and (a.shape[1], a.shape[0]) != tuple(size):
        raise ScanError(path, f"is {a.shape[1]} x {a.shape[0]} px, the image is {size[0]} x {size[1]}")
    return a.astype(np.uint8)


def write_depth(path, depth_mm) -> None:
    """Write an (H, W) depth map (camera mm, inf = nothing) as a float32 EXR, atomically."""
    from pipeline.bake.exr import write_exr

    a = np.asarray(depth_mm, np.float32)
    if a.ndim != 2 or a.size == 0 or np.isnan(a).any() or (a <= 0).any():
        raise ValueError("depth must be a non-empty 2D array of positive mm (inf where nothing is seen)")
    with atomic_file(path) as tmp:
        write_exr(tmp, a, channel=DEPTH_CHANNEL)


def read_depth(path, size: tuple[int, int] | None = None) -> np.ndarray:
    """The (H, W) float32 depth map (camera mm, inf = nothing), validated.

    Raises
    ------
    ScanError  missing, not an EXR with channel ``Z``, NaN or non-positive values, another size.
    """
    from pipeline.bake.exr import read_exr

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        a = read_exr(path, DEPTH_CHANNEL)
    except Exception as exc:  # noqa: BLE001 -- OpenEXR raises several types for unreadable files
        raise ScanError(path, f"is not a depth EXR with channel {DEPTH_CHANNEL!r} ({type(exc).__name__})") from None
    if a.ndim != 2 or np.isnan(a).any() or (a <= 0).any():
        raise ScanError(path, "depth must be positive mm (inf where nothing is seen), no NaN")
    if size is not None and (a.shape[1], a.shape[0]) != tuple(size):
        raise ScanError(path, f"is {a.shape[1]} x {a.shape[0]} px, the image is {size[0]} x {size[1]}")
    return a
