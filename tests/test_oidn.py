"""The worker's own OpenImageDenoise filters (pipeline/blender/oidn.py) and its film
(pipeline/blender/film.py): ctypes OIDN from the bpy wheel, without importing bpy."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.blender.film import standard_view_srgb8
from pipeline.blender.oidn import Denoiser, OidnUnavailable, library_path


def _lib_or_skip():
    try:
        path = library_path()
    except OidnUnavailable as exc:
        pytest.skip(str(exc))
    if not path.is_file():
        pytest.skip(f"{path}: not installed")
    return path


def _scene(h=48, w=64, spp=4, seed=0):
    """A clean (H, W, 3) image of flat-shaded tiles, its albedo and normal, and a Monte-Carlo-like
    noisy estimate of it: the mean of ``spp`` exponential samples per pixel (unbiased, heavy tail)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    tile = (yy // 12) * 8 + xx // 16
    albedo = rng.uniform(0.1, 0.9, (tile.max() + 1, 3))[tile]
    shade = 0.4 + 0.6 * (xx / w)[..., None]
    clean = albedo * shade
    normal = np.zeros((h, w, 3))
    normal[..., 2] = 1.0
    noisy = clean * rng.exponential(1.0, (spp, h, w, 3)).mean(0)
    return clean, noisy, albedo, normal


def test_denoising_lowers_the_error_against_the_clean_image():
    path = _lib_or_skip()
    clean, noisy, albedo, normal = _scene()
    d = Denoiser(path, threads=1)
    mse_noisy = np.mean((noisy - clean) ** 2)
    for prefilter in ("ACCURATE", "NONE", "FAST"):
        out = d.denoise(noisy, albedo, normal, prefilter)
        assert out.shape == clean.shape and out.dtype == np.float32
        assert np.mean((out - clean) ** 2) < mse_noisy / 10, prefilter
    d.close()


def test_filters_follow_the_image_size_and_repeat_exactly():
    path = _lib_or_skip()
    d = Denoiser(path, threads=1)
    a = _scene(48, 64)
    b = _scene(20, 30, seed=1)
    out_a = d.denoise(*a[1:])
    out_b = d.denoise(*b[1:])                      # a new size: filters rebuilt for it
    assert out_b.shape == (20, 30, 3)
    assert np.mean((out_b - b[0]) ** 2) < np.mean((b[1] - b[0]) ** 2) / 4
    assert np.array_equal(d.denoise(*a[1:]), out_a)   # back to the first size: same result
    with pytest.raises(ValueError, match="albedo shape"):
        d.denoise(a[1], b[2], a[3])
    with pytest.raises(ValueError, match="prefilter"):
        d.denoise(*a[1:], prefilter="BEST")


def test_a_missing_library_says_so(tmp_path):
    missing = tmp_path / "libOpenImageDenoise.so.2"
    with pytest.raises(OidnUnavailable, match="cannot load"):
        Denoiser(missing)
    not_oidn = tmp_path / "libnot.so"
    not_oidn.write_bytes(b"not an ELF file")
    with pytest.raises(OidnUnavailable, match=str(not_oidn)):
        Denoiser(not_oidn)


def test_standard_view_is_the_srgb_oetf_rounded():
    lin = np.array([[[0.0, 1.0, 2.0], [0.0031308, 0.5, 0.18], [-1.0, np.nan, 0.001]]])
    out = standard_view_srgb8(lin)
    # 0.0031308 -> 12.92 x = 0.04045 -> 10.3; 0.5 -> 0.7354 -> 187.5; 0.18 -> 0.4614 -> 117.7; 0.001 -> 3.3
    assert out.tolist() == [[[0, 255, 255], [10, 188, 118], [0, 0, 3]]]
    assert out.dtype == np.uint8
    # exposure in stops: one stop up = twice the linear light
    assert np.array_equal(standard_view_srgb8(lin[:, 1:2] / 2, exposure=1.0), out[:, 1:2])


def test_the_normal_prefilter_quality_is_its_own():
    """``normal_quality`` (the render worker's FAST normal prefilter): its own filters, kept beside
    the device default's; at HIGH the pixels are those of a device built all HIGH."""
    path = _lib_or_skip()
    clean, noisy, albedo, normal = _scene()
    rng = np.random.default_rng(3)
    normal = normal + 0.2 * rng.normal(size=normal.shape)       # a noisy normal pass to prefilter
    high = Denoiser(path, threads=1)
    fast = Denoiser(path, threads=1, normal_quality="FAST")
    a = high.denoise(noisy, albedo, normal)
    b = fast.denoise(noisy, albedo, normal)
    assert np.array_equal(fast.denoise(noisy, albedo, normal, normal_quality="HIGH"), a)
    assert np.array_equal(fast.denoise(noisy, albedo, normal), b)           # both filter sets kept
    assert np.mean((b - clean) ** 2) < np.mean((noisy - clean) ** 2) / 10
    with pytest.raises(ValueError, match="normal_quality"):
        fast.denoise(noisy, albedo, normal, normal_quality="BEST")
    with pytest.raises(ValueError, match="quality"):
        Denoiser(path, normal_quality="BEST")
    high.close()
    fast.close()
