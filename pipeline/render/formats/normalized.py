"""Label format ``normalized``: ETH-XGaze's normalised eye crop of every image, with its labels.

Per image ``NNNNNN`` (pipeline/render/normalize.py has the formulas and their sources):

* ``normalized/NNNNNN.png``: the crop, ``render.normalized_size_px`` (default 128 x 128, ETH-XGaze's
  eye crops; ``[60, 36]`` with ``normalized_focal_px: 960`` is MPIIGaze's), 8-bit RGB, black where
  the virtual camera sees past the rendered image;
* ``normalized/NNNNNN_seg.png``: the mask warped alike (nearest neighbour, the same classes and
  palette as ``NNNNNN_seg.png``; 255 where the source is outside the image), when the render has masks;
* ``normalized/NNNNNN.json``: the warp (both pixel conventions), rotation ``R``, scale ``S``, the
  virtual camera, the eye centre it is taken about, the normalised gaze and head pose (ETH-XGaze's
  conventions) and the 28 landmarks warped.

The virtual camera is ``render.normalized_focal_px`` px at ``render.normalized_distance_mm`` mm from
the eye centre (``render.normalized_center``: ``eyeball``, the rotation centre, or ``canthi``, the
eye corners' midpoint as ETH-XGaze's and MPIIGaze's face models give it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.io.atomic import atomic_file, write_json

NAME = "normalized"
FOLDER = "normalized"
FILES = {
    f"{FOLDER}/NNNNNN.png": "the ETH-XGaze-normalised eye crop of image NNNNNN (render.normalized_size_px), "
                            "8-bit RGB, black outside the rendered image",
    f"{FOLDER}/NNNNNN_seg.png": "its segmentation mask warped alike (nearest; class ids as NNNNNN_seg.png, "
                                "255 outside the rendered image)",
    f"{FOLDER}/NNNNNN.json": "its warp (rotation R, scale S, K_norm, W = K_norm S R K^-1 in label and OpenCV "
                             "pixels), eye centre, normalised gaze and head pose (ETH-XGaze conventions), "
                             "landmarks warped",
}
#: Reads the settings (format_job passes them).
READS_SETTINGS = True


def job(asset, smp, settings=None) -> dict:
    """The virtual camera of the settings (pipeline/render/settings.py ``normalized_*``)."""
    from pipeline.render.normalize import PROFILES

    d = PROFILES["eth_xgaze"]
    if settings is None:
        return {"size_px": list(d["size_px"]), "focal_px": d["focal_px"], "distance_mm": d["distance_mm"],
                "center": "eyeball"}
    return {"size_px": [int(x) for x in settings.normalized_size_px], "focal_px": float(settings.normalized_focal_px),
            "distance_mm": float(settings.normalized_distance_mm), "center": settings.normalized_center}


def _save_png(path: Path, img) -> None:
    with atomic_file(path) as tmp:
        img.save(tmp, format="PNG")


def write(out_dir, index: int, label: dict, job, png) -> list[Path]:
    """Write image ``index``'s crop, mask (when the render has one) and label; their paths."""
    from PIL import Image

    from pipeline.io.seg_file import palette
    from pipeline.render import normalize as nz

    job = job or globals()["job"](None, None)
    out = Path(out_dir) / FOLDER
    out.mkdir(parents=True, exist_ok=True)
    n = nz.normalization(label, job["size_px"], job["focal_px"], job["distance_mm"], job["center"])
    with Image.open(png) as im:
        rgb = np.asarray(im.convert("RGB"))
    paths = [out / f"{index:06d}.png"]
    _save_png(paths[0], Image.fromarray(nz.warp_image(rgb, n["warp_opencv"], n["size_px"])))
    seg = Path(out_dir) / f"{index:06d}_seg.png"
    if seg.is_file():
        with Image.open(seg) as im:
            ids = np.asarray(im)                     # mode P: the class ids themselves
        warped = nz.warp_image(ids, n["warp_opencv"], n["size_px"], nearest=True, fill=nz.OUTSIDE)
        m = Image.fromarray(warped.astype(np.uint8), mode="P")
        pal = palette()
        pal[3 * nz.OUTSIDE:3 * nz.OUTSIDE + 3] = [128, 128, 128]
        m.putpalette(pal)
        paths.append(out / f"{index:06d}_seg.png")
        _save_png(paths[-1], m)
    paths.append(out / f"{index:06d}.json")
    write_json(paths[-1], nz.normalized_label(label, n))
    return paths
