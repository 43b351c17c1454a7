"""Label format ``webdataset`` (pipeline/render/formats/webdataset.py): tar shards read back with
``tarfile`` and grouped by webdataset's key rule equal the loose files, byte-identical whatever
order the images finished in, with fixed member headers.

Folders come from fixtures.fake_renders (real labels of the tiny asset, drawn masks, no Blender).
"""

from __future__ import annotations

import tarfile

import pytest

from fixtures.fake_renders import fake_render
from pipeline.errors import ScanError
from pipeline.render.formats import webdataset as wds

N, K = 7, 3


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    return fake_render(tmp_path_factory.mktemp("shards"), N, tar_images=K)


def _samples(tar_path) -> dict:
    """webdataset's grouping: key = member name before its first dot, field = the rest."""
    out: dict = {}
    with tarfile.open(tar_path) as tar:
        for m in tar.getmembers():
            key, _, field = m.name.partition(".")
            assert m.isfile() and m.mtime == 0 and m.uid == m.gid == 0 and m.uname == m.gname == ""
            assert m.mode == 0o644
            out.setdefault(key, {})[field] = tar.extractfile(m).read()
    return out


def test_shards_hold_the_loose_files(made):
    out = made["out"]
    tars = sorted((out / wds.SHARD_DIR).iterdir())
    assert [p.name for p in tars] == ["shard-000000.tar", "shard-000001.tar", "shard-000002.tar"]
    seen = []
    for s, p in enumerate(tars):
        samples = _samples(p)
        assert list(samples) == [f"{i:06d}" for i in range(s * K, min(N, s * K + K))]
        with tarfile.open(p) as tar:                       # a sample's files are adjacent, in name order
            names = tar.getnames()
        assert names == sorted(names)
        for key, fields in samples.items():
            i = int(key)
            assert fields == {"png": (out / f"{i:06d}.png").read_bytes(),
                              "json": (out / f"{i:06d}.json").read_bytes(),
                              "seg.png": (out / f"{i:06d}_seg.png").read_bytes(),
                              "depth.exr": (out / f"{i:06d}_depth.exr").read_bytes()}
            seen.append(i)
    assert seen == list(range(N))


def test_shards_are_the_same_bytes_whatever_order_images_finished(made, tmp_path):
    other = fake_render(tmp_path, N, order=[6, 3, 0, 5, 1, 4, 2], tiny=made, tar_images=K)
    for s in range(3):
        name = wds.shard_name(s)
        assert (other["out"] / name).read_bytes() == (made["out"] / name).read_bytes()


def test_shard_ranges():
    assert wds.shard_ranges(7, 3) == [range(0, 3), range(3, 6), range(6, 7)]
    assert wds.shard_ranges(6, 3) == [range(0, 3), range(3, 6)] and wds.shard_ranges(0, 3) == []


def test_an_unfinished_image_is_one_line_naming_its_file(made, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(made["out"], out)
    (out / "000004.png").unlink()
    with pytest.raises(ScanError, match=r"000004\.png: missing: the image is not finished"):
        wds.finish(out, N, made["settings"])
