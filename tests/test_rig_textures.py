"""The smoothed colour and displacement variant for down-looking lids (pipeline/rig/textures.py)."""

from __future__ import annotations

import numpy as np
import pytest


def test_smoothed_variant_mixes_by_mask():
    from pipeline.rig import textures as tex

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (64, 64, 3), dtype=np.uint8)
    zero = np.zeros((64, 64))
    np.testing.assert_array_equal(tex.smoothed_variant(img, zero, 3.0), img)
    out = tex.smoothed_variant(img, np.ones((64, 64)), 3.0)
    assert out.dtype == np.uint8 and out.std() < 0.3 * img.std()
    disp = rng.normal(0, 0.2, (32, 48)).astype(np.float32)
    half = np.zeros((32, 48))
    half[:, 24:] = 1.0
    sm = tex.smoothed_variant(disp, half, 2.0)
    assert sm.dtype == np.float32
    np.testing.assert_array_equal(sm[:, :24], disp[:, :24])
    assert sm[:, 30:].std() < 0.5 * disp[:, 30:].std()
    const = np.full((16, 16), 0.7, np.float32)
    np.testing.assert_allclose(tex.smoothed_variant(const, np.ones((16, 16)), 4.0), const, rtol=1e-6)


def test_uv_rasterisation_and_texel_density():
    from pipeline.rig import textures as tex

    V = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = V[:, :2] / 10.0
    assert tex.texels_per_mm(V, F, UV, F, (100, 100)) == pytest.approx(10.0)
    values = V[:, 0] / 10.0                       # u itself
    img = tex.rasterize_vertex_scalar(UV, F, F, values, (50, 40))
    xs = (np.arange(50) + 0.5) / 50
    np.testing.assert_allclose(img, np.broadcast_to(xs, (40, 50)), atol=1e-9)
    mask = tex.motion_mask(4, np.array([1, 2]), np.array([[0, 2.0, 0], [0, 1.0, 0]]), power=1.0)
    np.testing.assert_allclose(mask, [0, 1.0, 0.5, 0])
