"""What one image asks of the Blender worker: :class:`RenderSpec`, written and read in one place.

The sampler (pipeline/render/sampling.py) builds a spec per image; the shard runner sends it to
a persistent Blender worker (pipeline/render/shard.py) as one JSON line (:meth:`RenderSpec.to_json`),
and the worker (pipeline/blender/render_worker.py) reads it back (:meth:`RenderSpec.from_dict`),
which checks every value once: a bad spec is one ``ValueError`` naming the key, and the worker
replies with it and carries on. The wire layout is the flat mapping of the fields below, with
``quality``'s fields and its ``overrides`` at the top level::

    {"index": 17, "png": "/abs/renders/s/.tmp/000017.png", "width": 120, "height": 80,
     "eye": "left", "camera": {"world_to_camera": [[...] * 4], "ortho_scale_mm": 32.0},
                                (pinhole: {"type": "pinhole", "world_to_camera": ..., "K": [[f, 0, cx], ...]})
     "eye_rotation": {"left": [w, x, y, z], "right": [w, x, y, z]},
     "lid_weights": {"lids_up": 0.2, "lids_down": 0.0},
     "eyeball": {"iris_color": "blue", "sclera_tint": "white", "veins": "clear",
                 "blend": {"pupil_dilate": 0.3, ...}},
     "lighting": {"hdri": "forest.exr", "rotation_deg": 30.0, "strength": 1.2},
     "samples": 10, "denoise": true, "cycles_seed": 123, "skin_detail": "bump",
     "landmarks_head_mm": [[x, y, z] * 28], "seg_png": "/abs/..." (optional), "depth_exr": ...}

Frames: head frame mm; ``world_to_camera`` head mm -> camera mm (OpenGL axes, the camera looks
down -Z; pipeline/render/camera.py); rotations are quaternions ``(w, x, y, z)`` in the head frame
about each eye's centre. Benchmarks and tests may add expert :data:`OVERRIDES` (the worker's
film, lashes, sampling and light paths for one image); the worker applies them and undoes them
on the next image.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from pipeline.render.camera import Camera

SIDES = ("left", "right")
SKIN_DETAIL = ("displacement", "bump", "none")
EYE_BLENDS = ("pupil_dilate", "pupil_constrict", "iris_large", "iris_small")
#: Optional per-image settings of the worker (tests and benchmarks), by name.
OVERRIDES = ("denoiser", "lashes", "skin_subdivision", "adaptive_sampling", "adaptive_threshold",
             "denoise_prefilter", "denoise_normal_quality", "max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
             "transparent_max_bounces", "volume_bounces", "cycles")
MAX_SIZE_PX, MAX_SAMPLES, N_LANDMARKS = 8192, 1 << 16, 28


def _need(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _finite(x, key: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{key} must be a number, got {x!r}") from None
    _need(math.isfinite(v), f"{key} must be finite, got {x!r}")
    return v


@dataclass(frozen=True)
class EyeConfiguration:
    """The eyeball variants and blend-shape weights of both eyes (the asset's variant sets)."""

    iris_color: str
    sclera_tint: str
    veins: str
    blend: dict = field(default_factory=dict)

    def __post_init__(self):
        from pipeline.eyeball.textures import IRIS_COLORS, SCLERA_TINTS, VEINS

        _need(self.iris_color in IRIS_COLORS, f"eyeball.iris_color {self.iris_color!r} not in {IRIS_COLORS}")
        _need(self.sclera_tint in SCLERA_TINTS,
              f"eyeball.sclera_tint {self.sclera_tint!r} not in {tuple(SCLERA_TINTS)}")
        _need(self.veins in VEINS, f"eyeball.veins {self.veins!r} not in {VEINS}")
        bad = set(self.blend) - set(EYE_BLENDS)
        _need(not bad, f"eyeball.blend: unknown shapes {sorted(bad)}")
        for k, v in self.blend.items():
            _need(0.0 <= _finite(v, f"eyeball.blend.{k}") <= 1.0, f"eyeball.blend.{k} = {v} outside [0, 1]")


@dataclass(frozen=True)
class Lighting:
    """One environment map (a bundled name or an absolute path; the worker finds it), its
    rotation about head +Y and its strength."""

    hdri: str
    rotation_deg: float
    strength: float

    def __post_init__(self):
        _need(isinstance(self.hdri, str) and bool(self.hdri), f"lighting.hdri {self.hdri!r}: a map name or path")
        _finite(self.rotation_deg, "lighting.rotation_deg")
        _need(_finite(self.strength, "lighting.strength") > 0, "lighting.strength must be > 0")


@dataclass(frozen=True)
class Quality:
    """How the image is rendered: Cycles samples, the denoiser, the seed, the skin's detail
    (pipeline/render/sampling.py ``choose_skin_detail``) and expert :data:`OVERRIDES`."""

    samples: int
    denoise: bool
    cycles_seed: int
    skin_detail: str = "bump"
    overrides: dict = field(default_factory=dict)

    def __post_init__(self):
        _need(isinstance(self.samples, int) and 1 <= self.samples <= MAX_SAMPLES,
              f"samples {self.samples} out of range")
        _need(self.skin_detail in SKIN_DETAIL, f"skin_detail {self.skin_detail!r} not in {SKIN_DETAIL}")
        bad = set(self.overrides) - set(OVERRIDES)
        _need(not bad, f"unknown spec keys {sorted(bad)}")


@dataclass(frozen=True)
class RenderSpec:
    """One image for the Blender worker: the camera, both eyes' rotations, the lid weights, the
    lighting, the eye configuration, the quality, and the 28 landmarks the worker measures
    again in its posed scene (landmark check). ``png`` (and the optional ``seg_png`` /
    ``depth_exr``) are absolute paths in a folder that exists."""

    index: int
    png: str
    width: int
    height: int
    eye: str
    camera: Camera
    eye_rotation: dict
    lid_weights: dict
    eyeball: EyeConfiguration
    lighting: Lighting
    quality: Quality
    landmarks_head_mm: list
    seg_png: str | None = None
    depth_exr: str | None = None

    def __post_init__(self):
        _need(isinstance(self.index, int), f"index must be an integer, got {self.index!r}")
        for k in ("png", "seg_png", "depth_exr"):
            p = getattr(self, k)
            if p is not None or k == "png":
                _need(isinstance(p, str) and Path(p).is_absolute(), f"{k} {p!r}: an absolute path")
        _need(self.png.lower().endswith(".png"), f"png {self.png!r}: an absolute .png path")
        _need(isinstance(self.width, int) and isinstance(self.height, int)
              and 1 <= self.width <= MAX_SIZE_PX and 1 <= self.height <= MAX_SIZE_PX,
              f"image size {self.width}x{self.height} out of range")
        _need(self.eye in SIDES, f"eye {self.eye!r} not in {SIDES}")
        _need(set(self.eye_rotation) == set(SIDES), f"eye_rotation must give both eyes {SIDES}")
        for s, q in self.eye_rotation.items():
            a = np.asarray(q, float)
            _need(a.shape == (4,) and bool(np.all(np.isfinite(a))) and np.linalg.norm(a) > 1e-9,
                  f"eye_rotation.{s}: a non-zero quaternion (w, x, y, z), got {q!r}")
        for k, v in self.lid_weights.items():
            _need(0.0 <= _finite(v, f"lid_weights.{k}") <= 1.0, f"lid_weights.{k} = {v} outside [0, 1]")
        L = np.asarray(self.landmarks_head_mm, float)
        _need(L.shape == (N_LANDMARKS, 3) and bool(np.all(np.isfinite(L))),
              f"landmarks_head_mm must be {N_LANDMARKS} x 3 finite numbers, got shape {L.shape}")

    # ------------------------------------------------------------------ the one serialisation

    def to_dict(self) -> dict:
        """The wire layout (module doc): plain JSON types, optional keys only when set."""
        d = {"index": self.index, "png": self.png, "width": self.width, "height": self.height,
             "samples": self.quality.samples, "denoise": self.quality.denoise,
             "cycles_seed": self.quality.cycles_seed, "eye": self.eye,
             "camera": self.camera.to_dict(), "eye_rotation": dict(self.eye_rotation),
             "lid_weights": dict(self.lid_weights), "eyeball": asdict(self.eyeball),
             "lighting": asdict(self.lighting), "skin_detail": self.quality.skin_detail,
             "landmarks_head_mm": self.landmarks_head_mm}
        for k in ("seg_png", "depth_exr"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        d.update(self.quality.overrides)
        return d

    def to_json(self) -> str:
        """One line of JSON: what the shard runner sends to the worker."""
        return json.dumps(self.to_dict())

    @classmethod
    def from_dict(cls, d) -> "RenderSpec":
        """A spec from its wire layout, every value checked (ValueError naming the key)."""
        _need(isinstance(d, dict), "a spec must be a JSON object")
        known = {"index", "png", "width", "height", "samples", "denoise", "cycles_seed", "eye", "camera",
                 "eye_rotation", "lid_weights", "eyeball", "lighting", "skin_detail", "landmarks_head_mm",
                 "seg_png", "depth_exr"}
        try:
            cam, eb, light = d["camera"], d["eyeball"], d["lighting"]
            return cls(index=d["index"], png=d["png"], width=d["width"], height=d["height"], eye=d["eye"],
                       camera=Camera.from_dict(cam),
                       eye_rotation=dict(d["eye_rotation"]), lid_weights=dict(d["lid_weights"]),
                       eyeball=EyeConfiguration(eb["iris_color"], eb["sclera_tint"], eb["veins"],
                                                dict(eb.get("blend", {}))),
                       lighting=Lighting(light["hdri"], light["rotation_deg"], light["strength"]),
                       quality=Quality(d["samples"], bool(d.get("denoise", True)), int(d.get("cycles_seed", 0)),
                                       d.get("skin_detail", "bump"),
                                       {k: v for k, v in d.items() if k not in known}),
                       landmarks_head_mm=d["landmarks_head_mm"], seg_png=d.get("seg_png"),
                       depth_exr=d.get("depth_exr"))
        except KeyError as exc:
            raise ValueError(f"spec has no {exc.args[0]!r}") from None
        except (TypeError, AttributeError) as exc:
            raise ValueError(f"spec is malformed ({type(exc).__name__}: {exc})") from None

    @classmethod
    def from_json(cls, line: str) -> "RenderSpec":
        return cls.from_dict(json.loads(line))

    def with_masks(self, seg_png, depth_exr) -> "RenderSpec":
        """The same image, also writing its seg mask and depth map to these paths."""
        return replace(self, seg_png=str(seg_png), depth_exr=str(depth_exr))

    def with_overrides(self, **overrides) -> "RenderSpec":
        """The same image with expert :data:`OVERRIDES` (and ``samples``, ``denoise``,
        ``cycles_seed``) changed: benchmarks and tests."""
        q = {k: overrides.pop(k) for k in ("samples", "denoise", "cycles_seed", "skin_detail") if k in overrides}
        return replace(self, quality=replace(self.quality, **q, overrides={**self.quality.overrides, **overrides}))
