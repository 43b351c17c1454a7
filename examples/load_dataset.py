"""Read an eyerig dataset folder into numpy arrays, with numpy and Pillow only.

    python examples/load_dataset.py DIR [--limit N]

DIR is what ``python -m stages.dataset ... --out DIR`` wrote. Everything needed is in
the folder itself: ``dataset.json`` (image size, the assets and their ids), ``index.jsonl``
(one line per image: its files and asset) and one JSON label per image (schema in DIR/README.md).
This script imports nothing from eyerig: copy it anywhere. It reads everything at once; for
training, examples/torch_dataset.py reads the same items lazily. Depth maps need OpenEXR
(``pip install OpenEXR``, >= 3); without it ``depth`` is None.

Printed: the shape of every array, images per asset, and two consistency checks made from the
labels alone (3D landmarks projected with the stored camera onto the stored pixels; unit gaze
vectors). Exit status 1 if a check fails.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def load_dataset(root, limit: int | None = None) -> dict:
    """The dataset at ``root`` as arrays (the first ``limit`` images when given).

    Returns
    -------
    dict with
        images : (N, H, W, 3) uint8          RGB, row 0 at the top
        landmarks : (N, 28, 2) float32       pixels: x right, y down, origin at the top-left
                                             pixel corner (pixel centres at +0.5); 0-11 eyelid,
                                             12-19 iris, 20-27 pupil
        landmarks_3d : (N, 28, 3) float32    the same points in the camera frame, mm
        gaze : (N, 3) float32                unit gaze vector of the imaged eye, camera frame
                                             (+X right, +Y up, the camera looks down -Z)
        gaze_angles : (N, 2) float32         its (pitch, yaw) in degrees (up, toward image right)
        visibility : (N, 28) bool            landmark seen in the image (label landmarks.visible;
                                             all True when the dataset has no masks: unknown)
        head_rotation : (N, 3, 3) float32    head frame -> camera frame (head_pose)
        head_angles : (N, 2) float32         (pitch, yaw) in degrees of the direction from the
                                             head toward the camera, head frame
        projection : (N, 3, 4) float32       camera mm -> homogeneous pixels
        asset_ids : (N,) int32               index into ``asset_names``
        asset_names : list of str
        eye : (N,) str                       'left' or 'right' (the subject's)
        masks : (N, H, W) uint8 or None      class ids per pixel (names in info["masks"]["classes"]),
                                             when the dataset has masks
        depth : (N, H, W) float32 or None    camera mm, inf where nothing is seen, when the
                                             dataset has masks and OpenEXR is installed
        info : dict                          dataset.json
    """
    root = Path(root)
    info = json.loads((root / "dataset.json").read_text(encoding="utf-8"))
    rows = [json.loads(line) for line in (root / "index.jsonl").read_text(encoding="utf-8").splitlines()
            if line.strip()]
    if limit is not None:
        rows = rows[:limit]
    n, h, w = len(rows), info["image"]["height"], info["image"]["width"]
    out = {"images": np.zeros((n, h, w, 3), np.uint8),
           "landmarks": np.zeros((n, 28, 2), np.float32),
           "landmarks_3d": np.zeros((n, 28, 3), np.float32),
           "gaze": np.zeros((n, 3), np.float32),
           "gaze_angles": np.zeros((n, 2), np.float32),
           "projection": np.zeros((n, 3, 4), np.float32),
           "visibility": np.ones((n, 28), bool),
           "head_rotation": np.zeros((n, 3, 3), np.float32),
           "head_angles": np.zeros((n, 2), np.float32),
           "asset_ids": np.zeros(n, np.int32),
           "asset_names": [a["name"] for a in sorted(info["assets"], key=lambda a: a["id"])],
           "eye": np.empty(n, "<U5"),
           "masks": None,
           "depth": None,
           "info": info}
    masks = info.get("masks")                 # {"file", "format", "classes": {id: name}} or null
    if masks:
        out["masks"] = np.zeros((n, h, w), np.uint8)
    try:
        import OpenEXR                        # depth maps: optional
    except ImportError:
        OpenEXR = None
    if masks and OpenEXR is not None:
        out["depth"] = np.zeros((n, h, w), np.float32)
    for k, row in enumerate(rows):
        label = json.loads((root / row["json"]).read_text(encoding="utf-8"))
        with Image.open(root / row["png"]) as im:
            out["images"][k] = np.asarray(im.convert("RGB"))
        lm = label["landmarks"]
        out["landmarks"][k] = lm["px"]
        out["landmarks_3d"][k] = lm["camera_mm"]
        out["gaze"][k] = label["gaze"]["vector_camera"]
        out["gaze_angles"][k] = (label["gaze"]["camera"]["pitch_deg"], label["gaze"]["camera"]["yaw_deg"])
        out["projection"][k] = label["camera"]["projection"]
        out["asset_ids"][k] = label["asset"]["id"]
        out["eye"][k] = label["gaze"]["eye"]
        if "visible" in lm:
            out["visibility"][k] = lm["visible"]
        hp = label["head_pose"]
        out["head_rotation"][k] = hp["rotation_head_to_camera"]
        out["head_angles"][k] = (hp["camera_pitch_deg"], hp["camera_yaw_deg"])
        if out["depth"] is not None and label.get("depth"):    # "NNNNNN_depth.exr", channel Z
            with OpenEXR.File(str(root / label["depth"]["file"])) as f:
                out["depth"][k] = f.channels()["Z"].pixels
        if masks:                             # "NNNNNN_seg.png": indexed PNG, the index is the class id
            with Image.open(root / masks["file"].replace("NNNNNN", f"{row['index']:06d}")) as im:
                out["masks"][k] = np.asarray(im)
    return out


def check(data: dict) -> dict:
    """Consistency from the labels alone: reprojection error (px) and gaze norm error."""
    P, C = data["projection"].astype(np.float64), data["landmarks_3d"].astype(np.float64)
    H = np.einsum("nij,nkj->nki", P, np.concatenate([C, np.ones(C.shape[:2] + (1,))], axis=2))
    reproj = np.abs(H[..., :2] / H[..., 2:] - data["landmarks"]).max() if len(C) else 0.0
    norm = np.abs(np.linalg.norm(data["gaze"], axis=1) - 1).max() if len(C) else 0.0
    return {"reprojection_px_max": float(reproj), "gaze_norm_error_max": float(norm)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", type=Path, help="the dataset folder")
    ap.add_argument("--limit", type=int, default=None, help="read only the first N images")
    args = ap.parse_args(argv)
    data = load_dataset(args.root, args.limit)
    for key in ("images", "landmarks", "landmarks_3d", "gaze", "gaze_angles", "visibility", "head_rotation",
                "head_angles", "asset_ids", "eye", "masks", "depth"):
        v = data[key]
        print(f"{key:13s}", "none" if v is None else f"{v.shape} {v.dtype}")
    counts = np.bincount(data["asset_ids"], minlength=len(data["asset_names"]))
    print("per asset    ", ", ".join(f"{name}: {c}" for name, c in zip(data["asset_names"], counts)))
    c = check(data)
    print(f"checks        landmarks reproject within {c['reprojection_px_max']:.2g} px; "
          f"gaze norm within {c['gaze_norm_error_max']:.2g}")
    ok = c["reprojection_px_max"] < 0.01 and c["gaze_norm_error_max"] < 1e-4
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
