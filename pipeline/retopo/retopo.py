"""Eye-region retopology: crop the dense head to the eye region and remesh it low-poly.

SynthesEyes (paper 3.3) retopologised the scan by hand-guided ZRemesher into an
animatable low-poly eye region (9,005 polygons) whose edge loops follow the
eyelids. Here two automatic routes are offered (``RetopoSettings.method``):

``quadric``
    Garland-Heckbert quadric edge collapse (``fast_simplification``) with the
    borders locked, then cleaned (duplicate / degenerate faces, non-manifold
    edges, stray components): a triangle mesh. Fast (~1-2 s on 300k faces).
``isotropic``
    Pre-decimation (``fast_simplification``) followed by isotropic explicit
    remeshing (``pymeshlab``, reprojected onto the pre-decimated surface) and a
    greedy pairing of triangles into quads: a quad-dominant mesh
    (``poly_counts``/``poly_indices``) with near-equilateral elements.

Both then share the eyelid-loop treatment: each eye's opening stays a boundary
loop of the output, resampled to exactly ``loop_points`` vertices by boundary
edge collapses/splits, its vertices placed at even arc-length steps on the
dense scan's eyelid loop (vertex 0 at the medial canthus, upper lid first, as
the input contract orders them), and the interior relaxed (tangential
Laplacian, reprojected onto the dense surface) so the triangles next to the
loop stay well shaped. The loops' vertex indices are returned as
``loop_left``/``loop_right``. A coarse scan whose eye openings have under a quarter of
``loop_points`` vertices (``james``: 11) is midpoint-subdivided first (surface unchanged), so
the loop is not reached by splitting each opening edge into a fan of slivers; edge flips never
leave a loop vertex with a single triangle (an "ear" with three loop corners, inverted on the
convex opening).

With ``band: grid`` (the default) the faces round each loop are then cut away and replaced by a
built band of quads, ``band_rings`` rings of ``loop_points`` vertices with fixed ids
(:func:`pipeline.retopo.eye_band.add_eye_bands`; docs/retopo.md); a handle of the crop within
``band_param_mm`` of an opening, which leaves that band no annulus, is cut out of the crop first
(:func:`pipeline.retopo.handles.cut_handles`, ``metrics["handles_cut"]``). With ``band: march`` and
``eye_rings`` > 0 (off by default), :func:`add_eye_rings` instead gives each loop concentric
edge flow: the faces within about ``(eye_rings + 1)`` ring spacings of the loop are replaced by
``eye_rings`` rings of ``loop_points`` vertices marched out over the dense surface, joined by
quads (``poly_counts``/``poly_indices`` gain them on both routes), and a greedy loft of
triangles out to the cut's border. An eye whose rings come out folded, flipped or with an
obtuse loft sliver (> 160 deg) gets fewer rings, down to none; ``metrics["eye_rings"]`` says
how many each eye got. On the real scans the loft next to a creased upper lid is where this
fails (ict_neutral's left eye), so it stays off by default.
"""

from __future__ import annotations

import gc
import time
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from typing import ClassVar, Literal

import numpy as np

from pipeline.geometry import mesh_checks as mc
from pipeline.geometry import meshtopo
from pipeline.retopo.eye_band import add_eye_bands
from pipeline.retopo.handles import cut_handles
from pipeline.retopo.eye_rings import add_eye_rings, edge_graph
from pipeline.retopo.eyelid_loop import (canthus_apex, orient_and_place, polyline_arclength,
                                          project_to_polyline, resample_loop, smooth_lids)
from pipeline.geometry.flips import (collapse_flipped, collapse_short_edges, count_flipped, delaunay_flips, flip_slivers, mirror_flipped,
                                     reference_face_normals, relax, repair_flips, untangle)
from pipeline.geometry.mesh_edit import TriMesh, fill_holes_smooth, loop_perimeter
from pipeline.geometry.spherefit import signed_distance as sphere_signed_distance
from pipeline.retopo.mesh_clean import clean_mesh
from pipeline.results import StageResult
from pipeline.settings import Settings, setting

METHODS = ("quadric", "isotropic")


@dataclass
class RetopoSettings(Settings):
    """Retopology knobs (the ``retopo:`` block of params.yaml); defaults here, checked by pipeline.settings."""

    block: ClassVar[str] = "retopo"

    method: Literal["quadric", "isotropic"] = "quadric"
    target_polygons: int = setting(9000, ge=100, le=2_000_000)
    margin_lateral_mm: float = setting(36.0, gt=0, le=200)   # beyond each eye centre, away from the nose (x)
    margin_above_mm: float = setting(32.0, gt=0, le=200)     # above the eye centres (brow)
    margin_below_mm: float = setting(30.0, gt=0, le=200)     # below the eye centres (upper cheek)
    margin_back_mm: float = setting(12.0, gt=0, le=200)      # behind the eye centres (z); keeps the front surface only
    loop_points: int = setting(64, ge=8, le=4096)            # vertices per eyelid loop in the output
    predecimate_faces: int = setting(120000, ge=1000, le=20_000_000)  # isotropic route: pre-decimate the crop to this many faces
    isotropic_iterations: int = setting(6, ge=0, le=100)
    quad_max_angle_dev_deg: float = setting(50.0, ge=0, le=90)
    relax_iterations: int = setting(4, ge=0, le=1000)
    min_edge_fraction: float = setting(0.2, ge=0, le=0.9)    # after the repairs, collapse edges shorter than this x the median (0 = off)
    band: Literal["grid", "march"] = "grid"                  # grid: eye_band.add_eye_bands; march: the repairs + eye_rings
    band_rings: int = setting(6, ge=1, le=50)                # grid band: rings outside the loop (the same in every asset)
    band_width_mm: float = setting(8.0, gt=0, le=50)         # grid band: loop to outer ring along each spoke
    band_param_mm: float = setting(20.0, gt=0, le=100)       # grid band: dense surface parametrised round the opening
    eye_rings: int = setting(0, ge=0, le=20)                 # band: march only: rings of quads around each eyelid loop (0 = off)
    ring_spacing_mm: float = setting(0.0, ge=0, le=20)       # between rings; 0: the loop's mean edge length
    metric_samples: int = setting(50000, ge=100, le=10_000_000)
    canthus_apex: bool = True                                # loop corners where the lid lines meet (eyelid_loop.canthus_apex)
    canthus_window_mm: tuple[float, float] = setting((1.0, 6.0), ge=0, le=50, ordered=True)  # lid arc fitted by each line
    canthus_max_reach_mm: float = setting(3.0, ge=0, le=20)  # an apex farther beyond the scan's corner is not trusted
    margin_smooth_mm: float = setting(3.0, ge=0, le=20)      # eyelid_loop.smooth_margin bandwidth (0 = off)
    margin_smooth_max_move_mm: float = setting(2.0, gt=0, le=20)  # no margin point moves farther
    margin_smooth_mid_mm: float = setting(7.0, ge=0, le=20)  # ... widened to this mid-lid where a notch stays (0 = never)
    margin_notch_mm: float = setting(1.0, gt=0, le=20)       # a smoothed margin notched deeper than this, seen from the front, is smoothed again
    margin_notch_keep: float = setting(0.7, gt=0, le=1)      # ... and that kept where it leaves at most this share of the notch
    margin_notch_max_move_mm: float = setting(3.0, gt=0, le=20)  # ... no point of it moving farther
    fill_holes_mm: float = setting(150.0, ge=0, le=1000)     # scanner holes in the crop up to this perimeter are filled (0 = off)


@dataclass
class RetopoResult:
    V: np.ndarray            # (n, 3) float64
    F: np.ndarray            # (m, 3) int64 triangles (fan triangulation of the polygons)
    loops: dict              # side -> (loop_points,) int64 ordered loop vertex indices
    lateral: dict            # side -> position of the lateral canthus in its loop (None: not known)
    poly_counts: np.ndarray | None
    poly_indices: np.ndarray | None
    crop_V: np.ndarray       # the cropped dense surface the result approximates
    crop_F: np.ndarray
    result: StageResult      # the stage's metrics, and the step times apart
    band: dict | None = None  # side -> (band_rings + 1, loop_points) vertex ids (band: grid), ring 0 = loop

    @property
    def metrics(self) -> dict:
        return self.result.metrics


# ----------------------------------------------------------------------------- crop

def crop_eye_region(V, F, eyes: dict, s: RetopoSettings):
    """Crop the dense mesh to a box around both eyes.

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        Dense head with eye openings.
    eyes : dict of str -> pipeline.io.eyes_file.Eye
        Both eyes, each with its ``loop_indices``.

    Returns
    -------
    Vc (p, 3), Fc (q, 3), vmap (p,) int64 original index of each kept vertex.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    C = np.array([e.center for e in eyes.values()], dtype=np.float64)
    lo = np.array([C[:, 0].min() - s.margin_lateral_mm, C[:, 1].min() - s.margin_below_mm,
                   C[:, 2].min() - s.margin_back_mm])
    hi = np.array([C[:, 0].max() + s.margin_lateral_mm, C[:, 1].max() + s.margin_above_mm, np.inf])
    inside = np.all((V >= lo) & (V <= hi), axis=1)
    keep = inside[F].all(axis=1)
    Fk = F[keep]
    loop_vs = np.concatenate([np.asarray(e.loop_indices, dtype=np.int64) for e in eyes.values()])
    if not inside[loop_vs].all():
        raise ValueError("an eyelid loop reaches outside the crop box; increase the retopo margins")
    # keep the connected component(s) that contain the eyelid loops
    n = len(V)
    e = mc.edges_of(Fk)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, lab = connected_components(A, directed=False)
    want = np.unique(lab[loop_vs])
    Fk = Fk[np.isin(lab[Fk[:, 0]], want)]
    used = np.zeros(n, dtype=bool)
    used[Fk.ravel()] = True
    vmap = np.flatnonzero(used)         # np.unique(Fk) without sorting its 0.5M corners
    remap = -np.ones(n, dtype=np.int64)
    remap[vmap] = np.arange(len(vmap))
    Vc, Fc = V[vmap], remap[Fk]
    # weld coincident vertices (zero-area faces then have a repeated index and are dropped),
    # so decimation sees one closed surface instead of pinholes. Each goes to the lowest id of
    # its coordinates (np.unique(Vc, axis=0)'s first index, without its sort of rows as records):
    # a stable sort by x, y, z puts equal rows together in id order
    order = np.lexsort(Vc.T[::-1])
    Vs = Vc[order]
    start = np.r_[True, (Vs[1:] != Vs[:-1]).any(axis=1)]
    if not start.all():
        rep = np.empty(len(Vc), dtype=np.int64)
        rep[order] = order[start][np.cumsum(start) - 1]
        Fc = rep[Fc]
        Fc = Fc[(Fc[:, 0] != Fc[:, 1]) & (Fc[:, 1] != Fc[:, 2]) & (Fc[:, 0] != Fc[:, 2])]
    # bow-ties: a vertex whose faces form two fans touching only there, where two boundary loops
    # meet (the box cut through a scan's thin tongue of faces: id308_halfblink's crop has 4 on its
    # lower edge; a scan may bring its own). Every step after this walks boundary loops, so each
    # fan gets its own copy of the vertex (same position: the surface is unchanged), and a piece
    # that only hung on by such a vertex is dropped with the other components away from the eyes
    Fc, parent = meshtopo.split_fans(Fc, len(Vc))
    if len(parent) > len(Vc):
        Vc, vmap = Vc[parent], vmap[parent]
        _, lab = connected_components(meshtopo.vertex_adjacency(Fc, len(Vc)), directed=False)
        want = np.unique(lab[np.isin(vmap, loop_vs)])
        Fc = Fc[np.isin(lab[Fc[:, 0]], want)]
        used = np.unique(Fc)
        remap = -np.ones(len(Vc), dtype=np.int64)
        remap[used] = np.arange(len(used))
        Vc, Fc, vmap = Vc[used], remap[Fc], vmap[used]
    return Vc, Fc, vmap


def scan_holes(Vc, Fc, vmap, F, eye_vertices, max_perimeter_mm: float, loops=None) -> list:
    """The crop's boundary loops that are holes of the scan itself: neither an eye opening (a loop
    through ``eye_vertices``, crop ids) nor made by the crop (a loop through a vertex that lost a
    face to it), with a perimeter of at most ``max_perimeter_mm``.

    Parameters
    ----------
    Vc (p, 3), Fc (q, 3), vmap (p,) : :func:`crop_eye_region`'s crop
    F : (m, 3) int64   the dense head's faces (before the crop)
    eye_vertices : (k,) int64   the eye loops' vertices in crop ids
    max_perimeter_mm : float
    loops : list of (L,) int64, optional   ``mc.boundary_loops(Fc)`` when already found

    Returns
    -------
    list of (L,) int64 loops in crop ids
    """
    n = int(max(int(np.asarray(F).max()) + 1, int(vmap.max()) + 1))
    lost = np.bincount(np.asarray(F).ravel(), minlength=n) > np.bincount(vmap[Fc].ravel(), minlength=n)
    eye = np.zeros(len(Vc), dtype=bool)
    eye[np.asarray(eye_vertices, dtype=np.int64)] = True
    holes = []
    for lp in mc.boundary_loops(Fc) if loops is None else loops:
        if eye[lp].any() or lost[vmap[lp]].any():
            continue
        if loop_perimeter(Vc[lp]) <= max_perimeter_mm:
            holes.append(lp)
    return holes


# ----------------------------------------------------------------------------- cleaning

def largest_components(V, F, min_share=0.0, keep_faces_with=None):
    """Keep the largest connected component (and any containing ``keep_faces_with`` vertices)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(V)
    e = mc.edges_of(F)
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    _, lab = connected_components(A, directed=False)
    fl = lab[F[:, 0]]
    counts = np.bincount(fl)
    F = F[fl == np.argmax(counts)]
    used = np.unique(F)
    remap = -np.ones(n, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


# ----------------------------------------------------------------------------- local mesh editing


# ----------------------------------------------------------------------------- quads

def pair_triangles(V, F, keep_boundary_edges=(), max_angle_dev_deg=35.0, max_dihedral_deg=30.0):
    """Greedy pairing of adjacent triangles into quads (best-shaped first).

    Returns
    -------
    poly_counts (p,) int64, poly_indices (sum,) int64 (quads as (a, d, b, c)
    for triangles (a, b, c) and (b, a, d)), and F_fan (m, 3) their fan
    triangulation (same triangles as ``F``, reordered).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    m, n = len(F), len(V)
    he = mc.edges_of(F)
    key = he[:, 0] * n + he[:, 1]
    rkey = he[:, 1] * n + he[:, 0]
    order = np.argsort(key)
    pos = np.searchsorted(key[order], rkey)
    pos = np.minimum(pos, len(key) - 1)
    has_twin = key[order][pos] == rkey
    twin = np.where(has_twin, order[pos], -1)
    h = np.flatnonzero(has_twin & (np.arange(len(he)) < twin))
    f1, f2 = h // 3, twin[h] // 3
    a, b = he[h, 0], he[h, 1]
    c = F[f1, (h % 3 + 2) % 3]
    d = F[f2, (twin[h] % 3 + 2) % 3]
    Q = np.stack([a, d, b, c], axis=1)
    P = V[Q]
    dev = np.zeros(len(h))
    angsum = np.zeros(len(h))
    for k in range(4):
        u = P[:, (k + 1) % 4] - P[:, k]
        w = P[:, (k - 1) % 4] - P[:, k]
        cs = np.einsum("ij,ij->i", u, w) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-300)
        ang = np.degrees(np.arccos(np.clip(cs, -1, 1)))
        dev = np.maximum(dev, np.abs(ang - 90.0))
        angsum += ang
    fn = mc.face_normals(V, F)
    dih = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", fn[f1], fn[f2]), -1, 1)))
    ok = (dev < max_angle_dev_deg) & (dih < max_dihedral_deg) & (np.abs(angsum - 360.0) < 5.0)
    used = np.zeros(m, dtype=bool)
    quads = []
    # two greedy passes: well-shaped quads first, then looser ones for the triangles left over
    for limit in (0.6 * max_angle_dev_deg, max_angle_dev_deg):
        cand = np.flatnonzero(ok & (dev < limit))
        cand = cand[np.argsort(dev[cand])]
        for i in cand:
            if used[f1[i]] or used[f2[i]]:
                continue
            used[f1[i]] = used[f2[i]] = True
            quads.append(i)
    quads = np.asarray(quads, dtype=np.int64)
    tris = F[~used]
    counts = np.concatenate([np.full(len(quads), 4), np.full(len(tris), 3)]).astype(np.int64)
    indices = np.concatenate([Q[quads].ravel(), tris.ravel()]).astype(np.int64)
    qf = Q[quads]
    F_fan = np.concatenate([qf[:, [0, 1, 2]], qf[:, [0, 2, 3]], tris]) if len(qf) else tris
    return counts, indices, F_fan


# ----------------------------------------------------------------------------- main entry

def subdivide_midpoint(V, F):
    """1-to-4 midpoint subdivision (the surface is unchanged: new vertices at edge midpoints).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64

    Returns
    -------
    V2 : (n + e, 3) float64
        ``V`` followed by one midpoint per unique edge.
    F2 : (4 m, 3) int64
        Same winding as ``F``.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    uniq, inv = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True)
    mid = len(V) + inv.reshape(3, len(F)).T                  # (m, 3): midpoints of edges 01, 12, 20
    a, b, c = F[:, 0], F[:, 1], F[:, 2]
    ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
    F2 = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                         np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    return np.concatenate([V, 0.5 * (V[uniq[:, 0]] + V[uniq[:, 1]])]), F2


def refine_coarse_crop(V, F, min_loop_vertices, eye_loop_lengths, max_levels=4):
    """Midpoint-subdivide a crop whose eye openings have fewer than ``min_loop_vertices``
    boundary vertices, until each has at least that many.

    An opening with fewer boundary vertices than ``loop_points`` (a coarse scan, or a narrow
    half-closed opening of a dense one: 34 of 64 on a 150k-face half blink) would otherwise
    reach ``loop_points`` only by splitting opening edges, leaving fans of sliver triangles
    from one interior vertex to a run of collinear loop vertices (5-11 mm long on that half
    blink), which fold as soon as the loop moves (snap, lid shapes). Subdividing first gives the
    remesher interior vertices next to the loop; the surface is unchanged.

    Returns
    -------
    V, F, levels : the refined mesh and the number of subdivisions applied (0 = unchanged).
    """
    levels = 0
    n_loop = min(eye_loop_lengths) if len(eye_loop_lengths) else min_loop_vertices
    if n_loop >= min_loop_vertices:
        return V, F, 0
    while levels < max_levels and n_loop < min_loop_vertices:
        V, F = subdivide_midpoint(V, F)
        n_loop *= 2
        levels += 1
    return V, F, levels


def _decimate(V, F, target_faces):
    import fast_simplification

    if len(F) <= target_faces:
        return V, F
    Vd, Fd = fast_simplification.simplify(V, F.astype(np.int32), target_count=int(target_faces),
                                          preserve_border=True)
    return clean_mesh(Vd, np.asarray(Fd, dtype=np.int64))


def close_opened_triangles(V, F, V_in, F_in):
    """``F`` with a face put back into each hole of three edges that ``F_in`` (the remesher's
    input, ``V_in`` its points) did not have. The decimation can drop one face of a noisy crop
    (``n1802_depth10_noise``, 0.15 mm noise at Poisson depth 10: a triangle 8 mm above its right
    opening), and the band round that eye then met the hole and retopo refused the head. A hole
    of the input itself (its three corners on one of the input's three-edge holes) stays."""
    small = [b for b in mc.boundary_loops(F) if len(b) == 3]
    if not small:
        return F
    had = {tuple(sorted(map(tuple, V_in[b].tolist()))) for b in mc.boundary_loops(F_in) if len(b) == 3}
    half = set(map(tuple, np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]).tolist()))
    new = [[int(b[0]), int(b[2]), int(b[1])] if (int(b[0]), int(b[1])) in half else [int(v) for v in b]
           for b in small if tuple(sorted(map(tuple, V[b].tolist()))) not in had]
    return np.concatenate([F, np.asarray(new, dtype=np.int64).reshape(-1, 3)])


def _isotropic(V, F, target_len, iterations):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=F.astype(np.int32)))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=int(iterations), targetlen=pymeshlab.PureValue(float(target_len)),
        featuredeg=180.0, checksurfdist=True, maxsurfdist=pymeshlab.PureValue(float(target_len) * 0.25),
        reprojectflag=True)
    m = ms.current_mesh()
    return clean_mesh(np.asarray(m.vertex_matrix(), dtype=np.float64),
                      np.asarray(m.face_matrix(), dtype=np.int64))


def _flip_counter(ref_V, ref_F):
    """:func:`count_flipped` against (ref_V, ref_F), remembering each vertex set's nearest scan
    faces: the repairs ask again and again about the same positions (unchanged by a pass that
    found nothing to do, or with two candidate face sets), and that query is the count's cost.
    The scan's tree and face normals are looked up once (each lookup compares the crop's bytes
    with the cached tree's)."""
    import hashlib

    nearest = {}
    closest = mc.closest_points_on(ref_V, ref_F)
    normals = closest.face_normals()

    def count(V, F):
        V = np.ascontiguousarray(V, dtype=np.float64)
        key = (V.shape, hashlib.blake2b(memoryview(V).cast("B"), digest_size=16).digest())
        if key not in nearest:
            nearest[key] = closest(V)[1]
        R = reference_face_normals(V, F, ref_V, ref_F, nearest_faces=nearest[key], ref_normals=normals)
        return int(np.count_nonzero(np.einsum("ij,ij->i", mc.face_normals(V, F), R) <= 0))

    return count


def band_zone(V, F, loops, width):
    """What the grid band will replace, before it is built: the vertices within ``width`` mm
    (straight line) of a loop's polyline and the faces with a corner among them. The band's
    outer ring lies ``width`` out along the surface, never nearer in a straight line, so the
    zone covers the band (and a little past it where the skin curves).

    Returns
    -------
    near : (n,) bool ; faces : (m,) bool
    """
    V = np.asarray(V, dtype=np.float64)
    near = np.zeros(len(V), dtype=bool)
    for lp in loops.values():
        near |= project_to_polyline(V, V[np.asarray(lp)])[2] < width
    return near, near[np.asarray(F)].any(axis=1)


@contextmanager
def _collector_paused():
    """Python's cycle collector off for the block (as it was after). The repairs and the band
    hold the remesh as Python lists and sets (TriMesh: one list per face, one set per vertex,
    built nine times) and allocate them by the hundred thousand; each full collection walked
    them and every imported module and freed nothing: 0.3-0.5 CPU-s of the stage on the 1.4M
    head. Reference counting still frees everything the step drops."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def retopologize(V, F, eyes: dict, settings: RetopoSettings) -> RetopoResult:
    """Crop the dense head to the eye region and remesh it (see module docstring).

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        Dense head with eye openings (mm, head frame).
    eyes : dict of str -> pipeline.io.eyes_file.Eye
        ``{"left": Eye, "right": Eye}`` (``remove_eyeballs``' eyes.json), each with its ordered
        ``loop_indices`` and, when known, ``lateral_canthus_index``.
    settings : RetopoSettings

    Returns
    -------
    RetopoResult
    """
    with _collector_paused():
        return _retopologize(V, F, eyes, settings)


def _retopologize(V, F, eyes: dict, settings: RetopoSettings) -> RetopoResult:
    s = settings
    t0 = time.perf_counter()
    timings = {}
    Vc, Fc, vmap = crop_eye_region(V, F, eyes, s)
    curves, lateral, apex_info, notched = {}, {}, {}, {}
    for side, e in eyes.items():
        li = np.asarray(e.loop_indices, dtype=np.int64)
        curves[side] = np.asarray(V, dtype=np.float64)[li]
        lateral[side] = e.lateral_canthus_index
        if s.canthus_apex and lateral[side] is not None:
            curves[side], lateral[side], apex_info[side] = canthus_apex(
                curves[side], lateral[side], s.canthus_window_mm, s.canthus_max_reach_mm)
        if s.margin_smooth_mm > 0 and lateral[side] is not None:
            # the cut follows the scan's triangles in 0.5-1 mm teeth, which snap amplifies; and
            # where it left scanned eyeball on a lid, its notch (smooth_lids)
            curves[side], lateral[side], tried = smooth_lids(
                curves[side], lateral[side], s.margin_smooth_mm, s.margin_smooth_max_move_mm,
                s.margin_smooth_mid_mm, s.margin_notch_mm, s.margin_notch_keep, s.margin_notch_max_move_mm,
                # the sphere without the cornea, which only brings points nearer: the share
                # on the eye measured against it is not too high
                off_eye=partial(sphere_signed_distance, center=np.asarray(e.center, float),
                                radius=float(e.radius)))
            if tried is not None:
                notched[side] = {"notch_mm": round(tried[0], 4), "wider_mm": round(tried[1], 4), "kept": tried[2]}
    holes, left_open, folded = [], [], []
    cbl = graph = None          # the crop's boundary loops and edge graph, while its faces are these
    if s.fill_holes_mm > 0:
        # left open, a scanner's hole in the skin stays a hole of the asset (a black spot in
        # every render); filled here it is remeshed like the skin round it, and the bake's rays
        # over it miss the scan and take the rim's colour at about zero displacement
        # every crop copy of a loop vertex (a bow-tie on the opening has one per fan)
        eye_vs = np.flatnonzero(np.isin(vmap, np.concatenate([np.asarray(e.loop_indices) for e in eyes.values()])))
        cbl = mc.boundary_loops(Fc)
        holes = scan_holes(Vc, Fc, vmap, F, eye_vs, np.inf, cbl)
        per = [loop_perimeter(Vc[h]) for h in holes]
        # a hole too large to be filled stays a hole of the asset, said in the metrics (and by
        # the stage as a warning): the background shows through it in every render
        left_open = [{"perimeter_mm": round(p, 1), "centre_mm": np.round(Vc[h].mean(axis=0), 1).tolist(),
                      "why": "over fill_holes_mm"} for h, p in zip(holes, per) if p > s.fill_holes_mm]
        holes = [h for h, p in zip(holes, per) if p <= s.fill_holes_mm]
        if holes:
            Vc, Fc, unfilled, kept = fill_holes_smooth(Vc, Fc, holes, return_unfilled=True,
                                                       return_folded=True)
            left_open += [{"perimeter_mm": round(loop_perimeter(Vc[holes[i]]), 1),
                           "centre_mm": np.round(Vc[holes[i]].mean(axis=0), 1).tolist(),
                           "why": "no fill without a fold"} for i in unfilled]
            # a hole neither plane closes, small enough to keep its folded grid (as every
            # release before the ear fill did): listed, with its count of turned faces
            folded = [{"perimeter_mm": round(loop_perimeter(Vc[holes[i]]), 1),
                       "centre_mm": np.round(Vc[holes[i]].mean(axis=0), 1).tolist(),
                       "faces_turned": n} for i, n in kept]
            holes = [h for i, h in enumerate(holes) if i not in unfilled]
            cbl = None
    handles_cut = []
    if s.band == "grid":
        # a handle within the band's reach leaves it no annulus to be built on (id339_laser's
        # crop has a tunnel 10 mm from its left opening): cut, the region is a disk with a hole
        cbl = mc.boundary_loops(Fc) if cbl is None else cbl
        openings = {}
        for side, e in eyes.items():
            li = set(np.flatnonzero(np.isin(vmap, np.asarray(e.loop_indices))).tolist())
            openings[side] = next((b for b in cbl if li & set(map(int, b))), None)
        openings = {k: v for k, v in openings.items() if v is not None}
        graph = edge_graph(Vc, Fc)
        Vc, Fc, handles_cut = cut_handles(Vc, Fc, openings, s.band_param_mm, max_loop_mm=s.band_width_mm,
                                          graph=graph)
        if handles_cut:
            cbl = graph = None
    timings["crop_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    tri_target = s.target_polygons if s.method == "quadric" else int(round(s.target_polygons / 0.58))
    if s.eye_rings > 0 and s.band == "march":
        # the rings replace a band of triangles by fewer, longer-sided polygons: ask the
        # remesher for about that many more so the polygon count stays on target
        area = 0.5 * np.linalg.norm(mc.face_normals(Vc, Fc, normalize=False), axis=1).sum()
        L0 = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        lost = 0.0
        for cur in curves.values():
            per = float(polyline_arclength(cur)[0][-1])
            h = s.ring_spacing_mm if s.ring_spacing_mm > 0 else per / s.loop_points
            w = (s.eye_rings + 1) * h
            band = (per * w + np.pi * w * w) / (np.sqrt(3.0) / 4.0 * L0 * L0)
            new = (s.eye_rings + 1) * s.loop_points + (per + 2 * np.pi * w) / L0
            lost += max(0.0, band - new)
        tri_target += int(round(lost * (1.0 if s.method == "quadric" else 1.0 / 0.58)))
    # eye openings with under three quarters of the output loop's vertices (coarse scans,
    # narrow half-closed openings: 34 of 64 on a 150k-face half blink) are subdivided first, so
    # that opening edges are not split into fans of slivers at the loop (at 50-53 of 64, the
    # tests' 100k-face synthetic head, the splits stay single and subdividing moved its medial
    # canthus behind the lid skin in a front view)
    cbl = mc.boundary_loops(Fc) if cbl is None else cbl
    eye_loop_lengths = []
    for side, e in eyes.items():
        li = set(np.flatnonzero(np.isin(vmap, np.asarray(e.loop_indices))).tolist())
        eye_loop_lengths += [len(b) for b in cbl if li & set(map(int, b))][:1]
    Vr, Fr, refine_levels = refine_coarse_crop(Vc, Fc, (3 * s.loop_points + 3) // 4, eye_loop_lengths)
    if s.method == "quadric":
        # the borders are locked during decimation and coarsened afterwards (each boundary vertex
        # collapsed removes one face): ask for that many more faces so the result lands on target
        area = 0.5 * np.linalg.norm(mc.face_normals(Vc, Fc, normalize=False), axis=1).sum()
        L = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        cb = mc.boundary_loops(Fr)
        n_border = sum(len(b) for b in cb)
        perim = sum(float(np.linalg.norm(Vr[b] - np.roll(Vr[b], -1, axis=0), axis=1).sum()) for b in cb)
        extra = max(0, n_border - int(perim / L) - 2 * s.loop_points // 2)
        Vl, Fl = _decimate(Vr, Fr, tri_target + extra)
    else:
        Vp, Fp = _decimate(Vr, Fr, max(s.predecimate_faces, 4 * tri_target))
        area = 0.5 * np.linalg.norm(mc.face_normals(Vp, Fp, normalize=False), axis=1).sum()
        L = np.sqrt(4.0 * area / (np.sqrt(3.0) * tri_target))
        Vl, Fl = _isotropic(Vp, Fp, L, s.isotropic_iterations)
    # the decimation can pinch a narrow neck of a noisy scan to one vertex: two cones touching
    # there (n706_250k_noise, 0.1 mm noise: beside its left opening, where the band's annulus
    # then had Euler characteristic -1 and retopo refused). Each cone gets its own copy, as
    # the crop's bow-ties do; a mesh without one keeps its bytes
    Fl, parent = meshtopo.split_fans(Fl, len(Vl))
    if len(parent) > len(Vl):
        Vl = Vl[parent]
    Vl, Fl = largest_components(Vl, Fl)
    Fl = close_opened_triangles(Vl, Fl, Vr, Fr)
    timings["remesh_s"] = time.perf_counter() - t1

    # ---- eyelid loops: find each eye's boundary loop, resample to loop_points, place on the curve
    t2 = time.perf_counter()
    bl = mc.boundary_loops(Fl)
    if len(bl) < 3:
        raise ValueError(f"remeshed eye region has {len(bl)} boundary loops; expected 2 eye openings + the crop border")
    assigned = {}
    for side, cur in curves.items():
        cen = cur.mean(axis=0)
        best, bd = None, np.inf
        for k, lp in enumerate(bl):
            if k in assigned.values():
                continue
            d = np.mean(project_to_polyline(Vl[lp], cur)[2]) + np.linalg.norm(Vl[lp].mean(axis=0) - cen)
            if d < bd:
                best, bd = k, d
        assigned[side] = best
    tm = TriMesh(Vl, Fl)
    new_loops = {}
    for side, k in assigned.items():
        new_loops[side] = resample_loop(tm, bl[k], s.loop_points, curves[side])
    # outer border: coarsen to about the mean edge length of the interior
    edge_len = float(np.mean(np.linalg.norm(Vl[Fl[:, 1]] - Vl[Fl[:, 0]], axis=1)))
    outer = [lp for k, lp in enumerate(bl) if k not in assigned.values()]
    for lp in outer:
        per = float(np.sum(np.linalg.norm(Vl[lp] - np.roll(Vl[lp], -1, axis=0), axis=1)))
        want = max(8, int(round(per / edge_len)))
        if want < len(lp):
            resample_loop(tm, lp, want)
    tm.flip_ears()
    Vn, Fn, remap = tm.arrays()
    loops = {}
    all_boundary = np.concatenate(mc.boundary_loops(Fn))
    for side, lp in new_loops.items():
        lp = remap[np.asarray(lp, dtype=np.int64)]
        # both canthi are targets; the lateral one's position goes to the stage (for rig)
        # grid band: each lid gets half the loop, so both canthi have fixed ids in every asset
        lp, targets, lateral[side] = orient_and_place(Vn, lp, curves[side], curves[side][0],
                                                      lateral[side],
                                                      split=s.loop_points // 2 if s.band == "grid" else None)
        # move in a few steps, keeping faces from flipping
        for alpha in (0.2, 0.4, 0.6, 0.8, 1.0):
            Vt = Vn.copy()
            Vt[lp] = (1 - alpha) * Vn[lp] + alpha * targets
            Vn = Vt
            Vn = relax(Vn, Fn, all_boundary, Vc, Fc, iterations=1)
        loops[side] = lp
    tm = TriMesh(Vn, Fn)
    if tm.flip_ears():
        Vn, Fn, remap = tm.arrays()          # no vertex is dropped by flips: remap is the identity
        loops = {k: remap[v] for k, v in loops.items()}
    timings["loops_s"] = time.perf_counter() - t2

    flipped = _flip_counter(Vc, Fc)
    t3 = time.perf_counter()
    fixed = np.unique(np.concatenate([np.concatenate(mc.boundary_loops(Fn))]))
    Vn = relax(Vn, Fn, fixed, Vc, Fc, iterations=s.relax_iterations)
    for _ in range(3):
        if flipped(Vn, Fn):             # repair remaining flips next to the (fixed) loops
            Vn = repair_flips(Vn, Fn, fixed, Vc, Fc)
        if flipped(Vn, Fn):             # slivers at the loop: move the free corner inside
            Vn = mirror_flipped(Vn, Fn, fixed, Vc, Fc)
        if flipped(Vn, Fn):             # still flipped: collapse their free vertex into a neighbour
            Vn, Fn, loops = collapse_flipped(Vn, Fn, loops, fixed, Vc, Fc)
            fixed = np.unique(np.concatenate(mc.boundary_loops(Fn)))
    if flipped(Vn, Fn):                 # last resort: slide free corners into their kernel
        free = np.ones(len(Vn), dtype=bool)
        free[fixed] = False
        R = reference_face_normals(Vn, Fn, Vc, Fc)
        nf = mc.face_normals(Vn, Fn, normalize=False)
        bad_v = np.unique(Fn[np.einsum("ij,ij->i", nf, R) <= 0])
        # the faces around them keep a quarter of the typical face area (no new slivers)
        near = np.isin(Fn, bad_v).any(axis=1)
        floor = np.where(near, 0.25 * float(np.median(np.linalg.norm(nf, axis=1))), 0.0)
        if s.band == "grid":
            # the grid band replaces the faces within band_width_mm of each loop: untangling them
            # only slid their vertices off the scan (its moves are tangential, never projected
            # back), up to 3.8 mm beside ident_s1_013's right lateral canthus and past the band's
            # outer ring, where the cut then followed that crumpled remesh 9-14 mm out and its zip
            # kept 30 faces turned over. Those faces are left as they are (never counted bad) and
            # their vertices held; the band cuts them away
            by_loop, replaced = band_zone(Vn, Fn, loops, s.band_width_mm)
            free &= ~by_loop
            floor = np.where(replaced, -np.inf, floor)
        Vn, _ = untangle(Vn, Fn, R, free, min_projected=floor)
    # slivers left by the loop placement and the repairs (a vertex almost on the edge of two
    # others, up to 15 mm long on unseen heads) fold in the lid sweep: flip them away, relax
    # what the flips freed, and flip again
    n_delaunay = 0
    # edges under a fifth of the median (the repairs' leftovers beside a canthus) go first
    elen = np.linalg.norm(Vn[Fn] - Vn[np.roll(Fn, -1, axis=1)], axis=2)
    Vn, Fn, loops, n_short = collapse_short_edges(Vn, Fn, loops, fixed,
                                                  s.min_edge_fraction * float(np.median(elen)),
                                                  coincident=COINCIDENT_MM)
    if n_short:
        fixed = np.unique(np.concatenate(mc.boundary_loops(Fn)))
    for _ in range(2):
        Fd, k = delaunay_flips(Vn, Fn)
        if k and flipped(Vn, Fd) <= flipped(Vn, Fn):
            Fn, n_delaunay = Fd, n_delaunay + k
            Vn = relax(Vn, Fn, fixed, Vc, Fc, iterations=s.relax_iterations)
    Fs = flip_slivers(Vn, Fn, Vc, Fc)
    if len(Fs) == len(Fn) and flipped(Vn, Fs) <= flipped(Vn, Fn):
        Fn = Fs
    timings["relax_quads_s"] = time.perf_counter() - t3

    t4 = time.perf_counter()
    band_ids, band_info = {}, {}
    if s.band == "grid":
        # built, not repaired: the loops' neighbourhood that the repairs above worked on is cut
        # away and replaced by the grid (eye_band module doc)
        Vn, Fn, ring_quads, band_ids, band_info = add_eye_bands(
            Vn, Fn, loops, Vc, Fc, s.band_rings, s.band_width_mm, s.band_param_mm, s.relax_iterations,
            graph, cbl)
        loops = {k: v[0].copy() for k, v in band_ids.items()}
        ring_info = {}
    else:
        Vn, Fn, ring_quads, loops, ring_info = add_eye_rings(
            Vn, Fn, loops, Vc, Fc, s.eye_rings, s.ring_spacing_mm, s.relax_iterations)
    if len(ring_quads) and s.band == "march":
        # the lofts' slivers: flips among the triangles only (the quads' edges are borders there)
        Fs = flip_slivers(Vn, Fn, Vc, Fc)
        Fq = np.concatenate([ring_quads[:, [0, 1, 2]], ring_quads[:, [0, 2, 3]]])
        if len(Fs) == len(Fn) and (count_flipped(Vn, np.concatenate([Fs, Fq]), Vc, Fc)
                                   <= count_flipped(Vn, np.concatenate([Fn, Fq]), Vc, Fc)):
            Fn = Fs
    poly_counts = poly_indices = None
    if s.method == "isotropic":
        poly_counts, poly_indices, Fn = pair_triangles(Vn, Fn, max_angle_dev_deg=s.quad_max_angle_dev_deg)
    elif len(ring_quads):
        poly_counts = np.full(len(Fn), 3, dtype=np.int64)
        poly_indices = Fn.ravel()
    if len(ring_quads):
        poly_counts = np.concatenate([poly_counts, np.full(len(ring_quads), 4, dtype=np.int64)])
        poly_indices = np.concatenate([poly_indices, ring_quads.ravel()])
        Fn = np.concatenate([Fn, ring_quads[:, [0, 1, 2]], ring_quads[:, [0, 2, 3]]])
    timings["band_s" if s.band == "grid" else "eye_rings_s"] = time.perf_counter() - t4
    check_no_coincident_corners(Vn, Fn, band_ids)
    timings["total_s"] = time.perf_counter() - t0

    metrics = retopo_metrics(Vn, Fn, loops, Vc, Fc, curves, s.metric_samples)
    metrics.update({
        "method": s.method,
        "polygons": int(len(poly_counts) if poly_counts is not None else len(Fn)),
        "triangles": int(len(Fn)),
        "quads": int(np.count_nonzero(poly_counts == 4)) if poly_counts is not None else 0,
        "vertices": int(len(Vn)),
        "crop_faces": int(len(Fc)),
        "crop_subdivisions": int(refine_levels),
        "scan_holes_filled": len(holes),
        **({"scan_holes_left_open": left_open} if left_open else {}),
        **({"scan_holes_filled_folded": folded} if folded else {}),
        "delaunay_flips": int(n_delaunay),
        "short_edges_collapsed": int(n_short),
        "eye_rings": ring_info,
        "band": {"kind": s.band, **({"rings": s.band_rings, "spokes": s.loop_points,
                                     "ids": {k: [int(v.min()), int(v.max()) + 1] for k, v in band_ids.items()},
                                     **band_info} if band_ids else {})},
        "canthus_apex": apex_info,
        # only when one was cut: the metrics of a scan without a handle keep their bytes
        **({"handles_cut": {"count": len(handles_cut), "cuts": handles_cut}} if handles_cut else {}),
        # and only where the margin was still notched: the notch seen from the front, mm, that of
        # the wider window's curve and whether that was kept
        **({"margin_notch": {k: notched[k] for k in sorted(notched)}} if notched else {}),
    })
    result = StageResult(metrics, {"timings_s": {k: round(v, 4) for k, v in timings.items()},
                                   "time_s": round(timings["total_s"], 4)})
    return RetopoResult(Vn, Fn, loops, lateral, poly_counts, poly_indices, Vc, Fc, result, band_ids)


#: Corners of one face nearer than this are one point (mm): on the unseen heads the shortest
#: edge of a good remesh is 0.1-0.5 mm.
COINCIDENT_MM = 1e-6


def check_no_coincident_corners(V, F, band_ids: dict) -> None:
    """ValueError naming where a face of the result has two corners on one point (zero area):
    no later stage can map, bake or rig it (the bake's conformal map is singular).
    ``band_ids``: side -> (rings + 1, spokes) ids of the grid band, to say where in it.
    ``n1108_blink_60k`` (a blink the placement took for open) left four nodes of the right
    band's outer ring on one point and the bake failed with a traceback."""
    F2 = np.roll(F, -1, axis=1)
    short = np.linalg.norm(V[F] - V[F2], axis=2) < COINCIDENT_MM
    bad = np.flatnonzero(short.any(axis=1))
    if len(bad) == 0:
        return
    verts = np.unique(np.concatenate([F[short], F2[short]]))    # the corners on one point
    where = []
    for side, ids in band_ids.items():
        ids = np.asarray(ids)
        k, i = np.nonzero(np.isin(ids, verts))
        if len(k):
            where.append(f"the {side} eye's band, ring{'s' if len(set(k)) > 1 else ''} "
                         f"{'-'.join(map(str, sorted({int(min(k)), int(max(k))})))} spokes "
                         f"{'-'.join(map(str, sorted({int(min(i)), int(max(i))})))}")
    if not where:
        c = V[verts].mean(axis=0)
        where.append(f"near ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) mm")
    raise ValueError(f"{len(bad)} faces of the result have two corners on one point ({'; '.join(where)}): "
                     f"the grid collapsed there (a lid folded over the eye, or a closed eye taken for open)")


def retopo_metrics(V, F, loops, Vc, Fc, curves, n_samples=50000) -> dict:
    """Validity, distance-to-scan, angle and loop figures of a retopo result."""
    rep = mc.check_mesh(V, F)
    dist = mc.surface_distance(V, F, Vc, Fc, n_samples=n_samples)
    flipped = count_flipped(V, F, Vc, Fc)
    bset = set()
    for lp in mc.boundary_loops(F):
        bset.update(map(int, lp))
    loop_info = {}
    for side, lp in loops.items():
        lp = np.asarray(lp)
        d = project_to_polyline(V[lp], curves[side])[2]
        seg = np.linalg.norm(V[lp] - np.roll(V[lp], -1, axis=0), axis=1)
        loop_info[side] = {"points": int(len(lp)), "all_on_boundary": bool(all(int(v) in bset for v in lp)),
                           "max_distance_to_scan_loop_mm": float(d.max()),
                           "edge_cv": float(seg.std() / seg.mean())}
    return {
        "mesh": rep.as_dict(),
        "flipped_faces": flipped,
        "distance_lowpoly_to_scan": dist["a_to_b"],
        "distance_scan_to_lowpoly": dist["b_to_a"],
        "distance_symmetric_mean_mm": dist["symmetric_mean_mm"],
        "angles": mc.angle_stats(V, F),
        "loops": loop_info,
    }
