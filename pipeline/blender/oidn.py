"""OpenImageDenoise through its C API (ctypes), with one device and filters kept for the worker's life.

Cycles builds a new OIDN device and new filters for every render it denoises (device start,
weight loading, network set-up): about a third of the denoiser's CPU time at 120 x 80. The
render worker renders without Cycles' denoiser and calls :class:`Denoiser` on the render's
noisy colour, albedo and normal passes instead, doing what Cycles' ``OIDNDenoiser`` does
(but for the normal prefilter's quality where the caller chooses its own):

* prefilter ``ACCURATE``: the albedo and the normal are denoised first, each by its own ``RT``
  filter, and the colour filter is told its auxiliary images are clean (``cleanAux``); the
  albedo and normal filters have their own quality (``aux_quality`` / ``normal_quality``:
  Cycles runs both at the colour's);
  ``NONE``: raw auxiliary images, ``cleanAux``; ``FAST``: raw auxiliary images, no ``cleanAux``;
* colour filter: ``hdr`` on (linear scene-referred input, OIDN picks the exposure itself),
  ``quality`` HIGH unless asked otherwise (at HIGH OIDN runs its large albedo and normal
  prefilter networks, BALANCED and FAST both its small ones: the same pixels);
* the CPU device with ``setAffinity`` off (Blender's own threads share the cores);
* the rows bottom-up, as they lie in Cycles' render buffers. The network is not symmetric
  under a vertical flip (the image is padded at one side to its block size): fed top-down,
  the same passes denoise 0.13 dB worse on bench_render_quality's frame (30.14 against
  30.27 dB at 10 spp), fed bottom-up they give Cycles' pixels exactly (checked against
  Cycles' own OIDN output buffer, read with gdb: difference 0).

The library is the one the ``bpy`` wheel ships (``bpy/lib/libOpenImageDenoise.so.2``), found
without importing ``bpy``; nothing here imports ``bpy``. :class:`OidnUnavailable` says why the
library or a device could not be had, so the worker can fall back to Cycles' denoiser.
"""

from __future__ import annotations

import ctypes
import importlib.util
from pathlib import Path

import numpy as np

DEVICE_TYPE_CPU = 1
FORMAT_FLOAT3 = 3
QUALITY = {"HIGH": 6, "BALANCED": 5, "FAST": 4}       # OIDNQuality (oidn.h)
PREFILTERS = ("ACCURATE", "NONE", "FAST")
LIBRARY_NAME = "libOpenImageDenoise.so.2"


class OidnUnavailable(RuntimeError):
    """The OIDN library could not be loaded or its CPU device not be created."""


def library_path() -> Path:
    """The OIDN library inside the installed ``bpy`` wheel (not imported), or OidnUnavailable."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise OidnUnavailable("the bpy package is not installed")
    return Path(next(iter(spec.submodule_search_locations))) / "lib" / LIBRARY_NAME


def _load(path: Path):
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        raise OidnUnavailable(f"{path}: cannot load ({exc})") from None
    vp, cp, sz = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t
    sigs = {"oidnNewDevice": (vp, [ctypes.c_int]), "oidnCommitDevice": (None, [vp]),
            "oidnReleaseDevice": (None, [vp]), "oidnSetDeviceBool": (None, [vp, cp, ctypes.c_bool]),
            "oidnSetDeviceInt": (None, [vp, cp, ctypes.c_int]),
            "oidnGetDeviceError": (ctypes.c_int, [vp, ctypes.POINTER(cp)]),
            "oidnNewFilter": (vp, [vp, cp]), "oidnReleaseFilter": (None, [vp]),
            "oidnSetSharedFilterImage": (None, [vp, cp, vp, ctypes.c_int, sz, sz, sz, sz, sz]),
            "oidnSetFilterBool": (None, [vp, cp, ctypes.c_bool]),
            "oidnSetFilterInt": (None, [vp, cp, ctypes.c_int]),
            "oidnCommitFilter": (None, [vp]), "oidnExecuteFilter": (None, [vp])}
    for name, (res, args) in sigs.items():
        try:
            f = getattr(lib, name)
        except AttributeError:
            raise OidnUnavailable(f"{path}: no symbol {name} (OIDN 2.x expected)") from None
        f.restype, f.argtypes = res, args
    return lib


class Denoiser:
    """A CPU OIDN device and, per image size and prefilter, the filters of one denoise.

    Parameters
    ----------
    path : the OIDN shared library (default :func:`library_path`)
    threads : OIDN worker threads (0 = OIDN's default, all cores)
    quality : ``HIGH`` | ``BALANCED`` | ``FAST`` of the colour filter
    aux_quality : the same for the albedo prefilter (default = ``quality``)
    normal_quality : the same for the normal prefilter (default = ``aux_quality``)
    """

    def __init__(self, path=None, threads: int = 0, quality: str = "HIGH", aux_quality: str | None = None,
                 normal_quality: str | None = None):
        aux_quality = aux_quality or quality
        normal_quality = normal_quality or aux_quality
        if any(q not in QUALITY for q in (quality, aux_quality, normal_quality)):
            raise ValueError(f"OIDN quality must be one of {tuple(QUALITY)}")
        self.path = Path(path) if path is not None else library_path()
        self.lib = _load(self.path)
        self.quality, self.aux_quality = QUALITY[quality], QUALITY[aux_quality]
        self.normal_quality = QUALITY[normal_quality]
        lib = self.lib
        self.device = lib.oidnNewDevice(DEVICE_TYPE_CPU)
        if not self.device:
            raise OidnUnavailable(f"{self.path}: no CPU device ({self._error(None)})")
        lib.oidnSetDeviceBool(self.device, b"setAffinity", False)
        if threads > 0:
            lib.oidnSetDeviceInt(self.device, b"numThreads", int(threads))
        lib.oidnCommitDevice(self.device)
        err = self._error(self.device)
        if err:
            raise OidnUnavailable(f"{self.path}: CPU device: {err}")
        self.size = None
        self.buf = {}
        self.filters = {}        # (prefilter, normal quality) -> [filters in execution order]

    def _error(self, device) -> str:
        msg = ctypes.c_char_p()
        code = self.lib.oidnGetDeviceError(device, ctypes.byref(msg))
        return "" if code == 0 else f"OIDN error {code}: {(msg.value or b'').decode(errors='replace')}"

    def _release_filters(self) -> None:
        for fs in self.filters.values():
            for f in fs:
                self.lib.oidnReleaseFilter(f)
        self.filters = {}

    def _filter(self, images: dict, quality: int, **flags):
        lib, (h, w) = self.lib, self.size
        f = lib.oidnNewFilter(self.device, b"RT")
        for name, key in images.items():
            lib.oidnSetSharedFilterImage(f, name.encode(), self.buf[key].ctypes.data, FORMAT_FLOAT3, w, h, 0, 0, 0)
        for k, v in flags.items():
            lib.oidnSetFilterBool(f, k.encode(), bool(v))
        lib.oidnSetFilterInt(f, b"quality", quality)
        lib.oidnCommitFilter(f)
        return f

    def _filters(self, prefilter: str, normal_quality: int) -> list:
        key = (prefilter, normal_quality)
        if key not in self.filters:
            q, qa, qn = self.quality, self.aux_quality, normal_quality
            if prefilter == "ACCURATE":
                fs = [self._filter({"albedo": "albedo", "output": "albedo_clean"}, qa),
                      self._filter({"normal": "normal", "output": "normal_clean"}, qn),
                      self._filter({"color": "color", "albedo": "albedo_clean", "normal": "normal_clean",
                                    "output": "output"}, q, hdr=True, cleanAux=True)]
            else:
                fs = [self._filter({"color": "color", "albedo": "albedo", "normal": "normal", "output": "output"},
                                   q, hdr=True, cleanAux=prefilter == "NONE")]
            err = self._error(self.device)
            if err:
                raise RuntimeError(f"OIDN filter set-up ({prefilter}): {err}")
            self.filters[key] = fs
        return self.filters[key]

    def denoise(self, color, albedo, normal, prefilter: str = "ACCURATE", normal_quality: str | None = None) -> np.ndarray:
        """Denoised (H, W, 3) float32 colour from the noisy colour, albedo and normal (each (H, W, 3),
        linear, any float dtype, top row first); ``normal_quality`` overrides the device's normal
        prefilter quality for this call. Filters are built on the first call for a size (and
        prefilter, normal quality) and kept."""
        if prefilter not in PREFILTERS:
            raise ValueError(f"prefilter {prefilter!r} not in {PREFILTERS}")
        if normal_quality is not None and normal_quality not in QUALITY:
            raise ValueError(f"normal_quality {normal_quality!r} not in {tuple(QUALITY)}")
        qn = self.normal_quality if normal_quality is None else QUALITY[normal_quality]
        c = np.asarray(color)
        if c.ndim != 3 or c.shape[2] != 3 or c.shape[0] < 1 or c.shape[1] < 1:
            raise ValueError(f"colour must be (H, W, 3), got {c.shape}")
        for name, a in (("albedo", albedo), ("normal", normal)):
            if np.shape(a) != c.shape:
                raise ValueError(f"{name} shape {np.shape(a)} differs from the colour's {c.shape}")
        if self.size != c.shape[:2]:
            self._release_filters()
            self.size = c.shape[:2]
            # the filters keep pointers to these arrays: they live as long as the filters
            self.buf = {k: np.zeros(c.shape, np.float32)
                        for k in ("color", "albedo", "normal", "albedo_clean", "normal_clean", "output")}
        np.copyto(self.buf["color"], c[::-1], casting="unsafe")       # bottom-up, as Cycles (module doc)
        np.copyto(self.buf["albedo"], np.asarray(albedo)[::-1], casting="unsafe")
        np.copyto(self.buf["normal"], np.asarray(normal)[::-1], casting="unsafe")
        for f in self._filters(prefilter, qn):
            self.lib.oidnExecuteFilter(f)
        err = self._error(self.device)
        if err:
            raise RuntimeError(f"OIDN denoise: {err}")
        return self.buf["output"][::-1].copy()

    def close(self) -> None:
        self._release_filters()
        if self.device:
            self.lib.oidnReleaseDevice(self.device)
            self.device = None
