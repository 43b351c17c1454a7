"""``python -m stages.dataset``: several assets mixed by weight in one resumable render;
the dataset card; ``examples/load_dataset.py``.

Two tiny assets (fixtures.make_render_asset, different names and licences) render 24 x 16 px
images at 1 sample. The mix is tested exactly: counts come from largest-remainder allocation,
so every asset gets its quota rounded up or down, never a sampled count.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import yaml

from fixtures import make_render_asset
from pipeline.io.labels_file import read_index, read_label
from pipeline.render import labels as lb
from pipeline.render import mix
from pipeline.render import plan as pl
from pipeline.render.run import CARD_PLOTS
from pipeline.render.settings import MAX_IMAGES

ROOT = Path(__file__).resolve().parents[1]
LOADER = ROOT / "examples" / "load_dataset.py"
TINY = {"width": 24, "height": 16, "frame_margin_px": None, "samples": 1, "denoise": False, "workers": 1, "shard_size": 2,
        "connect_timeout_s": 3, "sheet_images": 4}
LICENCES = {"alpha": "CC0-1.0 (test alpha)", "beta": "CC-BY-4.0 (test beta)"}


# ------------------------------------------------------------------------------- the mix (no Blender)

def test_every_prefix_is_within_one_image_of_its_quota():
    """The quota method: for every n (each prefix of one sequence) each asset holds floor or ceil
    of n w / W images, exact rational arithmetic as the check; float weights too."""
    rng = np.random.default_rng(3)
    for trial in range(200):
        k = int(rng.integers(1, 7))
        weights = ([int(x) for x in rng.integers(1, 20, size=k)] if trial % 2 else
                   [float(x) for x in rng.uniform(0.05, 3.0, size=k)])
        n = int(rng.integers(0, 600))
        a = mix.assign(n, weights, seed=int(rng.integers(0, 2**40)))
        assert a.shape == (n,)
        fw = [Fraction(float(w)) for w in weights]
        share = [f / sum(fw) for f in fw]
        c = [0] * k
        for t, x in enumerate(a.tolist(), 1):
            c[x] += 1
            for j in range(k):
                q = t * share[j]
                assert math.floor(q) <= c[j] <= math.ceil(q), (weights, t)
        counts = mix.allocate(n, weights)
        assert counts.sum() == n and np.all(np.abs(counts - n * np.asarray(weights, float) / sum(weights)) < 1)
    # whole quotas are met exactly
    assert mix.allocate(10000, [2, 1, 1]).tolist() == [5000, 2500, 2500]
    assert mix.allocate(8, [2.5, 1.25, 1.25]).tolist() == [4, 2, 2]


def test_assignment_is_a_prefix_of_one_sequence_and_mixes_every_slice():
    """Image i's asset depends on the weights, the seed and i, never on n."""
    a = mix.assign(1000, [1, 1], seed=0)
    assert np.array_equal(a, mix.assign(1000, [1, 1], seed=0))
    assert len({tuple(mix.assign(30, [1, 1, 1], seed=s)[:3]) for s in range(8)}) > 1   # the seed orders ties
    for n in (1, 7, 50, 200, 999):
        assert np.array_equal(mix.assign(n, [1, 1], seed=0), a[:n])
    b = mix.assign(1000, [3, 1, 2.5], seed=4)
    for n in (1, 60, 200, 300):
        assert np.array_equal(mix.assign(n, [3, 1, 2.5], seed=4), b[:n])
    for lo in range(0, 1000, 100):                                    # interleaved, not in blocks
        assert 25 <= np.count_nonzero(a[lo:lo + 100] == 0) <= 75
    # the mixing stream's key [seed, MIX_TAG] is no image's key [seed, index, attempt]
    assert mix.MIX_TAG >= MAX_IMAGES


def test_legacy_mix_is_the_largest_remainder_permutation():
    """Folders planned before the quota mix are read with it (pipeline/render/plan.py)."""
    a = mix.assign_legacy(10, [2.5, 1.25, 1.25], seed=0)
    assert np.bincount(a).tolist() == [5, 3, 2]


@pytest.mark.parametrize("weights, message", [
    ([1, 2, 3], "3 weight(s) for 2 asset(s)"), ([1, 0], "weight 2 must be a finite number > 0"),
    ([1, "nan"], "weight 2 must be a finite number > 0"), (["x", 1], "weight 1 ('x') is not a number")])
def test_bad_weights_named(weights, message):
    with pytest.raises(ValueError) as ei:
        mix.check_weights(weights, 2)
    assert message in str(ei.value)


# ------------------------------------------------------------------------------- the command

@pytest.fixture(scope="module")
def two(tmp_path_factory):
    root = tmp_path_factory.mktemp("dataset")
    made = [make_render_asset(root, name, licence=lic) for name, lic in LICENCES.items()]
    params = root / "params.yaml"
    params.write_text(yaml.safe_dump({"render": TINY}))
    return {"root": root, "assets": [m["asset_dir"] for m in made], "params": params,
            "eyeball": root / "rigged_assets" / "eyeball"}


def _cmd(two, out, *extra, n=6, assets=None):
    return [sys.executable, "-m", "stages.dataset", "--assets",
            *map(str, two["assets"] if assets is None else assets), "--n", str(n), "--out", str(out),
            "--params", str(two["params"]), "--no-progress", *extra]


def _run(cmd, **kw):
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, **kw)


@pytest.mark.slow
def test_bad_inputs_exit_2_with_one_line_and_nothing_written(two, tmp_path):
    out = tmp_path / "ds"
    broken = two["root"] / "rigged_assets" / "broken"            # a folder with a rig but no valid asset
    broken.mkdir(exist_ok=True)
    (broken / "broken.usda").write_text("#usda 1.0\ngarbage (((\n")
    shutil.copytree(two["root"] / "build" / "alpha" / "rig", two["root"] / "build" / "broken" / "rig",
                    dirs_exist_ok=True)
    cases = [
        (_cmd(two, out, assets=[two["assets"][0], tmp_path / "missing"]), "missing: rigged asset folder not found"),
        (_cmd(two, out, assets=[two["assets"][0], tmp_path]), f"{tmp_path.name}/rig: no rig.npz"),
        (_cmd(two, out, assets=[two["assets"][0], broken]), "broken.usda: USD stage could not be opened"),
        (_cmd(two, out, assets=[two["eyeball"]]), "no scan asset given"),
        (_cmd(two, out, n=0), "--n: must be between 1 and 1000000 (got 0)"),
        (_cmd(two, out, "--weights", "1", "2", "3"), "--weights: 3 weight(s) for 2 asset(s)"),
        (_cmd(two, out, "--weights", "1", "-1"), "--weights: weight 2 must be a finite number > 0"),
        (_cmd(two, out, "--preset", "nope"), "render.preset must be one of"),
        (_cmd(two, out, assets=[two["assets"][0], two["assets"][0]]), "asset name 'alpha' is also the name of"),
        ([sys.executable, "-m", "stages.dataset", "--assets", str(two["assets"][0]), "--n", "6"],
         "the following arguments are required: --out"),
    ]
    for cmd, message in cases:
        r = _run(cmd)
        assert r.returncode == 2 and r.stderr.startswith("error: ") and r.stderr.count("\n") == 1, (cmd, r.stderr)
        assert message in r.stderr, (message, r.stderr)
        assert not out.exists(), message
    taken = tmp_path / "taken"                                         # not a dataset: left alone
    taken.mkdir()
    (taken / "notes.txt").write_text("mine")
    (taken / "000000.png").write_bytes(b"not yours")
    r = _run(_cmd(two, taken))
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is not a dataset folder" in r.stderr
    assert sorted(p.name for p in taken.iterdir()) == ["000000.png", "notes.txt"]


def _labels(out):
    return sorted(p for p in out.glob("0*.json"))


@pytest.fixture(scope="module")
def resumed(two, tmp_path_factory):
    """A 6-image dataset of alpha (weight 2) and beta (weight 1), killed after two images and resumed."""
    out = tmp_path_factory.mktemp("resumed") / "ds"
    cmd = _cmd(two, out, "--weights", "2", "1")
    proc = subprocess.Popen(cmd, cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    t0 = time.time()
    while time.time() - t0 < 180 and len(_labels(out)) < 2 and proc.poll() is None:
        time.sleep(0.1)
    assert proc.poll() is None, proc.stderr.read().decode()
    os.killpg(proc.pid, signal.SIGKILL)                               # the run and its dask/Blender children
    proc.wait()
    n_before = len(_labels(out))
    assert 2 <= n_before < 6 and not (out / "index.jsonl").exists() and not (out / "README.md").exists()
    r = _run(cmd + ["--resume"])
    assert r.returncode == 0, r.stderr
    return {"out": out, "n_before": n_before, "stdout": r.stdout}


@pytest.mark.blender
def test_resumed_dataset_has_every_index_exactly_once(two, resumed):
    out = resumed["out"]
    plan = mix.assign(6, [2, 1], seed=0)
    names = list(LICENCES)
    rows = read_index(out / "index.jsonl")
    assert [r["index"] for r in rows] == list(range(6))
    assert [r["asset"] for r in rows] == [names[k] for k in plan]
    assert sorted(p.name for p in out.glob("0*")) == sorted(f"{i:06d}{e}" for i in range(6)
                                                             for e in (".png", ".json", "_seg.png", "_depth.exr"))
    streams = set()
    for r in rows:
        lab = read_label(out / r["json"])
        assert lab.doc["asset"] == {"name": names[plan[r["index"]]], "id": int(plan[r["index"]])}
        assert lab.doc["scan"] == names[plan[r["index"]]] and lb.check_label(lab.doc) < 0.01
        streams.add((lab.doc["seed"]["seed"], lab.doc["seed"]["index"]))
    assert len(streams) == 6                                          # no two images share a random stream
    t = json.loads((out / "timings.json").read_text())
    assert t["skipped_done"] >= resumed["n_before"] and t["rendered"] == 6 - t["skipped_done"]
    assert t["counts"] == {"alpha": 4, "beta": 2} and not (out / ".tmp").exists()
    info = json.loads((out / "dataset.json").read_text())
    assert [(a["name"], a["count"], a["licence"]) for a in info["assets"]] == [
        ("alpha", 4, LICENCES["alpha"]), ("beta", 2, LICENCES["beta"])]
    card = (out / "README.md").read_text()
    for text in ("| 0 | `alpha` | 2 | 0.6667 | 4 | CC0-1.0 (test alpha)", "| 1 | `beta` | 1 | 0.3333 | 2 | CC-BY-4.0",
                 "24 x 16 px", "Label schema 1", "`asset.id`: integer", "`landmarks.px`: numbers, shape (28, 2)",
                 "`NNNNNN_seg.png`: 8-bit indexed PNG", "pixel centres at +0.5"):
        assert text in card, text
    assert "## Doubts" not in card and all(a["doubts"] == [] for a in info["assets"])
    assert (out / "contact_sheet.png").is_file()
    # run again: nothing to render, the same files
    before = {p.name: p.read_bytes() for p in out.glob("0*")}
    r = _run(_cmd(two, out, "--weights", "2", "1"))
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "timings.json").read_text())["rendered"] == 0
    assert {p.name: p.read_bytes() for p in out.glob("0*")} == before


@pytest.mark.blender
def test_changed_weights_need_overwrite_and_rerender_only_the_images_whose_asset_changed(two, resumed, tmp_path):
    out = tmp_path / "ds"
    shutil.copytree(resumed["out"], out)
    old, new = mix.assign(6, [2, 1], seed=0), mix.assign(5, [1, 1], seed=0)
    changed = int(np.count_nonzero(old[:5] != new))
    keep = {f"{i:06d}.png": (out / f"{i:06d}.png").read_bytes() for i in range(5) if old[i] == new[i]}
    (out / "notes.txt").write_text("the user's own")
    r = _run(_cmd(two, out, "--weights", "1", "1", n=5))                  # another plan: refused
    assert r.returncode == 2 and r.stderr.startswith(f"error: {out}: holds a dataset of another plan ("
                                                     "weights [2.0, 1.0] -> [1.0, 1.0]): --overwrite replaces it")
    # --overwrite: 4 files per image that goes (index 5 and the changed ones), the index, sheet and
    # card files, and the card's plots
    # card files, the card's plots and the splits (plan.OWN_FILES)
    gone = 4 * (changed + 1) + 2 + len(pl.OWN_FILES) + len(CARD_PLOTS)
    r = _run(_cmd(two, out, "--weights", "1", "1", "--overwrite", n=5))
    assert r.returncode == 0, r.stderr
    assert r.stderr == f"note: --overwrite: {gone} files of the earlier dataset in {out} go (" \
                       "weights [2.0, 1.0] -> [1.0, 1.0])\n"
    t = json.loads((out / "timings.json").read_text())
    assert t["rendered"] == changed and t["skipped_done"] == 5 - changed and t["stale_images"] == changed
    assert t["removed_files"] == gone and (out / "notes.txt").read_text() == "the user's own"
    assert [r["asset_id"] for r in read_index(out / "index.jsonl")] == new.tolist()
    assert not (out / "000005.json").exists()
    assert all((out / k).read_bytes() == v for k, v in keep.items())


@pytest.mark.blender
def test_loader_example_reads_arrays_without_the_project(resumed, tmp_path):
    out = resumed["out"]
    # a subprocess in which importing pipeline or stages fails: the example must not need them
    code = ("import runpy, sys\n"
            "class Block:\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] in ('pipeline', 'stages', 'conftest'):\n"
            "            raise ImportError('project import: ' + name)\n"
            "sys.meta_path.insert(0, Block())\n"
            "sys.argv = sys.argv[1:]\n"
            "runpy.run_path(sys.argv[0], run_name='__main__')\n")
    r = subprocess.run([sys.executable, "-c", code, str(LOADER), str(out)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "images        (6, 16, 24, 3) uint8" in r.stdout and "landmarks     (6, 28, 2) float32" in r.stdout
    assert "gaze          (6, 3) float32" in r.stdout and "per asset     alpha: 4, beta: 2" in r.stdout
    spec = importlib.util.spec_from_file_location("load_dataset", LOADER)
    loader = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loader)
    data = loader.load_dataset(out)
    assert data["asset_ids"].tolist() == mix.assign(6, [2, 1], seed=0).tolist()
    assert data["masks"].shape == (6, 16, 24) and data["masks"].max() <= 6       # render.masks (default on)
    assert data["asset_names"] == ["alpha", "beta"]
    lab = read_label(out / "000003.json")
    np.testing.assert_allclose(data["landmarks"][3], lab.px, atol=1e-4)
    np.testing.assert_allclose(data["gaze"][3], lab.doc["gaze"]["vector_camera"], atol=1e-6)
    assert data["images"].dtype == np.uint8 and data["images"].std() > 1
    assert loader.check(data)["reprojection_px_max"] < 0.01
    # masks, when dataset.json names them: one class id per pixel from the indexed PNGs
    from PIL import Image

    copy = tmp_path / "with_masks"
    shutil.copytree(out, copy)
    info = json.loads((copy / "dataset.json").read_text())
    info["masks"] = {"file": "NNNNNN_seg.png", "format": "8-bit indexed PNG", "classes": {"0": "background"}}
    (copy / "dataset.json").write_text(json.dumps(info))
    for i in range(6):
        im = Image.fromarray(np.full((16, 24), i, np.uint8), mode="P")
        im.putpalette([v for k in range(256) for v in (k, 0, 255 - k)])
        im.save(copy / f"{i:06d}_seg.png", optimize=False)
    masks = loader.load_dataset(copy)["masks"]
    assert masks.shape == (6, 16, 24) and masks.dtype == np.uint8 and masks[:, 0, 0].tolist() == list(range(6))


def test_asset_doubts_reach_the_card():
    """An asset whose metadata doubts an eye (remove_eyeballs' ``doubts``, carried by rig and
    usd) is listed under "Doubts" in the card, named, with the sentence."""
    from pipeline.render.asset import RenderAsset
    from pipeline.render.card import _doubts
    from pipeline.render.dataset import DatasetAsset

    doubt = "opening 18.0 mm wide where the texture's fissure is 31.5 mm"
    meta = {"eyes": {"left": {"doubts": [doubt]}, "right": {}}}
    asset = RenderAsset("james", Path("james.usda"), Path("rig.npz"), np.zeros((0, 3)), 1.0, [], {}, {},
                        metadata=meta)
    a = DatasetAsset(0, "james", Path("."), Path("."), 1.0, asset, "")
    assert a.doubts() == [f"left eye: {doubt}"]
    lines = _doubts([{"name": "james", "doubts": a.doubts()}, {"name": "ok", "doubts": []}])
    assert lines[0] == "## Doubts" and f"- `james`, left eye: {doubt}" in lines
    assert not any("`ok`" in line for line in lines) and _doubts([{"name": "ok", "doubts": []}]) == []


@pytest.mark.blender
def test_growing_adds_only_the_new_images_and_shrinking_removes_the_tail(two, resumed, tmp_path):
    """Issue 33: --n 6 -> 9 renders images 6..8 and leaves images 0..5 byte-identical, with no
    --overwrite; 9 -> 4 removes the tail's files and renders nothing."""
    out = tmp_path / "ds"
    shutil.copytree(resumed["out"], out)
    before = {p.name: p.read_bytes() for p in out.glob("0*")}
    r = _run(_cmd(two, out, "--weights", "2", "1", n=9))
    assert r.returncode == 0, r.stderr
    assert f"note: {out}: n 6 -> 9: the same plan grown, images 6..8 are added" in r.stderr
    t = json.loads((out / "timings.json").read_text())
    assert t["rendered"] == 3 and t["skipped_done"] == 6 and t["stale_images"] == 0
    assert all((out / k).read_bytes() == v for k, v in before.items())
    assert [r["asset_id"] for r in read_index(out / "index.jsonl")] == mix.assign(9, [2, 1], seed=0).tolist()
    assert (out / "splits" / "splits.json").is_file()
    r = _run(_cmd(two, out, "--weights", "2", "1", n=4))
    assert r.returncode == 0 and "n 9 -> 4: the same plan shrunk, images 4..8 go" in r.stderr, r.stderr
    assert json.loads((out / "timings.json").read_text())["rendered"] == 0
    assert sorted({p.name[:6] for p in out.glob("0*")}) == [f"{i:06d}" for i in range(4)]
    assert all((out / k).read_bytes() == v for k, v in before.items() if int(k[:6]) < 4)
