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


def test_many_points_asked_in_morton_order_get_libigls_own_answers():
    """Over _SORT_FROM points go to libigl along a Morton curve and come back in the caller's
    order: the bits libigl gives each point asked in the caller's order (a NaN point included)."""
    import igl

    V, F = _grid(40)
    rng = np.random.default_rng(1)
    P = rng.random((mc._SORT_FROM + 500, 3)) * [1.2, 1.2, 0.6] - [0.1, 0.1, 0.3]
    P[7] = [np.nan, 0.5, 0.5]
    order = mc._morton_order(P)
    assert sorted(order.tolist()) == list(range(len(P))) and not np.array_equal(order, np.arange(len(P)))
    # neighbours in the order are near in space: far shorter steps than the random order's
    step = np.linalg.norm(np.diff(P[order[order != 7]], axis=0), axis=1).mean()
    assert step < 0.25 * np.linalg.norm(np.diff(P[np.arange(len(P)) != 7], axis=0), axis=1).mean()
    tree = igl.AABB()
    tree.init(V, F)
    sq, fi, C = tree.squared_distance(V, F, P)
    mc._TREES.clear()
    d, f, c = mc.closest_points(P, V, F)
    ok = np.arange(len(P)) != 7
    assert np.sqrt(np.maximum(sq[ok], 0)).tobytes() == d[ok].tobytes()
    assert np.asarray(fi)[ok].tobytes() == f[ok].tobytes() and np.asarray(C)[ok].tobytes() == c[ok].tobytes()


def test_surface_face_normals_rows_are_each_faces_own_normal():
    """The kept normals of a mesh are, row by row, the bits of face_normals of those faces alone
    (the repairs gather rows where they computed the normals of the faces they landed on)."""
    V, F = _grid()
    rng = np.random.default_rng(1)
    idx = rng.integers(0, len(F), 700)
    N = mc.surface_face_normals(V, F)
    assert N[idx].tobytes() == mc.face_normals(V, F[idx]).tobytes()
    assert not N.flags.writeable
    W = V.copy()
    W[5] += [0.0, 0.0, 0.3]                            # another mesh: its own normals
    moved = np.isin(F, 5).any(axis=1)
    NW = mc.surface_face_normals(W, F)
    assert NW.tobytes() == mc.face_normals(W, F).tobytes()
    assert not np.allclose(NW[moved], N[moved]) and np.array_equal(NW[~moved], N[~moved])
