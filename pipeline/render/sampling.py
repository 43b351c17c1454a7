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
   **Pinhole** (``camera: pinhole``, :func:`pinhole_camera`): the camera centre is
   ``c + distance * d`` (distance uniform in ``camera_distance_mm``), so eye contact is exactly
   ``d``; it looks at ``c`` (``camera_aim: eye``) or at the midpoint of both eyeball centres
   (``between_eyes``), shifted by the in-plane ``center_jitter_mm``; the same up. Focal length
   uniform in ``focal_px``; the sensor's principal point ``principal_point_px`` (default its
   centre) plus a uniform ``+-principal_jitter_px``; with ``sensor_px`` the image is the window
   of the sensor image whose whole-pixel offset centres the eyeball centre (plus a uniform
   ``+-crop_jitter_px``, clipped to the sensor), and its ``K`` is the sensor's with the
   principal point moved by the offset. These draws follow all the others, so an orthographic
   sample is drawn as before.
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
   pitch of both eyes (:func:`pipeline.rig.lids.pitch_from_gaze`), the asset's rule; and where
   the asset has them (its ``yaw_rule``), each eye's ``lids_look_in/out_<side>_*`` channels from
   its own yaw and that lid pitch (:func:`pipeline.rig.yaw_shapes.yaw_weights`).
6. **Eyeball**: iris colour, sclera tint and veins uniform over the asset's variants; one
   pupil value ``s`` uniform in [-1, 1] (``s > 0``: ``pupil_dilate = s``, else
   ``pupil_constrict = -s``) and one iris-size value likewise (``iris_large`` / ``iris_small``).
7. **Lighting**: one of the bundled HDRIs, rotation uniform in [0, 360) deg about head +Y,
   strength uniform in ``strength``.
8. **Framing** (orthographic, ``frame_margin_px`` set: the ``generic`` and ``targeted`` presets):
   every landmark and the whole iris ring (the circle through the 8 iris landmarks) must lie at
   least ``frame_margin_px`` inside the image (:func:`frame_fit`). The drawn shift is moved the
   least that brings them inside, and when they span more than the image allows the orthographic
   scale is widened as far as the top of ``ortho_scale_mm``; an eye that does not fit even then
   is drawn again (``attempt + 1``). Camera direction, gaze, lids, eyeball and lighting are the
   draw's own: only the framing moves. ``frame_margin_px: null`` leaves partial crops possible.
9. **Rejection**: if the projected pupil centre is outside the projected eyelid polygon (the
   posed lid loop of the imaged eye) or outside the polygon of the label's 12 eyelid
   landmarks (:func:`pupil_in_lids`), or if the camera sees past the asset (any pixel's filter
   footprint not covered by the posed skin and the eyeballs: background,
   :mod:`pipeline.render.coverage`), the sample is redrawn with ``attempt + 1``; the number
   of attempts is stored.

**Skin detail** (:func:`choose_skin_detail`): with ``p = ortho_scale_mm / width`` (mm per
pixel; pinhole: the median depth of the 28 landmarks / focal length), ``a`` = the 99th percentile of the baked |displacement| and ``e`` = the median edge
length of the low-poly skin: ``displacement`` when ``a >= p / 2`` (the relief moves
silhouettes and occlusions by half a pixel or more: real geometry needed); else ``bump`` when
``e > p`` (polygons span more than a pixel, so the map's shading detail is resolved); else
``none`` (relief and polygons are both below a pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.eyeball.textures import IRIS_COLORS, VEINS
from pipeline.eyeball.textures import SCLERA_TINTS as _SCLERA_TINTS
from pipeline.render import asset as ra
from pipeline.render import coverage
from pipeline.render import formats
from pipeline.render.camera import (Camera, crop_intrinsics, direction_from_angles, eye_angles, intrinsics, look_at, matrix_to_quat,
                                     ortho_size, point_in_polygon, project_pinhole, rotation_between, to_camera)
from pipeline.render.settings import RenderSettings
from pipeline.render.spec import EyeConfiguration, Lighting, Quality, RenderSpec
from pipeline.rig import landmarks as lmk
from pipeline.rig import lids
from pipeline.rig import yaw_shapes

#: Fallbacks when an asset names no variants (the eyeball asset's own, in sampling order).
SCLERA_TINTS = tuple(sorted(_SCLERA_TINTS))


# ----------------------------------------------------------------------------- the sample

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


@dataclass
class Sample:
    """One posed sample: the worker spec plus what the labels need."""

    index: int
    attempts: int
    spec: RenderSpec
    side: str
    camera: dict            # world_to_camera (4,4), ortho_scale_mm | K (pinhole_camera), position_mm, polar/azimuth
    gaze: dict              # per side: vector, pitch/yaw in eye frame, clipped flag, offsets
    lid_pitch_deg: float
    landmarks_head: np.ndarray   # (28, 3)
    landmarks_cam: np.ndarray    # (28, 3)
    landmarks_px: np.ndarray     # (28, 2)
    pupil_center_px: np.ndarray  # (2,)
    lid_polygon_px: np.ndarray   # (L, 2)
    eye_geometry: dict           # per side: centre (head, camera, px), radius, centre to iris plane (label eyes.<side>)


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
    if s.camera == "pinhole":          # drawn after the orthographic draws, which stay as they were
        d["distance_mm"] = float(rng.uniform(*_range(s.camera_distance_mm)))
        d["focal_px"] = float(rng.uniform(*_range(s.focal_px)))
        d["principal_shift_px"] = rng.uniform(-1.0, 1.0, size=2) * s.principal_jitter_px
        d["crop_shift_px"] = rng.uniform(-1.0, 1.0, size=2) * s.crop_jitter_px
    d.update({k: v for k, v in o.items() if not k.startswith("_")})
    return d


def _range(v) -> tuple[float, float]:
    """``(low, high)`` of a setting that is one value or a [low, high] range."""
    return (float(v[0]), float(v[1])) if isinstance(v, tuple) else (float(v), float(v))


def pinhole_camera(asset: ra.RenderAsset, s: RenderSettings, side: str, view, d: dict) -> dict:
    """The pinhole camera of one attempt (rule in the module doc): world_to_camera, the image's
    ``K``, the sensor's ``K_sensor`` and the crop offset, from the draws ``d``."""
    eye = asset.eyes[side]
    pos = eye.center + d["distance_mm"] * np.asarray(view, float)
    aim = eye.center if s.camera_aim == "eye" else 0.5 * (asset.eyes["left"].center + asset.eyes["right"].center)
    W2C0 = look_at(pos, aim, eye.basis[1])
    shift = W2C0[0, :3] * d["jitter"][0] + W2C0[1, :3] * d["jitter"][1]
    W2C = look_at(pos, aim + shift, eye.basis[1])
    sw, sh = s.sensor_px or (s.width, s.height)
    cx, cy = s.principal_point_px or (sw / 2.0, sh / 2.0)
    K_sensor = intrinsics(d["focal_px"], cx + d["principal_shift_px"][0], cy + d["principal_shift_px"][1])
    offset = (0, 0)
    if s.sensor_px is not None:        # the crop around the eye: whole pixels of the sensor image
        u = project_pinhole(to_camera(eye.center[None], W2C), K_sensor)[0] + d["crop_shift_px"]
        offset = tuple(int(min(max(math.floor(u[k] - n / 2.0 + 0.5), 0), full - n))
                       for k, (n, full) in enumerate(((s.width, sw), (s.height, sh))))
    return {"type": "pinhole", "world_to_camera": W2C, "K": crop_intrinsics(K_sensor, offset),
            "K_sensor": K_sensor, "sensor_px": [int(sw), int(sh)], "crop_offset_px": [int(offset[0]), int(offset[1])],
            "focal_px": d["focal_px"], "position_mm": pos, "aim": s.camera_aim, "aim_point_mm": aim + shift,
            "distance_mm": d["distance_mm"]}


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


#: Points on the iris ring the framing rule keeps inside the image (with the 28 landmarks).
IRIS_RING_POINTS = 64


def framing_points(L_cam: np.ndarray) -> np.ndarray:
    """(28 + 64, 3) camera-frame points the framing keeps in the image: the 28 landmarks and the
    circle through the 8 iris landmarks (12-19, 45 deg apart: 12 and 14 span a quarter turn), so
    the whole iris ring is inside, not only its 8 landmarks."""
    iris = np.asarray(L_cam[12:20], float)
    c = iris.mean(0)
    u, v = iris[0] - c, iris[2] - c
    t = np.linspace(0.0, 2.0 * math.pi, IRIS_RING_POINTS, endpoint=False)[:, None]
    return np.vstack([L_cam, c + np.cos(t) * u + np.sin(t) * v])


def frame_fit(points_cam: np.ndarray, jitter, scale_mm: float, s: RenderSettings):
    """``(jitter, ortho scale)`` that put ``points_cam`` (camera frame, drawn with the shift
    ``jitter``) at least ``s.frame_margin_px`` inside an orthographic image, changed as little as
    possible: the shift clipped into the interval that fits, the scale widened only when the
    points span more than the image (never above ``s.ortho_scale_mm``'s top). None when they do
    not fit at that top scale.

    An orthographic shift moves every point by the same amount and the scale is a zoom about
    the image centre, so the fit is exact: no iteration, no re-projection."""
    m = float(s.frame_margin_px)
    W, H = float(s.width), float(s.height)
    P = np.asarray(points_cam, float)[:, :2] + np.asarray(jitter, float)     # as seen with no shift
    lo, hi = P.min(0), P.max(0)
    # half extents in px available to the points, over the px-per-mm factor W / scale
    half_px = np.array([W / 2.0 - m, H / 2.0 - m])
    if (half_px <= 0).any():
        return None
    need = float(((hi - lo) / 2.0 * W / half_px).max())          # the smallest scale that fits both axes
    scale = max(float(scale_mm), need)
    if scale > float(s.ortho_scale_mm[1]) * (1 + 1e-12) and need > float(scale_mm):
        return None
    half_mm = half_px * scale / W
    j = np.clip(np.asarray(jitter, float), hi - half_mm, lo + half_mm)
    return j, scale


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
    if s.camera == "pinhole":
        pin = pinhole_camera(asset, s, side, view, d)
        W2C = pin["world_to_camera"]
        cam = Camera(W2C.tolist(), K=pin["K"].tolist())
    else:
        pos0 = eye.center + s.camera_distance_mm * view
        W2C = look_at(pos0, eye.center, B[1])
        # in-plane shift of the framing (camera x/y axes)
        shift = W2C[0, :3] * d["jitter"][0] + W2C[1, :3] * d["jitter"][1]
        pos = pos0 + shift
        W2C = look_at(pos, eye.center + shift, B[1])
        cam = Camera(W2C.tolist(), d["ortho_scale_mm"])

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
    yr = (asset.metadata or {}).get("yaw_rule")
    if yr:      # each eye's lids ride on its cornea as it turns (absent from older assets)
        have = {s.name for s in asset.lid_shapes}
        lw.update({k: v for k, v in yaw_shapes.yaw_weights({sd: gaze[sd]["yaw_eye_deg"] for sd in ra.SIDES},
                                                          lid_pitch, float(yr["max_yaw_deg"])).items() if k in have})
    blend = _blend(d["pupil"], d["iris"])

    L_head = ra.posed_landmarks(asset, side, lw, blend, rots[side])
    L_cam = to_camera(L_head, W2C)
    if s.frames_the_eye() and not (overrides or {}).get("_framed"):
        fit = frame_fit(framing_points(L_cam), d["jitter"], d["ortho_scale_mm"], s)
        if fit is None:
            raise FramingError(f"the eye spans more than a {s.ortho_scale_mm[1]:g} mm wide image with "
                               f"{s.frame_margin_px:g} px margins")
        if not (np.array_equal(fit[0], d["jitter"]) and fit[1] == d["ortho_scale_mm"]):
            # the same draw with the framing moved: the camera's direction, the gaze and all else stay
            return pose_sample(asset, s, index, attempt, png, {**(overrides or {}), "jitter": fit[0],
                                                                "ortho_scale_mm": fit[1], "_framed": True})
    L_px = cam.project(L_cam, s.width, s.height)
    pc_cam = to_camera(ra.pupil_center(asset, side, blend, rots[side])[None], W2C)
    pc_px = cam.project(pc_cam, s.width, s.height)[0]
    poly_px = cam.project(to_camera(ra.posed_lid_polygon(asset, side, lw), W2C), s.width, s.height)
    eye_geometry = _eye_geometry(asset, cam, s, blend)
    if s.camera == "pinhole":          # the footprint of a pixel at the landmarks' median depth
        mm_per_px = float(np.median(-L_cam[:, 2])) / d["focal_px"]
    else:
        mm_per_px = ortho_size(d["ortho_scale_mm"], s.width, s.height)[0] / s.width
    spec = RenderSpec(
        index=int(index), png=str(png), width=int(s.width), height=int(s.height), eye=side,
        camera=cam,
        eye_rotation={sd: gaze[sd]["rotation_wxyz"] for sd in ra.SIDES},
        lid_weights={k: float(v) for k, v in lw.items()},
        eyeball=EyeConfiguration(d["iris_color"], d["sclera_tint"], d["veins"], blend),
        lighting=Lighting(d["hdri"], d["hdri_rotation_deg"], d["strength"]),
        quality=Quality(int(s.samples), bool(s.denoise), d["cycles_seed"],
                        choose_skin_detail(mm_per_px, asset.displacement_amplitude_mm, asset.skin_faces_edge_mm)),
        landmarks_head_mm=L_head.tolist())
    if s.camera == "pinhole":
        camera = {**pin, "polar_deg": d["polar_deg"], "azimuth_deg": d["azimuth_deg"],
                  "jitter_mm": [float(x) for x in d["jitter"]], "gaze_offset_deg": [dp, dy],
                  "eye_contact_eye_deg": [p0, y0], "mm_per_px": mm_per_px}
    else:
        camera = {"world_to_camera": W2C, "ortho_scale_mm": d["ortho_scale_mm"], "position_mm": pos,
                  "polar_deg": d["polar_deg"], "azimuth_deg": d["azimuth_deg"],
                  "distance_mm": float(s.camera_distance_mm), "jitter_mm": [float(x) for x in d["jitter"]],
                  "gaze_offset_deg": [dp, dy], "eye_contact_eye_deg": [p0, y0], "mm_per_px": mm_per_px}
    return Sample(index=int(index), attempts=attempt + 1, spec=spec, side=side, camera=camera, gaze=gaze,
                  lid_pitch_deg=lid_pitch, landmarks_head=L_head, landmarks_cam=L_cam, landmarks_px=L_px,
                  pupil_center_px=pc_px, lid_polygon_px=poly_px, eye_geometry=eye_geometry)


def _eye_geometry(asset: ra.RenderAsset, cam: Camera, s: RenderSettings, blend: dict) -> dict:
    """Per side, what the asset says of the eye (the label's ``eyes.<side>``): its rotation centre
    (the gaze origin) in the head frame, the camera frame and pixels, its radius and the distance
    from the centre to the plane of its iris landmarks (:func:`pipeline.render.asset.iris_plane_distance`);
    ``center_px`` is None for a centre behind a pinhole camera (the other eye, at most)."""
    out = {}
    for sd in ra.SIDES:
        eye = asset.eyes[sd]
        c_cam = to_camera(np.asarray(eye.center, float)[None], cam.world_to_camera)
        seen = cam.kind == "ortho" or c_cam[0, 2] < 0          # a pinhole camera sees only what lies in front of it
        out[sd] = {"center_head_mm": [float(v) for v in eye.center],
                   "center_camera_mm": [float(v) for v in c_cam[0]],
                   "center_px": ([float(v) for v in cam.project(c_cam, s.width, s.height)[0]]
                                 if seen else None),
                   "radius_mm": float(eye.radius),
                   "center_to_iris_plane_mm": ra.iris_plane_distance(eye, blend)}
    return out


def pupil_in_lids(smp: Sample) -> bool:
    """The rejection rule: the projected pupil centre lies inside the posed lid opening and
    inside the polygon of the 12 eyelid landmarks that the label carries (a user who checks the
    rule on the label finds that it holds)."""
    return (point_in_polygon(smp.pupil_center_px, smp.lid_polygon_px)
            and point_in_polygon(smp.pupil_center_px, smp.landmarks_px[:lmk.N_EYELID]))


class FramingError(ValueError):
    """A drawn eye that no shift and no scale within ``ortho_scale_mm`` keeps inside the image's margins."""


class RejectionError(ValueError):
    """No attempt of a sample put the pupil inside the eyelid polygon with the asset covering the frame."""


def make_sample(asset: ra.RenderAsset, s: RenderSettings, index: int, png, overrides: dict | None = None,
                reject: bool = True, cover: bool = True) -> Sample:
    """Sample ``index``: the first attempt whose projected pupil centre is inside the lid polygon
    and whose frame the asset covers (no background: :mod:`pipeline.render.coverage`).
    ``cover=False`` keeps only the pupil rule (label studies that render nothing); the render
    stage always covers.

    Raises
    ------
    RejectionError after ``max_attempts`` rejected attempts (one line naming the asset and preset).
    """
    n_pupil = n_background = n_format = n_frame = 0
    for attempt in range(int(s.max_attempts)):
        try:
            smp = pose_sample(asset, s, index, attempt, str(png), overrides)
        except FramingError:
            if not reject:
                raise
            n_frame += 1
            continue
        if not reject:
            return smp
        if not pupil_in_lids(smp):
            n_pupil += 1
        elif cover and coverage.sample_uncovered(asset, smp, s.width, s.height) > 0:
            n_background += 1
        elif cover and not formats.accepts(asset, smp, s.label_formats):
            n_format += 1                            # e.g. GazeML's crop leaving the image (unityeyes)
        else:
            return smp
    if not (n_background or n_format or n_frame):
        raise RejectionError(f"{asset.name}, preset {s.preset}: sample {index}: pupil outside the eyelid polygon "
                             f"in all {s.max_attempts} attempts")
    wide = f", the eye wider than the widest framing in {n_frame}" if n_frame else ""
    # say what to change: a format's crop (GazeML's 1.5 eye widths) outgrowing the image is the
    # eye's width against the framing, not the asset's extent
    why = ("the eye, canthus to canthus, is too wide for a label format's crop at this framing"
           if n_format >= max(n_background, n_frame) else "the asset's eye region is too small for this framing")
    raise RejectionError(f"{asset.name}, preset {s.preset}: sample {index}: no attempt of {s.max_attempts} "
                         f"is usable (pupil outside the eyelid polygon in {n_pupil}, frame reaching past the "
                         f"asset (background) in {n_background}, a label format's own rule in {n_format}{wide}); "
                         f"{why}")


def png_name(index: int) -> str:
    return f"{int(index):06d}.png"


def tmp_png(out_dir, index: int) -> Path:
    """Where the worker writes image ``index`` (moved into place by the shard runner)."""
    return Path(out_dir).resolve() / ".tmp" / png_name(index)
