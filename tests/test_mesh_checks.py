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
