"""The per-image segmentation mask and depth map of a render: one writer and one reader each,
and the class table both files' users share.

* ``NNNNNN_seg.png``: 8-bit indexed PNG (mode ``P``), one class id per pixel, palette
  :func:`palette` (classes in :data:`CLASSES`); no time or text chunks, so the same mask gives
  the same bytes.
* ``NNNNNN_depth.exr``: one float32 channel ``Z``, zip-compressed; z-depth in camera mm
  (:data:`DEPTH_CONVENTION`), ``inf`` where the camera sees nothing.

:data:`CLASSES` names the class ids of ``NNNNNN_seg.png`` for every user: the Blender worker
(pipeline/blender/seg_passes.py writes one coverage channel per class), the render's rule that
turns coverage into classes (pipeline/render/seg.py), the visibility rule, tests, the docs and
the dataset card. It lives here, with the file it describes, so that a reader of masks needs
nothing of the renderer.

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
DEPTH_CONVENTION = ("z-depth along the optical axis from the label camera's origin (camera.position_head_mm) "
                    "to the first surface the camera ray meets (the cornea over the iris), = -z of that "
                    "point in the label's camera frame; inf where nothing is seen; first sample of each pixel")
#: id -> (name, palette RGB). The seg PNG is indexed (mode "P") with this palette.
CLASSES = {
    0: ("background", (0, 0, 0)),
    1: ("skin", (230, 170, 140)),
    2: ("sclera", (255, 255, 255)),
    3: ("iris", (40, 110, 220)),
    4: ("pupil", (250, 40, 40)),
    5: ("eyelashes", (90, 50, 20)),
    6: ("caruncle", (250, 120, 200)),
}
NAMES = {name: i for i, (name, _) in CLASSES.items()}
BACKGROUND, SKIN, SCLERA, IRIS, PUPIL, LASHES, CARUNCLE = range(7)


def palette() -> list[int]:
    """The seg PNG's palette: 256 RGB triples, flattened (unused entries black)."""
    pal = [0] * (256 * 3)
    for i, (_, rgb) in CLASSES.items():
        pal[3 * i:3 * i + 3] = rgb
    return pal


def classes_text() -> str:
    """``"0 background, 1 skin, ..."`` (labels, docs, dataset card)."""
    return ", ".join(f"{i} {name}" for i, (name, _) in CLASSES.items())


def seg_name(index: int) -> str:
    """``NNNNNN_seg.png``: the mask of image ``index``."""
    return f"{int(index):06d}_seg.png"


def depth_name(index: int) -> str:
    """``NNNNNN_depth.exr``: the depth map of image ``index``."""
    return f"{int(index):06d}_depth.exr"


def write_seg(path, seg) -> None:
    """Write an (H, W) array of class ids as an indexed PNG with the class palette, atomically."""
    from PIL import Image

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

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        with Image.open(path, formats=["PNG"]) as img:
            img.load()
            mode, pal, a = img.mode, img.getpalette(), np.asarray(img)
    except (OSError, UnidentifiedImageError) as exc:
        raise ScanError(path, f"is not a readable PNG ({type(exc).__name__})") from None
    if mode != "P":
        raise ScanError(path, f"must be an indexed PNG (mode P), got mode {mode}")
    n = len(CLASSES)
    if pal is None or list(pal[:3 * n]) != palette()[:3 * n]:
        raise ScanError(path, "palette is not the eyerig class palette (pipeline/io/seg_file.py)")
    if a.size and int(a.max()) >= n:
        raise ScanError(path, f"holds class id {int(a.max())}; classes are 0..{n - 1}")
    if size is not None and (a.shape[1], a.shape[0]) != tuple(size):
        raise ScanError(path, f"is {a.shape[1]} x {a.shape[0]} px, the image is {size[0]} x {size[1]}")
    return a.astype(np.uint8)


def write_depth(path, depth_mm) -> None:
    """Write an (H, W) depth map (camera mm, inf = nothing) as a float32 EXR, atomically."""
    from pipeline.io.exr import write_exr

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
    from pipeline.io.exr import read_exr_product

    path = Path(path)
    a = read_exr_product(path, DEPTH_CHANNEL, f"is not a depth EXR with channel {DEPTH_CHANNEL!r}")
    if a.ndim != 2 or np.isnan(a).any() or (a <= 0).any():
        raise ScanError(path, "depth must be positive mm (inf where nothing is seen), no NaN")
    if size is not None and (a.shape[1], a.shape[0]) != tuple(size):
        raise ScanError(path, f"is {a.shape[1]} x {a.shape[0]} px, the image is {size[0]} x {size[1]}")
    return a
