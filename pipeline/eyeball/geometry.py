"""The parametric eyeball (SynthesEyes paper, section 3.1), in millimetres.

The eye looks down +Z with its centre at the origin; +Y is up. Both parts are
surfaces of revolution about the Z axis, tessellated as rings of ``n_around``
vertices (vertex ``j`` of a ring at azimuth ``phi_j = 2*pi*j/n_around``,
measured from +X toward +Y, i.e. counter-clockwise seen from the front).

Outer part (``outer``): the eyeball sphere ``r1`` (12 mm) joined with the
corneal sphere ``r2`` (8 mm) whose centre sits on +Z at ``apex - r2`` (apex
13.5 mm from the centre by default). The radial distance along polar angle
``theta`` is a C2 smooth maximum (cubic, blend width ``seam_blend_mm``) of the
two spheres' radial functions, so the seam has no crease: the largest dihedral
angle in the seam band is at most the largest dihedral of the tessellation
elsewhere (see :func:`pipeline.eyeball.checks.seam_dihedral_report`).

Inner part (``inner``): a sphere of radius ``r1 - gap`` (``gap`` = 0.5 mm,
the thickness of the cornea/sclera shell) cut by the plane ``z = z_iris`` where
its cross-section has the iris radius; the planar front holds the iris
(annulus) and the pupil (disc). Every inner vertex lies at least ``gap`` inside
the outer surface.

Blend shapes (UsdSkel layout, inner mesh only): ``pupil_dilate`` (pupil radius
to ``pupil_dilated_mm``), ``pupil_constrict`` (to ``pupil_constricted_mm``),
``iris_large`` / ``iris_small`` (iris radius x (1 +- ``iris_scale_delta``)).
Weight rule (:func:`clamp_weights`): finite weights are clamped to [0, 1];
NaN/inf and unknown shape names are refused with ``ValueError``.

Placed in a scan (:func:`placed_params`): the sclera sphere takes the eye's radius (the paper's
12 mm by default; a population size or the scan's sphere when asked), everything else (cornea,
apex protrusion, iris, pupil) keeps its size in mm; the eye is never scaled.

Landmarks: 8 iris-boundary and 8 pupil-boundary vertices of the inner mesh at
azimuths ``45 deg * k`` (k = 0..7), starting at +X and running counter-clockwise
seen from the front (+X -> +Y -> -X -> -Y). With the eye facing the camera,
landmark 0 is at image right and landmark 2 at the top.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from pipeline.settings import SettingError, Settings, setting

SHAPE_NAMES = ("pupil_dilate", "pupil_constrict", "iris_large", "iris_small")
N_LANDMARKS = 8
LANDMARK_START_DEG = 0.0          # +X
LANDMARK_DIRECTION = "counter-clockwise seen from the front (+X toward +Y)"
WEIGHT_RULE = ("finite weights are clamped to [0, 1]; NaN/inf or unknown shape names raise "
               "ValueError (pipeline.eyeball.geometry.clamp_weights)")


@dataclass(frozen=True)
class EyeballParams(Settings):
    """Anatomical settings of the eyeball (mm): ``eyeball.geometry`` in params.yaml."""

    r1: float = setting(12.0, gt=0)                   # eyeball sphere
    r2: float = setting(8.0, gt=0)                    # corneal sphere
    apex: float = setting(13.5, gt=0)                 # corneal apex distance from the eyeball centre
    seam_blend_mm: float = setting(1.0, ge=0)         # width of the smooth maximum at the seam
    gap: float = setting(0.5, gt=0)                   # cornea thickness: inner part lies this far inside
    iris_radius: float = setting(5.85, gt=0)          # visible iris diameter 11.7 mm (see below)
    # pupil radii >= 0.01 mm (human: 0.5-4.5 mm; an eye scaled down tenfold still fits): near
    # 1e-6 mm the constricted pupil's rings fold over each other and the asset fails validation
    pupil_radius: float = setting(2.0, ge=0.01)       # rest pupil
    pupil_dilated_mm: float = setting(4.0, ge=0.01)
    pupil_constricted_mm: float = setting(1.0, ge=0.01)
    # >= 1 %: a smaller scale leaves offsets that round to nothing (an empty blend shape)
    iris_scale_delta: float = setting(0.10, ge=0.01, lt=0.5)  # iris_large / iris_small = x(1 +- delta)

    def validate(self) -> None:
        if not self.r1 < self.apex < self.r1 + self.r2:
            raise SettingError("apex", f"{self.apex:g} must lie between r1={self.r1:g} and r1+r2")
        if self.apex - self.r2 <= 0:
            raise SettingError("r2", "corneal sphere centre must lie in front of the eyeball centre")
        if not self.seam_blend_mm < self.apex - self.r1:
            raise SettingError("seam_blend_mm", "must be smaller than apex - r1")
        r_in = self.r1 - self.gap
        big = self.iris_radius * (1 + self.iris_scale_delta)
        small = self.iris_radius * (1 - self.iris_scale_delta)
        if big >= r_in * 0.95:
            raise SettingError("iris_radius", "too large for the inner sphere")
        if max(self.pupil_radius, self.pupil_dilated_mm) >= small:
            raise SettingError("pupil_dilated_mm", "pupil (rest/dilated) must stay smaller than the small iris")
        if self.pupil_dilated_mm <= self.pupil_radius:      # else the shape turns the pupil inside out
            raise SettingError("pupil_dilated_mm", "must be larger than pupil_radius")
        if self.pupil_constricted_mm >= self.pupil_radius:
            raise SettingError("pupil_constricted_mm", "must be smaller than pupil_radius")

    @property
    def cornea_center_z(self) -> float:
        return self.apex - self.r2

    @property
    def protrusion(self) -> float:
        """How far the corneal apex stands out of the eyeball sphere, mm (``apex - r1``)."""
        return self.apex - self.r1

    @property
    def inner_radius(self) -> float:
        return self.r1 - self.gap

    @classmethod
    def from_dict(cls, d: dict | None) -> "EyeballParams":
        d = dict(d or {})
        unknown = set(d) - set(cls.keys())
        if unknown:
            raise ValueError(f"unknown eyeball geometry setting(s) {sorted(unknown)}")
        return cls(**d)


@dataclass(frozen=True)
class Resolution(Settings):
    """Tessellation: vertices around the limbus and ring counts per zone.

    ``n_around`` must be a multiple of 8 (landmarks sit on ring vertices).
    """

    n_around: int = setting(64, ge=8, le=1024)
    cornea_rings: int = setting(16, ge=1, le=512)     # outer: apex .. limbus
    sclera_rings: int = setting(32, ge=2, le=512)     # outer and inner: limbus .. back pole
    iris_rings: int = setting(8, ge=1, le=512)        # inner: pupil boundary .. iris boundary
    pupil_rings: int = setting(3, ge=1, le=512)       # inner: centre .. pupil boundary

    def validate(self) -> None:
        if self.n_around % 8:
            raise SettingError("n_around", f"must be a multiple of 8 and >= 8, got {self.n_around}")

    @classmethod
    def preset(cls, name: str) -> "Resolution":
        try:
            return cls(**RESOLUTION_PRESETS[name])
        except KeyError:
            raise ValueError(f"unknown resolution {name!r}; choose one of "
                             f"{sorted(RESOLUTION_PRESETS)}") from None

    @classmethod
    def from_value(cls, value) -> "Resolution":
        if isinstance(value, Resolution):
            return value
        if isinstance(value, str):
            return cls.preset(value)
        return cls(**dict(value))


@dataclass(frozen=True)
class EyeballSettings(Settings):
    """The ``eyeball:`` block of params.yaml (the shared parametric eyeball asset)."""

    block: ClassVar[str] = "eyeball"

    resolution: Literal["low", "medium", "high", "full"] | Resolution = "high"
    geometry: EyeballParams = setting(default_factory=EyeballParams)
    texture_seed: int = setting(0, ge=0, le=2**32 - 1)
    iris_texture_px: int = setting(512, ge=16, le=4096)
    sclera_texture_px: tuple[int, int] = setting((1024, 512), ge=16, le=8192)
    # the eyeball_preview stage's (rigged_assets/eyeball.preview.png), not the asset's
    preview_px: int = setting(160, ge=16, le=2048)         # tile size
    preview_samples: int = setting(16, ge=1, le=4096)      # + OpenImageDenoise


RESOLUTION_PRESETS = {
    "low": dict(n_around=24, cornea_rings=5, sclera_rings=10, iris_rings=3, pupil_rings=1),
    "medium": dict(n_around=48, cornea_rings=10, sclera_rings=20, iris_rings=5, pupil_rings=2),
    "high": dict(n_around=64, cornea_rings=16, sclera_rings=32, iris_rings=8, pupil_rings=3),
    "full": dict(n_around=128, cornea_rings=28, sclera_rings=56, iris_rings=14, pupil_rings=5),
}


@dataclass
class RingMesh:
    """A closed ring-tessellated mesh.

    Attributes
    ----------
    V : (n, 3) float64
    F : (m, 3) int64, CCW seen from outside (triangulation of the polygons)
    poly_counts : (p,) int64 ; poly_indices : (sum(poly_counts),) int64  (USD layout)
    UV : (k, 2) float64 ; FUV : (m, 3) int64  per-triangle-corner UVs
    poly_uv_indices : (sum(poly_counts),) int64  per-polygon-corner UV indices
    subsets : dict name -> (q,) int64 polygon indices (material zones)
    rings : list of (n_around,) int64 vertex indices of each ring, front to back
    """

    V: np.ndarray
    F: np.ndarray
    poly_counts: np.ndarray
    poly_indices: np.ndarray
    UV: np.ndarray
    FUV: np.ndarray
    poly_uv_indices: np.ndarray
    subsets: dict = field(default_factory=dict)
    rings: list = field(default_factory=list)


def placed_params(params: EyeballParams, radius: float) -> EyeballParams:
    """The eyeball as placed in a scan whose eyeball sphere was fitted with ``radius`` (mm).

    THE placement rule, used wherever a placed eye is built or evaluated (snap's margin surface,
    the rig's eye frames, the usd stage's per-eye geometry, render): the sclera sphere follows
    the fit (``r1 = radius``); the cornea (``r2``), the corneal apex's protrusion out of the
    sphere (``apex - r1``), the iris and pupil radii, the cornea thickness (``gap``) and the seam
    blend keep their absolute values in mm, so the visible eye keeps human proportions whatever
    radius the scan's sclera gave (an eye scaled uniformly to ICT-FaceKit's 15.4 mm sphere had a
    15.1 mm iris). The defaults are human: iris 11.7 mm across (horizontal visible iris diameter
    11.71 +- 0.42 mm, Ruefer et al. 2005, "White-to-white corneal diameter: normal values in
    healthy humans"), cornea 8 mm (paper 3.1 after Ruhland et al. 2014; Gullstrand's schematic eye
    7.7 mm), apex 1.5 mm out of the 12 mm sphere (paper 3.1: 13.5 mm from the centre, the centre
    of rotation 13.5 mm behind the apex of Fry & Hill 1962). ``radius == params.r1`` gives
    ``params`` back.
    """
    r = float(radius)
    if not (math.isfinite(r) and r > 0):
        raise ValueError(f"eyeball radius must be a positive number, got {radius!r}")
    if r == params.r1:
        return params
    return _placed(params, r)


@functools.lru_cache(maxsize=64)
def _placed(params: EyeballParams, r: float) -> EyeballParams:
    return dataclasses.replace(params, r1=r, apex=r + params.protrusion)


# --------------------------------------------------------------------------- profile

def _smax(a, b, k):
    """C2 cubic smooth maximum of ``a`` and ``b`` with blend width ``k``."""
    if k <= 0:
        return np.maximum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + h ** 3 * k / 6.0


def cornea_radial(theta, p: EyeballParams):
    """Distance from the eye centre to the corneal sphere along polar angle ``theta``."""
    c = p.cornea_center_z
    s = np.sin(theta)
    disc = np.maximum(p.r2 ** 2 - (c * s) ** 2, 0.0)
    return c * np.cos(theta) + np.sqrt(disc)


def outer_radial(theta, p: EyeballParams, smooth: bool = True):
    """Radial distance of the outer surface along polar angle ``theta`` (rad from +Z)."""
    theta = np.asarray(theta, float)
    rc = cornea_radial(theta, p)
    return _smax(np.full_like(theta, p.r1), rc, p.seam_blend_mm if smooth else 0.0)


def limbus_theta(p: EyeballParams) -> float:
    """Polar angle where the two spheres intersect (the unsmoothed seam)."""
    c = p.cornea_center_z
    z = (p.r1 ** 2 + c ** 2 - p.r2 ** 2) / (2 * c)
    return float(math.acos(np.clip(z / p.r1, -1, 1)))


# --------------------------------------------------------------------------- tessellation

def _ring_strip_mesh(ring_pts, front_pole, back_pole, n):
    """Polygons of rings (each (n,3)) between an optional front and back pole vertex.

    Returns V, polygon list (counts, indices), ring index arrays.
    """
    V = []
    rings = []
    idx = 0
    if front_pole is not None:
        V.append(np.asarray(front_pole, float)[None])
        front = 0
        idx = 1
    for r in ring_pts:
        V.append(r)
        rings.append(np.arange(idx, idx + n))
        idx += n
    back = idx
    V.append(np.asarray(back_pole, float)[None])
    V = np.concatenate(V)
    counts, indices = [], []
    j = np.arange(n)
    jn = (j + 1) % n
    if front_pole is not None:
        r0 = rings[0]
        tri = np.stack([np.full(n, front), r0[j], r0[jn]], 1)
        counts.append(np.full(n, 3))
        indices.append(tri)
    for a, b in zip(rings[:-1], rings[1:]):
        quad = np.stack([a[j], b[j], b[jn], a[jn]], 1)
        counts.append(np.full(n, 4))
        indices.append(quad)
    rl = rings[-1]
    tri = np.stack([rl[j], np.full(n, back), rl[jn]], 1)
    counts.append(np.full(n, 3))
    indices.append(tri)
    return V, counts, indices, rings, back


def _flatten_polys(counts, indices):
    pc = np.concatenate(counts).astype(np.int64)
    pi = np.concatenate([np.asarray(i).reshape(-1) for i in indices]).astype(np.int64)
    return pc, pi


def triangulate(poly_counts, poly_indices) -> np.ndarray:
    """Fan-triangulate polygons (USD layout) -> (m, 3) int64."""
    poly_counts = np.asarray(poly_counts, np.int64)
    poly_indices = np.asarray(poly_indices, np.int64)
    starts = np.concatenate([[0], np.cumsum(poly_counts)[:-1]]).astype(np.int64)
    keys, tris = [], []
    for c in np.unique(poly_counts):
        s = starts[poly_counts == c]
        for k in range(1, int(c) - 1):
            keys.append(s * 64 + k)
            tris.append(np.stack([poly_indices[s], poly_indices[s + k], poly_indices[s + k + 1]], 1))
    if not tris:
        return np.zeros((0, 3), np.int64)
    allt = np.concatenate(tris)
    return allt[np.argsort(np.concatenate(keys), kind="stable")]


def _ring(rho, z, n):
    phi = 2 * np.pi * np.arange(n) / n
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), np.full(n, z)], 1)


def outer_thetas(p: EyeballParams, res: Resolution) -> np.ndarray:
    """Polar angles of the outer rings (without the apex at 0 and pole at pi)."""
    tl = limbus_theta(p)
    front = np.linspace(0, tl, res.cornea_rings + 1)[1:]
    back = np.linspace(tl, np.pi, res.sclera_rings + 1)[1:-1]
    return np.concatenate([front, back])


def _spherical_uv_polys(n, nrings, has_front, poly_counts_list):
    """Face-varying spherical UVs for a ring-strip mesh: u = phi / 2pi, v = 1 - t (t: ring/front..back)."""
    # UV grid: rows = [front pole] + rings + [back pole], cols 0..n (n duplicates 0 at u = 1)
    rows = nrings + 2
    us = np.arange(n + 1) / n
    vs = 1.0 - np.arange(rows) / (rows - 1)
    UV = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2)
    uvi = lambda r, c: r * (n + 1) + c  # noqa: E731
    j = np.arange(n)
    parts = []
    r0 = 1
    if has_front:
        parts.append(np.stack([uvi(0, j), uvi(1, j), uvi(1, j + 1)], 1))
    else:
        r0 = 0
    first_ring_row = 1 if has_front else 0
    for k in range(nrings - 1):
        r = first_ring_row + k
        parts.append(np.stack([uvi(r, j), uvi(r + 1, j), uvi(r + 1, j + 1), uvi(r, j + 1)], 1))
    rl = first_ring_row + nrings - 1
    parts.append(np.stack([uvi(rl, j), uvi(rl + 1, j), uvi(rl, j + 1)], 1))
    del r0
    return UV, parts


def _finish(V, counts, indices, uv, uv_parts, subsets, rings) -> RingMesh:
    pc, pi = _flatten_polys(counts, indices)
    puv = np.concatenate([np.asarray(i).reshape(-1) for i in uv_parts]).astype(np.int64)
    F = triangulate(pc, pi)
    FUV = triangulate(pc, puv)
    return RingMesh(V=V, F=F, poly_counts=pc, poly_indices=pi, UV=uv, FUV=FUV,
                    poly_uv_indices=puv, subsets=subsets, rings=rings)


def outer_mesh(params: EyeballParams | None = None, resolution=None, smooth: bool = True) -> RingMesh:
    """The outer part (cornea + sclera shell): one closed manifold mesh.

    Parameters
    ----------
    params : EyeballParams
    resolution : Resolution | str | dict
    smooth : bool
        False gives the raw union of the two spheres (crease at the seam); for tests.

    Returns
    -------
    RingMesh with subsets ``cornea`` (polygons in front of the seam) and ``sclera``.
    """
    p = params or EyeballParams()
    res = Resolution.from_value(resolution or "high")
    n = res.n_around
    th = outer_thetas(p, res)
    R = outer_radial(th, p, smooth)
    ring_pts = [_ring(r * math.sin(t), r * math.cos(t), n) for r, t in zip(R, th)]
    apex = [0.0, 0.0, float(outer_radial(np.array([0.0]), p, smooth)[0])]
    back = [0.0, 0.0, -float(outer_radial(np.array([np.pi]), p, smooth)[0])]
    V, counts, indices, rings, _ = _ring_strip_mesh(ring_pts, apex, back, n)
    UV, uv_parts = _spherical_uv_polys(n, len(rings), True, counts)
    npoly = sum(len(c) for c in counts)
    n_cornea = n * res.cornea_rings  # fan + (cornea_rings - 1) strips
    subsets = {"cornea": np.arange(n_cornea), "sclera": np.arange(n_cornea, npoly)}
    return _finish(V, counts, indices, UV, uv_parts, subsets, rings)


def _inner_rings(p: EyeballParams, res: Resolution, pupil_r: float, iris_r: float):
    """(rho, z) of every inner ring (front to back) plus the front/back pole z."""
    r_in = p.inner_radius
    z_iris = math.sqrt(r_in ** 2 - iris_r ** 2)
    th_i = math.asin(iris_r / r_in)
    rho = list(pupil_r * np.arange(1, res.pupil_rings + 1) / res.pupil_rings)
    rho += list(pupil_r + (iris_r - pupil_r) * np.arange(1, res.iris_rings + 1) / res.iris_rings)
    z = [z_iris] * len(rho)
    ths = th_i + (np.pi - th_i) * np.arange(1, res.sclera_rings) / res.sclera_rings
    rho += list(r_in * np.sin(ths))
    z += list(r_in * np.cos(ths))
    return np.array(rho), np.array(z), z_iris, -r_in


def _inner_vertices(p, res, pupil_r, iris_r):
    rho, z, zf, zb = _inner_rings(p, res, pupil_r, iris_r)
    n = res.n_around
    ring_pts = [_ring(r, zz, n) for r, zz in zip(rho, z)]
    V, counts, indices, rings, _ = _ring_strip_mesh(ring_pts, [0, 0, zf], [0, 0, zb], n)
    return V, counts, indices, rings


#: Texture radius (fraction of the iris image half-width) of the pupil boundary in iris textures.
IRIS_TEXTURE_PUPIL_FRACTION = 0.33
#: The iris texture's iris boundary sits at this fraction of the half-width (margin for filtering).
IRIS_TEXTURE_IRIS_FRACTION = 0.96


def inner_mesh(params: EyeballParams | None = None, resolution=None) -> RingMesh:
    """The inner part at rest: flattened sphere with planar iris + pupil front.

    UVs (face-varying, one ``st`` set): iris and pupil polygons map to the
    iris texture with a polar layout (centre (0.5, 0.5), pupil boundary at
    radius ``0.5 * IRIS_TEXTURE_PUPIL_FRACTION``, iris boundary at
    ``0.5 * IRIS_TEXTURE_IRIS_FRACTION``), so the texture follows pupil
    dilation; sclera polygons map to the sclera texture with u = azimuth / 2pi,
    v = 1 at the limbus to 0 at the back pole.

    Returns
    -------
    RingMesh with subsets ``pupil``, ``iris``, ``sclera`` and ``rings``
    (``rings[pupil_rings - 1]`` = pupil boundary, ``rings[pupil_rings +
    iris_rings - 1]`` = iris boundary).
    """
    p = params or EyeballParams()
    res = Resolution.from_value(resolution or "high")
    n = res.n_around
    V, counts, indices, rings = _inner_vertices(p, res, p.pupil_radius, p.iris_radius)
    # polygon zones: fan (pupil), pupil strips, iris strips, sclera strips, back fan
    n_pupil = n * res.pupil_rings
    n_iris = n * res.iris_rings
    npoly = sum(len(c) for c in counts)
    subsets = {"pupil": np.arange(n_pupil), "iris": np.arange(n_pupil, n_pupil + n_iris),
               "sclera": np.arange(n_pupil + n_iris, npoly)}
    # UVs: polar block for the front rings (centre + pupil + iris rings), spherical for the sclera
    j = np.arange(n + 1)
    phi = 2 * np.pi * j / n
    fp, fi = IRIS_TEXTURE_PUPIL_FRACTION, IRIS_TEXTURE_IRIS_FRACTION
    trad = list(fp * np.arange(1, res.pupil_rings + 1) / res.pupil_rings)
    trad += list(fp + (fi - fp) * np.arange(1, res.iris_rings + 1) / res.iris_rings)
    front_rows = [np.full((n + 1, 2), 0.5)]
    for t in trad:
        front_rows.append(np.stack([0.5 + 0.5 * t * np.cos(phi), 0.5 + 0.5 * t * np.sin(phi)], 1))
    UVf = np.concatenate(front_rows)
    nf = len(trad)
    uvf = lambda r, c: r * (n + 1) + c  # noqa: E731
    jj = np.arange(n)
    parts = [np.stack([uvf(0, jj), uvf(1, jj), uvf(1, jj + 1)], 1)]
    for k in range(1, nf):
        parts.append(np.stack([uvf(k, jj), uvf(k + 1, jj), uvf(k + 1, jj + 1), uvf(k, jj + 1)], 1))
    # sclera: rows = iris boundary ring (v=1) .. sclera rings .. back pole (v=0)
    ns_rows = res.sclera_rings + 1
    us = np.arange(n + 1) / n
    vs = 1.0 - np.arange(ns_rows) / (ns_rows - 1)
    UVs = np.stack(np.meshgrid(us, vs), -1).reshape(-1, 2)
    off = len(UVf)
    uvs = lambda r, c: off + r * (n + 1) + c  # noqa: E731
    for k in range(res.sclera_rings - 1):
        parts.append(np.stack([uvs(k, jj), uvs(k + 1, jj), uvs(k + 1, jj + 1), uvs(k, jj + 1)], 1))
    kl = res.sclera_rings - 1
    parts.append(np.stack([uvs(kl, jj), uvs(kl + 1, jj), uvs(kl, jj + 1)], 1))
    UV = np.concatenate([UVf, UVs])
    return _finish(V, counts, indices, UV, parts, subsets, rings)


# --------------------------------------------------------------------------- blend shapes

@dataclass
class EyeBlendShape:
    """One blend shape of the inner mesh (UsdSkel layout: sparse indices + offsets, mm)."""

    name: str
    point_indices: np.ndarray   # (k,) int64
    offsets: np.ndarray         # (k, 3) float64


def shape_targets(p: EyeballParams) -> dict[str, tuple[float, float]]:
    """(pupil radius, iris radius) of every blend-shape target at weight 1."""
    return {
        "pupil_dilate": (p.pupil_dilated_mm, p.iris_radius),
        "pupil_constrict": (p.pupil_constricted_mm, p.iris_radius),
        "iris_large": (p.pupil_radius, p.iris_radius * (1 + p.iris_scale_delta)),
        "iris_small": (p.pupil_radius, p.iris_radius * (1 - p.iris_scale_delta)),
    }


def inner_blend_shapes(params: EyeballParams | None = None, resolution=None,
                       tol: float = 1e-9) -> list[EyeBlendShape]:
    """The four inner-mesh blend shapes, sparse (only vertices that move)."""
    p = params or EyeballParams()
    res = Resolution.from_value(resolution or "high")
    V0, *_ = _inner_vertices(p, res, p.pupil_radius, p.iris_radius)
    out = []
    for name in SHAPE_NAMES:
        pr, ir = shape_targets(p)[name]
        V1, *_ = _inner_vertices(p, res, pr, ir)
        d = V1 - V0
        idx = np.flatnonzero(np.linalg.norm(d, axis=1) > tol)
        out.append(EyeBlendShape(name, idx.astype(np.int64), d[idx]))
    return out


def clamp_weights(weights: dict | None) -> dict[str, float]:
    """Apply the weight rule: every shape name gets a weight in [0, 1].

    Missing names are 0; finite values are clamped to [0, 1]; NaN/inf or an
    unknown name raises ``ValueError``.
    """
    weights = dict(weights or {})
    unknown = set(weights) - set(SHAPE_NAMES)
    if unknown:
        raise ValueError(f"unknown eyeball blend shape(s) {sorted(unknown)}; known: {list(SHAPE_NAMES)}")
    out = {}
    for name in SHAPE_NAMES:
        w = float(weights.get(name, 0.0))
        if not math.isfinite(w):
            raise ValueError(f"weight of {name} must be finite, got {w}")
        out[name] = min(max(w, 0.0), 1.0)
    return out


def apply_blend_shapes(V, shapes, weights: dict | None) -> np.ndarray:
    """Rest points plus weighted offsets (weights through :func:`clamp_weights`)."""
    w = clamp_weights(weights)
    P = np.array(V, float, copy=True)
    for s in shapes:
        if w[s.name]:
            P[s.point_indices] += w[s.name] * s.offsets
    return P


# --------------------------------------------------------------------------- landmarks

def landmark_indices(resolution=None, params: EyeballParams | None = None) -> dict[str, np.ndarray]:
    """Inner-mesh vertex indices of the 8 iris- and 8 pupil-boundary landmarks.

    Landmark k sits at azimuth 45 deg * k from +X, counter-clockwise seen from
    the front (see module docstring).
    """
    res = Resolution.from_value(resolution or "high")
    step = res.n_around // N_LANDMARKS
    # vertex 0 is the front centre; ring i (0-based) starts at 1 + i * n_around
    pupil_ring = res.pupil_rings - 1
    iris_ring = res.pupil_rings + res.iris_rings - 1
    k = np.arange(N_LANDMARKS) * step
    return {"iris": (1 + iris_ring * res.n_around + k).astype(np.int64),
            "pupil": (1 + pupil_ring * res.n_around + k).astype(np.int64)}


# --------------------------------------------------------------------------- the model

@dataclass
class Eyeball:
    """Everything the eyeball asset holds."""

    params: EyeballParams
    resolution: Resolution
    outer: RingMesh
    inner: RingMesh
    shapes: list
    landmarks: dict

    def stats(self) -> dict:
        return {"outer_vertices": len(self.outer.V), "outer_polygons": len(self.outer.poly_counts),
                "inner_vertices": len(self.inner.V), "inner_polygons": len(self.inner.poly_counts),
                "blend_shape_points": {s.name: len(s.point_indices) for s in self.shapes}}


def build_eyeball(params: EyeballParams | None = None, resolution="high") -> Eyeball:
    """Build the parametric eyeball: outer and inner meshes, blend shapes, landmarks.

    Parameters
    ----------
    params : EyeballParams, optional
    resolution : Resolution | str | dict
        A preset name (``low``, ``medium``, ``high``, ``full``) or explicit counts.
    """
    p = params or EyeballParams()
    res = Resolution.from_value(resolution)
    return Eyeball(params=p, resolution=res, outer=outer_mesh(p, res), inner=inner_mesh(p, res),
                   shapes=inner_blend_shapes(p, res), landmarks=landmark_indices(res, p))

