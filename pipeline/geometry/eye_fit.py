"""Fit one scanned eyeball near its hint: the sphere, the corneal bulge, the removal region.

Method (per eye, see ``find_eye``; ``pipeline.geometry.remove_eyeballs`` runs it for both eyes,
cuts the regions out and checks the result):

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
   residuals keeping the eye region outside the sphere (``inside_fit_margin_mm``), iterated.
4. Two-sphere model: a corneal sphere is fitted to the remaining bulge if there is
   one; forward = centre -> corneal centre, else the normal of the cornea footprint,
   else centre -> opening centroid.
5. Removal region: faces whose vertices lie on the two-sphere eye surface (within
   ``cut_tol_mm`` outside, ``inside_tol_mm`` inside), connected to the hint; islands
   filled, notches/spikes/bow-ties cleaned so that its border is one simple loop.
   An open eye has a crease there (lid skin rises steeply off the eyeball); no crease
   means the eye is closed (or covered by the lids) and is refused.
6. Scans too coarse to show the eyeball geometrically (``james``) use the colour
   texture instead: faces near the hint whose colour differs from the surrounding
   skin form the opening; the sphere is fitted to that region with the radius prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.spherefit import radius_sigma, ransac_sphere, refine_sphere, signed_distance

if TYPE_CHECKING:
    from pipeline.geometry.remove_eyeballs import EyeSettings


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


def median_edge_length(V, F):
    e = V[F[:, [1, 2, 0]]] - V[F]
    return float(np.median(np.linalg.norm(e, axis=2)))


def local_mesh(V, F, hints, radius):
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


def _patch(mesh: EyeMesh, hint, radius):
    """Faces within ``radius`` of the hint, connected to the face nearest it: (m,) bool."""
    d = np.linalg.norm(mesh.centroids - hint, axis=1)
    near = d < radius
    if not near.any():
        return near
    labels = meshtopo.face_components(len(mesh.F), mesh.pairs, near)
    f0 = int(np.argmin(d))
    return near & (labels == labels[f0])


def _interior(mesh: EyeMesh, region, vids, margin_mm):
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


def _crease(mesh: EyeMesh, region, dist=None, radius_mm=2.0):
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


def _clean_region(mesh: EyeMesh, region, keep_seed, local=None, max_iter=30):
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


def _cornea_bulge(mesh: EyeMesh, patch_v, center, radius, forward, st: EyeSettings, rng):
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


def _central_cornea(mesh: EyeMesh, hint, st: EyeSettings, rng, radius_mm=5.0):
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


def _fit_geometry(mesh: EyeMesh, hint, side, st: EyeSettings, source, rng, fixed_radius=None,
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


def _fit_geometry_once(mesh: EyeMesh, hint, side, st: EyeSettings, source, rng, fixed_radius=None,
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


def find_eye(mesh: EyeMesh, hint, side, st: EyeSettings, *, source="mesh", mesh_arrays=None,
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
            # The fold is measured around the fitted sphere's cut: with too little sclera showing
            # (down-gaze, squint, a coarse scan) a wrong sphere gives a flat fold too, so an open
            # eye cannot be told from a closed one here; say both.
            geo_err = ScanError(source, f"{side} eye looks closed, or too little of the eyeball "
                                        f"shows to place it: no eyeball surface with a lid crease "
                                        f"around it near "
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
        from pipeline.geometry.eye_texture import fit_texture

        tfit = fit_texture(mesh, mesh_arrays, texture, hint, side, st, source, fixed_radius)
        return tfit
    raise geo_err
