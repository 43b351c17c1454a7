"""A procedural test head that behaves like a real scan of a real head.

The head is one parametric surface over a regular ``(t, y)`` grid: ``t`` is the
angle of a flat-fronted superellipse base curve in the horizontal plane (the
"skull" outline, about 150 mm wide), ``y`` the height in mm. Each grid point is
pushed along the base curve's horizontal outward normal by a depth ``h(t, y)``
(mm), so the surface is single-valued like a scanner's depth fusion, and the grid
triangulates into one connected sheet with its only boundary at the grid rim.

``h`` is the smooth maximum of two depths along the same ray:

* the eye surface: the outer intersection with the eyeball sphere (radius drawn in
  11-13.5 mm by the seed) joined by a smooth maximum with the corneal sphere
  (radius ~8 mm, apex ~13-14 mm from the eyeball centre);
* the skin: a face depth field (forehead, brow ridge, orbits, nose, cheeks, lips,
  chin, jaw, neck) blended, near each eye, into a lid shell that follows the eye
  surface at ``+T(d)``, where ``d`` is the signed distance (mm) from an almond
  opening drawn in the eye's angular coordinates. ``T`` rises from 0 at the
  margin to the lid thickness outside and drops behind the eyeball inside, so
  inside the almond the eye surface wins and the crossing curve (the eyelid
  margin) lies on the eyeball.

The smooth maximum rounds the lid/eye crease over ~1 mm, like a Poisson
reconstruction, while eye vertices away from the crease lie exactly on the
ground-truth spheres. Skin detail (pores, forehead lines, crow's feet, lower-lid
lines) is added to the skin depth only and fades out at the margin, so the
eyeball carries none. The colour texture is painted in the same ``(t, y)`` UV
space from the same fields.

Coordinates: head frame, mm, +Y up, +Z out of the face, +X = subject's left.
"""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from pipeline.settings import SettingError, Settings, setting

__all__ = ["SyntheticHead", "SyntheticHeadSettings", "make_synthetic_head", "write_scan_folder", "grid_shape",
           "LICENCE", "EYE_SHAPES"]

LICENCE = "CC0-1.0 (procedural, eyerig)"
EYE_SHAPES = {"round": 0.0, "hooded": 1.0}


@dataclasses.dataclass(frozen=True)
class SyntheticHeadSettings(Settings):
    """The ``synthetic_head:`` block of params.yaml (the arguments of :func:`make_synthetic_head`)."""

    block: ClassVar[str] = "synthetic_head"

    seed: int = setting(7, ge=0, le=2**32 - 1)                   # drives every shape detail
    target_triangles: int = setting(350_000, ge=200, le=5_000_000)  # ~0.7 mm vertex spacing at 350k
    eye_shape: Literal["round", "hooded"] | float = "round"      # or a hoodedness in [0, 1]
    eye_spacing_mm: float = setting(63.0, ge=40, le=90)          # interpupillary distance
    noise_mm: float = setting(0.02, ge=0, le=1)                  # scanner noise along normals (0 = off)
    texture_size: int = setting(2048, ge=16, le=8192)            # colour texture side (px)

    def validate(self) -> None:
        if isinstance(self.eye_shape, float) and not 0.0 <= self.eye_shape <= 1.0:
            raise SettingError("eye_shape", f"must be round, hooded or a number in [0, 1] (got {self.eye_shape:g})")

    def kwargs(self) -> dict:
        """Keyword arguments of :func:`make_synthetic_head`."""
        return {k: getattr(self, k) for k in self.keys()}

# base curve (superellipse in x-z) and domain
_A_MM = 75.0          # half width of the head at the base curve
_B_MM = 92.0          # base curve front (forehead) z
_P = 4.0              # superellipse exponent: flat front, rounded sides
_T_RANGE = np.deg2rad(98.0)   # +-t covered: front half of the head out past the temples
_Y_RANGE = (-150.0, 95.0)     # neck to upper forehead, eyes at y ~ 0

_K_LID = 1.0          # smooth-max width of the lid/eye crease (mm)
_K_CORNEA = 0.5       # smooth-max width of the sclera/cornea seam (mm)
_MISS = -1.0e3        # depth of a ray that misses a sphere


# ----------------------------------------------------------------------------- helpers

def _smax(a, b, k):
    """Polynomial smooth maximum: ``max(a, b)`` where ``|a - b| >= k``, rounded inside."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + h * h * k * 0.25


def _smoothstep(e0, e1, x):
    s = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _gauss(x, s):
    return np.exp(-(x / s) ** 2)


def _rho(t):
    s, c = np.abs(np.sin(t)), np.abs(np.cos(t))
    return 1.0 / ((s / _A_MM) ** _P + (c / _B_MM) ** _P) ** (1.0 / _P)


def _base(t):
    """Base curve point (x, z) and outward unit normal (nx, nz) at angle ``t``."""
    r = _rho(t)
    x, z = r * np.sin(t), r * np.cos(t)
    eps = 1e-5
    rp, rm = _rho(t + eps), _rho(t - eps)
    dx = (rp * np.sin(t + eps) - rm * np.sin(t - eps)) / (2 * eps)
    dz = (rp * np.cos(t + eps) - rm * np.cos(t - eps)) / (2 * eps)
    n = np.hypot(dx, dz)
    return x, z, -dz / n, dx / n


_ARC_T = np.linspace(-_T_RANGE, _T_RANGE, 4001)


def _arc_table():
    x, z = _rho(_ARC_T) * np.sin(_ARC_T), _rho(_ARC_T) * np.cos(_ARC_T)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
    return s - np.interp(0.0, _ARC_T, s)


_ARC_S = _arc_table()


def _arc(t):
    """Signed arc length (mm) along the base curve from the midline (t = 0)."""
    return np.interp(t, _ARC_T, _ARC_S)


def _t_for_x(x):
    """Base-curve angle whose base point has abscissa ``x`` (front half)."""
    lo, hi = -_T_RANGE, _T_RANGE
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if _rho(mid) * np.sin(mid) < x:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


class _Noise:
    """Seeded 2-D value noise on a periodic lattice (vectorised, smooth)."""

    def __init__(self, rng, size=256):
        self.size = size
        self.table = rng.random((size, size))

    def __call__(self, u, v):
        n = self.size
        iu, iv = np.floor(u), np.floor(v)
        fu, fv = u - iu, v - iv
        fu = fu * fu * (3 - 2 * fu)
        fv = fv * fv * (3 - 2 * fv)
        i0 = iu.astype(np.int64) % n
        j0 = iv.astype(np.int64) % n
        i1, j1 = (i0 + 1) % n, (j0 + 1) % n
        tb = self.table
        a = tb[i0, j0] + (tb[i1, j0] - tb[i0, j0]) * fu
        b = tb[i0, j1] + (tb[i1, j1] - tb[i0, j1]) * fu
        return a + (b - a) * fv


def _ray_sphere(ox, oy, oz, nx, nz, c, r):
    """Outer root ``h`` of ``|o + h n - c| = r`` (``_MISS`` where the ray misses),
    plus the closest-approach parameter ``h0`` and squared distance ``dd``."""
    px, py, pz = ox - c[0], oy - c[1], oz - c[2]
    b = px * nx + pz * nz
    dd = px * px + py * py + pz * pz - b * b
    r = np.asarray(r, dtype=float)
    disc = r * r - dd
    h = np.where(disc >= 0, -b + np.sqrt(np.maximum(disc, 0.0)), _MISS)
    return h, -b, dd


# ----------------------------------------------------------------------------- model

@dataclasses.dataclass
class _Eye:
    side: str
    lat: float                 # +1 left eye (+X), -1 right eye
    center: np.ndarray         # (3,)
    radius: float
    gaze: np.ndarray           # (3,) unit
    cornea_center: np.ndarray  # (3,)
    cornea_radius: float
    apex: np.ndarray           # (3,)
    almond: dict               # angles in radians
    boundary_mm: np.ndarray    # (k, 2) almond boundary in (r*alpha, r*beta)
    tree: object               # cKDTree over boundary_mm
    crow_angles: np.ndarray    # crow's-feet line angles (rad)
    lateral_canthus: np.ndarray  # (2,) (alpha, beta) of the lateral corner


def _almond_curves(al, s):
    """Upper and lower lid elevation (rad) at almond parameter ``s`` in [0, 1]."""
    s = np.clip(s, 0.0, 1.0)
    base = al["b_m"] + (al["b_l"] - al["b_m"]) * s
    up = base + al["h_u"] * np.sin(np.pi * s ** al["g_u"])
    lo = base - al["h_l"] * np.sin(np.pi * s ** al["g_l"]) ** 0.85
    return base, up, lo


def _make_eye(side, rng, ipd, hood, y_eye):
    from scipy.spatial import cKDTree

    lat = 1.0 if side == "left" else -1.0
    radius = float(rng.uniform(11.0, 13.5))
    x = lat * (ipd / 2.0 + rng.uniform(-0.3, 0.3))
    tx = _t_for_x(x)
    bx, bz, _, _ = _base(np.array([tx]))
    center = np.array([x, y_eye + rng.uniform(-0.4, 0.4), float(bz[0]) - 15.0 + rng.uniform(-0.5, 0.5)])
    yaw = np.deg2rad(rng.uniform(-2.0, 2.0))
    pitch = np.deg2rad(rng.uniform(-2.0, 2.0))
    gaze = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    scale = radius / 12.0
    rc = 7.6 * scale * rng.uniform(0.98, 1.02)
    apex_dist = radius + rng.uniform(0.95, 1.25) * scale
    cc = center + (apex_dist - rc) * gaze
    d = np.deg2rad
    al = {
        "a_m": -d(rng.uniform(55.0, 60.0)), "a_l": d(rng.uniform(73.0, 78.0)),
        "b_m": d(rng.uniform(-3.0, -1.0)), "b_l": d(rng.uniform(1.0, 4.0)),
        "h_u": d((1 - hood) * rng.uniform(25.5, 27.5) + hood * rng.uniform(19.0, 21.0)),
        "h_l": d(rng.uniform(23.0, 25.0)),
        "g_u": float(rng.uniform(0.8, 0.95)), "g_l": float(rng.uniform(1.1, 1.25)),
    }
    s = np.linspace(0.0, 1.0, 1500)
    _, up, lo = _almond_curves(al, s)
    alpha = al["a_m"] + (al["a_l"] - al["a_m"]) * s
    bnd = np.concatenate([np.stack([alpha, up], 1), np.stack([alpha[::-1], lo[::-1]], 1)]) * radius
    crow = np.deg2rad(rng.uniform(-35, 35, size=5) + np.array([-50, -25, 0, 25, 50]) * 0.9)
    return _Eye(side, lat, center, radius, gaze, cc, rc, center + apex_dist * gaze, al, bnd,
                cKDTree(bnd), crow, np.array([al["a_l"], al["b_l"]]))


class _Model:
    """All seeded shape parameters; ``fields(t, y)`` evaluates the surface depths."""

    def __init__(self, seed, eye_shape, eye_spacing_mm, detail):
        rng = np.random.default_rng(seed)
        self.seed = seed
        self.hood = float(eye_shape)
        self.ipd = float(eye_spacing_mm)
        self.detail_scale = float(detail)
        self.y_eye = 0.0
        self.eyes = [_make_eye("left", rng, self.ipd, self.hood, self.y_eye),
                     _make_eye("right", rng, self.ipd, self.hood, self.y_eye)]
        j = lambda a, b: float(rng.uniform(a, b))  # noqa: E731
        self.face = {
            "brow": j(3.5, 5.5), "nose": j(21.0, 27.0), "nose_w": j(0.9, 1.15), "cheek": j(5.0, 8.0),
            "chin": j(4.0, 7.0), "orbit": j(7.0, 9.0), "lip": j(3.0, 4.5), "jaw": j(24.0, 32.0),
            "tilt": j(-0.02, 0.02),
        }
        self.noise_pore = _Noise(rng)
        self.noise_tone = _Noise(rng, 64)
        self.noise_brow = _Noise(rng)
        self.forehead_lines = np.sort(rng.uniform(38.0, 70.0, size=4))
        self.forehead_phase = rng.uniform(0, 2 * np.pi, size=4)
        self.pore_depth = float(rng.uniform(0.07, 0.1))
        self.wrinkle_depth = float(rng.uniform(0.25, 0.32))

    # -- face (no eyes) -------------------------------------------------------
    def face_depth(self, x, y):
        f = self.face
        ax = np.abs(x)
        ex = self.ipd / 2.0
        h = -0.0038 * np.maximum(y - 28.0, 0.0) ** 2 + f["tilt"] * y
        # brow ridge and glabella
        h += f["brow"] * _gauss(y - 15.0, 7.5) * _gauss(ax - 28.0, 24.0)
        h += 2.0 * _gauss(y - 12.0, 9.0) * _gauss(x, 12.0)
        # orbits (eye sockets) and the temples
        h -= f["orbit"] * np.exp(-(((ax - ex) / 16.0) ** 2 + ((y - 1.0) / 11.0) ** 2))
        h -= 3.0 * np.exp(-(((ax - 64.0) / 10.0) ** 2 + ((y - 18.0) / 16.0) ** 2))
        # nose: bridge to tip, alae
        prof = f["nose"] * _smoothstep(12.0, -44.0, y) ** 1.3 * _smoothstep(-58.0, -45.0, y)
        width = f["nose_w"] * (8.0 + 7.0 * _smoothstep(4.0, -46.0, y))
        h += prof * np.exp(-((x / width) ** 2))
        h += 5.5 * np.exp(-(((ax - 14.0) / 6.0) ** 2 + ((y + 48.0) / 6.0) ** 2))
        # cheeks, lips, chin
        h += f["cheek"] * np.exp(-(((ax - 40.0) / 19.0) ** 2 + ((y + 30.0) / 17.0) ** 2))
        h += f["lip"] * np.exp(-((x / 22.0) ** 4 + ((y + 66.0) / 5.5) ** 2))
        h += 0.8 * f["lip"] * np.exp(-((x / 20.0) ** 4 + ((y + 79.0) / 5.0) ** 2))
        h -= 2.2 * np.exp(-((x / 24.0) ** 4 + ((y + 72.5) / 1.3) ** 2))
        h -= 2.0 * np.exp(-((x / 18.0) ** 2 + ((y + 88.0) / 4.0) ** 2))
        h += f["chin"] * np.exp(-((x / 18.0) ** 2 + ((y + 101.0) / 10.0) ** 2))
        # jaw narrowing, under the chin, neck
        h -= f["jaw"] * (ax / _A_MM) ** 2.5 * _smoothstep(-25.0, -115.0, y)
        h -= 30.0 * _smoothstep(-106.0, -132.0, y) * (1.0 - 0.6 * (ax / _A_MM) ** 2)
        return h

    # -- everything along the rays ------------------------------------------
    def fields(self, t, y, detail=True, want_texture=False, base=None):
        """Depths along the rays at grid parameters ``t`` (rad), ``y`` (mm).

        Returns a dict with ``h`` (final depth), ``h_skin``, ``h_eye``, base point and
        normal (``bx, bz, nx, nz``) and, for texturing, the eye-local fields.
        """
        t = np.asarray(t, float)
        y = np.asarray(y, float)
        bx, bz, nx, nz = _base(t) if base is None else base
        h_face = self.face_depth(bx, y)
        h_skin = h_face.copy()
        h_eye = np.full(t.shape, _MISS)
        d_all = np.full(t.shape, 99.0)
        wrinkle = np.zeros(t.shape)
        out = {}
        if want_texture:
            out.update(eye_angle=np.full(t.shape, np.pi), eye_radius=np.zeros(t.shape),
                       upper=np.zeros(t.shape))
        for e in self.eyes:
            c = e.center
            box = (np.abs(bx - c[0]) < 34.0) & (np.abs(y - c[1]) < 30.0)
            if not box.any():
                continue
            ox, oy, oz = bx[box], y[box], bz[box]
            mx, mz = nx[box], nz[box]
            hs, h0, dd = _ray_sphere(ox, oy, oz, mx, mz, c, e.radius)
            hc, _, _ = _ray_sphere(ox, oy, oz, mx, mz, e.cornea_center, e.cornea_radius)
            he = _smax(hs, hc, _K_CORNEA)
            # eye angular coordinates from the sphere hit (closest approach on a miss)
            hp = np.where(hs > _MISS, hs, h0)
            px, py, pz = ox + hp * mx - c[0], oy - c[1], oz + hp * mz - c[2]
            alpha = np.arctan2(e.lat * px, pz)
            beta = np.arctan2(py, np.hypot(px, pz))
            al = e.almond
            s = (alpha - al["a_m"]) / (al["a_l"] - al["a_m"])
            base_b, up, lo = _almond_curves(al, s)
            # off the sphere, scale the angles by the ray's distance from the centre so d keeps
            # growing away from the eye (continuous at the silhouette)
            rho = np.where(hs > _MISS, e.radius, np.sqrt(np.maximum(dd, 0.0)))
            dist, _ = e.tree.query(np.stack([alpha * rho, beta * rho], 1))
            inside = (s > 0) & (s < 1) & (beta < up) & (beta > lo)
            d = np.where(inside, -dist, dist)
            upper = _smoothstep(-0.02, 0.02, beta - base_b)
            # lid profile T(d): thickness outside, behind the eye inside
            thick = 2.3 + 0.4 * upper
            tout = thick * np.tanh(np.maximum(d, 0.0) / 1.1) + 0.3 * np.maximum(d - 2.0, 0.0)
            tin = -4.0 * (1.0 - np.exp(np.minimum(d, 0.0) / 1.0))
            tlid = np.where(d >= 0, tout, tin)
            # upper-lid crease (round) or a hanging skin fold (hooded)
            hood = self.hood
            fold = upper * ((1 - hood) * (-0.9 * _gauss(d - 7.5, 1.3))
                            + hood * (2.6 * _gauss(d - 3.6, 1.6) - 1.2 * _gauss(d - 6.5, 1.2)))
            lower_fold = (1 - upper) * (-0.5 * _gauss(d - 5.5, 1.8))
            tlid = tlid + np.where(d > 0, (fold + lower_fold) * _smoothstep(0.0, 1.2, d), 0.0)
            # lid shell follows the eye surface scaled out by T (misses: continued past the rim)
            rs = e.radius + np.maximum(tlid, -e.radius + 1.0)
            hl_s, h0s, dds = _ray_sphere(ox, oy, oz, mx, mz, c, rs)
            hl_s = np.where(hl_s > _MISS, hl_s, h0s - 2.0 * (np.sqrt(dds) - rs))
            hl_c, _, _ = _ray_sphere(ox, oy, oz, mx, mz, e.cornea_center,
                                     np.maximum(e.cornea_radius + tlid, 0.5))
            h_lid = _smax(hl_s, hl_c, _K_CORNEA)
            # a few mm out from the margin the skin never sinks behind the face (no moat)
            q = _smoothstep(1.0, 4.0, d)
            h_lid = h_lid + q * (_smax(h_lid, h_skin[box], 3.0) - h_lid)
            w = 1.0 - _smoothstep(2.5, 12.0, d)
            hsk = w * h_lid + (1 - w) * h_skin[box]
            h_skin[box] = hsk
            h_eye[box] = np.maximum(h_eye[box], he)
            d_all[box] = np.minimum(d_all[box], d)
            # crow's feet and lower-lid lines (negative = crease)
            if detail:
                lc = e.lateral_canthus
                da, db = (alpha - lc[0]) * e.radius, (beta - lc[1]) * e.radius
                rr = np.hypot(da, db)
                ang = np.arctan2(db, da)
                cf = np.zeros_like(rr)
                for a0 in e.crow_angles:
                    cf += _gauss(rr * np.sin(ang - a0), 0.35) * (np.cos(ang - a0) > 0)
                cf *= _smoothstep(2.0, 5.0, rr) * (1 - _smoothstep(9.0, 15.0, rr))
                ll = (1 - upper) * (_gauss(d - 3.2, 0.35) + 0.7 * _gauss(d - 6.0, 0.4)) \
                    * _smoothstep(0.15, 0.45, s) * (1 - _smoothstep(0.75, 1.05, s))
                wr = np.zeros(t.shape)
                wr[box] = -np.minimum(cf + ll, 1.0)
                wrinkle = np.minimum(wrinkle, wr)
            if want_texture:
                # angle from the optical axis on the eye surface (for iris/pupil)
                qx = ox + he * mx - c[0]
                qy = oy - c[1]
                qz = oz + he * mz - c[2]
                qn = np.sqrt(qx * qx + qy * qy + qz * qz)
                cosang = (qx * e.gaze[0] + qy * e.gaze[1] + qz * e.gaze[2]) / np.maximum(qn, 1e-9)
                out["eye_angle"][box] = np.minimum(out["eye_angle"][box], np.arccos(np.clip(cosang, -1, 1)))
                out["eye_radius"][box] = e.radius
                out["upper"][box] = np.maximum(out["upper"][box], upper)
        det = np.zeros(t.shape)
        if detail and self.detail_scale > 0:
            det = self.skin_detail(bx, _arc(t), y, d_all, wrinkle) * self.detail_scale
            h_skin = h_skin + det
        h = _smax(h_skin, h_eye, _K_LID)
        out.update(h=h, h_skin=h_skin, h_eye=h_eye, d=d_all, detail=det, bx=bx, bz=bz, nx=nx, nz=nz,
                   wrinkle=wrinkle)
        return out

    def skin_detail(self, x, u, y, d, wrinkle):
        """Signed skin displacement (mm): pores, forehead lines, crow's feet, lid lines."""
        pores = self.noise_pore(u / 0.55, y / 0.55)
        pores = -self.pore_depth * _smoothstep(0.55, 0.85, pores) \
            + 0.03 * (self.noise_pore(u / 2.3 + 91.0, y / 2.3) - 0.5)
        fl = np.zeros_like(x)
        for yk, ph in zip(self.forehead_lines, self.forehead_phase):
            yy = yk + 2.0 * np.sin(x / 23.0 + ph) + 0.00045 * x * x
            fl += _gauss(y - yy, 0.55)
        fl *= 1 - _smoothstep(38.0, 60.0, np.abs(x))
        lines = np.minimum(fl, 1.0)
        wr = self.wrinkle_depth * np.minimum(-wrinkle + lines, 1.0)
        det = pores - wr
        # no detail on (or right next to) the eye: fade to 0 at the lid margin
        return det * _smoothstep(0.6, 2.0, d)


# ----------------------------------------------------------------------------- API

@dataclasses.dataclass
class SyntheticHead:
    """A generated head.

    Attributes
    ----------
    V : (n, 3) float64
        Vertices, mm, head frame.
    F : (m, 3) int64
        Triangles, counter-clockwise seen from outside.
    UV : (n, 2) float64
        Per-vertex texture coordinates in [0, 1], origin bottom-left.
    texture : (H, W, 3) uint8
        Colour texture (row 0 = top, i.e. v = 1).
    ground_truth : dict
        The ``ground_truth.json`` content (see module docs / DESIGN).
    hints : dict
        ``{"left": [x, y, z], "right": [x, y, z]}`` eye hints for ``scan.yaml``.
    grid_shape : tuple
        ``(n_y, n_t)`` of the parametric grid (vertex ``i`` = row ``i // n_t``).
    """

    V: np.ndarray
    F: np.ndarray
    UV: np.ndarray
    texture: np.ndarray
    ground_truth: dict
    hints: dict
    grid_shape: tuple


def _arc_length():
    t = np.linspace(-_T_RANGE, _T_RANGE, 2001)
    x, z, _, _ = _base(t)
    return float(np.sum(np.hypot(np.diff(x), np.diff(z))))


def grid_shape(target_triangles: int) -> tuple[int, int]:
    """Grid ``(n_y, n_t)`` whose triangle count ``2 (n_y-1)(n_t-1)`` is closest to the target."""
    target_triangles = int(target_triangles)
    if target_triangles < 200:
        raise ValueError(f"target_triangles must be >= 200, got {target_triangles}")
    aspect = _arc_length() / (_Y_RANGE[1] - _Y_RANGE[0])
    cells = target_triangles / 2.0
    ny = max(int(round(np.sqrt(cells / aspect))), 2)
    nt = max(int(round(cells / ny)), 2)
    return ny + 1, nt + 1


def _grid_faces(ny, nt):
    idx = np.arange(ny * nt, dtype=np.int64).reshape(ny, nt)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # rows go up in y, columns go toward +x: (a, b, d) is CCW seen from outside (+z)
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def _points(f, y, h):
    return np.stack([f["bx"] + h * f["nx"], y, f["bz"] + h * f["nz"]], axis=-1)


def _trace_margin(model, eye, n=256):
    """Eyelid margin = crossing of skin and eye depths, by radial bisection in (t, y).

    Returns points (n, 3) ordered from the medial canthus over the upper lid to the
    lateral canthus and back along the lower lid, and the lateral index.
    """
    c = eye.center
    # opening centre in parameter space: the ray through the almond's centre on the eye
    al = eye.almond
    a0 = 0.5 * (al["a_m"] + al["a_l"])
    _, up, lo = _almond_curves(al, np.array([0.5]))
    b0 = 0.5 * (up[0] + lo[0])
    dirn = np.array([eye.lat * np.sin(a0) * np.cos(b0), np.sin(b0), np.cos(a0) * np.cos(b0)])
    p = c + eye.radius * dirn
    t0, y0 = _t_for_x(p[0]), p[1]
    # parameter-space scale: mm per radian of t near the eye
    bx, bz, _, _ = _base(np.array([t0 - 1e-3, t0 + 1e-3]))
    mm_per_t = np.hypot(bx[1] - bx[0], bz[1] - bz[0]) / 2e-3
    phi = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    ux, uy = np.cos(phi) / mm_per_t, np.sin(phi)

    def g(rad):
        f = model.fields(t0 + rad * ux, y0 + rad * uy, detail=False)
        return f["h_skin"] - f["h_eye"]

    # march outward to bracket the first sign change, then bisect
    lo_r = np.zeros_like(phi)
    hi_r = np.full_like(phi, np.nan)
    prev = g(lo_r)
    step = 0.5
    steps = np.arange(step, 30.0, step)
    for r in steps:
        cur = g(np.full_like(phi, r))
        hit = np.isnan(hi_r) & (cur > 0) & (prev <= 0)
        hi_r[hit] = r
        lo_r[np.isnan(hi_r)] = r
        prev = cur
        if not np.isnan(hi_r).any():
            break
    lo_r = np.where(np.isnan(hi_r), lo_r, hi_r - step)
    hi_r = np.where(np.isnan(hi_r), lo_r, hi_r)
    for _ in range(32):
        mid = 0.5 * (lo_r + hi_r)
        neg = g(mid) <= 0
        lo_r = np.where(neg, mid, lo_r)
        hi_r = np.where(neg, hi_r, mid)
    rad = 0.5 * (lo_r + hi_r)
    tt, yy = t0 + rad * ux, y0 + rad * uy
    f = model.fields(tt, yy, detail=False)
    pts = _points(f, yy, f["h_eye"])
    # order: medial canthus first, over the upper lid to the lateral canthus, back below
    lat = eye.lat * (pts[:, 0] - c[0])
    i_med = int(np.argmin(lat))
    pts = np.roll(pts, -i_med, axis=0)
    # phi increases counter-clockwise in (x, y); for the left eye medial is -x so CCW from
    # medial goes down first: reverse so the upper lid comes first.
    if pts[len(pts) // 4, 1] < pts[(3 * len(pts)) // 4, 1]:
        pts = np.concatenate([pts[:1], pts[1:][::-1]])
    # resample to n points: equal arc length per lid with both canthi as samples
    lat = eye.lat * (pts[:, 0] - c[0])
    i_lat = int(np.argmax(lat))
    upper, lower = pts[: i_lat + 1], np.concatenate([pts[i_lat:], pts[:1]])

    def resample(poly, k):
        seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        q = np.linspace(0.0, s[-1], k + 1)
        return np.stack([np.interp(q, s, poly[:, j]) for j in range(3)], 1)[:-1]

    half = n // 2
    ring = np.concatenate([resample(upper, half), resample(lower, n - half)])
    return ring, half


def _ground_truth(model, hints_rng, target_triangles):
    eyes, hints = {}, {}
    shape_name = {0.0: "round", 1.0: "hooded"}.get(model.hood, f"{model.hood:g}")
    for e in model.eyes:
        margin, i_lat = _trace_margin(model, e)
        # project the margin centroid onto the eye surface along the ray from the centre
        cen = margin.mean(axis=0)
        v = cen - e.center
        opening = e.center + e.radius * v / np.linalg.norm(v)
        dist = np.abs(np.linalg.norm(margin - e.center, axis=1) - e.radius)
        rnd = hints_rng.normal(size=3)
        hint = opening + 2.0 * rnd / np.linalg.norm(rnd)
        gaze = e.gaze
        limbus_cos = (e.radius ** 2 + np.linalg.norm(e.cornea_center - e.center) ** 2
                      - e.cornea_radius ** 2) / (2 * e.radius * np.linalg.norm(e.cornea_center - e.center))
        width = float(np.linalg.norm(margin[0] - margin[i_lat]))
        up, lo = margin[1:i_lat], margin[i_lat + 1:]
        eyes[e.side] = {
            "eyeball_sphere": {"center_mm": e.center.round(5).tolist(), "radius_mm": round(e.radius, 5)},
            "cornea_sphere": {"center_mm": e.cornea_center.round(5).tolist(),
                              "radius_mm": round(e.cornea_radius, 5)},
            "corneal_apex_mm": e.apex.round(5).tolist(),
            "corneal_apex_distance_mm": round(float(np.linalg.norm(e.apex - e.center)), 5),
            "limbus_half_angle_deg": round(float(np.degrees(np.arccos(limbus_cos))), 4),
            "gaze_direction": gaze.round(6).tolist(),
            "gaze_pitch_deg": round(float(np.degrees(np.arcsin(gaze[1]))), 4),
            "gaze_yaw_deg": round(float(np.degrees(np.arctan2(gaze[0], gaze[2]))), 4),
            "eye_opening_center_mm": opening.round(5).tolist(),
            "eye_opening_center_definition": "eyelid-margin centroid projected radially onto the eyeball "
                                             "sphere; the scan.yaml hint is this point plus a 2 mm offset "
                                             "in a seeded random direction",
            "eyelid_margin": {
                "definition": "curve where the lid skin surface crosses the scanned eye surface "
                              "(traced on the noise-free, detail-free surface); ordered from the "
                              "medial canthus over the upper lid to the lateral canthus and back "
                              "along the lower lid",
                "closed": True,
                "points_mm": margin.round(5).tolist(),
                "medial_canthus_index": 0,
                "lateral_canthus_index": int(i_lat),
                "distance_to_eyeball_sphere_mm": {"max": round(float(dist.max()), 5),
                                                  "rms": round(float(np.sqrt(np.mean(dist ** 2))), 5)},
                "width_mm": round(width, 4),
                "upper_lid_length_mm": round(float(np.linalg.norm(np.diff(margin[: i_lat + 1], axis=0),
                                                                  axis=1).sum()), 4),
                "height_mm": round(float(up[:, 1].max() - lo[:, 1].min()), 4),
            },
        }
        hints[e.side] = hint.round(4).tolist()
    gt = {
        "tool": "eyerig pipeline.synthetic_head",
        "units": "mm",
        "frame": {"up": "+Y", "forward": "+Z (out of the face)", "x": "+X = subject's left"},
        "seed": int(model.seed),
        "skin_detail_amplitude_mm": None,  # filled by the caller (measured)
        "eye_shape": shape_name,
        "eye_shape_params": {
            "hoodedness": model.hood,
            "eye_spacing_mm": model.ipd,
            **{side: {k: (round(float(np.degrees(v)), 4) if k.startswith(("a_", "b_", "h_")) else round(v, 4))
                      for k, v in e.almond.items()}
               for side, e in zip(("left", "right"), model.eyes)},
            "almond_angles": "a_m/a_l medial/lateral corner azimuth, b_m/b_l corner elevation, "
                             "h_u/h_l upper/lower lid height (deg, about the eyeball centre)",
        },
        "target_triangles": int(target_triangles),
        "eyes": eyes,
    }
    return gt, hints


def _normals(P):
    """Grid vertex normals (ny, nt, 3) from central differences of the grid."""
    dt = np.gradient(P, axis=1)
    dy = np.gradient(P, axis=0)
    n = np.cross(dt, dy)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def _paint_texture(model, size, rows_per_chunk=128):
    """Colour texture (size, size, 3) uint8 painted in (t, y) UV space (row 0 = top)."""
    out = np.empty((size, size, 3), dtype=np.uint8)
    u = (np.arange(size) + 0.5) / size
    for r0 in range(0, size, rows_per_chunk):
        rows = np.arange(r0, min(r0 + rows_per_chunk, size))
        vv = 1.0 - (rows + 0.5) / size
        uu, vv = np.meshgrid(u, vv)
        t = -_T_RANGE + 2 * _T_RANGE * uu
        y = _Y_RANGE[0] + (_Y_RANGE[1] - _Y_RANGE[0]) * vv
        base = tuple(np.broadcast_to(b, t.shape).ravel() for b in _base(t[0]))
        out[rows] = _paint(model, t.ravel(), y.ravel(), base).reshape(len(rows), size, 3)
    return out


def _paint(model, t, y, base=None):
    """RGB uint8 (k, 3) of the skin/eye colour at parameters ``t``, ``y``."""
    f = model.fields(t, y, detail=True, want_texture=True, base=base)
    x = f["bx"]
    yy = y
    u = _arc(t)
    tone = model.noise_tone(u / 9.0, yy / 9.0) - 0.5
    fine = model.noise_pore(u / 0.8 + 17.0, yy / 0.8) - 0.5
    skin = np.array([224.0, 172.0, 146.0])
    col = skin[None, :] * (1.0 + 0.10 * tone[:, None] + 0.04 * fine[:, None])
    # redder cheeks, nose and lips; darker creases and pores
    ax = np.abs(x)
    red = 0.5 * np.exp(-(((ax - 40) / 16) ** 2 + ((yy + 28) / 14) ** 2)) \
        + 0.8 * np.exp(-((x / 21.0) ** 4 + ((yy + 72.0) / 8.0) ** 2)) \
        + 0.3 * np.exp(-((x / 8) ** 2 + ((yy + 40) / 10) ** 2))
    col = col * (1 - 0.25 * red[:, None]) + np.array([190.0, 80.0, 80.0]) * 0.25 * red[:, None]
    crease = np.clip(-f["detail"] / 0.3, 0, 1)
    col *= (1.0 - 0.35 * crease)[:, None]
    # brows: horizontal hair strokes along the brow ridge
    ex = model.ipd / 2
    by = 17.0 + 3.0 * np.sin(np.clip((ax - ex + 20) / 45, 0, 1) * np.pi) - 0.08 * np.maximum(ax - ex, 0)
    band = np.exp(-((yy - by) / 3.2) ** 4) * _smoothstep(6, 12, ax) * (1 - _smoothstep(ex + 18, ex + 26, ax))
    hair = _smoothstep(0.35, 0.7, model.noise_brow(x / 2.5, yy / 0.3))
    bmask = np.clip(band * (0.45 + 0.55 * hair), 0, 1)
    col = col * (1 - 0.8 * bmask[:, None]) + np.array([60.0, 42.0, 32.0]) * 0.8 * bmask[:, None]
    # lash line darkening along the upper margin
    d = f["d"]
    lash = (d > -0.2) & (d < 1.2)
    col[lash] *= np.where(f["upper"][lash] > 0.5, 0.45, 0.8)[:, None]
    # the scanned eyeball: sclera, iris, pupil where the eye surface is visible
    eye = f["h_eye"] >= f["h_skin"]
    ang = f["eye_angle"][eye]
    r = np.maximum(f["eye_radius"][eye], 1.0)
    rad_mm = r * np.sin(np.minimum(ang, np.pi / 2))
    sclera = np.array([236.0, 226.0, 218.0]) * (1 - 0.08 * _smoothstep(8, 14, rad_mm))[:, None]
    iris_c = np.array([92.0, 118.0, 140.0])
    ring = 0.85 + 0.15 * np.cos(np.arctan2(0, 1) + rad_mm * 6.0)
    iris = iris_c[None, :] * ring[:, None]
    iris = np.where((rad_mm > 5.4)[:, None], iris * 0.6, iris)
    ec = np.where((rad_mm < 5.8)[:, None], iris, sclera)
    ec = np.where((rad_mm < 1.9)[:, None], np.array([12.0, 10.0, 10.0]), ec)
    col[eye] = ec
    return np.clip(col, 0, 255).astype(np.uint8)


def make_synthetic_head(seed: int = 7, target_triangles: int = 300_000, eye_shape="round",
                        eye_spacing_mm: float = 63.0, noise_mm: float = 0.0,
                        texture_size: int = 1024, skin_detail: float = 1.0) -> SyntheticHead:
    """Generate the procedural test head.

    Parameters
    ----------
    seed : int
        Drives every shape detail (eyeball radius 11-13.5 mm, cornea, gaze, lid
        shape, face proportions, skin detail, eye hints).
    target_triangles : int
        Approximate triangle count (grid chosen to match within ~1 %), >= 200.
    eye_shape : {"round", "hooded"} or float
        Hoodedness in [0, 1]: 0 = round open eye, 1 = hooded (lower upper lid and a
        skin fold over it).
    eye_spacing_mm : float
        Interpupillary distance (distance between eyeball centres), mm.
    noise_mm : float
        Scanner noise: Gaussian displacement along vertex normals, this std (0 = off).
    texture_size : int
        Side of the square colour texture in pixels.
    skin_detail : float
        Scale of the fine skin detail (1 = nominal, 0 = none).

    Returns
    -------
    SyntheticHead
    """
    if isinstance(eye_shape, str):
        if eye_shape not in EYE_SHAPES:
            raise ValueError(f"eye_shape must be one of {sorted(EYE_SHAPES)} or a number in [0, 1], "
                             f"got {eye_shape!r}")
        hood = EYE_SHAPES[eye_shape]
    else:
        hood = float(eye_shape)
        if not 0.0 <= hood <= 1.0:
            raise ValueError(f"eye_shape hoodedness must be in [0, 1], got {hood}")
    if not 40.0 <= float(eye_spacing_mm) <= 80.0:
        raise ValueError(f"eye_spacing_mm must be in [40, 80], got {eye_spacing_mm}")
    if not float(noise_mm) >= 0.0:
        raise ValueError(f"noise_mm must be >= 0, got {noise_mm}")
    if int(texture_size) < 16:
        raise ValueError(f"texture_size must be >= 16, got {texture_size}")
    seed = int(seed)
    model = _Model(seed, hood, eye_spacing_mm, skin_detail)
    ny, nt = grid_shape(target_triangles)
    tv = np.linspace(-_T_RANGE, _T_RANGE, nt)
    yv = np.linspace(_Y_RANGE[0], _Y_RANGE[1], ny)
    T, Y = np.meshgrid(tv, yv)
    base = tuple(np.broadcast_to(b, T.shape).ravel() for b in _base(tv))
    f = model.fields(T.ravel(), Y.ravel(), detail=True, base=base)
    P = _points(f, Y.ravel(), f["h"]).reshape(ny, nt, 3)
    if noise_mm > 0:
        nrng = np.random.default_rng([seed, 1])
        P = P + _normals(P) * nrng.normal(0.0, float(noise_mm), size=(ny, nt, 1))
    V = P.reshape(-1, 3)
    F = _grid_faces(ny, nt)
    UV = np.stack([(T.ravel() + _T_RANGE) / (2 * _T_RANGE),
                   (Y.ravel() - _Y_RANGE[0]) / (_Y_RANGE[1] - _Y_RANGE[0])], 1)
    texture = _paint_texture(model, int(texture_size))
    gt, hints = _ground_truth(model, np.random.default_rng([seed, 2]), target_triangles)
    gt["skin_detail_amplitude_mm"] = round(float(np.abs(f["detail"]).max()), 5)
    gt["skin_detail_rms_mm"] = round(float(np.sqrt(np.mean(f["detail"][f["detail"] != 0] ** 2))), 5) \
        if np.any(f["detail"] != 0) else 0.0
    gt["noise_mm"] = float(noise_mm)
    gt["mesh"] = {"file": "scan.ply", "n_vertices": int(len(V)), "n_faces": int(len(F))}
    return SyntheticHead(V=V, F=F, UV=UV, texture=texture, ground_truth=gt, hints=hints,
                         grid_shape=(ny, nt))


# ----------------------------------------------------------------------------- writing

def ply_bytes(V, F, UV, texture_name="texture.png") -> bytes:
    """Binary little-endian PLY: float32 x y z s t per vertex, int32 triangles."""
    V = np.asarray(V)
    F = np.asarray(F)
    vert = np.empty(len(V), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("s", "<f4"), ("t", "<f4")])
    vert["x"], vert["y"], vert["z"] = V[:, 0], V[:, 1], V[:, 2]
    vert["s"], vert["t"] = UV[:, 0], UV[:, 1]
    face = np.empty(len(F), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"] = 3
    face["v"] = F
    header = ("ply\nformat binary_little_endian 1.0\ncomment eyerig synthetic head (mm, +Y up, +Z forward)\n"
              f"comment TextureFile {texture_name}\n"
              f"element vertex {len(V)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property float s\nproperty float t\n"
              f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
    return header.encode("ascii") + vert.tobytes() + face.tobytes()


def png_bytes(image) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buf, format="PNG", compress_level=3)
    return buf.getvalue()


def scan_yaml_text(head: SyntheticHead) -> str:
    import yaml

    data = {
        "mesh": "scan.ply",
        "texture": "texture.png",
        "units": "mm",
        "up_axis": "+Y",
        "forward_axis": "+Z",
        "eyes": {side: {"hint": [float(v) for v in head.hints[side]]} for side in ("left", "right")},
        "licence": LICENCE,
    }
    return "# procedural synthetic head (eyerig); ground truth in ground_truth.json\n" + \
        yaml.safe_dump(data, sort_keys=False, default_flow_style=None)


def write_scan_folder(head: SyntheticHead, folder) -> None:
    """Write ``scan.ply``, ``texture.png``, ``scan.yaml`` and ``ground_truth.json`` into ``folder``.

    ``folder`` must exist (a stage passes the temporary folder of ``atomic_dir``).
    """
    folder = Path(folder)
    (folder / "scan.ply").write_bytes(ply_bytes(head.V, head.F, head.UV))
    (folder / "texture.png").write_bytes(png_bytes(head.texture))
    (folder / "scan.yaml").write_text(scan_yaml_text(head), encoding="utf-8")
    (folder / "ground_truth.json").write_text(json.dumps(head.ground_truth, indent=1) + "\n",
                                              encoding="utf-8")
