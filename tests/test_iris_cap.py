"""The iris-plane refit of the limbus (pipeline/placement/iris_cap.py): known answers."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.placement import iris_cap
from pipeline.placement.model import Eye, limbus_center, surface_residual


def _frame(n):
    n = np.asarray(n, float) / np.linalg.norm(n)
    u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u), n


def _iris_eye_points(c, R, n, tl, hp, rp, noise=0.0, seed=0, reach_deg=50.0, k=1500):
    """Points on the iris-plane eye (iris_cap's module doc): the sclera out to ``reach_deg``
    off the axis, the flat iris and its ramp to the limbus."""
    rng = np.random.default_rng(seed)
    u, v, n = _frame(n)
    t = np.radians(tl)
    zl, rl = R * np.cos(t), R * np.sin(t)
    # the disc inside the limbus: rho uniform in area
    rho = rl * np.sqrt(rng.uniform(0.0, 1.0, k))
    phi = rng.uniform(0.0, 2 * np.pi, k)
    h = np.where(rho <= rp, hp, hp * (rl - rho) / (rl - rp))
    disc = c + np.outer(zl + h, n) + np.outer(rho * np.cos(phi), u) + np.outer(rho * np.sin(phi), v)
    # the sclera from the limbus out
    a = np.radians(rng.uniform(tl, reach_deg, k))
    phi = rng.uniform(0.0, 2 * np.pi, k)
    d = (np.outer(np.cos(a), n) + np.outer(np.sin(a) * np.cos(phi), u) + np.outer(np.sin(a) * np.sin(phi), v))
    P = np.vstack([disc, c + R * d])
    if noise:
        P = P + rng.normal(0.0, noise, P.shape)
    return P


def test_residual_known_answers():
    c, n = np.zeros(3), np.array([0.0, 0.0, 1.0])
    R, tl, hp, rp = 14.0, 30.0, 2.5, 4.0
    zl, rl = R * np.cos(np.radians(30.0)), 7.0
    P = np.array([[0.0, 0.0, zl + hp],            # on the iris plane, on the axis
                  [3.0, 0.0, zl + hp + 1.0],      # 1 mm in front of the iris plane
                  [5.5, 0.0, zl + 1.25],          # half-way down the ramp (rp 4 .. rl 7)
                  [0.0, 8.0, np.sqrt(R ** 2 - 64.0)],   # on the sclera outside the limbus
                  [0.0, -9.0, np.sqrt(15.0 ** 2 - 81.0)]])  # 1 mm outside the sclera
    d = iris_cap.iris_cap_residual(P, c, n, R, tl, hp, rp)
    assert np.allclose(d, [0.0, 1.0, 0.0, 0.0, 1.0], atol=1e-9)
    cap = iris_cap.IrisCap(c=c, R=R, n=n, tl=tl, hp=hp, rp=rp, rms_mm=0.0, n_points=0)
    assert np.allclose(cap.limbus_center, [0.0, 0.0, zl]) and cap.limbus_radius == pytest.approx(rl)


def test_fit_recovers_a_known_iris_eye_from_a_start_off_it():
    c = np.array([31.0, 34.0, 78.0])
    n = np.array([np.sin(np.radians(12.0)), np.sin(np.radians(-6.0)), 1.0])
    n /= np.linalg.norm(n)
    R, tl, hp, rp = 14.5, 32.0, 2.6, 4.6
    P = _iris_eye_points(c, R, n, tl, hp, rp, noise=0.03)
    start = Eye(c + np.array([0.6, -0.4, -1.0]), 13.5, np.array([0.0, 0.0, 1.0]), 0.3, 29.0, 0.3)
    got = iris_cap.fit_iris_cap(P, start)
    truth = c + R * np.cos(np.radians(tl)) * n
    assert np.linalg.norm(got.limbus_center - truth) < 0.1
    assert np.degrees(np.arccos(min(1.0, float(got.n @ n)))) < 0.5
    assert got.hp == pytest.approx(hp, abs=0.1) and got.rp == pytest.approx(rp, abs=0.3)
    assert got.rms_mm < 0.05
    with pytest.raises(ValueError, match="too few"):
        iris_cap.fit_iris_cap(P[:5], start)


def test_refit_takes_an_iris_and_keeps_the_model_on_a_dome_cornea():
    c, n = np.array([30.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    # an iris eye placed 1 mm and 5 deg off: the refit is taken
    P = _iris_eye_points(c, 14.0, n, 31.0, 2.5, 4.5, noise=0.03, seed=1)
    turned = np.array([np.sin(np.radians(5.0)), 0.0, np.cos(np.radians(5.0))])
    placed = Eye(c + [0.0, 0.0, -1.0], 14.0, turned, 0.3, 31.0, 0.4)
    lc, ax, cap, used = iris_cap.refit_limbus(P, placed)
    assert used and cap is not None
    assert np.linalg.norm(lc - (c + 14.0 * np.cos(np.radians(31.0)) * n)) < 0.15
    assert np.degrees(np.arccos(min(1.0, float(ax @ n)))) < 0.6
    # the paper's eye with its dome cornea, as the placement's model fits it: the iris plane
    # explains it far worse, so the model's limbus stands
    dome = Eye(c, 12.0, n, 1.0, 30.0, 0.0)
    rng = np.random.default_rng(2)
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d @ n > np.cos(np.radians(50.0))]
    Q = c + 12.0 * d
    Q = Q + (surface_residual(Q, dome)[0] * -1.0)[:, None] * d     # onto the model's surface
    Q = Q + rng.normal(0.0, 0.02, Q.shape)
    lc, ax, cap, used = iris_cap.refit_limbus(Q, dome)
    assert not used and cap is not None and cap.rms_mm > iris_cap.MAX_RMS_RATIO * 0.02
    assert np.allclose(lc, limbus_center(dome)) and np.allclose(ax, n)


def _loop_on_sphere(c, R, yaw_deg=48.0, pitch_deg=18.0, turn_deg=0.0, k=40):
    """A lid opening wrapped round the eye: directions on an ellipse of ``yaw_deg`` by
    ``pitch_deg`` about +z turned ``turn_deg`` about y (lids follow a sideways look), 0.6 mm
    outside the sphere."""
    t = np.linspace(0.0, 2 * np.pi, k, endpoint=False)
    yaw, pitch = np.radians(turn_deg) + np.radians(yaw_deg) * np.cos(t), np.radians(pitch_deg) * np.sin(t)
    d = np.stack([np.cos(pitch) * np.sin(yaw), np.sin(pitch), np.cos(pitch) * np.cos(yaw)], 1)
    return c + (R + 0.6) * d


def test_reread_finds_an_iris_turned_into_the_corner_and_refuses_a_bare_sphere():
    from pipeline.placement import human_eye

    c, R, tl, hp, rp = np.array([-33.0, 34.0, 80.0]), 15.5, 30.0, 2.5, 4.5
    n = np.array([-np.sin(np.radians(32.0)), 0.05, np.cos(np.radians(32.0))])
    n /= np.linalg.norm(n)
    P = _iris_eye_points(c, R, n, tl, hp, rp, noise=0.05, seed=3, reach_deg=80.0, k=3000)
    loop = _loop_on_sphere(c, R, turn_deg=-12.0)
    fwd = np.array([0.0, 0.0, 1.0])
    # the scan's sphere 0.6 mm off and 0.3 mm small: read about it from the eye region's forward
    seen = iris_cap.opening_eye_points(P, loop, c + [0.4, -0.3, 0.3], R - 0.3, fwd)
    assert 50 < len(seen) < len(P)
    got = human_eye.reread_iris(seen, loop, c + [0.4, -0.3, 0.3], R - 0.3, fwd, iris_radius=6.0)
    assert got is not None
    cap, iris, gap = got
    truth = c + R * np.cos(np.radians(tl)) * n
    assert np.linalg.norm(cap.limbus_center - truth) < 0.5
    assert np.degrees(np.arccos(min(1.0, float(cap.n @ n)))) < 2.0
    assert gap >= iris_cap.REREAD_GAP and iris["visible_share"] >= iris_cap.REREAD_VISIBLE
    # no iris at all: a bare sclera shows no reading clearly better than another
    rng = np.random.default_rng(4)
    d = rng.normal(size=(6000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    bare = iris_cap.opening_eye_points(c + R * d + rng.normal(0.0, 0.05, d.shape), loop, c, R, fwd)
    assert human_eye.reread_iris(bare, loop, c, R, fwd, iris_radius=6.0) is None
    assert human_eye.reread_iris(bare[:8], loop, c, R, fwd, iris_radius=6.0) is None


def test_an_eye_whose_reading_hid_its_iris_is_read_again_inside_its_opening():
    """human_eye.asset_eyes: the placement read the iris 57 deg into a corner (hidden at rest);
    the eye surface inside the opening shows it turned 32 deg, and that reading is published, at
    the re-read's sigma and with a doubt that says so. Without the scan's points it falls back
    to the opening, as before."""
    from pipeline.eyeball.geometry import EyeballParams
    from pipeline.placement import human_eye

    c, R, tl = np.array([-33.0, 34.0, 80.0]), 15.5, 30.0
    n = np.array([-np.sin(np.radians(32.0)), 0.05, np.cos(np.radians(32.0))])
    n /= np.linalg.norm(n)
    P = _iris_eye_points(c, R, n, tl, 2.5, 4.5, noise=0.05, seed=3, reach_deg=80.0, k=3000)
    loop = _loop_on_sphere(c, R, turn_deg=-12.0)
    wrong = np.array([-np.sin(np.radians(57.0)), 0.0, np.cos(np.radians(57.0))])

    def eye(near):
        return {"limbus_center": c + 13.0 * wrong, "axis": wrong, "limbus_radius": 7.0,
                "sigma_limbus_mm": 0.4, "sigma_axis_deg": 1.5, "source": "geometry", "center": c,
                "radius": R, "sigma_radius": 0.5, "loop_points": loop, "prior_axis": np.array([0.0, 0.0, 1.0]),
                **({} if near is None else {"scan_points": near})}

    for near, source in ((P, "geometry"), (None, "opening")):
        got = human_eye.asset_eyes({"left": eye(near), "right": eye(near)}, eye_size="human",
                                   eyeball=EyeballParams())["right"]
        assert got["limbus"]["source"] == source
        assert "lid opening at rest" in got["doubts"][0]
        if near is None:
            assert "placed from the opening instead" in got["doubts"][0]
            continue
        assert "read again from the eye surface inside the opening" in got["doubts"][0]
        truth = c + R * np.cos(np.radians(tl)) * n
        assert np.linalg.norm(got["limbus"]["center"] - truth) < 0.5
        assert np.degrees(np.arccos(min(1.0, float(got["forward"] @ n)))) < 2.0
        assert got["uncertainty"]["limbus_mm"] == iris_cap.REREAD_SIGMA[0]
        assert got["uncertainty"]["axis_deg"] == pytest.approx(iris_cap.REREAD_SIGMA[1])
