"""The procedural head's shape model: the base curve of the skull outline, seeded smooth noise,
the two eyes (sphere plus cornea, almond-shaped openings) and :class:`HeadModel`, whose
``fields(t, y)`` evaluates the skin and eye depths along the base curve's outward normal
(see :mod:`pipeline.synthetic_head`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from pipeline.geometry.ramps import smoothstep

# base curve (superellipse in x-z) and domain
_A_MM = 75.0          # half width of the head at the base curve
_B_MM = 92.0          # base curve front (forehead) z
_P = 4.0              # superellipse exponent: flat front, rounded sides
T_RANGE = np.deg2rad(98.0)   # +-t covered: front half of the head out past the temples
Y_RANGE = (-150.0, 95.0)     # neck to upper forehead, eyes at y ~ 0

_K_LID = 1.0          # smooth-max width of the lid/eye crease (mm)
_K_CORNEA = 0.5       # smooth-max width of the sclera/cornea seam (mm)
_K_POCKET = 0.6       # smooth-max width of the lid's inner face and the corner pockets' floor (mm)
_POCKET_SINK = 12.0   # how far a corner pocket's floor sinks where it fades out (mm)
_MISS = -1.0e3        # depth of a ray that misses a sphere


# ----------------------------------------------------------------------------- helpers

def _smax(a, b, k):
    """Polynomial smooth maximum: ``max(a, b)`` where ``|a - b| >= k``, rounded inside."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + h * h * k * 0.25


def _gauss(x, s):
    return np.exp(-(x / s) ** 2)


def _rho(t):
    s, c = np.abs(np.sin(t)), np.abs(np.cos(t))
    return 1.0 / ((s / _A_MM) ** _P + (c / _B_MM) ** _P) ** (1.0 / _P)


def base_curve(t):
    """Base curve point (x, z) and outward unit normal (nx, nz) at angle ``t``."""
    r = _rho(t)
    x, z = r * np.sin(t), r * np.cos(t)
    eps = 1e-5
    rp, rm = _rho(t + eps), _rho(t - eps)
    dx = (rp * np.sin(t + eps) - rm * np.sin(t - eps)) / (2 * eps)
    dz = (rp * np.cos(t + eps) - rm * np.cos(t - eps)) / (2 * eps)
    n = np.hypot(dx, dz)
    return x, z, -dz / n, dx / n


_ARC_T = np.linspace(-T_RANGE, T_RANGE, 4001)


def _arc_table():
    x, z = _rho(_ARC_T) * np.sin(_ARC_T), _rho(_ARC_T) * np.cos(_ARC_T)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
    return s - np.interp(0.0, _ARC_T, s)


_ARC_S = _arc_table()


def arc(t):
    """Signed arc length (mm) along the base curve from the midline (t = 0)."""
    return np.interp(t, _ARC_T, _ARC_S)


def t_for_x(x):
    """Base-curve angle whose base point has abscissa ``x`` (front half)."""
    lo, hi = -T_RANGE, T_RANGE
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
    limbus_radius: float       # radius of the circle where the cornea meets the sclera (mm)
    e1: np.ndarray             # (3,) the eye frame's horizontal axis (head +X side)
    e2: np.ndarray             # (3,) the eye frame's vertical axis (up)
    almond: dict               # the opening in the eye's (u, v) plane (mm), see almond_curves
    boundary_mm: np.ndarray    # (k, 2) almond boundary in (u, v): upper lid medial->lateral, lower back
    boundary_s: np.ndarray     # (k,) almond parameter s of each boundary point
    tree: object               # cKDTree over boundary_mm
    crow_angles: np.ndarray    # crow's-feet line angles (rad)
    lateral_canthus: np.ndarray  # (2,) (u, v) of the lateral corner


def almond_curves(al, s):
    """Upper and lower lid heights ``v`` (mm, in the eye's plane) at almond parameter ``s`` in
    [0, 1] (medial corner 0, lateral corner 1), and the canthal line between them."""
    s = np.clip(s, 0.0, 1.0)
    base = al["v_m"] + (al["v_l"] - al["v_m"]) * s
    up = base + al["h_u"] * np.sin(np.pi * s ** al["g_u"])
    lo = base - al["h_l"] * np.sin(np.pi * s ** al["g_l"]) ** 0.85
    return base, up, lo


def standoff(al, s):
    """How far the lid margin stands off the globe (mm) at almond parameter ``s``: ``st_mid``
    between the canthi, growing toward each corner to the corner's own distance off the globe."""
    s = np.clip(s, 0.0, 1.0)
    gm = np.maximum(1.0 - s / _GROW_MEDIAL, 0.0) ** 2
    gl = np.maximum(1.0 - (1.0 - s) / _GROW_LATERAL, 0.0) ** 2
    return al["st_mid"] + (al["st_m"] - al["st_mid"]) * gm + (al["st_l"] - al["st_mid"]) * gl


#: Share of the fissure (from each corner) over which the margin's standoff grows to the corner's.
_GROW_MEDIAL, _GROW_LATERAL = 0.3, 0.15
#: UnityEyes' eight registered eye regions around a 12.05 mm eye (mean, SD; mm): the medial end of
#: the fissure and the lateral corner in front of the centre along the gaze and off the gaze axis
#: (docs/remove_eyeballs.md, texture fallback); the procedural corners scale them with the radius.
_ANATOMY_RADIUS_MM = 12.05
_MEDIAL_FWD, _LATERAL_FWD, _LATERAL_AXIS = (8.56, 0.69), (4.51, 1.18), (12.68, 0.41)
#: Population fissure (mm, mean and SD; the width at the mean radius, scaled with the radius).
_FISSURE_WIDTH, _FISSURE_HEIGHT = (27.0, 1.7), (9.5, 1.5)
_MEAN_RADIUS_MM = 11.7
#: The lateral corner lies at least this far off the globe (mm).
_LATERAL_MIN_OFF_MM = 0.6
#: A fully hooded upper lid hangs this much lower than a round one (mm).
_HOOD_DROP_MM = 1.2
#: The cornea of the paper's eye (SynthesEyes 3.1, the asset's eyeball) at r1 = 12 mm, scaled with
#: r1: corneal sphere radius and apex distance from the centre (the limbus, where the two spheres
#: meet, then lies 6.6 mm off the axis and 10.0 mm in front): a head whose eye is the asset's own
#: is placed exactly, since the asset's eye is anchored at that limbus.
_CORNEA_R2_MM, _CORNEA_APEX_MM = 8.0, 13.5


def _clipped_normal(rng, mean, sd, k=2.0):
    return float(mean + sd * np.clip(rng.normal(), -k, k))


def draw_radius(rng, mean, sd):
    """One eyeball radius for a head (both eyes): a normal draw clipped to +-3 SD."""
    return _clipped_normal(rng, mean, sd, 3.0)


def _make_eye(side, rng, ipd, hood, y_eye, radius):
    from scipy.spatial import cKDTree

    lat = 1.0 if side == "left" else -1.0
    x = lat * (ipd / 2.0 + rng.uniform(-0.3, 0.3))
    tx = t_for_x(x)
    bx, bz, _, _ = base_curve(np.array([tx]))
    # the cornea's front stays where a 12.25 mm eye's was: a larger sphere sits deeper
    depth = 15.0 + (radius - 12.25)
    center = np.array([x, y_eye + rng.uniform(-0.4, 0.4), float(bz[0]) - depth + rng.uniform(-0.5, 0.5)])
    yaw = np.deg2rad(rng.uniform(-2.0, 2.0))
    pitch = np.deg2rad(rng.uniform(-2.0, 2.0))
    gaze = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    e1 = np.cross([0.0, 1.0, 0.0], gaze)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(gaze, e1)
    # the paper's cornea, scaled with the globe (r2 8 mm, apex 13.5 mm at r1 = 12)
    k = radius / 12.0
    rc = _CORNEA_R2_MM * k * rng.uniform(0.985, 1.015)
    apex_dist = _CORNEA_APEX_MM * k * rng.uniform(0.995, 1.005)
    cc = center + (apex_dist - rc) * gaze
    dcc = apex_dist - rc
    zl = (radius ** 2 + dcc ** 2 - rc ** 2) / (2 * dcc)
    limbus_r = float(np.sqrt(max(radius ** 2 - zl ** 2, 0.0)))
    # the fissure (UnityEyes' regions and the adult population; corners scaled with the radius)
    sc = radius / _ANATOMY_RADIUS_MM
    width = float(np.clip(_clipped_normal(rng, _FISSURE_WIDTH[0], 0.8 * _FISSURE_WIDTH[1]) * radius
                          / _MEAN_RADIUS_MM, _FISSURE_WIDTH[0] - 1.9 * _FISSURE_WIDTH[1],
                          _FISSURE_WIDTH[0] + 1.9 * _FISSURE_WIDTH[1]))
    f_m = float(np.clip(_clipped_normal(rng, *_MEDIAL_FWD) * sc, 7.2, 9.9))
    f_l = float(np.clip(_clipped_normal(rng, *_LATERAL_FWD) * sc, 2.2, 5.8))
    a_l = _clipped_normal(rng, *_LATERAL_AXIS) * sc
    # the lateral corner stays off the globe (a shallow corner on a large eye would touch it)
    a_l = float(max(a_l, np.sqrt((radius + _LATERAL_MIN_OFF_MM) ** 2 - f_l ** 2)))
    v_m, v_l = -rng.uniform(0.2, 0.8), rng.uniform(0.3, 1.5)
    horiz = np.sqrt(max(width ** 2 - (v_l - v_m) ** 2 - (f_m - f_l) ** 2, 1.0))
    u_l = float(np.sqrt(max(a_l ** 2 - v_l ** 2, 1.0)))
    u_m = float(u_l - horiz)                      # the medial corner: the rest of the width
    # height: a round opening's draw, the hooded lid lower by up to 1.2 mm
    h_round = _clipped_normal(rng, _FISSURE_HEIGHT[0] + 0.6, 0.85 * _FISSURE_HEIGHT[1])
    height = h_round - _HOOD_DROP_MM * hood
    al = {"u_m": u_m, "u_l": u_l, "v_m": float(v_m), "v_l": float(v_l), "f_m": f_m, "f_l": f_l,
          "g_u": float(rng.uniform(0.8, 0.95)), "g_l": float(rng.uniform(1.1, 1.25)),
          "h_u": 0.55 * h_round - _HOOD_DROP_MM * hood, "h_l": 0.45 * h_round}
    s = np.linspace(0.0, 1.0, 1500)
    _, up, lo = almond_curves(al, s)
    kh = height / float(up.max() - lo.min())
    al["h_u"] *= kh
    al["h_l"] *= kh
    # the margin's standoff off the globe: st_mid between the canthi, the corners' own at the ends
    al["st_mid"] = float(rng.uniform(0.5, 0.9))
    al["st_m"] = float(np.hypot(np.hypot(u_m, v_m), f_m) - radius)
    al["st_l"] = float(np.hypot(np.hypot(u_l, v_l), f_l) - radius)
    # the corner pockets' floors (caruncle medially) lie this far behind the corners
    al["pocket_m"], al["pocket_l"] = float(rng.uniform(1.2, 1.6)), float(rng.uniform(0.8, 1.0))
    _, up, lo = almond_curves(al, s)
    uu = al["u_m"] + (al["u_l"] - al["u_m"]) * s
    bnd = np.concatenate([np.stack([uu, up], 1), np.stack([uu[::-1], lo[::-1]], 1)])
    bs = np.concatenate([s, s[::-1]])
    crow = np.deg2rad(rng.uniform(-35, 35, size=5) + np.array([-50, -25, 0, 25, 50]) * 0.9)
    eye = _Eye(side, lat, center, radius, gaze, cc, rc, center + apex_dist * gaze, limbus_r, e1, e2,
               al, bnd, bs, cKDTree(bnd), crow, np.array([u_l, v_l]))
    # the lateral corner lies in the (u, v) plane at its depth; the medial corner's ray crosses
    # that plane 3-5 mm behind it, a little off the gaze: its standoff puts it at depth f_m exactly
    t, y = ray_for_uv(eye, u_m, v_m)
    bx, bz, nx, nz = base_curve(np.array([t]))
    o = np.array([bx[0], y, bz[0]])
    n = np.array([nx[0], 0.0, nz[0]])
    p = o + (f_m - (o - center) @ gaze) / (n @ gaze) * n
    al["st_m"] = float(np.linalg.norm(p - center) - radius)
    return eye


def eye_plane_uv(e, ox, oy, oz, nx, nz):
    """Where rays ``o + h n`` cross the eye's reference plane (across the gaze, at the lateral
    corner's depth in front of the centre, where the rays tilt most): ``(u, v)`` mm, ``u`` toward
    the lateral side, ``v`` up."""
    g = e.gaze
    w_ref = e.almond["f_l"]
    px, py, pz = ox - e.center[0], oy - e.center[1], oz - e.center[2]
    den = nx * g[0] + nz * g[2]
    h = (w_ref - (px * g[0] + py * g[1] + pz * g[2])) / den
    qx, qy, qz = px + h * nx, py, pz + h * nz
    u = e.lat * (qx * e.e1[0] + qy * e.e1[1] + qz * e.e1[2])
    v = qx * e.e2[0] + qy * e.e2[1] + qz * e.e2[2]
    return u, v


def mm_per_t(t0):
    """Millimetres along the base curve per radian of ``t`` at ``t0``."""
    bx, bz, _, _ = base_curve(np.array([t0 - 1e-3, t0 + 1e-3]))
    return float(np.hypot(bx[1] - bx[0], bz[1] - bz[0]) / 2e-3)


def ray_for_uv(e, u, v, iters=8):
    """Grid parameters ``(t, y)`` of the ray that crosses the eye's plane at ``(u, v)``."""
    p = e.center + e.almond["f_l"] * e.gaze + e.lat * u * e.e1 + v * e.e2
    t, y = t_for_x(p[0]), float(p[1])
    for _ in range(iters):
        bx, bz, nx, nz = base_curve(np.array([t]))
        uu, vv = eye_plane_uv(e, bx, np.array([y]), bz, nx, nz)
        dt = e.lat * (u - uu[0]) / (mm_per_t(t) * (e.e1[0] * nz[0] - e.e1[2] * nx[0]))
        t, y = t + float(dt), y + float(v - vv[0])
    return t, y


def _depth_at_w(e, ox, oy, oz, nx, nz, w):
    """Ray parameter ``h`` where rays reach ``w`` mm in front of the eye centre along the gaze."""
    g = e.gaze
    px, py, pz = ox - e.center[0], oy - e.center[1], oz - e.center[2]
    return (w - (px * g[0] + py * g[1] + pz * g[2])) / (nx * g[0] + nz * g[2])


class HeadModel:
    """All seeded shape parameters; ``fields(t, y)`` evaluates the surface depths."""

    def __init__(self, seed, eye_shape, eye_spacing_mm, detail, eye_radius_mm=(11.7, 0.45), *,
                 wrinkle_scale=1.0, pore_scale=1.0, skin_tone=None):
        rng = np.random.default_rng(seed)
        self.skin_tone = skin_tone           # None: paint's base tone
        self.seed = seed
        self.hood = float(eye_shape)
        self.ipd = float(eye_spacing_mm)
        self.detail_scale = float(detail)
        self.y_eye = 0.0
        # one eyeball radius per head (both eyes one size), drawn from the population
        self.radius = draw_radius(rng, *(float(r) for r in eye_radius_mm))
        self.eyes = [_make_eye("left", rng, self.ipd, self.hood, self.y_eye, self.radius),
                     _make_eye("right", rng, self.ipd, self.hood, self.y_eye, self.radius)]
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
        # the seed draws the depths; an identity's age-like scales multiply them (1.0: the draw, exactly)
        self.pore_depth = float(rng.uniform(0.07, 0.1)) * float(pore_scale)
        self.wrinkle_depth = float(rng.uniform(0.25, 0.32)) * float(wrinkle_scale)
        self.pore_fine = 0.03 * float(pore_scale)

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
        prof = f["nose"] * smoothstep(12.0, -44.0, y) ** 1.3 * smoothstep(-58.0, -45.0, y)
        width = f["nose_w"] * (8.0 + 7.0 * smoothstep(4.0, -46.0, y))
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
        h -= f["jaw"] * (ax / _A_MM) ** 2.5 * smoothstep(-25.0, -115.0, y)
        h -= 30.0 * smoothstep(-106.0, -132.0, y) * (1.0 - 0.6 * (ax / _A_MM) ** 2)
        return h

    # -- everything along the rays ------------------------------------------
    def fields(self, t, y, detail=True, want_texture=False, base=None):
        """Depths along the rays at grid parameters ``t`` (rad), ``y`` (mm).

        Returns a dict with ``h`` (final depth), ``h_skin``, ``h_eye``, base point and
        normal (``bx, bz, nx, nz``) and, for texturing, the eye-local fields.
        """
        t = np.asarray(t, float)
        y = np.asarray(y, float)
        bx, bz, nx, nz = base_curve(t) if base is None else base
        h_face = self.face_depth(bx, y)
        h_skin = h_face.copy()
        h_eye = np.full(t.shape, _MISS)
        d_all = np.full(t.shape, 99.0)
        wrinkle = np.zeros(t.shape)
        out = {}
        if want_texture:
            out.update(eye_angle=np.full(t.shape, np.pi), eye_radius=np.zeros(t.shape),
                       iris_radius=np.zeros(t.shape), upper=np.zeros(t.shape),
                       pocket=np.zeros(t.shape, bool))
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
            # the opening: an almond in the eye's plane across the gaze, (u, v) mm
            al = e.almond
            u, v = eye_plane_uv(e, ox, oy, oz, mx, mz)
            s = (u - al["u_m"]) / (al["u_l"] - al["u_m"])
            base_b, up, lo = almond_curves(al, s)
            dist, near = e.tree.query(np.stack([u, v], 1))
            inside = (s > 0) & (s < 1) & (v < up) & (v > lo)
            d = np.where(inside, -dist, dist)
            s_near = e.boundary_s[near]
            upper = smoothstep(-0.25, 0.25, v - base_b)
            # lid profile: the margin stands st(s) off the eye surface; outside it the lid
            # thickens, inside it drops behind the eye (the lid's inner face)
            st = standoff(al, s_near)
            thick = 2.3 + 0.4 * upper
            tout = thick * np.tanh(np.maximum(d, 0.0) / 1.1) + 0.3 * np.maximum(d - 2.0, 0.0)
            tin = -(st + 2.5) * (1.0 - np.exp(np.minimum(d, 0.0) / 0.45))
            tlid = st + np.where(d >= 0, tout, tin)
            # upper-lid crease (round) or a hanging skin fold (hooded)
            hood = self.hood
            fold = upper * ((1 - hood) * (-0.9 * _gauss(d - 7.5, 1.3))
                            + hood * (2.6 * _gauss(d - 3.6, 1.6) - 1.2 * _gauss(d - 6.5, 1.2)))
            lower_fold = (1 - upper) * (-0.5 * _gauss(d - 5.5, 1.8))
            tlid = tlid + np.where(d > 0, (fold + lower_fold) * smoothstep(0.0, 1.2, d), 0.0)
            # lid shell follows the eye surface scaled out by T (misses: continued past the rim)
            rs = e.radius + np.maximum(tlid, -e.radius + 1.0)
            hl_s, h0s, dds = _ray_sphere(ox, oy, oz, mx, mz, c, rs)
            hl_s = np.where(hl_s > _MISS, hl_s, h0s - 2.0 * (np.sqrt(dds) - rs))
            hl_c, _, _ = _ray_sphere(ox, oy, oz, mx, mz, e.cornea_center,
                                     np.maximum(e.cornea_radius + tlid, 0.5))
            h_lid = _smax(hl_s, hl_c, _K_CORNEA)
            # the corners lie off the globe: where the fissure runs past the globe's silhouette a
            # floor of tissue fills it, the caruncle medially (a low mound), the lateral fornix
            # laterally; each sinks under the globe toward the opening's middle
            du_m, du_l = u - al["u_m"], al["u_l"] - u
            w_med = (al["f_m"] - al["pocket_m"] - 0.12 * np.maximum(du_m, 0.0)
                     + 0.5 * np.exp(-((du_m - 2.5) / 2.2) ** 2 - ((v - al["v_m"]) / 1.6) ** 2))
            w_lat = al["f_l"] - al["pocket_l"] - 0.1 * np.maximum(du_l, 0.0)
            near_d = 1.0 - smoothstep(0.5, 2.0, d)
            m_med = (1.0 - smoothstep(0.2, 0.3, s)) * near_d
            m_lat = smoothstep(0.86, 0.93, s) * near_d
            h_pock = np.maximum(
                _depth_at_w(e, ox, oy, oz, mx, mz, w_med - _POCKET_SINK * (1.0 - m_med)),
                _depth_at_w(e, ox, oy, oz, mx, mz, w_lat - _POCKET_SINK * (1.0 - m_lat)))
            h_lid = _smax(h_lid, h_pock, _K_POCKET)
            pocket = (h_pock >= h_lid - 0.05) & (d < 0.5)
            # a few mm out from the margin the skin never sinks behind the face (no moat)
            q = smoothstep(1.0, 4.0, d)
            h_lid = h_lid + q * (_smax(h_lid, h_skin[box], 3.0) - h_lid)
            w = 1.0 - smoothstep(2.5, 12.0, d)
            hsk = w * h_lid + (1 - w) * h_skin[box]
            h_skin[box] = hsk
            h_eye[box] = np.maximum(h_eye[box], he)
            d_all[box] = np.minimum(d_all[box], d)
            # crow's feet and lower-lid lines (negative = crease)
            if detail:
                lc = e.lateral_canthus
                da, db = u - lc[0], v - lc[1]
                rr = np.hypot(da, db)
                ang = np.arctan2(db, da)
                cf = np.zeros_like(rr)
                for a0 in e.crow_angles:
                    cf += _gauss(rr * np.sin(ang - a0), 0.35) * (np.cos(ang - a0) > 0)
                cf *= smoothstep(2.0, 5.0, rr) * (1 - smoothstep(9.0, 15.0, rr))
                ll = (1 - upper) * (_gauss(d - 3.2, 0.35) + 0.7 * _gauss(d - 6.0, 0.4)) \
                    * smoothstep(0.15, 0.45, s) * (1 - smoothstep(0.75, 1.05, s))
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
                out["iris_radius"][box] = e.limbus_radius - 0.1
                out["upper"][box] = np.maximum(out["upper"][box], upper)
                out["pocket"][box] |= pocket
        det = np.zeros(t.shape)
        if detail and self.detail_scale > 0:
            det = self.skin_detail(bx, arc(t), y, d_all, wrinkle) * self.detail_scale
            h_skin = h_skin + det
        h = _smax(h_skin, h_eye, _K_LID)
        out.update(h=h, h_skin=h_skin, h_eye=h_eye, d=d_all, detail=det, bx=bx, bz=bz, nx=nx, nz=nz,
                   wrinkle=wrinkle)
        return out

    def skin_detail(self, x, u, y, d, wrinkle):
        """Signed skin displacement (mm): pores, forehead lines, crow's feet, lid lines."""
        pores = self.noise_pore(u / 0.55, y / 0.55)
        pores = -self.pore_depth * smoothstep(0.55, 0.85, pores) \
            + self.pore_fine * (self.noise_pore(u / 2.3 + 91.0, y / 2.3) - 0.5)
        fl = np.zeros_like(x)
        for yk, ph in zip(self.forehead_lines, self.forehead_phase):
            yy = yk + 2.0 * np.sin(x / 23.0 + ph) + 0.00045 * x * x
            fl += _gauss(y - yy, 0.55)
        fl *= 1 - smoothstep(38.0, 60.0, np.abs(x))
        lines = np.minimum(fl, 1.0)
        wr = self.wrinkle_depth * np.minimum(-wrinkle + lines, 1.0)
        det = pores - wr
        # no detail on (or right next to) the eye: fade to 0 at the lid margin
        return det * smoothstep(0.6, 2.0, d)


def surface_points(f, y, h):
    return np.stack([f["bx"] + h * f["nx"], y, f["bz"] + h * f["nz"]], axis=-1)
