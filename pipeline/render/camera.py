"""Camera math of a render: frames, the orthographic and pinhole projections and the eye-frame angles.

Frames (labels, pipeline/render/labels.py): head frame mm; camera frame OpenGL/Blender (the
camera looks down -Z, +Y up in the image, +X right, ``p_cam = world_to_camera @ [p_head, 1]``);
image pixels with the origin at the top-left pixel corner and pixel centres at +0.5
(``[u, v, 1] ~ projection @ [p_cam, 1]``). An eye frame is the rows ``e_x, e_y, forward`` of
:func:`pipeline.io.eyes_file.eye_basis`: pitch positive = up, yaw positive = toward ``e_x``
(head +X, the subject's left). Rotations are 3x3 matrices or quaternions ``(w, x, y, z)``.

Two camera kinds (:data:`CAMERA_KINDS`): ``ortho`` (image width ``ortho_scale_mm``) and
``pinhole``: intrinsics ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` (square pixels, no skew, no
distortion) in the same pixel convention, applied to OpenCV camera axes (x right, y down, z
forward = :data:`GL_TO_CV` of the OpenGL axes): ``[u, v, 1] ~ K @ GL_TO_CV @ p_cam``. A centred
principal point is ``(W / 2, H / 2)``; OpenCV's own pixel convention (centres at integers) is
``K`` with ``cx - 0.5, cy - 0.5`` (:func:`opencv_pixel_K`). A crop at integer offset ``(x0, y0)``
of a sensor image has ``K_crop = K_sensor`` with ``cx - x0, cy - y0`` (:func:`crop_intrinsics`).
:class:`Camera` is a camera of either kind, read once from whatever describes it (the worker
spec's wire layout, a label's camera block: :meth:`Camera.from_dict`); it projects
(:meth:`Camera.project`) and gives the camera ray of a pixel (:meth:`Camera.pixel_rays`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CAMERA_KINDS = ("ortho", "pinhole")
#: OpenGL/Blender camera axes (x right, y up, looking down -z) -> OpenCV's (x right, y down, z forward).
GL_TO_CV = np.diag([1.0, -1.0, -1.0])


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


def quat_to_matrix(q) -> np.ndarray:
    """(3, 3) rotation of a quaternion ``(w, x, y, z)`` (normalised first).

    Raises
    ------
    ValueError
        Not 4 finite numbers, or the zero quaternion.
    """
    q = np.asarray(q, float)
    n = np.linalg.norm(q) if q.shape == (4,) else float("nan")
    if not np.isfinite(n) or n < 1e-9:
        raise ValueError(f"bad quaternion {q.tolist()}")
    w, x, y, z = q / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


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


def intrinsics(focal_px: float, cx: float, cy: float) -> np.ndarray:
    """(3, 3) pinhole ``K`` (square pixels, no skew; pixel centres at +0.5, as the labels' px)."""
    return np.array([[float(focal_px), 0.0, float(cx)], [0.0, float(focal_px), float(cy)], [0.0, 0.0, 1.0]])


def crop_intrinsics(K_sensor, offset_px) -> np.ndarray:
    """(3, 3) ``K`` of the crop whose top-left pixel is sensor pixel ``offset_px = (x0, y0)``:
    the same focal length, the principal point moved by ``-(x0, y0)``."""
    K = np.array(K_sensor, float)
    K[0, 2] -= float(offset_px[0])
    K[1, 2] -= float(offset_px[1])
    return K


def opencv_pixel_K(K) -> np.ndarray:
    """``K`` in OpenCV's pixel convention (pixel centres at integers): ``cx - 0.5, cy - 0.5``."""
    Kc = np.array(K, float)
    Kc[:2, 2] -= 0.5
    return Kc


def pinhole_projection_matrix(K) -> np.ndarray:
    """(3, 4) OpenGL camera mm -> homogeneous pixels: ``K @ [GL_TO_CV | 0]``."""
    return np.asarray(K, float) @ np.hstack([GL_TO_CV, np.zeros((3, 1))])


def opencv_extrinsics(world_to_camera) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) of OpenCV camera axes: ``p_cv = R @ p_head + t`` (x right, y down, z forward)."""
    M = np.asarray(world_to_camera, float)
    return GL_TO_CV @ M[:3, :3], GL_TO_CV @ M[:3, 3]


def project_pinhole(points_cam, K) -> np.ndarray:
    """(n, 2) pixels of OpenGL camera-frame points (in front of the camera: z < 0) through ``K``."""
    P = np.asarray(points_cam, float)
    H = np.concatenate([P, np.ones((len(P), 1))], 1) @ pinhole_projection_matrix(K).T
    return H[:, :2] / H[:, 2:]


def _need(cond: bool, message: str) -> None:
    if not cond:
        raise ValueError(message)


def _matrix(x, shape: tuple, key: str) -> np.ndarray:
    try:
        M = np.asarray(x, float)
    except (TypeError, ValueError):
        raise ValueError(f"{key} must be {shape[0]} x {shape[1]} numbers, got {x!r}") from None
    _need(M.shape == shape and bool(np.all(np.isfinite(M))), f"{key} must be {shape[0]} x {shape[1]} finite numbers")
    return M


@dataclass(frozen=True)
class Camera:
    """The camera of one image: ``world_to_camera`` (4, 4) head mm -> camera mm (OpenGL axes),
    and exactly one of the image width in mm (``ortho_scale_mm``: orthographic) or the
    intrinsics ``K`` (3, 3: pinhole, square pixels, no skew; pixels as in the labels, centres
    at +0.5). Matrices are kept as nested lists, the values the wire carries.

    Wire layout (the worker's spec, pipeline/render/spec.py; :meth:`to_dict`):
    ``{"world_to_camera", "ortho_scale_mm"}`` or ``{"type": "pinhole", "world_to_camera", "K"}``.
    :meth:`from_dict` also reads a label's ``camera`` block (pipeline/render/labels.py:
    ``type`` ``orthographic`` with ``ortho_scale_mm``, or ``pinhole`` with ``intrinsics.K``) and
    any mapping of these keys (a sample's camera dict, a job dict).

    Raises
    ------
    ValueError
        Naming the problem: a matrix of the wrong shape or not finite, both or neither of
        ``ortho_scale_mm`` and ``K``, a scale <= 0, a ``K`` Blender's camera cannot be (skew,
        two focal lengths).
    """

    world_to_camera: list
    ortho_scale_mm: float | None = None
    K: list | None = None

    def __post_init__(self):
        for k in ("world_to_camera", "K"):
            # arrays become the lists that a caller would have written on the wire (tolist() is exact)
            if isinstance(getattr(self, k), np.ndarray):
                object.__setattr__(self, k, getattr(self, k).tolist())
        _matrix(self.world_to_camera, (4, 4), "camera.world_to_camera")
        _need((self.ortho_scale_mm is None) != (self.K is None),
              "camera needs exactly one of ortho_scale_mm and K, got "
              + ("both" if self.K is not None else "neither"))
        if self.K is None:
            try:
                s = float(self.ortho_scale_mm)
            except (TypeError, ValueError):
                raise ValueError(f"camera.ortho_scale_mm must be a number, got {self.ortho_scale_mm!r}") from None
            _need(math.isfinite(s), f"camera.ortho_scale_mm must be finite, got {self.ortho_scale_mm!r}")
            _need(s > 0, "camera.ortho_scale_mm must be > 0")
            return
        K = _matrix(self.K, (3, 3), "camera.K")
        _need(K[0, 0] > 0, f"camera.K focal length must be > 0, got {K[0, 0]:g}")
        # Blender's camera has one focal length (square pixels) and no skew
        _need(bool(K[1, 1] == K[0, 0] and K[0, 1] == 0 and K[1, 0] == 0 and np.all(K[2] == [0, 0, 1])),
              "camera.K must be [[f, 0, cx], [0, f, cy], [0, 0, 1]] (square pixels, no skew)")

    @property
    def kind(self) -> str:
        """``ortho`` | ``pinhole`` (:data:`CAMERA_KINDS`)."""
        return "ortho" if self.K is None else "pinhole"

    def to_dict(self) -> dict:
        """The wire layout (class doc)."""
        if self.K is None:
            return {"world_to_camera": self.world_to_camera, "ortho_scale_mm": self.ortho_scale_mm}
        return {"type": "pinhole", "world_to_camera": self.world_to_camera, "K": self.K}

    @classmethod
    def from_dict(cls, cam) -> "Camera":
        """A camera from its wire layout or a label's ``camera`` block (class doc); other keys
        are ignored. ``type`` (``ortho`` | ``orthographic`` | ``pinhole``) may be absent: then a
        ``K`` (or ``intrinsics.K``) makes it pinhole."""
        _need(isinstance(cam, dict), "camera must be a JSON object")
        kind = cam.get("type")
        _need(kind in (None, "ortho", "orthographic", "pinhole"),
              f"camera.type {kind!r} not in ('ortho', 'orthographic', 'pinhole')")
        K = cam.get("K")
        if K is None and isinstance(cam.get("intrinsics"), dict):
            K = cam["intrinsics"].get("K")
        scale = cam.get("ortho_scale_mm")
        if kind == "pinhole":
            _need(scale is None, "camera: a pinhole camera has no ortho_scale_mm")
            _need(K is not None, "camera: a pinhole camera needs K")
        elif kind is not None:
            _need(K is None, "camera: an orthographic camera has no K")
            _need(scale is not None, "camera: an orthographic camera needs ortho_scale_mm")
        _need("world_to_camera" in cam, "camera has no world_to_camera")
        return cls(cam["world_to_camera"], scale, K)

    def projection(self, width: int, height: int) -> np.ndarray:
        """(3, 4) OpenGL camera mm -> homogeneous pixels (:func:`projection_matrix` or
        :func:`pinhole_projection_matrix`)."""
        if self.K is None:
            return projection_matrix(self.ortho_scale_mm, width, height)
        return pinhole_projection_matrix(self.K)

    def project(self, points_cam, width: int, height: int) -> np.ndarray:
        """(n, 2) pixels (origin top-left, pixel centres at +0.5) of (n, 3) OpenGL camera-frame mm
        points. A pinhole camera sees only points in front of it (``z < 0``); those behind
        project to mirrored pixels, so mask them first."""
        if self.K is None:
            return project(points_cam, self.ortho_scale_mm, width, height)
        return project_pinhole(points_cam, self.K)

    def pixel_rays(self, px, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """Camera rays of (n, 2) pixel positions: (n, 3) origins and (n, 3) unit directions in the
        OpenGL camera frame (``origin + t * direction``, t > 0, projects to ``px``): orthographic
        rays start on the image plane z = 0 and run along -z, pinhole rays start at the camera
        centre."""
        px = np.atleast_2d(np.asarray(px, float))
        if self.K is None:
            ow, oh = ortho_size(self.ortho_scale_mm, width, height)
            O = np.c_[(px[:, 0] / width - 0.5) * ow, (0.5 - px[:, 1] / height) * oh, np.zeros(len(px))]
            return O, np.broadcast_to([0.0, 0.0, -1.0], O.shape).copy()
        d = np.c_[px, np.ones(len(px))] @ np.linalg.inv(np.asarray(self.K, float)).T @ GL_TO_CV
        return np.zeros((len(px), 3)), d / np.linalg.norm(d, axis=1, keepdims=True)


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
