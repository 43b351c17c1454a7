"""Scanner holes in the skin: mesh_edit.fill_holes_smooth (known answers on a plane and a sphere)
and retopo filling the scan's holes inside its crop, so the asset's only boundaries are the crop's
border and the two eye openings (issue 30, item 5)."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures import face_patch, height
from pipeline.geometry import mesh_checks as mc
from pipeline.geometry.mesh_edit import fill_holes_smooth
from pipeline.retopo.retopo import RetopoSettings, retopologize


def _grid(n=41, step=0.5):
    xs = (np.arange(n) - n // 2) * step
    X, Y = np.meshgrid(xs, xs)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    a = (np.arange(n - 1)[None, :] + n * np.arange(n - 1)[:, None]).ravel()
    F = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    return V, F


def _punch(V, F, centre, radius):
    """``F`` without the faces whose centroid lies within ``radius`` of ``centre`` (in x, y)."""
    c = V[F].mean(axis=1)
    return F[np.linalg.norm(c[:, :2] - np.asarray(centre)[:2], axis=1) > radius]


def _hole_loops(F, n_outer=1):
    loops = sorted(mc.boundary_loops(F), key=len)
    return loops[:len(loops) - n_outer]


def test_plane_hole_filled_flat_and_closed():
    V, F = _grid()
    F = _punch(V, F, (0.3, -0.2), 3.0)
    holes = _hole_loops(F)
    assert len(holes) == 1
    V2, F2 = fill_holes_smooth(V, F, holes)
    rep = mc.check_mesh(V2, F2)
    assert rep.manifold and rep.degenerate_faces == 0
    assert rep.boundary_loops == 1                                  # only the grid's border
    assert np.abs(V2[len(V):, 2]).max() < 1e-9                      # on the plane
    assert len(V2) - len(V) > 1                                     # rings, not one fan vertex
    # every fill face faces the way its neighbours do (+z)
    n = mc.face_normals(V2, F2[len(F):], normalize=True)
    assert (n[:, 2] > 0.99).all()
    assert (F2[:len(F)] == F).all()                                 # old faces keep their ids


def test_sphere_hole_follows_the_curvature():
    R = 50.0
    V, F = _grid(n=61, step=0.5)
    V[:, 2] = np.sqrt(R * R - V[:, 0] ** 2 - V[:, 1] ** 2) - R      # a cap of a 50 mm sphere
    F = _punch(V, F, (2.0, 1.0), 4.0)
    holes = _hole_loops(F)
    V2, F2 = fill_holes_smooth(V, F, holes)
    assert mc.check_mesh(V2, F2).boundary_loops == 1
    new = V2[len(V):]
    off = np.linalg.norm(new - [0.0, 0.0, -R], axis=1) - R
    # a flat fan's centre would sit sag = r^2 / 2R = 0.16 mm inside the sphere
    assert np.abs(off).max() < 0.01


def test_either_loop_direction_gives_the_same_orientation():
    V, F = _grid()
    F = _punch(V, F, (0.0, 0.0), 2.0)
    loop = _hole_loops(F)[0]
    A = fill_holes_smooth(V, F, [loop])
    B = fill_holes_smooth(V, F, [loop[::-1]])
    assert mc.check_mesh(*A).inconsistent_edges == 0 and mc.check_mesh(*B).inconsistent_edges == 0


def test_a_crescent_hole_is_closed_without_a_fold():
    """A harmonic grid onto a non-convex loop can fold (Tutte's theorem holds for convex ones):
    on a crescent 1 mm wide round 300 deg it turned 1422 of its 3486 faces over, and a sparse
    scan's 15 mm slit beside the nose (``n1504_sparse_samples``) 115 of 371. Such a loop is
    closed by its own vertices, every face the way the plane faces."""
    V, F = _grid(n=61, step=0.25)
    c = V[F].mean(axis=1)
    r = np.linalg.norm(c[:, :2], axis=1)
    a = np.degrees(np.arctan2(c[:, 1], c[:, 0]))
    F = F[~((r > 2.5) & (r < 3.5) & (np.abs(a) < 160))]
    holes = _hole_loops(F)
    assert len(holes) == 1
    V2, F2 = fill_holes_smooth(V, F, holes)
    rep = mc.check_mesh(V2, F2)
    assert rep.manifold and rep.degenerate_faces == 0 and rep.boundary_loops == 1
    n = mc.face_normals(V2, F2[len(F):], normalize=True)
    assert (n[:, 2] > 0.99).all()
    assert np.abs(V2[len(V):, 2]).max() < 1e-9                      # on the plane
    # inner vertices where the slit is wide, each inside the crescent
    r_new = np.linalg.norm(V2[len(V):, :2], axis=1)
    assert len(r_new) > 0 and ((r_new > 2.4) & (r_new < 3.6)).all()


def test_ear_clip_of_a_loop_pinched_at_a_point():
    """Two squares touching at one corner, walked as one loop through two copies of that corner
    (a scan's hole pinched at a bow-tie): each lobe is clipped alone, every face positive."""
    from pipeline.geometry.mesh_edit import _ear_clip, _signed_areas

    P = np.array([[0, 0], [1, 0], [1, 1], [0, 1],               # one square, to the corner...
                  [0, 2], [-1, 2], [-1, 1], [0, 1.0]])           # ...the other, to its copy
    T = _ear_clip(P)
    assert T is not None and len(T) == 4                           # two squares, two faces each
    assert (_signed_areas(P, T) > 0).all()
    assert np.isclose(_signed_areas(P, T).sum(), 2.0)
    assert _ear_clip(P[::-1]) is not None and (_signed_areas(P[::-1], _ear_clip(P[::-1])) > 0).all()


@pytest.fixture(scope="module")
def holed_patch():
    V, F, eyes = face_patch()
    F = _punch(V, F, (0.0, 50.0), 2.5)       # between the brows
    F = _punch(V, F, (45.0, 15.0), 1.5)      # on the cheek
    F = _punch(V, F, (0.0, 6.0), 2.0)        # on the crop's lower edge: a notch of the border, not a hole
    return V, F, eyes


def test_retopo_fills_the_scans_holes_inside_its_crop(holed_patch):
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32)
    r = retopologize(V, F, eyes, s)
    rep = mc.check_mesh(r.V, r.F)
    assert rep.manifold
    assert rep.boundary_loops == 3                      # two eye openings + the crop border
    assert r.metrics["scan_holes_filled"] == 2
    # the filled crop continues the skin: within the skin's own 0.3 mm ripple of the truth
    from scipy.spatial import cKDTree

    fill = r.crop_V[cKDTree(V).query(r.crop_V)[0] > 1e-9]      # the crop's new vertices
    assert len(fill) > 10
    assert np.abs(fill[:, 2] - height(fill[:, 0], fill[:, 1])).max() < 0.3
    # and the low-poly mesh over the holes lies on it as everywhere else
    near = np.linalg.norm(r.V[:, :2] - [0.0, 50.0], axis=1) < 3.0
    assert near.any()
    assert np.abs(r.V[near, 2] - height(r.V[near, 0], r.V[near, 1])).max() < 0.4


def test_retopo_says_which_holes_are_too_large_to_fill(holed_patch):
    """A hole over ``fill_holes_mm`` round stays open and is listed with its perimeter and
    centre (the stage prints each as a warning: renders see through it)."""
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, fill_holes_mm=16.0)
    r = retopologize(V, F, eyes, s)
    assert r.metrics["scan_holes_filled"] == 1                      # the cheek's, 13.8 mm round
    (big,) = r.metrics["scan_holes_left_open"]
    assert 16.0 < big["perimeter_mm"] < 2 * np.pi * 3.5             # round the 2.5 mm punch
    assert np.linalg.norm(np.asarray(big["centre_mm"])[:2] - [0.0, 50.0]) < 1.0
    assert mc.check_mesh(r.V, r.F).boundary_loops == 4


def test_retopo_leaves_the_holes_open_when_told(holed_patch):
    V, F, eyes = holed_patch
    s = RetopoSettings(method="quadric", target_polygons=1500, loop_points=32, fill_holes_mm=0)
    r = retopologize(V, F, eyes, s)
    assert r.metrics["scan_holes_filled"] == 0
    assert mc.check_mesh(r.V, r.F).boundary_loops == 5
