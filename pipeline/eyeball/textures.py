"""Procedural eyeball textures (numpy), deterministic by seed.

Iris textures use the polar layout of :func:`pipeline.eyeball.geometry.inner_mesh`:
the image centre is the pupil centre, the pupil boundary sits at radius
``IRIS_TEXTURE_PUPIL_FRACTION`` and the iris boundary at
``IRIS_TEXTURE_IRIS_FRACTION`` of the half-width. They are built from
radial fibres (angle-stretched smoothed noise with a wavy warp), the
collarette (a wavy ridge separating the pupillary and ciliary zones, with a
differently tinted pupillary zone), crypts (dark radially elongated lacunae
near the collarette), concentric contraction furrows, a dark pupillary ruff
and a darker limbal ring. The pupil is black.

Sclera textures are equirectangular over the inner sclera UVs (u = azimuth /
2pi, v = 1 at the limbus, 0 at the back pole): a near-white base with faint
mottling, a soft grey limbal transition (last ~1 mm before the iris) and a veins layer (``bloodshot``: many red branching vessels
running from the back toward the limbus, densest at the eye corners; ``clear``:
a few faint ones). The tint layer is a colour multiplier (:data:`SCLERA_TINTS`),
applied by the material (UsdUVTexture ``scale``, Cycles mix), not baked in.

All images are float32 RGB in [0, 1], sRGB-encoded, row 0 = top (v = 1).
"""

from __future__ import annotations

import numpy as np

from pipeline.eyeball.geometry import IRIS_TEXTURE_IRIS_FRACTION, IRIS_TEXTURE_PUPIL_FRACTION
from pipeline.geometry.ramps import smoothstep

IRIS_COLORS = ("amber", "blue", "brown", "grey")
SCLERA_TINTS = {"white": (1.0, 1.0, 1.0), "pink": (1.0, 0.84, 0.82), "yellow": (1.0, 0.94, 0.74)}
VEINS = ("bloodshot", "clear")

# (stroma dark, fibre light, pupillary zone, limbal ring), sRGB
_PALETTES = {
    "blue": ((0.16, 0.27, 0.42), (0.52, 0.68, 0.84), (0.42, 0.46, 0.44), (0.06, 0.09, 0.16)),
    "grey": ((0.30, 0.33, 0.35), (0.66, 0.70, 0.72), (0.50, 0.48, 0.40), (0.14, 0.15, 0.17)),
    "brown": ((0.09, 0.045, 0.02), (0.36, 0.21, 0.10), (0.20, 0.10, 0.04), (0.04, 0.02, 0.01)),
    "amber": ((0.33, 0.18, 0.04), (0.84, 0.58, 0.20), (0.52, 0.28, 0.08), (0.16, 0.08, 0.02)),
}
_SEED_OFFSET = {"amber": 11, "blue": 23, "brown": 37, "grey": 53}


def _smooth_noise(rng, shape, sigma, wrap_axes=()):
    from scipy.ndimage import gaussian_filter

    a = rng.standard_normal(shape)
    modes = ["wrap" if i in wrap_axes else "reflect" for i in range(len(shape))]
    a = gaussian_filter(a, sigma, mode=modes)
    return (a - a.mean()) / (a.std() + 1e-12)


def _sample_polar(grid, ang, t):
    """Bilinear sample of grid (n_ang, n_t) at angle fraction ang in [0,1) and t in [0,1]."""
    na, nt = grid.shape
    x = (ang % 1.0) * na
    y = np.clip(t, 0, 1) * (nt - 1)
    x0 = np.floor(x).astype(int)
    y0 = np.clip(np.floor(y).astype(int), 0, nt - 2)
    fx, fy = x - x0, y - y0
    x0 %= na
    x1 = (x0 + 1) % na
    g = grid
    return ((g[x0, y0] * (1 - fx) + g[x1, y0] * fx) * (1 - fy)
            + (g[x0, y0 + 1] * (1 - fx) + g[x1, y0 + 1] * fx) * fy)


def iris_texture(color: str, size: int = 512, seed: int = 0) -> np.ndarray:
    """One iris texture.

    Parameters
    ----------
    color : {"amber", "blue", "brown", "grey"}
    size : int, image width = height (pixels)
    seed : int

    Returns
    -------
    (size, size, 3) float32 sRGB in [0, 1]
    """
    if color not in _PALETTES:
        raise ValueError(f"unknown iris colour {color!r}; choose one of {IRIS_COLORS}")
    if size < 16:
        raise ValueError("iris texture size must be >= 16")
    rng = np.random.default_rng([int(seed), _SEED_OFFSET[color]])
    dark, light, inner, limbal = (np.array(c, float) for c in _PALETTES[color])
    c = (np.arange(size) + 0.5) / size * 2 - 1           # [-1, 1] with v up after flip
    X, Y = np.meshgrid(c, c)
    r = np.hypot(X, Y)
    ang = (np.arctan2(Y, X) / (2 * np.pi)) % 1.0
    fp, fi = IRIS_TEXTURE_PUPIL_FRACTION, IRIS_TEXTURE_IRIS_FRACTION
    t = (r - fp) / (fi - fp)                               # 0 at pupil, 1 at limbus

    # wavy warp of the angle (fibres are not perfectly radial)
    warp = _smooth_noise(rng, (64, 16), (3, 2), wrap_axes=(0,))
    a_w = ang + 0.0025 * _sample_polar(warp, ang, t)
    # radial fibres: fine (sigma ~1 px in angle) and coarse bundles
    fib_f = _smooth_noise(rng, (1400, 48), (0.9, 5.0), wrap_axes=(0,))
    fib_c = _smooth_noise(rng, (360, 24), (1.5, 3.0), wrap_axes=(0,))
    fib = 0.55 * _sample_polar(fib_f, a_w, t) + 0.45 * _sample_polar(fib_c, a_w, t)
    fibre = 1 / (1 + np.exp(-1.3 * fib))                   # 0..1, light = raised fibres

    # collarette: wavy ring at ~35 % of the iris width
    wav = _smooth_noise(rng, (96, 4), (2.5, 1), wrap_axes=(0,))
    t_col = 0.33 + 0.035 * _sample_polar(wav, ang, np.zeros_like(t))
    ridge = np.exp(-((t - t_col) / 0.035) ** 2)
    pupillary = 1 - smoothstep(t_col - 0.08, t_col + 0.06, t)

    col = dark[None, None] * (1 - fibre[..., None]) + light[None, None] * fibre[..., None]
    # pupillary zone tint
    col = col * (1 - 0.4 * pupillary[..., None]) + inner[None, None] * (0.4 * pupillary * (0.6 + 0.8 * fibre))[..., None]
    # collarette ridge lighter
    col = col + 0.18 * ridge[..., None] * (light - dark)[None, None]

    # crypts: dark radially elongated blobs near the collarette and in the ciliary zone
    # (drawn on a polar grid, then sampled: cheap and seamless across the angle wrap)
    na, nt = 1024, 128
    ga = (np.arange(na) + 0.5) / na
    gt = np.linspace(0, 1, nt)
    grid = np.zeros((na, nt))
    n_crypts = int(rng.integers(28, 44))
    ca = rng.random(n_crypts)
    ct = np.clip(rng.normal(0.45, 0.14, n_crypts), 0.2, 0.85)
    for a0, t0 in zip(ca, ct):
        wa = rng.uniform(0.004, 0.012)
        wt = rng.uniform(0.03, 0.08)
        amp = rng.uniform(0.5, 1.0)
        ia = (np.arange(int(a0 * na - 3 * wa * na) - 1, int(a0 * na + 3 * wa * na) + 2)) % na
        it = np.flatnonzero(np.abs(gt - t0) < 3 * wt)
        da = ((ga[ia] - a0 + 0.5) % 1.0) - 0.5
        blob = np.exp(-(da[:, None] / wa) ** 2 - ((gt[it][None, :] - t0) / wt) ** 2) * amp
        sub = grid[np.ix_(ia, it)]
        grid[np.ix_(ia, it)] = np.maximum(sub, blob)
    crypt = _sample_polar(grid, a_w, t) * ((t >= 0) & (t <= 1))
    col = col * (1 - 0.6 * crypt[..., None]) + dark[None, None] * 0.35 * crypt[..., None]

    # contraction furrows: broken concentric darker rings in the ciliary zone
    brk = _smooth_noise(rng, (128, 4), (4, 1), wrap_axes=(0,))
    for tf in (0.62, 0.74, 0.85):
        ring = np.exp(-((t - tf) / 0.012) ** 2) * (_sample_polar(brk, ang, np.full_like(t, tf)) > 0.2)
        col *= 1 - 0.25 * ring[..., None]

    # limbal ring and pupillary ruff
    limb = smoothstep(0.78, 1.0, t)
    col = col * (1 - 0.85 * limb[..., None]) + limbal[None, None] * 0.85 * limb[..., None]
    ruff = np.exp(-(np.clip(t, 0, None) / 0.035) ** 2) * (t >= 0)
    col = col * (1 - 0.5 * ruff[..., None])
    # fine grain
    grain = _smooth_noise(rng, (size, size), 0.7)
    col *= (1 + 0.05 * grain)[..., None]
    # pupil (soft 1 px edge) and outside the iris (limbal colour)
    pm = smoothstep(fp - 1.5 / size, fp + 0.5 / size, r)
    col = col * pm[..., None]
    outside = smoothstep(fi, fi + 2.0 / size, r)
    col = col * (1 - outside[..., None]) + limbal[None, None] * outside[..., None]
    img = np.clip(col, 0, 1).astype(np.float32)
    return np.flipud(img)  # row 0 = top = v 1


def _splat_paths(img_shape, paths, widths, rng):
    from scipy.ndimage import gaussian_filter

    h, w = img_shape
    acc = np.zeros((h, w))
    for pts, wd in zip(paths, widths):
        x = (pts[:, 0] % 1.0) * w
        y = np.clip(pts[:, 1], 0, 0.9999) * h
        np.add.at(acc, (y.astype(int), x.astype(int) % w), wd)
    return gaussian_filter(acc, (0.8, 0.8), mode=["reflect", "wrap"])


def sclera_texture(veins: str, width: int = 1024, height: int = 512, seed: int = 0) -> np.ndarray:
    """Sclera base + veins layer (untinted).

    Parameters
    ----------
    veins : {"bloodshot", "clear"}
    width, height : int
    seed : int

    Returns
    -------
    (height, width, 3) float32 sRGB in [0, 1], row 0 = v 1 (limbus).
    """
    from scipy.ndimage import gaussian_filter

    if veins not in VEINS:
        raise ValueError(f"unknown veins layer {veins!r}; choose one of {VEINS}")
    rng = np.random.default_rng([int(seed), 101])
    base = np.array([0.93, 0.91, 0.88])
    mott = _smooth_noise(rng, (height, width), (6, 12), wrap_axes=(1,))
    img = base[None, None] * (1 + 0.012 * mott[..., None])
    # slightly greyer toward the back, slightly warmer near the limbus
    vv = 1 - (np.arange(height) + 0.5) / height          # v per row (row 0 = v 1)
    img *= (0.9 + 0.1 * vv)[:, None, None]

    n = 45 if veins == "bloodshot" else 12
    strength = 1.0 if veins == "bloodshot" else 0.35
    paths, widths = [], []
    for _ in range(n):
        # corners of the eye (azimuth 0 and pi) get more vessels
        u0 = (rng.choice([0.0, 0.5]) + rng.normal(0, 0.09)) % 1.0 if rng.random() < 0.7 else rng.random()
        v0 = rng.uniform(0.3, 0.6)
        stack = [(u0, v0, 1.0, 0)]
        while stack:
            u, v, wd, depth = stack.pop()
            m = int(rng.integers(80, 220))
            # heading: mostly toward the limbus (+v), slowly meandering; steps ~1 px
            dev = np.empty(m)
            d = rng.normal(0, 0.5)
            eps = rng.normal(0, 0.15, m)
            for i in range(m):  # mean-reverting meander around "toward the limbus"
                d = 0.93 * d + eps[i]
                dev[i] = d
            head = np.pi / 2 + np.clip(dev, -1.3, 1.3)
            step = 1.0 / height
            pts = np.stack([u + np.cumsum(np.cos(head) * step * height / width * 2),
                            v + np.cumsum(np.sin(head) * step)], 1)
            # resample to ~0.3 px spacing so strokes are continuous
            k = 4
            tt = np.linspace(0, len(pts) - 1, (len(pts) - 1) * k + 1)
            pts = np.stack([np.interp(tt, np.arange(len(pts)), pts[:, 0]),
                            np.interp(tt, np.arange(len(pts)), pts[:, 1])], 1)
            pts = pts[pts[:, 1] < 0.985]
            if len(pts) < 3:
                continue
            paths.append(pts)
            widths.append(wd * 0.35)
            if depth < 3:
                for _k in range(int(rng.integers(0, 3))):
                    i = int(rng.integers(0, len(pts)))
                    stack.append((pts[i, 0], pts[i, 1], wd * 0.6, depth + 1))
    # image rows: v up -> row = (1 - v) * h
    flipped = [np.stack([p[:, 0], 1 - p[:, 1]], 1) for p in paths]
    dens = _splat_paths((height, width), flipped, widths, rng)
    dens = 1 - np.exp(-dens * 1.6)
    vessel = np.array([0.70, 0.12, 0.10])
    a = (strength * dens)[..., None]
    img = img * (1 - a) + vessel[None, None] * a
    # faint diffuse redness near the corners for bloodshot eyes
    if veins == "bloodshot":
        u = (np.arange(width) + 0.5) / width
        corner = np.maximum(np.cos(2 * np.pi * u), np.cos(2 * np.pi * (u - 0.5))) ** 6
        red = gaussian_filter(corner[None, :] * (0.3 + 0.7 * vv[:, None]), 3)
        img = img * (1 - 0.12 * red[..., None]) + np.array([0.85, 0.45, 0.42]) * 0.12 * red[..., None]
    # limbus: the sclera greys into the iris over ~1 mm (v within 0.035 of the limbus)
    lim = np.clip((vv - 0.965) / 0.035, 0, 1) ** 1.5
    img = img * (1 - 0.55 * lim)[:, None, None] + np.array([0.30, 0.30, 0.33]) * 0.25 * lim[:, None, None]
    return np.clip(img, 0, 1).astype(np.float32)


def to_uint8(img: np.ndarray) -> np.ndarray:
    """float [0, 1] -> uint8 (rounded)."""
    return np.clip(np.round(np.asarray(img) * 255.0), 0, 255).astype(np.uint8)


def texture_set(seed: int = 0, iris_size: int = 512, sclera_size=(1024, 512), params=None,
                resolution=None) -> dict[str, np.ndarray]:
    """All texture images by file name, uint8 (``sclera_bump.png`` uint16).

    ``iris_<colour>.png``, ``sclera_<veins>.png`` and the outer mesh's
    ``sclera_bump.png`` (height) / ``sclera_normal.png`` (tangent-space normals)
    for the given eyeball params and resolution (they follow the outer UVs).
    """
    import os
    from concurrent.futures import ThreadPoolExecutor

    from pipeline.eyeball import geometry as geo

    p = params or geo.EyeballParams()
    res = geo.Resolution.from_value(resolution or "high")
    jobs = {f"iris_{c}.png": (lambda c=c: to_uint8(iris_texture(c, iris_size, seed))) for c in IRIS_COLORS}
    for v in VEINS:
        jobs[f"sclera_{v}.png"] = lambda v=v: to_uint8(sclera_texture(v, sclera_size[0], sclera_size[1], seed))
    jobs["sclera_bump"] = lambda: sclera_bump_maps(geo.outer_thetas(p, res), geo.limbus_theta(p),
                                                   lambda th: geo.outer_radial(th, p), sclera_size, seed)
    # Each image has its own seeded generator, so running them on threads (numpy and
    # scipy.ndimage release the GIL on large arrays) changes nothing but the wall time.
    with ThreadPoolExecutor(max_workers=min(len(jobs), os.cpu_count() or 1)) as pool:
        futures = {name: pool.submit(job) for name, job in jobs.items()}
        out = {name: fut.result() for name, fut in futures.items()}
    hgt, nrm = out.pop("sclera_bump")
    out["sclera_bump.png"] = np.round(hgt * 65535).astype(np.uint16)
    out["sclera_normal.png"] = to_uint8(nrm)
    return out


def solid_noise(points, seed: int = 0, feature_mm: float = 1.2, extent_mm: float = 16.0,
                voxels: int = 48) -> np.ndarray:
    """Smoothed solid (3-D) noise at ``points`` (n, 3) mm: zero mean, unit std, cubic interpolation.

    A Gaussian-filtered random volume over [-extent, extent]^3 (sigma = ``feature_mm``).
    """
    from scipy.ndimage import gaussian_filter, map_coordinates

    rng = np.random.default_rng([int(seed), 202])
    vol = gaussian_filter(rng.standard_normal((voxels,) * 3), feature_mm / (2 * extent_mm / voxels),
                          mode="wrap")
    vol = (vol - vol.mean()) / (vol.std() + 1e-12)
    P = np.asarray(points, float)
    coords = ((P + extent_mm) / (2 * extent_mm) * voxels - 0.5).T
    return map_coordinates(vol, coords, order=3, mode="grid-wrap")


def sclera_bump_maps(outer_ring_thetas, limbus_theta: float, radial, size=(1024, 512), seed: int = 0,
                     amplitude_mm: float = 0.02):
    """Sclera bumps on the outer mesh UVs: height map and tangent-space normal map.

    The outer mesh's UVs are u = azimuth / 2pi and v = 1 - row / (rows - 1),
    row 0 = corneal apex, rows 1.. = rings at ``outer_ring_thetas``, last row
    = back pole. Each texel is mapped back to its surface point, where the
    solid noise is sampled; the bumps fade to 0 over the cornea (within 4 deg
    of the limbus) so the cornea stays smooth.

    Parameters
    ----------
    outer_ring_thetas : (k,) polar angles of the outer rings (geometry.outer_thetas)
    limbus_theta : float (rad)
    radial : callable theta -> radius (geometry.outer_radial with params bound)
    size : (width, height)
    amplitude_mm : height of one standard deviation of the noise

    Returns
    -------
    height : (h, w) float32 in [0, 1] (0.5 = no displacement; value = 0.5 + h_mm / (8 amplitude))
    normal : (h, w, 3) float32 in [0, 1], tangent space (+X = +u, +Y = +v, +Z = outward), encoded n/2 + 0.5
    """
    w, h = size
    th_rows = np.concatenate([[0.0], np.asarray(outer_ring_thetas, float), [np.pi]])
    rows = len(th_rows)
    u = (np.arange(w) + 0.5) / w
    v = 1 - (np.arange(h) + 0.5) / h                         # image row 0 = top = v 1
    U, Vv = np.meshgrid(u, v)
    th = np.interp((1 - Vv) * (rows - 1), np.arange(rows), th_rows)
    phi = 2 * np.pi * U
    R = radial(th)
    P = np.stack([R * np.sin(th) * np.cos(phi), R * np.sin(th) * np.sin(phi), R * np.cos(th)], -1)
    mask = np.clip((th - (limbus_theta + np.radians(1))) / np.radians(4), 0, 1)
    mask = mask * mask * (3 - 2 * mask)
    hmm = amplitude_mm * solid_noise(P.reshape(-1, 3), seed).reshape(h, w) * mask
    # physical derivatives: d/du (columns, wrap) and d/dv (rows, v decreases down the image)
    dPu = (np.roll(P, -1, 1) - np.roll(P, 1, 1))
    dhu = (np.roll(hmm, -1, 1) - np.roll(hmm, 1, 1))
    dPv = np.zeros_like(P)
    dhv = np.zeros_like(hmm)
    dPv[1:-1] = P[:-2] - P[2:]                                # toward +v
    dhv[1:-1] = hmm[:-2] - hmm[2:]
    lu = np.maximum(np.linalg.norm(dPu, axis=-1), 1e-9)
    lv = np.maximum(np.linalg.norm(dPv, axis=-1), 1e-9)
    n = np.stack([-dhu / lu, -dhv / lv, np.ones_like(hmm)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    height = np.clip(0.5 + hmm / (8 * amplitude_mm), 0, 1)
    return height.astype(np.float32), (n * 0.5 + 0.5).astype(np.float32)
