"""Which of an image's 28 landmarks the camera sees, from the same render's mask and depth.

For landmark ``k`` at image position ``p`` -- the eyelid landmarks (0-11) at their projection
``px``; the iris (12-19) and pupil (20-27) landmarks where they are seen through the cornea
(``apparent_px``; their straight projection where that is null) -- the rule is:

* ``outside``: ``p`` is not inside the image (``0 <= u < W``, ``0 <= v < H``).
* Otherwise the pixels whose centres lie within :data:`NEIGHBOURHOOD_PX` of ``p`` (a disc of up
  to 9 pixels, clipped to the image) are looked at; the landmark is **visible** when at least
  one of them shows a surface the landmark lies on:

  - eyelid landmark (on the seam of lid skin and eyeball): class skin, caruncle, sclera, iris
    or pupil, and no nearer than the landmark's own depth minus a tolerance
    (:func:`depth_tolerance_mm`: :data:`DEPTH_TOL_MM` plus the depth change of a surface
    sloped 2:1 over the neighbourhood) -- a margin landmark on the visible margin has the
    eyeball beside it at its own depth, so it is visible; a lid fold, the cornea or lashes in
    front of it are nearer;
  - iris landmark (on the limbus): class iris or sclera;
  - pupil landmark (on the pupil boundary): class pupil or iris.

* When none does, the reason is the most frequent class among the pixels that failed:
  skin or caruncle -> ``lid``, eyelashes -> ``lashes``, sclera / iris / pupil -> ``eye`` (the
  eyeball itself in front, e.g. the cornea hiding a far lid margin at a steep view),
  background -> ``outside``.

The depth of the render is the first surface along each camera ray, the mask the class of
that surface (iris and pupil as seen through the cornea); see :mod:`pipeline.render.seg`.
"""

from __future__ import annotations

import math

import numpy as np

from pipeline.io.seg_file import BACKGROUND, CARUNCLE, IRIS, LASHES, PUPIL, SCLERA, SKIN

RULE = ("visible when a pixel centre within 1.5 px of the landmark (eyelid: its projection; iris, pupil: "
        "apparent_px through the cornea) shows its surface: eyelid = skin/caruncle/eye classes no nearer than "
        "its depth - tolerance, iris = iris/sclera, pupil = pupil/iris; else occlusion = the most frequent other "
        "class (lid, lashes, eye) or outside the image; pipeline/render/visibility.py")
NEIGHBOURHOOD_PX = 1.5
DEPTH_TOL_MM = 0.5
REASONS = ("lid", "lashes", "eye", "outside")
_EYELID_OK = {SKIN, CARUNCLE, SCLERA, IRIS, PUPIL}
_IRIS_OK = {IRIS, SCLERA}
_PUPIL_OK = {PUPIL, IRIS}
_REASON = {SKIN: "lid", CARUNCLE: "lid", LASHES: "lashes", SCLERA: "eye", IRIS: "eye", PUPIL: "eye",
           BACKGROUND: "outside"}


def depth_tolerance_mm(mm_per_px: float) -> float:
    """How much nearer than an eyelid landmark a surface beside it may be and still count as its own."""
    return DEPTH_TOL_MM + 2.0 * NEIGHBOURHOOD_PX * float(mm_per_px)


def positions(px, apparent_px=None) -> np.ndarray:
    """(28, 2) where each landmark is seen: ``px``, with the non-null ``apparent_px`` (16) for 12-27."""
    P = np.array(px, float)
    for j, q in enumerate(apparent_px or []):
        if q is not None:
            P[12 + j] = q
    return P


def neighbourhood(p, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixels whose centres are within NEIGHBOURHOOD_PX of ``p``."""
    r = NEIGHBOURHOOD_PX
    u, v = float(p[0]), float(p[1])
    cols = np.arange(max(0, math.floor(u - r)), min(width, math.ceil(u + r) + 1))
    rows = np.arange(max(0, math.floor(v - r)), min(height, math.ceil(v + r) + 1))
    R, C = np.meshgrid(rows, cols, indexing="ij")
    near = (C + 0.5 - u) ** 2 + (R + 0.5 - v) ** 2 <= r * r
    return R[near], C[near]


def landmark_visibility(px, apparent_px, depth_mm, seg, depth, mm_per_px: float) -> dict:
    """Visibility of the 28 landmarks of one image (rule in the module doc).

    Parameters
    ----------
    px : (28, 2)           straight projections (label ``landmarks.px``)
    apparent_px : list of 16 (2,) or None, or None   iris/pupil through the cornea
    depth_mm : (28,)       each landmark's depth, camera mm (``-z`` of ``landmarks.camera_mm``)
    seg : (H, W) uint8     class ids; depth : (H, W) float   camera mm (inf = nothing)
    mm_per_px : float

    Returns
    -------
    dict  ``visible`` (28 bools), ``occlusion`` (28 of None or a :data:`REASONS` word),
          ``at_px`` ((28, 2) list: the position the rule looked at)
    """
    seg = np.asarray(seg)
    depth = np.asarray(depth, float)
    H, W = seg.shape
    P = positions(px, apparent_px)
    dz = np.asarray(depth_mm, float)
    tol = depth_tolerance_mm(mm_per_px)
    visible, why = [], []
    for k, p in enumerate(P):
        if not (np.all(np.isfinite(p)) and 0 <= p[0] < W and 0 <= p[1] < H):
            visible.append(False)
            why.append("outside")
            continue
        rows, cols = neighbourhood(p, W, H)
        cls = seg[rows, cols]
        if k < 12:
            ok = np.isin(cls, list(_EYELID_OK)) & (depth[rows, cols] >= dz[k] - tol)
        else:
            ok = np.isin(cls, list(_IRIS_OK if k < 20 else _PUPIL_OK))
        if ok.any():
            visible.append(True)
            why.append(None)
            continue
        vals, counts = np.unique(cls[~ok], return_counts=True)
        visible.append(False)
        why.append(_REASON[int(vals[np.argmax(counts)])])
    return {"visible": visible, "occlusion": why, "at_px": P.tolist()}


def boundary_distance_px(p, mask) -> float:
    """Distance (px) from point ``p`` to the boundary of the pixel region ``mask`` (H, W) bool:
    the nearest of the unit pixel edges between a pixel in the region and one outside it
    (inf if the region has no boundary)."""
    m = np.asarray(mask, bool)
    u, v = float(p[0]), float(p[1])
    best = math.inf
    # vertical edges between (r, c) and (r, c + 1): x = c + 1, y in [r, r + 1]
    r, c = np.nonzero(m[:, 1:] != m[:, :-1])
    if r.size:
        dx = np.abs(u - (c + 1.0))
        dy = np.maximum(0.0, np.maximum(r - v, v - (r + 1.0)))
        best = min(best, float(np.min(np.hypot(dx, dy))))
    r, c = np.nonzero(m[1:, :] != m[:-1, :])
    if r.size:
        dy = np.abs(v - (r + 1.0))
        dx = np.maximum(0.0, np.maximum(c - u, u - (c + 1.0)))
        best = min(best, float(np.min(np.hypot(dx, dy))))
    return best
