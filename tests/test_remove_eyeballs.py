"""remove_eyeballs: eye fit ground truth, cut topology, errors, stage I/O."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.eyes_file import read_eyes
from pipeline.io.meshfile import load_mesh, save_mesh
from pipeline.placement.eye_fit import eye_surface_distance
from pipeline.placement.prior import EyeRegionPrior
from pipeline.remove_eyeballs.remove_eyeballs import remove_eyeballs
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings

from fixtures import defaults_params, params_file
from fixtures.eye_heads import make_head


@pytest.mark.slow
@pytest.mark.parametrize("step,seed,noise", [(0.5, 0, 0.0), (0.4, 1, 0.03), (0.7, 2, 0.05)])
def test_ground_truth_and_topology(step, seed, noise):
    mesh, hints, gt = make_head(step, seed=seed, noise=noise)
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings())
    out = res.mesh
    # topology: one new simple loop per eye, edge-manifold; only the eyelid-loop vertices moved
    # (onto the fitted eyeball, where the lids lift off it), every other vertex unchanged
    assert res.metrics["boundary_loops_out"] == res.metrics["boundary_loops_in"] + 2 == 3
    assert meshtopo.is_edge_manifold(out["F"])
    loops = meshtopo.boundary_loops(out["F"])
    assert len(loops) == 3
    on_loop = np.zeros(len(out["V"]), bool)
    for s in ("left", "right"):
        on_loop[res.eyes[s].loop_indices] = True
    orig = set(map(tuple, mesh["V"].tolist()))
    same = np.array([tuple(v) in orig for v in out["V"].tolist()])
    assert same[~on_loop].all()
    assert len(out["V"]) + res.metrics["vertices_removed"] == len(mesh["V"])
    # no face flipped by the loop move: output normals agree with the input face they came from
    n_out = meshtopo.face_normals(out["V"], out["F"])
    assert (n_out[:, 2] > -0.2).all()  # height field facing +Z
    assert out["FUV"].shape == out["F"].shape and out["FUV"].max() < len(out["UV"])
    for s in ("left", "right"):
        e = res.eyes[s].to_doc()
        sph = e["scan_sphere"]      # the sphere the scan shows (the asset's eye is the human one)
        assert np.linalg.norm(np.array(sph["center"]) - gt[s]["center"]) <= 0.5
        assert abs(sph["radius"] - gt[s]["radius"]) <= 0.5
        L = np.array(e["loop_points"])
        assert np.allclose(out["V"][e["loop_indices"]], L)
        assert len(set(e["loop_indices"])) == len(L)  # simple
        assert closed_polyline_distance(L, gt[s]["margin"]).mean() <= 0.5
        # ordering: medial first, upper lid first, lateral canthus at lateral_canthus_index
        sign = 1 if s == "left" else -1
        x = sign * ((L - e["center"]) @ eye_basis(e["forward"])[0])
        assert x[0] == x.min() and x[e["lateral_canthus_index"]] == x.max()
        li = e["lateral_canthus_index"]
        assert L[1:li, 1].mean() > L[li + 1:, 1].mean()
        assert np.dot(e["forward"], [0, 0, 1]) > 0.9
        # moved loop points lie on the fitted eyeball (sclera or cornea), within an edge or two
        # of where they were
        d = eye_surface_distance(L, np.array(sph["center"]), sph["radius"], e["cornea"] and {
            "center": np.array(e["cornea"]["center"]), "radius": e["cornea"]["radius"]})
        # (a vertex whose move would fold a face, or with no lift-off nearby, stays on the cut)
        assert np.median(np.abs(d)) < 0.05 and np.abs(d).max() <= 0.9
        assert res.metrics[s]["loop_moved_mean_mm"] < 2 * step


@pytest.mark.slow
def test_the_eyes_removed_side_by_side_are_the_eyes_removed_here(monkeypatch):
    """The stage's children (the left eye's prior and search, the scan's boundary: pipeline.fork)
    give the mesh, the eyes and the metrics of the same steps run in this process, to the bit;
    every child returns its own result (none is rerun here)."""
    from fixtures.forks import strict_fork_result
    from pipeline import fork
    from pipeline.placement import fit, place
    from pipeline.remove_eyeballs import remove_eyeballs as stage_module

    mesh, hints, _ = make_head(0.5, seed=1, noise=0.03)
    for module in (fit, place, stage_module):
        monkeypatch.setattr(module, "fork_result", strict_fork_result)
    runs = {}
    for serial in ("1", "0"):
        monkeypatch.setenv(fork.SERIAL_ENV, serial)
        runs[serial] = remove_eyeballs(mesh, hints, RemoveEyeballsSettings(), prior=EyeRegionPrior.load().register)
    a, b = runs["1"], runs["0"]
    assert sorted(a.mesh) == sorted(b.mesh)
    for k in a.mesh:
        assert np.array_equal(np.asarray(a.mesh[k]), np.asarray(b.mesh[k])), k
    for s in ("left", "right"):
        assert json.dumps(a.eyes[s].to_doc(), sort_keys=True) == json.dumps(b.eyes[s].to_doc(), sort_keys=True)
    assert json.dumps(a.metrics, sort_keys=True, default=str) == json.dumps(b.metrics, sort_keys=True, default=str)


@pytest.mark.slow
def test_different_eye_sizes_are_kept():
    """Radius sharing only when both fits agree: a 12 mm and a 13 mm eye keep their radii."""
    mesh, hints, gt = make_head(0.5, seed=3, noise=0.02, radii=(12.0, 13.0))
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings())
    for s in ("left", "right"):
        sph = res.eyes[s].to_doc()["scan_sphere"]
        assert abs(sph["radius"] - gt[s]["radius"]) <= 0.3, (s, sph["radius"])
        assert np.linalg.norm(np.array(sph["center"]) - gt[s]["center"]) <= 0.5
        # the asset's eyes are one human size whatever the scan's spheres
        assert res.eyes[s].radius == 12.0


@pytest.mark.slow
def test_an_unmeasured_pupil_hole_is_part_of_the_opening():
    """Scanners lose the dark pupil: a 3 mm hole in the middle of each opening. The eye is fitted
    as before and the hole goes with the cut (one loop per eye, no extra boundary left)."""
    mesh, hints, gt = make_head(0.5, seed=2, noise=0.02)
    V, F = mesh["V"], mesh["F"]
    c = V[F].mean(axis=1)
    hole = np.zeros(len(F), bool)
    for s in ("left", "right"):
        hole |= np.linalg.norm(c[:, :2] - gt[s]["center"][:2], axis=1) < 1.5
    holed = {"V": V, "F": F[~hole], "UV": mesh["UV"], "FUV": mesh["FUV"][~hole]}
    assert meshtopo.boundary_component_count(holed["F"]) == 3        # outer border + 2 holes
    res = remove_eyeballs(holed, hints, RemoveEyeballsSettings())
    assert res.metrics["boundary_loops_out"] == 3                   # outer border + 2 openings
    for s in ("left", "right"):
        sph = res.eyes[s].to_doc()["scan_sphere"]
        assert np.linalg.norm(np.array(sph["center"]) - gt[s]["center"]) <= 0.5
        assert abs(sph["radius"] - gt[s]["radius"]) <= 0.5


@pytest.mark.slow
def test_eyes_of_unequal_size_beyond_anatomy_are_published_with_a_doubt():
    """12 and 15 mm eyes in one head: the fits may be right, but no head has them. The asset
    is still made; each eye carries a doubt naming the failed check."""
    mesh, hints, gt = make_head(0.5, seed=3, noise=0.02, radii=(12.0, 15.0))
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings(), source="unequal.npz")
    for s in ("left", "right"):
        assert abs(res.eyes[s].to_doc()["scan_sphere"]["radius"] - gt[s]["radius"]) <= 0.5
        assert any(d.startswith("self-check radii_agree: the two eyes' radii differ by 2.")
                   or d.startswith("self-check radii_agree: the two eyes' radii differ by 3.")
                   for d in res.eyes[s].doubts), res.eyes[s].doubts


@pytest.mark.slow
def test_eyes_json_records_placement_and_checks():
    mesh, hints, gt = make_head(0.5, seed=1, noise=0.02)
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings())
    for s in ("left", "right"):
        e = res.eyes[s].to_doc()
        # the whole eye shows: the sclera and the cornea carried the fit
        assert {"sclera", "cornea_or_iris"} <= set(e["placement"]), e["placement"]
        assert abs(sum(e["cue_shares"].values()) - 1.0) < 1e-3
        unc, st = e["uncertainty"], RemoveEyeballsSettings()
        # the truth (the paper's eye at the head's centre, looking along +Z) lies within 2 sigma;
        # the eye fits to 0.01 mm, so the Laplace part is scaled by the floor (0.2, residual_scaled):
        # 0.2 mm and 1.2 deg stated for 0.03 mm and 0.05 deg off (0.6 mm and 5.7 deg before, every
        # clean eye doubted), and an eye stated less sure than the doubt thresholds says so
        assert 0 < unc["limbus_mm"] < 0.3 and 0 < unc["axis_deg"] < 1.5, unc
        assert e["uncertainty_laplace_mm"]["residual_scale"] == 0.2
        assert np.linalg.norm(np.array(e["center"]) - gt[s]["center"]) <= 2 * unc["center_mm"]
        assert np.degrees(np.arccos(min(1.0, e["forward"][2]))) <= 2 * unc["axis_deg"]
        loose = unc["limbus_mm"] > st.doubt_limbus_sigma_mm or unc["axis_deg"] > st.doubt_axis_sigma_deg
        assert loose == any(d.startswith("placed from little evidence") for d in e["doubts"])
        assert not loose and e["doubts"] == [], e["doubts"]
        sph = e["scan_sphere"]
        err = np.linalg.norm(np.array(sph["center"]) - gt[s]["center"])
        assert err <= 2 * sph["uncertainty_mm"]["center"] + 0.05, (err, sph)
        assert set(e["checks"]) == {"inside", "radius_in_range", "opening_fits", "opening_wide", "opening_convex",
                                    "loop_on_sphere", "cornea_shows", "radii_agree"}
        assert all(c["ok"] for c in e["checks"].values())
        assert res.metrics[s]["checks_failed"] == []
        assert all(d.startswith("placed from little evidence") for d in e["doubts"]), e["doubts"]
        assert e["checks"]["loop_on_sphere"]["value"] <= 0.8


@pytest.mark.slow
def test_no_eye_near_hint_fails():
    mesh, hints, _ = make_head(0.7)
    hints["left"] = np.array([0.0, 15.0, 4.0])  # flat forehead-like area between the eyes
    with pytest.raises(ScanError, match="left eye"):
        remove_eyeballs(mesh, hints, RemoveEyeballsSettings(), source="flat.npz")


@pytest.mark.slow
def test_closed_eyes_fail():
    mesh, hints, _ = make_head(0.7, closed=True)
    with pytest.raises(ScanError) as exc:
        remove_eyeballs(mesh, hints, RemoveEyeballsSettings(texture_fallback=False), source="closed.npz")
    msg = str(exc.value)
    assert "closed.npz" in msg and "\n" not in msg and ("closed" in msg or "no eyeball" in msg)


@pytest.mark.slow
def test_closed_textured_eyes_are_refused_as_closed():
    """Closed lids with a texture that shows only skin: the texture fallback finds no eye either,
    and the one-line refusal says closed (it said "no eyeball surface found")."""
    from fixtures.unseen.metrics import says_closed

    mesh, hints, _ = make_head(0.7, closed=True)
    lo, hi = mesh["V"][:, :2].min(axis=0), mesh["V"][:, :2].max(axis=0)
    mesh = {**mesh, "UV": (mesh["V"][:, :2] - lo) / (hi - lo), "FUV": mesh["F"]}
    skin = np.empty((64, 64, 3), np.uint8)
    skin[:] = (188, 140, 120)
    with pytest.raises(ScanError) as exc:
        remove_eyeballs(mesh, hints, RemoveEyeballsSettings(), source="closed_textured.obj", texture=skin)
    msg = str(exc.value)
    assert "closed_textured.obj" in msg and "\n" not in msg and says_closed(msg), msg


@pytest.mark.slow
def test_a_closed_textured_scan_is_refused_as_closed(extra_scan, tmp_path, capsys):
    """A real textured scan with its eyes closed: ``james`` (coarse, placed from its photograph)
    with each eye painted over in the texture with the skin around it (skin across the opening;
    the coarse geometry unchanged, so it still offers a sliver of "eye"). The stage refuses it
    in one line naming the scan folder and saying closed (it said "no eyeball surface found
    near the hint (geometry and texture)")."""
    from PIL import Image, ImageDraw

    from fixtures.unseen.metrics import says_closed
    from stages._common import run_stage
    from stages.ingest import main as ingest_main
    from stages.remove_eyeballs import main

    folder = extra_scan("james")
    ing = tmp_path / "ingest"
    assert run_stage(ingest_main, [str(folder), str(ing), "--params", str(defaults_params(tmp_path))]) == 0
    m = load_mesh(ing / "mesh.npz")
    V, F, UV, FUV = m["V"], m["F"], m["UV"], m["FUV"]
    hints = {s: np.asarray(e["hint"], float) for s, e in json.loads((ing / "scan.json").read_text())["eyes"].items()}
    img = Image.open(ing / "texture.png").convert("RGB")
    tex = np.asarray(img)
    h, w = tex.shape[:2]
    draw = ImageDraw.Draw(img)
    c = V[F].mean(axis=1)
    for hint in hints.values():
        d, front = np.linalg.norm((c - hint)[:, :2], axis=1), np.abs(c[:, 2] - hint[2]) < 25.0
        px = np.clip((UV[FUV[front & (d > 16) & (d < 22)]].reshape(-1, 2) * [w - 1, h - 1]).astype(int),
                     0, [w - 1, h - 1])
        skin = tuple(int(v) for v in np.median(tex[h - 1 - px[:, 1], px[:, 0]], axis=0))
        for f in np.flatnonzero(front & (d < 15)):
            draw.polygon([(float(u), float(h - 1 - v)) for u, v in UV[FUV[f]] * [w - 1, h - 1]], fill=skin)
    img.save(ing / "texture.png")
    capsys.readouterr()
    assert run_stage(main, [str(ing), str(tmp_path / "out"), "--params", str(defaults_params(tmp_path))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {folder}: "), err
    assert says_closed(err[0]) and "eye looks closed" in err[0], err[0]
    assert not (tmp_path / "out").exists()


def _ingested_head(tmp_path) -> Path:
    """An ingest folder of the open test head."""
    mesh, hints, _ = make_head(0.7)
    ing = tmp_path / "ingest"
    ing.mkdir()
    save_mesh(ing / "mesh.npz", **mesh)
    (ing / "scan.json").write_text(json.dumps(
        {"name": "t", "eyes": {s: {"hint": h.tolist()} for s, h in hints.items()}}))
    return ing


@pytest.mark.slow
def test_stage_writes_outputs(tmp_path):
    from stages.remove_eyeballs import main

    ing = _ingested_head(tmp_path)
    out = tmp_path / "remove_eyeballs"
    metrics = main([str(ing), str(out), "--metrics", str(tmp_path / "m.json"), "--params", str(defaults_params(tmp_path))]).metrics
    assert metrics["boundary_loops_out"] == 3
    eyes = {s: e.to_doc() for s, e in read_eyes(out / "eyes.json").items()}
    m = load_mesh(out / "mesh.npz")
    for s in ("left", "right"):
        for k in ("center", "radius", "forward", "residual_rms_mm", "n_inliers", "loop_indices",
                  "loop_points", "lateral_canthus_index"):
            assert k in eyes[s]
        assert np.allclose(m["V"][eyes[s]["loop_indices"]], eyes[s]["loop_points"])


@pytest.mark.slow
def test_stage_names_the_scan_folder_when_the_eyes_are_closed(tmp_path, capsys):
    """The refusal names the scan folder ingest recorded, not build/<scan>/ingest/mesh.npz."""
    from stages._common import run_stage
    from stages.remove_eyeballs import main

    mesh, hints, _ = make_head(0.7, closed=True)
    ing = tmp_path / "ingest"
    ing.mkdir()
    save_mesh(ing / "mesh.npz", **{k: v for k, v in mesh.items() if k in ("V", "F")})
    (ing / "scan.json").write_text(json.dumps(
        {"name": "sleepy", "folder": "raw_scans/sleepy",
         "eyes": {s: {"hint": h.tolist()} for s, h in hints.items()}}))
    capsys.readouterr()
    assert run_stage(main, [str(ing), str(tmp_path / "out"), "--params", str(defaults_params(tmp_path))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: raw_scans/sleepy: ") and "closed" in err[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("text,message", [
    ("place_patch_mm: .nan", "remove_eyeballs.place_patch_mm must be a finite number"),
    ("cut_tol_mm: 0.5", "remove_eyeballs.cut_tol_mm is an unknown key"),
    ("radius_range_mm: [18, 10]", "remove_eyeballs.radius_range_mm"),
    ("uncertainty_scale: 0", "remove_eyeballs.uncertainty_scale must be > 0"),
])
def test_stage_refuses_bad_settings_in_one_line(tmp_path, capsys, text, message):
    from stages._common import run_stage
    from stages.remove_eyeballs import main

    params = params_file(tmp_path, {"remove_eyeballs": yaml.safe_load(text)}, name="p.yaml")
    capsys.readouterr()
    assert run_stage(main, [str(tmp_path / "in"), str(tmp_path / "out"), "--params", str(params)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {params}: {message}"), err


def test_stage_refuses_a_missing_prior_in_one_line(tmp_path, capsys):
    """The eye-region prior ships with eyerig; without it the stage stops, naming the file."""
    from stages._common import run_stage
    from stages.remove_eyeballs import main

    ing = _ingested_head(tmp_path)
    capsys.readouterr()
    missing = tmp_path / "nowhere" / "eye_region_prior.npz"
    assert run_stage(main, [str(ing), str(tmp_path / "out"), "--prior", str(missing), "--params", str(defaults_params(tmp_path))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {missing}: "), err
    assert not (tmp_path / "out").exists()


def test_stage_missing_input_is_one_line(tmp_path):
    from stages._common import run_stage
    from stages.remove_eyeballs import main

    assert run_stage(main, [str(tmp_path / "nope"), str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def _gt_errors(folder, res):
    gt = json.loads((folder / "ground_truth.json").read_text())["eyes"]
    out = {}
    for s in ("left", "right"):
        e, g = res.eyes[s].to_doc(), gt[s]
        sph = e["scan_sphere"]
        c = np.array(sph["center"])
        errs = [(np.linalg.norm(c - g[k]["center_mm"]), abs(sph["radius"] - g[k]["radius_mm"]))
                for k in ("eyeball_sphere", "anterior_sclera_sphere")]
        M = np.array(g["eyelid_margin"]["points_mm"])
        out[s] = (min(errs), closed_polyline_distance(np.array(e["loop_points"]), M).mean())
    return out


@pytest.mark.slow
def test_ict_neutral(extra_scan):
    from pipeline.ingest.ingest import IngestSettings, ingest_scan

    folder = extra_scan("ict_neutral")
    r = ingest_scan(folder, IngestSettings())
    hints = {s: r.scan["eyes"][s]["hint"] for s in ("left", "right")}
    # with the eye-region prior, as the stage runs (without it the left eye takes a rival optimum
    # 4.3 mm and 22 deg off, doubted)
    res = remove_eyeballs(r.mesh, hints, RemoveEyeballsSettings(), source="scan.ply",
                          prior=EyeRegionPrior.load().register)
    assert res.metrics["edge_manifold_out"]
    gt = json.loads((folder / "ground_truth.json").read_text())["eyes"]
    for s, ((cerr, rerr), loop_d) in _gt_errors(folder, res).items():
        # measured: centre 0.92 / 0.90 mm and radius -0.65 mm from the visible sclera's sphere
        # (1.55 mm and -0.98 mm from the whole eyeball's), stated uncertainty 0.79 mm (1 sigma),
        # so the truth lies within 2 sigma. The scanner flattened the cornea, the eye is placed
        # 14.45 mm where ICT's is 15.4, and cornea_shows doubts it. The loop misses the
        # 0.5 mm bound (measured 1.93/1.80 mm): the true margin lies at the base of the lid
        # rim, 1.6 mm (0.4-3.4) under the scan's Poisson-filled crease, where no scan surface is
        assert cerr <= 1.0 and rerr <= 1.0, (s, cerr, rerr)
        e, g = res.eyes[s].to_doc(), gt[s]["eyeball_sphere"]
        sph = e["scan_sphere"]
        assert np.linalg.norm(np.array(sph["center"]) - g["center_mm"]) <= 2 * sph["uncertainty_mm"]["center"] + 0.1
        assert any("cornea_shows" in d for d in e["doubts"]), e["doubts"]
        assert loop_d <= 2.2, (s, loop_d)
        # the asset's eye: the paper's 12 mm eye on ICT's 15.4 mm globe's limbus. Measured: limbus
        # centre 1.16 / 1.11 mm off (1.1 mm of it along the axis: the sphere that takes in the
        # flattened cornea is 14.45 mm and its limbus too far forward), axis 2.8 / 3.0 deg; both
        # eyes doubted (cornea_shows). The issue's 0.5 mm / 2 deg is not reached on this scan.
        lim = gt[s]["limbus"]
        assert e["radius"] == 12.0
        assert np.linalg.norm(np.array(e["limbus"]["center"]) - lim["center_mm"]) <= 1.3
        assert np.degrees(np.arccos(np.clip(np.dot(e["forward"], gt[s]["gaze_direction"]), -1, 1))) <= 3.5


@pytest.mark.slow
def test_james_texture_fallback(extra_scan):
    from PIL import Image

    from pipeline.ingest.ingest import IngestSettings, ingest_scan

    folder = extra_scan("james")
    r = ingest_scan(folder, IngestSettings())
    tex = r.texture if r.texture is not None else None
    if tex is None:
        import io
        tex = Image.open(io.BytesIO(r.texture_png_bytes))
    tex = np.asarray(tex.convert("RGB"))
    hints = {s: r.scan["eyes"][s]["hint"] for s in ("left", "right")}
    res = remove_eyeballs(r.mesh, hints, RemoveEyeballsSettings(), source="james.obj", texture=tex)
    assert res.metrics["boundary_loops_out"] == res.metrics["boundary_loops_in"] + 2
    for s in ("left", "right"):
        e = res.eyes[s].to_doc()
        assert e["method"] == "texture" and e["residual_rms_mm"] < 2.0
        assert np.linalg.norm(np.array(e["center"]) - hints[s]) < 20.0
    # The opening follows the fissure the photograph shows, corner to corner (the cut along its
    # outline on faces refined to < 1 mm): the loop's canthi against the hand-marked corners
    # (68-point annotations, group reye = the subject's left eye), no doubt about its width, and
    # no photographed eye left on the lids: nothing of the kept surface lies, seen from the front,
    # inside the hexagon of the six annotated eyelid points (inside the true fissure), beyond a
    # sliver at a canthus.
    from pipeline.geometry.frame import eye_basis
    from pipeline.placement.fissure import points_in_polygon

    L = np.load(folder / "james_landmarks68.npy")
    groups = json.loads((folder / "james_landmarks68_groups.json").read_text())
    V, F = res.mesh["V"], res.mesh["F"]
    B = eye_basis(np.array([0.0, 0.0, 1.0]))[:2]
    for s, group in (("left", "reye"), ("right", "leye")):
        e = res.eyes[s].to_doc()
        lm = L[groups[group]]
        med, lat = (lm[0], lm[3]) if s == "left" else (lm[3], lm[0])
        P = np.asarray(e["loop_points"])
        li = e["lateral_canthus_index"]
        # measured: left 1.2 / 1.6 mm, right 2.3 / 3.7 mm (the right lateral canthus lies in the
        # shadow of the lashes, where the photograph does not show the opening's last 3 mm)
        assert np.linalg.norm(P[0] - med) <= (2.0 if s == "left" else 3.0), s
        assert np.linalg.norm(P[li] - lat) <= (2.0 if s == "left" else 4.5), s
        assert abs(e["texture_fissure"]["width_mm"] - (lm[:, 0].max() - lm[:, 0].min())) <= 3.5
        # no doubt about its width; an eye placed from a photograph states the anatomy's spread
        # (limbus +-1.2 mm, axis +-5 deg), past the doubt thresholds, and says so
        assert e["doubts"] == ["placed from little evidence (texture): limbus centre +-1.20 mm, "
                               "axis +-5.0 deg (1 sigma)"], e["doubts"]
        assert e["radius"] == 12.0 and e["limbus"]["source"] == "texture"
        c = V[F].mean(axis=1)
        near = np.flatnonzero(np.linalg.norm(c - hints[s], axis=1) < 20.0)
        hexagon = (lm - hints[s]) @ B.T
        inside = near[points_in_polygon((c[near] - hints[s]) @ B.T, hexagon)]
        T = (V[F[inside]] - hints[s]) @ B.T
        kept = 0.5 * np.abs(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])).sum()
        x, y = hexagon[:, 0], hexagon[:, 1]
        area = 0.5 * abs(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
        # measured: 0.6 % (left) and 7.8 % (right: the lateral end, see above); the 18 mm
        # openings cut along the scan's faces before kept 43 % / 36 %
        assert kept <= 0.1 * area, (s, kept, area)
        # the corners stand off the eye, the medial one (past the caruncle) farther
        off = np.linalg.norm(P - e["center"], axis=1) - e["radius"]
        assert off[0] > 3.0 and off[0] > off[li], (s, off[0], off[li])


@pytest.mark.slow
@pytest.mark.parametrize("seed,triangles,noise,shape", [
    pytest.param(7, 300_000, 0.0, "round", marks=pytest.mark.slow),
    (1, 100_000, 0.05, "round"),
    (1, 100_000, 0.02, "round"),     # coarse: the loop is placed between mesh vertices
    (5, 150_000, 0.02, "hooded"),    # hooded: mostly cornea in the opening, a lid shell around it
    (2, 200_000, 0.02, "hooded"),    # few sclera vertices (at 100k the human eye region shows 20 vertices
                                     # of eye: too few to place from the geometry)
    (2, 150_000, 0.02, "round"),     # eyes of different sizes (11.7 / 13.2 mm): radius not shared
])
def test_synthetic_head_ground_truth(seed, triangles, noise, shape):
    from pipeline.synthetic_head import make_synthetic_head

    h = make_synthetic_head(seed=seed, target_triangles=triangles, noise_mm=noise, eye_shape=shape,
                            texture_size=16)
    res = remove_eyeballs({"V": h.V, "F": h.F}, {s: np.asarray(h.hints[s]) for s in ("left", "right")},
                          RemoveEyeballsSettings(), source="synthetic")
    assert res.metrics["boundary_loops_out"] == res.metrics["boundary_loops_in"] + 2
    assert res.metrics["edge_manifold_out"]
    for s in ("left", "right"):
        g, e = h.ground_truth["eyes"][s], res.eyes[s].to_doc()
        sph = e["scan_sphere"]
        assert np.linalg.norm(np.array(sph["center"]) - g["eyeball_sphere"]["center_mm"]) <= 0.5
        assert abs(sph["radius"] - g["eyeball_sphere"]["radius_mm"]) <= 0.5
        # forward = centre -> fitted corneal centre: a small cornea on a coarse mesh tilts it
        # (sweep max 7 deg at 100k triangles, <= 3.4 deg at 350k)
        assert np.dot(e["forward"], g["gaze_direction"]) > np.cos(np.radians(3.0 if triangles >= 300_000 else 5.0))
        # the cut follows the edge of the visible eye (where tissue meets the eye surface); the
        # lid margin stands off the globe, and the corners lie past the eye (known gap)
        loop_d = closed_polyline_distance(np.array(e["loop_points"]),
                                    np.array(g["eye_contact"]["points_mm"])).mean()
        # measured 0.16-0.32 mm on these cases (0.37-0.67 before the loop was moved to where the
        # lids lift off the eyeball)
        assert loop_d <= 0.5, (s, loop_d)


@pytest.mark.parametrize("off_mm", [-1.0, 1.0])
def test_the_priors_own_start_is_searched_whatever_the_drawn_spheres_rank(off_mm):
    """With one start kept, the test head's best drawn sphere is its cornea's (8.1 mm, not the
    eye); the eye-region prior's best start along its axis (its front put ``off_mm`` beside the
    truth's) is searched as well, at the true 12 mm: the search does not hang on whether a drawn
    pair leads into the eye's basin (fresh26's hooded eye missed it on one set of kernels)."""
    from pipeline.placement.cues import Cues, build_patch
    from pipeline.placement.fit import hypotheses, hypothesis_pairs

    mesh, hints, truth = make_head(0.7)
    p = build_patch(mesh["V"], mesh["F"], hints["left"], 20.0)
    axis = np.array([0.0, 0.0, 1.0])
    front = truth["left"]["center"] + [off_mm, 0.0, 0.0] + truth["left"]["radius"] * axis
    starts = hypotheses(p, Cues(front=front, axis=axis), (6.0, 21.0),
                        hypothesis_pairs(p, np.random.default_rng(0)), keep=1)
    assert len(starts) == 2 and abs(starts[0].R - 8.08) < 0.05, [(e.c, e.R) for e in starts]
    assert starts[1].R == 12.0 and np.allclose(starts[1].c + starts[1].R * axis, front)


def test_spherefit_helpers():
    """2-point oriented hypotheses, radius standard error, one-sided 'nothing inside' residuals."""
    from pipeline.geometry.spherefit import radius_sigma, refine_sphere, sphere_from_normals

    rng = np.random.default_rng(0)
    c, r = np.array([1.0, -2.0, 3.0]), 12.0
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    P = c + r * u
    c2, r2 = sphere_from_normals(P[0], u[0], P[1], u[1])
    assert np.allclose(c2, c) and abs(r2 - r) < 1e-9
    assert sphere_from_normals(P[0], u[0], P[0] + 1.0, u[0]) is None        # parallel normals
    assert sphere_from_normals(P[0], -u[0], P[1], -u[1]) is None            # centre outside
    # a small cap: the radius is poorly determined, and the standard error says so
    cap = u[:, 2] > 0.9
    noisy = P + rng.normal(0, 0.05, P.shape)
    assert radius_sigma(noisy[cap], c, r) > 5 * radius_sigma(noisy, c, r) > 0
    assert radius_sigma(P[:3], c, r) == np.inf
    # a cap fitted from a biased start drifts; surface points all around it that must stay
    # outside pin the sphere (points inside by more than the margin are penalised)
    band = (u[:, 2] > 0.75) & (u[:, 2] < 0.9)
    outer = c + (r + 0.5) * u[u[:, 2] > 0.3]
    c3, r3 = refine_sphere(noisy[band], c + [0, 0, 1.5], r - 1.5, inside_points=outer, inside_margin=0.2)
    assert (np.linalg.norm(outer - c3, axis=1) - r3).min() > -0.3


def test_holes_inside_counts_only_holes_whose_every_edge_is_removed():
    """A grid with two holes (one quad cut out each): a cut that covers a hole's whole rim absorbs
    it, a cut through part of its rim does not; the outer border is a loop too and counts only
    when every face along it goes."""
    from pipeline.remove_eyeballs.remove_eyeballs import _holes_inside

    n = 12
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = [(i, j) for i in range(n) for j in range(n) if (i, j) not in ((3, 3), (8, 8))]
    F = np.array([t for i, j in quads for t in ((idx[i, j], idx[i + 1, j], idx[i + 1, j + 1]),
                                                (idx[i, j], idx[i + 1, j + 1], idx[i, j + 1]))])
    quad_of = np.repeat(np.array(quads), 2, axis=0)

    def near(c, r):
        return np.abs(quad_of - np.array(c)).max(axis=1) <= r
    H = meshtopo.boundary_halfedges(F)
    assert _holes_inside(F, near((3, 3), 1)) == 1                   # the ring around hole (3, 3)
    assert _holes_inside(F, near((3, 3), 1), H) == 1                # same with H given
    assert _holes_inside(F, near((3, 3), 1) | near((8, 8), 1)) == 2
    assert _holes_inside(F, near((3, 2), 0) | near((2, 3), 0)) == 0  # part of the rim only
    assert _holes_inside(F, np.ones(len(F), bool)) == 3              # both holes and the border


def _shrunk_about_centroid(P, share):
    c = P.mean(axis=0)
    return c + share * (P - c)


def test_texture_fissure_reads_the_painted_opening():
    """The texture fissure of the procedural head against its true margin's width; a loop of
    that width is not doubted, one shrunk to 60 % is, with both widths in the sentence."""
    from types import SimpleNamespace

    from pipeline.geometry.frame import eye_basis
    from pipeline.placement.texture import texture_fissure
    from pipeline.placement.doubts import fissure_doubts
    from pipeline.synthetic_head import make_synthetic_head

    h = make_synthetic_head(seed=3, target_triangles=60_000, texture_size=1024, noise_mm=0.0)
    arrays = {"UV": h.UV, "FUV": h.F}
    for s in ("left", "right"):
        g = h.ground_truth["eyes"][s]
        fwd = np.asarray(g["gaze_direction"], float)
        margin = np.asarray(g["eyelid_margin"]["points_mm"], float)
        x = margin @ eye_basis(fwd)[0]
        true_w = x.max() - x.min()
        fis = texture_fissure(h.V, h.F, h.UV, h.F, h.texture, h.hints[s], fwd)
        # measured 2.0-2.6 mm wide of the margin: the painted lash line and liner run past the
        # corners, and the grid adds up to a cell at each end
        assert true_w - 1.0 <= fis["width_mm"] <= true_w + 3.5, (s, fis, true_w)
        fit = SimpleNamespace(center=np.asarray(g["eyeball_sphere"]["center_mm"], float), forward=fwd)
        rec, doubts = fissure_doubts(h.V, h.F, arrays, h.texture, h.hints[s], fit, margin, RemoveEyeballsSettings())
        assert doubts == [] and abs(rec["loop_width_mm"] - true_w) < 1e-9
        rec, doubts = fissure_doubts(h.V, h.F, arrays, h.texture, h.hints[s], fit,
                                      _shrunk_about_centroid(margin, 0.6), RemoveEyeballsSettings())
        assert len(doubts) == 1 and f"{0.6 * true_w:.1f} mm wide" in doubts[0], doubts
        assert f"{fis['width_mm']:.1f} mm" in doubts[0]


def test_texture_fissure_without_skin_around_reads_nothing():
    """A texture that is one colour everywhere has no fissure (nothing differs from the skin)."""
    from pipeline.placement.texture import texture_fissure
    from pipeline.synthetic_head import make_synthetic_head

    h = make_synthetic_head(seed=3, target_triangles=20_000, texture_size=16, noise_mm=0.0)
    flat = np.full((64, 64, 3), 180, np.uint8)
    fis = texture_fissure(h.V, h.F, h.UV, h.F, flat, h.hints["left"], np.array([0.0, 0.0, 1.0]))
    assert fis == {"width_mm": 0.0, "height_mm": 0.0, "cells": 0}


@pytest.mark.slow
def test_stage_warns_of_each_doubt_and_still_publishes(extra_scan, tmp_path, capsys):
    """james, asked for openings of 95 % of its photographed fissures (its own are 29.6 / 25.7 mm
    of 32.0 / 29.0 mm: 0.93 / 0.89, not doubted at the default 0.8): the stage exits 0 with both
    eyes written, and says on stderr, once per eye and naming the scan folder, that the opening
    is narrower than the texture's fissure."""
    from stages import ingest
    from stages._common import run_stage
    from stages.remove_eyeballs import main

    folder = extra_scan("james")
    params = params_file(tmp_path, {"remove_eyeballs": {"texture_fissure_min_share": 0.95}})
    assert run_stage(ingest.main, [str(folder), str(tmp_path / "ingest"), "--params", str(defaults_params(tmp_path))]) == 0
    capsys.readouterr()
    assert run_stage(main, [str(tmp_path / "ingest"), str(tmp_path / "out"), "--params", str(params)]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines()
                if line.startswith("warning:") and "texture's fissure" in line]
    assert [w.split(": ")[2] for w in warnings] == ["left eye", "right eye"], warnings
    assert all(str(folder) in w for w in warnings)
    eyes = read_eyes(tmp_path / "out" / "eyes.json")
    # beside the texture placement's own (limbus +-1.2 mm, axis +-5 deg: the anatomy's spread)
    assert all(sum("texture's fissure" in d for d in eyes[s].doubts) == 1 for s in ("left", "right"))


@pytest.fixture(scope="module")
def hooded_identity(tmp_path_factory):
    """``ident_s1_000`` (seed 1, index 0: eye_shape 0.98, the most hooded draw; issue 30) as
    ``stages.identities`` draws it and ``benchmarks.bench_identities`` makes it (./params.yaml
    with the identity): the scan, its ingest and the params file. The stages run as ``python
    -m`` (pinned kernels, as dvc runs them: the search's basins rest on the last bits)."""
    import subprocess
    import sys

    from pipeline.synthetic_head.identities import DEFAULT_TRIANGLES, draw_identity, identity_name

    root = Path(__file__).resolve().parents[1]
    work = tmp_path_factory.mktemp("ident_s1_000")
    name = identity_name(1, 0)
    blocks = yaml.safe_load((root / "params.yaml").read_text())
    blocks["identities"] = json.loads(json.dumps({name: draw_identity(1, 0, DEFAULT_TRIANGLES)}))
    params = work / "params.yaml"
    params.write_text(yaml.safe_dump(blocks, sort_keys=False))
    scan, ingest = work / "scans" / name, work / "ingest"
    for cmd in (["stages.synthetic_head", str(scan), "--identity", name],
                ["stages.ingest", str(scan), str(ingest)]):
        subprocess.run([sys.executable, "-m", *cmd, "--params", str(params), "--metrics", str(work / "m.json")],
                       cwd=root, check=True, capture_output=True)
    return {"root": root, "work": work, "scan": scan, "ingest": ingest, "params": params}


def _remove_eyeballs(ident, out, rival_restarts=True, below_margin=None):
    """The stage on the identity's ingest in a pinned subprocess; ``rival_restarts=False``
    searches as before issue 30's fix (restarts from the best optimum only), before the prior's
    own start was always searched (that start alone finds this eye too), before the partner's
    gaze was a start (with it alone the search places this eye from the geometry) and before an
    optimum centred below the lid margin was passed over (``below_margin``, by default as
    ``rival_restarts``)."""
    import subprocess
    import sys

    import os

    script = ident["work"] / "run_stage.py"
    rival = "fit.RIVAL_MM" if rival_restarts else "float('inf')"
    below = "place.BELOW_MARGIN_MM" if (rival_restarts if below_margin is None else below_margin) else "float('inf')"
    script.write_text("from pipeline.kernels import pin_process\npin_process()\n"
                      f"import pipeline.placement.fit as fit\nfit.RIVAL_MM = {rival}\n"
                      f"fit.PRIOR_OWN_START = {rival_restarts}\n"
                      f"fit.PARTNER_DEG = {'fit.PARTNER_DEG' if rival_restarts else 180.0}\n"
                      "import pipeline.placement.place as place\n"
                      f"place.BELOW_MARGIN_MM = {below}\n"
                      "from stages._common import stage_exit\nfrom stages.remove_eyeballs import main\n"
                      "stage_exit(main)\n")
    return subprocess.run([sys.executable, str(script), str(ident["ingest"]), str(out), "--params",
                           str(ident["params"]), "--metrics", str(ident["work"] / "re.json")],
                          cwd=ident["root"], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ident["root"])})


@pytest.mark.slow
def test_the_hooded_identity_is_placed_at_its_limbus(hooded_identity):
    """Issue 30: ident_s1_000's right eye was placed 9.2 mm off (a sphere through the lower lid,
    its loop cut below it); with the rival basin restarted it lies at the truth and its loop
    on it."""
    out = hooded_identity["work"] / "re"
    r = _remove_eyeballs(hooded_identity, out)
    assert r.returncode == 0, r.stderr
    truth = json.loads((hooded_identity["scan"] / "ground_truth.json").read_text())["eyes"]
    eyes = json.loads((out / "eyes.json").read_text())
    for s in ("left", "right"):
        lim = np.array(eyes[s]["limbus"]["center"]) - truth[s]["limbus"]["center_mm"]
        assert np.linalg.norm(lim) < 1.0 and eyes[s]["limbus"]["source"] == "geometry", (s, lim)
        assert eyes[s]["checks"]["loop_on_sphere"]["ok"] and "loop_on_eye" not in eyes[s]["checks"]
        margin = np.array(truth[s]["eyelid_margin"]["points_mm"])
        loop = np.array(eyes[s]["loop_points"])
        assert loop[:, 1].min() > margin[:, 1].min() - 1.5      # not cut below the lower lid


@pytest.mark.slow
def test_an_identity_keeps_the_eye_size_drawn_for_it(hooded_identity):
    """Issue 29: a procedural identity's asset eye is its population draw, not the 12 mm of
    scans: stages.identities writes asset_eye_size population, the head's scan.yaml says
    eye_size population, ingest carries it, and remove_eyeballs gives both eyes one radius
    within 0.25 mm of the globe the head was made with (its ground truth: 11.48 mm; the
    population's 11.7 +- 0.45 pulls the weighted estimate to 11.68), half the 12 mm eye's miss."""
    out = hooded_identity["work"] / "re"
    if not (out / "eyes.json").is_file():
        r = _remove_eyeballs(hooded_identity, out)
        assert r.returncode == 0, r.stderr
    assert yaml.safe_load((hooded_identity["scan"] / "scan.yaml").read_text())["eye_size"] == "population"
    assert json.loads((hooded_identity["ingest"] / "scan.json").read_text())["eye_size"] == "population"
    truth = json.loads((hooded_identity["scan"] / "ground_truth.json").read_text())["eyes"]
    eyes = json.loads((out / "eyes.json").read_text())
    r_true = truth["left"]["eyeball_sphere"]["radius_mm"]
    assert eyes["left"]["radius"] == eyes["right"]["radius"]
    miss = abs(eyes["left"]["radius"] - r_true)
    assert miss < 0.25 and miss < 0.5 * abs(12.0 - r_true), (eyes["left"]["radius"], r_true)
    assert eyes["left"]["eye_size"] == "population"


@pytest.mark.slow
def test_a_loop_that_follows_no_eye_is_cut_again_where_the_scan_shows_the_eye(hooded_identity):
    """The search before the fix puts ident_s1_000's right eye on a sphere through the lower lid
    (9.2 mm off) and cuts a 25-vertex loop below it: loop_on_sphere fails (1.52 mm) and the eye
    placed from that opening has the loop 2.4 mm inside it. Set back until its lids may rest on
    it, its loop (12 mm) is narrower than any fissure with no iris in it: the cut went round part
    of an eye, so the stage places that eye again where the scan shows it (this head's texture),
    doubted and saying why, its limbus within 3 mm of the truth (9.2 mm off before). Passing
    over an optimum centred below the lid margin (off here, as the other fixes) avoids that cut
    altogether, the eye within 3 mm too."""
    out = hooded_identity["work"] / "re_old"
    r = _remove_eyeballs(hooded_identity, out, rival_restarts=False)
    assert r.returncode == 0, r.stderr
    right = json.loads((out / "eyes.json").read_text())["right"]
    assert right["limbus"]["source"] == "texture"
    assert any(d.startswith("the cut round the eye the geometry found spans ")
               and d.endswith("with no iris in it: placed from the texture instead") for d in right["doubts"]), right["doubts"]
    truth = json.loads((hooded_identity["scan"] / "ground_truth.json").read_text())["eyes"]["right"]
    off = np.linalg.norm(np.asarray(right["limbus"]["center"]) - truth["limbus"]["center_mm"])
    assert off < 3.0, off
    # the sphere through the lower lid is centred over 4 mm below the lid margin: that rule alone
    # passes it over, and no cut round part of an eye is made to be redone
    again = hooded_identity["work"] / "re_old_below"
    r = _remove_eyeballs(hooded_identity, again, rival_restarts=False, below_margin=True)
    assert r.returncode == 0, r.stderr
    right = json.loads((again / "eyes.json").read_text())["right"]
    assert not any(d.startswith("the cut round the eye the geometry found spans ") for d in right["doubts"])
    off = np.linalg.norm(np.asarray(right["limbus"]["center"]) - truth["limbus"]["center_mm"])
    assert off < 3.0, (off, right["limbus"]["source"], right["doubts"])


@pytest.mark.slow
def test_a_loop_the_published_eye_holds_is_a_doubt_not_a_refusal(monkeypatch):
    """The right eye's fitted sphere moved 3 mm down under its (true) cut: loop_on_sphere fails,
    but the eye the asset carries (re-anchored at the limbus the scan shows) holds the loop, so
    the eye is published with both doubts and loop_on_eye in its checks."""
    from dataclasses import replace

    import pipeline.placement.place as place
    from pipeline.placement.model import Eye

    real = place.place_eyes

    def lowered(*a, **k):
        out = real(*a, **k)
        e = out["right"].eye
        low = Eye(np.asarray(e.c) + [0.0, -3.0, 0.0], e.R, e.n, e.ha, e.tl, e.hb)
        out["right"] = replace(out["right"], eye=low)
        return out

    monkeypatch.setattr(place, "place_eyes", lowered)
    mesh, hints, _ = make_head(0.7)
    res = remove_eyeballs(mesh, hints, RemoveEyeballsSettings(), source="lowered.npz")
    right = res.eyes["right"].to_doc()
    assert not right["checks"]["loop_on_sphere"]["ok"] and right["checks"]["loop_on_eye"]["ok"]
    assert any(d.startswith("self-check loop_on_sphere: the eyelid loop lies ") for d in right["doubts"])
    assert any(d.startswith("the eyelid loop missed the fitted sphere, but the eye the asset carries")
               for d in right["doubts"]), right["doubts"]
    assert "loop_on_eye" not in res.eyes["left"].to_doc()["checks"]


def _grid(n=12):
    """(V, F): n x n unit squares in the plane z = 0, two triangles each; square (i, j) is faces
    2 * (i * n + j) and 2 * (i * n + j) + 1 (i along x)."""
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    vid = lambda i, j: i * (n + 1) + j
    F = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)
            F += [[a, b, c], [a, c, d]]
    return V, np.asarray(F, dtype=np.int64)


def _grid_with_region(n=12):
    """:func:`_grid`, the faces of square (i, j) (``sq``) and an eye region over squares 4-7 x 4-7."""
    V, F = _grid(n)

    def sq(i, j):
        return [2 * (i * n + j), 2 * (i * n + j) + 1]
    region = np.zeros(len(F), bool)
    for i in range(4, 8):
        for j in range(4, 8):
            region[sq(i, j)] = True
    return V, F, sq, region


def test_a_scan_hole_the_eye_region_reaches_leaves_one_simple_opening():
    """A hole touching the region at one corner (id64_in's left eye) made the cut's border a
    bow-tie, and one it reaches beyond the fit's reach (id71_out's right) a loop through
    vertices of no eye face: both scans were refused. Settled, the grazed hole stays off the
    region (its own loop, for retopo to fill) and a hole half on the region joins the opening."""
    from pipeline.remove_eyeballs.remove_eyeballs import _settle_holes

    n = 12
    V, F, sq, region = _grid_with_region(n)
    holes = sq(8, 8) + sq(3, 5)          # one at the region's corner (8, 8), one on its x = 4 side
    keep = np.ones(len(F), bool)
    keep[holes] = False
    region, F = region[keep], F[keep]
    H = meshtopo.boundary_halfedges(F)
    with pytest.raises(ValueError, match="bow-tie"):       # the cut as it was
        meshtopo.boundary_loops(F[~region])
    settled = _settle_holes(F, region, H)
    loops = meshtopo.boundary_loops(F[~settled])
    assert len(loops) == 3                 # the grid's border, the opening, the grazed hole
    corner = 8 * (n + 1) + 8
    assert not np.isin(F[settled], corner).any()
    # the grazed hole keeps its own loop round square (8, 8); the other is swallowed by the opening
    assert any(sorted(lp.tolist()) == sorted({corner, corner + 1, corner + n + 1, corner + n + 2})
               for lp in loops)
    assert np.isin([3 * (n + 1) + 5, 3 * (n + 1) + 6], F[settled]).all()
    # of the region as it was, only the faces at the grazed corner left it
    assert np.array_equal(settled[region], ~np.isin(F[region], corner).any(axis=1))
    # a region that meets no hole comes back as it was
    clean = np.zeros(len(F), bool)
    full_ids = np.cumsum(keep) - 1
    for i in (1, 2):
        for j in (9, 10):
            clean[full_ids[sq(i, j)]] = True
    assert np.array_equal(_settle_holes(F, clean, H), clean)


def test_an_opening_cut_into_a_scan_hole_is_refused_with_the_hole_named():
    """Where the cut's border meets a scanner hole at a vertex the settling could not clear
    (n2003_trim_tight: a 168 mm trim hole over the upper lid, a strip of skin one face wide
    between it and the opening), the refusal names the hole, its size and where it lies, not a
    "non-simple boundary"; a cut that meets no hole gets None."""
    from pipeline.remove_eyeballs.remove_eyeballs import _hole_at_bow_ties

    n = 12
    V, F, sq, region = _grid_with_region(n)
    hole = [f for i in (8, 9) for j in (8, 9) for f in sq(i, j)]    # 2 x 2 squares at the corner (8, 8)
    keep = np.ones(len(F), bool)
    keep[hole] = False
    region, F = region[keep], F[keep]
    H_in = meshtopo.boundary_halfedges(F)

    def cut(region):
        used = np.zeros(len(V), bool)
        used[F[~region].ravel()] = True
        remap = -np.ones(len(V), np.int64)
        remap[used] = np.arange(used.sum())
        F2 = remap[F[~region]]
        border = np.zeros(len(V), bool)
        border[F[region].ravel()] = True
        return F2, meshtopo.boundary_halfedges(F2), np.flatnonzero(used), set(remap[border & used].tolist())

    F2, H2, old_ids, ids = cut(region)
    with pytest.raises(ValueError, match="bow-tie"):
        meshtopo.boundary_loops(F2, only=np.fromiter(ids, np.int64), H=H2)
    perimeter, centre, count = _hole_at_bow_ties(V, H_in, H2, old_ids, ids)
    assert perimeter == pytest.approx(8.0)         # the 2 x 2 hole's rim, unit squares
    assert centre == [9.0, 9.0, 0.0]
    assert count == 1
    away = np.zeros(len(F), bool)                   # the same opening moved off the hole
    full_ids = np.cumsum(keep) - 1
    for i in range(1, 4):
        for j in range(1, 4):
            away[full_ids[sq(i, j)]] = True
    assert _hole_at_bow_ties(V, H_in, *cut(away)[1:]) is None


def test_a_hole_whose_every_rim_vertex_is_on_the_region_but_not_every_rim_edge_joins_it():
    """A pupil the scanner left open (``n1501_pupil_holes``): every vertex of the hole's rim lay
    on a face of the eye's region, but the face across one rim edge did not, so the hole was
    counted as the skin's, the cut made it one loop with the opening, and the scan was refused
    for a loop count. Settled, the hole joins the opening: the cut absorbs it whole."""
    from pipeline.remove_eyeballs.remove_eyeballs import _holes_inside, _settle_holes

    n = 12
    V, F = _grid(n)
    sq = lambda i, j: [2 * (i * n + j), 2 * (i * n + j) + 1]
    keep = np.ones(len(F), bool)
    keep[sq(5, 5)] = False                                   # the hole
    region = np.zeros(len(F), bool)
    for i, j in [(4, 4), (4, 5), (4, 6), (5, 4), (6, 4), (6, 5), (6, 6)]:   # all but (5, 6)
        region[sq(i, j)] = True
    across = np.zeros(len(F), bool)
    across[sq(5, 6)] = True
    region, across, F = region[keep], across[keep], F[keep]
    H = meshtopo.boundary_halfedges(F)
    rim = [5 * (n + 1) + 5, 5 * (n + 1) + 6, 6 * (n + 1) + 5, 6 * (n + 1) + 6]
    assert np.isin(rim, F[region]).all()                     # every rim vertex on the region
    assert _holes_inside(F, region, H) == 0                  # yet not every rim edge
    settled = _settle_holes(F, region, H)
    assert settled[across].all() and (settled >= region).all()
    assert _holes_inside(F, settled, H) == 1
    loops_in = meshtopo.boundary_component_count(F, H)
    assert loops_in == 2                                     # the grid's border and the hole
    # the cut: the border and the opening, the hole inside the opening
    assert meshtopo.boundary_component_count(F[~settled]) == loops_in - 1 + 1


def test_a_scan_hole_pinched_at_a_vertex_inside_the_region_goes_with_the_opening():
    """A scanner's hole pinched at a vertex into two lobes, every face round the pinch on the eye's
    region (fresh31's ``n3703_squint_in``): the pinch leaves with the region, and the cut's border
    is the grid's and one simple opening. Settling used to take the faces round the pinch off the
    region, which left the scan's own bow-tie on the opening and the scan refused."""
    from pipeline.remove_eyeballs.remove_eyeballs import _settle_holes

    n = 12
    V, F, sq, region = _grid_with_region(n)
    keep = np.ones(len(F), bool)
    keep[sq(5, 5) + sq(6, 6)] = False         # two squares that meet at the grid point (6, 6)
    region, F = region[keep], F[keep]
    H = meshtopo.boundary_halfedges(F)
    pinch = 6 * (n + 1) + 6
    assert (H[:, 0] == pinch).sum() == 2      # the scan's own bow-tie
    settled = _settle_holes(F, region, H)
    assert np.array_equal(settled, region)    # nothing to settle: the pinch goes with the region
    loops = meshtopo.boundary_loops(F[~settled])
    assert len(loops) == 2 and not np.isin(pinch, F[~settled])
    assert sorted(len(lp) for lp in loops) == [16, 48]     # the opening (4 x 4 squares), the border


def test_no_two_loop_vertices_are_moved_onto_one_point():
    """Known answers of ``_apart``: two loop vertices 0.35 mm apart moved onto one point (they
    averaged the same lift-off points) would fold the faces between them flat; the later is left
    where the cut put it. Two copies of one scan vertex (a bow-tie on the opening) start together
    and move together; positions a hair over ``APART_MM`` apart are left alone, and a loop with no
    such pair gives None (the move stands as it was)."""
    from pipeline.remove_eyeballs.remove_eyeballs import APART_MM, _apart

    start = np.array([[0.0, 0.0, 0.0], [0.35, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.0, 0.0],
                      [4.0, 0.0, 0.0], [4.3, 0.0, 0.0]])
    moved = np.array([[0.2, 0.5, 0.0], [0.2, 0.5, 0.0], [2.1, 0.4, 0.0], [2.1, 0.4, 0.0],
                      [4.1, 0.4, 0.0], [4.1 + 2 * APART_MM, 0.4, 0.0]])
    assert _apart(moved, start).tolist() == [False, True, False, False, False, False]
    assert _apart(moved[2:], start[2:]) is None
