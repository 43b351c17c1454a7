"""One eye as the lid rig sees it (:class:`EyeFrame`: fitted sphere or parametric surface, rest
forward direction, ordered eyelid-margin loop), read and validated from the snap stage's eyes.json
and mesh (:func:`eye_frames`), and rotations about its pitch axis (:func:`rotate_about_axis`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.geometry.frame import eye_basis
from pipeline.io.eyes_file import Eye, lateral_canthus_index


@dataclass
class EyeFrame:
    """One eye: its fitted sphere, rest forward direction and eyelid-margin loop.

    Attributes
    ----------
    side : str
        ``"left"`` (subject's left, +X) or ``"right"``.
    center : (3,) float64
        Eyeball sphere centre, mm, head frame.
    radius : float
        Eyeball sphere radius, mm.
    forward : (3,) float64
        Unit rest gaze direction.
    loop : (L,) int64
        Eyelid-margin vertex indices: medial canthus first, upper lid, lateral canthus, lower lid.
    lateral_index : int
        Position of the lateral canthus in ``loop``.
    on_eye : (L,) bool or None
        Loop vertices the snap put on the eyeball; the others are corners that stand off the
        globe (``loop_snap_<side>`` < 1, :mod:`pipeline.geometry.corners`). None = all.
    strip : (k, 2) int64 or None
        The corner strip closing the gap between those corners and the eye: its vertices (the
        inner edge inside the eyeball, the caruncle's mound rows between it and the loop) and
        the loop vertex each hangs from (``corner_strip_<side>``).
    """

    side: str
    center: np.ndarray
    radius: float
    forward: np.ndarray
    loop: np.ndarray
    lateral_index: int
    profile: object = None
    on_eye: np.ndarray | None = None
    strip: np.ndarray | None = None

    @property
    def margin(self) -> np.ndarray:
        """(k,) int64 loop vertices that rest on the eyeball (the whole loop without corners)."""
        return self.loop if self.on_eye is None else self.loop[self.on_eye]

    @property
    def strip_inner(self) -> np.ndarray:
        """(k,) int64 the corner strip's vertices, each hanging from a loop vertex (none
        without a strip): its inner edge inside the eye and the caruncle's mound rows."""
        return np.zeros(0, np.int64) if self.strip is None else self.strip[:, 0]

    def basis(self) -> np.ndarray:
        """(3, 3) rows ``e_x`` (horizontal, toward head +X), ``e_y`` (up), ``e_z`` (forward)."""
        return eye_basis(self.forward)

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit rotation axis: a positive angle about it pitches the eye up."""
        return -self.basis()[0]

    def gaze(self, pitch_deg: float) -> np.ndarray:
        """(3,) forward direction of the eye pitched by ``pitch_deg``."""
        f = np.asarray(self.forward, float)
        return rotate_about_axis(f[None], np.zeros(3), self.axis, math.radians(pitch_deg))[0]

    def surface_radius(self, P, pitch_deg: float = 0.0) -> np.ndarray:
        """(n,) distance from the centre to the eyeball's outer surface along each point's ray.

        ``profile`` None: the sphere (``radius``). Else an ``EyeballParams`` of the parametric
        eye (pipeline.eyeball.geometry), placed with its sphere of ``radius`` (the cornea keeps
        its size: ``placed_params``), looking along the pitched gaze: the sphere joined smoothly
        with the corneal bulge.
        """
        P = np.asarray(P, float)
        if self.profile is None:
            return np.full(len(P), float(self.radius))
        from pipeline.eyeball.geometry import outer_radial, placed_params

        w = P - self.center
        u = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
        alpha = np.arccos(np.clip(u @ self.gaze(pitch_deg), -1.0, 1.0))
        return outer_radial(alpha, placed_params(self.profile, self.radius))

    def surface_distance(self, P, pitch_deg: float = 0.0) -> np.ndarray:
        """(n,) radial distance of points outside (+) / inside (-) the pitched eyeball surface."""
        P = np.asarray(P, float)
        return np.linalg.norm(P - self.center, axis=1) - self.surface_radius(P, pitch_deg)


def find_lateral_canthus(points, center, forward, side: str) -> int:
    """Index of the lateral canthus in an eyelid loop (the most lateral point).

    Parameters
    ----------
    points : (L, 3) float64
        Loop points, medial canthus first.
    center, forward : (3,)
        Eyeball centre and rest forward direction.
    side : {"left", "right"}
        Lateral is head +X for the left eye, -X for the right eye.
    """
    return lateral_canthus_index(points, np.asarray(center, dtype=np.float64), forward, side)


def rotate_about_axis(P, center, axis, angles) -> np.ndarray:
    """Rotate points about the line through ``center`` along unit ``axis`` (Rodrigues).

    Parameters
    ----------
    P : (n, 3) float64
    center, axis : (3,) float64
    angles : (n,) float64 or float
        Radians, right-handed about ``axis``.

    Returns
    -------
    (n, 3) float64
    """
    P = np.asarray(P, dtype=np.float64)
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    w = P - np.asarray(center, dtype=np.float64)
    th = np.broadcast_to(np.asarray(angles, dtype=np.float64), (len(P),))[:, None]
    cos, sin = np.cos(th), np.sin(th)
    return (np.asarray(center) + w * cos + np.cross(a, w) * sin
            + a[None, :] * (w @ a)[:, None] * (1.0 - cos))


def _lateral_index_for_loop(e: Eye, mesh: dict, side: str, V, loop, c, f) -> int:
    """Position of the lateral canthus in this mesh's loop.

    In order of preference: a mesh array ``lateral_index_<side>``; the eyes.json
    lateral canthus *point* (``loop_points[lateral_canthus_index]`` of the dense
    remove_eyeballs loop, which has other indices) mapped to the nearest vertex of
    this loop; an eyes.json index when its ``loop_indices`` has this loop's length;
    else the most lateral loop vertex (:func:`find_lateral_canthus`).
    """
    key = f"lateral_index_{side}"
    if key in mesh:
        return int(np.asarray(mesh[key]).ravel()[0])
    li = e.lateral_canthus_index
    pts = e.loop_points
    if li is not None and pts is not None:
        try:
            pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
            p = pts[int(li)]
        except (TypeError, ValueError, IndexError):
            p = None
        if p is not None and np.isfinite(p).all():
            return int(np.argmin(np.linalg.norm(V[loop] - p, axis=1)))
    ids = e.loop_indices
    if li is not None and (ids is None or len(ids) == len(loop)):
        return int(li)
    return find_lateral_canthus(V[loop], c, f, side)


def _corner_arrays(mesh: dict, side: str, loop, n_vertices: int, mesh_source):
    """(on_eye (L,) bool or None, strip (k, 2) int64 or None) of one eye from the snap stage's
    ``loop_snap_<side>`` and ``corner_strip_<side>``, validated."""
    from pipeline.errors import ScanError

    on_eye = strip = None
    key = f"loop_snap_{side}"
    if key in mesh:
        w = np.asarray(mesh[key], dtype=np.float64).ravel()
        if len(w) != len(loop) or not np.isfinite(w).all():
            raise ScanError(mesh_source, f"{key} must hold one finite weight per loop vertex")
        on_eye = w >= 1.0
        if on_eye.sum() < len(loop) // 2:
            raise ScanError(mesh_source, f"{key}: fewer than half the {side} loop rests on the eye")
    key = f"corner_strip_{side}"
    if key in mesh and len(mesh[key]):
        strip = np.asarray(mesh[key])
        if strip.ndim != 2 or strip.shape[1] != 2 or strip.dtype.kind not in "iu" \
                or strip.min() < 0 or strip.max() >= n_vertices or not np.isin(strip[:, 1], loop).all():
            raise ScanError(mesh_source, f"{key} must be (k, 2) vertex pairs: an inner vertex and "
                                         f"a vertex of loop_{side}")
        strip = strip.astype(np.int64)
    return on_eye, strip


def eye_frames(eyes: dict, mesh: dict, *, eyes_source="eyes.json", mesh_source="mesh.npz",
               max_rest_gap_mm: float = 0.5, profile=None) -> list[EyeFrame]:
    """Validated :class:`EyeFrame` per eye from the snap stage's eyes.json and mesh arrays.

    Parameters
    ----------
    eyes : dict
        ``{"left": Eye, "right": Eye}`` (:class:`pipeline.io.eyes_file.Eye`, as the snap stage's
        eyes.json holds them); see :func:`_lateral_index_for_loop` for how the lateral canthus
        is found.
    mesh : dict
        Arrays ``V``, ``F``, ``loop_left``, ``loop_right`` (ordered margin vertex indices),
        optional ``lateral_index_left`` / ``lateral_index_right``.
    eyes_source, mesh_source : str
        Names used in error messages.
    max_rest_gap_mm : float
        Largest allowed distance of a margin vertex from its eyeball surface.
    profile : EyeballParams, optional
        Outer surface of the parametric eye the snap stage snapped to (sphere + cornea);
        None = the fitted sphere.

    Raises
    ------
    pipeline.errors.ScanError
        On missing, malformed or inconsistent input (one sentence naming the problem).
    """
    from pipeline.errors import ScanError

    for key in ("V", "F"):
        if key not in mesh:
            raise ScanError(mesh_source, f"missing array {key}")
    V = np.asarray(mesh["V"], dtype=np.float64)
    F = np.asarray(mesh["F"])
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise ScanError(mesh_source, f"V must be (n, 3), got {V.shape}")
    if not np.isfinite(V).all():
        raise ScanError(mesh_source, "V has non-finite coordinates")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise ScanError(mesh_source, f"F must be (m, 3), got {F.shape}")
    if F.min() < 0 or F.max() >= len(V):
        raise ScanError(mesh_source, "F indexes vertices out of range")
    out = []
    for side in ("left", "right"):
        e = eyes.get(side)
        if e is None:
            raise ScanError(eyes_source, f"no '{side}' eye")
        try:
            c = np.asarray(e.center, dtype=np.float64).reshape(3)
            f = np.asarray(e.forward, dtype=np.float64).reshape(3)
            r = float(e.radius)
        except (TypeError, ValueError):
            raise ScanError(eyes_source, f"{side} eye: center/forward must be 3 numbers, "
                                         f"radius a number") from None
        if not (np.isfinite(c).all() and np.isfinite(f).all() and math.isfinite(r)):
            raise ScanError(eyes_source, f"{side} eye has non-finite values")
        if not 3.0 <= r <= 40.0:
            raise ScanError(eyes_source, f"{side} eye radius {r:g} is not a plausible eyeball "
                                         f"radius in mm (3..40)")
        if np.linalg.norm(f) < 1e-9:
            raise ScanError(eyes_source, f"{side} eye forward is zero")
        f = f / np.linalg.norm(f)
        if abs(f[1]) > 0.95:
            raise ScanError(eyes_source, f"{side} eye forward {f.round(3).tolist()} is vertical")
        key = f"loop_{side}"
        if key not in mesh:
            raise ScanError(mesh_source, f"missing array {key} (eyelid margin loop)")
        loop = np.asarray(mesh[key]).ravel()
        if not np.issubdtype(loop.dtype, np.integer):
            raise ScanError(mesh_source, f"{key} must hold integer vertex indices")
        loop = loop.astype(np.int64)
        if len(loop) < 8:
            raise ScanError(mesh_source, f"{key} has {len(loop)} vertices; at least 8 needed")
        if loop.min() < 0 or loop.max() >= len(V):
            raise ScanError(mesh_source, f"{key} indexes vertices out of range")
        if len(np.unique(loop)) != len(loop):
            raise ScanError(mesh_source, f"{key} repeats vertices")
        # ordering contract: medial canthus first, then over the upper lid
        B = eye_basis(f)
        Q = (V[loop] - c) @ B[:2].T
        lat = Q[:, 0] * (1.0 if side == "left" else -1.0)
        if lat[0] - lat.min() > 0.25 * (lat.max() - lat.min()):
            raise ScanError(mesh_source, f"{key} does not start at the medial canthus (its first "
                                         f"vertex is not at the nose side of the loop)")
        li = _lateral_index_for_loop(e, mesh, side, V, loop, c, f)
        if not 2 <= li <= len(loop) - 2:
            raise ScanError(eyes_source, f"{side} lateral canthus index {li} must leave at least one "
                                         f"vertex on each lid of the {len(loop)}-vertex loop")
        if Q[1:li, 1].mean() <= Q[li + 1:, 1].mean():
            raise ScanError(mesh_source, f"{key} runs over the lower lid first; the upper lid "
                                         f"must come first")
        on_eye, strip = _corner_arrays(mesh, side, loop, len(V), mesh_source)
        frame = EyeFrame(side=side, center=c, radius=r, forward=f, loop=loop, lateral_index=li,
                         profile=profile, on_eye=on_eye, strip=strip)
        d = frame.surface_distance(V[frame.margin], 0.0)
        if np.max(np.abs(d)) > max_rest_gap_mm:
            what = "sphere" if profile is None else "surface"
            raise ScanError(mesh_source, f"{side} eyelid margin is up to {np.max(np.abs(d)):.3g} mm "
                                         f"off the eyeball {what} (limit {max_rest_gap_mm:g} mm); "
                                         f"the snap stage must put it on the eyeball")
        if np.min(frame.surface_distance(V[loop], 0.0)) < -max_rest_gap_mm:
            raise ScanError(mesh_source, f"{side} eyelid corner lies inside the eyeball")
        out.append(frame)
    return out
