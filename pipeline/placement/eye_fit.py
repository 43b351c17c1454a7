"""What an eye fit is and the mesh helpers around it: :class:`EyeFit` (sphere, gaze, removal
region), :class:`EyeMesh`, the local sub-mesh around the hints, the region cleaning that
leaves one simple loop, and the lid-fold measure. The placement itself is
``pipeline.placement.fit`` (geometry) and ``pipeline.placement.texture`` (colour, coarse scans).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.geometry.spherefit import signed_distance


@dataclass
class EyeFit:
    """One fitted eye and its removal region.

    Attributes
    ----------
    side : str
    center : (3,) float64
    radius : float
    forward : (3,) float64 unit
    residual_rms_mm : float
        RMS distance of the sclera inliers to the sphere.
    n_inliers : int
    method : str
        ``"geometry"``, ``"texture"``, ``"fill"`` (behind a scanner's flat fill) or ``"coarse"``
        (behind the opening of a scanned eye too coarse to place from its shape).
    region : (m,) bool
        Faces to remove.
    cornea : dict or None
        ``{"center": (3,), "radius": r, "n_inliers": k}`` when a corneal bulge was fitted.
    crease_deg : float
        Median rise of the skin just outside the removal region (open-eye evidence).
    """

    side: str
    center: np.ndarray
    radius: float
    forward: np.ndarray
    residual_rms_mm: float
    n_inliers: int
    method: str
    region: np.ndarray
    cornea: dict | None = None
    crease_deg: float = 0.0
    capped: bool = False
    inliers: np.ndarray = field(default=None, repr=False)
    radius_sigma: float = float("inf")
    prior_axis: np.ndarray | None = field(default=None, repr=False)   # the eye region's forward
    why: str | None = None      # why the eye was placed as it was, when that is a doubt
    # why the surface the search found was judged no eye's, as a closed lid's (place.NO_EYE)
    no_eye: str | None = None


def unit_vector(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


class EyeMesh:
    """Adjacency cached once per mesh."""

    def __init__(self, V, F, median_edge=None):
        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        self.pairs, self.pair_edges = meshtopo.face_adjacency(self.F, len(self.V))
        self.centroids = self.V[self.F].mean(axis=1)
        if median_edge is None:
            median_edge = median_edge_length(self.V, self.F)
        self.median_edge = float(median_edge)

    def face_normals(self):
        """(m, 3) unit face normals (computed once)."""
        if getattr(self, "_fn", None) is None:
            self._fn = meshtopo.face_normals(self.V, self.F)
        return self._fn

    def neighbour_count(self, mask):
        """Per face: number of edge-neighbours inside ``mask``."""
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        n = len(self.F)
        return (np.bincount(a, weights=mask[b], minlength=n)
                + np.bincount(b, weights=mask[a], minlength=n)).astype(np.int64)


def median_edge_length(V, F, with_max: bool = False):
    """The median edge length of the faces ``F`` (each edge counted once per face); with
    ``with_max`` also the longest, ``(median, max)`` (what :func:`local_mesh` needs to look only
    near its hints)."""
    # one edge of every face at a time, its squares summed in norm's order (the same value), in
    # blocks of faces: over the whole scan at once the gathers' fresh memory (about 200 MB at
    # 1.4M faces, first touched page by page) cost more than the arithmetic, 0.5 s against 0.2
    V = np.asarray(V)
    F = np.asarray(F)
    L = np.empty((3, len(F)), dtype=np.result_type(V.dtype, np.float16))
    for s in range(0, len(F), _EDGE_BLOCK):
        Fb = F[s:s + _EDGE_BLOCK]
        C = [V[Fb[:, k]] for k in range(3)]
        for k in range(3):
            e = C[(k + 1) % 3] - C[k]
            L[k, s:s + len(Fb)] = np.sqrt(e[:, 0] * e[:, 0] + e[:, 1] * e[:, 1] + e[:, 2] * e[:, 2])
    longest = float(L.max(initial=0.0))
    med = float(np.median(L, overwrite_input=True))     # L is ours: no copy to partition
    return (med, longest) if with_max else med


# faces per block of :func:`median_edge_length`: its temporaries (about 10 arrays of a block's
# rows) stay in the cache and are reused from one block to the next
_EDGE_BLOCK = 1 << 15


def local_mesh(V, F, hints, radius, max_edge=None):
    """The faces with centroid within ``radius`` of any hint, as a sub-mesh.

    ``max_edge``: the mesh's longest edge, when known: a face whose centroid lies within
    ``radius`` has a vertex within ``radius + max_edge`` (a corner lies at most 2/3 of its
    longest edge from the centroid), so only faces with such a vertex are measured (the
    centroids of a 1.4M-face scan took a third of a second); the same faces either way.

    Returns ``(V_sub, F_sub, faces, verts)``: ``faces``/``verts`` (sorted) map sub-mesh face and
    vertex ids back to the full mesh, so the sub-mesh keeps the full mesh's face and vertex order.
    """
    cand = None
    if max_edge is not None:
        reach = radius + max_edge
        near = np.zeros(len(V), bool)
        for h in hints:
            near |= ((V - h) ** 2).sum(axis=1) < reach * reach
        cand = np.flatnonzero(meshtopo.faces_touching(F, near))
    Fc = F if cand is None else F[cand]
    c = V[Fc].mean(axis=1)
    sel = np.zeros(len(Fc), bool)
    for h in hints:
        sel |= np.linalg.norm(c - h, axis=1) < radius
    faces = np.flatnonzero(sel) if cand is None else cand[sel]
    verts, Fs = np.unique(F[faces], return_inverse=True)
    return V[verts], Fs.reshape(-1, 3).astype(np.int64), faces, verts


def patch_faces(mesh: EyeMesh, hint, radius):
    """Faces within ``radius`` of the hint, connected to the face nearest it: (m,) bool."""
    d = np.linalg.norm(mesh.centroids - hint, axis=1)
    near = d < radius
    if not near.any():
        return near
    labels = meshtopo.face_components(len(mesh.F), mesh.pairs, near)
    f0 = int(np.argmin(d))
    return near & (labels == labels[f0])


def lid_crease_deg(mesh: EyeMesh, region, dist=None, radius_mm=2.0):
    """How sharply the surface folds at the border of ``region``, degrees.

    Median over border vertices of the angle between the mean normal of region faces and
    the mean normal of non-region faces within ``radius_mm``: an open eye has a concave fold
    there (the lids rise off the eyeball), a closed lid continues smoothly.
    """
    from scipy.spatial import cKDTree

    Vin = np.zeros(len(mesh.V), bool)
    Vin[mesh.F[region].ravel()] = True
    Vout = np.zeros(len(mesh.V), bool)
    Vout[mesh.F[~region].ravel()] = True
    border = np.where(Vin & Vout)[0]
    if len(border) == 0:
        return 0.0
    N = meshtopo.face_normals(mesh.V, mesh.F)
    near = np.linalg.norm(mesh.centroids - mesh.V[border].mean(axis=0), axis=1) < 40.0
    fin, fout = np.where(region & near)[0], np.where(~region & near)[0]
    if len(fin) == 0 or len(fout) == 0:
        return 0.0
    tin, tout = cKDTree(mesh.centroids[fin]), cKDTree(mesh.centroids[fout])
    r = max(radius_mm, 1.5 * mesh.median_edge)
    P = mesh.V[border]
    angles = normal_fold_deg(N[fin], tin.query_ball_point(P, r), N[fout], tout.query_ball_point(P, r))
    return float(np.median(angles)) if len(angles) else 0.0


def normal_fold_deg(Na, near_a, Nb, near_b):
    """The angle (degrees) between the sum of the normals ``Na[near_a[j]]`` and that of
    ``Nb[near_b[j]]``, for every ``j`` with both lists non-empty (``query_ball_point``'s lists),
    (k,). Each sum is numpy's over its own (k, 3) block (numpy adds along it pairwise: a
    segmented sum adds in another order, in other last bits); the products and norms are
    made for all at once as ``np.dot`` and ``np.linalg.norm`` make them one by one (a stack of
    1x3 by 3x1 products calls the same dot): a loop of them over the border was most of the
    fold measure's time."""
    both = [j for j, (a, b) in enumerate(zip(near_a, near_b)) if a and b]
    if not both:
        return np.zeros(0)
    # each sum in a row of 4: every row then starts 16-byte aligned like a fresh (3,) array (at a
    # 24-byte stride every other one did not, and OpenBLAS's dot rounded those differently)
    SA, SB = np.zeros((len(both), 4)), np.zeros((len(both), 4))
    for i, j in enumerate(both):
        SA[i, :3] = Na[near_a[j]].sum(axis=0)
        SB[i, :3] = Nb[near_b[j]].sum(axis=0)
    SA, SB = SA[:, :3], SB[:, :3]

    def dot(X, Y):
        return np.matmul(X[:, None, :], Y[:, :, None])[:, 0, 0]
    c = dot(SA, SB) / np.maximum(np.sqrt(dot(SA, SA)) * np.sqrt(dot(SB, SB)), 1e-12)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def clean_region(mesh: EyeMesh, region, keep_seed, local=None, max_iter=30):
    """Make ``region``'s border one simple loop: keep the seeded component, fill islands,
    close notches, remove spikes, dissolve bow-tie vertices."""
    F = mesh.F
    nF = len(F)
    region = region.copy()
    for _ in range(max_iter):
        changed = False
        # component containing the seed
        lab = meshtopo.face_components(nF, mesh.pairs, region)
        seeds = np.where(region & keep_seed)[0]
        if len(seeds) == 0:
            return region & False
        best = np.bincount(lab[seeds]).argmax()
        new = region & (lab == best)
        # fill islands: components of the complement lying wholly inside the local patch
        lab_c = meshtopo.face_components(nF, mesh.pairs, ~new)
        outside = np.unique(lab_c[~new & ~local]) if local is not None else \
            np.array([np.bincount(lab_c[~new]).argmax()])
        new |= (~new) & ~np.isin(lab_c, outside)
        # close notches (outside faces with >= 2 region neighbours), remove spikes
        nc = mesh.neighbour_count(new)
        new |= (~new) & (nc >= 2)
        nc = mesh.neighbour_count(new)
        new &= ~(nc <= 1)
        # bow-ties: vertices with more than two region/non-region transitions
        sep = new[mesh.pairs[:, 0]] != new[mesh.pairs[:, 1]]
        trans = (np.bincount(mesh.pair_edges[sep, 0], minlength=len(mesh.V))
                 + np.bincount(mesh.pair_edges[sep, 1], minlength=len(mesh.V)))
        bad = np.where(trans > 2)[0]
        if len(bad):
            badv = np.zeros(len(mesh.V), bool)
            badv[bad] = True
            new |= badv[F].any(axis=1)
        changed = not np.array_equal(new, region)
        region = new
        if not changed:
            break
    return region


def eye_surface_distance(P, center, radius, cornea=None):
    """Signed distance to the union of the sclera sphere and (optional) corneal sphere, (n,)."""
    d = signed_distance(P, center, radius)
    if cornea is not None:
        d = np.minimum(d, signed_distance(P, cornea["center"], cornea["radius"]))
    return d
