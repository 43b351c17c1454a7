"""An eye opening a scanner filled flat: found, and the eye placed behind the fill's boundary.

Some scanners close what they could not measure (the wet, dark, moving eye) with a few large
flat triangles spanned across the opening: a triangulated polygon whose corners are the last
skin vertices the scanner kept. Such a fill says nothing about the eyeball, but its boundary is
where the dense skin begins, the lid margin: "an opening filled flat has the fill's boundary as
its fissure" (issue 30). :func:`find_flat_fill` finds it near a hint (faces far longer than the
scan's own edges and the ears hanging off their long edges, one simple loop around them, wide as
an eye opening, spanning its boundary with no vertices of its own); :func:`fit_from_fill`
places the eye behind its boundary by the same anatomy of the corners and the lid margin that
places an eye behind a photographed fissure
(:func:`pipeline.placement.texture.place_from_fissure`), with the gaze held near the head's
forward axis. The stage cuts the fill away and keeps its boundary as the opening loop.

A blink (skin across the opening, as dense as the rest) and an open eye (a dense eyeball
surface) have no such faces; holes the stage itself closed for the fit are left out
(``exclude``), so a scanner's lost pupil is not taken for a fill.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.placement.eye_fit import EyeFit, EyeMesh, lid_crease_deg, unit_vector
from pipeline.placement.human_eye import OPENING_AXIS_SIGMA_DEG, OPENING_SIGMA_MM

#: A face whose longest edge is this many times the scan's median edge seeds a fill.
SEED_EDGE_RATIO = 3.0
#: A face joins a fill across its own longest edge when that is this many times the median edge
#: (the ears of a triangulated polygon hang off its long diagonals; the skin meets it at short
#: edges).
JOIN_EDGE_RATIO = 1.5
#: The fill must span this much of an eye opening seen along the head's forward axis (mm): a
#: scanner's fill over a lost pupil or iris (4-12 mm) leaves the sclera to the geometry.
MIN_FILL_WIDTH_MM = 14.0
#: A fill spans its boundary: at most this share of its vertices lie inside it (an ear-clipped
#: polygon has none, a fan one); a scanned eye, however coarse, is a surface with its own
#: vertices, bulging over the loop.
MAX_INTERIOR_SHARE = 0.2
#: An eye placed behind a fill states this 1-sigma (limbus mm, axis deg): the eye placed from
#: its opening alone (:mod:`pipeline.placement.human_eye`), since a fill shows the opening and
#: nothing of the gaze. On six filled ICT-FaceKit dev heads the limbus lay 0.6-1.5 mm and 2-6 deg
#: off on heads looking ahead, 2-7.5 mm and 20-36 deg on heads looking up, down, in or out (the
#: anatomy holds the gaze near the head's forward axis): every eye within 2 sigma.
FILL_SIGMA = (OPENING_SIGMA_MM, OPENING_AXIS_SIGMA_DEG)


@dataclass
class FlatFill:
    """A flat fill across an eye opening: ``faces`` (m,) bool on the mesh (with the holes the
    stage closed that touch it), ``loop`` (L,) the fill's boundary's vertex ids in order,
    ``normal`` (3,) its mean plane's normal (out of the face), ``width_mm`` across the opening
    seen along the head's forward axis, ``tilt_deg`` the
    area-weighted mean angle of its faces to that plane (a fill over a loop that follows the
    lids is flat per face, not as a whole: 40-50 deg on scanify's ear-clipped fills)."""

    faces: np.ndarray
    loop: np.ndarray
    normal: np.ndarray
    width_mm: float
    tilt_deg: float


@dataclass
class FillEyeFit(EyeFit):
    """An eye placed behind a scanner's flat fill: ``fill`` the :class:`FlatFill` it was placed
    from (the stage cuts ``region``, the fill's faces, and keeps its boundary)."""

    fill: FlatFill | None = field(default=None, repr=False)


def _edge_lengths(V, F):
    return np.stack([np.linalg.norm(V[F[:, (k + 1) % 3]] - V[F[:, k]], axis=1) for k in range(3)], 1)


def find_flat_fill(V, F, hint, median_edge: float, *, exclude=None, radius_mm: float = 20.0,
                   min_width_mm: float = MIN_FILL_WIDTH_MM,
                   max_interior_share: float = MAX_INTERIOR_SHARE):
    """The flat fill across the eye opening at ``hint``, or None.

    Faces within ``radius_mm`` of the hint whose longest edge exceeds ``SEED_EDGE_RATIO`` x
    ``median_edge`` seed it (the part of them nearest the hint); a face joins it across its own
    longest edge when that is longer than ``JOIN_EDGE_RATIO`` x the median edge (the ears of the
    triangulated polygon hang off its long diagonals; the dense skin meets it at short edges).
    It is a fill when its boundary is one simple loop, it spans
    ``min_width_mm`` seen along the head's forward axis (+Z), the hint lies within it (or
    within 5 mm of it) seen that way, and it spans its boundary with (almost) no vertices of its
    own: at most ``max_interior_share`` of its vertices lie off the loop (the flat fill of a
    polygon; a scanned eye surface, however coarse, has vertices inside its border).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    hint : (3,) float64
    median_edge : float
        The scan's median edge length (mm).
    exclude : (m,) bool, optional
        Faces that are no scanner's fill (holes the stage closed itself).

    Returns
    -------
    FlatFill or None
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    hint = np.asarray(hint, np.float64)
    cen = V[F].mean(axis=1)
    near = np.linalg.norm(cen - hint, axis=1) < radius_mm
    if exclude is not None:
        near &= ~np.asarray(exclude, bool)
    E = _edge_lengths(V, F)
    seed = near & (E.max(axis=1) > SEED_EDGE_RATIO * median_edge)
    if not seed.any():
        return None
    # the seeds joined across any shared edge; the part nearest the hint
    idx = np.flatnonzero(seed)
    pairs, _ = meshtopo.face_adjacency(F[idx], len(V))
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(idx), len(idx)))
    _, comp = connected_components(g, directed=False)
    d = np.linalg.norm(cen[idx] - hint, axis=1)
    faces = np.zeros(len(F), bool)
    faces[idx[comp == comp[np.argmin(d)]]] = True
    # the ears of the triangulated polygon: faces hanging off it by their longest edge, a long one
    cand = np.flatnonzero(near)
    pairs, ev = meshtopo.face_adjacency(F[cand], len(V))
    elen = np.linalg.norm(V[ev[:, 0]] - V[ev[:, 1]], axis=1)
    pairs = cand[pairs]
    for _ in range(3):
        grew = False
        for a_, b_ in ((0, 1), (1, 0)):
            new = (faces[pairs[:, a_]] & ~faces[pairs[:, b_]] & (elen > JOIN_EDGE_RATIO * median_edge)
                   & (elen >= E[pairs[:, b_]].max(axis=1) - 1e-9))
            if new.any():
                faces[pairs[new, b_]] = True
                grew = True
        if not grew:
            break
    Ff = F[faces]
    try:
        loops = meshtopo.boundary_loops(Ff)
    except ValueError:
        return None
    if len(loops) != 1 or len(loops[0]) < 4:
        return None
    loop = np.asarray(loops[0], np.int64)
    A = 0.5 * np.linalg.norm(np.cross(V[Ff[:, 1]] - V[Ff[:, 0]], V[Ff[:, 2]] - V[Ff[:, 0]]), axis=1)
    N = meshtopo.face_normals(V, Ff)
    n = unit_vector((N * A[:, None]).sum(axis=0))
    if not np.all(np.isfinite(n)):
        return None
    if n[2] < 0:        # out of the face
        n = -n
    tilt = float(np.degrees(np.sum(A * np.arccos(np.clip(np.abs(N @ n), -1.0, 1.0))) / max(A.sum(), 1e-12)))
    q = V[loop][:, :2]
    width = float(np.ptp(q[:, 0]))
    interior = 1.0 - len(loop) / len(np.unique(Ff))
    if width < min_width_mm or interior > max_interior_share:
        return None
    # matplotlib only for a fill's last test: a dense scan's stretched faces reach the tests
    # above, and importing it cost 0.1 s of every run
    from matplotlib.path import Path as PolyPath

    inside = PolyPath(q).contains_point(hint[:2])
    gap = 0.0 if inside else float(np.min(np.linalg.norm(q - hint[:2], axis=1)))
    if gap > 5.0:
        return None
    if exclude is not None:     # a hole the stage closed that touches the fill goes with it
        faces |= _touching(F, faces, np.asarray(exclude, bool))
    return FlatFill(faces=faces, loop=loop, normal=n, width_mm=width, tilt_deg=tilt)


def _touching(F, faces, other):
    """(m,) bool: the faces of ``other`` edge-connected (within ``other``) to one that shares a
    vertex with ``faces``: whole closed holes that touch the fill, even at one vertex (left out,
    their rim would pinch the opening's loop into a bow-tie)."""
    idx = np.flatnonzero(other)
    if len(idx) == 0:
        return np.zeros(len(F), bool)
    on = np.zeros(int(F.max()) + 1, bool)
    on[F[faces].ravel()] = True
    comp = meshtopo.face_components(len(idx), meshtopo.face_adjacency(F[idx], len(on))[0])
    hit = np.unique(comp[on[F[idx]].any(axis=1)])
    out = np.zeros(len(F), bool)
    out[idx[np.isin(comp, hit)]] = True
    return out


def fit_from_fill(mesh: EyeMesh, fill: FlatFill, side: str, radius: float, forward=None) -> FillEyeFit:
    """The eye behind a flat fill: its boundary taken as the fissure, medial corner first and
    upper lid first (ordered in the head's forward view), the eye placed by
    :func:`pipeline.placement.texture.place_from_fissure` at ``radius`` (held), its gaze near
    ``forward`` (the eye-region prior's axis; default the head's forward axis)."""
    fit = fit_behind_loop(mesh, fill.loop, fill.faces.copy(), side, radius, forward, "fill")
    return FillEyeFit(**{k: getattr(fit, k) for k in fit.__dataclass_fields__}, fill=fill)


def fit_behind_loop(mesh: EyeMesh, loop, region, side: str, radius: float, forward=None,
                    method: str = "fill") -> EyeFit:
    """The anatomical eye behind an opening the scan shows only as its border ``loop`` (vertex
    ids of ``mesh``, either direction) round the faces ``region`` (m,) bool that the stage cuts:
    the loop as the fissure (see :func:`fit_from_fill`), the fit's ``method`` saying what the
    opening was (``fill``: a scanner's flat fill; ``coarse``: a scanned eye too coarse to place
    from its shape)."""
    from pipeline.placement.texture import place_from_fissure

    V, F = mesh.V, mesh.F
    view = unit_vector(np.array([0.0, 0.0, 1.0]) if forward is None else np.asarray(forward, float))
    loop = np.asarray(loop, np.int64)
    P = V[loop]
    B = eye_basis(view)
    Q = (P - P.mean(axis=0)) @ B[:2].T
    x = Q[:, 0] if side == "left" else -Q[:, 0]        # positive = lateral
    m = int(np.argmin(x))
    loop, Q, x = np.roll(loop, -m), np.roll(Q, -m, axis=0), np.roll(x, -m)
    lat = int(np.argmax(x))
    if Q[1:lat, 1].mean() < Q[lat + 1:, 1].mean():        # upper lid first
        loop, Q = np.concatenate([loop[:1], loop[1:][::-1]]), np.concatenate([Q[:1], Q[1:][::-1]])
        lat = len(loop) - lat
    c, fwd, r, rms = place_from_fissure(V[loop], lat, radius, view, fixed_radius=True)
    return EyeFit(side=side, center=c, radius=float(r), forward=fwd, residual_rms_mm=rms,
                  n_inliers=int(len(loop)), method=method, region=region,
                  crease_deg=lid_crease_deg(mesh, region), inliers=np.unique(F[region]))
