"""Cleaning a decimated mesh without opening holes (pipeline/retopo/mesh_clean.py)."""

from __future__ import annotations

import numpy as np

from pipeline.geometry import meshtopo
from pipeline.retopo.mesh_clean import clean_mesh


def test_a_collinear_cap_is_flipped_not_dropped():
    # a(0,0) b(2,0) d(1,1) above; c(1,0) on the segment ab below it, e(1,-1) under it: the cap
    # (b, a, c) has zero area; dropping it would leave a hole along a-c-b
    V = np.array([[0, 0, 0], [2, 0, 0], [1, 0, 0], [1, 1, 0], [1, -1, 0.0]])
    a, b, c, d, e = range(5)
    F = np.array([[a, b, d], [b, a, c], [a, e, c], [c, e, b]])
    assert meshtopo.boundary_component_count(F) == 1
    V2, F2 = clean_mesh(V, F)
    assert len(F2) == 4 and meshtopo.boundary_component_count(F2) == 1
    area = 0.5 * np.linalg.norm(np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]]), axis=1)
    assert area.min() > 0.1 and np.isclose(area.sum(), 2.0)
    n = np.cross(V2[F2[:, 1]] - V2[F2[:, 0]], V2[F2[:, 2]] - V2[F2[:, 0]])
    assert (n[:, 2] > 0).all()                                        # orientation kept


def test_vertices_on_one_spot_are_welded():
    # a fan of six faces round the centre; three of them use a copy of the centre 1e-13 mm away
    # (what the decimation leaves): a crack, and the faces between the copies degenerate
    t = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t), 0 * t], 1)
    V = np.concatenate([[[0, 0, 0.0], [1e-13, 0, 0]], ring])
    F = np.array([[0 if k < 3 else 1, 2 + k, 2 + (k + 1) % 6] for k in range(6)])
    V2, F2 = clean_mesh(V, F)
    assert len(V2) == 7 and len(F2) == 6
    assert meshtopo.boundary_component_count(F2) == 1 and meshtopo.is_edge_manifold(F2)
