"""Building the eyelid blend shapes from the sealed eye-region mesh and the fitted eyeballs
(SynthesEyes paper, section 3.4; the shapes and the pitch-to-weight rule: :mod:`pipeline.rig.lids`).

* The eyelid margin (the loop where skin meets the eyeball) rotates about the
  eye's horizontal axis through the eyeball centre ``c``: the upper lid by
  ``gain_upper * pitch``, the lower lid by ``gain_lower * pitch`` (the lower lid
  moves less), tapered toward both canthi by :func:`canthus_taper` (a sine
  ramp over ``canthus_width`` of the lid width at the medial end and
  ``lateral_canthus_width`` at the lateral end, from the canthus gain, ``canthus_floor`` times
  the mean of the two lids' gains (``lateral_canthus_floor`` at the lateral canthus) and the
  same for both lids, to each lid's own in the middle;
  ``u`` = 0 at the medial and 1 at the lateral canthus, measured along the eye's
  horizontal axis). A rotation about ``c`` keeps every point at its
  distance from ``c``, so a margin that lies on the eyeball sphere stays on it.
* Skin around the margin rotates the same way with an angle that changes with
  the (edge-graph) geodesic distance ``D`` from the margin: ``theta(v) =
  S(D / R(v)) * (Theta(v) + (K(v) - Theta(v)) * (1 - S(D / Q(v))))``, where ``Theta``,
  ``K``, ``R`` and ``Q`` are harmonic extensions of the margin's angle gains, the
  lid skin's gains (``skin_gain_*``, tapered at the canthi like the margin's), the
  falloff radii (``upper_falloff_mm`` above, ``lower_falloff_mm`` below) and the rise
  distances (``upper_rise_mm``, ``lower_rise_mm``; 0 = the skin keeps the margin's gain
  and the skin gains are not used), and ``S`` is the C2 "smootherstep" falloff (``S(0) = 1``,
  ``S(1) = 0``, first and second derivatives zero at both ends): the gain goes from the
  margin's to the skin's over the rise distance and fades to zero at the falloff radius,
  so there is no visible step at the edge of the support and nothing moves beyond it.
  (ICT-FaceKit's captured visible lid keeps the margin's gain for 4-6 mm and then falls off,
  over about 11 mm above the upper lid looking down; benchmarks/compare_ict_lids.py.) Where
  the skin far from the pitch axis would be squeezed past zero thickness by the rising
  upper (or dropping lower) lid, the radii are widened by the smallest factor (up to
  ``max_support_scale``) that keeps every face of the full poses (but those on the margin, set
  by its gains) above
  ``min_area_fraction`` of its rest area (no fold-over).

Linear blend shapes move each point along the straight chord of its rotation
arc, which would sink the margin into the eyeball (for 25 degrees on a 15 mm
eye the sag at half weight is ~0.3 mm). Each shape therefore carries
*inbetweens* (UsdSkel ``inbetweens:<name>``) at the weights ``j / N``: the
posed mesh is sampled at ``N`` evenly spaced pitches and interpolated piecewise
linearly, with ``N`` chosen so the chord sag stays below ``max_chord_sag_mm``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pipeline.rig.eye_frame import EyeFrame, rotate_about_axis
from pipeline.rig.lids import SHAPE_DOWN, SHAPE_UP, BlendShape, LidParams, evaluate_shapes, lid_weights


#: Exponent of the lids' ramp beside a corner that stands off the globe (:func:`lid_angle_field`).
OFF_GLOBE_RAMP_EXPONENT = 2.0


def canthus_taper(u, width: float = 0.35, exponent: float = 1.0,
                  lateral_width: float | None = None) -> np.ndarray:
    """The ramp of the lid gain at horizontal position ``u`` (0 medial, 1 lateral canthus).

    ``sin(pi/2 * min(1, u / width, (1 - u) / lateral_width)) ** exponent``: 0 at both canthi, a
    plateau of 1 between the ramps (``width`` at the medial end, ``lateral_width``, default
    ``width``, at the lateral end; 0 = no ramp), C1 where ramp and plateau meet.
    ``width = 0.5, exponent = 1`` gives ``sin(pi u)``. The rig ramps each lid's gain from the
    canthus gain to its own by this share (:func:`lid_angle_field`).
    """
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    wm = float(width)
    wl = wm if lateral_width is None else float(lateral_width)
    for w in (wm, wl):
        if not 0.0 <= w <= 0.5:
            raise ValueError(f"canthus width must be in [0, 0.5], got {w!r}")
    xm = np.minimum(1.0, u / wm) if wm > 0 else np.ones_like(u)
    xl = np.minimum(1.0, (1.0 - u) / wl) if wl > 0 else np.ones_like(u)
    return np.sin(0.5 * np.pi * np.minimum(xm, xl)) ** float(exponent)


def smootherstep_falloff(t) -> np.ndarray:
    """C2 falloff: 1 at ``t <= 0``, 0 at ``t >= 1``, ``1 - (6t^5 - 15t^4 + 10t^3)`` between."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return 1.0 - t * t * t * (t * (6.0 * t - 15.0) + 10.0)


def mesh_edges(F) -> np.ndarray:
    """(e, 2) int64 unique undirected edges of a triangle mesh."""
    F = np.asarray(F, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E.sort(axis=1)
    E = E[E[:, 0] != E[:, 1]]
    return np.unique(E, axis=0)


def _edge_graph(V, E):
    from scipy.sparse import coo_matrix

    n = len(V)
    length = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    length = np.maximum(length, 1e-9)
    rows = np.concatenate([E[:, 0], E[:, 1]])
    cols = np.concatenate([E[:, 1], E[:, 0]])
    data = np.concatenate([length, length])
    return coo_matrix((data, (rows, cols)), shape=(n, n)).tocsr()


def _harmonic_extension(G, region, fixed, values):
    """Extend ``values`` (k, c) at ``fixed`` vertices harmonically over ``region``.

    Inverse-edge-length weighted graph Laplacian, Dirichlet at ``fixed``, natural
    (Neumann) boundary at the rim of ``region``. Returns (n, c), zero outside.
    """
    from scipy.sparse import csr_matrix, diags
    from scipy.sparse.linalg import splu

    n = G.shape[0]
    out = np.zeros((n, values.shape[1]))
    out[fixed] = values
    is_fixed = np.zeros(n, bool)
    is_fixed[fixed] = True
    free = np.flatnonzero(region & ~is_fixed)
    if len(free) == 0:
        return out
    keep = np.flatnonzero(region | is_fixed)
    W = G[keep][:, keep].tocsr()
    W = csr_matrix((1.0 / W.data, W.indices, W.indptr), shape=W.shape)
    pos = np.full(n, -1)
    pos[keep] = np.arange(len(keep))
    fi, ci = pos[free], pos[fixed]
    deg = np.asarray(W.sum(axis=1)).ravel()
    A_ff = (diags(deg[fi]) - W[fi][:, fi]).tocsc()
    rhs = W[fi][:, ci] @ values
    out[free] = splu(A_ff).solve(np.asarray(rhs))
    return out


@dataclass
class EyeField:
    """Per-vertex lid rotation of one eye at full weight (diagnostics and reuse).

    Attributes
    ----------
    theta_up, theta_down : (n,) float64
        Rotation angle about ``eye.axis`` at weight 1 of lids_up / lids_down, radians.
    distance : (n,) float64
        Edge-graph distance from the margin loop, mm (inf beyond the support search).
    falloff : (n,) float64
        ``S(D / R)`` in [0, 1].
    loop_u : (L,) float64
        Horizontal position of each margin vertex, 0 medial .. 1 lateral canthus.
    support_mm : float
        Largest falloff radius used (the skin support), mm: ``upper/lower_falloff_mm``, widened
        (up to ``max_support_scale``) where the full poses would squeeze a face below
        ``min_area_fraction`` of its rest area (skin folding over).
    """

    theta_up: np.ndarray
    theta_down: np.ndarray
    distance: np.ndarray
    falloff: np.ndarray
    loop_u: np.ndarray
    support_mm: float = 0.0


def _keep_lids_apart(W, B, u, upper, lower, gain_up, gain_dn, pmax, frac):
    """Limit the margin gains so the upper lid stays above the lower lid in both full poses.

    A rotation about the pitch axis changes a margin point's angle ``phi`` about that
    axis by exactly the rotation angle and keeps its horizontal coordinate, so along
    each vertical line the opening is ``phi_upper - phi_lower`` (for points on the
    sphere). Each pose must keep at least ``frac`` of the rest opening: in the down pose
    the upper lid may not drop farther than the lower lid below it plus
    ``(1 - frac)`` of the opening, and vice versa for the lower lid in the up pose.
    """
    phi = np.arctan2(W @ B[1], W @ B[2])
    iu, il = np.flatnonzero(upper), np.flatnonzero(lower)
    if len(iu) < 1 or len(il) < 1:
        return gain_up, gain_dn
    gain_up, gain_dn = gain_up.copy(), gain_dn.copy()
    ol, ou = np.argsort(u[il]), np.argsort(u[iu])
    # lower lid under each upper point, upper lid over each lower point
    phi_lo = np.interp(u[iu], u[il][ol], phi[il][ol])
    dn_lo = np.interp(u[iu], u[il][ol], gain_dn[il][ol])
    phi_up = np.interp(u[il], u[iu][ou], phi[iu][ou])
    up_up = np.interp(u[il], u[iu][ou], gain_up[iu][ou])
    slack_u = np.maximum(phi[iu] - phi_lo, 0.0) * (1.0 - frac) / pmax
    slack_l = np.maximum(phi_up - phi[il], 0.0) * (1.0 - frac) / pmax
    gain_dn[iu] = np.minimum(gain_dn[iu], dn_lo + slack_u)       # upper lid going down
    gain_up[il] = np.minimum(gain_up[il], up_up + slack_l)       # lower lid going up
    return gain_up, gain_dn


def limit_margin_shear(P, gain, pmax: float, rho, max_shear: float) -> np.ndarray:
    """Lower the margin gains where they change faster along the loop than ``max_shear`` allows.

    Neighbouring margin points ``i``, ``j`` (distance ``d``, ``rho`` from the pitch axis) part
    by about ``rho * pmax * |g_i - g_j|`` in a full pose, beyond turning together. Where that
    nears ``d`` the segment between them turns over, and so does the face it shares with the
    skin: the canthus ramps (infinite slope at the corner for ``canthus_exponent`` < 1) do this
    on a loop sampled finer than a millimetre. The result is the largest ``g' <= g`` with
    ``|g'_i - g'_j| <= max_shear * d / (max(rho_i, rho_j) * pmax)`` along the closed loop ``P``
    (the lower Lipschitz envelope); gains that change slowly are kept as they are.

    Parameters
    ----------
    P : (k, 3) float64
        Loop points in order (closed).
    gain : (k,) float64
    pmax : float
        Full pose pitch, radians.
    rho : (k,) float64
        Each point's distance from the pitch axis, mm.
    max_shear : float
        Largest displacement difference of neighbours per mm between them.

    Returns
    -------
    (k,) float64
    """
    g = np.array(gain, dtype=np.float64, copy=True)
    k = len(g)
    if k < 2 or pmax <= 0:
        return g
    rho = np.broadcast_to(np.asarray(rho, dtype=np.float64), (k,))
    lever = np.maximum(np.maximum(rho, np.roll(rho, -1)), 1e-9) * pmax
    step = np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1) * max_shear / lever  # i -> i + 1
    # two sweeps each way round the closed loop reach every vertex from every other one
    for _ in range(2):
        for i in range(1, 2 * k):
            a, b = (i - 1) % k, i % k
            g[b] = min(g[b], g[a] + step[a])
        for i in range(2 * k - 2, -1, -1):
            a, b = (i + 1) % k, i % k
            g[b] = min(g[b], g[a] + step[b])
    return g


def lid_angle_field(V, F, eye: EyeFrame, params: LidParams, graph=None) -> EyeField:
    """Rotation angle of every vertex for the full lids_up and lids_down poses of one eye.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    eye : EyeFrame
    params : LidParams
    graph : scipy.sparse matrix, optional
        Edge-length graph of (V, F), reused across eyes.

    Returns
    -------
    EyeField
    """
    from scipy.sparse.csgraph import dijkstra

    V = np.asarray(V, dtype=np.float64)
    G = _edge_graph(V, mesh_edges(F)) if graph is None else graph
    loop = np.asarray(eye.loop, dtype=np.int64)
    L, li = len(loop), int(eye.lateral_index)
    B = eye.basis()
    x = (V[loop] - eye.center) @ B[0]
    x0, x1 = x[0], x[li]
    u = np.clip((x - x0) / (x1 - x0), 0.0, 1.0) if abs(x1 - x0) > 1e-9 else np.zeros(L)
    # Corners off the globe (snap left them there, eye.on_eye False) keep their canthus's gain:
    # the lids ramp up from where they meet the eye (the caruncle and the corner skin barely
    # follow the gaze, and a ramp across a corner standing millimetres off the eye shears the
    # faces between it and the eye).
    ut, exponent = u, params.canthus_exponent
    off = np.zeros(L, bool) if eye.on_eye is None else ~np.asarray(eye.on_eye, bool)
    if off.any():
        um = max(u[off & (u < 0.5)].max(initial=0.0), 0.0)
        ul = min(u[off & (u >= 0.5)].min(initial=1.0), 1.0)
        ut = np.clip((u - um) / max(ul - um, 1e-9), 0.0, 1.0)
        # and start flat: a ramp as steep as the capture's (exponent < 1, infinite slope) turns
        # the first lid vertex beside such a corner millimetres past it, and the strip closing the
        # corner folds
        exponent = max(exponent, OFF_GLOBE_RAMP_EXPONENT)
    ramp = canthus_taper(ut, params.canthus_width, exponent, params.lateral_canthus_width)
    ramp[[0, li]] = 0.0
    ramp[off] = 0.0
    # which canthus's ramp a point is on: the medial one up to where the two ramps meet
    wm, wl = params.canthus_width, params.lateral_canthus_width
    medial = u <= (wm / (wm + wl) if wm + wl > 0 else 0.5)
    medial[[0, li]] = [True, False]
    upper = np.zeros(L, bool)
    upper[1:li] = True
    lower = np.zeros(L, bool)
    lower[li + 1:] = True

    def per_lid(a, b):
        return np.where(upper, a, np.where(lower, b, 0.5 * (a + b)))

    def tapered(a, b):
        # Both lids ramp from the same canthus gain (the floor share of their mean) to their own:
        # a floor taken of each lid's own gain parts the two lids right at the corner, and the
        # corner faces (two margin points and the skin beyond) shear over (the rig tests' narrow
        # opening on the cornea folded so).
        corner = np.where(medial, params.canthus_floor, params.lateral_canthus_floor) * 0.5 * (a + b)
        return corner + (per_lid(a, b) - corner) * ramp

    gain_up = tapered(params.gain_upper_up, params.gain_lower_up)
    gain_dn = tapered(params.gain_upper_down, params.gain_lower_down)
    pmax = math.radians(params.max_pitch_deg)
    rho = np.linalg.norm(np.cross(V[loop] - eye.center, eye.axis), axis=1)
    # both rules only lower gains, so alternating them settles; keeping the lids apart goes last
    for _ in range(4 if params.max_margin_shear > 0 else 1):
        if params.max_margin_shear > 0:
            gain_up = limit_margin_shear(V[loop], gain_up, pmax, rho, params.max_margin_shear)
            gain_dn = limit_margin_shear(V[loop], gain_dn, pmax, rho, params.max_margin_shear)
        gain_up, gain_dn = _keep_lids_apart(V[loop] - eye.center, B, u, upper, lower, gain_up,
                                            gain_dn, pmax, params.min_opening_fraction)
    skin_up = tapered(params.skin_gain_upper_up, params.skin_gain_lower_up)
    skin_dn = tapered(params.skin_gain_upper_down, params.skin_gain_lower_down)
    radius = per_lid(params.upper_falloff_mm, params.lower_falloff_mm)
    rise = per_lid(params.upper_rise_mm, params.lower_rise_mm)
    # Skin turning by Theta * S(D / R) is compressed where the motion falls off fast along D
    # (above the upper lid when it rises, below the lower lid when it drops): neighbours differ
    # in arc displacement by about rho * Theta * |S'(D / R)| / R per mm (rho = distance from the
    # pitch axis), and the skin folds over (faces flip) near 1. The falloff radii are scaled by
    # the smallest factor (steps of 5 %, from 1) for which no face of the full poses keeps less
    # than min_area_fraction of its area seen along its rest normal.
    F = np.asarray(F, dtype=np.int64)
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a0 = np.linalg.norm(n0, axis=1)
    # Faces with a margin vertex are left out of that test: the margin's gains set their shape
    # (S is flat at the margin, so no radius changes them) and the sweep refuses any that flips;
    # judged here, one squeezed corner face widened the whole eye's support to its limit.
    on_margin = np.zeros(len(V), bool)
    on_margin[loop] = True
    judged = ~on_margin[F].any(axis=1) & (a0 > 1e-12)
    for scale in np.arange(1.0, params.max_support_scale + 1e-9, 0.05):
        r_max = float(radius.max()) * scale
        D = dijkstra(G, directed=False, indices=loop, min_only=True, limit=r_max * 1.0001)
        region = np.isfinite(D)
        ext = _harmonic_extension(G, region, loop, np.stack([gain_up, gain_dn, scale * radius,
                                                             skin_up, skin_dn, scale * rise], axis=1))
        R = np.where(region, np.maximum(ext[:, 2], 1e-6), 1.0)
        Dr = np.where(region, D, 0.0)
        S = np.where(region, smootherstep_falloff(Dr / R), 0.0)
        # share of the skin's gain: 0 at the margin, 1 from the rise distance on (none where the
        # rise distance is 0: the skin keeps the margin's gain)
        Q = ext[:, 5]
        k = np.where(Q > 1e-6, 1.0 - smootherstep_falloff(Dr / np.maximum(Q, 1e-6)), 0.0)
        k[loop] = 0.0
        g_up = ext[:, 0] + (ext[:, 3] - ext[:, 0]) * k
        g_dn = ext[:, 1] + (ext[:, 4] - ext[:, 1]) * k
        th_up, th_dn = pmax * g_up * S, -pmax * g_dn * S
        worst = np.inf
        for th in (th_up, th_dn):
            mv = np.flatnonzero(th != 0.0)
            P = V.copy()
            P[mv] = rotate_about_axis(V[mv], eye.center, eye.axis, th[mv])
            fm = np.flatnonzero(region[F].any(axis=1) & judged)
            n1 = np.cross(P[F[fm, 1]] - P[F[fm, 0]], P[F[fm, 2]] - P[F[fm, 0]])
            if len(fm):
                worst = min(worst, float(np.min(np.einsum("ij,ij->i", n1, n0[fm]) / a0[fm] ** 2)))
        if worst >= params.min_area_fraction:
            break
    return EyeField(theta_up=th_up, theta_down=th_dn, distance=D, falloff=S, loop_u=u,
                    support_mm=r_max)


def n_segments_for_sag(dist_to_axis, theta, max_sag_mm: float, max_segments: int) -> int:
    """Fewest even pitch segments whose chord sag ``d (1 - cos(theta / 2N))`` stays below a bound."""
    d = np.asarray(dist_to_axis, float)
    th = np.abs(np.asarray(theta, float))
    for n in range(1, int(max_segments) + 1):
        if d.size == 0 or float(np.max(d * (1.0 - np.cos(th / (2.0 * n))))) <= max_sag_mm:
            return n
    return int(max_segments)


@dataclass
class LidRig:
    """The lid blend shapes of a mesh and how they were made.

    Attributes
    ----------
    shapes : list of BlendShape
        ``lids_up`` and ``lids_down``.
    fields : dict
        ``side -> EyeField``.
    n_segments : int
        Stored poses per direction (inbetweens = n_segments - 1).
    predicted_sag_mm : float
        Largest drift of the margin from its rest surface offset, or sinking of moved skin
        below ``min(rest clearance, 0)``, at the mid-points between stored poses (where
        piecewise-linear interpolation deviates most), mm.
    """

    shapes: list
    fields: dict
    n_segments: int
    predicted_sag_mm: float

    def shape(self, name: str) -> BlendShape:
        return next(s for s in self.shapes if s.name == name)


def pose_points(P, eyes, angles_by_side: dict, scale: float = 1.0) -> np.ndarray:
    """Rotate points ``P`` by each eye's angle field times ``scale`` (displacements summed).

    Parameters
    ----------
    P : (n, 3) float64
    eyes : sequence of EyeFrame
    angles_by_side : dict
        ``side -> (n,) radians``.
    """
    P = np.asarray(P, dtype=np.float64)
    out = P.copy()
    for eye in eyes:
        th = angles_by_side[eye.side] * scale
        moving = np.flatnonzero(th != 0.0)
        if len(moving):
            out[moving] += rotate_about_axis(P[moving], eye.center, eye.axis, th[moving]) - P[moving]
    return out


def follow_surface(P, eye: EyeFrame, pitch_deg: float, rest_clearance,
                   follow_mm: float) -> np.ndarray:
    """Push posed points radially so skin lying on a non-spherical eyeball does not sink into it.

    A rotation about the eye centre keeps every point at its distance from the centre, so
    on the eyeball *sphere* the lid rotation alone keeps each point's clearance. The
    parametric eye's cornea (pipeline.eyeball) bulges out of the sphere by up to
    ``b = R_surface(gaze) - radius`` and turns with the eye by the full pitch, while the
    skin turns by less (lid gain < 1, geodesic falloff): the bulge slides under the skin,
    and skin near the lid margin -- or lower-lid skin several mm away when looking down --
    would end up inside the eye. Each point therefore gets back the share

        ``w = S(|c0| / H)``,  ``H = max(follow_mm, 1.25 b)``

    of the clearance it lost, ``dr = w (c0 - c1)`` along its ray from the centre, where
    ``c0`` is its rest clearance, ``c1`` its clearance from the pitched surface after the
    rotation and ``S`` the C2 smootherstep falloff. Points on the eye (``c0 = 0``, the
    margin included) keep their rest clearance exactly, points ``H`` or more off (or inside)
    it are left alone. Because ``c1 >= c0 - b`` and ``x / (1 - S(x)) >= 0.835`` on [0, 1],
    ``H >= 1.2 b`` guarantees ``c0 + dr >= 0`` for every ``c0 >= 0``. ``w`` and ``dr`` are
    smooth functions of position, so the push has no step or kink (unlike a projection
    onto the surface, which would crease the skin where contact starts).

    Parameters
    ----------
    P : (n, 3) float64
        Posed points (rest points rotated by the lid angle field), mm.
    eye : EyeFrame
        The eye, with its ``profile``; a sphere (``profile`` None) needs no push.
    pitch_deg : float
        Eyeball pitch of the pose, degrees.
    rest_clearance : (n,) float64
        ``eye.surface_distance(V, 0.0)`` of the rest points, mm.
    follow_mm : float
        Rest clearance at which the push has faded out (floor of ``H``), mm.

    Returns
    -------
    (n, 3) float64
        The pushed points (a copy).
    """
    P = np.array(P, dtype=np.float64, copy=True)
    if eye.profile is None:
        return P
    c0 = np.asarray(rest_clearance, dtype=np.float64)
    bulge = float(eye.surface_radius(eye.center[None] + eye.forward[None], 0.0)[0]) - eye.radius
    H = max(float(follow_mm), 1.25 * max(bulge, 0.0), 1e-9)
    w = smootherstep_falloff(np.abs(c0) / H)
    idx = np.flatnonzero(w > 0.0)
    if len(idx) == 0:
        return P
    dr = w[idx] * (c0[idx] - eye.surface_distance(P[idx], pitch_deg))
    ray = P[idx] - eye.center
    P[idx] += ray / np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12) * dr[:, None]
    return P


def near_eye_skin(V, shapes, eyes) -> dict:
    """Moved skin near each eye: ``side -> (k,) int64`` indices of the vertices some shape
    moves, excluding every eyelid margin and corner strip, within two eyeball radii of that eye's
    centre."""
    moved = np.zeros(len(V), bool)
    for s in shapes:
        moved[s.point_indices] = True
    for e in eyes:
        moved[e.loop] = False
        moved[e.strip_inner] = False     # inside the eye by design (corner strips)
    return {e.side: np.flatnonzero(moved & (np.linalg.norm(V - e.center, axis=1) < 2.0 * e.radius))
            for e in eyes}


class _SurfaceFollow:
    """Keeps the margin and the skin on a non-spherical eyeball (see :func:`follow_surface`)."""

    def __init__(self, V, eyes, params: LidParams):
        self.eyes = [e for e in eyes if e.profile is not None]
        self.eyes_all = list(eyes)
        self.follow_mm = float(params.surface_follow_mm)
        self.rest = {e.side: e.surface_distance(V, 0.0) for e in self.eyes}
        for rest in self.rest.values():     # corner strips turn with their lid, never pushed
            for e in eyes:
                rest[e.strip_inner] = np.inf

    def apply(self, P, eye: EyeFrame, pitch_deg: float) -> np.ndarray:
        """Posed points ``P`` pushed off the pitched eyeball surface of one eye."""
        return follow_surface(P, eye, pitch_deg, self.rest[eye.side], self.follow_mm)

    def interpolation_error(self, V, shapes, n_seg, max_pitch) -> float:
        """Largest interpolation error at the mid-points between stored poses, mm.

        The larger of the margin's drift from its rest surface offset and the depth by which
        moved skin near the eye sinks below ``min(rest clearance, 0)`` (skin lying on the
        eye sees the same chord sag as the margin; stored poses keep it out by
        :func:`follow_surface`).
        """
        all_eyes = self.eyes_all
        skin = near_eye_skin(V, shapes, all_eyes)
        near = {}
        for e in all_eyes:
            sel = skin[e.side]
            near[e.side] = (sel, np.minimum(e.surface_distance(V[sel], 0.0), 0.0),
                            e.surface_distance(V[e.margin], 0.0))
        worst = 0.0
        for j in range(n_seg):
            for sign in (1.0, -1.0):
                p = sign * max_pitch * (j + 0.5) / n_seg
                P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch))
                for e in all_eyes:
                    sel, floor, d0 = near[e.side]
                    worst = max(worst, float(np.abs(e.surface_distance(P[e.margin], p) - d0).max()))
                    if len(sel):
                        worst = max(worst, float(np.max(floor - e.surface_distance(P[sel], p))))
        return worst


def _lid_shape(V, eyes, fields, follow: _SurfaceFollow, name, key, n_seg, params) -> BlendShape:
    sign = 1.0 if name == SHAPE_UP else -1.0
    poses = []
    for j in range(1, n_seg + 1):
        frac = j / n_seg
        P = pose_points(V, eyes, {e.side: getattr(fields[e.side], key) for e in eyes}, frac)
        for e in follow.eyes:
            P = follow.apply(P, e, sign * params.max_pitch_deg * frac)
        poses.append(P - V)
    poses = np.stack(poses)
    moved = np.flatnonzero(np.max(np.linalg.norm(poses, axis=2), axis=0) > params.min_offset_mm)
    return BlendShape(name=name, point_indices=moved.astype(np.int64), offsets=poses[-1][moved],
                      inbetween_weights=np.arange(1, n_seg) / n_seg,
                      inbetween_offsets=poses[:-1][:, moved])


def _strip_angles(F, loop, q, p, theta):
    """(len(q),) angles for corner-strip vertices ``q`` (hanging from loop vertices ``p``): the
    harmonic interpolation over the strip's edges of the angles of the loop vertices it meets
    (each strip vertex the mean of its strip and loop neighbours'; its own ``p``'s where its part
    of the strip meets no loop vertex). A strip vertex turned with its own loop vertex alone shears
    the faces it shares with the next: a medial strip fanned round the first upper-lid vertex but
    hung from the canthus turned 0.42 mm against it at pitch -25 deg, across a face 0.38 mm high,
    and folded (n3002_in_up). Turned about the eye's axis by any angle, a vertex keeps its distance
    from the centre: the strip stays inside the eye."""
    q = np.asarray(q, dtype=np.int64)
    loop = np.asarray(loop, dtype=np.int64)
    m = len(q)
    local = {int(v): j for j, v in enumerate(q)}
    on_loop = set(map(int, loop))
    # only the faces that hold a strip vertex carry its edges (the whole mesh's edge list, made
    # and walked here, was a tenth of the rig stage); np.unique keeps the edges in the same order
    Fq = F[np.isin(F, q).any(axis=1)]
    E = np.concatenate([Fq[:, [0, 1]], Fq[:, [1, 2]], Fq[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    Lq = np.zeros((m, m))
    rhs = np.zeros(m)
    for a, b in E:
        for x, y in ((int(a), int(b)), (int(b), int(a))):
            if x not in local:
                continue
            i = local[x]
            if y in local:
                Lq[i, i] += 1.0
                Lq[i, local[y]] -= 1.0
            elif y in on_loop:
                Lq[i, i] += 1.0
                rhs[i] += theta[y]
    out = np.array(theta[np.asarray(p, dtype=np.int64)], dtype=np.float64)
    # the strip vertices joined to the loop through the strip are solved for; a part that meets no
    # loop vertex keeps its own p's angle
    strip_nbrs = np.abs(Lq).sum(axis=1) - np.diag(Lq)
    reach = np.diag(Lq) - strip_nbrs > 0.5
    frontier = reach.copy()
    while frontier.any():
        frontier = (Lq[:, frontier] < 0).any(axis=1) & ~reach
        reach |= frontier
    if reach.any():
        out[reach] = np.linalg.solve(Lq[np.ix_(reach, reach)], rhs[reach])
    return out


def build_lid_shapes(V, F, eyes, params: LidParams | None = None) -> LidRig:
    """Compute the ``lids_up`` and ``lids_down`` blend shapes (with inbetweens).

    Parameters
    ----------
    V : (n, 3) float64
        Sealed eye-region vertices, mm, head frame (margins on the eyeball spheres).
    F : (m, 3) int64
    eyes : sequence of EyeFrame
    params : LidParams, optional

    Returns
    -------
    LidRig
    """
    params = params or LidParams()
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    # corner strips (inside the eye at one edge) take no part in the skin's fields: each strip
    # vertex turns exactly with the loop vertex it hangs from, so it stays inside the eye
    inner = np.zeros(len(V), bool)
    for e in eyes:
        inner[e.strip_inner] = True
    F_skin = F[~inner[F].any(axis=1)]
    G = _edge_graph(V, mesh_edges(F_skin))
    fields = {e.side: lid_angle_field(V, F_skin, e, params, graph=G) for e in eyes}
    for e in eyes:
        if e.strip is not None:
            f = fields[e.side]
            q, p = e.strip[:, 0], e.strip[:, 1]
            up, dn = _strip_angles(F, e.loop, q, p, f.theta_up), _strip_angles(F, e.loop, q, p, f.theta_down)
            f.theta_up[q], f.theta_down[q] = up, dn
            f.distance[q], f.falloff[q] = 0.0, 1.0
    n_seg, sag = 1, 0.0
    for e in eyes:
        w = V - e.center
        d_axis = np.linalg.norm(w - np.outer(w @ e.axis, e.axis), axis=1)
        f = fields[e.side]
        for th in (f.theta_up, f.theta_down):
            n_seg = max(n_seg, n_segments_for_sag(d_axis, th, params.max_chord_sag_mm,
                                                  params.max_segments))
    follow = _SurfaceFollow(V, eyes, params)
    while True:
        shapes = [_lid_shape(V, eyes, fields, follow, name, key, n_seg, params)
                  for name, key in ((SHAPE_UP, "theta_up"), (SHAPE_DOWN, "theta_down"))]
        sag = follow.interpolation_error(V, shapes, n_seg, params.max_pitch_deg)
        if sag <= params.max_chord_sag_mm or n_seg >= params.max_segments:
            break
        n_seg += 1
    return LidRig(shapes=shapes, fields=fields, n_segments=n_seg, predicted_sag_mm=sag)

