"""Place both eyes of a head from every cue the scan keeps: a MAP fit of an eye model.

The eye model (per eye): a sclera sphere (centre ``c``, radius ``R``) and, around the gaze
``n``, an anterior cap: a sphere through the limbus circle (half-angle ``tl`` off the axis, so
the limbus scales with the globe: 29 +- 1.5 deg in people, 27-33 in ICT-FaceKit's eyes) and an
apex ``ha * APEX_FRACTION * R`` above the sclera, plus a ring ``hb`` that stands highest half-way
between axis and limbus. ``ha`` = 1 is a scanned cornea (the human apex stands 1.0 mm above a
12 mm sclera), < 0 a recessed iris; the iris seen through a transparent cornea is a low ring
(``ha`` ~ 0.1-0.3, ``hb`` ~ 0.3-0.5: the pupil lies deeper than the iris around it). Without
the ring, that shape biased the radius by about 1 mm.

Cues and how they enter (each one optional; none is required):

* the visible sclera and the anterior cap: Gaussian residuals to the model surface of the
  vertices labelled *eye* (``SIG_SCLERA`` / ``SIG_ANTERIOR``);
* the skin around the opening: every vertex labelled *skin* must lie outside the globe
  (one-sided residual beyond ``TAU_INSIDE``), and the eye/skin labels come from a minimum
  graph cut whose edges are cheap along concave creases (the lid fold around the opening), so
  the opening's border follows the fold;
* the eye-region prior (``eye_prior``, the UnityEyes shape model registered to the skin
  around the eye, when its data are present): where the front of the globe lies;
* the two eyes together: one radius (inverse-variance mean of agreeing fits, refitted), and
  a loose mirror prior on the centres about the face's midplane;
* a broad population prior on ``R`` (``radius_prior_mm``).

Search: sphere hypotheses from pairs of oriented vertices near the hint (and along the prior's
axis), ranked by the graph-cut energy; the best few are refined by alternating the cut and a
robust least-squares fit of ``(c, R, n, ha, tl)`` (EM). The best of them is refitted again from
gazes turned up to 45 deg away (:func:`gaze_restarts`; the least squares does not cross from
the eye region's forward to a gaze turned in, out or down), and the two lowest are polished. The uncertainty is the Laplace
approximation of the final fit, widened by the other local optima weighted by their energy
(``temperature``), times a calibration factor measured on unseen heads (benchmarks).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pipeline.geometry.spherefit import sphere_from_normals

SIDES = ("left", "right")
SIG_SCLERA = 0.15       # mm: scanner noise on the exposed sclera
SIG_ANTERIOR = 0.15     # mm: as the sclera; a looser cap made a small sphere through the cornea
                        # (every vertex at the tighter scale) likelier than the true globe
TAU_INSIDE = 0.35       # mm: skin may lie this far inside the globe (noise) before it is impossible
SKIN_SPREAD_MM = 10.0   # skin near the eye: anywhere within this of the globe, uniform
APEX_FRACTION = 0.1     # corneal apex above the sclera sphere, in units of R (people 0.08, ICT 0.13)
HA_RANGE = (-1.0, 1.6)  # anterior height: recessed iris .. a prominent cornea
HB_RANGE = (-1.0, 1.6)  # anterior ring: the iris seen through a clear cornea stands highest off the axis
HB_SIGMA = 1.0          # weak prior on the ring (0 = a plain cap)
REFINE_ITERS = 3
POLISH_KEEP, POLISH_ITERS = 2, 4   # the best local optima refined further (polish)
RESTARTS_KEEP = 4                  # turned gazes refined in full after one round each
NP = 8                  # parameters per eye besides the radius: c (3), gaze (2), ha, tl, hb
LIMBUS_DEG = (30.5, 2.0)        # prior on the limbus half-angle, deg (people 29 +- 1.5, ICT 30-34)
LIMBUS_RANGE = (24.0, 37.0)
CUT_LAMBDA = 2.0        # graph-cut cost per mm of an eye/skin border on smooth skin
CREASE_DEG = 8.0        # ... falling by e per this many degrees of concave fold


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass
class Patch:
    """The surface around one hint, with what the energy needs.

    Attributes
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    A : (n,) float64
        Vertex areas (mm^2; zero for vertices only on ``ignore`` faces).
    N : (n, 3) float64
        Unit vertex normals.
    E : (k, 2) int64
        Interior edges.
    w : (k,) float64
        Cut cost of each edge (cheap along concave folds).
    hint : (3,) float64
    verts : (n,) int64
        Vertex ids in the mesh the patch was cut from.
    faces : (m,) int64
        Face ids in that mesh.
    """

    V: np.ndarray
    F: np.ndarray
    A: np.ndarray
    N: np.ndarray
    E: np.ndarray
    w: np.ndarray
    hint: np.ndarray
    verts: np.ndarray
    faces: np.ndarray


def build_patch(V, F, hint, radius_mm, ignore=None) -> Patch:
    """Faces with centroid within ``radius_mm`` of ``hint``; ``ignore`` (m,) bool marks faces
    that carry no evidence (a scanner's flat fill across an opening): their vertices get no
    area unless a measured face shares them."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    hint = np.asarray(hint, dtype=np.float64)
    faces = np.flatnonzero(np.linalg.norm(V[F].mean(axis=1) - hint, axis=1) < radius_mm)
    verts, Fs = np.unique(F[faces], return_inverse=True)
    Fs = Fs.reshape(-1, 3).astype(np.int64)
    P = V[verts]
    FN = np.cross(P[Fs[:, 1]] - P[Fs[:, 0]], P[Fs[:, 2]] - P[Fs[:, 0]])
    fa = 0.5 * np.linalg.norm(FN, axis=1)
    ign = np.zeros(len(Fs), bool) if ignore is None else np.asarray(ignore, bool)[faces]
    A = np.zeros(len(P))
    np.add.at(A, Fs[~ign].ravel(), np.repeat(fa[~ign] / 3.0, 3))
    VN = np.zeros_like(P)
    for k in range(3):
        np.add.at(VN, Fs[:, k], FN)
    VN = VN / np.maximum(np.linalg.norm(VN, axis=1, keepdims=True), 1e-300)
    fu = FN / np.maximum(2.0 * fa, 1e-300)[:, None]
    # interior edges with their two faces; concave when the far vertex of one face lies above
    # the other's plane (the lid rising off the eye)
    Ed = np.concatenate([Fs[:, [0, 1]], Fs[:, [1, 2]], Fs[:, [2, 0]]])
    opp = np.concatenate([Fs[:, 2], Fs[:, 0], Fs[:, 1]])
    fid = np.tile(np.arange(len(Fs)), 3)
    key = np.sort(Ed, axis=1)
    k1 = key[:, 0] * len(P) + key[:, 1]
    order = np.argsort(k1, kind="stable")
    same = np.flatnonzero(k1[order][1:] == k1[order][:-1])
    a, b = order[same], order[same + 1]
    E = key[a]
    h = ((P[opp[b]] - P[E[:, 0]]) * fu[fid[a]]).sum(axis=1)
    fold = np.degrees(np.arccos(np.clip((fu[fid[a]] * fu[fid[b]]).sum(axis=1), -1.0, 1.0)))
    concave = np.where(h > 0, fold, 0.0)
    L = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1)
    w = CUT_LAMBDA * L * np.exp(-concave / CREASE_DEG)
    return Patch(P, Fs, A, VN, E, w, hint, verts, faces)


@dataclass
class Eye:
    """One eye of the model: centre (3,), radius, unit gaze (3,), anterior height."""

    c: np.ndarray
    R: float
    n: np.ndarray
    ha: float = 0.5
    tl: float = LIMBUS_DEG[0]
    hb: float = 0.0


def _cap(R, ha, tl):
    """The anterior cap's sphere: centre offset along the axis and radius (mm)."""
    a = np.radians(tl)
    rl, zl = R * np.sin(a), R * np.cos(a)
    apex = R * (1.0 + APEX_FRACTION * ha)
    # centre on the axis at z0: (apex - z0)^2 = rl^2 + (zl - z0)^2
    z0 = (apex ** 2 - rl ** 2 - zl ** 2) / (2.0 * (apex - zl))
    return z0, apex - z0


def cap_height(cos_alpha, R, ha, tl, hb=0.0):
    """Height (mm) of the anterior cap above the sclera sphere along the rays at ``cos_alpha``
    from the axis (0 outside the limbus; negative for a recessed iris), (n,): the sphere
    through the limbus circle and the apex, plus a ring ``hb * APEX_FRACTION * R * 4 s^2
    (1 - s^2)`` (``s`` = angle / ``tl``) peaking half-way out: the iris seen through a clear
    cornea stands off the sclera most between pupil and limbus."""
    ca = np.clip(cos_alpha, -1.0, 1.0)
    z0, r = _cap(R, ha, tl)
    t = z0 * ca + np.sqrt(np.maximum(r * r - z0 * z0 * (1.0 - ca * ca), 0.0))
    s2 = (np.arccos(ca) / np.radians(tl)) ** 2
    ring = hb * APEX_FRACTION * R * 4.0 * s2 * (1.0 - s2)
    return np.where(ca > np.cos(np.radians(tl)), t - R + ring, 0.0)


def cornea_sphere(e: Eye):
    """The anterior cap as a sphere for the rest of the pipeline, or None when it is flat or
    recessed (the sclera sphere is then the whole eye surface)."""
    if e.ha <= 0.05:
        return None
    z0, r = _cap(e.R, e.ha, e.tl)
    return {"center": np.asarray(e.c) + z0 * np.asarray(e.n), "radius": float(r)}


def surface_residual(P, e: Eye):
    """Signed distance (mm) of ``P`` (n, 3) off the eye model, whether each point lies on the
    anterior cap (inside the limbus), the plain distance off the sclera sphere, and unit
    directions from the centre."""
    w = P - e.c
    nw = np.maximum(np.linalg.norm(w, axis=1), 1e-9)
    ca = (w @ e.n) / nw
    h = cap_height(ca, e.R, e.ha, e.tl, e.hb)
    ant = ca > np.cos(np.radians(e.tl))
    return nw - e.R - h, ant, nw - e.R, w / nw[:, None]


def unary_costs(p: Patch, e: Eye):
    """Area-weighted negative log-likelihoods of each vertex as eye and as skin, (n,), (n,)."""
    d, ant, dsph, u = surface_residual(p.V, e)
    sig = np.where(ant, SIG_ANTERIOR, SIG_SCLERA)
    eye = 0.5 * (d / sig) ** 2 + np.log(sig * np.sqrt(2.0 * np.pi))
    eye = np.where((u * p.N).sum(axis=1) > 0.5, np.minimum(eye, 30.0), 30.0)   # eye faces outward
    skin = np.log(SKIN_SPREAD_MM) + np.where(dsph < -TAU_INSIDE,
                                             0.5 * ((dsph + TAU_INSIDE) / SIG_SCLERA) ** 2, 0.0)
    return p.A * eye, p.A * skin


def graph_cut(p: Patch, ce, ck):
    """Minimum cut of the eye/skin labelling: (n,) bool, True = eye."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    n = len(p.V)
    S, T = n, n + 1
    m = np.minimum(ce, ck)
    rows = np.concatenate([p.E[:, 0], p.E[:, 1], np.full(n, S), np.arange(n)])
    cols = np.concatenate([p.E[:, 1], p.E[:, 0], np.arange(n), np.full(n, T)])
    caps = np.concatenate([p.w, p.w, ck - m, ce - m])      # s->i: cost of skin; i->t: of eye
    caps = np.minimum(np.round(caps * 1000.0), 2 ** 30).astype(np.int32)
    G = csr_matrix((caps, (rows, cols)), shape=(n + 2, n + 2))
    flow = maximum_flow(G, S, T).flow
    res = (G - flow).tocsr()
    res.data = (res.data > 0).astype(np.int8)
    res.eliminate_zeros()
    lab = np.zeros(n + 2, bool)
    lab[breadth_first_order(res, S, directed=True, return_predecessors=False)] = True
    return lab[:n]


def eye_components(p: Patch, lab, e: Eye, max_angle_deg=70.0):
    """The eye-labelled components of this eye: the one nearest the front of the globe, and
    every other wholly within ``max_angle_deg`` of the axis (sclera beyond the limbus, split
    off by the cap's rim)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    if not lab.any():
        return lab
    ok = lab[p.E[:, 0]] & lab[p.E[:, 1]]
    G = csr_matrix((np.ones(int(ok.sum())), (p.E[ok, 0], p.E[ok, 1])), shape=(len(p.V),) * 2)
    _, comp = connected_components(G, directed=False)
    ids = np.flatnonzero(lab)
    w = p.V[ids] - e.c
    cosa = (w @ e.n) / np.linalg.norm(w, axis=1)
    front = e.c + e.R * e.n
    keep = {int(comp[ids[np.argmin(np.linalg.norm(p.V[ids] - front, axis=1))]])}
    mins = {}
    for k, ca in zip(comp[ids], cosa):
        mins[k] = min(mins.get(k, 1.0), ca)
    keep |= {int(k) for k, v in mins.items() if v > np.cos(np.radians(max_angle_deg))
             and np.count_nonzero(comp[ids] == k) >= 2}
    return lab & np.isin(comp, sorted(keep))


def segment(p: Patch, e: Eye):
    """The eye/skin labelling of ``p`` under ``e`` and its energy (unaries + cut)."""
    ce, ck = unary_costs(p, e)
    lab = eye_components(p, graph_cut(p, ce, ck), e)
    cut = lab[p.E[:, 0]] != lab[p.E[:, 1]]
    return lab, float(ce[lab].sum() + ck[~lab].sum() + p.w[cut].sum())


# ----------------------------------------------------------------------------- fitting
def _angles(n):
    return np.array([np.arccos(np.clip(n[2], -1.0, 1.0)), np.arctan2(n[1], n[0])])


def _vec(a):
    return np.array([np.sin(a[0]) * np.cos(a[1]), np.sin(a[0]) * np.sin(a[1]), np.cos(a[0])])


def mirror(c, xm):
    """``c`` reflected in the plane x = ``xm``."""
    c = np.array(c, dtype=np.float64)
    c[..., 0] = 2.0 * xm - c[..., 0]
    return c


@dataclass
class Cues:
    """Fixed inputs of one eye's least squares besides its patch and labels."""

    front: np.ndarray | None = None     # eye-region prior: front of the globe (3,)
    axis: np.ndarray | None = None      # ... along this unit axis
    front_sigma: float = 4.0
    radius_prior: tuple = (12.0, 3.0)


def _blocks(p: Patch, lab, e: Eye, cues: Cues, anterior=None):
    """Residual blocks (name -> array) of one eye; ``anterior`` (n,) bool fixes which eye
    vertices count as anterior (default: where the eye's dome stands off the sclera)."""
    d, ant, dsph, _ = surface_residual(p.V, e)
    sa = np.sqrt(p.A)
    if anterior is None:
        anterior = ant
    out = {"sclera": sa[lab & ~anterior] * d[lab & ~anterior] / SIG_SCLERA,
           "anterior": sa[lab & anterior] * d[lab & anterior] / SIG_ANTERIOR,
           "skin": sa[~lab] * np.minimum(dsph[~lab] + TAU_INSIDE, 0.0) / SIG_SCLERA}
    if cues.front is not None:
        out["prior"] = (e.c + e.R * cues.axis - cues.front) / cues.front_sigma
    out["radius_prior"] = np.array([(e.R - cues.radius_prior[0]) / cues.radius_prior[1]])
    out["limbus_prior"] = np.array([(e.tl - LIMBUS_DEG[0]) / LIMBUS_DEG[1]])
    out["ring_prior"] = np.array([e.hb / HB_SIGMA])
    return out


@dataclass
class FitResult:
    eyes: list
    cov: np.ndarray
    shares: list          # per eye: {cue: share of the information on (c, R)}
    cost: float
    limbus_cov: list = None   # per eye: (6, 6) covariance of (limbus centre, unit gaze)


def limbus_center(e: Eye) -> np.ndarray:
    """Centre of the eye model's limbus circle (the rim of its anterior cap), (3,)."""
    return np.asarray(e.c, float) + e.R * np.cos(np.radians(e.tl)) * np.asarray(e.n, float)


def fit_eyes(patches, labs, eyes, cues, radius_range, *, shared_radius=False, xm=None,
             sym_sigma=1.0, fixed_radius=None, max_nfev=60):
    """Robust least squares of every eye's ``(c, n, ha, tl)`` and the radius (one shared radius when
    ``shared_radius``; ``fixed_radius`` holds it); ``xm``: mirror prior on the centres about
    x = xm (two eyes). Returns a :class:`FitResult` (covariance of the centres and radii in
    the order c_0, R_0, c_1, R_1, ...)."""
    from scipy.optimize import least_squares

    k = len(eyes)
    nR = 0 if fixed_radius is not None else (1 if shared_radius else k)

    def unpack(x):
        out = []
        for i in range(k):
            b = nR + NP * i
            R = fixed_radius if nR == 0 else x[0 if nR == 1 else i]
            out.append(Eye(x[b:b + 3], float(R), _vec(x[b + 3:b + 5]), float(x[b + 5]), float(x[b + 6]),
                           float(x[b + 7])))
        return out

    # which eye vertices are anterior is decided once per fit, so the blocks keep their sizes
    ant = [surface_residual(patches[i].V, eyes[i])[1] for i in range(k)]

    def blocks(x):
        es = unpack(x)
        bl = [_blocks(patches[i], labs[i], es[i], cues[i], ant[i]) for i in range(k)]
        extra = {}
        if xm is not None and k == 2:
            extra["pair"] = (es[1].c - mirror(es[0].c, xm))[1:] / sym_sigma
        return bl, extra

    def f(x):
        bl, extra = blocks(x)
        return np.concatenate([v for b in bl for v in b.values()] + list(extra.values()))

    x0, lo, hi = [], [], []
    if nR:
        x0 += [float(np.mean([e.R for e in eyes]))] if nR == 1 else [e.R for e in eyes]
        lo += [radius_range[0]] * nR
        hi += [radius_range[1]] * nR
    for e in eyes:
        x0 += list(e.c) + list(_angles(e.n)) + [e.ha, e.tl, e.hb]
        lo += list(np.asarray(e.c) - 15.0) + [0.0, -np.pi - 1.0, HA_RANGE[0], LIMBUS_RANGE[0], HB_RANGE[0]]
        hi += list(np.asarray(e.c) + 15.0) + [np.radians(60.0), np.pi + 1.0, HA_RANGE[1], LIMBUS_RANGE[1],
                                              HB_RANGE[1]]
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    x0 = np.clip(np.asarray(x0, float), lo + 1e-6, hi - 1e-6)
    res = least_squares(f, x0, loss="soft_l1", f_scale=2.0, max_nfev=max_nfev, bounds=(lo, hi))
    es = unpack(res.x)
    # Laplace approximation on (c, R) of every eye: Jacobian by central differences
    cols = []
    for i in range(k):
        b = nR + NP * i
        cols.append([b, b + 1, b + 2, (0 if nR == 1 else i) if nR else None])
    J_full = _jacobian_blocks(blocks, res.x)
    cov, shares, C = _laplace(J_full, res.x, cols, nR, k)
    # what a scan shows best is the front of the eye: the limbus centre and the gaze, with their
    # covariance from the same Laplace approximation (the asset's eye is anchored there)
    lcov = []
    for i in range(k):
        def g(x, i=i):
            e = unpack(x)[i]
            return np.concatenate([limbus_center(e), e.n])
        J = np.zeros((6, len(res.x)))
        for j in range(len(res.x)):
            xp, xq = res.x.copy(), res.x.copy()
            xp[j] += 1e-5
            xq[j] -= 1e-5
            J[:, j] = (g(xp) - g(xq)) / 2e-5
        lcov.append(J @ C @ J.T if np.isfinite(C).all() else np.full((6, 6), np.inf))
    return FitResult(es, cov, shares, float(res.cost), lcov)


def _jacobian_blocks(blocks, x, h=1e-4):
    """Per residual block, its Jacobian (rows x len(x)) by central differences."""
    names = None
    Js = None
    for j in range(len(x)):
        xp, xq = x.copy(), x.copy()
        xp[j] += h
        xq[j] -= h
        bp, ep = blocks(xp)
        bq, eq = blocks(xq)
        flat_p = [(f"{i}:{n}", v) for i, b in enumerate(bp) for n, v in b.items()] + list(ep.items())
        flat_q = [(f"{i}:{n}", v) for i, b in enumerate(bq) for n, v in b.items()] + list(eq.items())
        if names is None:
            names = [n for n, _ in flat_p]
            Js = {n: np.zeros((len(v), len(x))) for n, v in flat_p}
        for (n, vp), (_, vq) in zip(flat_p, flat_q):
            Js[n][:, j] = (vp - vq) / (2 * h)
    return Js


def _laplace(Js, x, cols, nR, k):
    """Covariance of (c, R) per eye from the Gauss-Newton information, and each cue's share
    of that information (trace over the eye's c and R)."""
    H = sum(J.T @ J for J in Js.values())
    n = len(x)
    H = H + 1e-9 * np.eye(n)
    try:
        C = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        C = np.full((n, n), np.inf)
    idx = []
    for c in cols:
        idx += c[:3] + ([c[3]] if c[3] is not None else [])
    cov = C[np.ix_(idx, idx)]
    shares = []
    for i, c in enumerate(cols):
        sel = c[:3] + ([c[3]] if c[3] is not None else [])
        tot = {}
        for name, J in Js.items():
            cue = name.split(":")[-1]
            if ":" in name and int(name.split(":")[0]) != i and cue != "pair":
                continue
            tot[cue] = tot.get(cue, 0.0) + float(np.sum(J[:, sel] ** 2))
        s = sum(tot.values()) or 1.0
        shares.append({kk: v / s for kk, v in tot.items()})
    return cov, shares, C


def hypotheses(p: Patch, cues: Cues, radius_range, rng, n_pairs=1500, keep=3, min_fold_deg=15.0,
               pool=60):
    """Starting eyes: spheres through pairs of oriented vertices near the hint, and along the
    prior's axis at every whole radius; the ``pool`` best by their unaries are segmented, and
    the ``keep`` lowest in energy among those ringed by a lid fold (``min_fold_deg``; the
    cheek or a lid laid over a sphere is not) are returned, distinct in centre or radius."""
    near = np.flatnonzero((np.linalg.norm(p.V - p.hint, axis=1) < 12.0) & (p.A > 0))
    cands = []
    if len(near) >= 2:
        for a, b in rng.integers(0, len(near), (n_pairs, 2)):
            if a == b:
                continue
            h = sphere_from_normals(p.V[near[a]], p.N[near[a]], p.V[near[b]], p.N[near[b]])
            if h is None:
                continue
            c, r = h
            v = p.hint - c
            if (radius_range[0] <= r <= radius_range[1] and v[2] > 0.6 * np.linalg.norm(v)
                    and abs(np.linalg.norm(v) - r) < 4.0):
                cands.append(Eye(c, r, unit(v) if cues.axis is None else cues.axis))
    if cues.front is not None:
        for R in np.arange(np.ceil(radius_range[0]), radius_range[1] + 1e-9, 1.0):
            cands.append(Eye(cues.front - R * cues.axis, float(R), cues.axis))
    if not cands:
        return []
    pre = []
    for e in cands:
        best = np.inf
        for ha in (0.0, 0.5, 1.0):
            e.ha = ha
            ce, ck = unary_costs(p, e)
            best = min(best, float(np.minimum(ce, ck).sum()))
        pre.append(best)
    scored = []
    for i in np.argsort(pre, kind="stable")[:pool]:
        e0 = cands[i]
        segs = [segment(p, Eye(e0.c, e0.R, e0.n, ha)) for ha in (0.0, 0.5, 1.0)]
        j = int(np.argmin([E for _, E in segs]))
        if fold_deg(p, segs[j][0]) >= min_fold_deg:
            scored.append((segs[j][1], Eye(e0.c, e0.R, e0.n, (0.0, 0.5, 1.0)[j])))
    scored.sort(key=lambda t: t[0])
    pick = []
    for E, e in scored:
        if all(np.linalg.norm(e.c - e2.c) > 1.0 or abs(e.R - e2.R) > 0.7 for _, e2 in pick):
            pick.append((E, e))
        if len(pick) >= keep:
            break
    return [e for _, e in pick]


@dataclass
class Mode:
    """A local optimum of one eye's fit; ``fold_deg``: the lid fold around its eye surface."""

    eye: Eye
    lab: np.ndarray
    energy: float
    fit: FitResult = field(repr=False, default=None)
    fold_deg: float = 0.0


def fold_deg(p: Patch, lab, radius_mm=2.0):
    """How sharply the surface folds where the eye surface meets the skin, degrees: median over
    the border vertices of the angle between the mean normal of eye vertices and of skin
    vertices within ``radius_mm``. An open eye is ringed by a fold (the lids rise off the
    globe); a sphere laid over a closed lid, or over the cheek, continues smoothly into the skin."""
    from scipy.spatial import cKDTree

    if not lab.any() or lab.all():
        return 0.0
    border = np.unique(np.concatenate([p.E[lab[p.E[:, 0]] & ~lab[p.E[:, 1]], 0],
                                       p.E[lab[p.E[:, 1]] & ~lab[p.E[:, 0]], 1]]))
    if len(border) == 0:
        return 0.0
    ie, ik = np.flatnonzero(lab), np.flatnonzero(~lab)
    te, tk = cKDTree(p.V[ie]), cKDTree(p.V[ik])
    angles = []
    for a, b in zip(te.query_ball_point(p.V[border], radius_mm), tk.query_ball_point(p.V[border], radius_mm)):
        if a and b:
            na, nb = p.N[ie[a]].sum(axis=0), p.N[ik[b]].sum(axis=0)
            c = na @ nb / max(np.linalg.norm(na) * np.linalg.norm(nb), 1e-12)
            angles.append(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))
    return float(np.median(angles)) if angles else 0.0


def refine(p: Patch, e: Eye, cues: Cues, radius_range, iters=REFINE_ITERS) -> Mode:
    """Alternate the graph cut and the least squares from ``e``."""
    fit = None
    for _ in range(iters):
        lab, _ = segment(p, e)
        fit = fit_eyes([p], [lab], [e], [cues], radius_range)
        e = fit.eyes[0]
    lab, energy = segment(p, e)
    energy += 0.5 * float(np.sum(np.concatenate(
        [v for k, v in _blocks(p, lab, e, cues).items()
         if k in PRIOR_BLOCKS]) ** 2))
    return Mode(e, lab, energy, fit, fold_deg(p, lab))


def midplane_x(V, hints, reach_mm=40.0, max_points=6000):
    """x of the face's mirror plane (normal +X, the head frame's left-right axis): the
    reflection that best overlays the surface around the eyes on itself (1-D search)."""
    from scipy.spatial import cKDTree

    mid = 0.5 * (np.asarray(hints["left"], float) + np.asarray(hints["right"], float))
    sel = np.flatnonzero((np.abs(V[:, 1] - mid[1]) < reach_mm) & (V[:, 2] > mid[2] - reach_mm)
                         & (np.abs(V[:, 0] - mid[0]) < 2.5 * reach_mm))
    P = V[sel][:: max(1, len(sel) // max_points)]
    if len(P) < 10:
        return float(mid[0])
    tree = cKDTree(P)

    def cost(xm):
        Q = P.copy()
        Q[:, 0] = 2.0 * xm - Q[:, 0]
        return float(np.mean(np.minimum(tree.query(Q)[0], 3.0) ** 2))
    xs = np.linspace(mid[0] - 4.0, mid[0] + 4.0, 33)
    x0 = xs[int(np.argmin([cost(x) for x in xs]))]
    xs = np.linspace(x0 - 0.3, x0 + 0.3, 25)
    return float(xs[int(np.argmin([cost(x) for x in xs]))])


@dataclass
class Placement:
    """One placed eye.

    Attributes
    ----------
    eye : Eye
    lab : (n,) bool
        Eye vertices of ``patch``.
    patch : Patch
    sigma_center_mm, sigma_radius_mm : float
        Calibrated 1-sigma: RMS of the 3-D centre error, and of the radius error.
    cues : list of str
        The cues that carried the fit (share of the information on c and R >= 5 %).
    shares : dict
    modes : list of (centre (3,), radius, energy above the best)
    """

    eye: Eye
    lab: np.ndarray
    patch: Patch
    sigma_center_mm: float
    sigma_radius_mm: float
    cues: list
    shares: dict
    modes: list
    fold_deg: float = 0.0
    profile: tuple = None      # (radii, energy above the placement's) of radius_profile
    sigma_laplace_mm: tuple = (0.0, 0.0)   # the Laplace part of (sigma_center, sigma_radius)
    sigma_limbus_mm: float = 0.0      # calibrated 1-sigma of the limbus centre (RMS 3-D error)
    sigma_axis_deg: float = 0.0       # ... of the gaze (optical axis), degrees
    limbus_laplace: tuple = (0.0, 0.0)  # the Laplace part of (sigma_limbus_mm, sigma_axis_deg)


PRIOR_BLOCKS = ("prior", "radius_prior", "limbus_prior", "ring_prior")
CUE_NAMES = {"sclera": "sclera", "anterior": "cornea_or_iris", "skin": "skin",
             "prior": "eye_region_prior", "radius_prior": "radius_prior", "pair": "pair",
             "limbus_prior": "limbus_prior", "ring_prior": "ring_prior"}


RANGE_EDGE_MM = 0.05    # a radius this close to a bound of the range rests on it


def _inside_range(R, radius_range):
    """Whether ``R`` lies inside the radius range, off its bounds. A fit that presses against
    a bound wants a globe no eye has: a sphere laid over a closed lid, a cheek or a filled
    opening (on 33 unseen ICT heads every optimum at 18 mm was 5.9-13.7 mm off, most with a
    confident 0.4-0.9 mm uncertainty), not an eye. The range reaches 21 mm because an eye
    turned in or out fits a sphere 1.5-2 mm larger than its own (ICT's 15-16 mm eyes at 17-18
    mm), and an upper bound of 18 cut off its true gaze's optimum; the sphere is a diagnostic,
    the asset's eye is the human one anchored at the limbus."""
    return radius_range[0] + RANGE_EDGE_MM < R < radius_range[1] - RANGE_EDGE_MM


GAZE_RESTARTS_DEG = tuple((y, 0.0) for y in (-45.0, -30.0, -15.0, 15.0, 30.0, 45.0)) + tuple(
    (0.0, q) for q in (-30.0, -15.0, 15.0, 25.0)) + tuple(
    (y, q) for y in (-20.0, 20.0) for q in (-18.0, 18.0))


def _turn(n, yaw_deg, pitch_deg):
    """``n`` turned by ``yaw_deg`` about the head's up axis (+Y), then ``pitch_deg`` up."""
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    Ry = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    v = Ry @ n
    h = unit(np.cross([0.0, 1.0, 0.0], v)) if abs(v[1]) < 0.99 else np.array([1.0, 0.0, 0.0])
    return unit(np.cos(b) * v + np.sin(b) * np.cross(v, h))


def gaze_restarts(p: Patch, found, cues: Cues, radius_range, min_fold_deg):
    """The best local optimum refitted from gazes turned in, out, up and down
    (``GAZE_RESTARTS_DEG``). Every start takes the eye region's forward as its gaze, but a gaze
    turned 20-45 deg from it (looking in, out, down; ICT's eyes rest 5-10 deg out) sits in
    another basin of the least squares; the energy tells them apart (on the unseen heads a
    start at the true gaze ended lower in every case that had gone astray)."""
    ok = [m for m in found if m.fold_deg >= min_fold_deg and m.lab.any()]
    if not ok:
        return []
    m = min(ok, key=lambda m: m.energy)
    e = m.eye
    # one round from every turned gaze, then the full refinement of the few lowest: most turned
    # starts fall back into the start's basin or wander off within one round
    first = [refine(p, Eye(e.c, e.R, _turn(e.n, yaw, pitch), e.ha, e.tl, e.hb), cues, radius_range, iters=1)
             for yaw, pitch in GAZE_RESTARTS_DEG]
    first.sort(key=lambda t: t.energy)
    return [refine(p, t.eye, cues, radius_range, iters=REFINE_ITERS - 1) for t in first[:RESTARTS_KEEP]]


def polish(p: Patch, found, cues: Cues, radius_range, keep=POLISH_KEEP, iters=POLISH_ITERS):
    """The ``keep`` lowest local optima refined further (``iters`` more rounds of cut and least
    squares): three rounds leave a start near the true gaze short of its basin's floor, above a
    wrong gaze's (an ICT head looking in: 2764 against 2720 after three, 2678 after eight)."""
    order = sorted(range(len(found)), key=lambda i: found[i].energy)
    out = list(found)
    for i in order[:keep]:
        m = refine(p, found[i].eye, cues, radius_range, iters=iters)
        if m.energy < found[i].energy:
            out[i] = m
    return out


def place_eyes(V, F, hints, *, patch_radius_mm, radius_range, radius_prior, prior=None,
               ignore=None, seed=0, temperature=20.0, sigma_scale=1.0, shared_radius_z=2.5,
               sym_sigma_mm=1.0, min_fold_deg=20.0):
    """Place both eyes (module doc). ``prior``: callable ``(side) -> dict(front, axis, sigma)``
    or None. Only local optima ringed by a lid fold of ``min_fold_deg`` count as an open eye;
    an eye with none is returned as None (closed, or nothing eye-like near the hint).
    Returns ``{side: Placement or None}``."""
    rng = np.random.default_rng(seed)
    patches, cues, modes = {}, {}, {}
    for s in SIDES:
        patches[s] = build_patch(V, F, hints[s], patch_radius_mm, ignore)
        pr = prior(s) if prior is not None else None
        cues[s] = Cues(front=None if pr is None else pr["front"], axis=None if pr is None else pr["axis"],
                       front_sigma=4.0 if pr is None else pr["sigma"], radius_prior=radius_prior)
        found = [refine(patches[s], h, cues[s], radius_range)
                 for h in hypotheses(patches[s], cues[s], radius_range, rng, min_fold_deg=min_fold_deg)]
        found += gaze_restarts(patches[s], found, cues[s], radius_range, min_fold_deg)
        found = polish(patches[s], found, cues[s], radius_range)
        modes[s] = sorted((m for m in found if m.fold_deg >= min_fold_deg and m.lab.any()
                           and _inside_range(m.eye.R, radius_range)), key=lambda m: m.energy)
    if not all(modes[s] for s in SIDES):
        return {s: None if not modes[s] else _placement(patches[s], modes[s], None, temperature,
                                                        sigma_scale) for s in SIDES}
    best = {s: modes[s][0] for s in SIDES}
    # one radius for the two eyes when they agree; then a joint fit with a loose mirror prior
    sr = {s: float(np.sqrt(max(best[s].fit.cov[3, 3], 1e-6))) for s in SIDES}
    agree = abs(best["left"].eye.R - best["right"].eye.R) <= shared_radius_z * np.hypot(*sr.values())
    xm = midplane_x(V, hints)
    fit = fit_eyes([patches[s] for s in SIDES], [best[s].lab for s in SIDES],
                   [best[s].eye for s in SIDES], [cues[s] for s in SIDES], radius_range,
                   shared_radius=agree, xm=xm, sym_sigma=sym_sigma_mm)
    out = {}
    for i, s in enumerate(SIDES):
        e = fit.eyes[i]
        lab, energy = segment(patches[s], e)
        m0 = Mode(e, lab, energy, fit, fold_deg(patches[s], lab))
        radii = np.arange(np.ceil(radius_range[0]), radius_range[1] + 1e-9, 1.0)
        prof = radius_profile(patches[s], e, cues[s], radii)
        out[s] = _placement(patches[s], [m0] + modes[s][1:], (fit, i, agree), temperature,
                            sigma_scale, prof)
    return _share_radius_doubt(out)


def _share_radius_doubt(out):
    """A head's two eyes are one size (left-right 0.2 +- 0.4 mm), so the radius is the head's:
    a rival radius of one eye is a rival for both, fitted with one radius or not. And an eye's
    centre moves with its radius along the axis (its front is what the opening shows). So each
    eye takes the larger radius variance, and its centre variance grows by the difference.
    (On the unseen heads a dome cornea's eye placed 6.8 mm off with sigma 0.57 mm, and another
    2.3 mm off with 0.58 mm, while their pairs' radii were +-1.6 and +-2.6 mm.)"""
    from dataclasses import replace

    vr = {s: out[s].sigma_radius_mm ** 2 for s in SIDES}
    top = max(vr.values())
    return {s: replace(out[s], sigma_radius_mm=float(np.sqrt(top)),
                       sigma_center_mm=float(np.sqrt(out[s].sigma_center_mm ** 2 + top - vr[s])))
            for s in SIDES}


def radius_profile(p: Patch, e: Eye, cues: Cues, radii, iters=2):
    """The energy of the best eye at each radius of ``radii`` with its front held: the eye
    slides along its axis (the front of the globe is what the opening shows best), the centre
    and anterior cap are refitted and the surface segmented again. The scan's evidence on the
    radius is how fast this rises: a flat profile (little sclera, a squint) is a wide one.

    Returns ``(radii, energies, centres)``."""
    front = e.c + e.R * e.n
    E, C = [], []
    for R in radii:
        x = Eye(front - R * e.n, float(R), e.n, e.ha, e.tl, e.hb)
        for _ in range(iters):
            lab, _ = segment(p, x)
            x = fit_eyes([p], [lab], [x], [cues], (R, R), fixed_radius=float(R), max_nfev=20).eyes[0]
        lab, energy = segment(p, x)
        energy += 0.5 * float(np.sum(np.concatenate(
            [v for k, v in _blocks(p, lab, x, cues).items()
             if k in PRIOR_BLOCKS]) ** 2))
        E.append(energy)
        C.append(x.c)
    return np.asarray(radii, float), np.asarray(E), np.asarray(C)


def _placement(p, modes, joint, temperature, sigma_scale, profile=None):
    m0 = modes[0]
    if joint is not None:
        fit, i, _ = joint
        cov, ci, ri, shares = fit.cov, list(range(4 * i, 4 * i + 3)), 4 * i + 3, fit.shares[i]
    else:
        cov, ci, ri, shares = m0.fit.cov, [0, 1, 2], 3, m0.fit.shares[0]
    var_c = float(np.trace(cov[np.ix_(ci, ci)])) * sigma_scale ** 2
    var_r = float(cov[ri, ri]) * sigma_scale ** 2
    lap = (float(np.sqrt(var_c)), float(np.sqrt(var_r)))
    lc = (fit.limbus_cov[i] if joint is not None else m0.fit.limbus_cov[0])
    var_l = float(np.trace(lc[:3, :3])) * sigma_scale ** 2
    var_a = float(np.trace(lc[3:, 3:])) * sigma_scale ** 2       # rad^2 (small angles)
    lap_l = (float(np.sqrt(var_l)), float(np.degrees(np.sqrt(var_a))))
    l0 = limbus_center(m0.eye)
    # other local optima, weighted by their energy: a second explanation nearly as good widens
    # the uncertainty by how far away it lies
    e0 = min(m.energy for m in modes)
    wts = np.array([np.exp(-(m.energy - e0) / temperature) for m in modes])
    wts /= wts.sum()
    for w, m in zip(wts, modes):
        var_c += w * float(np.sum((m.eye.c - m0.eye.c) ** 2))
        var_r += w * (m.eye.R - m0.eye.R) ** 2
        var_l += w * float(np.sum((limbus_center(m.eye) - l0) ** 2))
        var_a += w * float(np.arccos(np.clip(np.dot(m.eye.n, m0.eye.n), -1.0, 1.0))) ** 2
    if profile is not None:     # the radius's own evidence, and where the centre goes with it
        radii, energies, centres = profile
        w = np.exp(-(energies - min(energies.min(), m0.energy)) / temperature)
        w /= w.sum()
        var_r += float(np.sum(w * (radii - m0.eye.R) ** 2))
        var_c += float(np.sum(w * np.sum((centres - m0.eye.c) ** 2, axis=1)))
        # the front is held along the profile: the limbus moves by the cap's depth change only
        lp = centres + (radii * np.cos(np.radians(m0.eye.tl)))[:, None] * np.asarray(m0.eye.n)
        var_l += float(np.sum(w * np.sum((lp - l0) ** 2, axis=1)))
    cues = sorted((CUE_NAMES.get(k, k) for k, v in shares.items() if v >= 0.05),
                  key=lambda k: -shares.get({v: kk for kk, v in CUE_NAMES.items()}.get(k, k), 0))
    prof = None if profile is None else (profile[0], profile[1] - m0.energy)
    return Placement(m0.eye, m0.lab, p, float(np.sqrt(var_c)), float(np.sqrt(var_r)), cues,
                     {CUE_NAMES.get(k, k): round(v, 4) for k, v in shares.items()},
                     [(m.eye.c, m.eye.R, m.energy - e0) for m in modes], m0.fold_deg, prof, lap,
                     float(np.sqrt(var_l)), float(np.degrees(np.sqrt(var_a))), lap_l)
