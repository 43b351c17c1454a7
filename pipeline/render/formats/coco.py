"""Label format ``coco``: one COCO keypoints + segmentation file per render or dataset folder.

``coco.json`` (read by pycocotools' ``COCO``, detectron2, mmpose, ...), assembled at the end of
every run (:func:`finish`) from the per-image fragments ``coco/NNNNNN.json`` that :func:`write`
leaves beside each image, in index order, with annotation ids numbered in that order: a resumed
or killed run, or images finishing in any order, give the same bytes.

* **images**: ``id`` = our global image index, ``file_name`` = ``NNNNNN.png``, ``width``,
  ``height``; also ``label_file``, ``seg_file``, ``depth_file`` (our per-image files) and
  ``asset``.
* **categories**: ids 1-6 are the segmentation classes with the ids of ``NNNNNN_seg.png``
  (skin, sclera, iris, pupil, eyelashes, caruncle: category id = mask value; background, 0, has
  none), and :data:`EYE_ID` = 7 is ``eye``, the keypoint category: 28 ``keypoints`` named as our
  landmarks (0-11 eyelid, 12-19 iris, 20-27 pupil) and a ``skeleton`` of three closed rings.
* **annotations** of an image: first one ``eye`` annotation, then one per segmentation class
  present in its mask, classes in id order; all ``iscrowd`` 0, ``segmentation`` a compressed RLE
  (pycocotools' string form, pipeline/io/coco_file.py) of exactly the mask's pixels of that class.

  - ``eye``: ``keypoints`` = 28 ``(x, y, v)``. ``x, y`` = our landmark pixels - 0.5: COCO
    keypoints are pixel indices (the centre of the top-left pixel is (0, 0); detectron2 adds 0.5
    on reading them), ours have the pixel corner at 0. ``v`` from our landmark visibility
    (``landmarks.visible``, docs/labels.md): 2 visible, 1 in the image but hidden (by a lid,
    lashes, the lid's skin), 0 outside the image (then ``x = y = 0``, as COCO asks).
    ``num_keypoints`` = landmarks with ``v > 0``. ``segmentation`` = the visible eyeball (mask
    classes sclera, iris, pupil and caruncle: the eye opening as seen); ``area`` = its pixel
    count; ``bbox`` = the box around that mask and the labelled eyelid landmarks (the outline of
    the eye, which a closed lid keeps), clipped to the image. Also ``eye`` (``left``/``right``,
    the subject's), ``gaze_camera`` (unit vector, our camera frame), ``gaze_pitch_yaw_deg``
    (label ``gaze.camera``) and the imaged eye's geometry (label ``eyes.<eye>``): ``gaze_origin``
    = its rotation centre as a keypoint ``(x, y)`` (our pixels - 0.5, as the keypoints; null
    behind a pinhole camera), ``gaze_origin_camera_mm``, ``eyeball_radius_mm`` and
    ``center_to_iris_plane_mm``.
  - one per class: ``segmentation`` = the class's pixels, ``area`` = their count, ``bbox`` = their
    box (pycocotools ``toBbox`` of the RLE).

So keypoint tools read category ``eye``, instance or semantic segmentation tools the classes,
and the union of the class masks with background is the whole ``NNNNNN_seg.png``. It needs the
masks (``render.masks: true``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_text
from pipeline.io.coco_file import fragment_name, mask_bbox, read_fragment, rle_encode
from pipeline.io.seg_file import CARUNCLE, CLASSES, IRIS, PUPIL, SCLERA, read_seg

NAME = "coco"
NEEDS_MASKS = True
COCO_DIR = "coco"
COCO_FILE = "coco.json"
FILES = {f"{COCO_DIR}/NNNNNN.json": "the image's part of coco.json (its COCO image and annotations); "
                                    "coco.json is assembled from these"}
DATASET_FILES = {COCO_FILE: "COCO keypoints (category eye: 28 landmarks with visibility v) and the "
                            "segmentation classes as RLE masks, every image (eyerig docs/labels.md)"}
#: The keypoint category; ids 1-6 are the mask classes.
EYE_ID = len(CLASSES)
#: Mask classes that make the ``eye`` annotation's mask: the eyeball seen through the opening.
EYE_CLASSES = (SCLERA, IRIS, PUPIL, CARUNCLE)
#: The landmark order (our label's ``landmarks.order``, in short).
KEYPOINT_ORDER = ("our 28 landmarks of the imaged eye: 0-11 eyelid (0 medial canthus, 1-5 upper lid, 6 lateral "
                  "canthus, 7-11 lower lid), 12-19 iris boundary, 20-27 pupil boundary (label landmarks.order)")
KEYPOINT_NAMES = ([f"eyelid_{k}" for k in range(12)] + [f"iris_{k}" for k in range(8)]
                  + [f"pupil_{k}" for k in range(8)])


def _ring(first: int, n: int) -> list[list[int]]:
    """A closed ring of keypoints ``first..first+n-1`` as COCO skeleton edges (1-based)."""
    return [[first + k + 1, first + (k + 1) % n + 1] for k in range(n)]


SKELETON = _ring(0, 12) + _ring(12, 8) + _ring(20, 8)


def categories() -> list[dict]:
    """COCO ``categories``: the mask classes (ids as in the masks), then ``eye`` with its keypoints."""
    out = [{"id": i, "name": name, "supercategory": "eye_region"} for i, (name, _) in sorted(CLASSES.items())
           if i != 0]
    out.append({"id": EYE_ID, "name": "eye", "supercategory": "eye", "keypoints": KEYPOINT_NAMES,
                "skeleton": SKELETON, "keypoint_order": KEYPOINT_ORDER})
    return out


def keypoints(label: dict) -> tuple[list[float], int]:
    """COCO ``keypoints`` (84 numbers: x, y, v per landmark; module doc) and ``num_keypoints``."""
    lm = label["landmarks"]
    if "visible" not in lm:
        raise ValueError("the label has no landmark visibility (render.masks: true)")
    w, h = label["image"]["width"], label["image"]["height"]
    out: list[float] = []
    for (x, y), vis, why in zip(lm["px"], lm["visible"], lm["occlusion"]):
        inside = why != "outside" and 0 <= x < w and 0 <= y < h
        out += [float(x) - 0.5, float(y) - 0.5, 2 if vis else 1] if inside else [0.0, 0.0, 0]
    return out, sum(1 for v in out[2::3] if v > 0)


def _eye_bbox(mask, kp: list[float], width: int, height: int) -> list[float]:
    """Box around the eye mask and the labelled eyelid keypoints, clipped to the image (module doc)."""
    xs, ys = [], []
    x, y, bw, bh = mask_bbox(mask)
    if bw > 0:
        xs += [x, x + bw]
        ys += [y, y + bh]
    for k in range(12):
        if kp[3 * k + 2] > 0:
            xs.append(kp[3 * k] + 0.5)                  # back to continuous pixel coordinates
            ys.append(kp[3 * k + 1] + 0.5)
    if not xs:
        return [0.0, 0.0, 0.0, 0.0]
    x0, x1 = max(0.0, min(xs)), min(float(width), max(xs))
    y0, y1 = max(0.0, min(ys)), min(float(height), max(ys))
    return [x0, y0, x1 - x0, y1 - y0]


def _eye_geometry(label: dict) -> dict:
    """The imaged eye's rotation centre (COCO keypoint pixels, camera mm), radius and centre-to-iris-plane
    distance from the label's ``eyes.<eye>`` (nothing for a label without them)."""
    e = (label.get("eyes") or {}).get(label["gaze"]["eye"]) or {}
    if "center_camera_mm" not in e:
        return {}
    px = e["center_px"]
    return {"gaze_origin": None if px is None else [float(px[0]) - 0.5, float(px[1]) - 0.5],
            "gaze_origin_camera_mm": [float(v) for v in e["center_camera_mm"]],
            "eyeball_radius_mm": float(e["radius_mm"]), "center_to_iris_plane_mm": float(e["center_to_iris_plane_mm"])}


def fragment(index: int, label: dict, seg: np.ndarray) -> dict:
    """Image ``index``'s COCO image and annotations (without annotation ids) from its label and
    (H, W) class mask."""
    w, h = label["image"]["width"], label["image"]["height"]
    seg = np.asarray(seg)
    if seg.shape != (h, w):
        raise ValueError(f"mask is {seg.shape[1]} x {seg.shape[0]}, the label's image {w} x {h}")
    kp, nk = keypoints(label)
    eye = np.isin(seg, EYE_CLASSES)
    g = label["gaze"]
    anns = [{"image_id": int(index), "category_id": EYE_ID, "iscrowd": 0,
             "keypoints": kp, "num_keypoints": nk,
             "segmentation": rle_encode(eye), "area": int(eye.sum()), "bbox": _eye_bbox(eye, kp, w, h),
             "eye": g["eye"], "gaze_camera": [float(v) for v in g["vector_camera"]],
             "gaze_pitch_yaw_deg": [float(g["camera"]["pitch_deg"]), float(g["camera"]["yaw_deg"])],
             **_eye_geometry(label)}]
    for c in sorted(CLASSES):
        m = seg == c
        if c == 0 or not m.any():
            continue
        anns.append({"image_id": int(index), "category_id": int(c), "iscrowd": 0,
                     "segmentation": rle_encode(m), "area": int(m.sum()), "bbox": mask_bbox(m)})
    name = f"{int(index):06d}"
    image = {"id": int(index), "file_name": f"{name}.png", "width": int(w), "height": int(h),
             "label_file": f"{name}.json", "seg_file": label["seg"]["file"],
             "depth_file": (label.get("depth") or {}).get("file"),
             "asset": (label.get("asset") or {}).get("name", label.get("scan"))}
    return {"image": image, "annotations": anns}


def _dumps(doc) -> str:
    return json.dumps(doc, separators=(",", ":"), allow_nan=False) + "\n"


def job(asset, smp) -> None:
    """Nothing beyond the label (the mask is read from disk when the image is written)."""
    return None


def write(out_dir, index: int, label: dict, job, png) -> list[Path]:
    """Write image ``index``'s fragment ``coco/NNNNNN.json`` (its mask is already in ``out_dir``)."""
    out = Path(out_dir)
    if "seg" not in label:
        raise ScanError(out, "label format coco needs the masks (render.masks: true)")
    w, h = label["image"]["width"], label["image"]["height"]
    seg = read_seg(out / label["seg"]["file"], (w, h))
    p = out / COCO_DIR / fragment_name(index)
    p.parent.mkdir(parents=True, exist_ok=True)
    write_text(p, _dumps(fragment(index, label, seg)))
    return [p]


def assemble(fragments) -> dict:
    """The COCO document of ``fragments`` (in image order): annotation ids 1, 2, ... in that order."""
    images, anns = [], []
    for fr in fragments:
        images.append(fr["image"])
        for a in fr["annotations"]:
            anns.append({"id": len(anns) + 1, **a})
    return {"info": {"description": "eyerig eye-region renders: keypoints (category eye) and segmentation "
                                    "classes; eyerig docs/labels.md", "version": "1"},
            "licenses": [], "images": images, "annotations": anns, "categories": categories()}


def finish(out_dir, n: int, settings) -> list[Path]:
    """Assemble ``coco.json`` of images ``0..n-1`` from their fragments; its path."""
    out = Path(out_dir)
    doc = assemble(read_fragment(out / COCO_DIR / fragment_name(i)) for i in range(n))
    write_text(out / COCO_FILE, _dumps(doc))
    return [out / COCO_FILE]
