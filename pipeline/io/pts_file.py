"""300-W / iBUG landmark files (``renders/<scan>/NNNNNN.pts``): one writer, one reader.

The format of the 300-W annotations (``version: 1``, ``n_points:  N``, ``{``, one ``x y`` line a
point, ``}``), coordinates in pixels, 1-based (the centre of the top-left pixel is (1, 1)); the
caller converts (pipeline/render/label_formats.py: ours + 0.5). Six decimals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_text
from pipeline.io.docfile import check_array


def pts_name(index: int) -> str:
    """``NNNNNN.pts``: the landmark file of image ``index``."""
    return f"{int(index):06d}.pts"


def pts_text(points) -> str:
    """The text of a ``.pts`` file of ``points`` (n, 2)."""
    P = np.asarray(points, float)
    lines = ["version: 1", f"n_points:  {len(P)}", "{"] + [f"{x:.6f} {y:.6f}" for x, y in P] + ["}"]
    return "\n".join(lines) + "\n"


def write_pts(path, points) -> None:
    """Write ``points`` (n, 2), finite, to ``path`` atomically."""
    P = check_array(np.asarray(points, float), (None, 2), path, "points")
    write_text(path, pts_text(P))


def read_pts(path) -> np.ndarray:
    """(n, 2) float64 points of a ``.pts`` file, as stored (1-based).

    Raises
    ------
    ScanError
        One line naming the file: missing, not the format, a count that is not ``n_points``.
    """
    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as exc:
        raise ScanError(path, f"cannot be read ({type(exc).__name__})") from None
    head = lines[:3]
    if len(head) < 3 or head[0] != "version: 1" or not head[1].startswith("n_points:") or head[2] != "{" \
            or lines[-1] != "}":
        raise ScanError(path, "is not a version 1 .pts file (version: 1, n_points: N, '{', points, '}')")
    try:
        n = int(head[1].split(":", 1)[1])
    except ValueError:
        raise ScanError(path, f"n_points must be an integer (got {head[1]!r})") from None
    try:
        rows = [[float(v) for v in ln.split()] for ln in lines[3:-1]]
    except ValueError:
        rows = None
    if rows is None or any(len(r) != 2 for r in rows):
        raise ScanError(path, "holds a point line that is not two numbers")
    P = np.array(rows, float).reshape(-1, 2)
    if len(P) != n:
        raise ScanError(path, f"n_points is {n} but it lists {len(P)} points")
    return check_array(P, (n, 2), path, "points")
