"""Procedural identities: params.yaml's ``identities:`` (checked, built by the synthetic_head stage),
the command that adds N of them, the skin tone and age-like detail they set, and assets that
publish anywhere and keep their eyes when their folder is copied."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline.synthetic_head import make_synthetic_head
from pipeline.synthetic_head.paint import SKIN_RGB, SKIN_TONE_BASE, melanin_transmittance
from pipeline.params_check import check_params
from pipeline.synthetic_head import identities as idlib
from stages import check_params as cp
from stages import identities as ids
from stages import synthetic_head as sh_stage
from stages._common import run_stage

ROOT = Path(__file__).resolve().parents[1]
TINY = {"target_triangles": 2000, "texture_size": 64}


def _copy_params(tmp_path) -> Path:
    p = tmp_path / "params.yaml"
    shutil.copyfile(ROOT / "params.yaml", p)
    return p


def _add(p, n, seed=0, capsys=None):
    rc = ids.main(["--n", str(n), "--seed", str(seed), "--params", str(p), "--no-repro"])
    assert rc == 0
    return capsys.readouterr().out if capsys else None


# ----------------------------------------------------------------------------- the command

def test_command_adds_n_entries_deterministically_keeping_every_line(tmp_path, capsys):
    p = _copy_params(tmp_path)
    before = p.read_text().split("\n")
    out = _add(p, 4, seed=3, capsys=capsys)
    names = [f"ident_s3_{i:03d}" for i in range(4)]
    assert out.splitlines()[-1] == "dvc repro " + " ".join(f"usd@{n}" for n in names)
    after = p.read_text()
    lines = after.split("\n")
    it = iter(lines)                      # every original line (comments too), in order
    assert all(any(ln == b for ln in it) for b in before)
    assert len(lines) == len(before) + 8
    data = yaml.safe_load(after)
    assert list(data["identities"]) == ["synthetic_head", *names]
    assert data["scans"] == ["synthetic_head", *names]
    e = data["identities"]["ident_s3_002"]
    assert set(e) == {"seed", "eye_shape", "skin_tone", "wrinkle_scale", "pore_scale", "eye_spacing_mm",
                      "target_triangles", "asset_eye_size"}
    assert e["asset_eye_size"] == "population"          # the asset keeps the globe drawn for the head
    assert e["target_triangles"] == idlib.DEFAULT_TRIANGLES and 0 <= e["skin_tone"] <= 1
    assert check_params(data)["identities"]["ident_s3_002"].skin_tone == e["skin_tone"]
    # the same run again: the same bytes; a shorter run elsewhere: the first entries
    _add(p, 4, seed=3)
    assert p.read_text() == after
    (tmp_path / "b").mkdir()
    q = _copy_params(tmp_path / "b")
    _add(q, 2, seed=3)
    short = yaml.safe_load(q.read_text())["identities"]
    assert short == {k: data["identities"][k] for k in ["synthetic_head", *names[:2]]}
    # another seed adds beside them
    _add(p, 2, seed=4)
    assert len(yaml.safe_load(p.read_text())["scans"]) == 7


def test_tones_spread_over_the_range_for_any_n():
    tones = sorted(idlib.draw_identity(0, i, 1000)["skin_tone"] for i in range(20))
    assert np.diff([0.0, *tones, 1.0]).max() < 0.1        # 20 tones leave no gap of 0.1


def test_command_refuses_params_without_marks_in_one_line(tmp_path, capsys):
    p = tmp_path / "params.yaml"
    p.write_text("scans:\n  - synthetic_head\n\nidentities:\n  synthetic_head: {}\n")
    assert ids.main(["--n", "2", "--params", str(p), "--no-repro"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {p}: 'identities:' has no '# >>> identities'") and err.count("\n") == 1
    assert p.read_text() == "scans:\n  - synthetic_head\n\nidentities:\n  synthetic_head: {}\n"


# ----------------------------------------------------------------------------- check_params

@pytest.mark.parametrize("entry, scans_too, message", [
    ({"seed": 3, "skin_colour": 0.5}, True, "identities.idx.skin_colour is an unknown key"),
    ({"skin_tone": 1.5}, True, "identities.idx.skin_tone must be <= 1 (got 1.5)"),
    ({"wrinkle_scale": -1}, True, "identities.idx.wrinkle_scale must be >= 0"),
    ({"eye_shape": "sleepy"}, True, "identities.idx.eye_shape must be one of 'round', 'hooded'"),
    ({"seed": 3}, False, "identities: 'idx' is not listed under scans"),
])
def test_check_params_refuses_a_bad_identity_in_one_line(tmp_path, capsys, entry, scans_too, message):
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["identities"]["idx"] = entry
    if scans_too:
        data["scans"].append("idx")
    p = tmp_path / "params.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {p}: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "ok").exists()


def test_check_params_refuses_a_dotted_identity_name(tmp_path, capsys):
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["identities"]["a.b"] = {}
    data["scans"].append("a.b")
    p = tmp_path / "params.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    assert run_stage(cp.main, [str(p), str(tmp_path / "ok")]) == 2
    assert "identities: 'a.b' has a '.'" in capsys.readouterr().err


# ----------------------------------------------------------------------------- the stage and the head

def _tree(folder) -> dict:
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(Path(folder).iterdir())}


def test_stage_builds_an_identity_and_the_home_head_unchanged(tmp_path):
    data = yaml.safe_load((ROOT / "params.yaml").read_text())
    data["synthetic_head"].update(TINY)
    data["identities"]["idx"] = {"seed": 11, "skin_tone": 0.9, "eye_shape": 0.5}
    data["scans"].append("idx")
    p = tmp_path / "params.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    for name, extra in (("plain", []), ("synthetic_head", ["--identity", "synthetic_head"]),
                        ("idx", ["--identity", "idx"])):
        argv = [str(tmp_path / name), "--params", str(p), "--metrics", str(tmp_path / f"{name}.json"), *extra]
        assert run_stage(sh_stage.main, argv) == 0
    assert _tree(tmp_path / "plain") == _tree(tmp_path / "synthetic_head")     # {} = the block
    assert _tree(tmp_path / "idx")["texture.png"] != _tree(tmp_path / "plain")["texture.png"]


def test_melanin_known_answers():
    assert np.array_equal(melanin_transmittance(SKIN_TONE_BASE), [1.0, 1.0, 1.0])
    assert np.allclose(np.array(SKIN_RGB) * melanin_transmittance(1.0), (64, 43, 28), atol=1)
    assert np.allclose(np.array(SKIN_RGB) * melanin_transmittance(0.0), (239, 185, 159), atol=1)


@pytest.mark.slow
def test_skin_tone_darkens_and_browns_the_texture_monotonically():
    """The same head at rising tones: the skin's mean colour falls in every channel, and blue falls
    faster than red (a hue change, not a brightness scale); the eyes keep their colours."""
    base = make_synthetic_head(**TINY)
    tex = {t: make_synthetic_head(**TINY, skin_tone=t).texture.astype(float) for t in (0.0, 0.3, 0.6, 1.0)}
    assert np.array_equal(make_synthetic_head(**TINY, skin_tone=SKIN_TONE_BASE).texture, base.texture)
    skin = (base.texture.astype(float).sum(2) > 300)              # lit skin texels (not brows, lashes, eyes)
    assert skin.mean() > 0.3
    means = np.array([tex[t][skin].mean(0) for t in sorted(tex)])  # (4, 3) RGB
    assert np.all(np.diff(means, axis=0) < -3)
    ratio = means[:, 2] / means[:, 0]
    assert np.all(np.diff(ratio) < 0)
    eye = np.all(base.texture == [12, 10, 10], axis=2)           # the pupils: painted over the skin
    assert eye.any() and all(np.all(tex[t][eye] == [12, 10, 10]) for t in tex)


def test_age_like_detail_scales_the_relief():
    amp = [make_synthetic_head(**TINY, wrinkle_scale=w, pore_scale=w).ground_truth["skin_detail_amplitude_mm"]
           for w in (0.0, 1.0, 2.0)]
    assert amp[0] == 0.0 and amp[1] < amp[2]
    assert amp[2] == pytest.approx(2 * amp[1], rel=0.05)


# ----------------------------------------------------------------------------- assets that travel

def _eyes_resolve(layer, root="tiny") -> list[int]:
    """Face-vertex count of each eye's Outer and Inner mesh, composed from ``layer``."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(layer))
    out = []
    for side in ("left", "right"):
        for part in ("Outer", "Inner"):
            prim = stage.GetPrimAtPath(f"/{root}/Eyes/eye_{side}/{part}")
            out.append(len(UsdGeom.Mesh(prim).GetFaceVertexIndicesAttr().Get() or []) if prim else 0)
    return out


def test_usd_publishes_anywhere_and_a_copied_folder_keeps_its_eyes(tmp_path):
    from fixtures import make_inputs, usd_argv
    from pipeline.usd.asset import check_package
    from pipeline.usd.validate import validate_stage
    from stages import usd as usd_stage

    inp = make_inputs(tmp_path / "build")
    out = tmp_path / "somewhere else" / "deep" / "tiny"           # no rigged_assets/ anywhere
    assert run_stage(usd_stage.main, usd_argv(inp, out)) == 0
    assert (out / "eyeball" / "eyeball.usda").read_bytes() == (inp["eyeball"] / "eyeball.usda").read_bytes()
    assert sorted(p.name for p in (out / "eyeball" / "textures").iterdir()) == \
        sorted(p.name for p in (inp["eyeball"] / "textures").iterdir())
    shutil.rmtree(inp["eyeball"])                                 # the source eyeball is gone
    moved = tmp_path / "moved" / "copy of tiny"
    shutil.copytree(out, moved)
    shutil.rmtree(out)
    counts = _eyes_resolve(moved / "tiny.usda")
    assert min(counts) > 0 and counts[:2] == counts[2:]
    assert validate_stage(moved / "tiny.usda") == []
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(moved / "tiny.usdz", lone / "x.usdz")            # the package alone
    assert check_package(lone / "x.usdz") == [] and _eyes_resolve(lone / "x.usdz") == counts
