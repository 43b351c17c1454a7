"""High-to-low baking: displacement (signed mm along the normal) and colour maps.

For every texel of the low-poly mesh's UV atlas the texel centre is mapped to
its 3D point ``P`` and interpolated vertex normal ``N`` on the low-poly
surface; a ray along ``+N`` and one along ``-N`` (bounded by
``max_distance_mm``) are cast into the dense scan with Embree and the nearer
hit gives the displacement ``d`` (so ``P + d N`` lies on the scan) and the hit's
barycentric coordinates, which look up the scan's colour (texture through its
per-corner UVs, or vertex colours). Texels whose rays both miss fall back to
the closest point on the scan and are counted. The displacement fades to zero
at the eyelid margin (smoothstep over ``falloff_mm`` of distance from the
loops, or over ``falloff_per_mm`` times the nearby loop's distance off the scan where that is
longer) so the snapped lids stay on the eyeball. Maps are padded past island
borders by ``padding_texels``.

The base surface is the *flat* low-poly mesh with interpolated normals
(midpoint subdivision + displacement reproduces the scan); renderers that
smooth the surface (Catmull-Clark/Loop) before displacing will differ by the
smoothing offset.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from pipeline.bake.raycast import DenseScene, cast_both_ways, in_chunks
from pipeline.bake.uv import UnwrapError, conformal_unwrap, dilation_sources, rasterize, sample_bilinear, unwrap
from pipeline.geometry import mesh_checks as mc
from pipeline.geometry.ramps import smoothstep
from pipeline.settings import Settings, setting


@dataclass
class BakeSettings(Settings):
    """Bake knobs (the ``bake:`` block of params.yaml); defaults here, checked by pipeline.settings."""

    block: ClassVar[str] = "bake"

    resolution: int = setting(2048, ge=16, le=16384)            # map side, texels
    uv_padding_texels: int = setting(8, ge=0, le=256)           # gap between UV charts
    unwrap: str = setting("conformal", choices=("conformal", "xatlas"))   # conformal: a chart per half (xatlas where not one-to-one)
    padding_texels: int = setting(6, ge=0, le=256)              # dilation past island borders
    max_distance_mm: float = setting(4.0, gt=0, le=100)         # ray length each way
    falloff_mm: float = setting(2.0, ge=0, le=100)              # displacement fades to 0 over this distance from the eyelid loops
    falloff_per_mm: float = setting(2.0, ge=0, le=100)          # ... or over this many times the loop's distance off the scan, where longer
    subdivision_levels: int = setting(2, ge=0, le=4)            # evaluation: midpoint subdivision levels (x4 faces each)
    metric_samples: int = setting(100000, ge=100, le=10_000_000)


@dataclass
class BakeResult:
    UV: np.ndarray            # (k, 2)
    FUV: np.ndarray           # (m, 3)
    displacement: np.ndarray  # (H, W) float32, mm along the normal, padded
    color: np.ndarray | None  # (H, W, 3) uint8, padded
    mask: np.ndarray          # (H, W) bool, texels covered by the atlas
    metrics: dict             # what the inputs determine (bake_metrics)
    timings_s: dict = field(default_factory=dict)   # seconds per step


def distance_to_polylines(P, loops, step=0.05):
    """Euclidean distance from points to closed polylines (sampled every ``step`` mm)."""
    from scipy.spatial import cKDTree

    if not loops:
        return np.full(len(P), np.inf)
    pts = []
    for L in loops:
        L = np.asarray(L, dtype=np.float64)
        A, B = L, np.roll(L, -1, axis=0)
        n = np.maximum(np.ceil(np.linalg.norm(B - A, axis=1) / step).astype(int), 1)
        t = np.concatenate([np.arange(k) / k for k in n])
        ia = np.repeat(np.arange(len(L)), n)
        pts.append(A[ia] + t[:, None] * (B[ia] - A[ia]))
    d, _ = cKDTree(np.concatenate(pts)).query(P, workers=-1)     # nearest neighbours: same on any core count
    return d


def faces_near_box(V, F, lo, hi):
    """Indices of faces with at least one vertex inside the axis-aligned box [lo, hi]."""
    inside = np.all((V >= lo) & (V <= hi), axis=1)
    return np.flatnonzero(inside[F].any(axis=1))


def _dense_colour(dense: dict, texture, face, bary):
    """Colour (k, 3) float64 in 0..255 at barycentric points of the dense mesh, or None."""
    if texture is not None and "UV" in dense and "FUV" in dense:
        uv = _interpolate(bary, np.asarray(dense["UV"], dtype=np.float64), dense["FUV"][face])
        return sample_bilinear(np.asarray(texture)[..., :3], uv)
    if "VC" in dense:
        return _interpolate(bary, np.asarray(dense["VC"], dtype=np.float64), dense["F"][face])
    return None


def dense_scene(V, dense: Mapping, settings: BakeSettings = BakeSettings()) -> DenseScene:
    """The Embree scene of the part of the dense scan that rays from the low-poly mesh ``V``
    (n, 3) can reach: faces with a vertex in its bounding box padded by ``max_distance_mm`` + 1.
    Its BVH is built here (one ray is cast), so it can be made while the mesh is unwrapped.
    Its ``face_ids`` (r,) int64 map the scene's faces back to ``dense["F"]``."""
    V = np.asarray(V, dtype=np.float64)
    dV = np.asarray(dense["V"], dtype=np.float64)
    dF_all = np.asarray(dense["F"], dtype=np.int64)
    pad = settings.max_distance_mm + 1.0
    near_faces = faces_near_box(dV, dF_all, V.min(axis=0) - pad, V.max(axis=0) + pad)
    scene = DenseScene(dV, dF_all[near_faces], face_ids=near_faces)
    scene.intersect(V[:1], np.array([[0.0, 0.0, 1.0]]), 1.0)     # Embree builds the BVH on first use
    return scene


@dataclass
class Texels:
    """The texels of a UV atlas on the low-poly mesh: atlas ``rows``, ``cols`` (k,), the
    ``face`` (k,) and barycentric ``bary`` (k, 3) each lies in, its surface point ``P`` and
    interpolated unit normal ``N`` (k, 3), and the covered ``mask`` (res, res)."""

    rows: np.ndarray
    cols: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    P: np.ndarray
    N: np.ndarray
    mask: np.ndarray


def atlas_unwrap(V, F, loops, s: BakeSettings):
    """UV atlas of the low-poly eye region: ``(UV, FUV, method)``.

    ``conformal``: one conformal chart per half, split halfway between the two openings'
    centres (:func:`pipeline.bake.uv.conformal_unwrap`; a single chart where there are not two
    openings); ``xatlas`` where a chart is not one-to-one, or when asked for.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if s.unwrap == "conformal":
        centres = [V[np.asarray(lp, dtype=np.int64)].mean(axis=0) for lp in loops if len(lp)]
        side = np.zeros(len(F), dtype=np.int64)
        if len(centres) == 2:
            axis = centres[0] - centres[1]
            side = ((V[F].mean(axis=1) - 0.5 * (centres[0] + centres[1])) @ axis > 0).astype(np.int64)
        try:
            return (*conformal_unwrap(V, F, side, s.resolution, s.uv_padding_texels), "conformal")
        except UnwrapError as exc:
            method = f"xatlas ({exc})"
    else:
        method = "xatlas"
    return (*unwrap(V, F, s.resolution, s.uv_padding_texels), method)


def atlas_texels(V, F, UV, FUV, res: int) -> Texels:
    """Rasterize the atlas: every texel's point and normal on the flat low-poly surface."""
    rows, cols, face, bary = rasterize(UV, FUV, res, res)
    X = np.hstack([V, mc.vertex_normals(V, F)])
    PN = np.empty((len(face), 6))

    def part(a, b):            # position and normal in one pass, a piece at a time (CHUNK)
        pn = _interpolate(bary[a:b], X, F[face[a:b]])
        pn[:, 3:] /= np.maximum(np.linalg.norm(pn[:, 3:], axis=1, keepdims=True), 1e-300)
        PN[a:b] = pn

    in_chunks(len(face), part)
    P, N = PN[:, :3], PN[:, 3:]
    mask = np.zeros((res, res), dtype=bool)
    mask[rows, cols] = True
    return Texels(rows, cols, face, bary, P, N, mask)


def cast_texels(scene: DenseScene, tx: Texels, s: BakeSettings):
    """Signed displacement (k,) along each texel's normal to the scan, the scan face (k,) and
    barycentrics (k, 3) it hits, and how many texels missed both ways (the closest point on the
    scan stands in for those)."""
    dV, dF = scene.V, scene.F
    disp, hface, hbary = cast_both_ways(scene, tx.P, tx.N, s.max_distance_mm)
    miss = np.isnan(disp)
    n_miss = int(miss.sum())
    if n_miss:
        _, cf, C = mc.closest_points(tx.P[miss], dV, dF)
        disp[miss] = np.einsum("ij,ij->i", C - tx.P[miss], tx.N[miss])
        hface[miss] = cf
        hbary[miss] = _barycentric(C, dV[dF[cf]])
    return disp, scene.face_ids[hface], hbary, n_miss       # back to the scan's own face indices


def texel_weights(V, F, tx: Texels, loops, s: BakeSettings, gaps=None):
    """The texels' displacement weights (:func:`falloff_weights`; ``gaps``: :func:`loop_gaps`)
    and the atlas padding (:func:`~pipeline.bake.uv.dilation_sources`): they need the texels
    only, not the rays."""
    return (falloff_weights(V, F, tx.P, tx.face, loops, s.falloff_mm, gaps, s.falloff_per_mm),
            dilation_sources(tx.mask, s.padding_texels))


def loop_gaps(V, loops, dense_V, dense_F, reach=3.0):
    """Each loop vertex's distance (mm) to the dense scan: a list of (len(loop),) arrays.

    The distances are :func:`closest_distances`' (the scan's faces round the loops only: the same
    values as against the whole scan, whose AABB tree of 1.4M faces cost 1.2 of bake's 8.6 CPU-s)."""
    loops = [np.asarray(l, dtype=np.int64) for l in loops]
    if not loops:
        return []
    d = closest_distances(V[np.concatenate(loops)], dense_V, dense_F, reach)
    return np.split(d, np.cumsum([len(l) for l in loops])[:-1])


def faces_touching_box(V, F, lo, hi):
    """Indices of faces whose bounding box meets the axis-aligned box [lo, hi]: every face with a
    point in the box is one (unlike :func:`faces_near_box`, which asks for a vertex inside)."""
    V = np.asarray(V)
    code = np.zeros(len(V), dtype=np.uint8)          # bit 2a: below the box on axis a, 2a+1: above
    for a in range(3):
        code |= (V[:, a] < lo[a]).view(np.uint8) << (2 * a)
        code |= (V[:, a] > hi[a]).view(np.uint8) << (2 * a + 1)
    c = code[np.asarray(F)]
    # a face misses the box exactly when all three corners lie beyond the same side of it
    return np.flatnonzero((c[:, 0] & c[:, 1] & c[:, 2]) == 0)


def closest_distances(P, V, F, reach=1.0):
    """Distances (k,) from points ``P`` (k, 3) to the mesh (V, F), the same values as
    ``mc.closest_points(P, V, F)[0]``, from the faces round the points only.

    The faces whose bounding box meets the points' box grown by ``reach`` are searched; every
    other face lies more than ``reach`` from every point (beyond the grown box along some axis),
    so where all the distances found are within ``reach`` they are the whole mesh's. Otherwise
    ``reach`` grows fourfold and the search is repeated (the whole mesh at the latest)."""
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if len(P) == 0:
        return np.zeros(0)
    lo, hi = P.min(axis=0), P.max(axis=0)
    while True:
        near = faces_touching_box(V, F, lo - reach, hi + reach)
        if len(near) == len(F):
            return mc.closest_points(P, V, F)[0]
        if len(near):
            used, Fc = np.unique(F[near], return_inverse=True)
            d = mc.closest_points(P, V[used], Fc.reshape(-1, 3))[0]
            if d.max() <= reach:
                return d
        reach *= 4.0


def displacement_map(tx: Texels, disp, weights, res: int):
    """The padded (res, res) float32 displacement map and the weighted displacements (k,)."""
    w, (grow, sy, sx) = weights
    disp_w = disp * w
    dimg = np.zeros((res, res), dtype=np.float32)
    dimg[tx.rows, tx.cols] = disp_w
    dimg[grow] = dimg[sy, sx]
    return dimg, disp_w


def colour_map(tx: Texels, dense: Mapping, texture, hface, hbary, weights, res: int):
    """The padded (res, res, 3) uint8 colour map from the scan at the texels' hits, or None
    (a scan without texture or vertex colours). Looked up in pieces of :data:`CHUNK` texels
    (each texel's colour is its own: the same bytes as in one batch, without its temporaries)."""
    _, (grow, sy, sx) = weights
    if _dense_colour(dense, texture, hface[:0], hbary[:0]) is None:
        return None
    col = np.empty((len(hface), 3), dtype=np.uint8)

    def part(a, b):
        c = _dense_colour(dense, texture, hface[a:b], hbary[a:b])
        col[a:b] = np.clip(np.round(c), 0, 255)

    in_chunks(len(hface), part)
    cimg = np.zeros((res, res, 3), dtype=np.uint8)
    cimg[tx.rows, tx.cols] = col
    cimg[grow] = cimg[sy, sx]
    return cimg


def bake_metrics(tx: Texels, disp_w, n_miss: int, colour: str | None, res: int) -> dict:
    """What the inputs determine of a bake (the stage's metrics)."""
    return {
        "resolution": res,
        "texels": int(len(tx.rows)),
        "atlas_coverage": float(len(tx.rows) / (res * res)),
        "missed_texels": n_miss,
        "missed_texel_fraction": float(n_miss / max(len(tx.rows), 1)),
        "displacement_mm": {"min": float(disp_w.min()), "max": float(disp_w.max()),
                            "mean_abs": float(np.abs(disp_w).mean())},
        "colour": colour,
    }


def colour_source(dense: Mapping, texture, cimg) -> str | None:
    """Where the colour map came from: ``texture``, ``vertex_colours`` or None."""
    if cimg is None:
        return None
    return "texture" if texture is not None and "UV" in dense else "vertex_colours"


def bake_maps(V, F, loops, dense: dict, texture=None, settings: BakeSettings = BakeSettings(),
              UV=None, FUV=None, scene: DenseScene | None = None) -> BakeResult:
    """UV-unwrap the low-poly mesh and bake displacement and colour from the dense scan, one step
    after the other (the bake stage runs the same steps with the independent ones side by side:
    pipeline/bake/build.py).

    Parameters
    ----------
    V : (n, 3) float64, F : (m, 3) int64
        Low-poly eye region (triangulation).
    loops : dict
        side -> ordered eyelid loop vertex indices into ``V``.
    dense : dict
        Dense scan arrays ``V``, ``F`` and optionally ``UV``/``FUV`` (with ``texture``) or ``VC``.
    texture : (h, w, 3|4) uint8 array or None
    UV, FUV : optional existing atlas (skips xatlas)
    scene : optional :func:`dense_scene` of ``V`` and ``dense`` with these settings, already built

    Returns
    -------
    BakeResult
    """
    s = settings
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    t = {}
    t0 = time.perf_counter()
    method = "given"
    if UV is None:
        UV, FUV, method = atlas_unwrap(V, F, list(loops.values()), s)
    t["unwrap_s"] = time.perf_counter() - t0
    res = int(s.resolution)
    t1 = time.perf_counter()
    tx = atlas_texels(V, F, UV, FUV, res)
    t["rasterize_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    gaps = loop_gaps(V, list(loops.values()), dense["V"], dense["F"]) if s.falloff_per_mm > 0 else None
    weights = texel_weights(V, F, tx, list(loops.values()), s, gaps)
    t["weights_padding_s"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    scene = scene if scene is not None else dense_scene(V, dense, s)
    t["scene_s"] = time.perf_counter() - t3
    t4 = time.perf_counter()
    disp, hface, hbary, n_miss = cast_texels(scene, tx, s)
    t["raycast_s"] = time.perf_counter() - t4
    t5 = time.perf_counter()
    dimg, disp_w = displacement_map(tx, disp, weights, res)
    cimg = colour_map(tx, dense, texture, hface, hbary, weights, res)
    t["maps_s"] = time.perf_counter() - t5
    t["total_s"] = time.perf_counter() - t0
    metrics = {**bake_metrics(tx, disp_w, n_miss, colour_source(dense, texture, cimg), res), "unwrap": method}
    return BakeResult(UV, FUV, dimg, cimg, tx.mask, metrics, {k: round(v, 4) for k, v in t.items()})


def falloff_weights(V, F, P, face, loops, falloff_mm, gaps=None, per_mm=0.0):
    """Displacement weights (k,) of texels at ``P`` (k, 3) on faces ``face`` (k,) of the low-poly
    mesh (V, F): a smoothstep from 0 on the eyelid ``loops`` (vertex index lists) to 1 at
    ``falloff_mm`` from them, and round each loop vertex that lies off the scan (``gaps``: one
    (len(loop),) array of distances per loop) from 0 at the vertex to 1 at ``per_mm`` times its
    gap, where that is longer; the smaller weight wins.

    Why the gap: a loop vertex placed off the scan (a canthus apex, up to ~2.5 mm under the skin
    of the fissure's corner) would have the skin beside it baked back onto the scan within
    ``falloff_mm``: a wall that hides the canthus from the front. The skin should reach the loop
    no steeper than ``1 : per_mm``."""
    lp = [V[np.asarray(l, dtype=np.int64)] for l in loops]
    w = np.ones(len(P))
    if falloff_mm > 0 and lp:
        Q, rad = np.zeros((0, 3)), np.zeros(0)
        if gaps is not None and per_mm > 0:
            rad = per_mm * np.concatenate([np.asarray(g, float) for g in gaps])
            Q, rad = np.concatenate(lp)[rad > falloff_mm], rad[rad > falloff_mm]
        reach = max(falloff_mm, float(rad.max(initial=0.0)))
        # only faces that can reach within falloff of a loop need the per-texel distance
        dv = distance_to_polylines(V, lp)
        elen = np.linalg.norm(V[F] - np.roll(V[F], 1, axis=1), axis=2).max(axis=1)
        near_face = dv[F].min(axis=1) <= reach + elen
        sel = near_face[face]
        ws = smoothstep(0.0, 1.0, distance_to_polylines(P[sel], lp) / falloff_mm)
        for q, r in zip(Q, rad):
            np.minimum(ws, smoothstep(0.0, 1.0, np.linalg.norm(P[sel] - q, axis=1) / r), out=ws)
        w[sel] = ws
    return w


def _interpolate(bary, X, corners):
    """sum_j bary[:, j] X[corners[:, j]], (k, c): corner by corner (no (k, 3, c) temporary) and
    column by column: gathers from one contiguous column of X and contiguous (k,) temporaries
    take under half the time of (k, c) row gathers (millions of texels), with the same sums in
    the same order, so the same bits."""
    X = np.asarray(X)
    out = np.empty((len(bary), X.shape[1]), dtype=np.result_type(bary, X))
    b = [np.ascontiguousarray(bary[:, j]) for j in range(3)]
    c = [np.ascontiguousarray(corners[:, j]) for j in range(3)]
    tmp = np.empty(len(bary), dtype=out.dtype)
    for col in range(X.shape[1]):
        x = np.ascontiguousarray(X[:, col])
        o = np.multiply(b[0], x.take(c[0]))
        np.multiply(b[1], x.take(c[1]), out=tmp)
        o += tmp
        np.multiply(b[2], x.take(c[2]), out=tmp)
        o += tmp
        out[:, col] = o
    return out


def _barycentric(P, T):
    """Barycentric coordinates (k, 3) of points P in triangles T (k, 3, 3)."""
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    v0, v1, v2 = b - a, c - a, P - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = np.where(np.abs(d00 * d11 - d01 * d01) > 1e-300, d00 * d11 - d01 * d01, 1.0)
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    return np.stack([1 - v - w, v, w], axis=1)


def subdivide_displaced(V, F, UV, FUV, displacement, levels=2, displace=True):
    """Midpoint-subdivide the low-poly mesh ``levels`` times and displace along interpolated normals.

    Each triangle becomes a barycentric grid of ``4**levels`` triangles; the
    vertex at barycentric ``b`` sits at ``sum b_i V_i + d(uv) N(b)`` with ``d``
    bilinearly sampled from the map at the interpolated UV. Vertices on shared
    edges are duplicated per triangle (fine for distance measurements).

    Returns
    -------
    Vs : (p, 3) float64, Fs : (q, 3) int64
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = 2 ** int(levels)
    ij = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
    B = np.array([[(n - i - j) / n, i / n, j / n] for i, j in ij])
    index = {p: k for k, p in enumerate(ij)}
    tris = []
    for i in range(n):
        for j in range(n - i):
            tris.append([index[(i, j)], index[(i + 1, j)], index[(i, j + 1)]])
            if i + j < n - 1:
                tris.append([index[(i + 1, j)], index[(i + 1, j + 1)], index[(i, j + 1)]])
    tris = np.array(tris, dtype=np.int64)
    m, g = len(F), len(B)
    P = np.einsum("gj,mjc->mgc", B, V[F]).reshape(-1, 3)
    if displace:
        VN = mc.vertex_normals(V, F)
        N = np.einsum("gj,mjc->mgc", B, VN[F]).reshape(-1, 3)
        N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-300)
        uv = np.einsum("gj,mjc->mgc", B, np.asarray(UV)[np.asarray(FUV)]).reshape(-1, 2)
        P = P + sample_bilinear(displacement, uv)[:, None] * N
    Fs = (tris[None, :, :] + (np.arange(m) * g)[:, None, None]).reshape(-1, 3)
    return P, Fs


def reconstruction_baseline(V, F, dense_V, dense_F, levels=2, n_samples=100000, region_mm=3.0) -> dict:
    """The UV-independent half of :func:`reconstruction_error` (scan region and the error
    without displacement), so it can run before/while the mesh is unwrapped and baked.

    Returns
    -------
    dict with ``region_faces`` (scan faces compared, (r, 3) int64) and ``without_displacement``.
    """
    dense_V = np.asarray(dense_V, dtype=np.float64)
    dense_F = np.asarray(dense_F, dtype=np.int64)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    dense_F = dense_F[faces_near_box(dense_V, dense_F, V.min(axis=0) - region_mm, V.max(axis=0) + region_mm)]
    cen = dense_V[dense_F].mean(axis=1)
    d, fi, C = mc.closest_points(cen, V, F)
    # keep scan faces that project onto the low-poly surface (not past its borders)
    cosang = np.abs(np.einsum("ij,ij->i", cen - C, mc.face_normals(V, F)[fi])) / np.maximum(d, 1e-300)
    Fr = dense_F[(d <= region_mm) & ((d < 1e-3) | (cosang >= 0.95))]
    Vs, Fs = subdivide_displaced(V, F, None, None, None, levels, displace=False)
    return {"region_faces": Fr, "levels": int(levels), "n_samples": int(n_samples),
            "without_displacement": _distance_entry(Vs, Fs, dense_V, Fr, n_samples)}


def _distance_entry(Vs, Fs, dense_V, Fr, n_samples):
    sd = mc.surface_distance(Vs, Fs, dense_V, Fr, n_samples=n_samples)
    return {"lowpoly_to_scan": sd["a_to_b"], "scan_to_lowpoly": sd["b_to_a"],
            "symmetric_mean_mm": sd["symmetric_mean_mm"]}


def reconstruction_error(V, F, UV, FUV, displacement, dense_V, dense_F, levels=2,
                         n_samples=100000, region_mm=3.0, baseline=None) -> dict:
    """Distance to the scan of the subdivided low-poly mesh with and without displacement.

    The scan is restricted to faces within ``region_mm`` of the low-poly
    surface whose offset to it is along its normal (within 18 degrees), i.e.
    the part the low-poly mesh stands for, not the scan beyond its borders.
    ``baseline``: :func:`reconstruction_baseline` of the same meshes/settings, when already computed.

    Returns
    -------
    dict with ``without_displacement`` / ``with_displacement`` two-sided stats and
    ``mean_error_removed`` = 1 - mean_with / mean_without (symmetric means).
    """
    dense_V = np.asarray(dense_V, dtype=np.float64)
    if baseline is None or baseline["levels"] != int(levels) or baseline["n_samples"] != int(n_samples):
        baseline = reconstruction_baseline(V, F, dense_V, dense_F, levels, n_samples, region_mm)
    Fr = baseline["region_faces"]
    out = {"without_displacement": baseline["without_displacement"]}
    Vs, Fs = subdivide_displaced(V, F, UV, FUV, displacement, levels, displace=True)
    out["with_displacement"] = _distance_entry(Vs, Fs, dense_V, Fr, n_samples)
    e0 = out["without_displacement"]["symmetric_mean_mm"]
    e1 = out["with_displacement"]["symmetric_mean_mm"]
    out["mean_error_removed"] = float(1.0 - e1 / e0) if e0 > 0 else 0.0
    out["subdivision_levels"] = int(levels)
    return out
