"""closest_points: answers kept from the last query of as many points are those a fresh query gives."""

import numpy as np

from pipeline.geometry import mesh_checks as mc


def _grid(n=30):
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.stack([u.ravel(), v.ravel(), 0.1 * np.sin(3 * u.ravel()) * np.cos(2 * v.ravel())], axis=1)
    i = np.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).ravel()
    F = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return V, F


def test_closest_points_after_a_few_points_moved_match_a_fresh_query():
    V, F = _grid()
    rng = np.random.default_rng(0)
    P = rng.random((500, 3)) * [1, 1, 0.4] - [0, 0, 0.2]
    mc._TREES.clear()
    mc.closest_points(P, V, F)
    Q = P.copy()
    Q[[3, 77, 400]] += 0.05
    got = mc.closest_points(Q, V, F)
    again = mc.closest_points(Q, V, F)                 # nothing moved since
    mc._TREES.clear()
    fresh = mc.closest_points(Q, V, F)
    for g, a, f in zip(got, again, fresh):
        assert g.tobytes() == f.tobytes() and a.tobytes() == f.tobytes()
    got[2][:] = 0.0                                    # the caller's arrays are its own
    assert mc.closest_points(Q, V, F)[2].tobytes() == fresh[2].tobytes()


def test_same_bits_compares_every_byte():
    """The tree cache's byte comparison: chunked 8-byte words, a difference in the last chunk or
    in an odd-sized array's tail found, -0.0 told from 0.0, a NaN equal to itself."""
    from pipeline.geometry.mesh_checks import _same_bits

    a = np.random.default_rng(0).random((100_000, 3))
    assert _same_bits(a, a.copy()) and not _same_bits(a, a.reshape(3, -1).copy())
    b = a.copy()
    b[-1, 2] = np.nextafter(b[-1, 2], 2.0)
    assert not _same_bits(a, b)
    z, nz = np.zeros(4), np.zeros(4)
    nz[3] = -0.0
    assert not _same_bits(z, nz) and _same_bits(np.full(3, np.nan), np.full(3, np.nan))
    c = np.arange(7, dtype=np.uint8)
    d = c.copy()
    d[6] = 9
    assert _same_bits(c, c.copy()) and not _same_bits(c, d)
    assert not _same_bits(np.zeros(3, dtype=np.int64), np.zeros(3))
