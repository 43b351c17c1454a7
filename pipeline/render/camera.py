"""Camera math of a render: frames, the orthographic projection and the eye-frame angles.

Frames (labels, pipeline/render/labels.py): head frame mm; camera frame OpenGL/Blender (the
camera looks down -Z, +Y up in the image, +X right, ``p_cam = world_to_camera @ [p_head, 1]``);
image pixels with the origin at the top-left pixel corner and pixel centres at +0.5
(``[u, v, 1] ~ projection @ [p_cam, 1]``). An eye frame is the rows ``e_x, e_y, forward`` of
:func:`pipeline.io.eyes_file.eye_basis`: pitch positive = up, yaw positive = toward ``e_x``
(head +X, the subject's left). Rotations are 3x3 matrices or quaternions ``(w, x, y, z)``.
"""

from __future__ import annotations

import math

import numpy as np


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
