"""The ``render:`` block of params.yaml: what to render (sampling ranges, image size, quality,
label formats, masks), the presets that fill it, and how to run (workers, shards; not hashed).

:class:`RenderSettings` is read by the render stage and the dataset command; the sampler
(pipeline/render/sampling.py) draws every image from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from pipeline.render.formats import NAMES as LABEL_FORMATS
from pipeline.render.formats import REQUIRED as REQUIRED_FORMAT
from pipeline.render.formats import needs_masks
from pipeline.render.formats.unityeyes import GAZEML_EYEBALL_RADIUS_PX
from pipeline.settings import SettingError, Settings, setting

HDRIS = ("city.exr", "courtyard.exr", "forest.exr", "interior.exr", "night.exr", "studio.exr",
         "sunrise.exr", "sunset.exr")

PRESETS = {
    # paper: ~40 deg of head-pose (viewpoint) variation, gaze up to 45 deg from eye contact in
    # 10 deg steps; the paper's training images show the whole eye, so every landmark and the
    # whole iris stay 3 px inside the frame (frame_margin_px; issue 33: without it the lateral
    # canthus fell outside 17 of 60 images)
    "generic": {"camera_polar_max_deg": 20.0, "gaze_offset_max_deg": 45.0, "gaze_step_deg": 10.0,
                "frame_margin_px": 3.0},
    # paper's laptop setting: 10 deg pose, 20 deg gaze variation; the whole eye framed likewise
    "targeted": {"camera_polar_max_deg": 5.0, "gaze_offset_max_deg": 10.0, "gaze_step_deg": 5.0,
                 "frame_margin_px": 3.0},
    # framed as UnityEyes frames its images, so that GazeML's UnityEyes loader (eyeball centre at the
    # image centre, iris centre 71.7593 px from it along the gaze) holds; see
    # pipeline/render/formats/unityeyes.py. The central 320 x 240 of UnityEyes' recommended 512 x 384
    # (the same scale and centre, so GazeML reads it alike; the eye region covers this window, not
    # the whole 512 x 384: benchmarks/results/background.md), its left eye, its camera 10 units (cm)
    # from the eyeball centre looking at it (no shift), GazeML's |head pitch|, |yaw| <= 20
    "unityeyes": {"camera_polar_max_deg": 20.0, "gaze_offset_max_deg": 30.0, "gaze_step_deg": 1.0,
                  "width": 320, "height": 240, "eyes": ("left",), "center_jitter_mm": 0.0,
                  "camera_distance_mm": 100.0, "iris_distance_px": GAZEML_EYEBALL_RADIUS_PX},
    # a near-eye (headset) eye camera, pinhole: NVGaze's 4:3 frame (its real camera 640 x 480,
    # here halved), the camera 20-60 mm in front of the cornea (issue 24: headsets; the cornea's
    # apex is 13.5 mm in front of the eyeball centre, so 33.5-73.5 mm from it: nearer, the
    # camera would sit among the lashes), a 50 deg horizontal field of view (focal 160 / tan 25
    # deg = 343.1 px; eye cameras image the whole eye from 15-25 mm with ~60 deg, but at 60 deg
    # the frame outgrows the eye-region asset beyond ~45 mm: benchmarks/results/background.md),
    # the principal point within 8 px of the centre
    "near_eye": {"camera": "pinhole", "width": 320, "height": 240, "camera_distance_mm": (33.5, 73.5),
                 "focal_px": 343.1, "principal_jitter_px": 8.0, "camera_polar_max_deg": 25.0,
                 "gaze_offset_max_deg": 30.0, "gaze_step_deg": 2.0},
    # a laptop webcam, pinhole, at 400-700 mm: MPIIGaze's 1280 x 720 laptop sensors, focal
    # 950-1150 px (horizontal field of view 68-58 deg), aimed between the eyes; the image is the
    # 80 x 48 px crop of the sensor image around the eye (the 5:3 of MPIIGaze's and GazeML's
    # 60 x 36 eye patch, a third larger: the corner-to-corner eye spans a median 0.56-0.68 of it
    # on our scans and fits at 400 mm), the eye within 4 px of the crop centre
    "webcam": {"camera": "pinhole", "width": 80, "height": 48, "sensor_px": (1280, 720),
               "camera_distance_mm": (400.0, 700.0), "focal_px": (950.0, 1150.0), "principal_jitter_px": 10.0,
               "camera_aim": "between_eyes", "crop_jitter_px": 4.0, "camera_polar_max_deg": 20.0,
               "gaze_offset_max_deg": 30.0, "gaze_step_deg": 2.0},
}


_GENERIC = PRESETS["generic"]
#: A pinhole camera nearer than this to the eyeball centre would sit in the cornea (its apex is
#: ~13 mm in front of the centre) or the lashes' roots.
MIN_PINHOLE_DISTANCE_MM = 15.0
#: Keys that only a pinhole camera reads: left out of the config hash of an orthographic render
#: (its hash, and so its files, stay those of before the pinhole camera existed).
PINHOLE_KEYS = ("camera", "focal_px", "principal_point_px", "principal_jitter_px", "sensor_px", "camera_aim",
                "crop_jitter_px")


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
    camera_distance_mm: float | tuple[float, float] = setting(200.0, gt=0, le=100_000, ordered=True)
    iris_distance_px: float | None = setting(None, gt=0, le=100_000)
    camera: Literal["ortho", "pinhole"] = "ortho"
    focal_px: float | tuple[float, float] | None = setting(None, gt=0, le=1_000_000, ordered=True)
    principal_point_px: tuple[float, float] | None = None
    principal_jitter_px: float = setting(0.0, ge=0, le=100_000)
    sensor_px: tuple[int, int] | None = setting(None, ge=8, le=100_000)
    camera_aim: Literal["eye", "between_eyes"] = "eye"
    crop_jitter_px: float = setting(0.0, ge=0, le=100_000)
    frame_margin_px: float | None = setting(None, ge=0, le=1000)

#: How a dataset's identities are split (pipeline/render/splits.py): files written from the images, not hashed.
SPLIT_KEYS = ("splits", "split_seed")
#: Keys only the label format ``normalized`` reads: hashed only when it is listed.
NORMALIZED_KEYS = ("normalized_size_px", "normalized_focal_px", "normalized_distance_mm", "normalized_center")


#: The keys of the ``render:`` block that say how to run, not what to render (not hashed).
RUN_KEYS = ("workers", "scheduler", "shard_size", "threads", "tile_size", "sheet_images", "image_timeout_s",
            "progress", "connect_timeout_s", "tar_images")
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
    # along the view ray, from the eyeball centre; orthographic: framing only (one value);
    # pinhole: a [low, high] range drawn uniformly, or one value
    camera_distance_mm: float | tuple[float, float] = setting(200.0, gt=0, le=100_000, ordered=True)
    strength: tuple[float, float] = setting((0.6, 1.6), ge=0, le=1000, ordered=True)
    hdris: tuple[str, ...] = setting(HDRIS, min_len=1, max_len=1000)
    max_attempts: int = setting(100, ge=1, le=100_000)
    landmark_tolerance_mm: float = setting(0.01, gt=0, le=10)
    # framing for GazeML's UnityEyes loader: the orthographic scale of each image puts the iris
    # centre this many pixels from the eyeball centre (ortho_scale_mm is then not used)
    iris_distance_px: float | None = setting(None, gt=0, le=100_000)
    # the camera (pipeline/render/camera.py): ortho (image width ortho_scale_mm) or pinhole (the keys
    # below; docs/render.md, Cameras)
    camera: Literal["ortho", "pinhole"] = "ortho"
    # pinhole: focal length of the sensor in px, a [low, high] range drawn uniformly or one value
    focal_px: float | tuple[float, float] | None = setting(None, gt=0, le=1_000_000, ordered=True)
    # pinhole: the sensor's principal point (px, pixel centres at +0.5; null = the sensor's centre),
    # moved by a uniform +-principal_jitter_px in x and y
    principal_point_px: tuple[float, float] | None = None
    principal_jitter_px: float = setting(0.0, ge=0, le=100_000)
    # pinhole: the full sensor (width, height px) when the image is a crop of it around the eye
    # (webcam); null = the image is the whole sensor
    sensor_px: tuple[int, int] | None = setting(None, ge=8, le=100_000)
    # pinhole: where the camera looks: the imaged eye's centre, or the midpoint of both eyeball
    # centres (a webcam facing the face); plus the center_jitter_mm shift in both cases
    camera_aim: Literal["eye", "between_eyes"] = "eye"
    # pinhole with sensor_px: the crop's offset moves the eye up to this many px off the crop centre
    crop_jitter_px: float = setting(0.0, ge=0, le=100_000)
    # orthographic: every landmark and the whole iris ring at least this many px inside the image
    # (the drawn shift moved, the scale widened up to ortho_scale_mm's top; pipeline/render/sampling.py
    # frame_fit); null = partial crops allowed (the framing as drawn). Not used by a pinhole camera
    # or with iris_distance_px (their framing is their own): frames_the_eye()
    frame_margin_px: float | None = setting(None, ge=0, le=1000)
    # label files per image, one module each in pipeline/render/formats/ (eyerig: NNNNNN.json, always)
    label_formats: tuple[Literal[LABEL_FORMATS], ...] = setting((REQUIRED_FORMAT,), min_len=1,
                                                               max_len=len(LABEL_FORMATS))
    # label format normalized (pipeline/render/formats/normalized.py): ETH-XGaze's normalised eye crop, a
    # virtual camera of this focal length (px) this far (mm) from the eye centre (eyeball: its rotation
    # centre; canthi: the eye corners' midpoint); ETH-XGaze's eye crops 128 x 128, 1800 px, 600 mm;
    # MPIIGaze's [60, 36], 960 px, 600 mm
    normalized_size_px: tuple[int, int] = setting((128, 128), ge=8, le=4096)
    normalized_focal_px: float = setting(1800.0, gt=0, le=1_000_000)
    normalized_distance_mm: float = setting(600.0, gt=0, le=100_000)
    normalized_center: Literal["eyeball", "canthi"] = "eyeball"
    # dataset splits by identity (pipeline/render/splits.py): train, val, test proportions of the assets
    # and the seed of their order; they change no image (not hashed: a re-run rewrites DIR/splits/)
    splits: tuple[float, float, float] = setting((0.8, 0.1, 0.1), ge=0, le=1_000_000)
    split_seed: int = setting(0, ge=0, le=2**63 - 1)
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
    tar_images: int = setting(1000, ge=1, le=MAX_IMAGES)  # images per shard of label format webdataset
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
        if self.camera == "pinhole":
            self._validate_pinhole()
        else:
            for k in PINHOLE_KEYS[1:]:
                if getattr(self, k) != type(self).__dataclass_fields__[k].default:
                    raise SettingError(k, f"is a pinhole setting: it needs camera: pinhole (got {getattr(self, k)!r} "
                                          "with camera: ortho)")
            if isinstance(self.camera_distance_mm, tuple):
                raise SettingError("camera_distance_mm", "must be one value with camera: ortho (the orthographic "
                                                         "image does not depend on it; a range needs camera: pinhole)")
        if self.camera == "ortho" and self.width < self.height:
            raise SettingError("width", f"must be >= height (orthographic scale = image width; got "
                                        f"{self.width} x {self.height})")
        if sum(self.splits) <= 0:
            raise SettingError("splits", f"must give a positive proportion to one split at least (got {list(self.splits)})")
        if any(not h.endswith(".exr") for h in self.hdris):
            raise SettingError("hdris", "must be a list of .exr names")
        if self.iris_distance_px is not None and self.center_jitter_mm != 0:
            raise SettingError("center_jitter_mm", "must be 0 with iris_distance_px (GazeML's loader takes the "
                                                   "image centre for the eyeball centre); with preset unityeyes, "
                                                   "drop the explicit center_jitter_mm, width, height, eyes and "
                                                   f"camera_distance_mm or set them (got {self.center_jitter_mm:g})")
        if REQUIRED_FORMAT not in self.label_formats or len(set(self.label_formats)) < len(self.label_formats):
            raise SettingError("label_formats", f"must list {REQUIRED_FORMAT} (its label marks an image done) and "
                                                f"each format once (got {list(self.label_formats)})")
        if not self.masks and needs_masks(self.label_formats):
            raise SettingError("masks", f"must be true for label format {', '.join(needs_masks(self.label_formats))} "
                                        "(it reads the masks and landmark visibility)")
        # GazeML's loader hard-codes the framing (formats/unityeyes.py): anything else misplaces its iris centre
        if (self.camera == "ortho" and "unityeyes" in self.label_formats
                and self.iris_distance_px != GAZEML_EYEBALL_RADIUS_PX):
            lo, hi = self.ortho_scale_mm
            framing = (f"iris_distance_px {self.iris_distance_px:g}" if self.iris_distance_px is not None else
                       f"ortho_scale_mm {lo:g}-{hi:g} at {self.width} x {self.height} px with a "
                       f"{self.center_jitter_mm:g} mm shift")
            raise SettingError("label_formats", "lists unityeyes, which needs GazeML's framing (eyeball centre at the "
                                                f"image centre, iris centre {GAZEML_EYEBALL_RADIUS_PX} px from it, its "
                                                f"crop of 1.5 eye widths inside the image): preset {self.preset} "
                                                f"frames {framing}; use preset unityeyes, or set iris_distance_px: "
                                                f"{GAZEML_EYEBALL_RADIUS_PX}, center_jitter_mm: 0 and width x height "
                                                f">= 320 x 240")

    def _validate_pinhole(self) -> None:
        """Cross-field checks of a pinhole camera (one line each, naming the key)."""
        if self.focal_px is None:
            raise SettingError("focal_px", "must be set with camera: pinhole (the sensor's focal length in px, "
                                           "one value or a [low, high] range)")
        dist = self.camera_distance_mm
        if (dist[0] if isinstance(dist, tuple) else dist) < MIN_PINHOLE_DISTANCE_MM:
            raise SettingError("camera_distance_mm", f"must be >= {MIN_PINHOLE_DISTANCE_MM:g} mm with camera: pinhole (the "
                                                     f"cornea's apex is ~13 mm from the eyeball centre; got "
                                                     f"{list(dist) if isinstance(dist, tuple) else dist})")
        if self.iris_distance_px is not None:
            raise SettingError("iris_distance_px", "needs camera: ortho (it sets the orthographic scale)")
        if "unityeyes" in self.label_formats:
            raise SettingError("label_formats", "unityeyes needs camera: ortho (GazeML's UnityEyes loader assumes "
                                                "UnityEyes' orthographic framing)")
        sw, sh = self.sensor_px or (self.width, self.height)
        if sw < self.width or sh < self.height:
            raise SettingError("sensor_px", f"must be at least the image size {self.width} x {self.height} "
                                            f"(the image is a crop of the sensor; got {sw} x {sh})")
        if self.crop_jitter_px and self.sensor_px is None:
            raise SettingError("crop_jitter_px", "needs sensor_px (the image is a crop of a larger sensor)")
        cx, cy = self.principal_point_px or (sw / 2.0, sh / 2.0)
        j = self.principal_jitter_px
        if not (0 < cx - j and cx + j < sw and 0 < cy - j and cy + j < sh):
            raise SettingError("principal_point_px", f"[{cx:g}, {cy:g}] +- principal_jitter_px {j:g} must lie inside "
                                                     f"the {sw} x {sh} px sensor")

    def frames_the_eye(self) -> bool:
        """Whether the framing rule applies: ``frame_margin_px`` set, an orthographic camera free to
        move (not ``iris_distance_px``, whose framing GazeML's loader fixes); a pinhole camera's
        framing is its own (a preset's margin, e.g. generic's under ``camera: pinhole``, is not used)."""
        return self.frame_margin_px is not None and self.camera == "ortho" and self.iris_distance_px is None

    def hashed(self) -> dict:
        """The settings that change images or labels (not n_images: sample i ignores it; not how to run;
        not the pinhole keys of an orthographic render; not an unset frame_margin_px)."""
        skip = {"n_images", "presets", *RUN_KEYS, *SPLIT_KEYS, *(PINHOLE_KEYS if self.camera == "ortho" else ()),
                # unset or not applied, the framing rule is absent: such renders keep the hash they had before it
                *(() if self.frames_the_eye() else ("frame_margin_px",)),
                *(() if "normalized" in self.label_formats else NORMALIZED_KEYS)}
        d = {k: getattr(self, k) for k in self.keys() if k not in skip}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def parse_overrides(items) -> dict:
    """``KEY=VALUE`` strings (``--set``) -> ``{key: value}``, each value read as YAML with
    params.yaml's rules (:func:`pipeline.io.strict_yaml.load_strict`).

    Raises
    ------
    ScanError
        One line naming ``--set``: no ``=``, a repeated key inside a value, or no YAML value.
    """
    import yaml

    from pipeline.errors import ScanError
    from pipeline.io.strict_yaml import DuplicateKeyError, load_strict

    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ScanError("--set", f"{item!r} is not KEY=VALUE")
        try:
            out[key] = load_strict(value)
        except DuplicateKeyError as exc:
            raise ScanError("--set", f"{key}: {exc}") from None
        except yaml.YAMLError:
            raise ScanError("--set", f"{key}: {value!r} is not a YAML value") from None
    return out
