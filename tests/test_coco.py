"""Label format ``coco`` (pipeline/render/formats/coco.py, pipeline/io/coco_file.py): RLE as
pycocotools writes it, and ``coco.json`` read back with pycocotools' ``COCO`` (or, where
pycocotools is not installed, with our transcription of its RLE decoder) equal to the labels and
masks it was made from, byte-identical whatever order the images finished in.

Folders come from fixtures.fake_renders (real labels of the tiny asset, drawn masks, no Blender).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fixtures.fake_renders import fake_render
from pipeline.errors import ScanError
from pipeline.io import coco_file as cf
from pipeline.io.labels_file import read_label
from pipeline.io.seg_file import CLASSES, read_seg
from pipeline.render.formats import coco

try:
    from pycocotools import mask as cmask
    from pycocotools.coco import COCO
except ImportError:                      # the dev extra pins it; without it our transcription decodes
    cmask = COCO = None

N = 6


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    return fake_render(tmp_path_factory.mktemp("coco"), N)


# ------------------------------------------------------------------------------------- RLE

def test_rle_known_answer():
    # column-major: column 0 = (0, 1), column 1 = (1, 1) -> runs 1 zero, 3 ones
    m = np.array([[0, 1], [1, 1]], np.uint8)
    assert cf.rle_counts(m) == [1, 3]
    assert cf.rle_counts(np.ones((2, 2))) == [0, 4]
    assert cf.rle_decode({"size": [2, 2], "counts": [1, 3]}).tolist() == m.tolist()
    assert cf.mask_bbox(m) == [0.0, 0.0, 2.0, 2.0] and cf.mask_bbox(np.zeros((3, 3))) == [0.0] * 4


@pytest.mark.skipif(cmask is None, reason="pycocotools not installed (dev extra)")
def test_rle_is_pycocotools_byte_for_byte():
    rng = np.random.default_rng(0)
    for t in range(200):
        h, w = rng.integers(1, 50, 2)
        m = (rng.random((h, w)) < rng.random()).astype(np.uint8)
        if t % 9 == 0:
            m[:] = t % 2                                # empty and full masks
        ref = cmask.encode(np.asfortranarray(m))
        ours = cf.rle_encode(m)
        assert ours["counts"] == ref["counts"].decode() and ours["size"] == list(ref["size"])
        assert cf.rle_decode(ours).tolist() == m.tolist()
        assert cf.mask_bbox(m) == cmask.toBbox(ref).tolist() and int(cmask.area(ref)) == int(m.sum())


def test_rle_decode_refuses_counts_of_another_size():
    with pytest.raises(ValueError, match="cover 3 pixels, size 2 x 2 has 4"):
        cf.rle_decode({"size": [2, 2], "counts": [1, 2]})


# ------------------------------------------------------------------------------- coco.json

def test_coco_json_read_back_equals_labels_and_masks(made):
    out = made["out"]
    path = out / coco.COCO_FILE
    doc = json.loads(path.read_text())
    if COCO is not None:
        api = COCO(str(path))
        anns_of = {i: api.loadAnns(api.getAnnIds(imgIds=[i])) for i in range(N)}
        assert sorted(api.getImgIds()) == list(range(N))
        assert api.loadCats([coco.EYE_ID])[0]["keypoints"] == coco.KEYPOINT_NAMES
        mask_of = api.annToMask                                   # pycocotools' own decoding
    else:
        anns_of = {i: [a for a in doc["annotations"] if a["image_id"] == i] for i in range(N)}
        mask_of = lambda a: cf.rle_decode(a["segmentation"])  # noqa: E731
    assert [a["id"] for a in doc["annotations"]] == list(range(1, len(doc["annotations"]) + 1))
    cats = {c["id"]: c["name"] for c in doc["categories"]}
    assert cats == {**{i: name for i, (name, _) in CLASSES.items() if i}, 7: "eye"}
    n_hidden = 0
    for i in range(N):
        label = read_label(out / f"{i:06d}.json").doc
        seg = read_seg(out / f"{i:06d}_seg.png")
        anns = anns_of[i]
        eye = [a for a in anns if a["category_id"] == coco.EYE_ID]
        assert len(eye) == 1
        kp = np.asarray(eye[0]["keypoints"], float).reshape(28, 3)
        lm = label["landmarks"]
        px = np.asarray(lm["px"], float)
        for k in range(28):
            if lm["occlusion"][k] == "outside":
                assert kp[k].tolist() == [0, 0, 0]
            else:
                assert kp[k, 2] == (2 if lm["visible"][k] else 1)
                assert np.array_equal(kp[k, :2], px[k] - 0.5)          # COCO: pixel indices
                n_hidden += kp[k, 2] == 1
        assert eye[0]["num_keypoints"] == int((kp[:, 2] > 0).sum())
        eye_mask = mask_of(eye[0])
        assert np.array_equal(eye_mask, np.isin(seg, coco.EYE_CLASSES)) and eye[0]["area"] == eye_mask.sum()
        x, y, w, h = eye[0]["bbox"]
        mx, my, mw, mh = cf.mask_bbox(eye_mask)
        assert x <= mx and y <= my and mx + mw <= x + w + 1e-9 and my + mh <= y + h + 1e-9
        np.testing.assert_allclose(eye[0]["gaze_camera"], label["gaze"]["vector_camera"])
        geo = label["eyes"][label["gaze"]["eye"]]                      # the imaged eye's centre, radius, iris plane
        np.testing.assert_allclose(eye[0]["gaze_origin"], np.asarray(geo["center_px"]) - 0.5)
        np.testing.assert_allclose(eye[0]["gaze_origin_camera_mm"], geo["center_camera_mm"])
        assert eye[0]["eyeball_radius_mm"] == geo["radius_mm"]
        assert eye[0]["center_to_iris_plane_mm"] == geo["center_to_iris_plane_mm"]
        # the class annotations rebuild the mask exactly
        rebuilt = np.zeros_like(seg)
        for a in anns:
            if a["category_id"] != coco.EYE_ID:
                m = mask_of(a).astype(bool)
                assert not rebuilt[m].any() and a["area"] == m.sum() > 0
                assert a["bbox"] == cf.mask_bbox(m)
                rebuilt[m] = a["category_id"]
        assert np.array_equal(rebuilt, seg)
    assert n_hidden > 0                       # the lids hide some iris landmarks: v = 1 is exercised


def test_coco_json_is_the_same_bytes_whatever_order_images_finished(made, tmp_path):
    other = fake_render(tmp_path, N, order=[5, 2, 0, 4, 1, 3], tiny=made)
    assert (other["out"] / coco.COCO_FILE).read_bytes() == (made["out"] / coco.COCO_FILE).read_bytes()


def test_missing_fragment_is_one_line_naming_it(made, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(made["out"] / coco.COCO_DIR, out / coco.COCO_DIR)
    (out / coco.COCO_DIR / "000003.json").unlink()
    with pytest.raises(ScanError, match=r"000003\.json: missing: the image has no COCO fragment") as e:
        coco.finish(out, N, made["settings"])
    assert "\n" not in str(e.value)
    (out / coco.COCO_DIR / "000003.json").write_text("[1]")
    with pytest.raises(ScanError, match=r"000003\.json: is not a COCO fragment"):
        coco.finish(out, N, made["settings"])


def test_a_closed_or_offscreen_eye_still_gives_a_valid_annotation(made):
    label = read_label(made["out"] / "000000.json").doc
    label["landmarks"] = dict(label["landmarks"], occlusion=["outside"] * 28, visible=[False] * 28)
    h, w = label["image"]["height"], label["image"]["width"]
    fr = coco.fragment(0, label, np.ones((h, w), np.uint8))      # all skin: no eye pixels
    eye = fr["annotations"][0]
    assert eye["keypoints"] == [0.0, 0.0, 0] * 28 and eye["num_keypoints"] == 0
    assert eye["area"] == 0 and eye["bbox"] == [0.0, 0.0, 0.0, 0.0]
    assert [a["category_id"] for a in fr["annotations"]] == [coco.EYE_ID, 1]
