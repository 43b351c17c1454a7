"""Sample specs: image ``i`` of a render is a pure function of ``(seed, i)``.

Posing (SynthesEyes section 4.1), for one sample drawn with
``numpy.random.default_rng([seed, i, attempt])``:

1. **Eye** of the close-up: uniform over ``eyes`` (params).
2. **Camera** on spherical coordinates around that eyeball's centre ``c``; the polar axis is
   the eye's rest forward ``f``, so polar angle 0 (the pole) is the frontal view. The polar
   angle is drawn uniformly over the spherical cap (``cos`` uniform) up to
   ``camera_polar_max_deg``, the azimuth uniformly in [0, 360). The orthographic camera
   looks at ``c`` (plus a small random in-plane shift ``center_jitter_mm``) from
   ``c + camera_distance_mm * d``; image up = the eye's up ``e_y`` projected off ``d`` (no
   roll), image right = up x d. Orthographic scale (the image width, mm) uniform in
   ``ortho_scale_mm``, or, with ``iris_distance_px`` (the ``unityeyes`` preset), the scale that
   puts the iris centre that many pixels from the eyeball centre (:func:`iris_framed_scale`).
3. **Gaze**: eye contact (``d``, towards the orthographic camera) expressed as pitch/yaw in
   the eye's rest frame (``e_x`` = towards head +X = subject's left, ``e_y`` up, ``f``), plus
   offsets drawn from the grid ``k * gaze_step_deg``, ``|k * step| <= gaze_offset_max_deg``
   for pitch and yaw independently, then clipped to ``|pitch| <= max_pitch_deg`` and
   ``|yaw| <= max_yaw_deg`` (anatomical limits relative to the head).
   The other eye looks the same way (target at infinity: parallel gaze), clipped to its own
   limits.
4. **Eye rotation**: Listing's law with the rest forward as primary position: the rotation
   axis lies in Listing's plane (perpendicular to ``f``), i.e. the minimal rotation taking
   ``f`` to the gaze ``g`` (axis ``f x g``, angle ``acos(f . g)``), applied about the eyeball
   centre; no torsion. For a pure pitch this is the rotation about ``-e_x`` the lid rig assumes.
5. **Eyelids**: channel weights from :func:`pipeline.rig.lids.lid_weights` of the mean lid
   pitch of both eyes (:func:`pipeline.rig.lids.pitch_from_gaze`), the asset's rule.
6. **Eyeball**: iris colour, sclera tint and veins uniform over the asset's variants; one
   pupil value ``s`` uniform in [-1, 1] (``s > 0``: ``pupil_dilate = s``, else
   ``pupil_constrict = -s``) and one iris-size value likewise (``iris_large`` / ``iris_small``).
7. **Lighting**: one of the bundled HDRIs, rotation uniform in [0, 360) deg about head +Y,
   strength uniform in ``strength``.
8. **Rejection**: if the projected pupil centre is outside the projected eyelid polygon (the
   posed lid loop of the imaged eye) or outside the polygon of the label's 12 eyelid
   landmarks (:func:`pupil_in_lids`), the sample is redrawn with ``attempt + 1``; the number
   of attempts is stored.

**Skin detail** (:func:`choose_skin_detail`): with ``p = ortho_scale_mm / width`` (mm per
pixel), ``a`` = the 99th percentile of the baked |displacement| and ``e`` = the median edge
length of the low-poly skin: ``displacement`` when ``a >= p / 2`` (the relief moves
silhouettes and occlusions by half a pixel or more: real geometry needed); else ``bump`` when
``e > p`` (polygons span more than a pixel, so the map's shading detail is resolved); else
``none`` (relief and polygons are both below a pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Literal
from pathlib import Path

import numpy as np

from pipeline.eyeball.textures import IRIS_COLORS
from pipeline.render import asset as ra
from pipeline.rig import landmarks as lmk
from pipeline.rig import lids
from pipeline.settings import SettingError, Settings, setting

HDRIS = ("city.exr", "courtyard.exr", "forest.exr", "interior.exr", "night.exr", "studio.exr",
         "sunrise.exr", "sunset.exr")
SCLERA_TINTS = ("pink", "white", "yellow")
VEINS = ("bloodshot", "clear")

PRESETS = {
    # paper: ~40 deg of head-pose (viewpoint) variation, gaze up to 45 deg from eye contact in
    # 10 deg steps
    "generic": {"camera_polar_max_deg": 20.0, "gaze_offset_max_deg": 45.0, "gaze_step_deg": 10.0},
    # paper's laptop setting: 10 deg pose, 20 deg gaze variation
    "targeted": {"camera_polar_max_deg": 5.0, "gaze_offset_max_deg": 10.0, "gaze_step_deg": 5.0},
    # framed as UnityEyes frames its images, so that GazeML's UnityEyes loader (eyeball centre at the
    # image centre, iris centre 71.7593 px from it along the gaze) holds; see
    # pipeline/render/label_formats.py. UnityEyes' recommended 512 x 384, its left eye, its camera
    # 10 units (cm) from the eyeball centre looking at it (no shift), GazeML's |head pitch|, |yaw| <= 20
    "unityeyes": {"camera_polar_max_deg": 20.0, "gaze_offset_max_deg": 30.0, "gaze_step_deg": 1.0,
                  "width": 512, "height": 384, "eyes": ("left",), "center_jitter_mm": 0.0,
                  "camera_distance_mm": 100.0, "iris_distance_px": 71.7593},
}


_GENERIC = PRESETS["generic"]


@dataclass(frozen=True)
class RenderPreset(Settings):
    """One entry of ``render.presets``: pose and gaze ranges (and, for a preset that names them,
    image size, eyes and framing) filled in by ``render.preset``; only the keys the entry names."""

    camera_polar_max_deg: float = setting(_GENERIC["camera_polar_max_deg"], ge=0, lt=80)
    gaze_offset_max_deg: float = setting(_GENERIC["gaze_offset_max_deg"], ge=0, le=90)
    gaze_step_deg: float = setting(_GENERIC["gaze_step_deg"], gt=0, le=90)
    width: int = setting(120, ge=8, le=8192)
    height: int = setting(80, ge=8, le=8192)
    eyes: tuple[Literal["left", "right"], ...] = setting(("left", "right"), min_len=1, max_len=2)
    center_jitter_mm: float = setting(1.0, ge=0, le=100)
    camera_distance_mm: float = setting(200.0, gt=0, le=100_000)
    iris_distance_px: float | None = setting(None, gt=0, le=100_000)


#: The keys of the ``render:`` block that say how to run, not what to render (not hashed).
RUN_KEYS = ("workers", "scheduler", "shard_size", "threads", "tile_size", "sheet_images", "image_timeout_s",
            "progress", "connect_timeout_s")
#: Image files are named NNNNNN.png: at most a million images per scan.
MAX_IMAGES = 1_000_000


@dataclass(frozen=True)
class RenderSettings(Settings):
    """The ``render:`` block of params.yaml (sampling, render and run settings).

    ``preset`` fills ``camera_polar_max_deg``, ``gaze_offset_max_deg`` and ``gaze_step_deg``
    from ``presets`` (built-in :data:`PRESETS`, entries replaced by the block's own); explicit
    keys override the preset.
    """

    block: ClassVar[str] = "render"

    preset: str = "generic"
    n_images: int = setting(16, ge=0, le=MAX_IMAGES)     # sample i = f(seed, i)
    seed: int = setting(0, ge=0, le=2**63 - 1)
    width: int = setting(120, ge=8, le=8192)
    height: int = setting(80, ge=8, le=8192)
    samples: int = setting(10, ge=1, le=65536)          # Cycles samples per pixel
    denoise: bool = True
    eyes: tuple[Literal["left", "right"], ...] = setting(("left", "right"), min_len=1, max_len=2)
    camera_polar_max_deg: float = setting(_GENERIC["camera_polar_max_deg"], ge=0, lt=80)   # the preset's
    gaze_offset_max_deg: float = setting(_GENERIC["gaze_offset_max_deg"], ge=0, le=90)
    gaze_step_deg: float = setting(_GENERIC["gaze_step_deg"], gt=0, le=90)
    max_pitch_deg: float = setting(25.0, ge=0, le=90)
    max_yaw_deg: float = setting(35.0, ge=0, le=90)
    ortho_scale_mm: tuple[float, float] = setting((30.0, 36.0), gt=0, le=1000, ordered=True)
    center_jitter_mm: float = setting(1.0, ge=0, le=100)
    camera_distance_mm: float = setting(200.0, gt=0, le=100_000)
    strength: tuple[float, float] = setting((0.6, 1.6), ge=0, le=1000, ordered=True)
    hdris: tuple[str, ...] = setting(HDRIS, min_len=1, max_len=1000)
    max_attempts: int = setting(100, ge=1, le=100_000)
    landmark_tolerance_mm: float = setting(0.01, gt=0, le=10)
    # framing for GazeML's UnityEyes loader: the orthographic scale of each image puts the iris
    # centre this many pixels from the eyeball centre (ortho_scale_mm is then not used)
    iris_distance_px: float | None = setting(None, gt=0, le=100_000)
    # label files per image: eyerig (NNNNNN.json, always), unityeyes (unityeyes/NNNNNN.json + .jpg),
    # pts (NNNNNN.pts, 300-W); pipeline/render/label_formats.py
    label_formats: tuple[Literal["eyerig", "unityeyes", "pts"], ...] = setting(("eyerig",), min_len=1,
                                                                                max_len=3)
    # per image also NNNNNN_seg.png, NNNNNN_depth.exr and landmark visibility, from the same render's
    # passes (pipeline/render/seg.py, visibility.py)
    masks: bool = True
    presets: dict[str, RenderPreset] = setting(
        default_factory=lambda: {k: RenderPreset(**v) for k, v in PRESETS.items()})
    # how to run (RUN_KEYS: not part of the config hash)
    workers: int = setting(0, ge=0, le=1024)            # LocalCluster worker processes (0 = auto)
    scheduler: str | None = None                        # dask scheduler address instead of a LocalCluster
    shard_size: int = setting(8, ge=1, le=100_000)      # images per dask task
    threads: int = setting(0, ge=0, le=1024)            # Cycles threads per Blender (0 = cores / workers)
    tile_size: int | None = setting(None, ge=8, le=8192)
    sheet_images: int = setting(16, ge=0, le=1024)      # tiles on contact_sheet.png
    image_timeout_s: float = setting(600.0, gt=0, le=86_400)
    progress: bool = True
    connect_timeout_s: float = setting(10.0, gt=0, le=3600)

    @classmethod
    def prepare(cls, params: dict) -> dict:
        """Fill the preset's values (explicit keys win); ``presets`` entries replace built-in ones."""
        presets = {k: dict(v) for k, v in PRESETS.items()}
        own = params.get("presets")
        if own is not None and not isinstance(own, dict):
            raise SettingError("presets", "must be a mapping of preset name -> settings")
        presets.update(own or {})
        name = params.get("preset", "generic")
        if not isinstance(name, str) or name not in presets:
            raise SettingError("preset", f"must be one of {', '.join(sorted(map(str, presets)))} (got {name!r})")
        chosen = RenderPreset._build(presets[name], prefix=f"presets.{name}")   # its own key in errors
        fill = {k: getattr(chosen, k) for k in RenderPreset.keys() if k in presets[name]}
        return {**fill, **params, "presets": presets}

    @classmethod
    def from_dict(cls, d: dict | None) -> "RenderSettings":
        """Same as :meth:`from_params` (kept for callers of the old name)."""
        return cls.from_params(d)

    def validate(self) -> None:
        if self.width < self.height:
            raise SettingError("width", f"must be >= height (orthographic scale = image width; got "
                                        f"{self.width} x {self.height})")
        if any(not h.endswith(".exr") for h in self.hdris):
            raise SettingError("hdris", "must be a list of .exr names")
        if self.iris_distance_px is not None and self.center_jitter_mm != 0:
            raise SettingError("center_jitter_mm", "must be 0 with iris_distance_px (GazeML's loader takes the "
                                                   "image centre for the eyeball centre); with preset unityeyes, "
                                                   "drop the explicit center_jitter_mm, width, height, eyes and "
                                                   f"camera_distance_mm or set them (got {self.center_jitter_mm:g})")
        if "eyerig" not in self.label_formats or len(set(self.label_formats)) < len(self.label_formats):
            raise SettingError("label_formats", "must list eyerig (its label marks an image done) and each "
                                                f"format once (got {list(self.label_formats)})")

    def hashed(self) -> dict:
        """The settings that change images or labels (not n_images: sample i ignores it; not how to run)."""
        skip = {"n_images", "presets", *RUN_KEYS}
        d = {k: getattr(self, k) for k in self.keys() if k not in skip}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


# ----------------------------------------------------------------------------- geometry helpers

def rotation_between(a, b) -> np.ndarray:
    """(3, 3) minimal rotation taking unit ``a`` to unit ``b`` (Listing's law from ``a``)."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        raise ValueError("opposite directions: minimal rotation undefined")
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = math.atan2(s, c)
    return np.eye(3) + math.sin(ang) * K + (1 - math.cos(ang)) * (K @ K)


def matrix_to_quat(R) -> list[float]:
    """Unit quaternion ``[w, x, y, z]`` (w >= 0) of a rotation matrix."""
    R = np.asarray(R, float)
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return [float(x) for x in q]


def eye_angles(g, basis) -> tuple[float, float]:
    """(pitch, yaw) degrees of direction ``g`` in an eye frame (rows e_x, e_y, forward).

    pitch = asin(g . e_y) (up positive), yaw = atan2(g . e_x, g . f) (toward e_x = head +X =
    subject's left positive).
    """
    g = np.asarray(g, float) / np.linalg.norm(g)
    x, y, z = basis @ g
    return math.degrees(math.asin(max(-1.0, min(1.0, y)))), math.degrees(math.atan2(x, z))


def direction_from_angles(pitch_deg: float, yaw_deg: float, basis) -> np.ndarray:
    """Inverse of :func:`eye_angles`: (3,) unit head-frame direction."""
    p, y = math.radians(pitch_deg), math.radians(yaw_deg)
    return np.array([math.cos(p) * math.sin(y), math.sin(p), math.cos(p) * math.cos(y)]) @ basis


def look_at(position, target, up) -> np.ndarray:
    """(4, 4) world-to-camera (column vectors), camera looks down -Z, +Y up, +X right."""
    position = np.asarray(position, float)
    z = position - np.asarray(target, float)
    z /= np.linalg.norm(z)
    upv = np.asarray(up, float)
    y = upv - np.dot(upv, z) * z
    if np.linalg.norm(y) < 1e-9:
        raise ValueError("up direction parallel to the view direction")
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    M = np.eye(4)
    M[:3, :3] = np.stack([x, y, z])
    M[:3, 3] = -M[:3, :3] @ position
    return M


def ortho_size(ortho_scale_mm: float, width: int, height: int) -> tuple[float, float]:
    """(image width, image height) in mm of an orthographic camera (Blender sensor_fit AUTO)."""
    w = float(ortho_scale_mm)
    if width >= height:
        return w, w * height / width
    return w * width / height, w


def projection_matrix(ortho_scale_mm: float, width: int, height: int) -> np.ndarray:
    """(3, 4) camera mm -> homogeneous pixels: ``u = (x / w + 0.5) W``, ``v = (0.5 - y / h) H``."""
    ow, oh = ortho_size(ortho_scale_mm, width, height)
    return np.array([[width / ow, 0.0, 0.0, width / 2.0],
                     [0.0, -height / oh, 0.0, height / 2.0],
                     [0.0, 0.0, 0.0, 1.0]])


def to_camera(points_head, world_to_camera) -> np.ndarray:
    """(n, 3) camera-frame mm of head-frame points."""
    P = np.asarray(points_head, float)
    M = np.asarray(world_to_camera, float)
    return P @ M[:3, :3].T + M[:3, 3]


def project(points_cam, ortho_scale_mm: float, width: int, height: int) -> np.ndarray:
    """(n, 2) pixel coordinates (origin top-left, pixel centres at +0.5) of camera-frame points."""
    P = np.asarray(points_cam, float)
    H = np.concatenate([P, np.ones((len(P), 1))], 1) @ projection_matrix(ortho_scale_mm, width, height).T
    return H[:, :2] / H[:, 2:]


def point_in_polygon(pt, poly) -> bool:
    """Even-odd rule: is 2D point ``pt`` inside the closed polygon ``poly`` (n, 2)?"""
    x, y = float(pt[0]), float(pt[1])
    P = np.asarray(poly, float)
    x0, y0 = P[:, 0], P[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return bool(np.count_nonzero(crosses & (x < xi)) % 2 == 1)


def choose_skin_detail(mm_per_px: float, amplitude_mm: float, edge_mm: float) -> str:
    """``displacement`` | ``bump`` | ``none`` from the pixel footprint (rule in the module doc)."""
    if amplitude_mm > 0 and amplitude_mm >= 0.5 * mm_per_px:
        return "displacement"
    if amplitude_mm > 0 and edge_mm > mm_per_px:
        return "bump"
    return "none"


def offset_grid(max_deg: float, step_deg: float) -> np.ndarray:
    """Gaze offsets ``k * step`` with ``|k * step| <= max`` (always contains 0)."""
    k = int(math.floor(max_deg / step_deg + 1e-9))
    return np.arange(-k, k + 1) * float(step_deg)


# ----------------------------------------------------------------------------- the sample

@dataclass
class Sample:
    """One posed sample: the worker spec plus what the labels need."""

    index: int
    attempts: int
    spec: dict
    side: str
    camera: dict            # world_to_camera (4,4), ortho_scale_mm, position_mm, polar/azimuth
    gaze: dict              # per side: vector, pitch/yaw in eye frame, clipped flag, offsets
    lid_pitch_deg: float
    landmarks_head: np.ndarray   # (28, 3)
    landmarks_cam: np.ndarray    # (28, 3)
    landmarks_px: np.ndarray     # (28, 2)
    pupil_center_px: np.ndarray  # (2,)
    lid_polygon_px: np.ndarray   # (L, 2)


def _draw(asset: ra.RenderAsset, s: RenderSettings, rng, overrides: dict | None = None) -> dict:
    """Random choices of one attempt (``overrides`` pins any of them; for tests/extremes)."""
    o = dict(overrides or {})
    side = str(rng.choice(list(s.eyes)))
    cmax = math.radians(s.camera_polar_max_deg)
    cos_t = rng.uniform(math.cos(cmax), 1.0)
    d = {
        "side": side,
        "polar_deg": math.degrees(math.acos(min(1.0, cos_t))),
        "azimuth_deg": float(rng.uniform(0.0, 360.0)),
        "ortho_scale_mm": float(rng.uniform(*s.ortho_scale_mm)),
        "jitter": rng.uniform(-1.0, 1.0, size=2) * s.center_jitter_mm,
        "gaze_offset_deg": [float(x) for x in rng.choice(offset_grid(s.gaze_offset_max_deg,
                                                                      s.gaze_step_deg), size=2)],
        "iris_color": str(rng.choice(list(asset.variants.get("irisColor") or IRIS_COLORS))),
        "sclera_tint": str(rng.choice(list(asset.variants.get("scleraTint") or SCLERA_TINTS))),
        "veins": str(rng.choice(list(asset.variants.get("veins") or VEINS))),
        "pupil": float(rng.uniform(-1.0, 1.0)),
        "iris": float(rng.uniform(-1.0, 1.0)),
        "hdri": str(rng.choice(list(s.hdris))),
        "hdri_rotation_deg": float(rng.uniform(0.0, 360.0)),
        "strength": float(rng.uniform(*s.strength)),
        "cycles_seed": int(rng.integers(0, 2**31 - 1)),
    }
    d.update(o)
    return d


def _blend(pupil: float, iris: float) -> dict:
    return {"pupil_dilate": max(pupil, 0.0), "pupil_constrict": max(-pupil, 0.0),
            "iris_large": max(iris, 0.0), "iris_small": max(-iris, 0.0)}


def iris_framed_scale(eye: ra.EyeAsset, blend: dict, s: RenderSettings) -> float:
    """Orthographic scale (image width, mm) putting the iris centre ``s.iris_distance_px`` pixels
    from the eyeball centre.

    GazeML's UnityEyes loader puts the iris centre at ``image centre + 71.7593 px * (look x,
    -look y)`` (an orthographic eyeball of fixed radius, gaze in camera axes). Our camera is
    orthographic and looks at the eyeball centre, so the projected iris centre (the centre of the
    iris ring, on the gaze axis at distance ``d`` from the eyeball centre) is there exactly when
    ``d`` mm span that many pixels. ``d`` changes with the iris size blend shapes (the iris plane
    moves along the flattened inner sphere), so it is taken from the posed iris landmarks.
    """
    iris = ra.inner_points(eye, blend, np.eye(3), eye.iris)
    d = float(np.linalg.norm(iris.mean(0) - eye.center))
    return float(s.width) * d / float(s.iris_distance_px)


def pose_sample(asset: ra.RenderAsset, s: RenderSettings, index: int, attempt: int, png: str,
                overrides: dict | None = None) -> Sample:
    """Pose one attempt of sample ``index`` (no rejection test; see :func:`make_sample`)."""
    rng = np.random.default_rng([int(s.seed), int(index), int(attempt)])
    d = _draw(asset, s, rng, overrides)
    side = d["side"]
    eye = asset.eyes[side]
    if s.iris_distance_px and "ortho_scale_mm" not in (overrides or {}):
        d["ortho_scale_mm"] = iris_framed_scale(eye, _blend(d["pupil"], d["iris"]), s)
    B = eye.basis
    th, ph = math.radians(d["polar_deg"]), math.radians(d["azimuth_deg"])
    view = math.cos(th) * B[2] + math.sin(th) * (math.cos(ph) * B[0] + math.sin(ph) * B[1])
    view /= np.linalg.norm(view)
    pos0 = eye.center + s.camera_distance_mm * view
    W2C = look_at(pos0, eye.center, B[1])
    # in-plane shift of the framing (camera x/y axes)
    shift = W2C[0, :3] * d["jitter"][0] + W2C[1, :3] * d["jitter"][1]
    pos = pos0 + shift
    W2C = look_at(pos, eye.center + shift, B[1])

    # gaze: eye contact + offsets, clipped; the other eye parallel
    p0, y0 = eye_angles(view, B)
    dp, dy = d["gaze_offset_deg"]
    gaze = {}
    want = direction_from_angles(p0 + dp, y0 + dy, B) if "gaze_pitch_deg" not in d else None
    rots = {}
    for sd in ra.SIDES:
        Bs = asset.eyes[sd].basis
        if "gaze_pitch_deg" in d:          # pinned eye-frame angles (extremes)
            pr, yr = float(d["gaze_pitch_deg"]), float(d["gaze_yaw_deg"])
        else:
            pr, yr = eye_angles(want, Bs)
        pc = min(max(pr, -s.max_pitch_deg), s.max_pitch_deg)
        yc = min(max(yr, -s.max_yaw_deg), s.max_yaw_deg)
        g = direction_from_angles(pc, yc, Bs)
        R = rotation_between(Bs[2], g)
        rots[sd] = R
        gaze[sd] = {"vector_head": g, "pitch_eye_deg": pc, "yaw_eye_deg": yc,
                    "requested_pitch_eye_deg": pr, "requested_yaw_eye_deg": yr,
                    "clipped": bool(abs(pc - pr) > 1e-9 or abs(yc - yr) > 1e-9),
                    "lid_pitch_deg": lids.pitch_from_gaze(g, Bs[2]),
                    "rotation_wxyz": matrix_to_quat(R)}
    lid_pitch = float(np.mean([gaze[sd]["lid_pitch_deg"] for sd in ra.SIDES]))
    lw = lids.lid_weights(lid_pitch, asset.max_pitch_deg)
    blend = _blend(d["pupil"], d["iris"])

    L_head = ra.posed_landmarks(asset, side, lw, blend, rots[side])
    L_cam = to_camera(L_head, W2C)
    L_px = project(L_cam, d["ortho_scale_mm"], s.width, s.height)
    pc_cam = to_camera(ra.pupil_center(asset, side, blend, rots[side])[None], W2C)
    pc_px = project(pc_cam, d["ortho_scale_mm"], s.width, s.height)[0]
    poly_px = project(to_camera(ra.posed_lid_polygon(asset, side, lw), W2C),
                      d["ortho_scale_mm"], s.width, s.height)
    mm_per_px = ortho_size(d["ortho_scale_mm"], s.width, s.height)[0] / s.width
    spec = {
        "index": int(index), "png": str(png), "width": int(s.width), "height": int(s.height),
        "samples": int(s.samples), "denoise": bool(s.denoise), "cycles_seed": d["cycles_seed"],
        "eye": side,
        "camera": {"world_to_camera": W2C.tolist(), "ortho_scale_mm": d["ortho_scale_mm"]},
        "eye_rotation": {sd: gaze[sd]["rotation_wxyz"] for sd in ra.SIDES},
        "lid_weights": {k: float(v) for k, v in lw.items()},
        "eyeball": {"iris_color": d["iris_color"], "sclera_tint": d["sclera_tint"], "veins": d["veins"],
                    "blend": blend},
        "lighting": {"hdri": d["hdri"], "rotation_deg": d["hdri_rotation_deg"], "strength": d["strength"]},
        "skin_detail": choose_skin_detail(mm_per_px, asset.displacement_amplitude_mm,
                                          asset.skin_faces_edge_mm),
        "landmarks_head_mm": L_head.tolist(),
    }
    camera = {"world_to_camera": W2C, "ortho_scale_mm": d["ortho_scale_mm"], "position_mm": pos,
              "polar_deg": d["polar_deg"], "azimuth_deg": d["azimuth_deg"],
              "distance_mm": float(s.camera_distance_mm), "jitter_mm": [float(x) for x in d["jitter"]],
              "gaze_offset_deg": [dp, dy], "eye_contact_eye_deg": [p0, y0], "mm_per_px": mm_per_px}
    return Sample(index=int(index), attempts=attempt + 1, spec=spec, side=side, camera=camera, gaze=gaze,
                  lid_pitch_deg=lid_pitch, landmarks_head=L_head, landmarks_cam=L_cam, landmarks_px=L_px,
                  pupil_center_px=pc_px, lid_polygon_px=poly_px)


def pupil_in_lids(smp: Sample) -> bool:
    """The rejection rule: the projected pupil centre lies inside the posed lid opening and
    inside the polygon of the 12 eyelid landmarks that the label carries (a user who checks the
    rule on the label finds that it holds)."""
    return (point_in_polygon(smp.pupil_center_px, smp.lid_polygon_px)
            and point_in_polygon(smp.pupil_center_px, smp.landmarks_px[:lmk.N_EYELID]))


class RejectionError(ValueError):
    """No attempt of a sample put the pupil inside the eyelid polygon."""


def make_sample(asset: ra.RenderAsset, s: RenderSettings, index: int, png, overrides: dict | None = None,
                reject: bool = True) -> Sample:
    """Sample ``index``: the first attempt whose projected pupil centre is inside the lid polygon.

    Raises
    ------
    RejectionError after ``max_attempts`` rejected attempts.
    """
    for attempt in range(int(s.max_attempts)):
        smp = pose_sample(asset, s, index, attempt, str(png), overrides)
        if not reject or pupil_in_lids(smp):
            return smp
    raise RejectionError(f"sample {index}: pupil outside the eyelid polygon in all "
                         f"{s.max_attempts} attempts")


def png_name(index: int) -> str:
    return f"{int(index):06d}.png"


def tmp_png(out_dir, index: int) -> Path:
    """Where the worker writes image ``index`` (moved into place by the shard runner)."""
    return Path(out_dir).resolve() / ".tmp" / png_name(index)
