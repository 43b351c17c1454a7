"""Eyelid blend shapes driven by eyeball pitch (SynthesEyes paper, section 3.4).

Two blend shapes, ``lids_up`` (eyes pitched up by ``max_pitch_deg``) and
``lids_down`` (pitched down by the same angle), are computed automatically from
the sealed eye-region mesh and the fitted eyeball spheres:

* The eyelid margin (the loop where skin meets the eyeball) rotates about the
  eye's horizontal axis through the eyeball centre ``c``: the upper lid by
  ``gain_upper * pitch``, the lower lid by ``gain_lower * pitch`` (the lower lid
  moves less), tapered to zero at both canthi by :func:`canthus_taper` (a sine
  ramp over ``canthus_width`` of the lid width at each end, 1 in the middle;
  ``u`` = 0 at the medial and 1 at the lateral canthus, measured along the eye's
  horizontal axis). A rotation about ``c`` keeps every point at its
  distance from ``c``, so a margin that lies on the eyeball sphere stays on it.
* Skin around the margin rotates the same way with an angle that fades with
  the (edge-graph) geodesic distance ``D`` from the margin: ``theta(v) =
  Theta(v) * S(D / R(v))``, where ``Theta`` and ``R`` are harmonic extensions of
  the margin's angle gains and falloff radii (``upper_falloff_mm`` above,
  ``lower_falloff_mm`` below) and ``S`` is the C2 "smootherstep" falloff
  (``S(0) = 1``, ``S(1) = 0``, first and second derivatives zero at both ends),
  so there is no visible step at the edge of the support and nothing moves
  beyond it. Where the skin far from the pitch axis would be squeezed past zero
  thickness by the rising upper (or dropping lower) lid, the radii are widened by
  the smallest factor (up to ``max_support_scale``) that keeps every face of the
  full poses above ``min_area_fraction`` of its rest area (no fold-over).

Linear blend shapes move each point along the straight chord of its rotation
arc, which would sink the margin into the eyeball (for 25 degrees on a 15 mm
eye the sag at half weight is ~0.3 mm). Each shape therefore carries
*inbetweens* (UsdSkel ``inbetweens:<name>``) at the weights ``j / N``: the
posed mesh is sampled at ``N`` evenly spaced pitches and interpolated piecewise
linearly, with ``N`` chosen so the chord sag stays below ``max_chord_sag_mm``.

The pitch-to-weight rule (:func:`lid_weights`, documented in
:data:`WEIGHT_RULE`) is the single function that the renderer and the USD
stage use; it is stored in the asset. For shape-key systems without
inbetweens (Blender shape keys) :func:`flat_shape_weights` expands channel
weights to one weight per stored pose (hat functions), which gives exactly the
same points as the UsdSkel inbetween evaluation (:func:`evaluate_shapes`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis  # noqa: F401 (also lids.eye_basis)
from pipeline.settings import Settings, setting

SHAPE_UP = "lids_up"
SHAPE_DOWN = "lids_down"
MAX_PITCH_DEG = 25.0

#: The pitch-to-weight rule, as stored in the asset (rig.json, USD metadata).
WEIGHT_RULE = {
    "function": "pipeline.rig.lids.lid_weights (pitch from pipeline.rig.lids.pitch_from_gaze)",
    "formula": "w_lids_up = clamp(pitch_deg / max_pitch_deg, 0, 1); "
               "w_lids_down = clamp(-pitch_deg / max_pitch_deg, 0, 1)",
    "pitch_definition": "gaze elevation relative to the rest gaze, degrees, positive = looking up: "
                        "pitch_deg = degrees(asin(g_y) - asin(forward_y)) for the head-frame unit "
                        "gaze g and the eye's rest forward (eyes.<side>.forward); for a pure pitch "
                        "this is the eyeball's rotation about its horizontal axis (through the "
                        "centre, perpendicular to forward and head +Y). Both eyes share one pitch "
                        "(use their mean if they differ).",
    "channels": [SHAPE_UP, SHAPE_DOWN],
    "inbetweens": "UsdSkel semantics: a channel weight w between two stored poses (implicit 0, "
                  "inbetween weights, 1) interpolates their offsets linearly; see "
                  "pipeline.rig.lids.evaluate_shapes / flat_shape_weights",
}


def weight_rule(max_pitch_deg: float = MAX_PITCH_DEG) -> dict:
    """The pitch-to-weight rule as metadata for the asset: :data:`WEIGHT_RULE` plus its parameter."""
    return {**WEIGHT_RULE, "max_pitch_deg": float(max_pitch_deg)}


def pitch_from_gaze(gaze, forward) -> float:
    """Lid-rule pitch of a head-frame gaze direction: its elevation above the rest gaze, degrees.

    ``degrees(asin(g_y) - asin(f_y))`` with ``g``, ``f`` normalised; positive = looking up.

    Parameters
    ----------
    gaze : (3,) float64
        Gaze direction in the head frame.
    forward : (3,) float64
        The eye's rest forward direction (rig.json ``eyes.<side>.forward``).
    """
    g = np.asarray(gaze, dtype=np.float64)
    f = np.asarray(forward, dtype=np.float64)
    g, f = g / np.linalg.norm(g), f / np.linalg.norm(f)
    return math.degrees(math.asin(float(np.clip(g[1], -1, 1))) - math.asin(float(np.clip(f[1], -1, 1))))


def lid_weights(pitch_deg: float, max_pitch_deg: float = MAX_PITCH_DEG) -> dict[str, float]:
    """Blend-shape channel weights for an eyeball pitch: THE pitch-to-weight rule.

    ``w_lids_up = clamp(pitch / max_pitch, 0, 1)``,
    ``w_lids_down = clamp(-pitch / max_pitch, 0, 1)``.

    Parameters
    ----------
    pitch_deg : float
        Eyeball pitch from its rest orientation, degrees, positive = looking up.
    max_pitch_deg : float
        Pitch at which each shape reaches weight 1 (the anatomical limit, 25 deg).

    Returns
    -------
    dict
        ``{"lids_up": w_up, "lids_down": w_down}``, each in [0, 1], at most one non-zero.
    """
    p = float(pitch_deg)
    m = float(max_pitch_deg)
    if not math.isfinite(p):
        raise ValueError(f"pitch must be finite, got {pitch_deg!r}")
    if not (math.isfinite(m) and m > 0):
        raise ValueError(f"max_pitch_deg must be positive, got {max_pitch_deg!r}")
    return {SHAPE_UP: min(max(p / m, 0.0), 1.0), SHAPE_DOWN: min(max(-p / m, 0.0), 1.0)}


@dataclass(frozen=True)
class LidParams(Settings):
    """Settings of the lid shapes (the ``rig:`` block of params.yaml, see :class:`RigSettings`).

    Gains are lid rotation / eyeball rotation at the middle of each lid.
    """

    max_pitch_deg: float = setting(MAX_PITCH_DEG, gt=0, le=90)
    gain_upper_up: float = setting(0.8, ge=0, le=2)
    gain_upper_down: float = setting(0.9, ge=0, le=2)
    gain_lower_up: float = setting(0.3, ge=0, le=2)
    gain_lower_down: float = setting(0.4, ge=0, le=2)
    canthus_width: float = setting(0.35, ge=0, le=0.5)
    canthus_exponent: float = setting(1.0, gt=0, le=10)
    upper_falloff_mm: float = setting(12.0, gt=0, le=100)
    lower_falloff_mm: float = setting(8.0, gt=0, le=100)
    max_chord_sag_mm: float = setting(0.03, gt=0, le=10)
    max_segments: int = setting(12, ge=1, le=100)
    min_opening_fraction: float = setting(0.2, le=1)   # negative: the guard is off
    surface_follow_mm: float = setting(2.0, ge=0, le=50)   # skin this far off the eyeball no longer follows the cornea
    min_offset_mm: float = setting(1e-6, ge=0, le=1)
    min_area_fraction: float = setting(0.25, ge=0, le=1)   # faces keep this share of their area in the full poses
    max_support_scale: float = setting(2.0, ge=1, le=10)   # ... by widening the falloff radii up to this factor

    @classmethod
    def from_dict(cls, d: dict | None) -> "LidParams":
        """Build from a params dict, ignoring keys that are not lid settings."""
        d = dict(d or {})
        names = set(LidParams.keys())
        return LidParams(**{k: v for k, v in d.items() if k in names})

    def lid_params(self) -> "LidParams":
        """Only the lid-shape settings (what rig.json records)."""
        return LidParams(**{k: getattr(self, k) for k in LidParams.keys()})


@dataclass(frozen=True)
class RigSettings(LidParams):
    """The whole ``rig:`` block: the lid-shape settings plus the stage's checks and outputs."""

    block: ClassVar[str] = "rig"

    max_rest_gap_mm: float = setting(0.5, gt=0, le=10)    # refuse a margin farther than this from its eyeball sphere
    sweep_step_deg: float = setting(0.5, ge=0.05, le=25)   # pitch step of the sweep written to the metrics
    down_smoothing_sigma_mm: float = setting(0.75, ge=0, le=20)  # blur of the down-looking texture variant


@dataclass
class EyeFrame:
    """One eye: its fitted sphere, rest forward direction and eyelid-margin loop.

    Attributes
    ----------
    side : str
        ``"left"`` (subject's left, +X) or ``"right"``.
    center : (3,) float64
        Eyeball sphere centre, mm, head frame.
    radius : float
        Eyeball sphere radius, mm.
    forward : (3,) float64
        Unit rest gaze direction.
    loop : (L,) int64
        Eyelid-margin vertex indices: medial canthus first, upper lid, lateral canthus, lower lid.
    lateral_index : int
        Position of the lateral canthus in ``loop``.
    """

    side: str
    center: np.ndarray
    radius: float
    forward: np.ndarray
    loop: np.ndarray
    lateral_index: int
    profile: object = None

    def basis(self) -> np.ndarray:
        """(3, 3) rows ``e_x`` (horizontal, toward head +X), ``e_y`` (up), ``e_z`` (forward)."""
        return eye_basis(self.forward)

    @property
    def axis(self) -> np.ndarray:
        """(3,) unit rotation axis: a positive angle about it pitches the eye up."""
        return -self.basis()[0]

    def gaze(self, pitch_deg: float) -> np.ndarray:
        """(3,) forward direction of the eye pitched by ``pitch_deg``."""
        f = np.asarray(self.forward, float)
        return rotate_about_axis(f[None], np.zeros(3), self.axis, math.radians(pitch_deg))[0]

    def surface_radius(self, P, pitch_deg: float = 0.0) -> np.ndarray:
        """(n,) distance from the centre to the eyeball's outer surface along each point's ray.

        ``profile`` None: the sphere (``radius``). Else an ``EyeballParams`` of the parametric
        eye (pipeline.eyeball.geometry), scaled so its sphere has ``radius``, looking along
        the pitched gaze: the sphere joined smoothly with the corneal bulge.
        """
        P = np.asarray(P, float)
        if self.profile is None:
            return np.full(len(P), float(self.radius))
        from pipeline.eyeball.geometry import outer_radial

        w = P - self.center
        u = w / np.maximum(np.linalg.norm(w, axis=1, keepdims=True), 1e-12)
        alpha = np.arccos(np.clip(u @ self.gaze(pitch_deg), -1.0, 1.0))
        return outer_radial(alpha, self.profile) * (float(self.radius) / float(self.profile.r1))

    def surface_distance(self, P, pitch_deg: float = 0.0) -> np.ndarray:
        """(n,) radial distance of points outside (+) / inside (-) the pitched eyeball surface."""
        P = np.asarray(P, float)
        return np.linalg.norm(P - self.center, axis=1) - self.surface_radius(P, pitch_deg)


def find_lateral_canthus(points, center, forward, side: str) -> int:
    """Index of the lateral canthus in an eyelid loop (the most lateral point).

    Parameters
    ----------
    points : (L, 3) float64
        Loop points, medial canthus first.
    center, forward : (3,)
        Eyeball centre and rest forward direction.
    side : {"left", "right"}
        Lateral is head +X for the left eye, -X for the right eye.
    """
    ex = eye_basis(forward)[0]
    sign = 1.0 if side == "left" else -1.0
    x = (np.asarray(points, dtype=np.float64) - np.asarray(center)) @ ex * sign
    return int(np.argmax(x))


def rotate_about_axis(P, center, axis, angles) -> np.ndarray:
    """Rotate points about the line through ``center`` along unit ``axis`` (Rodrigues).

    Parameters
    ----------
    P : (n, 3) float64
    center, axis : (3,) float64
    angles : (n,) float64 or float
        Radians, right-handed about ``axis``.

    Returns
    -------
    (n, 3) float64
    """
    P = np.asarray(P, dtype=np.float64)
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    w = P - np.asarray(center, dtype=np.float64)
    th = np.broadcast_to(np.asarray(angles, dtype=np.float64), (len(P),))[:, None]
    cos, sin = np.cos(th), np.sin(th)
    return (np.asarray(center) + w * cos + np.cross(a, w) * sin
            + a[None, :] * (w @ a)[:, None] * (1.0 - cos))


def canthus_taper(u, width: float = 0.35, exponent: float = 1.0) -> np.ndarray:
    """How much of the lid gain applies at horizontal position ``u`` (0 medial, 1 lateral canthus).

    ``sin(pi/2 * min(1, u / width, (1 - u) / width)) ** exponent``: zero at both canthi,
    a plateau of 1 over the middle ``[width, 1 - width]``, C1 where ramp and plateau meet.
    ``width = 0.5, exponent = 1`` gives ``sin(pi u)``.
    """
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    w = float(width)
    if not 0.0 < w <= 0.5:
        raise ValueError(f"canthus width must be in (0, 0.5], got {width!r}")
    x = np.minimum(1.0, np.minimum(u, 1.0 - u) / w)
    return np.sin(0.5 * np.pi * x) ** float(exponent)


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
    taper = canthus_taper(u, params.canthus_width, params.canthus_exponent)
    taper[[0, li]] = 0.0
    upper = np.zeros(L, bool)
    upper[1:li] = True
    lower = np.zeros(L, bool)
    lower[li + 1:] = True
    gain_up = np.where(upper, params.gain_upper_up, params.gain_lower_up) * taper
    gain_dn = np.where(upper, params.gain_upper_down, params.gain_lower_down) * taper
    gain_up, gain_dn = _keep_lids_apart(V[loop] - eye.center, B, u, upper, lower, gain_up, gain_dn,
                                        math.radians(params.max_pitch_deg),
                                        params.min_opening_fraction)
    radius = np.where(upper, params.upper_falloff_mm,
                      np.where(lower, params.lower_falloff_mm,
                               0.5 * (params.upper_falloff_mm + params.lower_falloff_mm)))
    # Skin turning by Theta * S(D / R) is compressed where the motion falls off fast along D
    # (above the upper lid when it rises, below the lower lid when it drops): neighbours differ
    # in arc displacement by about rho * Theta * |S'(D / R)| / R per mm (rho = distance from the
    # pitch axis), and the skin folds over (faces flip) near 1. The falloff radii are scaled by
    # the smallest factor (steps of 5 %, from 1) for which no face of the full poses keeps less
    # than min_area_fraction of its area seen along its rest normal.
    pmax = math.radians(params.max_pitch_deg)
    F = np.asarray(F, dtype=np.int64)
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    a0 = np.linalg.norm(n0, axis=1)
    for scale in np.arange(1.0, params.max_support_scale + 1e-9, 0.05):
        r_max = float(radius.max()) * scale
        D = dijkstra(G, directed=False, indices=loop, min_only=True, limit=r_max * 1.0001)
        region = np.isfinite(D)
        ext = _harmonic_extension(G, region, loop, np.stack([gain_up, gain_dn, scale * radius], axis=1))
        R = np.where(region, np.maximum(ext[:, 2], 1e-6), 1.0)
        S = np.where(region, smootherstep_falloff(np.where(region, D, 0.0) / R), 0.0)
        th_up, th_dn = pmax * ext[:, 0] * S, -pmax * ext[:, 1] * S
        worst = np.inf
        for th in (th_up, th_dn):
            mv = np.flatnonzero(th != 0.0)
            P = V.copy()
            P[mv] = rotate_about_axis(V[mv], eye.center, eye.axis, th[mv])
            fm = np.flatnonzero(region[F].any(axis=1) & (a0 > 1e-12))
            n1 = np.cross(P[F[fm, 1]] - P[F[fm, 0]], P[F[fm, 2]] - P[F[fm, 0]])
            if len(fm):
                worst = min(worst, float(np.min(np.einsum("ij,ij->i", n1, n0[fm]) / a0[fm] ** 2)))
        if worst >= params.min_area_fraction:
            break
    return EyeField(theta_up=th_up, theta_down=th_dn, distance=D, falloff=S, loop_u=u,
                    support_mm=r_max)


@dataclass
class BlendShape:
    """One blend-shape channel in UsdSkel layout.

    Attributes
    ----------
    name : str
    point_indices : (k,) int64
        Mesh vertices the shape moves.
    offsets : (k, 3) float64
        Offsets at weight 1, mm.
    inbetween_weights : (j,) float64
        Weights in (0, 1) of the inbetween shapes, increasing.
    inbetween_offsets : (j, k, 3) float64
        Offsets of each inbetween (same ``point_indices``).
    """

    name: str
    point_indices: np.ndarray
    offsets: np.ndarray
    inbetween_weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    inbetween_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))

    def knots(self):
        """(weights (j+2,), offsets (j+2, k, 3)) including the implicit 0 and the full shape."""
        k = len(self.point_indices)
        w = np.concatenate([[0.0], np.asarray(self.inbetween_weights, float), [1.0]])
        o = np.concatenate([np.zeros((1, k, 3)),
                            np.asarray(self.inbetween_offsets, float).reshape(-1, k, 3),
                            np.asarray(self.offsets, float)[None]])
        return w, o

    def inbetween_names(self) -> list[str]:
        """Names for the inbetweens: ``<name>_ib<j>`` (j = 1 .. number of inbetweens)."""
        return [f"{self.name}_ib{j + 1}" for j in range(len(self.inbetween_weights))]


def subshape_weights(shape: BlendShape, w: float) -> np.ndarray:
    """Weights of the stored poses (inbetweens..., full) for channel weight ``w``.

    UsdSkel semantics: piecewise-linear between the knots (implicit 0, inbetweens,
    1); outside [0, 1] linear extrapolation of the end segment.

    Returns
    -------
    (j+1,) float64
        One weight per inbetween, then the full shape.
    """
    knots, _ = shape.knots()
    w = float(w)
    if w <= knots[1]:
        seg = 0
    elif w >= knots[-2]:
        seg = len(knots) - 2
    else:
        seg = int(np.searchsorted(knots, w, side="right") - 1)
    a = (w - knots[seg]) / (knots[seg + 1] - knots[seg])
    full = np.zeros(len(knots))
    full[seg] = 1.0 - a
    full[seg + 1] = a
    return full[1:]


def flat_shape_weights(shapes, channel_weights: dict) -> dict[str, float]:
    """Expand channel weights to one weight per stored pose, for shape keys without inbetweens.

    Parameters
    ----------
    shapes : sequence of BlendShape
    channel_weights : dict
        ``{name: w}``, e.g. from :func:`lid_weights`.

    Returns
    -------
    dict
        ``{"<name>_ib1": .., ..., "<name>": ..}`` for every shape; a renderer that
        creates one shape key per stored pose (offsets relative to the rest mesh)
        and sets these values reproduces :func:`evaluate_shapes` exactly.
    """
    out = {}
    for s in shapes:
        sub = subshape_weights(s, channel_weights.get(s.name, 0.0))
        for name, w in zip(s.inbetween_names() + [s.name], sub):
            out[name] = float(w)
    return out


def evaluate_shapes(V, shapes, channel_weights: dict) -> np.ndarray:
    """Posed points: rest ``V`` plus every shape at its channel weight (UsdSkel semantics).

    Parameters
    ----------
    V : (n, 3) float64
    shapes : sequence of BlendShape
    channel_weights : dict

    Returns
    -------
    (n, 3) float64
    """
    P = np.array(V, dtype=np.float64, copy=True)
    for s in shapes:
        w = channel_weights.get(s.name, 0.0)
        if w == 0.0 or len(s.point_indices) == 0:
            continue
        _, offs = s.knots()
        sub = subshape_weights(s, w)
        P[s.point_indices] += np.tensordot(sub, offs[1:], axes=1)
    return P


def n_segments_for_sag(dist_to_axis, theta, max_sag_mm: float, max_segments: int) -> int:
    """Fewest even pitch segments whose chord sag ``d (1 - cos(theta / 2N))`` stays below a bound."""
    d = np.asarray(dist_to_axis, float)
    th = np.abs(np.asarray(theta, float))
    for n in range(1, int(max_segments) + 1):
        if d.size == 0 or float(np.max(d * (1.0 - np.cos(th / (2.0 * n))))) <= max_sag_mm:
            return n
    return int(max_segments)


def chord_sag(dist_to_axis, theta, n: int) -> float:
    """Largest chord sag, mm, of points rotated by ``theta`` sampled at ``n`` even segments."""
    d = np.asarray(dist_to_axis, float)
    th = np.abs(np.asarray(theta, float))
    return float(np.max(d * (1.0 - np.cos(th / (2.0 * n))))) if d.size else 0.0


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
    moves, excluding every eyelid margin, within two eyeball radii of that eye's centre."""
    moved = np.zeros(len(V), bool)
    for s in shapes:
        moved[s.point_indices] = True
    for e in eyes:
        moved[e.loop] = False
    return {e.side: np.flatnonzero(moved & (np.linalg.norm(V - e.center, axis=1) < 2.0 * e.radius))
            for e in eyes}


class _SurfaceFollow:
    """Keeps the margin and the skin on a non-spherical eyeball (see :func:`follow_surface`)."""

    def __init__(self, V, eyes, params: LidParams):
        self.eyes = [e for e in eyes if e.profile is not None]
        self.eyes_all = list(eyes)
        self.follow_mm = float(params.surface_follow_mm)
        self.rest = {e.side: e.surface_distance(V, 0.0) for e in self.eyes}

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
                            e.surface_distance(V[e.loop], 0.0))
        worst = 0.0
        for j in range(n_seg):
            for sign in (1.0, -1.0):
                p = sign * max_pitch * (j + 0.5) / n_seg
                P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch))
                for e in all_eyes:
                    sel, floor, d0 = near[e.side]
                    worst = max(worst, float(np.abs(e.surface_distance(P[e.loop], p) - d0).max()))
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
    G = _edge_graph(V, mesh_edges(F))
    fields = {e.side: lid_angle_field(V, F, e, params, graph=G) for e in eyes}
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


# ----------------------------------------------------------------------------------------------
# checks

def lid_opening(P, eye: EyeFrame, n_lines: int = 64, margin_frac: float = 0.02) -> np.ndarray:
    """Vertical opening along vertical lines: lowest upper-lid minus highest lower-lid height.

    The loop is projected on the eye's (horizontal, up) plane; vertical lines sample
    the span between the canthi (leaving ``margin_frac`` at each end).

    Parameters
    ----------
    P : (n, 3) float64
        Posed mesh points.
    eye : EyeFrame

    Returns
    -------
    (n_lines,) float64
        Opening per line, mm (negative = the upper lid crossed the lower lid);
        NaN where a lid does not reach the line.
    """
    B = eye.basis()
    loop = np.asarray(eye.loop)
    li = int(eye.lateral_index)
    Q = (np.asarray(P)[loop] - eye.center) @ B[:2].T
    up = Q[: li + 1]
    lo = np.concatenate([Q[li:], Q[:1]])
    xa, xb = sorted((Q[0, 0], Q[li, 0]))
    span = xb - xa
    xs = np.linspace(xa + margin_frac * span, xb - margin_frac * span, n_lines)

    def heights(poly, reduce):
        x0, y0, x1, y1 = poly[:-1, 0], poly[:-1, 1], poly[1:, 0], poly[1:, 1]
        res = np.full(len(xs), np.nan)
        for k, s in enumerate(xs):
            hit = ((x0 - s) * (x1 - s) <= 0) & (np.abs(x1 - x0) > 1e-12)
            if hit.any():
                y = y0[hit] + (s - x0[hit]) / (x1[hit] - x0[hit]) * (y1[hit] - y0[hit])
                res[k] = reduce(y)
        return res

    return heights(up, np.min) - heights(lo, np.max)


def cornea_intrusion(points, eye: EyeFrame, cornea_center, cornea_radius: float,
                     pitch_deg: float) -> np.ndarray:
    """How far the corneal bulge of the pitched eye pokes out past each margin point, mm.

    Along the ray from the eyeball centre through each point, the distance of the
    outer cornea-sphere surface (cornea rotated with the eye by ``pitch_deg``) minus
    the point's distance; 0 where the ray misses the cornea or the cornea lies inside.

    Parameters
    ----------
    points : (k, 3) float64
    eye : EyeFrame
    cornea_center : (3,) float64
        Cornea sphere centre at rest.
    cornea_radius : float
    pitch_deg : float

    Returns
    -------
    (k,) float64, >= 0
    """
    cc = rotate_about_axis(np.asarray(cornea_center, float)[None], eye.center, eye.axis,
                           math.radians(pitch_deg))[0] - eye.center
    w = np.asarray(points, float) - eye.center
    dist = np.linalg.norm(w, axis=1)
    d = w / dist[:, None]
    b = d @ cc
    disc = b * b - (cc @ cc - float(cornea_radius) ** 2)
    t = np.where(disc >= 0, b + np.sqrt(np.maximum(disc, 0.0)), -np.inf)
    return np.maximum(t - dist, 0.0)


def sweep_check(V, F, eyes, shapes, pitches_deg, max_pitch_deg: float = MAX_PITCH_DEG,
                corneas: dict | None = None) -> dict:
    """Pose the rig at every pitch and measure the lid invariants.

    The eyeball is a sphere about its centre, so rotating it by the pitch leaves
    its surface in place: the margin-to-eyeball distance is ``|v - c| - r``.

    Returns
    -------
    dict
        ``max_gap_mm`` (margin outside the sphere), ``max_penetration_mm`` (inside),
        ``rest_max_abs_mm`` (same at pitch 0), ``flipped_faces`` (max over pitches of
        faces whose normal turned by more than 90 degrees), ``min_opening_mm``
        (smallest upper-minus-lower lid height along vertical lines; < 0 = crossing),
        ``min_skin_clearance_mm`` (smallest distance outside the pitched eyeball surface of
        moved non-margin vertices within 2 r of the centre; ``rest_min_skin_clearance_mm`` the same at rest) and
        ``max_skin_sink_mm`` (largest decrease of that clearance by posing), and with
        ``corneas`` (``side -> (centre (3,), radius)``) ``max_cornea_intrusion_mm`` /
        ``rest_cornea_intrusion_mm`` (:func:`cornea_intrusion` of the margin),
        ``worst_pitch_deg`` for the gap/penetration, and ``n_pitches``.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    n0 = meshtopo.face_normals(V, F, normalize=False)
    ok = np.linalg.norm(n0, axis=1) > 1e-12
    moved = np.zeros(len(V), bool)
    for s in shapes:
        moved[s.point_indices] = True
    check_faces = ok & moved[F].any(axis=1)
    res = {"max_gap_mm": 0.0, "max_penetration_mm": 0.0, "flipped_faces": 0,
           "min_opening_mm": math.inf, "min_skin_clearance_mm": math.inf,
           "rest_min_skin_clearance_mm": math.inf, "max_skin_sink_mm": 0.0,
           "worst_pitch_deg": 0.0, "n_pitches": 0}
    skin = near_eye_skin(V, shapes, eyes)
    near_skin = {}
    for e in eyes:
        sel = skin[e.side]
        near_skin[e.side] = (sel, e.surface_distance(V[sel], 0.0))
        if len(sel):
            res["rest_min_skin_clearance_mm"] = min(res["rest_min_skin_clearance_mm"],
                                                    float(near_skin[e.side][1].min()))
    rest = max(float(np.max(np.abs(e.surface_distance(V[e.loop], 0.0)))) for e in eyes)
    res["rest_max_abs_mm"] = rest
    worst = -1.0
    for p in pitches_deg:
        P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch_deg))
        for e in eyes:
            d = e.surface_distance(P[e.loop], p)
            gap, pen = float(max(d.max(), 0.0)), float(max(-d.min(), 0.0))
            res["max_gap_mm"] = max(res["max_gap_mm"], gap)
            res["max_penetration_mm"] = max(res["max_penetration_mm"], pen)
            if max(gap, pen) > worst:
                worst, res["worst_pitch_deg"] = max(gap, pen), float(p)
            if corneas and e.side in corneas:
                cin = cornea_intrusion(P[e.loop], e, *corneas[e.side], p)
                res["max_cornea_intrusion_mm"] = max(res.get("max_cornea_intrusion_mm", 0.0),
                                                     float(cin.max()))
                if p == 0:
                    res["rest_cornea_intrusion_mm"] = float(cin.max())
            op = lid_opening(P, e)
            if np.isfinite(op).any():
                res["min_opening_mm"] = min(res["min_opening_mm"], float(np.nanmin(op)))
            sel, rest_clear = near_skin[e.side]
            if len(sel):
                ds = e.surface_distance(P[sel], p)
                res["min_skin_clearance_mm"] = min(res["min_skin_clearance_mm"], float(ds.min()))
                res["max_skin_sink_mm"] = max(res["max_skin_sink_mm"],
                                              float(np.max(rest_clear - ds)))
        n1 = meshtopo.face_normals(P, F, normalize=False)
        flipped = int(np.count_nonzero(np.einsum("ij,ij->i", n0[check_faces], n1[check_faces]) <= 0))
        res["flipped_faces"] = max(res["flipped_faces"], flipped)
        res["n_pitches"] += 1
    for k in ("min_opening_mm", "min_skin_clearance_mm", "rest_min_skin_clearance_mm"):
        if not math.isfinite(res[k]):
            res[k] = None
    return res


# ----------------------------------------------------------------------------------------------
# array layout of rig.npz (pure conversions; the stage does the file I/O)

def shapes_to_arrays(shapes, prefix: str = "") -> dict[str, np.ndarray]:
    """Flatten blend shapes into named arrays (the rig.npz layout).

    Keys per shape ``<prefix><name>.point_indices`` (k,) int64, ``.offsets`` (k, 3),
    ``.inbetween_weights`` (j,), ``.inbetween_offsets`` (j, k, 3); plus
    ``<prefix>shape_names`` (s,) str.
    """
    out = {f"{prefix}shape_names": np.array([s.name for s in shapes], dtype=str)}
    for s in shapes:
        k = len(s.point_indices)
        out[f"{prefix}{s.name}.point_indices"] = np.asarray(s.point_indices, np.int64)
        out[f"{prefix}{s.name}.offsets"] = np.asarray(s.offsets, np.float64).reshape(k, 3)
        out[f"{prefix}{s.name}.inbetween_weights"] = np.asarray(s.inbetween_weights, np.float64)
        out[f"{prefix}{s.name}.inbetween_offsets"] = np.asarray(
            s.inbetween_offsets, np.float64).reshape(-1, k, 3)
    return out


def shapes_from_arrays(arrays, prefix: str = "") -> list[BlendShape]:
    """Inverse of :func:`shapes_to_arrays` (accepts a dict or an open ``np.load`` file)."""
    names = [str(n) for n in arrays[f"{prefix}shape_names"]]
    return [BlendShape(name=n,
                       point_indices=np.asarray(arrays[f"{prefix}{n}.point_indices"], np.int64),
                       offsets=np.asarray(arrays[f"{prefix}{n}.offsets"], np.float64),
                       inbetween_weights=np.asarray(arrays[f"{prefix}{n}.inbetween_weights"],
                                                    np.float64),
                       inbetween_offsets=np.asarray(arrays[f"{prefix}{n}.inbetween_offsets"],
                                                    np.float64))
            for n in names]


# ----------------------------------------------------------------------------------------------
# input validation

def _first(d: dict, keys):
    for k in keys:
        if k in d and d[k] is not None:
            return d[k]
    return None


def _lateral_index_for_loop(e: dict, mesh: dict, side: str, V, loop, c, f) -> int:
    """Position of the lateral canthus in this mesh's loop.

    In order of preference: a mesh array ``lateral_index_<side>``; the eyes.json
    lateral canthus *point* (``loop_points[lateral_canthus_index]`` of the dense
    remove_eyeballs loop, which has other indices) mapped to the nearest vertex of
    this loop; an eyes.json index when its ``loop_indices`` has this loop's length;
    else the most lateral loop vertex (:func:`find_lateral_canthus`).
    """
    key = f"lateral_index_{side}"
    if key in mesh:
        return int(np.asarray(mesh[key]).ravel()[0])
    li = _first(e, ("lateral_index", "lateral_canthus_index", "loop_lateral_index"))
    pts = e.get("loop_points")
    if li is not None and pts is not None:
        try:
            pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
            p = pts[int(li)]
        except (TypeError, ValueError, IndexError):
            p = None
        if p is not None and np.isfinite(p).all():
            return int(np.argmin(np.linalg.norm(V[loop] - p, axis=1)))
    ids = e.get("loop_indices")
    if li is not None and (ids is None or len(ids) == len(loop)):
        return int(li)
    return find_lateral_canthus(V[loop], c, f, side)


def eye_frames(eyes: dict, mesh: dict, *, eyes_source="eyes.json", mesh_source="mesh.npz",
               max_rest_gap_mm: float = 0.5, profile=None) -> list[EyeFrame]:
    """Validated :class:`EyeFrame` per eye from the snap stage's eyes.json and mesh arrays.

    Parameters
    ----------
    eyes : dict
        ``{"left": {"center": [3], "radius": r, "forward": [3], optional
        "lateral_index" | "lateral_canthus_index", "loop_points", "loop_indices"},
        "right": {...}}`` (``center_mm`` / ``radius_mm`` / ``gaze_direction`` accepted too);
        see :func:`_lateral_index_for_loop` for how the lateral canthus is found.
    mesh : dict
        Arrays ``V``, ``F``, ``loop_left``, ``loop_right`` (ordered margin vertex indices),
        optional ``lateral_index_left`` / ``lateral_index_right``.
    eyes_source, mesh_source : str
        Names used in error messages.
    max_rest_gap_mm : float
        Largest allowed distance of a margin vertex from its eyeball surface.
    profile : EyeballParams, optional
        Outer surface of the parametric eye the snap stage snapped to (sphere + cornea);
        None = the fitted sphere.

    Raises
    ------
    pipeline.errors.ScanError
        On missing, malformed or inconsistent input (one sentence naming the problem).
    """
    from pipeline.errors import ScanError

    for key in ("V", "F"):
        if key not in mesh:
            raise ScanError(mesh_source, f"missing array {key}")
    V = np.asarray(mesh["V"], dtype=np.float64)
    F = np.asarray(mesh["F"])
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise ScanError(mesh_source, f"V must be (n, 3), got {V.shape}")
    if not np.isfinite(V).all():
        raise ScanError(mesh_source, "V has non-finite coordinates")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise ScanError(mesh_source, f"F must be (m, 3), got {F.shape}")
    if F.min() < 0 or F.max() >= len(V):
        raise ScanError(mesh_source, "F indexes vertices out of range")
    if not isinstance(eyes, dict):
        raise ScanError(eyes_source, "must be a JSON object with 'left' and 'right' eyes")
    out = []
    for side in ("left", "right"):
        e = eyes.get(side)
        if not isinstance(e, dict):
            raise ScanError(eyes_source, f"no '{side}' eye")
        c = _first(e, ("center", "center_mm"))
        r = _first(e, ("radius", "radius_mm"))
        f = _first(e, ("forward", "gaze_direction"))
        if c is None or r is None or f is None:
            raise ScanError(eyes_source, f"{side} eye needs center, radius and forward")
        try:
            c = np.asarray(c, dtype=np.float64).reshape(3)
            f = np.asarray(f, dtype=np.float64).reshape(3)
            r = float(r)
        except (TypeError, ValueError):
            raise ScanError(eyes_source, f"{side} eye: center/forward must be 3 numbers, "
                                         f"radius a number") from None
        if not (np.isfinite(c).all() and np.isfinite(f).all() and math.isfinite(r)):
            raise ScanError(eyes_source, f"{side} eye has non-finite values")
        if not 3.0 <= r <= 40.0:
            raise ScanError(eyes_source, f"{side} eye radius {r:g} is not a plausible eyeball "
                                         f"radius in mm (3..40)")
        if np.linalg.norm(f) < 1e-9:
            raise ScanError(eyes_source, f"{side} eye forward is zero")
        f = f / np.linalg.norm(f)
        if abs(f[1]) > 0.95:
            raise ScanError(eyes_source, f"{side} eye forward {f.round(3).tolist()} is vertical")
        key = f"loop_{side}"
        if key not in mesh:
            raise ScanError(mesh_source, f"missing array {key} (eyelid margin loop)")
        loop = np.asarray(mesh[key]).ravel()
        if not np.issubdtype(loop.dtype, np.integer):
            raise ScanError(mesh_source, f"{key} must hold integer vertex indices")
        loop = loop.astype(np.int64)
        if len(loop) < 8:
            raise ScanError(mesh_source, f"{key} has {len(loop)} vertices; at least 8 needed")
        if loop.min() < 0 or loop.max() >= len(V):
            raise ScanError(mesh_source, f"{key} indexes vertices out of range")
        if len(np.unique(loop)) != len(loop):
            raise ScanError(mesh_source, f"{key} repeats vertices")
        # ordering contract: medial canthus first, then over the upper lid
        B = eye_basis(f)
        Q = (V[loop] - c) @ B[:2].T
        lat = Q[:, 0] * (1.0 if side == "left" else -1.0)
        if lat[0] - lat.min() > 0.25 * (lat.max() - lat.min()):
            raise ScanError(mesh_source, f"{key} does not start at the medial canthus (its first "
                                         f"vertex is not at the nose side of the loop)")
        li = _lateral_index_for_loop(e, mesh, side, V, loop, c, f)
        if not 2 <= li <= len(loop) - 2:
            raise ScanError(eyes_source, f"{side} lateral canthus index {li} must leave at least one "
                                         f"vertex on each lid of the {len(loop)}-vertex loop")
        if Q[1:li, 1].mean() <= Q[li + 1:, 1].mean():
            raise ScanError(mesh_source, f"{key} runs over the lower lid first; the upper lid "
                                         f"must come first")
        frame = EyeFrame(side=side, center=c, radius=r, forward=f, loop=loop, lateral_index=li,
                         profile=profile)
        d = frame.surface_distance(V[loop], 0.0)
        if np.max(np.abs(d)) > max_rest_gap_mm:
            what = "sphere" if profile is None else "surface"
            raise ScanError(mesh_source, f"{side} eyelid margin is up to {np.max(np.abs(d)):.3g} mm "
                                         f"off the eyeball {what} (limit {max_rest_gap_mm:g} mm); "
                                         f"the snap stage must put it on the eyeball")
        out.append(frame)
    return out
