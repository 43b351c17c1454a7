"""Seeing the data: the dataset card's plots, the contact sheet's asset names, the one progress
bar of a run, and ``dvc metrics show`` fitting 120 columns.

No Blender: the labels are made here with known gaze, head pose, assets and visibility, so the
statistics the plots draw are checked against counts taken independently of pipeline/render/plots.py.
"""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image, ImageDraw, ImageFont

from pipeline.render import plots
from pipeline.render import run as rr
from pipeline.render.card import dataset_card
from pipeline.render.sheet import CAPTION_H, NAME_PT, PAD, asset_name, contact_sheet
from stages import _common

ROOT = Path(__file__).resolve().parents[1]
ASSETS = ["alpha", "a_much_longer_asset_name"]


def _label(i: int, rng, w: int = 24, h: int = 16) -> dict:
    """A label with the fields the card, plots and contact sheet read (image ``i``)."""
    asset = ASSETS[0] if i % 3 else ASSETS[1]
    ang = np.linspace(0, 2 * np.pi, 28, endpoint=False)
    px = np.c_[w / 2 + 6 * np.cos(ang), h / 2 + 4 * np.sin(ang)]
    return {"index": i, "scan": asset, "asset": {"name": asset, "id": ASSETS.index(asset)},
            "gaze": {"eye": "left" if i % 2 else "right", "vector_camera": [0.1, 0.2, 0.97],
                     "camera": {"pitch_deg": float(rng.uniform(-25, 25)), "yaw_deg": float(rng.uniform(-35, 35))}},
            "head_pose": {"camera_pitch_deg": float(rng.uniform(-20, 10)), "camera_yaw_deg": float(rng.uniform(-20, 20))},
            "eyes": {side: {"radius_mm": 12.0 if asset == ASSETS[0] else 11.55,
                            "center_to_iris_plane_mm": float(rng.uniform(9.5, 10.5))} for side in ("left", "right")},
            "landmarks": {"px": px.tolist(), "pupil_center_px": [w / 2, h / 2], "apparent_px": None,
                          "visible": [bool(v) for v in rng.random(28) < np.linspace(0.05, 0.95, 28)]}}


@pytest.fixture(scope="module")
def labels():
    rng = np.random.default_rng(3)
    return [_label(i, rng) for i in range(30)]


def _info(stats, files, n) -> dict:
    """The parts of ``dataset.json`` the card reads (pipeline/render/dataset.py dataset_info)."""
    counts = stats["images_per_asset"]
    return {"name": "ds", "pipeline_version": "0", "n_images": n, "seed": 0, "preset": "generic",
            "label_schema": 1, "image": {"width": 24, "height": 16, "format": "PNG", "pixels": "top-left"},
            "files": {}, "mixing": "by weight",
            "assets": [{"id": k, "name": a, "weight": 1.0, "share": 0.5, "count": counts[a], "licence": "CC0",
                        "source_sha256": "", "doubts": []} for k, a in enumerate(ASSETS)],
            "settings": {"hdris": ["studio.exr"]}, "masks": None, "statistics": stats, "plots": files}


def test_plots_are_pngs_of_the_labels_numbers_and_the_card_quotes_them(labels, tmp_path):
    stats = plots.label_stats(labels, ASSETS)
    # the numbers, counted here without plots.py
    for key, field in (("gaze_camera_deg", lambda d: d["gaze"]["camera"]["pitch_deg"]),
                       ("head_pose_deg", lambda d: d["head_pose"]["camera_yaw_deg"])):
        part = stats[key]["pitch" if key == "gaze_camera_deg" else "yaw"]
        v = np.array([field(d) for d in labels])
        e = np.asarray(part["edges"])
        assert np.all(np.diff(e) == plots.BIN_DEG) and e[0] <= v.min() and v.max() < e[-1]
        assert part["counts"] == [int(np.sum((v >= a) & (v < b))) for a, b in zip(e[:-1], e[1:])]
        assert sum(part["counts"]) == len(labels) and part["max"] == round(float(v.max()), 4)
    assert stats["images_per_asset"] == {"alpha": 20, "a_much_longer_asset_name": 10}
    vis = np.array([d["landmarks"]["visible"] for d in labels])
    assert stats["landmark_visible_share"] == [round(float(s), 4) for s in vis.mean(0)]
    # the imaged eye's radius and iris plane, in 0.1 mm bins (12.0 in the bin [12.0, 12.1))
    r = stats["eye_mm"]["radius"]
    assert dict(zip(r["edges"], r["counts"])) == {11.5: 10, 11.6: 0, 11.7: 0, 11.8: 0, 11.9: 0, 12.0: 20}
    d = np.array([x["eyes"][x["gaze"]["eye"]]["center_to_iris_plane_mm"] for x in labels])
    e = np.asarray(stats["eye_mm"]["center_to_iris_plane"]["edges"])
    assert np.allclose(np.diff(e), plots.BIN_MM) and e[0] <= d.min() and d.max() < e[-1]
    assert stats["eye_mm"]["center_to_iris_plane"]["counts"] == [int(np.sum((d >= a) & (d < b)))
                                                                 for a, b in zip(e[:-1], e[1:])]

    out = tmp_path / "ds"
    files = plots.write_plots(out, stats)
    assert files == list(rr.CARD_PLOTS) and set(files) <= set(rr.DERIVED_FILES)   # a re-run deletes them
    first = {f: (out / f).read_bytes() for f in files}
    for f, data in first.items():
        with Image.open(io.BytesIO(data)) as im:
            im.verify()
            assert im.format == "PNG" and "Software" not in im.info and im.size[0] >= 600, f
    assert plots.write_plots(out, json.loads(json.dumps(stats))) == files       # as read from dataset.json
    assert {f: (out / f).read_bytes() for f in files} == first                    # same labels, same bytes

    card = dataset_card(_info(stats, files, len(labels)), labels[0])
    for f in files:
        assert f"]({f})" in card
    assert "](contact_sheet.png)" in card
    line = next(t for t in card.splitlines() if t.startswith("- Images per asset: "))
    assert dict((a, int(n)) for a, n in re.findall(r"`([^`]+)` (\d+)", line)) == stats["images_per_asset"]
    rows = [t for t in card.splitlines() if re.match(r"\| \d+-\d+ \|", t)]
    read = [float(c) for t in rows for c in t.strip("|").split("|")[1:]]
    assert np.allclose(read, vis.mean(0), atol=5e-4) and len(read) == 28
    g = np.array([d["gaze"]["camera"]["pitch_deg"] for d in labels])
    assert f"pitch {g.min():+.1f} to {g.max():+.1f} deg" in card
    assert (f"eyeball radius 11.55 to 12.00 mm, mean {np.mean([12.0] * 20 + [11.55] * 10):.2f}; rotation centre to "
            f"iris plane {d.min():.2f} to {d.max():.2f} mm") in card


def test_a_rerun_deletes_the_card_plots_and_nothing_else(tmp_path):
    for f in [*rr.CARD_PLOTS, "card/mine.png", "notes.txt"]:
        (tmp_path / f).parent.mkdir(exist_ok=True)
        (tmp_path / f).write_bytes(b"x")
    gone = {p.relative_to(tmp_path).as_posix() for p in rr.doomed_files(tmp_path, lambda i: True)}
    assert gone == set(rr.CARD_PLOTS)


def test_labels_without_the_eyes_geometry_have_no_eye_plot(labels, tmp_path):
    bare = [{k: v for k, v in d.items() if k != "eyes"} for d in labels]
    stats = plots.label_stats(bare, ASSETS)
    assert stats["eye_mm"] is None
    assert plots.write_plots(tmp_path, stats) == [f for f in rr.CARD_PLOTS if not f.endswith("/eye.png")]
    assert "eyeball radius" not in dataset_card(_info(stats, [], len(bare)), bare[0])


def test_no_visibility_no_visibility_plot(labels, tmp_path):
    bare = [{**d, "landmarks": {k: v for k, v in d["landmarks"].items() if k != "visible"}} for d in labels]
    stats = plots.label_stats(bare, ASSETS + ["unused"])
    assert stats["landmark_visible_share"] is None and stats["images_per_asset"]["unused"] == 0
    assert plots.write_plots(tmp_path, stats) == [f for f in rr.CARD_PLOTS if "visibility" not in f]
    assert not (tmp_path / "card" / "visibility.png").exists()


def test_contact_sheet_tiles_name_their_asset(labels, tmp_path):
    items = []
    for d in labels[:4]:
        p = tmp_path / f"{d['index']:06d}.png"
        Image.new("RGB", (24, 16), (90, 60, 50)).save(p)
        items.append((p, d))
    W, H = contact_sheet(items, tmp_path / "sheet.png", scale=2, columns=2)
    sheet = np.asarray(Image.open(tmp_path / "sheet.png").convert("RGB"))
    font = ImageFont.load_default(NAME_PT)
    tw = (W - PAD) // 2 - PAD
    assert tw >= font.getlength(ASSETS[1])                     # the column fits the longest name
    for k, (_, d) in enumerate(items):
        assert asset_name(d) == d["asset"]["name"]
        x = PAD + (k % 2) * (tw + PAD)
        y = PAD + (k // 2) * (2 * 16 + CAPTION_H + PAD)
        # the name, drawn alone on the sheet's background, is what the tile's first caption line holds
        ref = Image.new("RGB", (tw, NAME_PT + 3), (28, 28, 31))
        ImageDraw.Draw(ref).text((1, 1), asset_name(d), fill=(255, 255, 255), font=font)
        assert np.array_equal(sheet[y:y + NAME_PT + 3, x:x + tw], np.asarray(ref)), d["asset"]["name"]
    assert asset_name({"scan": "james"}) == "james"            # a render stage's label names its scan


def test_one_progress_bar_over_all_assets_named_and_quiet_when_off(monkeypatch, capsys, tmp_path):
    """render_dataset shows one bar over every pending image (not one per asset), its description
    the asset of the latest image; shard.py's own bar is off. Rendering is replaced by a stand-in
    that reports each image, then the run stops at the index (no labels were written)."""
    from pipeline.errors import ScanError
    from pipeline.render import shard as sh
    from pipeline.render.dataset import DatasetAsset, render_dataset
    from pipeline.render.settings import RenderSettings

    class Fake:                     # what render_dataset reads of a RenderAsset before rendering
        def __init__(self, name):
            self.name, self.usda, self.rig_npz = name, tmp_path / f"{name}.usda", tmp_path / "rig.npz"

    seen = []

    def run_shards(shards, asset, rig, out, opts, progress=True, total=0, on_result=None, **kw):
        seen.append((Path(asset).stem, progress, total))
        for i in range(total):
            on_result({"ok": True, "index": i})
        return {"workers": 1, "blender": {}}

    monkeypatch.setattr(sh, "run_shards", run_shards)
    assets = [DatasetAsset(k, a, tmp_path, tmp_path, w, Fake(a), f"h{k}") for k, (a, w) in enumerate(zip(ASSETS, (2, 1)))]
    settings = RenderSettings.from_params({"workers": 1})
    for enabled in (True, False):
        capsys.readouterr()
        seen.clear()
        with pytest.raises(ScanError, match="missing after the run"):
            render_dataset(assets, settings, 6, tmp_path / f"ds{enabled}", progress=enabled)
        err = capsys.readouterr().err
        assert seen == [("alpha", False, 4), ("a_much_longer_asset_name", False, 2)]
        if not enabled:
            assert err == ""
            continue
        states = [s.strip() for s in err.split("\r") if s.strip()]
        assert states and all(re.search(r"\b\d/6\b", s) for s in states), states     # one bar, of all 6
        assert states[-1].startswith(ASSETS[1]) and "6/6" in states[-1]


def test_progress_bar_names_each_asset_as_it_renders():
    buf = io.StringIO()
    bar = rr.Progress(3, True, file=buf)
    got = []
    bar.of("alpha", got.append)({"ok": True})
    bar.bar.refresh()
    bar.of("beta", got.append)({"ok": False})
    bar.of("beta", got.append)({"ok": True, "skipped": True})
    bar.close()
    states = [s.strip() for s in buf.getvalue().split("\r") if s.strip()]
    assert any(s.startswith("alpha") and "1/3" in s for s in states)
    assert states[-1].startswith("beta") and "3/3" in states[-1] and "failed=1" in states[-1]
    assert len(got) == 3 and bar.failed == 1


# ---------------------------------------------------------------------------------- dvc metrics show

def _dvc(cwd, *args) -> subprocess.CompletedProcess:
    env = {**os.environ, "DVC_NO_ANALYTICS": "1"}
    return subprocess.run([sys.executable, "-m", "dvc", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def _declared_metrics(repo) -> list[tuple[str, str]]:
    """``(stage, path)`` of every DVC metrics output of ``repo``, foreach stages expanded by DVC."""
    from dvc.repo import Repo

    with Repo(str(repo)) as r:
        return [(s.name.split("@")[0], o.def_path) for s in r.index.stages for o in s.outs if o.metric]


@pytest.mark.slow
def test_dvc_metrics_show_fits_120_columns(tmp_path):
    """The repository's dvc.yaml in a fresh DVC repo with every declared metrics file written the way
    stages/_common.py writes it, from metrics at their widest (7-digit face counts, 4-digit
    errors), for the home scans and a long-named identity: the table ``dvc metrics show`` prints
    is at most 120 columns wide, and every stage's full metrics are still a (non-metric) output."""
    doc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    for stage in doc["stages"].values():
        body = stage.get("do", stage)
        if body.get("metrics"):
            full = [next(iter(e)) for e in body["outs"] if isinstance(e, dict) and next(iter(e)).endswith(".metrics.json")]
            assert [_common.summary_path(f).name for f in full] == [Path(next(iter(e))).name for e in body["metrics"]], \
                body["cmd"]
    (tmp_path / "dvc.yaml").write_text((ROOT / "dvc.yaml").read_text())
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    scans = ["synthetic_head", "james", "ict_neutral", "synthetic_head_identity_19"]
    (tmp_path / "params.yaml").write_text(yaml.safe_dump({**params, "scans": scans}))
    assert _dvc(tmp_path, "init", "--no-scm", "-q").returncode == 0
    declared = _declared_metrics(tmp_path)
    assert len(declared) >= 2 + 8 * len(scans) and all(p.endswith(".summary.json") for _, p in declared)
    widest = {"faces": 9_999_999, "images": 1_000_000, "issues": 99, "err_mm": 0.123456789}
    for stage, p in declared:
        metrics: dict = {}
        for key, sources in _common.HEADLINES[stage].items():
            for s in sources:
                node = metrics
                *parents, leaf = s.split(".")
                for part in parents:
                    node = node.setdefault(part, {})
                node[leaf] = widest[key]
        f = tmp_path / p
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(json.dumps(_common.headline(stage, metrics)))
    r = _dvc(tmp_path, "metrics", "show")
    assert r.returncode == 0 and not r.stderr.strip(), r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 1 + len(declared) and {ln.split()[0] for ln in lines[1:]} == {p for _, p in declared}
    assert lines[0].split() == ["Path", "err_mm", "faces", "images", "issues"]
    assert max(map(len, lines)) <= 120, r.stdout


def test_stage_writes_its_headline_beside_the_full_metrics(tmp_path):
    from pipeline.results import StageResult

    def main(argv):
        return StageResult({"n_faces": 10, "interpolation_error_mm": -0.0123456, "sweep_flipped_faces": 2,
                            "lids": {"up": 1}}, {"wall_s": 1.0}, tmp_path / "rig.metrics.json")

    main.__module__ = "stages.rig"
    assert _common.run_stage(main, []) == 0
    assert json.loads((tmp_path / "rig.metrics.json").read_text())["lids"] == {"up": 1}     # nothing lost
    assert json.loads((tmp_path / "rig.summary.json").read_text()) == {"faces": 10, "err_mm": 0.01235, "issues": 2}
    assert _common.headline("dataset", {"n_images": 3}) is None


def test_card_counts_lighting_eye_configurations_and_landmarks_inside(labels, tmp_path):
    """Issue 33: the card says how many images hold every landmark inside, and counts the lighting
    and the eye configurations; their plots are files a dataset run deletes and redraws."""
    from pipeline.render import plan as pl

    rng = np.random.default_rng(5)
    full = []
    for i, d in enumerate(labels):
        px = np.asarray(d["landmarks"]["px"], float)
        if i in (3, 7):
            px[6, 0] = 24.4                                  # the lateral canthus 0.4 px past the right border
        full.append({**d, "image": {"width": 24, "height": 16}, "landmarks": {**d["landmarks"], "px": px.tolist()},
                     "lighting": {"hdri": ["city.exr", "night.exr"][i % 2], "rotation_deg": 0.0,
                                  "strength": float(rng.uniform(0.6, 1.6))},
                     "eye_configuration": {"iris_color": ["brown", "blue", "green"][i % 3], "sclera_tint": "white",
                                           "veins": ["none", "light"][i % 2],
                                           "pupil_radius_mm": float(rng.uniform(1.0, 3.5))}})
    stats = plots.label_stats(full, ASSETS)
    inside = stats["landmarks_inside"]
    assert inside["images_all_inside"] == 28 and inside["share"] == round(28 / 30, 4)
    assert inside["outside_per_landmark"][6] == 2 and sum(inside["outside_per_landmark"]) == 2
    assert inside["min_margin_px"] == -0.4
    assert stats["lighting"]["hdri"] == {"city.exr": 15, "night.exr": 15}
    assert sum(stats["lighting"]["strength"]["counts"]) == 30
    conf = stats["eye_configuration"]
    assert conf["iris_color"] == {"blue": 10, "brown": 10, "green": 10} and conf["sclera_tint"] == {"white": 30}
    assert conf["veins"] == {"light": 15, "none": 15} and sum(conf["pupil_radius_mm"]["counts"]) == 30
    files = plots.write_plots(tmp_path, stats)
    assert {"card/lighting.png", "card/eye_configuration.png"} <= set(files)
    assert set(files) <= set(rr.DERIVED_FILES) | set(pl.OWN_FILES)                 # a re-run deletes them
    card = dataset_card(_info(stats, files, len(full)), full[0])
    assert "Every landmark inside the image (`landmarks.px` within the frame): 28 of 30 images (93.3 %)" in card
    assert "by index: 6: 2." in card and "environment map `city.exr` 15, `night.exr` 15" in card
    assert "iris colour `blue` 10, `brown` 10, `green` 10; sclera tint `white` 30; veins `light` 15, `none` 15" in card
