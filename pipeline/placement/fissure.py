"""The palpebral fissure a colour texture shows, as an outline from canthus to canthus.

For scans too coarse to show the eyeball in their geometry (``james``: ~3 mm triangles), the
opening comes from the photograph. Seen along the face's normal at the eye:

1. :func:`eye_colour_map`: every texel within ``radius_mm`` of the hint scores how much more it
   looks like the eye than like the skin: the log-likelihood ratio of two Gaussian colour models
   (log brightness, red and blue chromaticity, full covariance), the skin's learnt from a ring
   beyond ``skin_from_mm``, the eye's from the texels near the hint that differ from the skin
   (robust z-score over ``min_contrast``: iris, sclera, the lash line). A shadowed white of the
   eye reads dark and a lit one white; either way it is the eye's colour, not the skin's.
2. :func:`fit_almond`: the opening as two lid curves meeting at the canthi (a chord from the
   medial to the lateral corner, each lid a bump over it, its height and the position of its
   peak free), placed where the soft inside of the outline gathers the most eye-like texels.
   A model rather than a threshold: the lash line, a shadow by the nose or a highlight on the
   lower lid cannot pull the corners away, and the corners are the lids' meeting points, not
   the end of a blob. :func:`fit_fissure`: where the ends of that almond show pink tissue (the
   caruncle, the lateral fornix: unlike the sclera and iris the eye's colour was learnt from,
   and redder than any skin), the almond is fitted again with it as eye-like, so the corners
   are the far ends of the caruncle and the fornix, where the lids meet.
3. :func:`lift`: outline points onto the scan surface, along the viewing direction.

The iris (:func:`iris_centre`) is the darkest iris-sized disc inside the outline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.geometry.frame import eye_basis

#: Radius of the visible iris, mm (white-to-white 11.7 mm): the disc searched for the iris centre.
IRIS_RADIUS_MM = 5.85
#: Lower over upper lid height above the canthal line (UnityEyes' mean margin, 3.7 / 6.2 mm), the
#: spread allowed (in log) and the prior's weight (mm^2 of fully eye-like texels per unit z^2).
LID_RATIO, LID_RATIO_SIGMA, LID_PRIOR_WEIGHT = 0.6, 0.5, 5.0
#: Palpebral fissure width of adults (mean, SD, mm; issue 21's population figures) and the weight
#: of that prior (mm^2 of fully eye-like texels per unit z^2).
FISSURE_WIDTH_MM, FISSURE_WIDTH_SIGMA_MM, WIDTH_PRIOR_WEIGHT = 27.0, 1.7, 1.0


@dataclass
class ColourMap:
    """Eye-likeness of the surface around a hint, on a grid across the viewing direction.

    Attributes
    ----------
    llr : (n, n) float64
        Mean log-likelihood ratio (eye over skin) per cell, clipped; NaN where no texel falls.
    lum : (n, n) float64
        Mean brightness per cell (0..255); NaN where empty.
    hint, view : (3,) float64
        Grid centre and the unit viewing direction (out of the face).
    basis : (2, 3) float64
        In-plane axes of the grid (x toward head +X, y up).
    cell_mm, radius_mm : float
        Cell side; the grid spans [-radius, radius] on both axes.
    q, X : (k, 2), (k, 3) float64
        The texels' plane coordinates and colour features (log brightness, red and blue
        chromaticity), kept to learn the eye's colour again (:func:`relearn`).
    ring : (k,) bool
        The texels the skin's colour is learnt from.
    """

    llr: np.ndarray
    lum: np.ndarray
    hint: np.ndarray
    view: np.ndarray
    basis: np.ndarray
    cell_mm: float
    radius_mm: float
    q: np.ndarray = None
    X: np.ndarray = None
    ring: np.ndarray = None
    clip: float = 6.0

    def centres(self):
        """(n, n, 2) plane coordinates of the cell centres, mm (row = y index, col = x index)."""
        n = self.llr.shape[0]
        t = (np.arange(n) + 0.5) * self.cell_mm - self.radius_mm
        X, Y = np.meshgrid(t, t)
        return np.stack([X, Y], axis=-1)


def _gauss_loglik(X, sel, ridge=1e-4):
    mu = X[sel].mean(axis=0)
    C = np.cov(X[sel].T) + ridge * np.eye(X.shape[1])
    d = X - mu
    return -0.5 * np.einsum("ij,jk,ik->i", d, np.linalg.inv(C), d) - 0.5 * np.log(np.linalg.det(C))


def eye_colour_map(V, F, UV, FUV, texture, hint, view, *, radius_mm=22.0, skin_from_mm=18.0,
                   core_mm=6.0, cell_mm=0.25, min_contrast=3.0, clip=6.0) -> ColourMap | None:
    """The eye-likeness map around ``hint`` (module doc, step 1); None when the texture shows too
    little skin or too little eye to learn both colours."""
    from pipeline.placement.texels import colour_z, surface_texels

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    hint = np.asarray(hint, np.float64)
    view = np.asarray(view, np.float64) / np.linalg.norm(view)
    B = eye_basis(view)[:2]
    faces = np.flatnonzero(np.linalg.norm(V[F].mean(axis=1) - hint, axis=1) < radius_mm + 3.0)
    faces = faces[(np.cross(V[F[faces, 1]] - V[F[faces, 0]], V[F[faces, 2]] - V[F[faces, 0]]) @ view) > 0]
    P, col = surface_texels(V, F, UV, FUV, texture, faces, step_mm=cell_mm / 2.0)
    q = (P - hint) @ B.T
    r = np.linalg.norm(q, axis=1)
    keep = r < radius_mm
    q, col, r = q[keep], col[keep], r[keep]
    ring = r > skin_from_mm
    core = (colour_z(col, ring) > min_contrast) & (r < core_mm) if ring.sum() >= 50 else ring & False
    if ring.sum() < 50 or core.sum() < 50:
        return None
    lum = col.mean(axis=1)
    chroma = col / np.maximum(col.sum(axis=1, keepdims=True), 1.0)
    X = np.column_stack([np.log(lum + 5.0), chroma[:, 0], chroma[:, 2]])
    n = int(np.ceil(2.0 * radius_mm / cell_mm))
    ij = np.clip(((q + radius_mm) / cell_mm).astype(np.int64), 0, n - 1)
    cnt = np.zeros((n, n))
    lacc = np.zeros((n, n))
    np.add.at(cnt, (ij[:, 1], ij[:, 0]), 1.0)
    np.add.at(lacc, (ij[:, 1], ij[:, 0]), lum)
    with np.errstate(invalid="ignore", divide="ignore"):
        cmap = ColourMap(llr=np.zeros((n, n)), lum=np.where(cnt > 0, lacc / cnt, np.nan), hint=hint,
                         view=view, basis=B, cell_mm=float(cell_mm), radius_mm=float(radius_mm),
                         q=q, X=X, ring=ring, clip=float(clip))
    return relearn(cmap, core)


def relearn(cmap: ColourMap, eye, pocket=None) -> ColourMap:
    """The map with the eye's colour learnt from the texels ``eye`` ((k,) bool, or an outline
    (p, 2) whose inside they are), the skin's from the ring as before. ``pocket`` ((k,) bool,
    optional): the texels of a second eye colour (the corners' pink tissue, :func:`corner_tissue`);
    a texel then is as eye-like as the likelier of the two."""
    eye = np.asarray(eye)
    if eye.dtype != bool:
        eye = points_in_polygon(cmap.q, eye) & ~cmap.ring
    ll_eye = _gauss_loglik(cmap.X, eye)
    if pocket is not None:
        ll_eye = np.maximum(ll_eye, _gauss_loglik(cmap.X, pocket))
    llr = np.clip(ll_eye - _gauss_loglik(cmap.X, cmap.ring), -cmap.clip, cmap.clip)
    n = cmap.llr.shape[0]
    ij = np.clip(((cmap.q + cmap.radius_mm) / cmap.cell_mm).astype(np.int64), 0, n - 1)
    cnt = np.zeros((n, n))
    acc = np.zeros((n, n))
    np.add.at(cnt, (ij[:, 1], ij[:, 0]), 1.0)
    np.add.at(acc, (ij[:, 1], ij[:, 0]), llr)
    with np.errstate(invalid="ignore", divide="ignore"):
        cmap.llr = np.where(cnt > 0, acc / cnt, np.nan)
    return cmap


# ------------------------------------------------------------------------------------ almond

def _bump(s, peak, sharp=1.0):
    """Lid height profile over the chord, 0 at both canthi, 1 at ``peak`` (s, peak in (0, 1));
    ``sharp`` < 1 rounds the corners off (the lid leaves the canthus steeply), > 1 sharpens them."""
    s = np.clip(s, 0.0, 1.0)
    a, b = 2.0 * peak * sharp, 2.0 * (1.0 - peak) * sharp
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num((s / peak) ** a * ((1.0 - s) / (1.0 - peak)) ** b)


def _unpack(theta):
    m, l = theta[0:2], theta[2:4]
    hu, hl = np.abs(theta[4]), np.abs(theta[5])
    pu, pl = np.clip(theta[6], 0.2, 0.8), np.clip(theta[7], 0.2, 0.8)
    k = float(np.clip(theta[8], 0.3, 1.5)) if len(theta) > 8 else 1.0
    return m, l, hu, hl, pu, pl, k


def almond_points(theta, n=128):
    """Outline (n, 2) of almond parameters: medial canthus first, over the upper lid to the lateral
    canthus at index ``n // 2``, back along the lower lid (plane coordinates, mm)."""
    m, l, hu, hl, pu, pl, sharp = _unpack(theta)
    d = l - m
    nrm = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-9)
    if nrm[1] < 0:
        nrm = -nrm                                    # the upper lid is up
    k = n // 2
    su = np.linspace(0.0, 1.0, k + 1)
    sl = np.linspace(1.0, 0.0, n - k + 1)[1:-1]
    up = m + su[:, None] * d + (hu * _bump(su, pu, sharp))[:, None] * nrm
    lo = m + sl[:, None] * d - (hl * _bump(sl, pl, sharp))[:, None] * nrm
    return np.concatenate([up, lo])


def _soft_inside(theta, qx, qy, tau):
    """(k,) soft indicator of the cells ``(qx, qy)`` (each (k,), contiguous) inside the almond
    ``theta``: four logistic edges of width ``tau`` (the two lids and the two ends of the chord).

    The fit's cost, about 2,000 calls a fissure: both lids' :func:`_bump` from one log of the
    chord position and of its rest (an exponential each, where ``_bump``'s two powers take a log
    and an exponential each), and the four edges through one ``tanh`` over a (4, k) block. The
    same values as ``_bump`` and four separate edges to 1e-13; the almonds fitted with them agree
    to 1e-8 mm on ``james``, and on the textured-only heads but one eye (seed 20's left: its
    canthi 0.05 mm on, Powell's path parted)."""
    m, l, hu, hl, pu, pl, sharp = _unpack(theta)
    d = l - m
    L2 = max(float(d @ d), 1e-9)
    nrm = np.array([-d[1], d[0]]) / np.sqrt(L2)
    if nrm[1] < 0:
        nrm = -nrm
    dx, dy = qx - m[0], qy - m[1]
    s = (dx * d[0] + dy * d[1]) / L2
    t = dx * nrm[0] + dy * nrm[1]
    span = np.sqrt(L2)
    # _bump is 0 outside the open chord (a power of 0 there): log 0 = -inf gives exp(-inf) = 0
    inner = (s > 0.0) & (s < 1.0)
    ls, l1 = np.full(len(s), -np.inf), np.full(len(s), -np.inf)
    ls[inner] = np.log(s[inner])
    l1[inner] = np.log1p(-s[inner])

    def bump(peak):
        a, b = 2.0 * peak * sharp, 2.0 * (1.0 - peak) * sharp
        return np.exp(a * (ls - np.log(peak)) + b * (l1 - np.log1p(-peak)))

    X = np.empty((4, len(s)))
    X[0] = hu * bump(pu) - t
    X[1] = t + hl * bump(pl)
    X[2] = s * span
    X[3] = (1.0 - s) * span
    X *= 0.5 / tau
    np.tanh(X, out=X)           # sig(x / tau) = (1 + tanh(x / (2 tau))) / 2, each edge
    X += 1.0
    X *= 0.5
    return X[0] * X[1] * X[2] * X[3]


def fit_almond(cmap: ColourMap, lateral_sign: float, init_half_width=None, start=None):
    """The almond (module doc, step 2) fitted to the map.

    Parameters
    ----------
    cmap : ColourMap
    lateral_sign : float
        +1 when the lateral side is toward +x of the map (the subject's left eye), -1 otherwise.
    init_half_width : float, optional
        Start half-width, mm (default: the extent of the eye-like region through the hint).
    start : (9,) float64, optional
        An almond to start from instead (a first fit's, :func:`fit_fissure`).

    Returns
    -------
    theta : (8,) float64
        Medial canthus (2), lateral canthus (2), upper and lower lid heights, their peak positions.
    score : float
    """
    from scipy import ndimage
    from scipy.optimize import minimize

    C = cmap.centres()
    ok = np.isfinite(cmap.llr)
    Q, w = C[ok], cmap.llr[ok]
    qx, qy = np.ascontiguousarray(Q[:, 0]), np.ascontiguousarray(Q[:, 1])
    # start: the eye-like region connected to the hint
    grid = np.where(ok, cmap.llr, -1.0) > 0.0
    grid = ndimage.binary_opening(grid, iterations=2)
    lab, _ = ndimage.label(grid)
    h = cmap.llr.shape[0] // 2
    near = lab[h - 4:h + 5, h - 4:h + 5]
    if (near > 0).any():
        comp = lab == np.bincount(near[near > 0]).argmax()
        P = C[comp]
        x0, x1 = np.percentile(P[:, 0], [2, 98])
        yc = float(np.median(P[:, 1]))
        hu0 = max(np.percentile(P[:, 1], 95) - yc, 2.0)
        hl0 = max(yc - np.percentile(P[:, 1], 5), 2.0)
    else:
        x0, x1, yc, hu0, hl0 = -12.0, 12.0, 0.0, 4.0, 4.0
    if init_half_width is not None:
        xm = 0.5 * (x0 + x1)
        x0, x1 = xm - init_half_width, xm + init_half_width
    med, lat = (x0, x1) if lateral_sign > 0 else (x1, x0)
    theta0 = np.array([med, yc, lat, yc, hu0, hl0, 0.5, 0.5, 1.0]) if start is None \
        else np.asarray(start, float)
    wm, ws = FISSURE_WIDTH_MM, FISSURE_WIDTH_SIGMA_MM
    tau = 1.5 * cmap.cell_mm
    cell_area = cmap.cell_mm ** 2

    def cost(th):
        # the lower lid rises about 0.6 as far from the canthal line as the upper lid (UnityEyes'
        # mean margin: 3.7 and 6.2 mm), a weak prior against a lid flattened onto the chord
        z = (np.log(max(abs(th[5]), 1e-3) / max(abs(th[4]), 1e-3)) - np.log(LID_RATIO)) / LID_RATIO_SIGMA
        # and the fissure is 27 +- 1.7 mm wide in adults: where the texture cannot tell the corner
        # (a canthus in shadow under the lashes), the population decides
        zw = (np.linalg.norm(th[2:4] - th[0:2]) - wm) / ws
        return (-float(np.sum(_soft_inside(th, qx, qy, tau) * w)) * cell_area
                + LID_PRIOR_WEIGHT * z * z + WIDTH_PRIOR_WEIGHT * zw * zw)

    best = None
    for t0 in (theta0, theta0 * np.array([1, 1, 1, 1, 0.7, 0.7, 1, 1, 0.6])):
        res = minimize(cost, t0, method="Powell", options={"xtol": 1e-2, "ftol": 1e-4, "maxfev": 4000})
        if best is None or res.fun < best.fun:
            best = res
    return best.x, -float(best.fun)


#: How far past each fitted corner, along the canthal line, the corners' tissue is looked for
#: (mm; the caruncle is 3-5 mm long), how far off that line (mm), and how little of it (mm^2 of
#: surface; a procedural caruncle shows 20-40) is no tissue to learn a colour from.
POCKET_REACH_MM, POCKET_OFF_LINE_MM, POCKET_MIN_AREA_MM2 = 6.0, 3.5, 2.0
#: How much redder than the skin (robust SDs of the ring's red chromaticity) the corners' tissue
#: is: the ring's own 99th percentile lies at 2-2.3, and on ``james`` the lid and nasal skin past
#: the first almond's corners reaches 3-4.5 (at most 0.8 mm^2 of it over 5); the procedural
#: caruncle and fornix read 7.5-8.5. On a dark skin that tissue is as red as the skin but
#: brighter: by 4.2-4.5 robust SDs of the ring's log brightness (floor 0.1) on the procedural dark
#: head; no texel by ``james``'s corners is brighter than its skin by more than 1.2.
POCKET_MIN_Z, POCKET_MIN_BRIGHT_Z = 5.0, 3.0


def _robust_z(values, ring, floor):
    mu = np.median(values[ring])
    return (values - mu) / (1.4826 * np.median(np.abs(values[ring] - mu)) + floor)


def corner_tissue(cmap: ColourMap, theta, min_z=POCKET_MIN_Z, min_bright_z=POCKET_MIN_BRIGHT_Z):
    """(k,) bool: the texels of the pink tissue in the fissure's corners (the caruncle medially,
    the fornix laterally) near the corners of a first almond ``theta``: redder than the skin (red
    chromaticity over ``min_z`` robust SDs above the ring's) or brighter (log brightness over
    ``min_bright_z``), and not inside that almond.

    The eye's colour is learnt from the sclera and iris at the hint, which the caruncle is not
    like; the skin's from the ring, which it is not like either, so the first almond ends at the
    caruncle's lateral edge, 3-5 mm short of the medial canthus (the far end of the caruncle,
    where the lids meet). Redness or brightness tells that tissue from the lash line and the
    shadows by the nose: they are darker than the skin, with its chromaticity."""
    m, l = np.asarray(theta[0:2], float), np.asarray(theta[2:4], float)
    d = l - m
    L = max(float(np.linalg.norm(d)), 1e-9)
    u = d / L
    s = (cmap.q - m) @ u / L
    off = np.abs((cmap.q - m) @ np.array([-u[1], u[0]]))
    reach = POCKET_REACH_MM / L
    ends = (((s > -reach) & (s < 0.3)) | ((s > 0.85) & (s < 1.0 + reach))) & (off < POCKET_OFF_LINE_MM)
    unlike = ((_robust_z(cmap.X[:, 1], cmap.ring, 0.005) > min_z)
              | (_robust_z(cmap.X[:, 0], cmap.ring, 0.1) > min_bright_z))
    inside = points_in_polygon(cmap.q, almond_points(theta, 128))
    return ends & unlike & ~inside & ~cmap.ring


def _skin_z(cmap: ColourMap):
    """(k,) robust z-score of each texel's colour features from the ring's (the skin), as
    :func:`pipeline.placement.texels.colour_z` on the map's log brightness (floor 0.1: a tenth
    brighter or darker) and red and blue chromaticity (floor 0.005)."""
    mu = np.median(cmap.X[cmap.ring], axis=0)
    mad = 1.4826 * np.median(np.abs(cmap.X[cmap.ring] - mu), axis=0) + np.array([0.1, 0.005, 0.005])
    return np.sqrt((((cmap.X - mu) / mad) ** 2).sum(axis=1))


def fit_fissure(cmap: ColourMap, lateral_sign: float, min_contrast=3.0):
    """The almond (:func:`fit_almond`); where its ends show the corners' pink tissue
    (:func:`corner_tissue`, at least ``POCKET_MIN_AREA_MM2`` of it), fitted again from there with
    the eye's colours learnt anew: from the texels inside the first almond that differ from the
    skin by ``min_contrast`` (the sclera as well as the iris the hint sits on) and from that
    tissue, so the outline runs on through the caruncle to the canthi. Returns ``(theta,
    score)``.

    Without such tissue the first almond stands: on ``james`` (no corner redder than its skin by
    ``POCKET_MIN_Z``) learning the eye anew from inside its first almond, lashes and the shadow by
    the nose included, moved the right eye's medial corner 1.5 mm on past its annotation."""
    theta, score = fit_almond(cmap, lateral_sign)
    pocket = corner_tissue(cmap, theta)
    # the map's texels sample the surface every half cell (surface_texels' step)
    if pocket.sum() * (0.5 * cmap.cell_mm) ** 2 < POCKET_MIN_AREA_MM2:
        return theta, score
    eye = points_in_polygon(cmap.q, almond_points(theta, 128)) & ~cmap.ring & (_skin_z(cmap) > min_contrast)
    if eye.sum() < 50:
        return theta, score
    saved = cmap.llr
    relearn(cmap, eye, pocket)
    try:
        return fit_almond(cmap, lateral_sign, start=theta)
    finally:
        cmap.llr = saved        # the caller's map stays the first one


def iris_centre(cmap: ColourMap, outline, radius_mm=IRIS_RADIUS_MM):
    """(2,) plane coordinates of the darkest iris-sized disc whose centre lies inside the outline,
    or None when the outline holds no measured texel."""
    from scipy import ndimage

    C = cmap.centres()
    inside = points_in_polygon(C.reshape(-1, 2), outline).reshape(C.shape[:2])
    lum = cmap.lum
    ok = np.isfinite(lum) & inside
    if not ok.any():
        return None
    k = max(1, int(round(radius_mm / cmap.cell_mm)))
    yy, xx = np.mgrid[-k:k + 1, -k:k + 1]
    disc = ((xx ** 2 + yy ** 2) <= k * k).astype(np.float64)
    num = ndimage.convolve(np.where(ok, lum, 0.0), disc, mode="constant")
    den = ndimage.convolve(ok.astype(np.float64), disc, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(den > 0.3 * disc.sum(), num / den, np.inf)
    mean[~inside] = np.inf
    j = np.unravel_index(np.argmin(mean), mean.shape)
    return C[j] if np.isfinite(mean[j]) else None


def points_in_polygon(Q, poly):
    """(k,) bool: which points (k, 2) lie inside the closed polygon (p, 2) (even-odd rule)."""
    Q = np.asarray(Q, np.float64)
    P = np.asarray(poly, np.float64)
    x, y = Q[:, 0], Q[:, 1]
    inside = np.zeros(len(Q), bool)
    for a, b in zip(P, np.roll(P, -1, axis=0)):
        cross = (a[1] > y) != (b[1] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0]
        inside ^= cross & (x < xc)
    return inside


def lift(V, F, Q, hint, view, basis, max_depth_mm=40.0):
    """Points on the surface seen at plane coordinates ``Q`` (k, 2) along ``view``: the front-most
    crossing of the line ``hint + Q @ basis + t view`` with a face turned toward ``view``.

    Returns
    -------
    (k, 3) float64, NaN rows where the line meets no such face within ``max_depth_mm``.
    """
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    Q = np.asarray(Q, np.float64)
    hint = np.asarray(hint, np.float64)
    T = V[F]
    N = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    front = (N @ view) > 0
    q3 = (T - hint) @ basis.T                         # (m, 3, 2) in-plane corners
    depth = (T - hint) @ view                         # (m, 3)
    lo, hi = q3.min(axis=1), q3.max(axis=1)
    out = np.full((len(Q), 3), np.nan)
    for k, p in enumerate(Q):
        cand = np.flatnonzero(front & (lo[:, 0] <= p[0]) & (hi[:, 0] >= p[0])
                              & (lo[:, 1] <= p[1]) & (hi[:, 1] >= p[1])
                              & (np.abs(depth).min(axis=1) < max_depth_mm))
        best = -np.inf
        for f in cand:
            a, b, c = q3[f]
            M = np.array([b - a, c - a]).T
            det = np.linalg.det(M)
            if abs(det) < 1e-12:
                continue
            u, v = np.linalg.solve(M, p - a)
            if u < -1e-9 or v < -1e-9 or u + v > 1 + 1e-9:
                continue
            z = depth[f, 0] + u * (depth[f, 1] - depth[f, 0]) + v * (depth[f, 2] - depth[f, 0])
            if z > best:
                best = z
                out[k] = hint + p @ basis + z * view
    return out
