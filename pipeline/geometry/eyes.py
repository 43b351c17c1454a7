"""Find the scanned eyeballs, fit them, and cut them out of the head mesh.

Method (per eye, see ``find_eye``):

1. Local patch: faces within ``patch_radius_mm`` of the hint, connected to the face
   nearest the hint.
2. Sclera sphere: LO-RANSAC over 4-point spheres drawn from vertices near the hint and
   2-point spheres from pairs of oriented faces (likely all-inlier even when only a few
   canthal sclera vertices show, as in hooded eyes), radius in ``radius_range_mm``, centre
   behind the hint; the score counts vertices within ``inlier_tol_mm`` of the sphere and
   penalises vertices inside it (nothing of the head lies inside the eyeball; beyond
   ``inside_soft_tol_mm`` this also rejects a lid shell concentric with the eye). The best
   ``ransac_refine`` samples are refined locally before the final ranking. The corneal
   bulge, the flattened cornea footprint of scanners that see the iris, lids and lashes
   are all outliers.
3. Refinement: robust geometric fit (soft-L1) on the inliers outside a cornea cap
   of ``cornea_cap_deg`` around the forward axis, with a weak radius prior and one-sided
   residuals keeping the eye region outside the sphere (``inside_fit_margin_mm``),
   iterated; both eyes share one radius only when their radii agree within
   ``shared_radius_max_z`` standard errors (``fit_eye_pair``).
4. Two-sphere model: a corneal sphere is fitted to the remaining bulge if there is
   one; forward = centre -> corneal centre, else the normal of the cornea footprint,
   else centre -> opening centroid.
5. Removal region: faces whose vertices lie on the two-sphere eye surface (within
   ``cut_tol_mm`` outside, ``inside_tol_mm`` inside), connected to the hint; islands
   filled, notches/spikes/bow-ties cleaned so that its border is one simple loop.
   An open eye has a crease there (lid skin rises steeply off the eyeball); no crease
   means the eye is closed and is refused.
6. Eyelid loop: where the cut border lies on the eyeball, each loop vertex moves to where
   the uncut surface lifts off the fitted eye by ``margin_lift_mm``, projected onto the eye
   (the margin between the last eyeball vertex and the first lid vertex); flip-guarded.
   Loop vertices already lifted off (a crease filled by the reconstruction) keep the cut.
7. Scans too coarse to show the eyeball geometrically (``james``) use the colour
   texture instead: faces near the hint whose colour differs from the surrounding
   skin form the opening; the sphere is fitted to that region with the radius prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import eye_checks, meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.spherefit import (fit_sphere_algebraic, radius_sigma, ransac_sphere,
                                         refine_sphere, signed_distance)
from pipeline.settings import Settings, setting

SIDES = ("left", "right")


@dataclass
class EyeSettings(Settings):
    """Parameters of eye finding and removal (``remove_eyeballs:`` block of params.yaml); the
    defaults are here, values are checked by pipeline.settings."""

    block: ClassVar[str] = "remove_eyeballs"

    patch_radius_mm: float = setting(22.0, gt=0, le=100)       # surface considered around a hint
    sample_radius_mm: float = setting(13.0, gt=0, le=100)      # RANSAC samples within this of the hint
    radius_range_mm: tuple[float, float] = setting((10.0, 18.0), gt=0, le=100, ordered=True)
    radius_prior_mm: float = setting(12.0, gt=0, le=100)
    radius_prior_sigma_mm: float = setting(3.0, gt=0, le=100)
    inlier_tol_mm: float = setting(0.3, gt=0, le=10)
    inside_tol_mm: float = setting(1.5, ge=0, le=20)
    inside_soft_tol_mm: float = setting(0.5, ge=0, le=20)
    inside_soft_weight: float = setting(3.0, ge=0, le=1000)
    inside_fit_margin_mm: float = setting(0.2, ge=-1, le=20)   # < 0: no inside constraint
    cut_tol_mm: float = setting(0.8, gt=0, le=20)
    cornea_cap_deg: float = setting(35.0, ge=0, lt=90)
    ransac_iterations: int = setting(1500, ge=1, le=1_000_000)
    ransac_refine: int = setting(6, ge=0, le=1000)
    min_inliers: int = setting(20, ge=4, le=1_000_000)
    crease_margin_mm: float = setting(0.5, ge=-1, le=20)
    crease_margin_capped: bool = False
    fit_iterations: int = setting(4, ge=1, le=100)
    min_crease_deg: float = setting(20.0, ge=0, le=180)        # lid fold at the cut border; below = closed
    shared_radius: bool = True
    shared_radius_max_z: float = setting(3.0, ge=0, le=1000)
    max_center_hint_distance_mm: float = setting(22.0, gt=0, le=100)
    texture_fallback: bool = True
    texture_min_contrast: float = setting(3.0, gt=0, le=1000)
    max_fit_rms_mm: float = setting(0.6, gt=0, le=20)
    margin_lift_mm: float = setting(0.6, ge=0, le=20)          # 0 = loop left on the cut
    margin_max_turn_deg: float = setting(60.0, gt=0, le=180)
    margin_on_eye_mm: float = setting(0.3, ge=0, le=20)
    max_gaze_deg: float = setting(40.0, gt=0, le=90)
    max_hole_perimeter_mm: float = setting(60.0, ge=0, le=1000)  # holes near the hints (an unmeasured pupil) closed for the fit
    cornea_min_inliers: int = setting(20, ge=4, le=1_000_000)
    cornea_min_fraction: float = setting(0.45, gt=0, le=1)
    seed: int = setting(0, ge=0)


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
        ``"geometry"`` or ``"texture"``.
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


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


class _Mesh:
    """Adjacency cached once per mesh."""

    def __init__(self, V, F, median_edge=None):
        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        self.pairs, self.pair_edges = meshtopo.face_adjacency(self.F, len(self.V))
        self.centroids = self.V[self.F].mean(axis=1)
        if median_edge is None:
            median_edge = _median_edge(self.V, self.F)
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


def _median_edge(V, F):
    e = V[F[:, [1, 2, 0]]] - V[F]
    return float(np.median(np.linalg.norm(e, axis=2)))


def _local_mesh(V, F, hints, radius):
    """The faces with centroid within ``radius`` of any hint, as a sub-mesh.

    Returns ``(V_sub, F_sub, faces, verts)``: ``faces``/``verts`` (sorted) map sub-mesh face and
    vertex ids back to the full mesh, so the sub-mesh keeps the full mesh's face and vertex order.
    """
    c = V[F].mean(axis=1)
    sel = np.zeros(len(F), bool)
    for h in hints:
        sel |= np.linalg.norm(c - h, axis=1) < radius
    faces = np.flatnonzero(sel)
    verts, Fs = np.unique(F[faces], return_inverse=True)
    return V[verts], Fs.reshape(-1, 3).astype(np.int64), faces, verts


def _patch(mesh: _Mesh, hint, radius):
    """Faces within ``radius`` of the hint, connected to the face nearest it: (m,) bool."""
    d = np.linalg.norm(mesh.centroids - hint, axis=1)
    near = d < radius
    if not near.any():
        return near
    labels = meshtopo.face_components(len(mesh.F), mesh.pairs, near)
    f0 = int(np.argmin(d))
    return near & (labels == labels[f0])


def _interior(mesh: _Mesh, region, vids, margin_mm):
    """(len(vids),) bool: vertices of ``region`` farther than ``margin_mm`` from its border."""
    from scipy.spatial import cKDTree

    Vin = np.zeros(len(mesh.V), bool)
    Vin[mesh.F[region].ravel()] = True
    Vout = np.zeros(len(mesh.V), bool)
    Vout[mesh.F[~region].ravel()] = True
    border = np.where(Vin & Vout)[0]
    ok = Vin[vids]
    if len(border) and margin_mm > 0:
        dist, _ = cKDTree(mesh.V[border]).query(mesh.V[vids])
        ok &= dist > margin_mm
    return ok


def _crease(mesh: _Mesh, region, dist=None, radius_mm=2.0):
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
    angles = []
    for v, a_, b_ in zip(border, tin.query_ball_point(mesh.V[border], r),
                         tout.query_ball_point(mesh.V[border], r)):
        if not a_ or not b_:
            continue
        na, nb = N[fin[a_]].sum(axis=0), N[fout[b_]].sum(axis=0)
        c = na @ nb / max(np.linalg.norm(na) * np.linalg.norm(nb), 1e-12)
        angles.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
    return float(np.median(angles)) if angles else 0.0


def _clean_region(mesh: _Mesh, region, keep_seed, local=None, max_iter=30):
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


def _texture_colours(mesh_arrays, texture, faces, samples=7):
    """Median sRGB colour of the texture over each face, (k, 3) float64 (0..255)."""
    UV = np.asarray(mesh_arrays["UV"], dtype=np.float64)
    FUV = np.asarray(mesh_arrays["FUV"], dtype=np.int64)[faces]
    H, W = texture.shape[:2]
    bary = np.array([[1 / 3, 1 / 3, 1 / 3], [0.6, 0.2, 0.2], [0.2, 0.6, 0.2], [0.2, 0.2, 0.6],
                     [0.45, 0.45, 0.1], [0.1, 0.45, 0.45], [0.45, 0.1, 0.45]])[:samples]
    uv = np.einsum("sk,fkd->fsd", bary, UV[FUV])
    px = np.clip((uv[..., 0] % 1.0) * W, 0, W - 1).astype(np.int64)
    py = np.clip((1.0 - uv[..., 1] % 1.0) * H, 0, H - 1).astype(np.int64)
    return np.median(texture[py, px, :3].astype(np.float64), axis=1)


def _forward_from(center, pts_cornea, pts_region):
    """Forward direction: normal of the cornea footprint (oriented outward), else opening."""
    if pts_cornea is not None and len(pts_cornea) >= 20:
        Q = pts_cornea - pts_cornea.mean(axis=0)
        _, s, vt = np.linalg.svd(Q, full_matrices=False)
        n = vt[2]
        if s[2] < 0.5 * s[1]:
            out = pts_cornea.mean(axis=0) - center
            return _unit(n if n @ out > 0 else -n)
    return _unit(pts_region.mean(axis=0) - center)


def _cornea_bulge(mesh: _Mesh, patch_v, center, radius, forward, st: EyeSettings, rng):
    """Fit a corneal sphere to vertices bulging off the sclera sphere near the forward axis."""
    V = mesh.V
    w = V[patch_v] - center
    dist = np.linalg.norm(w, axis=1) - radius
    ang = np.degrees(np.arccos(np.clip((w @ forward) / np.linalg.norm(w, axis=1), -1, 1)))
    cand = patch_v[(ang < st.cornea_cap_deg + 10) & (dist > st.inlier_tol_mm)
                   & (dist < 0.25 * radius)]
    if len(cand) < 30:
        return None
    P = V[cand]

    def score(c, r):
        return (np.abs(np.linalg.norm(P - c, axis=1) - r) < st.inlier_tol_mm).sum()

    def accept(c, r):
        a = (c - center) @ forward
        off = np.linalg.norm((c - center) - a * forward)
        return 0.2 * radius < a < 0.8 * radius and off < 0.3 * radius

    best = ransac_sphere(P, score, rng=rng, n_iter=800, r_range=(0.45 * radius, 0.85 * radius),
                         accept=accept)
    if best is None or best[2] < max(30, 0.5 * len(cand)):
        return None
    c2, r2, _ = best
    inl = np.abs(np.linalg.norm(P - c2, axis=1) - r2) < st.inlier_tol_mm
    c2, r2 = refine_sphere(P[inl], c2, r2, scale=0.1)
    if not (0.45 * radius <= r2 <= 0.85 * radius and accept(c2, r2)):
        return None
    inl = np.abs(np.linalg.norm(P - c2, axis=1) - r2) < st.inlier_tol_mm
    if inl.sum() < max(30, 0.5 * len(cand)):
        return None
    return {"center": c2, "radius": float(r2), "n_inliers": int(inl.sum())}


def _central_cornea(mesh: _Mesh, hint, st: EyeSettings, rng, radius_mm=5.0):
    """A corneal sphere (r 5.5-10 mm) fitting most of the surface right around the hint, or None.

    A scan that reconstructed the corneal bulge shows a small, very regular sphere in the middle
    of the opening; lids, a flattened cornea footprint (scanner saw the iris) or a closed lid
    do not fit one that well.
    """
    V = mesh.V
    near = np.unique(mesh.F[np.linalg.norm(mesh.centroids - hint, axis=1) < radius_mm])
    if len(near) < st.cornea_min_inliers:
        return None
    P = V[near]
    tol = 0.15

    def score(c, r):
        return float((np.abs(np.linalg.norm(P - c, axis=1) - r) < tol).sum())

    def accept(c, r):
        v = hint - c
        return v[2] > 0.5 * np.linalg.norm(v)

    best = ransac_sphere(P, score, rng=rng, n_iter=400, r_range=(5.5, 10.0), accept=accept)
    if best is None or best[2] < max(st.cornea_min_inliers, st.cornea_min_fraction * len(P)):
        return None
    c2, r2, _ = best
    inl = np.abs(np.linalg.norm(P - c2, axis=1) - r2) < tol
    c2, r2 = refine_sphere(P[inl], c2, r2, scale=0.05)
    d = np.linalg.norm(P - c2, axis=1) - r2
    inl = np.abs(d) < tol
    if (not (5.5 <= r2 <= 10.0) or inl.sum() < st.cornea_min_fraction * len(P)
            or np.sqrt(np.mean(d[inl] ** 2)) > 0.08):
        return None
    return {"center": c2, "radius": float(r2), "n_inliers": int(inl.sum())}


def eye_surface_distance(P, center, radius, cornea=None):
    """Signed distance to the union of the sclera sphere and (optional) corneal sphere, (n,)."""
    d = signed_distance(P, center, radius)
    if cornea is not None:
        d = np.minimum(d, signed_distance(P, cornea["center"], cornea["radius"]))
    return d


def _fit_geometry(mesh: _Mesh, hint, side, st: EyeSettings, source, rng, fixed_radius=None,
                  capped=None):
    """Geometric eye fit; returns EyeFit or raises ScanError.

    Fits twice, with and without the cornea-cap exclusion; the fit without it wins when
    including the central part of the opening does not worsen the residual (no cornea bulge
    or footprint there), since the cap leaves only the canthal sclera to fit.
    """
    from dataclasses import replace

    seed = int(rng.integers(1 << 31))
    cornea = _central_cornea(mesh, np.asarray(hint, float), st, np.random.default_rng(seed))
    if cornea is not None:  # two-sphere eye: sclera fitted outside the fitted cornea
        fit = _fit_geometry_once(mesh, hint, side, st, source, np.random.default_rng(seed),
                                 fixed_radius, cornea_fixed=cornea)
        fit.capped = True
        return fit
    if capped is not None:  # decided by an earlier pass
        s2 = st if capped else replace(st, cornea_cap_deg=0.0)
        fit = _fit_geometry_once(mesh, hint, side, s2, source, np.random.default_rng(seed),
                                 fixed_radius)
        fit.capped = capped
        return fit
    full = _fit_geometry_once(mesh, hint, side, replace(st, cornea_cap_deg=0.0), source,
                              np.random.default_rng(seed), fixed_radius)
    full.capped = False
    if st.cornea_cap_deg <= 0:
        return full
    if full.cornea is None:
        # does the central part (cornea cap) fit the sphere as well as the periphery?
        pv = np.unique(mesh.F[full.region])
        inner = pv[_interior(mesh, full.region, pv, max(1.0, 1.5 * mesh.median_edge))]
        w = mesh.V[inner] - full.center
        nw = np.linalg.norm(w, axis=1)
        d = nw - full.radius
        cap = (w @ full.forward) > np.cos(np.radians(st.cornea_cap_deg)) * nw
        if cap.sum() < 5 or (~cap).sum() < 5:
            return full
        rms_in = float(np.sqrt(np.mean(d[cap] ** 2)))
        rms_out = float(np.sqrt(np.mean(d[~cap] ** 2)))
        if rms_in <= max(1.4 * rms_out, 0.1):
            return full
    try:
        fit = _fit_geometry_once(mesh, hint, side, st, source, np.random.default_rng(seed),
                                 fixed_radius)
        fit.capped = True
        return fit
    except ScanError:
        return full


def _fit_geometry_once(mesh: _Mesh, hint, side, st: EyeSettings, source, rng, fixed_radius=None,
                       cornea_fixed=None):
    """One geometric eye fit with the given settings (and optionally a known corneal sphere)."""
    V, F = mesh.V, mesh.F
    patch = _patch(mesh, hint, st.patch_radius_mm)
    patch_v = np.unique(F[patch])
    if len(patch_v) < 20:
        raise ScanError(source, f"{side} eye: no mesh surface near the hint {np.round(hint, 2).tolist()}")
    P = V[patch_v]
    dh = np.linalg.norm(P - hint, axis=1)
    sample = np.where(dh < st.sample_radius_mm)[0]
    scored = np.where(dh < st.sample_radius_mm + 2.0)[0]
    Ps = P[scored]
    tol = max(st.inlier_tol_mm, 0.0)

    cos_cap = np.cos(np.radians(st.cornea_cap_deg))

    if cornea_fixed is not None:
        c2, r2 = np.asarray(cornea_fixed["center"]), cornea_fixed["radius"]
        on_cornea = np.abs(np.linalg.norm(Ps - c2, axis=1) - r2) < 0.2
        # draw sclera samples off the fitted cornea (in a hooded eye most of the opening is cornea)
        off = np.linalg.norm(P[sample] - c2, axis=1) - r2 > 0.3
        if off.sum() >= 4 * st.min_inliers // 5:
            sample = sample[off]
    else:
        on_cornea = np.zeros(len(Ps), bool)
    # oriented samples: faces near the hint (off the fitted cornea)
    nfaces = np.flatnonzero(patch & (np.linalg.norm(mesh.centroids - hint, axis=1) < st.sample_radius_mm))
    if cornea_fixed is not None:
        nfaces = nfaces[np.linalg.norm(mesh.centroids[nfaces] - c2, axis=1) - r2 > 0.3]

    def _periph(c, r):
        w = Ps - c
        nw = np.linalg.norm(w, axis=1)
        u = hint - c if cornea_fixed is None else c2 - c
        return nw - r, ((w @ u) < cos_cap * nw * np.linalg.norm(u)) & ~on_cornea

    def prescore(c, r):
        # sclera inliers outside a cornea cap around centre->hint; nothing may lie inside
        d, periph = _periph(c, r)
        return float((periph & (np.abs(d) < tol)).sum() - 10.0 * (d < -st.inside_tol_mm).sum())

    def score(c, r):
        # ... and (after local refinement) little even slightly inside: a lid shell concentric
        # with the eye, or a sphere through lid and sclera, has skin or eye surface inside it
        d, _ = _periph(c, r)
        return prescore(c, r) - st.inside_soft_weight * float((d < -st.inside_soft_tol_mm).sum())

    def local_refine(c, r):
        for _ in range(2):
            d, periph = _periph(c, r)
            sel = periph & (np.abs(d) < tol)
            if sel.sum() < 8:
                break
            if fixed_radius is not None:
                c, r = refine_sphere(Ps[sel], c, r, scale=0.1, fixed_radius=fixed_radius)
            else:
                c, r = refine_sphere(Ps[sel], c, r, scale=0.1, radius_prior=st.radius_prior_mm,
                                     radius_sigma=st.radius_prior_sigma_mm / 0.1)
        return c, r

    def accept(c, r):
        v = hint - c
        n = np.linalg.norm(v)
        ok = abs(n - r) < 5.0 and v[2] > 0.4 * n and n < st.max_center_hint_distance_mm
        if ok and cornea_fixed is not None:
            a = np.linalg.norm(c2 - c)  # cornea centre in front, apex beyond the sclera
            ok = (0.2 * r < a < 0.8 * r and 1.03 * r < a + r2 < 1.25 * r and r2 < r
                  and (c2 - c)[2] > np.cos(np.radians(st.max_gaze_deg)) * a)
        return ok

    best = ransac_sphere(P, score, rng=rng, n_iter=st.ransac_iterations, sample_from=sample,
                         r_range=tuple(st.radius_range_mm), accept=accept, refine=local_refine,
                         prescore=prescore, n_refine=st.ransac_refine,
                         normals=(mesh.centroids[nfaces], mesh.face_normals()[nfaces]))
    if best is None or best[2] < st.min_inliers:
        raise ScanError(source, f"{side} eye: no eyeball surface found near the hint "
                                f"{np.round(hint, 2).tolist()}")
    c, r, _ = best
    forward = _unit(hint - c) if cornea_fixed is None else _unit(c2 - c)
    cornea = cornea_fixed
    inl = None
    in_region = None  # (len(patch_v),) bool: interior vertices of the current removal region
    # away from the crease only when the whole opening is fitted (with a cornea cap too few
    # canthal sclera vertices would remain)
    use_margin = st.crease_margin_mm >= 0 and (st.cornea_cap_deg <= 0 or cornea_fixed is not None
                                               or st.crease_margin_capped)
    for it in range(st.fit_iterations):
        w = P - c
        nw = np.linalg.norm(w, axis=1)
        d = nw - r
        ang = np.degrees(np.arccos(np.clip((w @ forward) / nw, -1, 1)))
        cap_deg = st.cornea_cap_deg
        if cornea_fixed is not None:  # limbus of the two-sphere model + seam margin
            a = np.linalg.norm(c2 - c)
            x = (r * r - r2 * r2 + a * a) / (2 * a)
            cap_deg = np.degrees(np.arccos(np.clip(x / r, -1, 1))) + 5.0
        if in_region is None or not use_margin:
            inl = (np.abs(d) < tol) & (dh < st.sample_radius_mm + 2.0) & (ang > cap_deg)
        else:
            # exposed sclera: inside the cut, away from its (rounded) crease, outside the cornea
            inl = in_region & (np.abs(d) < 3 * tol) & (ang > cap_deg)
        if inl.sum() < st.min_inliers:
            inl = (np.abs(d) < tol) & (dh < st.sample_radius_mm + 2.0)
        # nothing of the eye region may lie inside the eyeball (beyond the noise)
        Q = Ps if st.inside_fit_margin_mm >= 0 else None
        if fixed_radius is not None:
            c, r = refine_sphere(P[inl], c, r, scale=0.1, fixed_radius=fixed_radius,
                                 inside_points=Q, inside_margin=st.inside_fit_margin_mm)
        else:
            c, r = refine_sphere(P[inl], c, r, scale=0.1, radius_prior=st.radius_prior_mm,
                                 radius_sigma=st.radius_prior_sigma_mm / 0.1,
                                 inside_points=Q, inside_margin=st.inside_fit_margin_mm)
        dn = np.linalg.norm(P[inl] - c, axis=1) - r
        tol = float(np.clip(3.0 * 1.4826 * np.median(np.abs(dn)), 0.1, st.inlier_tol_mm))
        # region and forward direction with the current sphere
        cornea = cornea_fixed if cornea_fixed is not None else \
            _cornea_bulge(mesh, patch_v, c, r, forward, st, rng)
        dd = np.full(len(V), np.inf)
        dd[patch_v] = eye_surface_distance(P, c, r, cornea)
        okv = (dd <= st.cut_tol_mm) & (dd >= -st.inside_tol_mm)
        allowed = patch & okv[F].all(axis=1)
        seed = np.linalg.norm(mesh.centroids - hint, axis=1) < max(6.0, 3 * mesh.median_edge)
        region = _clean_region(mesh, allowed, seed, patch)
        if not region.any():
            raise ScanError(source, f"{side} eye: no eyeball surface found near the hint "
                                    f"{np.round(hint, 2).tolist()}")
        rv = np.unique(F[region])
        if use_margin:
            in_region = _interior(mesh, region, patch_v, st.crease_margin_mm)
        if cornea is not None:
            forward = _unit(cornea["center"] - c)
        else:
            inner = patch_v[_interior(mesh, region, patch_v, max(1.0, 1.5 * mesh.median_edge))]
            dr = np.linalg.norm(V[inner] - c, axis=1) - r
            foot = V[inner][dr > 0.5 * tol]
            forward = _forward_from(c, foot, V[rv])
    w = P - c
    d = np.linalg.norm(w, axis=1) - r
    rms = float(np.sqrt(np.mean(d[inl] ** 2)))
    crease = _crease(mesh, region, np.where(np.isfinite(dd), dd, np.nan))
    return EyeFit(side=side, center=c, radius=float(r), forward=forward, residual_rms_mm=rms,
                  n_inliers=int(inl.sum()), method="geometry", region=region, cornea=cornea,
                  crease_deg=crease, inliers=patch_v[inl],
                  radius_sigma=radius_sigma(P[inl], c, r) if fixed_radius is None else float("inf"))


def _fit_texture(mesh: _Mesh, mesh_arrays, texture, hint, side, st: EyeSettings, source,
                 fixed_radius=None):
    """Eye opening from the colour texture (coarse scans), sphere from its vertices."""
    V, F = mesh.V, mesh.F
    patch = _patch(mesh, hint, st.patch_radius_mm)
    faces = np.where(patch)[0]
    col = _texture_colours(mesh_arrays, texture, faces)
    dh = np.linalg.norm(mesh.centroids[faces] - hint, axis=1)
    ring = (dh > 14.0) & (dh < st.patch_radius_mm)
    if ring.sum() < 10:
        raise ScanError(source, f"{side} eye: too little skin around the hint to read the texture")
    # chroma/brightness features; skin statistics from the ring
    lum = col.mean(axis=1)
    chroma = col / np.maximum(col.sum(axis=1, keepdims=True), 1.0)
    feat = np.column_stack([lum / 255.0, chroma[:, 0], chroma[:, 2]])
    mu = np.median(feat[ring], axis=0)
    mad = 1.4826 * np.median(np.abs(feat[ring] - mu), axis=0) + np.array([0.02, 0.005, 0.005])
    z = np.sqrt((((feat - mu) / mad) ** 2).sum(axis=1))
    eye = (z > st.texture_min_contrast) & (dh < 12.0)
    mask = np.zeros(len(F), bool)
    mask[faces[eye]] = True
    seed = np.zeros(len(F), bool)
    seed[faces[dh < max(4.0, 1.5 * mesh.median_edge)]] = True
    region = _clean_region(mesh, mask, seed, patch)
    if region.sum() < 2:
        raise ScanError(source, f"{side} eye: no eyeball surface found near the hint "
                                f"{np.round(hint, 2).tolist()} (geometry and texture)")
    rv = np.unique(F[region])
    P = V[rv]
    r0 = st.radius_prior_mm if fixed_radius is None else fixed_radius
    # start: sphere of the prior radius behind the region centroid along the mean normal
    N = meshtopo.face_normals(V, F)[region].mean(axis=0)
    N = _unit(N if np.linalg.norm(N) > 0 else [0, 0, 1.0])
    c0 = P.mean(axis=0) - r0 * N
    c, r = refine_sphere(P, c0, r0, scale=0.3, fixed_radius=r0, center_prior_sigma=1.0)
    d = signed_distance(P, c, r)
    rms = float(np.sqrt(np.mean(d ** 2)))
    forward = _unit(P.mean(axis=0) - c)
    dd = np.full(len(V), np.nan)
    pv = np.unique(F[patch])
    dd[pv] = signed_distance(V[pv], c, r)
    return EyeFit(side=side, center=c, radius=float(r), forward=forward, residual_rms_mm=rms,
                  n_inliers=int(len(rv)), method="texture", region=region,
                  crease_deg=_crease(mesh, region, dd), inliers=rv)


def find_eye(mesh: _Mesh, hint, side, st: EyeSettings, *, source="mesh", mesh_arrays=None,
             texture=None, fixed_radius=None, capped=None) -> EyeFit:
    """Fit one eye near ``hint`` (geometry first, texture as fallback).

    Raises
    ------
    ScanError
        No eyeball near the hint, or a closed eye.
    """
    rng = np.random.default_rng(st.seed + (0 if side == "left" else 1))
    hint = np.asarray(hint, dtype=np.float64)
    geo_err = None
    fit = None
    try:
        fit = _fit_geometry(mesh, hint, side, st, source, rng, fixed_radius, capped)
        if fit.n_inliers < st.min_inliers:
            geo_err = ScanError(source, f"{side} eye: no eyeball surface found near the hint "
                                        f"{np.round(hint, 2).tolist()} (only {fit.n_inliers} "
                                        f"vertices on the fitted sphere)")
            fit = None
        elif fit.crease_deg < st.min_crease_deg or fit.residual_rms_mm > st.max_fit_rms_mm:
            geo_err = ScanError(source, f"{side} eye looks closed or covered by the lids: no "
                                        f"eyeball surface with a lid crease around it near "
                                        f"{np.round(hint, 2).tolist()} (fold {fit.crease_deg:.0f} deg "
                                        f"< {st.min_crease_deg:g} deg, residual "
                                        f"{fit.residual_rms_mm:.2f} mm)")
            fit = None
    except ScanError as exc:
        geo_err = exc
    if fit is not None:
        return fit
    has_tex = (texture is not None and mesh_arrays is not None and "UV" in mesh_arrays
               and "FUV" in mesh_arrays)
    if st.texture_fallback and has_tex:
        tfit = _fit_texture(mesh, mesh_arrays, texture, hint, side, st, source, fixed_radius)
        return tfit
    raise geo_err


def order_loop(loop, V, center, forward, side):
    """Rotate/reverse a closed loop: start at the medial canthus, upper lid first.

    Returns
    -------
    loop : (L,) int64
    lateral_index : int
        Position of the lateral canthus in the returned loop.
    """
    B = eye_basis(forward)
    Q = (V[loop] - center) @ B.T
    sign = 1.0 if side == "left" else -1.0
    x = Q[:, 0] * sign  # positive = lateral
    m = int(np.argmin(x))
    loop = np.roll(loop, -m)
    Q = np.roll(Q, -m, axis=0)
    x = np.roll(x, -m)
    lat = int(np.argmax(x))
    y_first = Q[1:lat, 1].mean() if lat > 1 else Q[1, 1]
    y_second = Q[lat + 1:, 1].mean() if lat + 1 < len(loop) else Q[-1, 1]
    if y_first < y_second:
        loop = np.concatenate([loop[:1], loop[1:][::-1]])
        lat = len(loop) - lat
    return loop, int(lat)


@dataclass
class RemovalResult:
    mesh: dict
    eyes: dict
    fits: dict
    metrics: dict


def _lift_off_points(V, F, loop_old, h, tau, reach, k=3):
    """Where the surface lifts off the eye by ``tau``, nearest to each loop vertex.

    The ``tau`` iso-line of the height field is sampled where it crosses the edges of the uncut
    mesh near the loop (linear interpolation along each edge); each loop vertex gets the mean
    of its ``k`` nearest crossing points within ``reach`` mm (itself when there are none).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        The uncut mesh.
    loop_old : (L,) int64
        Loop vertices (ids of ``V``).
    h : (n,) float64
        Height of each vertex above the eye surface (NaN where unknown).
    tau : float
    reach : float
    k : int

    Returns
    -------
    (L, 3) float64
    """
    from scipy.spatial import cKDTree

    ok = np.isfinite(h)
    Fl = F[ok[F].all(axis=1)]
    E = np.concatenate([Fl[:, [0, 1]], Fl[:, [1, 2]], Fl[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    ha, hb = h[E[:, 0]], h[E[:, 1]]
    cross = (ha - tau) * (hb - tau) < 0
    E, ha, hb = E[cross], ha[cross], hb[cross]
    out = V[loop_old].copy()
    if len(E) == 0:
        return out
    t = (tau - ha) / (hb - ha)
    P = V[E[:, 0]] + t[:, None] * (V[E[:, 1]] - V[E[:, 0]])
    kk = min(k, len(P))
    dist, idx = cKDTree(P).query(out, k=kk)
    dist, idx = dist.reshape(len(out), kk), idx.reshape(len(out), kk)
    w = (dist <= reach).astype(np.float64)
    n = w.sum(axis=1)
    has = n > 0
    out[has] = (P[idx[has]] * w[has, :, None]).sum(axis=1) / n[has, None]
    return out


def _project_to_eye(P, center, radius, cornea=None):
    """Closest points on the surface of the two-sphere eye (sclera sphere or corneal sphere,
    whichever is nearer), (n, 3)."""
    def onto(c, r):
        w = P - c
        return c + r * w / np.maximum(np.linalg.norm(w, axis=1), 1e-12)[:, None]
    out = onto(center, radius)
    if cornea is not None:
        ds = np.abs(signed_distance(P, center, radius))
        dc = np.abs(signed_distance(P, cornea["center"], cornea["radius"]))
        use = (dc < ds) & (signed_distance(P, center, radius) > 0)
        out[use] = onto(np.asarray(cornea["center"]), cornea["radius"])[use]
    return out


def _move_to_lift_off(V, F, V2, F2, old_ids, loop, fit, tau, min_cos=0.5, on_eye=0.3):
    """Move the loop vertices of the cut mesh (in place) to where the uncut surface lifts off the
    fitted eye surface by ``tau`` (``_lift_off_points``), the eyelid margin at a sub-edge
    position; a move that would turn an incident face by more than ``acos(min_cos)`` or shrink
    it below a tenth of its area is halved (three times, then dropped). Returns the mean move, mm.
    """
    loop_old = old_ids[loop]
    L = V[loop_old]
    reach = 2.0 * _median_edge(V2, F2[np.isin(F2, loop).any(axis=1)])
    lo, hi = L.min(axis=0) - reach - 1.0, L.max(axis=0) + reach + 1.0
    box = np.flatnonzero(((V >= lo) & (V <= hi)).all(axis=1))
    h = np.full(len(V), np.nan)
    h[box] = eye_surface_distance(V[box], fit.center, fit.radius, fit.cornea)
    target = _lift_off_points(V, F, loop_old, h, tau, reach)
    # onto the eye surface (the margin lies on the eyeball; the scan rounds the crease)
    # only where the cut reached the eyeball (the loop vertex lies within on_eye of it, so the
    # margin is between it and the first lid vertex); a loop vertex already lifted off lies on a
    # reconstruction-filled crease whose margin is hidden under the surface, and dropping the
    # loop there would fold the lid rim
    on = np.abs(h[loop_old]) <= on_eye
    target = np.where(on[:, None], _project_to_eye(target, fit.center, fit.radius, fit.cornea), L)
    start = V2[loop].copy()
    faces = np.flatnonzero(np.isin(F2, loop).any(axis=1))
    Fa = F2[faces]

    def normals(X):
        return np.cross(X[Fa[:, 1]] - X[Fa[:, 0]], X[Fa[:, 2]] - X[Fa[:, 0]])

    N0 = normals(V2)
    A0 = np.linalg.norm(N0, axis=1)
    frac = np.ones(len(loop))
    for _ in range(4):
        V2[loop] = start + frac[:, None] * (target - start)
        N1 = normals(V2)
        A1 = np.linalg.norm(N1, axis=1)
        bad = ((N0 * N1).sum(axis=1) < min_cos * A0 * A1) | (A1 < 0.1 * A0)
        if not bad.any():
            break
        hit = np.isin(loop, Fa[bad])
        frac[hit] *= 0.5
    else:
        V2[loop] = start
        N1 = normals(V2)
        frac[:] = 0.0
    return float(np.linalg.norm(V2[loop] - start, axis=1).mean())


def _radii_agree(fits, st: EyeSettings):
    """Whether the two eyes' radii are equal within ``shared_radius_max_z`` combined standard errors."""
    sig = np.hypot(fits["left"].radius_sigma, fits["right"].radius_sigma)
    return bool(np.isfinite(sig) and abs(fits["left"].radius - fits["right"].radius)
                <= st.shared_radius_max_z * sig)


def fill_holes_near(V, F, centres, near_mm, max_perimeter_mm):
    """Close the mesh's holes near ``centres`` with a fan around each hole's centroid.

    Scanners often leave the dark pupil and iris unmeasured: a hole in the eye opening. The eye fit
    and the cut run on the closed surface; :func:`fit_eye_pair` then gives each hole to the
    opening or to the skin.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    centres : list of (3,) float64
    near_mm : float
        A hole is closed when one of its vertices lies this close to a centre ...
    max_perimeter_mm : float
        ... and its perimeter is at most this.

    Returns
    -------
    V2 : (n + k, 3) float64
        ``V`` and one centroid vertex per closed hole.
    F2 : (m + f, 3) int64
        ``F`` and the fan faces (appended, so face ``i < m`` is still face ``i`` of ``F``).
    holes : list of (L,) int64
        The closed holes' loops (vertex ids), in the order of their centroid vertices.
    hole_of_face : (m + f,) int64
        -1 for the faces of ``F``, else the hole index.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    C = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    H = meshtopo.boundary_halfedges(F)
    loops = []
    if len(H):
        # each connected piece of the boundary near a centre that is one simple loop
        bv, Hc = np.unique(H, return_inverse=True)
        Hc = Hc.reshape(-1, 2)
        g = coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])), shape=(len(bv), len(bv)))
        _, comp = connected_components(g, directed=False)
        near = np.linalg.norm(V[bv][:, None, :] - C[None], axis=2).min(axis=1) <= near_mm
        for k in np.unique(comp[near]):
            try:
                loops += meshtopo.boundary_loops(F, only=bv[comp == k], H=H)
            except ValueError:      # a bow-tie boundary: left as it is
                pass
    newV, newF, holes, owner = [], [], [], []
    for loop in loops:
        P = V[loop]
        per = float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).sum())
        if per > max_perimeter_mm or len(loop) < 3:
            continue
        if np.linalg.norm(P[:, None, :] - C[None], axis=2).min() > near_mm:
            continue
        k = len(holes)
        c = len(V) + k
        # the boundary half-edge a -> b belongs to a face; the fill face runs b -> a
        newF.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), c)]))
        newV.append(P.mean(axis=0))
        holes.append(np.asarray(loop, dtype=np.int64))
        owner.append(np.full(len(loop), k))
    if not holes:
        return V, F, [], np.full(len(F), -1, dtype=np.int64)
    V2 = np.concatenate([V, np.asarray(newV)])
    F2 = np.concatenate([F, *newF]).astype(np.int64)
    return V2, F2, holes, np.concatenate([np.full(len(F), -1), *owner]).astype(np.int64)


def _opening_holes(region, F, holes, hole_of_face, n_faces, min_share=0.3):
    """The fitted region on the original faces. A hole whose fill or rim the region reaches
    (``min_share`` of its rim vertices, or half its fill) is part of the opening: the faces
    around it join the region, so the cut border passes around it (a scanner loses the crease
    where lid meets eye as easily as the pupil). A hole the region only grazes is kept off it."""
    out = region[:n_faces].copy()
    Fo = F[:n_faces]
    inside = np.zeros(int(F.max()) + 1, bool)
    inside[Fo[out].ravel()] = True
    for k, loop in enumerate(holes):
        rim = np.isin(Fo, loop).any(axis=1)
        if region[hole_of_face == k].mean() >= 0.5 or inside[loop].mean() >= min_share:
            out |= rim
        else:
            out &= ~rim
    return out


def _holes_inside(F, remove):
    """Number of the mesh's boundary loops whose every edge belongs to a removed face (holes in
    the eye openings, which the cut absorbs)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H = meshtopo.boundary_halfedges(F)
    if len(H) == 0:
        return 0
    # the face of each boundary half-edge a -> b
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    n = int(F.max()) + 1
    key = E[:, 0] * n + E[:, 1]
    order = np.argsort(key)
    hf = fid[order[np.searchsorted(key[order], H[:, 0] * n + H[:, 1])]]
    bv, Hc = np.unique(H, return_inverse=True)
    Hc = Hc.reshape(-1, 2)
    g = coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])), shape=(len(bv), len(bv)))
    _, comp = connected_components(g, directed=False)
    ecomp = comp[Hc[:, 0]]
    kept = np.zeros(comp.max() + 1, bool)
    np.logical_or.at(kept, ecomp, ~remove[hf])
    return int((~kept).sum())


def fit_eye_pair(mesh_arrays, hints: dict, st: EyeSettings, *, source="mesh", texture=None):
    """Fit both eyes; with ``shared_radius`` refit both with their inverse-variance weighted mean
    radius when both are geometric fits whose radii agree within ``shared_radius_max_z`` standard
    errors (eyes of one head are usually the same size; a clear difference is kept)."""
    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    median_edge = _median_edge(V, F)
    # Everything a fit reads lies within patch_radius_mm of its hint, plus a few edge rings
    # (region borders, crease neighbourhoods): fit on that sub-mesh, which keeps the full mesh's
    # face/vertex order (same random samples, same results) and map regions back.
    reach = st.patch_radius_mm + 5.0 + 6.0 * median_edge + max(2.0, 1.5 * median_edge)
    centres = [np.asarray(hints[s], float) for s in SIDES]
    Vs, Fs, faces, verts = _local_mesh(V, F, centres, reach)
    n_local = len(Fs)
    Vs, Fs, holes, hole_of_face = fill_holes_near(Vs, Fs, centres, st.sample_radius_mm,
                                                  st.max_hole_perimeter_mm)
    mesh = _Mesh(Vs, Fs, median_edge=median_edge)
    sub_arrays = {k: (np.asarray(mesh_arrays[k])[faces] if k == "FUV" else mesh_arrays[k])
                  for k in ("UV", "FUV") if k in mesh_arrays}
    if holes and "FUV" in sub_arrays:   # fan faces take the texture corners of a rim face
        rim = np.array([np.flatnonzero(np.isin(Fs[:n_local], loop).any(axis=1))[0] for loop in holes])
        sub_arrays["FUV"] = np.concatenate([sub_arrays["FUV"],
                                            sub_arrays["FUV"][rim[hole_of_face[n_local:]]]])
    fits = {s: find_eye(mesh, hints[s], s, st, source=source, mesh_arrays=sub_arrays,
                        texture=texture) for s in SIDES}
    if st.shared_radius and all(fits[s].method == "geometry" for s in SIDES) and _radii_agree(fits, st):
        w = np.array([1.0 / max(fits[s].radius_sigma, 1e-3) ** 2 for s in SIDES])
        r = float(np.average([fits[s].radius for s in SIDES], weights=w))
        fits = {s: find_eye(mesh, hints[s], s, st, source=source, mesh_arrays=sub_arrays,
                            texture=texture, fixed_radius=r, capped=fits[s].capped)
                for s in SIDES}
    for fit in fits.values():       # back to full-mesh ids
        region = np.zeros(len(F), bool)
        region[faces[_opening_holes(fit.region, Fs, holes, hole_of_face, n_local)]] = True
        fit.region = region
        if fit.inliers is not None:
            inl = np.asarray(fit.inliers, dtype=np.int64)
            fit.inliers = verts[inl[inl < len(verts)]]
    return mesh, fits


def _refuse_unsure(eyes: dict, source):
    """One line naming every failed self-check (``eye_checks``): an eye placed wrongly would
    otherwise pass silently into every later stage."""
    bad = [(s, k) for s in SIDES for k in eye_checks.failed(eyes[s]["checks"])]
    if not bad:
        return
    pair = [k for s, k in bad if k == "radii_agree"][:1]
    per_eye = [f"{s} eye: " + eye_checks.describe(k, eyes[s]["checks"][k]) for s, k in bad
               if k != "radii_agree"]
    both = [eye_checks.describe(k, eyes["left"]["checks"][k]) for k in pair]
    raise ScanError(source, "not sure of the eyeball placement: " + "; ".join(per_eye + both)
                    + " (see the remove_eyeballs self-checks in the README)")


def remove_eyeballs(mesh_arrays: dict, hints: dict, st: EyeSettings | None = None, *,
                    source="mesh", texture=None) -> RemovalResult:
    """Fit both eyes and cut the scanned eyeball surface out of the head mesh.

    Parameters
    ----------
    mesh_arrays : dict
        ``V`` (n,3) float64 mm head frame, ``F`` (m,3) int64, optional ``UV``/``FUV``/``VC``
        and other per-face/per-vertex arrays (carried through).
    hints : dict
        ``{"left": (3,), "right": (3,)}`` eye hints, head frame mm.
    st : EyeSettings
    source : str
        File named in error messages.
    texture : (h, w, 3) uint8, optional
        Colour texture (used when geometry alone cannot find the eye).

    Returns
    -------
    RemovalResult
        ``mesh`` (arrays with the eyeball faces removed and vertices re-indexed),
        ``eyes`` (eyes.json content), ``fits`` (EyeFit per side), ``metrics``.
    """
    st = st or EyeSettings()
    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    mesh, fits = fit_eye_pair(mesh_arrays, hints, st, source=source, texture=texture)
    if (fits["left"].region & fits["right"].region).any():
        raise ScanError(source, "the two eye regions overlap (hints too close or wrong)")
    loops_in = meshtopo.boundary_component_count(F)
    remove = fits["left"].region | fits["right"].region
    absorbed = _holes_inside(F, remove)
    keepF = ~remove
    F2 = F[keepF]
    used = np.zeros(len(V), bool)
    used[F2.ravel()] = True
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(used.sum())
    out = {}
    nV, nF = len(V), len(F)
    for k, a in mesh_arrays.items():
        a = np.asarray(a)
        if k == "F":
            out[k] = remap[F2]
        elif k == "V":
            out[k] = V[used]
        elif k == "FUV":
            out[k] = a[keepF]
        elif k in ("poly_counts", "poly_indices"):
            continue  # polygons are not kept through a cut of the triangulation
        elif a.ndim >= 1 and a.shape[0] == nV and k not in ("UV",):
            out[k] = a[used]
        elif a.ndim >= 1 and a.shape[0] == nF and k not in ("UV",):
            out[k] = a[keepF]
        else:
            out[k] = a
    if "UV" in out and "FUV" in out:
        usedt = np.zeros(len(out["UV"]), bool)
        usedt[out["FUV"].ravel()] = True
        rt = -np.ones(len(out["UV"]), dtype=np.int64)
        rt[usedt] = np.arange(usedt.sum())
        out["UV"] = out["UV"][usedt]
        out["FUV"] = rt[out["FUV"]]
    V2, F2n = out["V"], out["F"]
    H2 = meshtopo.boundary_halfedges(F2n)
    n_loops_out = meshtopo.boundary_component_count(F2n, H2)
    # region border vertices (old ids) per eye -> loops touching them
    eyes, metrics, moved, checks = {}, {}, {}, {}
    lim = eye_checks.limits_for(mesh.median_edge, st.radius_range_mm)
    old_ids = np.flatnonzero(used)
    for s in SIDES:
        fit = fits[s]
        border = np.zeros(len(V), bool)
        border[F[fit.region].ravel()] = True
        border &= used
        ids_new = set(remap[border].tolist())
        try:
            mine = meshtopo.boundary_loops(F2n, only=np.fromiter(ids_new, dtype=np.int64), H=H2)
        except ValueError as exc:
            raise ScanError(source, f"{s} eye: the cut left a non-simple boundary ({exc})") from None
        if len(mine) != 1:
            raise ScanError(source, f"{s} eye: the cut left {len(mine)} boundary loops at the eye "
                                    f"opening instead of one")
        loop = mine[0]
        if st.margin_lift_mm > 0 and fit.method == "geometry":
            moved[s] = _move_to_lift_off(V, F, V2, F2n, old_ids, loop, fit, st.margin_lift_mm,
                                         np.cos(np.radians(st.margin_max_turn_deg)),
                                         st.margin_on_eye_mm)
        try:
            loop, lat = order_loop(loop, V2, fit.center, fit.forward, s)
        except ValueError:      # eye_basis: a gaze straight up or down has no pitch axis
            raise ScanError(source, f"{s} eye: the fitted gaze {np.round(fit.forward, 3).tolist()} "
                                    f"is vertical; not an eye") from None
        checks[s] = eye_checks.check_eye(
            V, F, fit.center, fit.radius, fit.forward, V2[loop], lim, fit.residual_rms_mm,
            eye_points=V[np.unique(F[fit.region])] if fit.method == "geometry" else None,
            cornea=fit.cornea)
        eyes[s] = {
            "center": fit.center.tolist(), "radius": fit.radius, "forward": fit.forward.tolist(),
            "residual_rms_mm": fit.residual_rms_mm, "n_inliers": fit.n_inliers,
            "method": fit.method,
            "placement": "surface" if fit.method == "geometry" else fit.method,
            "checks": checks[s],
            "cornea": None if fit.cornea is None else {
                "center": np.asarray(fit.cornea["center"]).tolist(),
                "radius": fit.cornea["radius"], "n_inliers": fit.cornea["n_inliers"]},
            "loop_indices": loop.tolist(), "loop_points": V2[loop].tolist(),
            "lateral_canthus_index": lat,
        }
        metrics[s] = {"radius_mm": round(fit.radius, 4), "residual_rms_mm": round(fit.residual_rms_mm, 4),
                      "n_inliers": fit.n_inliers, "method": fit.method,
                      "faces_removed": int(fit.region.sum()), "loop_length": len(loop),
                      "crease_deg": round(fit.crease_deg, 3),
                      "cornea_fitted": fit.cornea is not None,
                      "loop_moved_mean_mm": round(moved.get(s, 0.0), 4)}
    pair = eye_checks.check_pair({s: fits[s].radius for s in SIDES}, lim)
    for s in SIDES:
        eyes[s]["checks"].update(pair)
        metrics[s]["placement"] = eyes[s]["placement"]
        metrics[s]["checks_failed"] = eye_checks.failed(eyes[s]["checks"])
        metrics[s].update({f"check_{k}": c["value"] for k, c in eyes[s]["checks"].items()})
    _refuse_unsure(eyes, source)
    if n_loops_out != loops_in - absorbed + 2:
        raise ScanError(source, f"cutting the eyeballs gave {n_loops_out} boundary loops, expected "
                                f"{loops_in} - {absorbed} holes in the openings + 2")
    metrics.update({"vertices_in": nV, "faces_in": nF, "vertices_out": int(len(V2)),
                    "faces_out": int(len(F2n)), "vertices_removed": int(nV - len(V2)),
                    "faces_removed": int(remove.sum()), "boundary_loops_in": loops_in,
                    "boundary_loops_out": n_loops_out, "holes_in_openings": absorbed,
                    "edge_manifold_out": meshtopo.is_edge_manifold(F2n)})
    return RemovalResult(mesh=out, eyes=eyes, fits=fits, metrics=metrics)
