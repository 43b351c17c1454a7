"""Does the asset cover the whole frame? A scanline rasteriser of triangles, run per sample attempt.

A render shows background (segmentation class 0, :func:`pipeline.render.seg.classes_from_coverage`)
where less than half of a pixel's filtered samples meet a surface. The sampler
(:func:`pipeline.render.sampling.make_sample`) redraws an attempt whose camera would see past the
asset, so the test must be cheap and must not miss a visible gap:

* What covers: the posed eye-region skin (the ``EyeRegion`` triangles, posed with the sample's
  lid weights) and both eyeballs, each as the polygon inscribed in its silhouette (the sphere of
  the eye's radius; the cornea bulges beyond it, so leaving it out can only under-count
  coverage). Lashes are left out the same way. Back faces count (Blender renders them).
* Where: every pixel's whole filter footprint, plus a safety margin. Cycles' pixel filter
  (Blackman-Harris, ``film_filter_width`` 1.5 px, left at Blender's default in
  pipeline/blender/) spreads a pixel's samples up to :data:`FILTER_RADIUS_PX` from its centre, so
  the pixels of a ``W x H`` image draw samples from ``[0.5 - r, W - 0.5 + r]`` and likewise in y;
  the test region is that rectangle grown by :data:`SAFETY_PX` on each side
  (:data:`MARGIN_PX` beyond the image edges).
* How: the region is cut into rows ``ROW_STEP_PX`` apart; each triangle crossing a row covers
  one exact x-interval of it; the intervals of a row are merged (sorted, running maximum) and
  the row is covered when one merged interval spans the region's width (gaps below
  :data:`GAP_TOL_PX`, rounding between triangles sharing an edge, are closed). A gap thinner than
  the row step (0.5 px) leaves more than half of any pixel's 1.5 px footprint covered, so the
  majority rule still gives that pixel a class. The answer is the uncovered area in px^2
  (uncovered row length x row step); 0 means no background.

Cameras: the rasteriser takes a projection function of camera-frame points (OpenGL axes, the
camera looks down -Z) to pixels, so it serves the orthographic camera
and the pinhole one (:meth:`pipeline.render.camera.Camera.project`). A perspective projection maps
triangles to triangles only when all three vertices are in front of the camera: with ``near_mm``
set, a triangle with a vertex nearer than that (``z > -near_mm``) is refused (it covers nothing,
which can only under-count coverage); sphere silhouettes are then the cone's tangent circle.
"""

from __future__ import annotations

import math

import numpy as np

# the scanline rasteriser itself is geometry's (the rig's lid check uses it too); render reads it here
from pipeline.geometry.raster import GAP_TOL_PX, covered_points, merged_spans, row_spans  # noqa: F401
from pipeline.render import asset as ra
from pipeline.render.camera import to_camera

#: Cycles' default pixel filter width is 1.5 px: samples reach 0.75 px from the pixel centre.
FILTER_RADIUS_PX = 0.75
#: Extra margin beyond the footprints (rounding of the rasteriser against Cycles' own).
SAFETY_PX = 0.5
#: Test region beyond each image edge: footprint overhang (r - 0.5) plus the safety margin.
MARGIN_PX = FILTER_RADIUS_PX - 0.5 + SAFETY_PX
ROW_STEP_PX = 0.5
#: Vertices of the polygon inscribed in an eyeball's silhouette (radius short by 1 - cos(pi/n)).
SPHERE_SEGMENTS = 48


# ---------------------------------------------------------------------------- rasteriser

def uncovered_area(tri_px, x0: float, x1: float, y0: float, y1: float, step: float = ROW_STEP_PX,
                   tol: float = GAP_TOL_PX) -> float:
    """Area (px^2, as rows ``step`` apart times uncovered length) of the rectangle
    ``[x0, x1] x [y0, y1]`` that the triangles ``tri_px`` (T, 3, 2) leave uncovered; 0 when the
    union of the triangles covers every row."""
    ys = np.arange(y0, y1 + 0.5 * step, step)
    ys = ys[ys <= y1 + 1e-9]
    r, lo, hi = merged_spans(*row_spans(tri_px, ys), x0, x1, tol)
    covered = np.bincount(r, weights=hi - lo, minlength=len(ys))
    gap = np.maximum((x1 - x0) - covered, 0.0)
    gap[gap <= tol] = 0.0
    return float(gap.sum() * step)


# ---------------------------------------------------------------------------- the frame

def frame_region(width: int, height: int, margin_px: float = MARGIN_PX) -> tuple[float, float, float, float]:
    """(x0, x1, y0, y1): the image ``[0, W] x [0, H]`` grown by ``margin_px`` on each side."""
    return -margin_px, float(width) + margin_px, -margin_px, float(height) + margin_px


def sphere_silhouette(center_cam, radius: float, perspective: bool = False,
                      n: int = SPHERE_SEGMENTS) -> np.ndarray:
    """(n, 3, 3) camera-frame triangles filling the polygon inscribed in a sphere's silhouette.

    Orthographic (camera looking down -Z): the great circle in the plane ``z = c_z``. Perspective
    (centre of projection at the origin): the circle where the cone from the origin touches the
    sphere, centre ``c (1 - r^2/|c|^2)``, radius ``r sqrt(1 - r^2/|c|^2)``; empty when the origin
    is inside the sphere. The polygon's corners lie on the silhouette, so its image lies inside
    the sphere's image (a chord is a straight line under either projection).
    """
    c = np.asarray(center_cam, np.float64)
    if perspective:
        d2 = float(c @ c)
        if d2 <= radius * radius:
            return np.zeros((0, 3, 3))
        k = 1.0 - radius * radius / d2
        centre, rad = c * k, radius * math.sqrt(k)
        axis = c / math.sqrt(d2)
    else:
        centre, rad, axis = c, float(radius), np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    ring = centre + rad * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
    return np.stack([np.broadcast_to(centre, ring.shape), ring, np.roll(ring, -1, axis=0)], axis=1)


def frame_uncovered(tris_cam, project, width: int, height: int, near_mm: float | None = None,
                    margin_px: float = MARGIN_PX, step: float = ROW_STEP_PX) -> float:
    """Uncovered area (px^2) of the frame's test region (:func:`frame_region`).

    Parameters
    ----------
    tris_cam : (T, 3, 3) float   camera-frame triangles (mm, OpenGL axes)
    project : callable           (n, 3) camera points -> (n, 2) pixels
    width, height : int          image size
    near_mm : float | None       perspective cameras: triangles with a vertex at ``z > -near_mm``
                                 are refused (None: orthographic, every triangle projects)
    """
    T = np.asarray(tris_cam, np.float64).reshape(-1, 3, 3)
    if near_mm is not None:
        T = T[np.all(T[:, :, 2] < -float(near_mm), axis=1)]
    P = np.asarray(project(T.reshape(-1, 3)), np.float64).reshape(-1, 3, 2)
    x0, x1, y0, y1 = frame_region(width, height, margin_px)
    # triangles wholly outside the region cannot cover it
    inside = ((P[:, :, 0].max(1) >= x0) & (P[:, :, 0].min(1) <= x1)
              & (P[:, :, 1].max(1) >= y0) & (P[:, :, 1].min(1) <= y1))
    return uncovered_area(P[inside], x0, x1, y0, y1, step)


# ---------------------------------------------------------------------------- a sample's scene

def scene_triangles(asset, lid_weights: dict, world_to_camera, perspective: bool = False) -> np.ndarray:
    """(T, 3, 3) camera-frame triangles of what covers a frame: the posed skin (``asset.skin_faces``)
    and both eyeballs' inscribed silhouettes (:func:`sphere_silhouette`)."""
    if asset.skin_faces is None:
        raise ValueError(f"{asset.name}: the render asset carries no skin faces (load it with load_render_asset)")
    V = to_camera(ra.posed_skin(asset, lid_weights), world_to_camera)
    parts = [V[asset.skin_faces]]
    for side in ra.SIDES:
        eye = asset.eyes[side]
        c = to_camera(eye.center[None], world_to_camera)[0]
        parts.append(sphere_silhouette(c, eye.radius, perspective))
    return np.concatenate(parts)


#: Pinhole cameras: a skin triangle with a vertex nearer than this (mm along the view) is refused.
NEAR_MM = 1.0


def sample_uncovered(asset, smp, width: int, height: int) -> float:
    """Uncovered area (px^2) of a sample (:class:`pipeline.render.sampling.Sample`), either camera
    kind (the camera of the sample's spec, :class:`pipeline.render.camera.Camera`).

    With true displacement (``skin_detail`` ``displacement``) the skin's border moves by up to
    the asset's displacement amplitude, so the margin grows by that many pixels.
    """
    camera = smp.spec.camera
    perspective = camera.kind == "pinhole"
    margin = MARGIN_PX
    if smp.spec.quality.skin_detail == "displacement":
        margin += float(asset.displacement_amplitude_mm) / float(smp.camera["mm_per_px"])
    tris = scene_triangles(asset, smp.spec.lid_weights, camera.world_to_camera, perspective)
    return frame_uncovered(tris, lambda P: camera.project(P, width, height), width, height,
                           near_mm=NEAR_MM if perspective else None, margin_px=margin)
