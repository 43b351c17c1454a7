"""Label format ``unityeyes``: UnityEyes JSON + JPEG pairs that GazeML reads unchanged.

Only in GazeML's framing (``iris_distance_px: 71.7593`` and no framing shift: the ``unityeyes``
preset): its loader takes the image centre for the eyeball centre and puts the iris centre
71.7593 px from it along the look vector, so any other scale or shift misplaces the iris centre
(generic framing: 8-14 px median), and it crops 1.5 eye widths around the eye, wider than a
30-36 mm frame. Settings that list ``unityeyes`` with another framing are refused
(pipeline/render/settings.py); an image whose GazeML crop leaves the frame is refused when it is
drawn (:func:`job`). UnityEyes renders the subject's left eye only: a right eye is written
mirrored (the JPEG, every 2D point, ``look_vec`` x and ``head_pose``), so it reads as a left eye.

``unityeyes/NNNNNN.json`` + ``unityeyes/NNNNNN.jpg`` (written by pipeline/io/unityeyes_file.py).
UnityEyes (Wood et al., ETRA 2016) writes ``imgs/N.jpg`` + ``imgs/N.json``; GazeML
(swook/GazeML ``src/datasources/unityeyes.py``) and its forks read a folder of such pairs, so
``renders/<scan>/unityeyes/`` is a folder GazeML reads unchanged. Conventions, each from
UnityEyes' own writer (``SynthesEyesServer.saveDetails``, ``EyeballController.GetEyeballDetails``,
``LightingController.GetLightingDetails`` in the UnityEyes Unity sources that its forks carry) or
from GazeML's reader:

* Every vector is a string, a C# ``Vector3/4.ToString("F4")``: ``"(x, y, z)"`` with 4 decimals
  (GazeML: ``eval(l)`` of each string); plain numbers are C# ``float.ToString()`` strings
  (``"0.9058223"``, 7 significant digits).
* ``interior_margin_2d`` (16), ``caruncle_2d`` (7), ``iris_2d`` (32): ``Camera.WorldToScreenPoint``
  of mesh vertices: x in pixels from the left edge, **y in pixels from the bottom edge** (Unity's
  screen origin; GazeML flips with ``ih - y``), z = depth in front of the camera in Unity units.
  Pixel ``(0, 0)`` is the bottom-left pixel's corner, so ``x`` = our ``u`` and ``y = height - v``
  exactly (ours: top-left corner, y down). UnityEyes' camera stands 10 units from the eyeball
  centre (``RandomVec(...) * 10f``, then ``LookAt(Vector3.zero)``) and its landmarks lie at
  depths ~9-9.7 with a ~1.2-unit eyeball, so a Unity unit is a centimetre: z = our depth / 10
  (the ``unityeyes`` preset puts the camera 100 mm away, so the eyeball centre is at z = 10).
* ``eye_details.look_vec``: ``Camera.main.transform.worldToLocalMatrix * GetEyeLookVector()``,
  the eye's forward in Unity's **left-handed** camera axes (x right, y up, z forward, away from
  the camera) as a ``Vector4`` with w = 0: ``(gx, gy, -gz, 0)`` of our camera-frame gaze (ours:
  OpenGL, z toward the viewer). An eye looking into the camera has ``look_vec = (0, 0, -1, 0)``.
* ``head_pose``: ``Camera.main.transform.rotation.eulerAngles``, degrees in [0, 360), Unity's
  order (``Quaternion.Euler(x, y, z)`` turns z about Z, then x about X, then y about Y:
  ``R = Ry Rx Rz``), of the camera in Unity's world: the head frame with x mirrored (Unity's
  world has +Y up and the face looking along +Z, as ours, but is left-handed, so its +X is the
  subject's right). A camera straight in front of the face is ``(0, 180, 0)``; GazeML keeps an
  image when ``|pitch| <= 20`` (pitch > 180 taken as pitch - 360) and ``|yaw - 180| <= 20``.
* ``eye_details.pupil_size``: our signed pupil blend (``pupil_dilate - pupil_constrict``, -1..1;
  UnityEyes writes its shader's ``_PupilSize``, a N(0, 1) / 5 draw with no published unit);
  ``iris_size``: the iris radius over the eyeball asset's rest iris radius (UnityEyes: its limbus
  scale, 0.9-1.0; ours 0.9-1.1); ``iris_texture``: ``eyeball_<colour>``.
* ``lighting_details``: ``skybox_texture`` = the HDR map's name, ``skybox_exposure`` = its
  strength, ``skybox_rotation`` = its rotation (degrees), ``ambient_intensity`` = 1 (no separate
  ambient scale: the map lights the scene), ``light_rotation`` = ``"(0.0, 0.0, 0.0)"`` and
  ``light_intensity`` = 0 (no directional light).
* ``eye_region_details``: ``pca_shape_coeffs`` = [] (a scanned head, no shape model),
  ``primary_skin_texture`` = the scan's name (its baked colour map).

Point orders are anatomical, as UnityEyes' vertex lists are: for the subject's left eye (the eye
UnityEyes renders: its caruncle lies at the image left) they read as UnityEyes' do on screen; a
right eye's image and points are mirrored (x -> width - x), so they read the same way.

* **interior margin**, 16 points on our posed lid loop (the skin/eyeball seam). UnityEyes'
  ``interior_margin_idxs`` start at vertex 12 where the upper and lower margins meet beside the
  caruncle, run over the upper lid to the lateral canthus (index 8, GazeML's ``right_corner``) and
  back along the lower lid. Our lids meet at the medial canthus itself (landmark 0, the fissure's
  end past the caruncle), so the caruncle gets the medial :data:`CARUNCLE_FRACTION` of each lid's
  arc length (UnityEyes' loop of
  the opening, ``EyeRegionTopology.loops[0]``, gives the caruncle 2 of the 10 edges of each lid
  branch): points 1-7 lie on the upper lid at ``c + (1 - c) k / 8`` of its arc length from the
  medial canthus (k = 1..7), 8 is the lateral canthus (our landmark 6), 15-9 on the lower lid
  alike, and point 0 is UnityEyes' vertex 12 rule: the midpoint of points 1 and 15 cast onto the
  eyeball along the eye's rest forward (``CastOntoEyeball(.., Vector3.forward)``).
* **caruncle**, 7 points in that medial part of the opening, in UnityEyes' vertex order
  ``caruncle_idxs = {28, 27, 25, 32, 31, 30, 33}``: 33 (last) is the medial canthus (our
  landmark 0); 32 / 30 lie on the upper / lower lid at ``c / 2``, 25 / 28 at ``c``; 27 and 31 are
  the midpoints of 25-28 and 32-30 cast onto the eyeball (UnityEyes moves them with the
  neighbouring margin vertices). The asset models a caruncle only where the medial corner
  stands off the globe (the strip closing it, pipeline/geometry/corners.py); the points follow
  the rule above either way.
* **iris**, 32 points on the iris boundary circle (through our 8 iris landmarks, which are
  vertices of that ring): UnityEyes' ``iris_idxs`` start at the medial side and go over the top
  (its sample JSON: ``iris_2d[1]`` is above ``iris_2d[0]``, which is the leftmost of a left eye),
  11.25 deg apart. GazeML takes ``iris_2d[::4]``; those are our 8 iris landmarks exactly:
  ``iris_2d[4 m]`` = landmark ``12 + (4 - m) % 8`` of a left eye, ``12 + m`` of a right eye.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.unityeyes_file import write_unityeyes
from pipeline.render import asset as ra
from pipeline.render import camera as cam
from pipeline.render import conventions as conv

NAME = "unityeyes"
#: Folder of the UnityEyes pairs inside a render folder.
UNITYEYES_DIR = "unityeyes"
#: GazeML's fixed eyeball radius in pixels (``original_eyeball_radius`` of its UnityEyes loader).
GAZEML_EYEBALL_RADIUS_PX = 71.7593
#: Share of each lid's arc length, from the medial canthus, given to the caruncle (module doc).
CARUNCLE_FRACTION = 0.2
N_INTERIOR, N_CARUNCLE, N_IRIS_2D = 16, 7, 32
#: GazeML's eye image (height, width): its crop is ``oh / ow`` times as high as wide.
GAZEML_EYE_IMAGE = (36, 60)
#: Unity units (cm) per millimetre.
UNITY_PER_MM = 0.1
FILES = {f"{UNITYEYES_DIR}/NNNNNN.json": "the label in UnityEyes' JSON format: GazeML's UnityEyes loader reads "
                                         "unityeyes/ as it is (preset unityeyes; its iris centre and gaze agree "
                                         "with ours; right eyes mirrored into left eyes)",
         f"{UNITYEYES_DIR}/NNNNNN.jpg": "the image as a JPEG, beside its UnityEyes label (a right eye mirrored)"}


# ------------------------------------------------------------------------------ lid points (3D)

def _arc_points(rest, posed, fractions) -> np.ndarray:
    """Posed points at arc-length ``fractions`` (0..1) of an open polyline, measured at rest.

    The landmarks' rule (pipeline/rig/landmarks.py): a point keeps its place on its edge when the
    lids move, so the arc length is taken on the rest positions.
    """
    rest = np.asarray(rest, float)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(rest, axis=0), axis=1))])
    s = np.clip(np.asarray(fractions, float), 0.0, 1.0) * cum[-1]
    posed = np.asarray(posed, float)
    return np.stack([np.interp(s, cum, posed[:, j]) for j in range(3)], axis=1)


def cast_onto_eyeball(p, center, radius: float, forward) -> np.ndarray:
    """``p`` moved along ``forward`` onto the front of the sphere (``p`` itself when the line misses)."""
    q = np.asarray(p, float) - center
    b = float(q @ forward)
    disc = b * b - float(q @ q) + radius * radius
    if disc < 0:
        return np.asarray(p, float)
    return np.asarray(p, float) + (-b + math.sqrt(disc)) * np.asarray(forward, float)


def lid_points(loop_rest, loop_posed, lateral_index: int, center, radius: float, forward,
               fraction: float = CARUNCLE_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """UnityEyes' interior margin (16) and caruncle (7) points on one posed lid loop.

    Parameters
    ----------
    loop_rest, loop_posed : (L, 3) float64
        The lid loop at rest and posed, starting at the medial canthus and running over the upper
        lid; ``loop[lateral_index]`` is the lateral canthus.
    center, radius, forward
        The eyeball (head mm) and its rest forward, for UnityEyes' cast onto the eyeball.

    Returns
    -------
    interior : (16, 3) float64 ; caruncle : (7, 3) float64   head mm, orders in the module doc.
    """
    li = int(lateral_index)
    up = np.arange(0, li + 1)
    low = np.concatenate([[0], np.arange(len(loop_rest) - 1, li - 1, -1)])   # medial .. lateral
    c = float(fraction)
    fr = np.concatenate([[c / 2, c], c + (1.0 - c) * np.arange(1, 9) / 8.0])
    U = _arc_points(np.asarray(loop_rest)[up], np.asarray(loop_posed)[up], fr)
    D = _arc_points(np.asarray(loop_rest)[low], np.asarray(loop_posed)[low], fr)
    U[-1] = D[-1] = loop_posed[li]                    # the lateral canthus exactly
    f = np.asarray(forward, float)

    def cast(a, b):
        return cast_onto_eyeball(0.5 * (a + b), center, radius, f)

    interior = np.empty((N_INTERIOR, 3))
    interior[1:9] = U[2:10]                           # upper lid, medial -> lateral canthus
    interior[9:16] = D[8:1:-1]                        # lower lid, lateral -> medial
    interior[0] = cast(interior[1], interior[15])
    k = np.asarray(loop_posed[0], float)              # the medial canthus
    caruncle = np.stack([D[1], cast(U[1], D[1]), U[1], U[0], cast(U[0], D[0]), D[0], k])
    return interior, caruncle


def gazeml_crop(interior_px, caruncle_px, eye_image=GAZEML_EYE_IMAGE) -> np.ndarray:
    """(4,) ``x0, y0, x1, y1`` px: the part of the image GazeML's UnityEyes loader crops (no
    augmentation): 1.5 times the distance from the caruncle's mean to interior point 8 wide,
    ``oh / ow`` of that high, centred on the interior margin's bounding box. Points (n, 2+) in
    pixels, either y direction (the box is symmetric about its centre)."""
    interior = np.asarray(interior_px, float)[:, :2]
    left, right = np.asarray(caruncle_px, float)[:, :2].mean(axis=0), interior[8]
    w = 1.5 * abs(left[0] - right[0])
    h = w * eye_image[0] / eye_image[1]
    mid = 0.5 * (interior.min(axis=0) + interior.max(axis=0))
    return np.array([mid[0] - w / 2, mid[1] - h / 2, mid[0] + w / 2, mid[1] + h / 2])


def _inside(crop, width: int, height: int) -> bool:
    x0, y0, x1, y1 = crop
    return bool(x0 >= 0 and y0 >= 0 and x1 <= width and y1 <= height)


def check_crop(interior_px, caruncle_px, width: int, height: int, where, index: int) -> None:
    """Refuse (one line) an image whose GazeML crop does not lie inside the ``width`` x ``height`` image."""
    x0, y0, x1, y1 = crop = gazeml_crop(interior_px, caruncle_px)
    if not _inside(crop, width, height):
        raise ScanError(where, f"image {index}: label format unityeyes needs GazeML's crop (1.5 eye widths, "
                               f"{x1 - x0:.0f} x {y1 - y0:.0f} px at {x0:.0f}..{x1:.0f}, {y0:.0f}..{y1:.0f}) "
                               f"inside the {width} x {height} image; use preset unityeyes or a larger width and "
                               f"height")


def points_job(asset, smp) -> dict:
    """The posed lid points of the imaged eye (head mm) and its iris size: :func:`job` unchecked.

    From the asset's lid loop (``loop_<side>`` of rig.npz; the lateral canthus is the loop vertex
    of eyelid landmark 6); a rig without a loop uses the 12 eyelid landmarks as the loop.
    """
    eye = asset.eyes[smp.side]
    lw = smp.spec.lid_weights
    if eye.loop is not None and eye.lm_edge is not None:
        loop = np.asarray(eye.loop)
        li = int(np.flatnonzero(loop == eye.lm_edge[6, 0])[0])
        rest, posed = asset.skin_rest[loop], ra.posed_skin(asset, lw, loop)
    else:
        li, rest, posed = 6, ra.eyelid_points(asset, smp.side, {}), ra.eyelid_points(asset, smp.side, lw)
    interior, caruncle = lid_points(rest, posed, li, eye.center, eye.radius, eye.basis[2])
    iris_rest = ra.inner_points(eye, {}, np.eye(3), eye.iris)
    iris = ra.inner_points(eye, smp.spec.eyeball.blend, np.eye(3), eye.iris)
    return {"interior_head_mm": interior.tolist(), "caruncle_head_mm": caruncle.tolist(),
            "iris_size": float(ra.ring_radius(iris) / ra.ring_radius(iris_rest))}


def _crop_px(asset, smp, j) -> tuple:
    """GazeML's loader's interior margin and caruncle points of ``smp`` in the image (px)."""
    camera = smp.spec.camera
    w, h = smp.spec.width, smp.spec.height

    def px(P):
        return camera.project(cam.to_camera(P, camera.world_to_camera), w, h)

    return px(j["interior_head_mm"]), px(j["caruncle_head_mm"]), w, h


def accepts(asset, smp) -> bool:
    """GazeML's crop of the drawn sample lies inside the image (else the sampler draws again)."""
    if smp.spec.camera.kind == "pinhole":
        return False                                 # settings refuse this; never write it
    interior, caruncle, w, h = _crop_px(asset, smp, points_job(asset, smp))
    return _inside(gazeml_crop(interior, caruncle), w, h)


def job(asset, smp) -> dict:
    """What the UnityEyes writer needs beyond the label (:func:`points_job`), once GazeML's crop of
    the image is known to lie inside it.

    Raises
    ------
    ScanError  naming the asset and the image when the crop leaves the image (:func:`check_crop`).
    """
    j = points_job(asset, smp)
    interior, caruncle, w, h = _crop_px(asset, smp, j)
    check_crop(interior, caruncle, w, h, getattr(asset, "usda", "asset"), smp.index)
    return j


# --------------------------------------------------------------------------- UnityEyes document

def cs_vec(v, decimals: int = 4) -> str:
    """C# ``Vector3/4.ToString("F<decimals>")``: ``"(x, y, z)"`` (no negative zero)."""
    return "(" + ", ".join(f"{float(x) + 0.0:.{decimals}f}".replace("-0." + "0" * decimals,
                                                                        "0." + "0" * decimals)
                           for x in v) + ")"


def cs_float(x) -> str:
    """C# ``float.ToString()``: 7 significant digits, no trailing zeros (``"1"``, ``"0.9058223"``)."""
    s = f"{float(np.float32(x)) + 0.0:.7g}"
    return s.replace("e", "E") if "e" in s else s


#: UnityEyes' ``head_pose`` (pipeline/render/conventions.py).
head_pose = conv.unityeyes_head_pose


def unity_screen(points_head, label, mirror: bool = False) -> np.ndarray:
    """(n, 3) ``WorldToScreenPoint`` of head-frame points: x right, y up from the bottom, depth (cm);
    ``mirror``: of the horizontally mirrored image (x -> width - x: x counts from pixel corners)."""
    P = np.asarray(points_head, float)
    W2C = np.asarray(label["camera"]["world_to_camera"], float)
    cam = P @ W2C[:3, :3].T + W2C[:3, 3]
    H = np.concatenate([cam, np.ones((len(P), 1))], 1) @ np.asarray(label["camera"]["projection"], float).T
    uv = H[:, :2] / H[:, 2:]
    x = label["image"]["width"] - uv[:, 0] if mirror else uv[:, 0]
    return np.stack([x, label["image"]["height"] - uv[:, 1], -cam[:, 2] * UNITY_PER_MM], axis=1)


def iris_circle(iris_head, side: str, n: int = N_IRIS_2D) -> np.ndarray:
    """(n, 3) points on the iris boundary circle through our 8 iris landmarks, UnityEyes' order.

    The landmarks sit at azimuth 45 deg * k from the eye's +X (the subject's left),
    counter-clockwise seen from the front: landmark 0 and 2 give the circle's axes. UnityEyes
    starts at the medial side (azimuth 180 deg for a left eye, 0 for a right eye) and goes over the
    top first (module doc).
    """
    P = np.asarray(iris_head, float)
    c = P.mean(0)
    u, v = P[0] - c, P[2] - c
    j = np.arange(n) * (360.0 / n)
    az = np.radians(180.0 - j if side == "left" else j)
    return c + np.outer(np.cos(az), u) + np.outer(np.sin(az), v)


def unityeyes_document(label: dict, job: dict) -> dict:
    """The UnityEyes JSON of one image (strings as UnityEyes writes them; module doc); a right eye's
    is that of the mirrored image.

    Parameters
    ----------
    label : dict   our label (:func:`pipeline.render.labels.make_label`, or as read back)
    job : dict     :func:`job` of the same sample
    """
    lm_head = np.asarray(label["landmarks"]["head_mm"], float)
    side = label["gaze"]["eye"]
    g = np.asarray(label["gaze"]["vector_camera"], float)
    conf = label["eye_configuration"]
    blend = conf["blend"]
    light = label["lighting"]
    mirror = side == "right"
    look = conv.unityeyes_look_vec(g)

    def pts(P):
        return [cs_vec(p) for p in unity_screen(P, label, mirror)]

    hdri = str(light["hdri"])
    return {
        "interior_margin_2d": pts(job["interior_head_mm"]),
        "caruncle_2d": pts(job["caruncle_head_mm"]),
        "iris_2d": pts(iris_circle(lm_head[12:20], side)),
        "eye_details": {"look_vec": cs_vec(conv.mirror_look_vec(look) if mirror else look),
                        "pupil_size": cs_float(blend["pupil_dilate"] - blend["pupil_constrict"]),
                        "iris_size": cs_float(job["iris_size"]),
                        "iris_texture": f"eyeball_{conf['iris_color']}"},
        "lighting_details": {"skybox_texture": hdri[:-4] if hdri.endswith(".exr") else hdri,
                             "skybox_exposure": cs_float(light["strength"]),
                             "skybox_rotation": cs_float(light["rotation_deg"]),
                             "ambient_intensity": cs_float(1.0),
                             "light_rotation": cs_vec([0.0, 0.0, 0.0], 1),
                             "light_intensity": cs_float(0.0)},
        "eye_region_details": {"pca_shape_coeffs": [], "primary_skin_texture": str(label["scan"])},
        "head_pose": cs_vec(head_pose(label["camera"]["world_to_camera"], mirror)),
    }


def write(out_dir, index: int, label: dict, job: dict, png) -> list[Path]:
    """Write the UnityEyes pair of image ``index`` into ``out_dir/unityeyes/`` (a right eye mirrored); the paths."""
    return write_unityeyes(Path(out_dir) / UNITYEYES_DIR, index, unityeyes_document(label, job), png,
                           mirror=label["gaze"]["eye"] == "right")
