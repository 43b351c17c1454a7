"""Label format ``pts``: the 28 landmarks as a 300-W / iBUG ``.pts`` file per image.

``NNNNNN.pts`` (written by pipeline/io/pts_file.py): the 28 landmarks in our order (0-11 eyelid,
12-19 iris, 20-27 pupil) in the 300-W / iBUG format, whose coordinates are 1-based (the centre of
the top-left pixel is (1, 1); menpo, from the same group, subtracts 1 on reading): our pixel
coordinates + 0.5.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.io.pts_file import pts_name, write_pts

NAME = "pts"
FILES = {"NNNNNN.pts": "the 28 landmarks as a 300-W .pts file (pixels)"}


def pts_points(label: dict) -> np.ndarray:
    """(28, 2) the landmarks in 300-W's 1-based pixel coordinates (ours + 0.5)."""
    return np.asarray(label["landmarks"]["px"], float) + 0.5


def job(asset, smp) -> None:
    """Nothing beyond the label."""
    return None


def write(out_dir, index: int, label: dict, job, png) -> list[Path]:
    """Write ``NNNNNN.pts`` of image ``index`` into ``out_dir``; its path."""
    p = Path(out_dir) / pts_name(index)
    write_pts(p, pts_points(label))
    return [p]
