"""ETH-XGaze's data normalisation of one rendered image: the warp, the normalised eye crop and its labels.

Gaze models are trained and evaluated on normalised eye crops (Zhang, Sugano and Bulling,
"Revisiting data normalization for appearance-based gaze estimation", ETRA 2018; ETH-XGaze,
ECCV 2020; their code ``xucong-zhang/data-preprocessing-gaze`` ``normalizeData``): a virtual
camera at ``distance_norm`` mm from the eye centre looks at it, its x axis turned toward the
head's x axis, with focal length ``focal_norm`` px and a ``roi`` image. With the eye centre ``e``
in OpenCV camera axes (x right, y down, z forward), ``hR`` the head rotation (face model ->
OpenCV camera, the label's ``conventions.eth_xgaze.head_rotation_opencv``) and ``K`` the
camera's intrinsics (OpenCV pixels, centres at integers)::

    forward = e / |e|,  down = unit(forward x hR[:, 0]),  right = unit(down x forward)
    R = [right; down; forward]                 (rows)
    S = diag(1, 1, distance_norm / |e|)
    K_norm = [[focal_norm, 0, roi_w / 2], [0, focal_norm, roi_h / 2], [0, 0, 1]]
    W = K_norm S R K^-1                         (cv2.warpPerspective(img, W, roi))
    gaze_norm = R g,  hR_norm = R hR            (the gaze is not scaled: the "modified" normalisation)

The normalised landmarks are ``W`` applied to the image's landmarks (``cv2.perspectiveTransform``).
For a pinhole camera that is exactly the virtual camera's view of the 3D landmarks,
``K_norm S R p`` (``S`` only rescales z, so the warp is a homography of the image).

**Orthographic cameras** (the ``generic`` and ``targeted`` presets) have no ``K``: every ray is
parallel to the optical axis, as for a pinhole camera infinitely far away. Their warp is the
formula's limit as the camera recedes along its axis: ``forward`` is the axis (0, 0, 1), so ``R``
is a roll about it, and ``K_norm S R K^-1`` tends to the similarity ``u_n = K_norm-centre +
(focal_norm / distance_norm) R_2x2 (p - e)_xy``, ``p`` the point in camera mm that the pixel shows:
the virtual camera's weak-perspective view (every point at the eye centre's depth). That is
what the warp gives and what the labels say; a true perspective camera at 600 mm would move a
point ``dz`` mm off the eye centre's depth by ``dz / 600`` of its distance from the centre
(at most ~0.3 px of a 128 px crop for the eye region's +-10 mm).

The eye centre is the eyeball's rotation centre (``center: eyeball``, the label's
``eyes.<side>.center_camera_mm``: the gaze origin, so a gaze at the virtual camera puts the pupil
at the crop's principal point and reads (0, 0)) or, as ETH-XGaze's and MPIIGaze's code take it
from a face model, the midpoint of the two eye corners (``center: canthi``, landmarks 0 and 6).

Pixels: ``W`` here (``warp_opencv``) is ETH-XGaze's, between OpenCV pixel coordinates (centres at
integers), so ``cv2.warpPerspective(image, W, roi)`` reproduces the crop; ``warp`` is the same map
between the labels' pixels (centres at +0.5): ``T(+0.5) W T(-0.5)``. The crop is sampled
bilinearly (``cv2.INTER_LINEAR``), the mask by nearest neighbour; pixels whose source lies
outside the rendered image are black in the crop and :data:`OUTSIDE` in the mask.
"""

from __future__ import annotations

import numpy as np

from pipeline.render import conventions as conv
from pipeline.render.camera import Camera, opencv_pixel_K, ortho_size

#: Mask value of a normalised pixel whose source lies outside the rendered image.
OUTSIDE = 255
#: ETH-XGaze's eye crops (its normalisation for eye models) and MPIIGaze's.
PROFILES = {"eth_xgaze": {"size_px": (128, 128), "focal_px": 1800.0, "distance_mm": 600.0},
            "mpiigaze": {"size_px": (60, 36), "focal_px": 960.0, "distance_mm": 600.0}}

_HALF = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])       # OpenCV px -> label px
_HALF_INV = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])


def eye_center_camera(label: dict, center: str = "eyeball") -> np.ndarray:
    """(3,) the normalisation's eye centre in the label's camera frame (OpenGL axes, mm)."""
    if center == "canthi":
        L = np.asarray(label["landmarks"]["camera_mm"], float)
        return 0.5 * (L[0] + L[6])
    return np.asarray(label["eyes"][label["gaze"]["eye"]]["center_camera_mm"], float)


def normalization(label: dict, size_px=(128, 128), focal_px: float = 1800.0, distance_mm: float = 600.0,
                  center: str = "eyeball") -> dict:
    """The normalisation of one labelled image (module doc): ``R``, ``S``, ``K_norm``, the warp in
    both pixel conventions, and the eye centre it is taken about."""
    w, h = int(size_px[0]), int(size_px[1])
    e_gl = eye_center_camera(label, center)
    e = conv.to_opencv(e_gl)
    hR = np.asarray(label["conventions"]["eth_xgaze"]["head_rotation_opencv"], float)
    K_norm = np.array([[focal_px, 0.0, w / 2.0], [0.0, focal_px, h / 2.0], [0.0, 0.0, 1.0]])
    camera = Camera.from_dict(label["camera"])
    dist = float(np.linalg.norm(e))
    if camera.kind == "pinhole":
        K = opencv_pixel_K(camera.K)           # OpenCV pixels (centres at integers), as ETH-XGaze's K
        R = conv.eth_normalization(hR, e / dist)
        S = np.diag([1.0, 1.0, distance_mm / dist])
        W = K_norm @ S @ R @ np.linalg.inv(K)
    else:                                  # the limit of a camera receding along its axis (module doc)
        R = conv.eth_normalization(hR, (0.0, 0.0, 1.0))
        S = None
        W_img, H_img = label["image"]["width"], label["image"]["height"]
        a = W_img / ortho_size(camera.ortho_scale_mm, W_img, H_img)[0]          # px per mm
        # OpenCV px -> camera mm (x right, y down) relative to the eye centre
        to_mm = np.array([[1.0 / a, 0.0, (0.5 - W_img / 2.0) / a - e[0]],
                          [0.0, 1.0 / a, (0.5 - H_img / 2.0) / a - e[1]],
                          [0.0, 0.0, 1.0]])
        k = focal_px / distance_mm
        roll = np.eye(3)
        roll[:2, :2] = R[:2, :2]
        centre = np.array([[1.0, 0.0, w / 2.0], [0.0, 1.0, h / 2.0], [0.0, 0.0, 1.0]])     # K_norm's principal point
        W = centre @ np.diag([k, k, 1.0]) @ roll @ to_mm
    return {"R": R, "S": S, "K_norm": K_norm, "warp_opencv": W, "warp": _HALF @ W @ _HALF_INV,
            "center_camera_mm": e_gl, "center_opencv_mm": e, "distance_mm": dist, "center": center,
            "size_px": (w, h), "focal_px": float(focal_px), "distance_norm_mm": float(distance_mm),
            "orthographic": camera.kind == "ortho"}


def apply_h(H, px) -> np.ndarray:
    """(n, 2) points ``px`` mapped by the homography ``H`` (``cv2.perspectiveTransform``)."""
    P = np.c_[np.asarray(px, float), np.ones(len(px))] @ np.asarray(H, float).T
    return P[:, :2] / P[:, 2:]


def project_normalized(points_camera_gl, n: dict) -> np.ndarray:
    """(k, 2) the virtual camera's view (label pixels, centres at +0.5) of camera-frame points: the
    formula ``K_norm S R p`` (pinhole), or its orthographic limit (module doc). For checks: the
    warped landmarks equal it."""
    P = np.asarray(points_camera_gl, float) @ conv.GL_TO_CV.T
    if not n["orthographic"]:
        Q = P @ (n["K_norm"] @ n["S"] @ n["R"]).T
        uv = Q[:, :2] / Q[:, 2:]
    else:
        k = n["focal_px"] / n["distance_norm_mm"]
        uv = k * ((P - n["center_opencv_mm"]) @ n["R"].T)[:, :2] + n["K_norm"][:2, 2]
    return uv + 0.5


def warp_image(img: np.ndarray, W_opencv, size_px, nearest: bool = False, fill=0) -> np.ndarray:
    """``cv2.warpPerspective(img, W, size)`` in numpy: each output pixel (OpenCV centres) takes the
    source at ``W^-1`` of it, bilinear (or nearest), ``fill`` where the source is outside."""
    w, h = int(size_px[0]), int(size_px[1])
    src = np.asarray(img)
    Hs, Ws = src.shape[:2]
    jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    q = apply_h(np.linalg.inv(np.asarray(W_opencv, float)), np.c_[jj.ravel(), ii.ravel()])
    x, y = q[:, 0], q[:, 1]
    chans = src.reshape(Hs, Ws, -1).astype(np.float64)
    if nearest:
        xi, yi = np.floor(x + 0.5).astype(int), np.floor(y + 0.5).astype(int)
        ok = (xi >= 0) & (xi < Ws) & (yi >= 0) & (yi < Hs)
        out = np.full((len(x), chans.shape[2]), float(fill))
        out[ok] = chans[yi[ok], xi[ok]]
    else:
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        out = np.zeros((len(x), chans.shape[2]))
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            xs, ys = x0 + dx, y0 + dy
            ok = (xs >= 0) & (xs < Ws) & (ys >= 0) & (ys < Hs)
            vals = np.full((len(x), chans.shape[2]), float(fill))
            vals[ok] = chans[ys[ok], xs[ok]]
            out += wgt * vals
        out = np.clip(np.floor(out + 0.5), 0, 255)
    out = out.reshape(h, w, -1).astype(src.dtype)
    return out[..., 0] if src.ndim == 2 else out


def normalized_label(label: dict, n: dict) -> dict:
    """The normalised crop's label: the warp, the virtual camera, the normalised gaze and head pose
    (ETH-XGaze's conventions), and the landmarks warped (label pixels, centres at +0.5)."""
    g = conv.to_opencv(label["gaze"]["vector_camera"])
    hR = np.asarray(label["conventions"]["eth_xgaze"]["head_rotation_opencv"], float)
    R = n["R"]
    g_n, hR_n = R @ g, R @ hR
    px = apply_h(n["warp"], label["landmarks"]["px"])
    w, h = n["size_px"]

    def fl(a):
        return None if a is None else [float(x) for x in np.asarray(a, float).ravel()]

    pitch, yaw = conv.eth_gaze_pitchyaw(g_n)
    return {
        "index": label["index"], "source": label["image"]["file"], "eye": label["gaze"]["eye"],
        "image": {"width": w, "height": h, "pixels": "origin top-left, pixel centres at +0.5 (as the label's)"},
        "method": "ETH-XGaze / Zhang et al. ETRA 2018 normalizeData: W = K_norm S R K^-1 about the eye centre "
                  + ("(orthographic source: the limit of a receding camera, S R K^-1 -> a similarity; "
                     "pipeline/render/normalize.py)" if n["orthographic"] else "(pinhole source)"),
        "center": {"rule": {"eyeball": "the eyeball's rotation centre (label eyes.<side>.center_camera_mm)",
                            "canthi": "the midpoint of landmarks 0 and 6 (the eye corners)"}[n["center"]],
                   "camera_mm": fl(n["center_camera_mm"]), "opencv_mm": fl(n["center_opencv_mm"]),
                   "distance_mm": n["distance_mm"],
                   "px": fl(n["K_norm"][:2, 2] + 0.5)},
        "virtual_camera": {"focal_px": n["focal_px"], "distance_mm": n["distance_norm_mm"],
                           "K_norm": n["K_norm"].tolist(),
                           "K_norm_pixels": "OpenCV (centres at integers), as ETH-XGaze's cam_norm: the eye centre "
                                            "lies at (w/2, h/2) there, (w/2 + 0.5, h/2 + 0.5) in label pixels"},
        "rotation": R.tolist(),
        "scale": None if n["S"] is None else n["S"].tolist(),
        "warp": n["warp"].tolist(),
        "warp_opencv": n["warp_opencv"].tolist(),
        "warp_note": "warp: label pixels of the source image -> label pixels of the crop; warp_opencv: the same in "
                     "OpenCV pixels (cv2.warpPerspective(image, warp_opencv, (w, h)) gives the crop)",
        "gaze": {"vector_opencv": fl(g_n), "pitchyaw_rad": [float(pitch), float(yaw)],
                 "convention": "ETH-XGaze: pitch = arcsin(-y), yaw = arctan2(-x, -z) of the normalised gaze "
                               "(OpenCV axes); a gaze at the virtual camera is (0, 0)"},
        "head_pose": {"rotation_opencv": hR_n.tolist(), "rotvec": fl(conv.rotation_vector(hR_n)),
                      "pitchyaw_rad": fl(conv.eth_head_pitchyaw(hR_n)),
                      "convention": "ETH-XGaze: hR_norm = R hR; (asin(Z[1]), atan2(Z[0], Z[2])) of its z column"},
        "landmarks": {"px": px.tolist(), "order": "the label's 28 landmarks, warped by warp"},
    }

