"""Segmentation classes and depth of a render, from its own passes (no bpy).

The class table (:data:`pipeline.io.seg_file.CLASSES`) and the mask and depth files belong to
io; this module holds how a render decides them: the Blender worker
(:mod:`pipeline.blender.seg_passes` writes one coverage AOV channel per class) and the rule below.

How a pixel gets its class: every material writes its class as a coverage value (1 in its
class's channel of two colour AOVs, :data:`AOV_CHANNELS`) at the first surface the camera
ray meets (the view layer's pass alpha threshold is 0, so a transparent coat ends the data
passes too). Cycles writes shader AOVs only before the first non-transparent bounce: seen
through the refractive cornea, the iris and pupil materials write nothing (measured: a glass
sphere over a plane whose material writes an AOV leaves 0 inside the sphere). So the cornea
(and the sclera's tear-film coat) writes what lies behind it itself: its shader refracts the
camera ray with its own shading normal (the refraction its BSDF does, roughness 0,
n = 1.376) and intersects the refracted ray with the posed pupil disc and iris disc (plane,
centre and radius of the evaluated pupil and iris rings of the Inner mesh, set per image):
pupil inside the pupil ring, iris inside the iris ring, sclera elsewhere. The per-pixel values
are coverages (filtered over the pixel like the image); a pixel's class is the class of
largest coverage, background where no surface covers half of it
(:func:`classes_from_coverage`).

Caruncle / inner corner (6): the asset's caruncle faces (``Materials/Caruncle``: the strip that
closes a medial corner standing off the globe, pipeline/geometry/corners.py), and the skin within
:data:`CARUNCLE_RADIUS_MM` of the medial canthus (vertex 0 of the lid loop of each eye) on the
rest mesh -- a per-vertex distance attribute, interpolated over the faces, that moves with the
lids (a corner resting on the eye has no caruncle faces).

Depth (``NNNNNN_depth.exr``, one float32 channel ``Z``): z-depth in camera mm, the distance
along the optical axis from the label's camera origin (``camera.position_head_mm``) to the
first surface the camera ray meets (skin, lashes, or the outer eye surface: the cornea and
tear film, not the iris behind them), i.e. ``-z`` of that point in the label's camera frame
(OpenGL axes, the camera looks down -Z); ``inf`` where the ray meets nothing. Cycles' Z pass
is this distance from the Blender camera, in metres, which sits ``CAMERA_PULLBACK_M`` behind
the label's camera (:func:`depth_mm_from_z`). Written at the first sample of each pixel (not
filtered).
"""

from __future__ import annotations

import numpy as np

from pipeline.io.seg_file import BACKGROUND, CARUNCLE, CLASSES, IRIS, LASHES, PUPIL, SCLERA, SKIN

RULE = ("class of the first surface the camera ray meets, iris and pupil as seen through the cornea "
        "(the cornea's shader refracts the ray onto the posed pupil and iris discs); caruncle = the asset's "
        "caruncle faces and skin within 2.5 mm of the medial canthus; majority coverage per pixel, background below half; "
        "pipeline/render/seg.py")
#: The two colour AOVs the materials write: class id of each (R, G, B) channel.
AOV_CHANNELS = {"eyerig_seg_a": (SKIN, SCLERA, IRIS), "eyerig_seg_b": (PUPIL, LASHES, CARUNCLE)}
CARUNCLE_RADIUS_MM = 2.5
#: A pixel whose covered fraction is below this is background.
MIN_COVERAGE = 0.5


def classes_from_coverage(coverage: dict) -> np.ndarray:
    """(H, W) uint8 class ids from per-class coverage images.

    Parameters
    ----------
    coverage : dict  class id -> (H, W) float coverage in [0, 1] (classes 1..6; missing = 0)

    Returns
    -------
    (H, W) uint8: the class of largest coverage (ties: the lower id); background (0) where
    the covered fraction (sum over classes) is below :data:`MIN_COVERAGE`.
    """
    shape = next(iter(coverage.values())).shape
    stack = np.zeros((len(CLASSES),) + shape, np.float32)
    for k, v in coverage.items():
        stack[int(k)] = np.clip(np.nan_to_num(np.asarray(v, np.float32)), 0.0, None)
    covered = stack[1:].sum(0)
    cls = np.argmax(stack[1:], axis=0).astype(np.uint8) + 1
    cls[covered < MIN_COVERAGE] = BACKGROUND
    return cls


def depth_mm_from_z(z_m, scale_m_per_mm: float, pullback_m: float) -> np.ndarray:
    """(H, W) float32 label depth (mm) from Cycles' Z pass (metres from the Blender camera).

    ``depth = (Z - pullback) / scale``; ``inf`` where Cycles saw nothing (Z >= 1e9 m).
    """
    z = np.asarray(z_m, np.float64)
    d = (z - float(pullback_m)) / float(scale_m_per_mm)
    d[~np.isfinite(z) | (z >= 1e9)] = np.inf
    return d.astype(np.float32)
