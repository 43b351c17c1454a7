"""How sure a placement is: the Laplace approximation of the final fit, widened by the other
local optima weighted by their energy (``temperature``) and by the radius profile, times a
calibration factor measured on unseen heads (benchmarks); both eyes of a head share the
larger radius variance (:func:`share_radius`). The result is one :class:`Placement` per eye;
:func:`residual_scaled` then scales its limbus and axis sigmas' Laplace part by the eye's own
residual (the reduced chi-square).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.placement.cues import CUE_NAMES, Patch
from pipeline.placement.model import Eye, limbus_center

SIDES = ("left", "right")


def laplace(Js, x, cols, nR, k):
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
    passed_over: str = ""           # why the search's lowest optimum was no eye here ("": it was; fit.passed_over_why)


def share_radius(out):
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


#: The Laplace part's noise is the cues' (``cues.SIG_SCLERA``, 0.15 mm); a fit whose eye residual is
#: smaller or larger says how noisy this scan's eye really is, and the Laplace part scales with it
#: (the reduced chi-square), within these factors: a procedural head's mesh leaves 0.03 mm
#: (discretisation, not the eye), a poor fit up to 0.45 mm
RESIDUAL_SCALE = (0.2, 3.0)


def residual_factor(rms_mm: float) -> float:
    """The factor :func:`residual_scaled` puts on the Laplace part: ``rms_mm / SIG_SCLERA``
    within :data:`RESIDUAL_SCALE`."""
    from pipeline.placement.cues import SIG_SCLERA

    return float(np.clip(rms_mm / SIG_SCLERA, *RESIDUAL_SCALE))


def residual_scaled(pl, rms_mm: float):
    """``pl`` with the Laplace parts of its limbus and axis sigmas scaled by the eye's residual
    (``rms_mm``, RMS over the eye surface) against the noise the cues assume; the rival optima's
    and the radius profile's parts are kept. The Laplace covariance read 0.15 mm of noise on every
    eye, and ``uncertainty_scale`` was calibrated on ICT-FaceKit heads whose eyes fit to 0.15 mm
    (median over the held-out set): the procedural heads' eyes fit to 0.03 mm and lay 4-10 times
    closer to the truth than they stated (docs/remove_eyeballs.md, Uncertainty)."""
    from dataclasses import replace

    if pl is None or not np.isfinite(rms_mm):
        return pl
    f = residual_factor(rms_mm)
    (ll, la) = pl.limbus_laplace

    def part(total, lap):
        return float(np.sqrt(max(total ** 2 - lap ** 2 * (1.0 - f ** 2), 0.0)))

    return replace(pl, sigma_limbus_mm=part(pl.sigma_limbus_mm, ll), sigma_axis_deg=part(pl.sigma_axis_deg, la),
                   limbus_laplace=(ll * f, la * f))


#: A 1-sigma past these says the data do not locate the eye at all: a near-singular Gauss-Newton
#: information (a cue-less direction, or the inverse failing: infinite) gives sigmas of 10^6 mm.
#: They are held here, so every record stays finite (the JSON writers refuse inf) and a doubt reads
#: "undetermined" (:func:`plus_minus`): 100 mm is ten eye radii, past any head's eye region; 180
#: deg is every gaze.
UNDETERMINED_MM = 100.0
UNDETERMINED_DEG = 180.0


def _bounded(sigma: float, cap: float) -> float:
    """``sigma`` held to ``cap`` (NaN or infinite gives ``cap``)."""
    return float(min(sigma, cap)) if np.isfinite(sigma) else float(cap)


def plus_minus(sigma: float, unit: str, digits: int = 2) -> str:
    """``+-sigma unit``, or ``undetermined`` at or past :data:`UNDETERMINED_MM` (mm) or
    :data:`UNDETERMINED_DEG` (deg)."""
    cap = UNDETERMINED_DEG if unit == "deg" else UNDETERMINED_MM
    return "undetermined" if not sigma < cap else f"+-{sigma:.{digits}f} {unit}"


def placement_of(p, modes, joint, temperature, sigma_scale, profile=None):
    """The :class:`Placement` of the best of ``modes`` (local optima, the best first) on patch
    ``p``: its Laplace covariance (from the joint fit ``joint = (fit, eye index, shared radius)``,
    else its own), times ``sigma_scale``, widened by the rival optima and the radius ``profile``."""
    m0 = modes[0]
    if joint is not None:
        fit, i, _ = joint
        cov, ci, ri, shares = fit.cov, list(range(4 * i, 4 * i + 3)), 4 * i + 3, fit.shares[i]
    else:
        cov, ci, ri, shares = m0.fit.cov, [0, 1, 2], 3, m0.fit.shares[0]
    var_c = float(np.trace(cov[np.ix_(ci, ci)])) * sigma_scale ** 2
    var_r = float(cov[ri, ri]) * sigma_scale ** 2
    lap = (_bounded(np.sqrt(var_c), UNDETERMINED_MM), _bounded(np.sqrt(var_r), UNDETERMINED_MM))
    lc = (fit.limbus_cov[i] if joint is not None else m0.fit.limbus_cov[0])
    var_l = float(np.trace(lc[:3, :3])) * sigma_scale ** 2
    var_a = float(np.trace(lc[3:, 3:])) * sigma_scale ** 2       # rad^2 (small angles)
    lap_l = (_bounded(np.sqrt(var_l), UNDETERMINED_MM), _bounded(np.degrees(np.sqrt(var_a)), UNDETERMINED_DEG))
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
    return Placement(m0.eye, m0.lab, p, _bounded(np.sqrt(var_c), UNDETERMINED_MM),
                     _bounded(np.sqrt(var_r), UNDETERMINED_MM), cues,
                     {CUE_NAMES.get(k, k): round(v, 4) for k, v in shares.items()},
                     [(m.eye.c, m.eye.R, m.energy - e0) for m in modes], m0.fold_deg, prof, lap,
                     _bounded(np.sqrt(var_l), UNDETERMINED_MM), _bounded(np.degrees(np.sqrt(var_a)), UNDETERMINED_DEG),
                     lap_l)
