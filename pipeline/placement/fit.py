"""Place both eyes of a head from every cue the scan keeps: a MAP fit of the eye model
(:mod:`pipeline.placement.model`) to the cues (:mod:`pipeline.placement.cues`).

Search: sphere hypotheses from pairs of oriented vertices near the hint (and along the prior's
axis), ranked by the graph-cut energy; the best few are refined by alternating the cut and a
robust least-squares fit of ``(c, R, n, ha, tl)`` (EM). The best of them is refitted again from
gazes turned up to 45 deg away (:func:`gaze_restarts`; the least squares does not cross from
the eye region's forward to a gaze turned in, out or down), and so is the rival optimum more
than ``RIVAL_MM`` away that the eye-region prior points to; a best optimum that may be a scanned
cornea (a small sphere with no bulge of its own) is refitted from the globe behind it too
(:func:`cornea_starts`); the two lowest are polished. An eye looking more than ``PARTNER_DEG``
away from the other eye's best gaze (as it is, or mirrored) is refitted from that gaze
(:func:`partner_starts`). Then the joint fit of both eyes (one radius when they agree, a loose
mirror prior on the centres); its uncertainty is :mod:`pipeline.placement.uncertainty`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from pipeline.fork import fork_call, fork_result
from pipeline.geometry.spherefit import sphere_from_normals
from pipeline.placement.cues import (COARSE_VERTICES, Cues, Patch, ResidualRows, build_patch, coarse_patch,
                                     fold_deg, midplane_x, prior_blocks, residual_jacobians, segment, unary_costs)
from pipeline.placement.model import (HA_RANGE, HB_RANGE, LIMBUS_DEG, LIMBUS_RANGE, Eye, _cap, limbus_center, rays,
                                      surface_residual, unit)
from pipeline.placement.uncertainty import laplace, placement_of, share_radius

SIDES = ("left", "right")
REFINE_ITERS = 3
POLISH_KEEP, POLISH_ITERS = 2, 4   # the best local optima refined further (polish)
RESTARTS_KEEP = 4                  # turned gazes refined in full after one round each
# the radius profile: one round of least squares per radius (at most PROFILE_NFEV evaluations),
# fitted to the placed eye's labels, then cut once. It feeds the uncertainty only (never the
# eye), and two rounds from cuts under each slid eye (max 20) were a tenth of the stage's time
# for the same coverage: on the 30 placed held-out heads the truth lay within 2 sigma for 53
# of 60 eyes against 52, median limbus sigma 1.10 against 1.05 mm (docs/remove_eyeballs.md Speed)
PROFILE_ITERS, PROFILE_NFEV = 1, 10
RIVAL_MM = 3.0                     # an optimum this far from the best is another basin: restarted too
PRIOR_OWN_START = True             # the prior's best start refined whatever the drawn spheres rank
NP = 8                  # parameters per eye besides the radius: c (3), gaze (2), ha, tl, hb
# least-squares stops: a relative change of 1e-5 in a cost of ~1e3 is 0.01 of an energy whose
# rivals are weighed at a temperature of 5, and a step of 1e-5 of |x| (~80, the centre in mm)
# is under 1 micron and 0.05 deg; scipy's 1e-8 ran over a quarter of the fits to max_nfev for nothing
FIT_FTOL, FIT_XTOL = 1e-5, 1e-5


# ----------------------------------------------------------------------------- fitting
def _angles(n):
    return np.array([np.arccos(np.clip(n[2], -1.0, 1.0)), np.arctan2(n[1], n[0])])


def _vec(a):
    return np.array([np.sin(a[0]) * np.cos(a[1]), np.sin(a[0]) * np.sin(a[1]), np.cos(a[0])])


def _dvec(a):
    """Partials of :func:`_vec` along its two angles, (3, 2)."""
    st, ct, sp, cp = np.sin(a[0]), np.cos(a[0]), np.sin(a[1]), np.cos(a[1])
    return np.array([[ct * cp, -st * sp], [ct * sp, st * cp], [-st, 0.0]])


def mirror(c, xm):
    """``c`` reflected in the plane x = ``xm``."""
    c = np.array(c, dtype=np.float64)
    c[..., 0] = 2.0 * xm - c[..., 0]
    return c


class FitResult:
    """One least-squares fit: ``eyes``, ``cost``, and its Laplace approximation: ``cov`` (the
    centres and radii), ``shares`` (per eye: {cue: share of the information on (c, R)}),
    ``limbus_cov`` (per eye: (6, 6) covariance of (limbus centre, unit gaze)). The Laplace part
    is made when first read (``laplace_of()`` -> (cov, shares, limbus_cov)): the search makes
    about 120 fits and reads it of the few it keeps (the same numbers whenever it is made)."""

    def __init__(self, eyes, cost, laplace_of):
        self.eyes, self.cost = eyes, cost
        self._laplace_of, self._laplace = laplace_of, None

    def _get(self, i):
        if self._laplace is None:
            if self._laplace_of is None:
                raise RuntimeError("this fit's Laplace approximation was not made before it was sent "
                                   "from another process")
            self._laplace = self._laplace_of()
            self._laplace_of = None
        return self._laplace[i]

    def __getstate__(self):
        # the closure does not pickle: a fit sent back from a child (place_eyes' search of one
        # side) carries its Laplace part only where the child made it (the placed mode's)
        return {"eyes": self.eyes, "cost": self.cost, "_laplace": self._laplace, "_laplace_of": None}

    cov = property(lambda self: self._get(0))
    shares = property(lambda self: self._get(1))
    limbus_cov = property(lambda self: self._get(2))


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
    rows = [ResidualRows(patches[i], labs[i], cues[i], ant[i]) for i in range(k)]

    def f_rows(X):
        """The residual vector of every row of ``X`` (b, len(x)), (b, m): every eye's
        :func:`residual_blocks` concatenated, then the mirror prior on the centres (``pair``)."""
        out = []
        for i in range(k):
            b = nR + NP * i
            R = [fixed_radius if nR == 0 else float(x[0 if nR == 1 else i]) for x in X]
            out.append(rows[i](X[:, b:b + 3], R, np.array([_vec(x[b + 3:b + 5]) for x in X]),
                               [float(x[b + 5]) for x in X], [float(x[b + 6]) for x in X],
                               [float(x[b + 7]) for x in X]))
        if xm is not None and k == 2:
            c0, c1 = X[:, nR:nR + 3], X[:, nR + NP:nR + NP + 3]
            out.append((c1 - mirror(c0, xm))[:, 1:] / sym_sigma)
        return np.concatenate(out, axis=1)

    last = {}

    def f(x):
        r = f_rows(x[None, :])[0]
        last["x"], last["f"] = x.copy(), r
        return r

    def jac(x):
        """scipy's forward differences ('2-point', the step and its turn at a bound as
        ``approx_derivative`` takes them), every shifted x evaluated in one stack."""
        f0 = last["f"] if "x" in last and np.array_equal(last["x"], x) else f(x)
        return forward_differences(f_rows, x, f0, lo, hi)

    def jac_blocks(x):
        """The partials of ``blocks`` along ``x``, named as the Laplace step reads them."""
        es = unpack(x)
        out = {}
        for i in range(k):
            b = nR + NP * i
            T = _dvec(x[b + 3:b + 5])
            for name, Jl in residual_jacobians(patches[i], labs[i], es[i], cues[i], ant[i]).items():
                G = np.zeros((len(Jl), len(x)))
                G[:, b:b + 3] = Jl[:, 0:3]
                if nR:
                    G[:, 0 if nR == 1 else i] = Jl[:, 3]
                G[:, b + 3:b + 5] = Jl[:, 4:7] @ T
                G[:, b + 5:b + 8] = Jl[:, 7:10]
                out[f"{i}:{name}"] = G
        if xm is not None and k == 2:
            G = np.zeros((2, len(x)))
            G[[0, 1], [nR + NP + 1, nR + NP + 2]] = 1.0 / sym_sigma
            G[[0, 1], [nR + 1, nR + 2]] = -1.0 / sym_sigma
            out["pair"] = G
        return out

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
    # the steps keep scipy's forward differences, not jac_blocks: which local optimum the search
    # ends in rests on them (on 13 unseen heads the exact Jacobian moved 6 of 26 eyes into another
    # basin, 5 of them further off; central differences moved eyes of the two heads tried too)
    res = least_squares(f, x0, jac=jac, loss="soft_l1", f_scale=2.0, max_nfev=max_nfev, bounds=(lo, hi),
                        ftol=FIT_FTOL, xtol=FIT_XTOL)
    es = unpack(res.x)

    def laplace_of():
        # Laplace approximation on (c, R) of every eye
        cols = []
        for i in range(k):
            b = nR + NP * i
            cols.append([b, b + 1, b + 2, (0 if nR == 1 else i) if nR else None])
        J_full = jac_blocks(res.x)
        cov, shares, C = laplace(J_full, res.x, cols, nR, k)
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
        return cov, shares, lcov
    return FitResult(es, float(res.cost), laplace_of)


def forward_differences(f_rows, x, f0, lo, hi):
    """The Jacobian scipy's ``least_squares`` takes with ``jac='2-point'`` and bounds ``(lo,
    hi)`` at ``x`` (``f0`` = f(x)), (m, len(x)), with every shifted x evaluated by one call of
    ``f_rows`` ((b, len(x)) -> (b, m)): the same steps (scipy's ``_compute_absolute_step``
    and ``_adjust_scheme_to_bounds``), the same shifted points and quotients, so the same
    numbers, the same layout, and the fits end where they ended
    (``tests/test_placement.py`` compares it with ``approx_derivative``)."""
    from scipy.optimize._numdiff import _adjust_scheme_to_bounds, _compute_absolute_step

    h = _compute_absolute_step(None, x, f0, "2-point")
    h, _ = _adjust_scheme_to_bounds(x, h, 1, "1-sided", lo, hi)
    n = len(x)
    X = np.repeat(x[None, :], n, axis=0)
    X[np.arange(n), np.arange(n)] = x + h
    dx = (x + h) - x
    JT = (f_rows(X) - f0) / dx[:, None]
    return JT.T


HYPOTHESIS_PAIRS = 1500    # pairs of oriented vertices drawn per eye


def hypothesis_pairs(p: Patch, rng, n_pairs=HYPOTHESIS_PAIRS):
    """The pairs of oriented vertices near the hint that :func:`hypotheses` draws spheres
    through: ``(near, pairs)``, vertex indices of ``p`` and (n_pairs, 2) indices into ``near``
    (None with fewer than two). Drawn apart from the search, so that both eyes' draws come from
    one generator in order while their searches run side by side."""
    near = np.flatnonzero((np.linalg.norm(p.V - p.hint, axis=1) < 12.0) & (p.A > 0))
    return near, (rng.integers(0, len(near), (n_pairs, 2)) if len(near) >= 2 else None)


def hypotheses(p: Patch, cues: Cues, radius_range, drawn, keep=3, min_fold_deg=15.0, pool=60):
    """Starting eyes: spheres through pairs of oriented vertices near the hint (``drawn``, from
    :func:`hypothesis_pairs`), and along the
    prior's axis at every whole radius; the ``pool`` best by their unaries are segmented, and
    the ``keep`` lowest in energy among those ringed by a lid fold (``min_fold_deg``; the
    cheek or a lid laid over a sphere is not) are returned, distinct in centre or radius."""
    near, pairs = drawn
    cands = []
    if pairs is not None:
        for a, b in pairs:
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
    n_drawn = len(cands)
    if cues.front is not None:
        for R in np.arange(np.ceil(radius_range[0]), radius_range[1] + 1e-9, 1.0):
            cands.append(Eye(cues.front - R * cues.axis, float(R), cues.axis))
    if not cands:
        return []
    pre = []
    for e in cands:
        best = np.inf
        ray = rays(p.V, e.c, e.n)       # one sphere and gaze: the three heights share their rays
        for ha in (0.0, 0.5, 1.0):
            e.ha = ha
            ce, ck = unary_costs(p, e, ray)
            best = min(best, float(np.minimum(ce, ck).sum()))
        pre.append(best)
    scored = []
    for i in np.argsort(pre, kind="stable")[:pool]:
        e0 = cands[i]
        segs = [segment(p, Eye(e0.c, e0.R, e0.n, ha)) for ha in (0.0, 0.5, 1.0)]
        j = int(np.argmin([E for _, E in segs]))
        if fold_deg(p, segs[j][0]) >= min_fold_deg:
            scored.append((segs[j][1], Eye(e0.c, e0.R, e0.n, (0.0, 0.5, 1.0)[j]), i >= n_drawn))
    scored.sort(key=lambda t: t[0])
    pick = []
    for E, e, _ in scored:
        if all(np.linalg.norm(e.c - e2.c) > 1.0 or abs(e.R - e2.R) > 0.7 for _, e2 in pick):
            pick.append((E, e))
        if len(pick) >= keep:
            break
    # the prior's own best start is refined too, whatever the drawn spheres rank: when no drawn
    # pair leads into the true eye's basin the search otherwise hangs on last-bit arithmetic
    # (fresh26's hooded synthetic_hood0.7_s3207, docs/known-gaps.md)
    own = next(((E, e) for E, e, from_prior in scored if from_prior), None) if PRIOR_OWN_START else None
    if own is not None and all(np.linalg.norm(own[1].c - e2.c) > 1.0 or abs(own[1].R - e2.R) > 0.7
                               for _, e2 in pick):
        pick.append(own)
    return [e for _, e in pick]


@dataclass
class Mode:
    """A local optimum of one eye's fit; ``fold_deg``: the lid fold around its eye surface."""

    eye: Eye
    lab: np.ndarray
    energy: float
    fit: FitResult = field(repr=False, default=None)
    fold_deg: float = 0.0


def refine(p: Patch, e: Eye, cues: Cues, radius_range, iters=REFINE_ITERS, fold=True) -> Mode:
    """Alternate the graph cut and the least squares from ``e``. ``fold=False`` leaves the
    mode's ``fold_deg`` at 0 (for a caller that ranks modes by energy only)."""
    fit = None
    for _ in range(iters):
        lab, _ = segment(p, e)
        fit = fit_eyes([p], [lab], [e], [cues], radius_range)
        e = fit.eyes[0]
    lab, energy = segment(p, e)
    energy += 0.5 * float(np.sum(np.concatenate(list(prior_blocks(e, cues).values())) ** 2))
    return Mode(e, lab, energy, fit, fold_deg(p, lab) if fold else 0.0)


RANGE_EDGE_MM = 0.05    # a radius this close to a bound of the range rests on it


@dataclass(frozen=True)
class AtRadiusBound:
    """What :func:`place_eyes` returns for an eye whose only optima ringed by a lid fold rest on
    a bound of the radius range: the scan shows an open eye's surface, too little of it to size
    a sphere (a coarse 80k-face scan's eye looking out, every folded optimum at 21 mm). The
    stage places such an eye behind its opening; a closed lid shows no fold at all (the
    held-out blinks' optima, at the bound or not, were ringed by 5-11 deg)."""

    radius: float
    fold_deg: float


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
    """:func:`turned_starts`, one round from each, then :func:`restarts_refined`."""
    first = [refine(p, e, cues, radius_range, iters=1, fold=False)
             for e in turned_starts(found, cues, min_fold_deg)]
    return restarts_refined(p, first, cues, radius_range)


def turned_starts(found, cues: Cues, min_fold_deg):
    """The starts of :func:`gaze_restarts`: the best local optimum of ``found`` (and a rival in
    another basin, below) with its gaze turned in, out, up and down (``GAZE_RESTARTS_DEG``),
    one start per turn. Every start takes the eye region's forward as
    its gaze, but a gaze turned 20-45 deg from it (looking in, out, down; ICT's eyes rest 5-10
    deg out) sits in
    another basin of the least squares; the energy tells them apart (on the unseen heads a
    start at the true gaze ended lower in every case that had gone astray)."""
    ok = sorted((m for m in found if m.fold_deg >= min_fold_deg and m.lab.any()), key=lambda m: m.energy)
    if not ok:
        return []
    # from the best optimum and from one in another place (a rival basin, its centre RIVAL_MM
    # away): a start whose gaze the eye region's forward turned 20 deg off can end above a wrong
    # sphere (ident_s1_000's hooded right eye: the true eye's start ended at 3449 with its gaze
    # wandered 70 deg off, a sphere through the lower lid 8 mm low at 3369, and only turned
    # gazes from the true eye's start reach its floor, 3083)
    starts = [(ok[0].eye, ok[0].eye.n)]
    rivals = [m for m in ok[1:] if np.linalg.norm(m.eye.c - ok[0].eye.c) > RIVAL_MM]
    if rivals:
        axis = None if cues.axis is None else np.asarray(cues.axis, float)
        # the rival the eye-region prior points to (its globe's front nearest the prior's), else
        # the lowest: a lower rival through a half-blinked lower lid (id308_halfblink, 7 mm
        # below the prior's front) only leads the restarts to a lower wrong optimum
        rival = rivals[0] if cues.front is None or axis is None else min(
            rivals, key=lambda m: float(np.linalg.norm(m.eye.c + m.eye.R * axis - cues.front)))
        # turned about the gaze every start took (the eye region's forward), not the rival's own
        starts.append((rival.eye, rival.eye.n if axis is None else axis))
    return [Eye(e.c, e.R, _turn(n, yaw, pitch), e.ha, e.tl, e.hb)
            for e, n in starts for yaw, pitch in GAZE_RESTARTS_DEG]


#: The globe behind a scanned cornea the search took for the globe: this many times its radius
#: (the paper's eye 12 / 8 mm, ICT-FaceKit's 14.6 / 9.3), its cap this prominent
#: (:data:`pipeline.placement.model.HA_RANGE`; the scanned domes' fits end at 1.4).
CORNEA_GLOBE_RATIO, CORNEA_HA = 1.5, 1.2
#: Only a sphere no larger than this (mm) may be a cornea: ICT-FaceKit's scanned corneas are
#: 7.5-10.8 mm, their globes 13-17.8 mm (the paper's cornea 8 mm); and only one whose own cap
#: bulges less than a cornea would (anterior height under this: a sphere through a dome carries
#: none, ``n3505``'s -0.3 and -0.7, where the procedural heads' 11-12.4 mm globes carry 1.2-1.6).
CORNEA_MAX_MM, CORNEA_MAX_HA = 12.5, 0.5
CORNEA_KEEP = 2                   # the globe-behind-the-cornea starts refined in full after one round


def cornea_starts(found, cues: Cues, min_fold_deg, radius_range):
    """Starts for the globe behind the best optimum of ``found`` read as its cornea: a scan that
    shows the cornea's dome (a scanned cornea, a gaze turned far) can offer the search a small
    sphere through the dome, its cap a bump of the sclera beside it, in a basin the turned
    starts (which keep its centre and radius) never leave (fresh29's ``n3505_dome_out_90k``:
    10.7 mm spheres through the corneas of 14.6 mm eyes looking 24 deg out, turned 37-42 deg
    the other way; from the truth the same fit ends 110 lower). A globe
    ``CORNEA_GLOBE_RATIO`` times as large whose cap sphere is centred where that sphere is,
    along the eye region's forward and every turn of ``GAZE_RESTARTS_DEG``; none when that
    sphere is larger than a cornea or carries a cornea's bulge itself (``CORNEA_MAX_MM``,
    ``CORNEA_MAX_HA``)."""
    ok = sorted((m for m in found if m.fold_deg >= min_fold_deg and m.lab.any()), key=lambda m: m.energy)
    if not ok:
        return []
    e = ok[0].eye
    R = min(CORNEA_GLOBE_RATIO * e.R, radius_range[1] - 1.0)
    if e.R > CORNEA_MAX_MM or e.ha >= CORNEA_MAX_HA or R < e.R + 1.0:
        return []
    z0, _ = _cap(R, CORNEA_HA, LIMBUS_DEG[0])
    axis = e.n if cues.axis is None else np.asarray(cues.axis, float)
    return [Eye(e.c - z0 * n, float(R), n, CORNEA_HA, LIMBUS_DEG[0], 0.0)
            for n in [axis] + [_turn(axis, y, q) for y, q in GAZE_RESTARTS_DEG]]


#: The other eye's gaze is offered to an eye whose best optimum looks more than this many degrees
#: away from it, both as the same gaze and mirrored (eyes turn together, or in and out alike).
PARTNER_DEG = 20.0


def partner_starts(modes, other):
    """Starts for one eye from the other eye's search (``modes``, ``other``: each eye's
    placeable optima, the lowest first): its best optimum with the other eye's best gaze, as it
    is and mirrored in the midplane (x), each where it looks more than ``PARTNER_DEG`` away.
    An eye's search can settle on a sphere whose cap is a bump of sclera or lid beside the
    cornea, its gaze 40-60 deg off, while its partner looks the true way; the turned starts
    (15-45 deg about the wrong gaze) lose their first round there (``n3003_wide_noise``'s right
    eye: 50 deg off from its own search, 4 deg from its partner's gaze, lower)."""
    if not modes or not other:
        return []
    e, n = modes[0].eye, other[0].eye.n
    cos = np.cos(np.radians(PARTNER_DEG))
    gazes = [g for g in (n, mirror(n, 0.0)) if float(np.dot(g, e.n)) < cos]
    return [Eye(e.c, e.R, unit(g), e.ha, e.tl, e.hb) for g in gazes]


SAME_MM, SAME_DEG = 0.05, 0.5     # an optimum this close to one the search holds is that one


def _same(a: Eye, b: Eye) -> bool:
    return (float(np.linalg.norm(np.asarray(a.c) - b.c)) < SAME_MM and abs(a.R - b.R) < SAME_MM
            and float(np.degrees(np.arccos(np.clip(np.dot(a.n, b.n), -1.0, 1.0)))) < SAME_DEG)


def partnered(p: Patch, cues: Cues, modes, starts, radius_range, min_fold_deg, laplace=False, ok=None):
    """``modes`` with the optima :func:`partner_starts` ``starts`` end at (refined as far as
    a polished optimum is), the lowest first: those that count as an open eye, and not one the
    search already holds (a start that falls back into the best optimum's basin changes
    nothing). ``laplace``: the lowest mode's Laplace part is made (as :func:`_finished`; of
    the lowest that ``ok`` admits, :func:`admitted`)."""
    new = [m for m in _refine_each(p, starts, cues, radius_range, REFINE_ITERS + POLISH_ITERS)
           if _placeable(m, radius_range, min_fold_deg) and not any(_same(m.eye, k.eye) for k in modes)]
    out = sorted(list(modes) + new, key=lambda m: m.energy)
    if laplace:
        admitted(out, ok)[0].fit.cov          # noqa: B018
    return out


def restarts_refined(p: Patch, first, cues: Cues, radius_range):
    """The full refinement of the few lowest of ``first`` (the modes one round took the turned
    starts to): most turned starts fall back into the start's basin or wander off within one
    round (ranked by energy alone: their lid folds are not read)."""
    first = sorted(first, key=lambda t: t.energy)
    return _refine_each(p, [t.eye for t in first[:RESTARTS_KEEP]], cues, radius_range, REFINE_ITERS - 1)


TWIN_MM, TWIN_DEG = 1e-2, 5e-2      # two starts this close end where one ends (the refinement is deterministic)


def _twins(a: Eye, b: Eye) -> bool:
    return (float(np.max(np.abs(np.asarray(a.c) - b.c))) < TWIN_MM and abs(a.R - b.R) < TWIN_MM
            and float(np.degrees(np.arccos(np.clip(np.dot(a.n, b.n), -1.0, 1.0)))) < TWIN_DEG
            and abs(a.ha - b.ha) < TWIN_MM and abs(a.tl - b.tl) < TWIN_DEG and abs(a.hb - b.hb) < TWIN_MM)


def _refine_each(p: Patch, starts, cues: Cues, radius_range, iters):
    """:func:`refine` from each start, once per set of twins (turned gazes that fell back into
    one basin within the first round, or polish's two best when they are one optimum: refining
    each again repeated the same fits); a twin's result is a copy of the first one's."""
    done, out = [], []
    for e in starts:
        m = next((m for e0, m in done if _twins(e0, e)), None)
        if m is None:
            m = refine(p, e, cues, radius_range, iters=iters)
            done.append((e, m))
        else:
            m = replace(m)
        out.append(m)
    return out


def polish(p: Patch, found, cues: Cues, radius_range, keep=POLISH_KEEP, iters=POLISH_ITERS):
    """The ``keep`` lowest local optima refined further (``iters`` more rounds of cut and least
    squares): three rounds leave a start near the true gaze short of its basin's floor, above a
    wrong gaze's (an ICT head looking in: 2764 against 2720 after three, 2678 after eight)."""
    order = sorted(range(len(found)), key=lambda i: found[i].energy)[:keep]
    out = list(found)
    for i, m in zip(order, _refine_each(p, [found[i].eye for i in order], cues, radius_range, iters)):
        if m.energy < found[i].energy:
            out[i] = m
    return out


def _placeable(m: Mode, radius_range, min_fold_deg) -> bool:
    """Whether ``m`` counts as an open eye: ringed by a lid fold, with eye labels, its radius
    inside the range."""
    return m.fold_deg >= min_fold_deg and bool(m.lab.any()) and _inside_range(m.eye.R, radius_range)


def _hypothesised(p: Patch, cues: Cues, drawn, radius_range, min_fold_deg, laplace=False):
    """The first part of one eye's search: its :func:`hypotheses`, each refined. ``laplace``: the
    Laplace part of every mode that may end up placed is made (a mode sent back from a child
    carries it only so)."""
    found = [refine(p, h, cues, radius_range)
             for h in hypotheses(p, cues, radius_range, drawn, min_fold_deg=min_fold_deg)]
    for m in found if laplace else ():
        if _placeable(m, radius_range, min_fold_deg):
            m.fit.cov       # noqa: B018
    return found


def _finished(p: Patch, cues: Cues, found, first, radius_range, min_fold_deg, laplace=False, cornea=(),
              ok=None):
    """The last part of one eye's search, from its refined hypotheses ``found`` and the modes one
    round took its turned starts to (``first``): the restarts' refinement and the polish.
    Returns ``(modes, at_bound)``: the local optima that count as an open eye (:func:`_placeable`),
    the lowest first, and, where there is none, an :class:`AtRadiusBound` for folded optima on a
    bound of the radius range (else None). ``laplace``: the lowest mode's Laplace part is made (to
    travel with it from a child). ``cornea``: the modes one round took its :func:`cornea_starts`
    to, whose ``CORNEA_KEEP`` lowest are refined in full beside the turned starts' (one round
    leaves them above the small sphere they start from)."""
    lowest = [m.eye for m in sorted(cornea, key=lambda t: t.energy)[:CORNEA_KEEP]]
    found = polish(p, found + restarts_refined(p, first, cues, radius_range)
                   + _refine_each(p, lowest, cues, radius_range, REFINE_ITERS - 1), cues, radius_range)
    modes = sorted((m for m in found if _placeable(m, radius_range, min_fold_deg)), key=lambda m: m.energy)
    if laplace and modes:
        admitted(modes, ok)[0].fit.cov        # noqa: B018
    at_bound = None
    if not modes:
        bound = sorted((m for m in found if m.fold_deg >= min_fold_deg and m.lab.any()), key=lambda m: m.energy)
        if bound:
            at_bound = AtRadiusBound(float(bound[0].eye.R), float(bound[0].fold_deg))
    return modes, at_bound


MIDPLANE_ROUNDS = 6     # the midplane's search takes about as long as this many first rounds


#: An eye the search places on a sphere over ``LID_BULGE_RADIUS_MM`` ringed by a fold under
#: ``LID_BULGE_FOLD_DEG`` is a closed lid's bulge: the closed eyes the geometry placed on the
#: cached unseen heads (the blink `n1208_blink_100k`'s two, 18.3 / 19.3 mm at 12.4 / 12.6 deg, the
#: wink `n1408_wink_right`'s closed one, 19.7 mm at 12.9 deg) lay there, and none of the 165 open
#: eyes of the held-out and fresh heads did (folds under 14 deg: four eyes, on 13-17 mm spheres;
#: spheres over 18 mm: ten, ringed by 17-28 deg). An open eye's lids rise off it in a fold; a
#: sphere laid over a closed lid is wide and barely folded where it meets the skin. One open eye
#: of the dev heads lies there too, and its head is refused: `id19_squint_down`'s right (a squint
#: looking down, 20.0 mm at 11.7 deg, placed 3.9 mm / 19 deg off at +-4.5 mm / 12.5 deg before).
#: A scan with a photograph is judged by the fissure it shows instead (``place.PHOTO_INSIDE_MIN``):
#: a hooded head's skin under its fold fits such a sphere too, and the texture places that eye.
LID_BULGE_RADIUS_MM = 18.0
LID_BULGE_FOLD_DEG = 13.0


#: An optimum placed instead of a lowest one that ``admissible`` rejected is no sphere larger than
#: this (mm, the lid-bulge rule's radius) and is ringed by a lid
#: fold of at least ``REPLACEMENT_MIN_FOLD_DEG``: it is less sure than a lowest optimum, so it must
#: show an open eye more clearly than any surface that was no eye did on the cached unseen heads
#: (the blinks' best optima 9.5-12.1 deg, closed lids' bulges 12.4-12.9 deg and 18.3-19.7 mm,
#: the optima the margin test let through on the blinks `n3008_blink_200k_noise` 12.9-13.5 deg and
#: `n3208_blink_holes` 20.9 mm, and the rejected lowest optima of `id330_icteye_down` 13.6-14.1
#: deg), where those it let through on open eyes were ringed by 16.5-23.5 deg on 13.9-16.0 mm.
REPLACEMENT_MAX_RADIUS_MM = LID_BULGE_RADIUS_MM
REPLACEMENT_MIN_FOLD_DEG = 15.0


def passed_over_why(modes, ok) -> str:
    """Why the lowest of ``modes`` is no eye of this side, or "" when it may be one: the reason
    ``ok`` (callable ``Mode -> str``, "" where the mode may be an eye; or None) gives for it
    (``off_margin``, ``below_margin``: :func:`pipeline.placement.place._admissible`), else
    ``weak_fold`` where it is a sphere over ``REPLACEMENT_MAX_RADIUS_MM`` ringed by a fold between
    ``LID_BULGE_FOLD_DEG`` (under it: a closed lid's bulge, refused as closed) and
    ``REPLACEMENT_MIN_FOLD_DEG``. Over the 385 eyes the geometry placed on the cached unseen heads,
    the five placed on such a sphere were all wrong: a 100k-face photogrammetry head's left on a
    21 mm sphere over its cheek (10.96 mm off, the cut round it then torn through the cheek), a
    60k-face head's (7.71 mm), a blink's closed eye (16.4 mm) and two half blinks' turned 23-27
    deg; open eyes on spheres that large were ringed by 17-28 deg."""
    if not modes:
        return ""
    why = ok(modes[0]) if ok is not None else ""
    if why:
        return why
    m = modes[0]
    if m.eye.R > REPLACEMENT_MAX_RADIUS_MM and LID_BULGE_FOLD_DEG <= m.fold_deg < REPLACEMENT_MIN_FOLD_DEG:
        return "weak_fold"
    return ""


def admitted(modes, ok):
    """``modes`` (the lowest first) as they are when the lowest may be an eye of this side
    (:func:`passed_over_why`); else those ``ok`` (callable ``Mode -> str``, or None) gives no
    reason against on a sphere of at most ``REPLACEMENT_MAX_RADIUS_MM`` ringed by a fold of at
    least ``REPLACEMENT_MIN_FOLD_DEG``, or all of them when there are none (the caller then judges
    the lowest as before)."""
    if not passed_over_why(modes, ok):
        return modes
    kept = [m for m in modes if (ok is None or not ok(m)) and m.eye.R <= REPLACEMENT_MAX_RADIUS_MM
            and m.fold_deg >= REPLACEMENT_MIN_FOLD_DEG]
    return kept or modes


def place_eyes(V, F, hints, *, patch_radius_mm, radius_range, radius_prior, prior=None,
               ignore=None, seed=0, temperature=20.0, sigma_scale=1.0, shared_radius_z=2.5,
               sym_sigma_mm=1.0, min_fold_deg=20.0, coarse_vertices=COARSE_VERTICES, admissible=None):
    """Place both eyes (module doc). ``prior``: callable ``(side) -> dict(front, axis, sigma)``
    or None. ``admissible``: callable ``(side, Mode) -> str`` or None: a lowest optimum it gives
    a reason against is no eye of that side (an eye whose limbus lies outside the lid margin the
    skin round it outlines, or whose centre lies below it), nor is a lowest optimum on a large
    sphere weakly ringed
    (:func:`passed_over_why`), and the lowest optimum it admits is placed instead, the rejected
    ones left out of its rivals (:func:`admitted`); that placement is marked ``passed_over``
    with the reason. The
    search runs on each patch simplified to about ``coarse_vertices``
    (:func:`pipeline.placement.cues.coarse_patch`; a patch with fill faces as it is), and the
    placed eye then labels the full patch. Only local optima ringed by a lid fold of ``min_fold_deg`` count as an open eye;
    an eye with none is returned as None (closed, or nothing eye-like near the hint), and one
    whose folded optima all rest on a bound of the radius range as :class:`AtRadiusBound`.
    Returns ``{side: Placement, AtRadiusBound or None}``."""
    rng = np.random.default_rng(seed)
    patches, full, cues, drawn = {}, {}, {}, {}
    for s in SIDES:
        full[s] = build_patch(V, F, hints[s], patch_radius_mm, ignore)
        filled = ignore is not None and bool(np.asarray(ignore, bool)[full[s].faces].any())
        patches[s] = full[s] if filled else coarse_patch(full[s], coarse_vertices)
        pr = prior(s) if prior is not None else None
        cues[s] = Cues(front=None if pr is None else pr["front"], axis=None if pr is None else pr["axis"],
                       front_sigma=4.0 if pr is None else pr["sigma"], radius_prior=radius_prior)
        drawn[s] = hypothesis_pairs(patches[s], rng)
    # the two eyes' searches are independent and run side by side (pipeline.fork; the same bytes
    # with EYERIG_SERIAL=1): the left eye's hypotheses in a child beside the right eye's, then
    # the first rounds from both eyes' turned starts shared out evenly (an eye with a rival basin
    # has twice as many) with the midplane's search, then each eye's last part
    job = fork_call(_hypothesised, patches["left"], cues["left"], drawn["left"], radius_range, min_fold_deg,
                    laplace=True)
    found = {"right": _hypothesised(patches["right"], cues["right"], drawn["right"], radius_range, min_fold_deg)}
    found["left"] = fork_result(job)[0]
    starts = [(s, e) for s in SIDES for e in turned_starts(found[s], cues[s], min_fold_deg)]
    n_turned = len(starts)
    starts += [(s, e) for s in SIDES for e in cornea_starts(found[s], cues[s], min_fold_deg, radius_range)]

    def first_rounds(part):
        return [refine(patches[s], e, cues[s], radius_range, iters=1, fold=False) for s, e in part]

    half = min(len(starts), (len(starts) + MIDPLANE_ROUNDS + 1) // 2)
    job = fork_call(first_rounds, starts[:half])
    rest = first_rounds(starts[half:])
    xm = midplane_x(V, hints)
    first = fork_result(job)[0] + rest
    mine = {s: [m for (side, _), m in zip(starts[:n_turned], first) if side == s] for s in SIDES}
    cornea = {s: [m for (side, _), m in zip(starts[n_turned:], first[n_turned:]) if side == s] for s in SIDES}
    ok = {s: None if admissible is None else (lambda m, s=s: admissible(s, m)) for s in SIDES}
    job = fork_call(_finished, patches["left"], cues["left"], found["left"], mine["left"], radius_range,
                    min_fold_deg, laplace=True, cornea=cornea["left"], ok=ok["left"])
    done = {"right": _finished(patches["right"], cues["right"], found["right"], mine["right"], radius_range,
                               min_fold_deg, cornea=cornea["right"])}
    done["left"] = fork_result(job)[0]
    modes = {s: admitted(done[s][0], ok[s]) for s in SIDES}
    passed = {s: passed_over_why(done[s][0], ok[s]) if modes[s] and modes[s][0] is not done[s][0][0] else ""
              for s in SIDES}
    at_bound = {s: done[s][1] for s in SIDES if done[s][1] is not None}
    if not all(modes[s] for s in SIDES):
        return {s: at_bound.get(s) if not modes[s] else replace(_on_full(placement_of(
            patches[s], modes[s], None, temperature, sigma_scale), full[s]), passed_over=passed[s]) for s in SIDES}
    # an eye looking away from its partner is started from the partner's gaze too
    pst = {s: partner_starts(modes[s], modes[o]) for s, o in zip(SIDES, SIDES[::-1])}
    if pst["left"]:
        job = fork_call(partnered, patches["left"], cues["left"], modes["left"], pst["left"], radius_range,
                        min_fold_deg, laplace=True, ok=ok["left"])
    if pst["right"]:
        modes["right"] = partnered(patches["right"], cues["right"], modes["right"], pst["right"], radius_range,
                                   min_fold_deg)
    if pst["left"]:
        modes["left"] = fork_result(job)[0]
    again = {s: admitted(modes[s], ok[s]) for s in SIDES}
    passed = {s: passed[s] or (passed_over_why(modes[s], ok[s]) if again[s][0] is not modes[s][0] else "")
              for s in SIDES}
    modes = again
    best = {s: modes[s][0] for s in SIDES}
    # one radius for the two eyes when they agree; then a joint fit with a loose mirror prior
    sr = {s: float(np.sqrt(max(best[s].fit.cov[3, 3], 1e-6))) for s in SIDES}
    agree = abs(best["left"].eye.R - best["right"].eye.R) <= shared_radius_z * np.hypot(*sr.values())
    fit = fit_eyes([patches[s] for s in SIDES], [best[s].lab for s in SIDES],
                   [best[s].eye for s in SIDES], [cues[s] for s in SIDES], radius_range,
                   shared_radius=agree, xm=xm, sym_sigma=sym_sigma_mm)
    fit.cov         # noqa: B018 -- the joint fit's Laplace part, made once before the sides part

    def placed(i, s):
        """Side ``s``'s placement from the joint fit (its radius profile, its rivals), labelled
        on the full patch, which it does not carry (the caller's ``full[s]``)."""
        e = fit.eyes[i]
        lab, energy = segment(patches[s], e)
        m0 = Mode(e, lab, energy, fit, fold_deg(patches[s], lab))
        radii = np.arange(np.ceil(radius_range[0]), radius_range[1] + 1e-9, 1.0)
        prof = radius_profile(patches[s], e, cues[s], radii, lab=lab)
        pl = placement_of(patches[s], [m0] + modes[s][1:], (fit, i, agree), temperature, sigma_scale, prof)
        return replace(pl, patch=None, lab=pl.lab if patches[s] is full[s] else segment(full[s], pl.eye)[0])

    job = fork_call(placed, 0, "left")      # the two sides' profiles side by side, as their searches
    out = {"right": placed(1, "right")}
    out["left"] = fork_result(job)[0]
    out = {s: replace(out[s], patch=full[s], passed_over=passed[s]) for s in SIDES}
    return share_radius(out)


def _on_full(pl, full: Patch):
    """``pl`` with the scan's own patch, labelled under its eye: the cut follows the scan's
    vertices, whichever copy the eye was searched on."""
    if pl.patch is full:
        return pl
    return replace(pl, patch=full, lab=segment(full, pl.eye)[0])


def radius_profile(p: Patch, e: Eye, cues: Cues, radii, iters=PROFILE_ITERS, lab=None, max_nfev=PROFILE_NFEV):
    """The energy of the best eye at each radius of ``radii`` with its front held: the eye
    slides along its axis (the front of the globe is what the opening shows best), the centre
    and anterior cap are refitted and the surface segmented again. The scan's evidence on the
    radius is how fast this rises: a flat profile (little sclera, a squint) is a wide one.
    ``lab`` (n,) bool: the labels the first round fits to (default: a cut under the slid eye);
    the eye's own labels say where the opening is, whichever radius is tried.

    Returns ``(radii, energies, centres)``."""
    front = e.c + e.R * e.n
    E, C = [], []
    for R in radii:
        x = Eye(front - R * e.n, float(R), e.n, e.ha, e.tl, e.hb)
        for it in range(iters):
            lab_x = lab if it == 0 and lab is not None else segment(p, x)[0]
            x = fit_eyes([p], [lab_x], [x], [cues], (R, R), fixed_radius=float(R), max_nfev=max_nfev).eyes[0]
        lab_x, energy = segment(p, x)
        energy += 0.5 * float(np.sum(np.concatenate(list(prior_blocks(x, cues).values())) ** 2))
        E.append(energy)
        C.append(x.c)
    return np.asarray(radii, float), np.asarray(E), np.asarray(C)
