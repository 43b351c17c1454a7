"""Textured-only scans (issue 30): a procedural head whose eye openings are smoothed over in the
geometry and shown in the texture only (tests/fixtures/textured_only.py). The geometry alone
finds no eye; with the texture the opening follows the photographed fissure, its canthi within
2 mm of the truth; painted over in skin, the same head is refused as closed."""

from __future__ import annotations

import numpy as np
import pytest

from fixtures.textured_only import make_textured_only_head, paint_over_eyes, smooth_over_openings
from pipeline.errors import ScanError
from pipeline.remove_eyeballs.remove_eyeballs import remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings
from pipeline.synthetic_head import make_synthetic_head

SIDES = ("left", "right")


@pytest.fixture(scope="module")
def head():
    return make_textured_only_head(7)


def _arrays(h):
    return {"V": h.V, "F": h.F, "UV": h.UV, "FUV": h.F.copy()}


def _prior():
    from pipeline.placement.prior import EyeRegionPrior

    return EyeRegionPrior.load().register


@pytest.mark.slow
def test_only_the_openings_change_and_the_truth_lies_on_the_new_surface():
    from pipeline.geometry.frame import eye_basis
    from pipeline.placement.fissure import lift

    base = make_synthetic_head(seed=3, target_triangles=30_000, texture_size=64, noise_mm=0.0)
    h = smooth_over_openings(base)
    moved = np.linalg.norm(h.V - base.V, axis=1) > 1e-9
    rec = h.ground_truth["textured_only"]
    assert moved.sum() == rec["refilled_vertices"] > 0
    assert h.F is base.F and h.UV is base.UV and h.texture is base.texture    # the photograph stays
    for s in SIDES:
        e = base.ground_truth["eyes"][s]
        M = np.asarray(h.ground_truth["eyes"][s]["eyelid_margin"]["points_mm"])
        # the changed vertices lie about the opening only (within 8 mm of its true margin)
        assert np.linalg.norm(M.mean(axis=0) - np.asarray(e["eye_opening_center_mm"])) < 5.0
        # on the mesh: the surface seen along +Z at each margin point lies at its depth (up to the
        # linear faces of a 2.3 mm grid, no noise)
        B = eye_basis(np.array([0.0, 0.0, 1.0]))[:2]
        S = lift(h.V, h.F, M[:, :2] @ B[:, :2].T, np.zeros(3), np.array([0.0, 0.0, 1.0]), B, max_depth_mm=200.0)
        assert np.abs(S[:, 2] - M[:, 2]).max() < 0.3
        assert "eye_contact" not in h.ground_truth["eyes"][s]
        # the margin keeps its place across the face; only its depth follows the new skin
        M0 = np.asarray(e["eyelid_margin"]["points_mm"])
        assert np.abs(M[:, 1] - M0[:, 1]).max() < 1e-9
        # a closed lid's skin: it bulges over the globe, 1 mm in front of the corneal apex
        A = np.asarray(e["corneal_apex_mm"])
        S = lift(h.V, h.F, A[None, :2] @ B[:, :2].T, np.zeros(3), np.array([0.0, 0.0, 1.0]), B, max_depth_mm=200.0)
        assert S[0, 2] - A[2] == pytest.approx(rec["cover_mm"], abs=0.3)
    # the skin runs smoothly across: the crease where lid met eye (second differences of the
    # depth across the grid rows of 6.8 mm on this 2.3 mm grid) is gone (measured 1.34)
    ny, nt = h.grid_shape
    inner = moved.reshape(ny, nt)[1:-1]
    for V, most in ((base.V, None), (h.V, 1.6)):
        Z = V[:, 2].reshape(ny, nt)
        d2 = np.abs(Z[2:] - 2 * Z[1:-1] + Z[:-2])[inner].max()
        assert d2 > 5.0 if most is None else d2 < most


@pytest.mark.slow
def test_the_geometry_of_a_textured_only_head_shows_no_eye(head):
    """Without its texture the stage finds no eye: the skin across the opening is refused as
    closed (the check that the fixture is what it claims)."""
    with pytest.raises(ScanError) as exc:
        remove_eyeballs(_arrays(head), head.hints, RemoveEyeballsSettings(texture_fallback=False),
                        source="textured_only.ply", prior=_prior())
    msg = str(exc.value)
    assert "textured_only.ply" in msg and "looks closed" in msg and "\n" not in msg, msg


@pytest.mark.slow
def test_a_textured_only_head_is_opened_along_the_fissure_its_texture_shows(head):
    """Both eyes placed from the texture; the opening loop's canthi within 2 mm of the truth's
    (measured: 0.25-0.45 mm; 2.7-4.2 mm short medially before the corners' pink tissue counted
    as eye), the limbus within the anatomy's spread."""
    from fixtures.truth import truth_limbus

    res = remove_eyeballs(_arrays(head), head.hints, RemoveEyeballsSettings(), source="textured_only.ply",
                          texture=head.texture, prior=_prior())
    assert res.metrics["boundary_loops_out"] == res.metrics["boundary_loops_in"] + 2
    for s in SIDES:
        e = res.eyes[s].to_doc()
        truth = head.ground_truth["eyes"][s]
        M = np.asarray(truth["eyelid_margin"]["points_mm"])
        P = np.asarray(e["loop_points"])
        assert e["method"] == "texture"
        assert np.linalg.norm(P[0] - M[truth["eyelid_margin"]["medial_canthus_index"]]) <= 2.0, s
        assert np.linalg.norm(P[e["lateral_canthus_index"]] - M[truth["eyelid_margin"]["lateral_canthus_index"]]) <= 2.0, s
        limbus, _ = truth_limbus(truth)
        assert np.linalg.norm(np.asarray(e["limbus"]["center"]) - limbus) <= 2.5, s


@pytest.mark.slow
def test_a_textured_only_head_painted_over_in_skin_is_refused_as_closed(head):
    """The same head with skin painted over its eyes: neither the geometry nor the texture shows
    an eye, and the one-line refusal says closed."""
    closed = paint_over_eyes(head)
    with pytest.raises(ScanError) as exc:
        remove_eyeballs(_arrays(closed), closed.hints, RemoveEyeballsSettings(), source="closed.ply",
                        texture=closed.texture, prior=_prior())
    msg = str(exc.value)
    assert "closed.ply" in msg and "looks closed" in msg and "\n" not in msg, msg


@pytest.mark.slow
def test_an_eye_the_geometry_placed_off_the_photographed_fissure_is_placed_from_the_texture():
    """A hooded head smoothed over (seed 3): the skin bulging under its hanging fold fits a 20.6 mm
    sphere ringed by a fold, and the geometry placed the left eye there (canthi 7.8 / 3.8 mm off,
    16 % of it inside the fissure the texture shows). The photograph overrules it: both eyes are
    placed from the texture, the left one's doubt says why, and every canthus lies within 2 mm
    (measured 0.25-0.90 mm)."""
    h = make_textured_only_head(3, eye_shape="hooded")
    res = remove_eyeballs(_arrays(h), h.hints, RemoveEyeballsSettings(), source="hooded.ply",
                          texture=h.texture, prior=_prior())
    for s in SIDES:
        e = res.eyes[s].to_doc()
        truth = h.ground_truth["eyes"][s]["eyelid_margin"]
        M, P = np.asarray(truth["points_mm"]), np.asarray(e["loop_points"])
        assert e["method"] == "texture", s
        assert np.linalg.norm(P[0] - M[truth["medial_canthus_index"]]) <= 2.0, s
        assert np.linalg.norm(P[e["lateral_canthus_index"]] - M[truth["lateral_canthus_index"]]) <= 2.0, s
    why = [d for d in res.eyes["left"].to_doc()["doubts"] if "fissure the texture shows" in d]
    assert len(why) == 1 and "placed from the texture instead" in why[0], why


def test_a_human_sized_eye_the_geometry_placed_is_not_put_to_the_photograph(monkeypatch):
    """Only a sphere more than PHOTO_CHECK_SIGMAS prior sigmas off the prior radius is checked
    against the texture (the fissure's fit costs seconds an eye): a 12 mm or a 17.9 mm fit is
    not, an 18.1 mm one is (here: no texture eye to find, so the geometry stands either way)."""
    from types import SimpleNamespace

    import pipeline.placement.place as place
    from pipeline.placement.settings import PlacementSettings

    st = PlacementSettings()
    asked = []

    def no_eye_in_texture(*args, **kwargs):
        asked.append(args[4])
        raise ScanError("x.ply", "no eye in the texture")

    monkeypatch.setattr(place, "fit_texture", no_eye_in_texture)
    for r in (12.0, 6.1, 17.9, 18.1, 5.9):
        assert place._photo_disagrees(None, SimpleNamespace(radius=r), {}, None, np.zeros(3), f"r{r}",
                                      st, "x.ply") is None
    assert st.radius_prior_mm + place.PHOTO_CHECK_SIGMAS * st.radius_prior_sigma_mm == 18.0
    assert asked == ["r18.1", "r5.9"]
