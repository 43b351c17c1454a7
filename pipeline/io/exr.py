"""Single-channel float32 OpenEXR read/write (OpenEXR >= 3 python API) and 16-bit PNG previews:
the codec of the EXR products (the bake's displacement map, a render's depth map)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_exr(path, img, channel="Y"):
    """Write an (H, W) float image as a 32-bit float, zip-compressed EXR."""
    import OpenEXR

    a = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if a.ndim != 2:
        raise ValueError("write_exr expects an (H, W) image")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {channel: a}) as f:
        f.write(str(path))


def read_exr(path, channel="Y"):
    """Read one channel of an EXR as an (H, W) float32 array."""
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if channel not in ch:
            raise ValueError(f"{path}: no channel {channel!r} (has {sorted(ch)})")
        return np.array(ch[channel].pixels, dtype=np.float32)


def read_exr_product(path, channel: str, unreadable: str):
    """One channel of an EXR product as (H, W) float32, or a ScanError naming ``path``: missing,
    or not decodable with that channel (``unreadable``, then the decoder's complaint)."""
    from pipeline.errors import ScanError

    path = Path(path)
    if not path.is_file():
        raise ScanError(path, "not found")
    try:
        return read_exr(path, channel)
    except Exception as exc:  # noqa: BLE001 -- OpenEXR raises several types for unreadable files
        raise ScanError(path, f"{unreadable} ({type(exc).__name__}: {exc})") from None


def preview_16bit(img, mask=None):
    """Map a float image to uint16 with a recorded scale/offset: ``value = offset + scale * pixel``.

    Returns
    -------
    (H, W) uint16, scale (float), offset (float)
    """
    a = np.asarray(img)
    if a.dtype.kind != "f":
        a = a.astype(np.float64)
    vals = a[mask] if mask is not None and mask.any() else a.ravel()
    # min and max of the image's own floats: the same numbers as of their float64 copies
    lo, hi = float(vals.min()), float(vals.max())
    if hi <= lo:
        hi = lo + 1e-6
    scale = (hi - lo) / 65535.0
    q = np.empty(a.shape, dtype=np.uint16)
    flat_a, flat_q = a.reshape(-1), q.reshape(-1)
    n = 1 << 18
    for i in range(0, flat_a.size, n):     # in float64 a piece at a time: no 32 MB temporaries
        flat_q[i:i + n] = np.clip(np.round((flat_a[i:i + n].astype(np.float64) - lo) / scale), 0, 65535)
    return q, scale, lo
