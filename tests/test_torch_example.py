"""examples/torch_dataset.py: the lazy Dataset reads a 20-image folder without eyerig and without
torch (where torch is installed too), item for item equal to the labels, masks and depth maps.

The fast test reads fixtures.fake_renders' folder (real labels of the tiny asset, drawn masks, no
Blender); the Blender test renders a real 20-image dataset of the tiny asset with every new
format and reads it back through coco.json (pycocotools), the shards and the example.
"""

from __future__ import annotations

import importlib.util
import io
import json
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from fixtures.fake_renders import fake_render
from pipeline.io.labels_file import read_label
from pipeline.io.seg_file import read_depth, read_seg

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "torch_dataset.py"
N = 20
KEYS = {"index", "eye", "asset", "image", "landmarks", "visibility", "gaze", "gaze_pitch_yaw", "head_rotation",
        "head_pitch_yaw", "mask", "depth"}

# runs the example with pipeline, stages and torch unimportable; saves every item's arrays
BLOCKED = """
import json, runpy, sys
import numpy as np
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('pipeline', 'stages', 'conftest', 'fixtures', 'torch'):
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
ns = runpy.run_path(sys.argv[1])
ds = ns['EyeDataset'](sys.argv[2])
assert ns['_Base'] is object
arrays, meta = {}, []
for k in range(len(ds)):
    item = ds[k]
    meta.append({key: v for key, v in item.items() if not isinstance(v, np.ndarray)} | {'keys': sorted(item)})
    arrays.update({f'{k}/{key}': v for key, v in item.items() if isinstance(v, np.ndarray)})
np.savez(sys.argv[3], **arrays)
print(json.dumps({'n': len(ds), 'has_depth': ds.has_depth, 'meta': meta}))
"""


def _read_blocked(folder: Path, tmp_path: Path) -> tuple[dict, np.lib.npyio.NpzFile]:
    r = subprocess.run([sys.executable, "-c", BLOCKED, str(EXAMPLE), str(folder), str(tmp_path / "items.npz")],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    return json.loads(r.stdout), np.load(tmp_path / "items.npz")


def _check_items(folder: Path, got: dict, arrays) -> None:
    assert got["n"] == N and got["has_depth"]
    for k in range(N):
        label = read_label(folder / f"{k:06d}.json").doc
        assert set(got["meta"][k]["keys"]) == KEYS and got["meta"][k]["index"] == k
        assert got["meta"][k]["eye"] == label["gaze"]["eye"]

        def a(key):
            return arrays[f"{k}/{key}"]
        from PIL import Image

        with Image.open(folder / f"{k:06d}.png") as im:
            assert np.array_equal(a("image"), np.asarray(im.convert("RGB")))
        assert a("image").shape == (label["image"]["height"], label["image"]["width"], 3)
        np.testing.assert_array_equal(a("landmarks"), np.asarray(label["landmarks"]["px"], np.float32))
        assert a("visibility").dtype == bool and a("visibility").tolist() == label["landmarks"]["visible"]
        np.testing.assert_array_equal(a("gaze"), np.asarray(label["gaze"]["vector_camera"], np.float32))
        g = label["gaze"]["camera"]
        assert np.allclose(a("gaze_pitch_yaw"), [g["pitch_deg"], g["yaw_deg"]])
        R = np.asarray(label["head_pose"]["rotation_head_to_camera"])
        np.testing.assert_allclose(a("head_rotation"), R, atol=1e-6)
        assert np.array_equal(a("mask"), read_seg(folder / f"{k:06d}_seg.png"))
        assert np.array_equal(a("depth"), read_depth(folder / f"{k:06d}_depth.exr"))
    assert any(not all(read_label(folder / f"{k:06d}.json").doc["landmarks"]["visible"]) for k in range(N))


def test_torch_example_reads_a_20_image_folder_without_eyerig_or_torch(tmp_path):
    made = fake_render(tmp_path / "made", N, formats=("eyerig",))
    got, arrays = _read_blocked(made["out"], tmp_path)
    _check_items(made["out"], got, arrays)


def test_torch_example_is_lazy_and_bounds_checked(tmp_path):
    made = fake_render(tmp_path / "made", 3, formats=("eyerig",))
    spec = importlib.util.spec_from_file_location("torch_dataset", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    ds = mod.EyeDataset(made["out"])
    (made["out"] / "000002.png").unlink()              # nothing read until asked for
    assert len(ds) == 3 and ds[-3]["index"] == 0
    with pytest.raises(IndexError, match="item 3 of 3"):
        ds[3]
    with pytest.raises(FileNotFoundError, match="index.jsonl: missing"):
        mod.EyeDataset(tmp_path)


def test_shard_seg_round_trip_keeps_the_class_ids(tmp_path):
    """The example's shard reader (and its webdataset decoder seg_ids) give the loose masks' class
    ids; the conversion every webdataset image decoder makes first ("l8": luminance, "pil" and
    "rgb8": RGB) gives palette colours instead: the trap the docs warn of."""
    from PIL import Image

    made = fake_render(tmp_path / "made", 5, formats=("eyerig", "webdataset"))
    spec = importlib.util.spec_from_file_location("torch_dataset", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    samples = list(mod.EyeShards(made["out"]))
    assert [s["key"] for s in samples] == [f"{i:06d}" for i in range(5)]
    for i, s in enumerate(samples):
        ids = read_seg(made["out"] / f"{i:06d}_seg.png")
        assert s["mask"].dtype == np.uint8 and np.array_equal(s["mask"], ids)
        assert s["label"]["index"] == i and s["image"].shape == (32, 48, 3)
    with tarfile.open(made["out"] / "shards" / "shard-000000.tar") as tar:
        data = tar.extractfile("000000.seg.png").read()
    ids = read_seg(made["out"] / "000000_seg.png")
    assert np.array_equal(mod.seg_ids("seg.png", data), ids) and mod.seg_ids("png", data) is None
    with Image.open(io.BytesIO(data)) as im:
        l8, rgb = np.asarray(im.convert("L")), np.asarray(im.convert("RGB"))
    assert len(np.unique(ids)) > 1 and not np.array_equal(l8, ids) and rgb.shape == ids.shape + (3,)


@pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="torch not installed")
def test_torch_example_batches_with_a_dataloader(tmp_path):
    from torch.utils.data import DataLoader

    made = fake_render(tmp_path / "made", 4, formats=("eyerig",))
    spec = importlib.util.spec_from_file_location("torch_dataset", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    batch = next(iter(DataLoader(mod.EyeDataset(made["out"]), batch_size=4)))
    assert tuple(batch["landmarks"].shape) == (4, 28, 2) and tuple(batch["mask"].shape) == (4, 32, 48)


@pytest.mark.blender
@pytest.mark.slow
def test_a_real_20_image_dataset_reads_back_through_coco_shards_and_the_example(tmp_path):
    """The dataset command on the tiny asset with coco and webdataset: every reader agrees with the
    loose files (pycocotools where installed)."""
    from fixtures import make_two_assets
    from pipeline.io import coco_file as cf

    two = make_two_assets(tmp_path, {"width": 48, "height": 32, "samples": 1, "denoise": False, "workers": 1,
                                     "shard_size": 10, "tar_images": 8, "progress": False,
                                     "connect_timeout_s": 5, "label_formats": ["eyerig", "coco", "webdataset"]})
    out = tmp_path / "ds"
    r = subprocess.run([sys.executable, "-m", "stages.dataset", "--assets", *map(str, two["assets"]),
                        "--n", str(N), "--out", str(out), "--params", str(two["params"]), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    got, arrays = _read_blocked(out, tmp_path)
    _check_items(out, got, arrays)
    doc = json.loads((out / "coco.json").read_text())
    try:
        from pycocotools.coco import COCO
        api = COCO(str(out / "coco.json"))

        def mask_of(a):
            return api.annToMask(a)
    except ImportError:
        def mask_of(a):
            return cf.rle_decode(a["segmentation"])
    for k in range(N):
        seg = read_seg(out / f"{k:06d}_seg.png")
        rebuilt = np.zeros_like(seg)
        label = read_label(out / f"{k:06d}.json").doc
        for a in (a for a in doc["annotations"] if a["image_id"] == k):
            if a["category_id"] == 7:
                v = np.asarray(a["keypoints"]).reshape(28, 3)[:, 2]
                assert [x == 2 for x in v] == label["landmarks"]["visible"]
            else:
                rebuilt[mask_of(a).astype(bool)] = a["category_id"]
        assert np.array_equal(rebuilt, seg)
    tars = sorted((out / "shards").iterdir())
    assert [p.name for p in tars] == ["shard-000000.tar", "shard-000001.tar", "shard-000002.tar"]
    members = [m for p in tars for m in tarfile.open(p).getmembers()]
    assert len(members) == 4 * N and [m.name.partition(".")[0] for m in members][::4] == [f"{k:06d}" for k in range(N)]
    # the eager loader carries visibility, head pose and depth too
    spec = importlib.util.spec_from_file_location("load_dataset", ROOT / "examples" / "load_dataset.py")
    loader = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(loader)
    data = loader.load_dataset(out)
    for k in range(N):
        assert np.array_equal(data["visibility"][k], arrays[f"{k}/visibility"])
        assert np.array_equal(data["head_rotation"][k], arrays[f"{k}/head_rotation"])
        assert np.array_equal(data["depth"][k], arrays[f"{k}/depth"])
    card = (out / "README.md").read_text()
    assert "coco.json" in card and "shards/shard-SSSSSS.tar" in card
    # a second run of the same plan (nothing to render) rebuilds the same bytes
    before = {p: p.read_bytes() for p in [out / "coco.json", *tars]}
    r = subprocess.run([sys.executable, "-m", "stages.dataset", "--assets", *map(str, two["assets"]),
                        "--n", str(N), "--out", str(out), "--params", str(two["params"]), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    assert {p: p.read_bytes() for p in before} == before
