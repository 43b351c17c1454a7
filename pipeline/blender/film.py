"""The render worker's film: the render result's passes read back, and the PNG made from them.

* :func:`render_passes` saves the last render's passes (Combined, the denoising albedo and
  normal, Z, the seg AOVs) to one uncompressed multilayer EXR and reads them back: Blender's
  Python API gives no other access to a render result's pixels without the compositor.
* :func:`standard_view_srgb8` is Blender's "Standard" view transform on the sRGB display
  (look None, gamma 1) for the 8-bit PNG: exposure ``2**stops``, clip to [0, 1], the sRGB
  OETF (linear below 0.0031308, else ``1.055 x^(1/2.4) - 0.055``), rounded to the nearest of
  255 levels. Blender adds a +-1 level dither (``render.dither_intensity`` 1) when it writes
  PNGs itself; here it is left out, so one image is one set of bytes (measured against
  Blender's own PNG of the same render: at most 1 level apart, mean difference 0.0005 level).
* :func:`write_png_rgb` writes it without time or text chunks; :func:`write_film_png` is the
  worker's whole step: the noisy colour, denoised by the worker's OIDN filters when given,
  through the view transform into the PNG.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np

SRGB_LINEAR_BELOW = 0.0031308


def standard_view_srgb8(rgb, exposure: float = 0.0) -> np.ndarray:
    """(H, W, 3) uint8 display values of linear scene-referred (H, W, 3) RGB (NaN -> 0)."""
    x = np.asarray(rgb, np.float64) * (2.0 ** float(exposure))
    x = np.clip(np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    v = np.where(x <= SRGB_LINEAR_BELOW, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.floor(v * 255.0 + 0.5).astype(np.uint8)


def write_png_rgb(path, rgb8) -> None:
    """Write (H, W, 3) uint8 as an 8-bit RGB PNG (no metadata chunks) to ``path``."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb8, np.uint8), mode="RGB").save(buf, format="PNG", compress_level=6)
    with open(path, "wb") as f:
        f.write(buf.getvalue())


def write_film_png(path, passes: dict, exposure: float, denoiser=None, prefilter: str = "ACCURATE",
                   normal_quality: str | None = None):
    """The worker's PNG at ``path`` from the render's ``passes`` (:func:`render_passes`): the
    noisy colour, denoised by ``denoiser`` (a :class:`pipeline.blender.oidn.Denoiser`, with the
    denoising albedo and normal; ``normal_quality`` for its normal prefilter, None = the
    denoiser's own) when given, through the Standard view at ``exposure`` stops.
    Returns the denoiser's wall and CPU seconds (0 without it)."""
    rgb = passes["Combined"][..., :3]
    t_den = c_den = 0.0
    if denoiser is not None:
        t0, c0 = time.perf_counter(), time.process_time()
        rgb = denoiser.denoise(rgb, passes["Denoising Albedo"], passes["Denoising Normal"], prefilter,
                                normal_quality)
        t_den, c_den = time.perf_counter() - t0, time.process_time() - c0
    write_png_rgb(path, standard_view_srgb8(rgb, exposure))
    return t_den, c_den


def render_passes(bpy, scene, path) -> dict:
    """The last render's passes by name (view-layer prefix dropped), via the multilayer EXR
    ``path`` (a scratch file, removed before returning).

    Returns
    -------
    dict  ``"Combined"`` (H, W, 4), ``"Denoising Albedo"`` / ``"Denoising Normal"`` (H, W, 3),
          AOVs (H, W, 3), ``"Depth"`` (H, W), ... float32, top row first; only the passes enabled
    """
    import OpenEXR

    path = Path(path)
    s = scene.render.image_settings
    old = (s.media_type, s.file_format, s.color_depth)
    s.media_type = "MULTI_LAYER_IMAGE"            # Blender 5: file_format becomes OPEN_EXR_MULTILAYER
    s.color_depth = "32"
    s.exr_codec = "NONE"
    ch = {}
    try:
        bpy.data.images["Render Result"].save_render(str(path), scene=scene)
        with OpenEXR.File(str(path)) as f:
            for part in f.parts:
                ch.update({k: np.asarray(v.pixels, np.float32) for k, v in part.channels.items()})
    finally:
        s.media_type = old[0]
        s.file_format = old[1]
        s.color_depth = old[2]
        path.unlink(missing_ok=True)      # a scratch file beside the image
    prefix = scene.view_layers[0].name + "."
    out, split = {}, {}
    for k, v in ch.items():
        name = k[len(prefix):] if k.startswith(prefix) else k
        base, _, comp = name.rpartition(".")
        if base and comp in ("X", "Y", "Z", "R", "G", "B", "A", "V") and v.ndim == 2:
            split.setdefault(base, {})[comp] = v      # a pass the python OpenEXR left as single channels
        else:
            out[name] = v
    for base, comps in split.items():
        if len(comps) == 1:
            out[base] = next(iter(comps.values()))
            out[f"{base}.{next(iter(comps))}"] = out[base]
        else:
            order = [c for c in ("X", "Y", "Z", "R", "G", "B", "A") if c in comps]
            out[base] = np.stack([comps[c] for c in order], axis=-1)
    return out
