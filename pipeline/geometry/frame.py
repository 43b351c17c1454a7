"""Units and axes: scan coordinates -> the head frame in millimetres.

Head frame (fixed, DESIGN.md): +Y up, +Z forward (out of the face), +X toward
the subject's left, right-handed, so ``x = up x forward``. A scan declares which
of its signed axes points up and which forward; the third is derived by
right-handedness (a mirrored scan cannot be told apart from its axes alone:
:func:`check_eye_layout` catches it through the eye hints).
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import ScanError
# the eye frame is part of eyes.json's convention (what its forward means), so io defines it
from pipeline.io.eyes_file import eye_basis  # noqa: F401

UNITS_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
_AXIS = {"X": 0, "Y": 1, "Z": 2}


def axis_vector(axis: str) -> np.ndarray:
    """``"+Y"`` -> ``[0, 1, 0]``; ``"-Z"`` -> ``[0, 0, -1]`` (float64, shape (3,))."""
    axis = axis.strip().upper()
    if len(axis) != 2 or axis[0] not in "+-" or axis[1] not in _AXIS:
        raise ValueError(f"axis must be one of +X -X +Y -Y +Z -Z, got {axis!r}")
    v = np.zeros(3)
    v[_AXIS[axis[1]]] = 1.0 if axis[0] == "+" else -1.0
    return v


def scan_to_head_rotation(up_axis: str, forward_axis: str) -> np.ndarray:
    """Rotation taking scan coordinates to head-frame axes.

    Parameters
    ----------
    up_axis, forward_axis : str
        Signed scan axes (``"+Y"``, ``"-Z"``, ...), not parallel.

    Returns
    -------
    (3, 3) float64
        ``R`` with rows ``(up x forward, up, forward)`` so ``p_head = R @ p_scan``;
        ``det(R) = +1``.
    """
    up, fwd = axis_vector(up_axis), axis_vector(forward_axis)
    if abs(np.dot(up, fwd)) > 0.5:
        raise ValueError(f"up_axis {up_axis} and forward_axis {forward_axis} are parallel")
    return np.stack([np.cross(up, fwd), up, fwd])


def to_head_frame(P, units: str, up_axis: str, forward_axis: str) -> np.ndarray:
    """Scan points -> head-frame millimetres.

    Parameters
    ----------
    P : (n, 3) or (3,) array_like
        Points in scan coordinates and ``units``.
    units : str
        ``"mm"``, ``"cm"`` or ``"m"``.
    up_axis, forward_axis : str

    Returns
    -------
    (n, 3) or (3,) float64
    """
    R = scan_to_head_rotation(up_axis, forward_axis) * UNITS_TO_MM[units]
    return np.asarray(P, dtype=np.float64) @ R.T


def from_head_frame(P, units: str, up_axis: str, forward_axis: str) -> np.ndarray:
    """Inverse of :func:`to_head_frame`: head-frame mm -> scan coordinates and units."""
    R = scan_to_head_rotation(up_axis, forward_axis) / UNITS_TO_MM[units]
    return np.asarray(P, dtype=np.float64) @ R


def bounds(V):
    """Bounding box of ``V`` (n, 3): ``lo``, ``hi`` (3,) float64.

    One reduction per column: numpy's ``V.min(axis=0)`` runs a length-3 inner loop per row,
    13x slower on a million vertices; the values are the same.
    """
    lo = np.array([V[:, k].min() for k in range(3)], dtype=np.float64)
    hi = np.array([V[:, k].max() for k in range(3)], dtype=np.float64)
    return lo, hi


def check_float32(V, path, tolerance_mm: float = 0.01) -> float:
    """Refuse coordinates whose float32 step exceeds ``tolerance_mm`` (huge offsets).

    Parameters
    ----------
    V : (n, 3) float64, mm
    path : str or os.PathLike
        Named in the error.
    tolerance_mm : float

    Returns
    -------
    float
        The float32 step (mm) at the largest coordinate magnitude.
    """
    if len(V):
        lo, hi = bounds(V)                      # max |x| without an |V| temporary
        big = float(max(0.0, -lo.min(), hi.max()))
    else:
        big = 0.0
    step = float(np.spacing(np.float32(big)))
    if step > tolerance_mm:
        raise ScanError(path, f"coordinates reach {big:.4g} mm from the origin, where float32 steps are "
                              f"{step:.3g} mm (> {tolerance_mm} mm): move the scan near the origin")
    return step


def check_head_size(V, units: str, path, size_range_mm=(40.0, 1000.0), *, hints=None,
                    separation_mm=(30.0, 120.0)) -> np.ndarray:
    """Refuse a bounding box implausible for a head in the declared units.

    Where the eye hints (declared in the same units) lie a plausible distance apart, the units
    are right and the mesh is what is wrong (a fragment a scanner's trim left, or a body), so no
    other units are suggested.

    Parameters
    ----------
    V : (n, 3) float64
        Head-frame mm (already scaled with ``units``).
    units : str
        The declared units (to suggest the likely right ones).
    path : str or os.PathLike
    size_range_mm : (2,) float
        Accepted range of the largest bounding-box side, mm.
    hints : dict or None
        ``{"left", "right"}`` eye hints, head-frame mm, or None.
    separation_mm : (2,) float
        The distance between the hints that says the units are right (:func:`check_eye_layout`).

    Returns
    -------
    (3,) float64
        Bounding-box extent, mm.
    """
    lo, hi = bounds(V)
    extent = hi - lo
    size = float(extent.max())
    lo, hi = size_range_mm
    if lo <= size <= hi:
        return extent
    if hints is not None:
        sep = float(np.linalg.norm(np.asarray(hints["left"], float) - np.asarray(hints["right"], float)))
        if separation_mm[0] <= sep <= separation_mm[1]:
            what = "only a fragment of a head" if size < lo else "more than a head (crop it to the head)"
            raise ScanError(path, f"bounding box is {size:.4g} mm across with units {units}, not a plausible "
                                  f"head ({lo:g} to {hi:g} mm); the eye hints lie {sep:.3g} mm apart in the "
                                  f"same units, so the units are right and the mesh holds {what}")
    scale = UNITS_TO_MM[units]
    raw = size / scale
    fits = [u for u, s in UNITS_TO_MM.items() if u != units and lo <= raw * s <= hi]
    hint = f"; read as {fits[0]} it would be {raw * UNITS_TO_MM[fits[0]]:.4g} mm: units is probably {fits[0]}" \
        if fits else ""
    raise ScanError(path, f"bounding box is {size:.4g} mm across with units {units}, not a plausible head "
                          f"({lo:g} to {hi:g} mm){hint}")


def check_eye_layout(left, right, path, separation_mm=(30.0, 120.0)) -> float:
    """Check that the eye hints sit side by side with the left eye on +X.

    Parameters
    ----------
    left, right : (3,) float64
        Head-frame mm.
    path : str or os.PathLike
        Named in errors (the sidecar).
    separation_mm : (2,) float
        Accepted distance between the hints.

    Returns
    -------
    float
        Distance between the hints, mm.
    """
    d = np.asarray(left, float) - np.asarray(right, float)
    dist = float(np.linalg.norm(d))
    lo, hi = separation_mm
    if not lo <= dist <= hi:
        raise ScanError(path, f"eye hints are {dist:.4g} mm apart in the head frame, outside {lo:g} to {hi:g} mm "
                              "(wrong units or hints?)")
    if abs(d[0]) < max(abs(d[1]), abs(d[2])):
        raise ScanError(path, f"eye hints are not side by side along the head's X axis (left - right = "
                              f"[{d[0]:.3g}, {d[1]:.3g}, {d[2]:.3g}] mm): check up_axis and forward_axis")
    if d[0] < 0:
        raise ScanError(path, "the left eye hint lies on the subject's right (-X) in the head frame: "
                              "forward_axis sign is wrong, the scan is mirrored, or left/right hints are swapped")
    return dist
