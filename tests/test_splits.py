"""Splits by identity (pipeline/render/splits.py): disjoint, every image once, independent of the
order of --assets, the render seed and n; the proportions' counts."""

from __future__ import annotations

import json

import pytest

from pipeline.render import splits as sl
from pipeline.render.settings import RenderSettings
from pipeline.settings import SettingsError


def test_split_counts_give_each_split_an_identity_while_there_are_enough():
    assert sl.split_counts(1, [0.8, 0.1, 0.1]) == [1, 0, 0]
    assert sl.split_counts(3, [0.8, 0.1, 0.1]) == [1, 1, 1]
    assert sl.split_counts(5, [0.8, 0.1, 0.1]) == [3, 1, 1]
    assert sl.split_counts(23, [0.8, 0.1, 0.1]) == [19, 2, 2]            # 18.4, 2.3, 2.3
    assert sl.split_counts(4, [1, 0, 0]) == [4, 0, 0] and sl.split_counts(10, [2, 1, 1]) == [5, 3, 2]


def test_splits_are_disjoint_and_list_every_image_once(tmp_path):
    names = [f"ident_{k}" for k in range(7)]
    assign = [k % 7 for k in range(100)]
    doc = sl.write_splits(tmp_path, names, assign, (0.7, 0.15, 0.15), seed=0)
    seen = {}
    for s in sl.NAMES:
        for line in (tmp_path / "splits" / f"{s}.txt").read_text().splitlines():
            assert line not in seen
            seen[line] = s
    assert sorted(seen) == [f"{i:06d}.png" for i in range(100)]
    owner = {}
    for line, s in seen.items():
        a = names[assign[int(line[:6])]]
        assert owner.setdefault(a, s) == s                      # no identity in two splits
    assert json.loads((tmp_path / "splits" / "splits.json").read_text()) == json.loads(json.dumps(doc))
    assert sum(map(len, doc["assets"].values())) == 7 and doc["images"]["train"] + doc["images"]["val"] \
        + doc["images"]["test"] == 100


def test_an_assets_split_depends_on_the_names_and_split_seed_only():
    names = ["b", "a", "e", "c", "d"]
    one = sl.split_assets(names, (0.8, 0.1, 0.1), 0)
    assert one == sl.split_assets(sorted(names), (0.8, 0.1, 0.1), 0)
    assert any(sl.split_assets(names, (0.8, 0.1, 0.1), s) != one for s in range(1, 6))


def test_split_settings_are_checked_and_not_hashed():
    s = RenderSettings.from_params({"splits": [0.6, 0.2, 0.2], "split_seed": 3})
    assert "splits" not in s.hashed() and "split_seed" not in s.hashed()
    with pytest.raises(SettingsError, match="splits"):
        RenderSettings.from_params({"splits": [0, 0, 0]})
