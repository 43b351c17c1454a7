"""A dataset folder is never lost: another plan is refused naming what differs, ``--overwrite``
says how many files go, ``--resume`` continues only the same plan, and no run deletes a file a
render does not write (pipeline/render/plan.py, the folder checks of pipeline/render/run.py).

The datasets here are made without Blender: the plan's ``config.json`` as a run writes it, and
stand-in image files (the runs that render: test_dataset.py).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fixtures import make_two_assets
from pipeline.errors import ScanError
from pipeline.render import dataset as ds
from pipeline.render import mix
from pipeline.render import plan as pl
from pipeline.render import run as rr
from pipeline.render.settings import RenderSettings

ROOT = Path(__file__).resolve().parents[1]
TINY = {"width": 24, "height": 16, "frame_margin_px": None, "samples": 1, "denoise": False, "workers": 1, "shard_size": 2}
IMAGE_FILES = (".png", ".json", "_seg.png", "_depth.exr")


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    return make_two_assets(tmp_path_factory.mktemp("plan"), TINY)


def _plan(two, n, weights=None, **settings):
    st = RenderSettings.from_params({**TINY, **settings, "n_images": n})
    pairs, _ = ds.asset_inputs(two["assets"])
    assets = ds.load_assets(pairs, weights, st)
    return assets, mix.assign(n, [a.weight for a in assets], st.seed), st


def _dataset(two, out, n=8, weights=None) -> dict:
    """A finished dataset of ``n`` images as a run leaves it (stand-in image bytes), plus a file
    of the user's; returns every file's bytes."""
    assets, assign, st = _plan(two, n, weights)
    ds.prepare_dataset(out, assets, assign, st)
    for i in range(n):
        for end in IMAGE_FILES:
            (out / f"{i:06d}{end}").write_bytes(f"image {i}{end}".encode())
    for name in ("index.jsonl", "contact_sheet.png", *pl.OWN_FILES):
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_text(name)
    (out / "notes.txt").write_text("the user's own")
    return _snapshot(out)


def _snapshot(out: Path) -> dict:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def _cmd(two, out, *extra, n=8):
    return [sys.executable, "-m", "stages.dataset", "--assets", *map(str, two["assets"]),
            "--n", str(n), "--out", str(out), "--params", str(two["params"]), "--no-progress", *extra]


def _run(cmd):
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_another_plan_is_refused_naming_what_differs_and_nothing_is_touched(two, tmp_path):
    out = tmp_path / "ds"
    before = _dataset(two, out)
    cases = [
        (("--weights", "2", "1"), 8, "weights [1.0, 1.0] -> [2.0, 1.0]"),
        (("--seed", "7"), 8, "seed 0 -> 7"),
        (("--set", "samples=2", "width=32"), 8, "settings samples 1 -> 2, width 24 -> 32"),
        (("--weights", "2", "1", "--resume"), 8, "weights [1.0, 1.0] -> [2.0, 1.0]): --resume continues only the same plan"),
    ]
    for extra, n, what in cases:
        r = _run(_cmd(two, out, *extra, n=n))
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert r.stderr.startswith(f"error: {out}: holds a dataset of another plan (") and what in r.stderr, r.stderr
        if "--resume" not in extra:
            assert "--overwrite replaces it (" in r.stderr and "files go" in r.stderr
        assert _snapshot(out) == before
    # one asset fewer
    r = _run([sys.executable, "-m", "stages.dataset", "--assets", str(two["assets"][0]), "--n", "8",
              "--out", str(out), "--params", str(two["params"]), "--no-progress"])
    assert r.returncode == 2 and "(assets alpha, beta -> alpha)" in r.stderr and _snapshot(out) == before


def test_overwrite_lists_only_the_renders_files_and_keeps_what_the_new_plan_shares(two, tmp_path):
    out = tmp_path / "ds"
    _dataset(two, out, n=8)
    assets, assign, st = _plan(two, 6, weights=[2, 1])
    fp = pl.inspect_dataset(out, assets, assign, st)
    old = mix.assign(8, [1, 1], 0)
    shared = [i for i in range(6) if old[i] == assign[i]]
    assert fp.state == "other" and fp.differences == ["weights [1.0, 1.0] -> [2.0, 1.0]"]
    assert sorted(p.relative_to(out).as_posix() for p in fp.remove) == sorted(
        [f"{i:06d}{e}" for i in range(8) if i not in shared for e in IMAGE_FILES]
        + ["index.jsonl", "contact_sheet.png", *pl.OWN_FILES])
    assert fp.stale_images == 6 - len(shared) and "notes.txt" not in {p.name for p in fp.remove}
    with pytest.raises(ScanError, match="holds a dataset of another plan"):
        ds.prepare_dataset(out, assets, assign, st)
    prep = ds.prepare_dataset(out, assets, assign, st, overwrite=True)
    assert prep["removed_files"] == len(fp.remove)
    left = sorted(p.name for p in out.iterdir())
    assert left == sorted([f"{i:06d}{e}" for i in shared for e in IMAGE_FILES] + [".tmp", "config.json", "notes.txt",
                                                                               "card", "splits"])
    # the same plan again: nothing to refuse, only unfinished images go (and the end-of-run files)
    (out / "000005.png").write_bytes(b"half")                # no label: unfinished
    again = pl.inspect_dataset(out, assets, assign, st)
    assert again.state == "same" and [p.name for p in again.remove] == (["000005.png"] if 5 not in shared else [])


def test_another_n_is_the_same_plan_grown_or_shrunk(two, tmp_path):
    """Image i does not depend on n: a larger n adds images and keeps every file, a smaller one
    removes only the tail (no --overwrite either way)."""
    out = tmp_path / "ds"
    before = _dataset(two, out, n=8)
    assets, assign, st = _plan(two, 12)
    fp = pl.inspect_dataset(out, assets, assign, st)
    assert fp.state == "same" and fp.differences == [] and fp.stale_images == 0 and fp.old_n == 8
    assert sorted(p.relative_to(out).as_posix() for p in fp.remove) == sorted(["index.jsonl", "contact_sheet.png", *pl.OWN_FILES])
    assert pl.refusal(out, fp) is None and pl.resize_note(out, fp, 12).endswith("images 8..11 are added")
    assets, assign, st = _plan(two, 5)
    fp = pl.inspect_dataset(out, assets, assign, st)
    assert fp.state == "same" and pl.refusal(out, fp) is None
    assert sorted(p.relative_to(out).as_posix() for p in fp.remove) == sorted(
        [f"{i:06d}{e}" for i in range(5, 8) for e in IMAGE_FILES] + ["index.jsonl", "contact_sheet.png", *pl.OWN_FILES])
    assert pl.resize_note(out, fp, 5).endswith(f"images 5..7 go ({3 * len(IMAGE_FILES)} files)")
    notes = pl.run_notes(out, fp, 5, overwrite=True)      # the resize first, then what --overwrite removes
    assert len(notes) == 2 and notes[0] == pl.resize_note(out, fp, 5)
    assert notes[1] == f"note: --overwrite: {len(fp.remove)} files of the earlier dataset in {out} go (the same plan)"
    assert pl.run_notes(out, fp, 8) == []                 # the same length, no --overwrite: nothing to say
    assert pl.run_notes(tmp_path / "new", pl.inspect_dataset(tmp_path / "new", assets, assign, st), 5,
                        overwrite=True) == [f"note: --overwrite: no earlier dataset in {tmp_path / 'new'}, nothing goes"]
    ds.prepare_dataset(out, assets, assign, st)
    kept = _snapshot(out)
    assert all(kept[k] == before[k] for k in before if k[:6].isdigit() and int(k[:6]) < 5)


def test_a_plan_of_the_earlier_mix_is_another_plan(two, tmp_path):
    """A folder planned with the n-dependent mix (no ``mix`` in its config) is read with that
    mix, and a run of today's mix needs --overwrite (its images keep only where the assets agree)."""
    out = tmp_path / "ds"
    _dataset(two, out, n=8)
    cfg = json.loads((out / "config.json").read_text())
    del cfg["dataset"]["mix"]
    (out / "config.json").write_text(json.dumps(cfg))
    assets, assign, st = _plan(two, 8)
    fp = pl.inspect_dataset(out, assets, assign, st)
    assert fp.state == "other" and fp.differences == ["mix largest remainder, n-dependent -> quota"]
    legacy = mix.assign_legacy(8, [1, 1], 0)
    assert fp.stale_images == int(np.count_nonzero(legacy != assign))


def test_resume_needs_a_dataset_and_overwrite_needs_one_too(two, tmp_path):
    new = tmp_path / "new"
    r = _run(_cmd(two, new, "--resume"))
    assert r.returncode == 2 and r.stderr == f"error: {new}: --resume: holds no dataset to resume (leave out " \
                                             "--resume to start one)\n" and not new.exists()
    r = _run(_cmd(two, new, "--resume", "--overwrite"))
    assert r.returncode == 2 and "--overwrite: not allowed with argument --resume" in r.stderr and not new.exists()
    mine = tmp_path / "mine"                                  # someone's folder: --overwrite or not
    mine.mkdir()
    (mine / "000000.png").write_bytes(b"not a render")
    (mine / ".tmp").mkdir()
    (mine / ".tmp" / "x").write_text("scratch of theirs")
    for extra in ((), ("--overwrite",)):
        r = _run(_cmd(two, mine, *extra))
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is not a dataset folder" in r.stderr, r.stderr
        assert _snapshot(mine) == {"000000.png": b"not a render", ".tmp/x": b"scratch of theirs"}


def test_folder_states_keep_renders_and_datasets_apart(two, tmp_path):
    hidden = tmp_path / "hidden"
    hidden.mkdir()
    (hidden / ".DS_Store").write_bytes(b"")
    assert rr.folder_state(tmp_path / "absent") == "new" and rr.folder_state(hidden) == "new"
    (hidden / ".tmp").mkdir()
    assert rr.folder_state(hidden) == "other"                 # a render would empty a .tmp
    (tmp_path / "file").write_text("x")
    assert rr.folder_state(tmp_path / "file") == "file"
    render = tmp_path / "render"
    render.mkdir()
    (render / "config.json").write_text(json.dumps({"config_hash": "a", "scan": "alpha"}))
    dataset = tmp_path / "dataset"
    _dataset(two, dataset, n=2)
    assert rr.folder_state(render) == "render" and rr.folder_state(dataset) == "dataset"
    with pytest.raises(ScanError, match="holds a scan's renders"):
        pl.check_out(render)
    with pytest.raises(ScanError, match="holds a dataset of python -m stages.dataset"):
        rr.check_render_out(dataset)
    with pytest.raises(ScanError, match="holds no renders"):
        rr.check_render_out(hidden)


def test_render_stage_refuses_someone_elses_folder(two, tmp_path, capsys):
    from stages import render as render_stage
    from stages._common import run_stage

    mine = tmp_path / "Pictures"
    mine.mkdir()
    (mine / "000000.png").write_bytes(b"a holiday")
    (mine / "index.jsonl").write_text("mine")
    rig = two["root"] / "build" / "alpha" / "rig"
    assert run_stage(render_stage.main, [str(two["assets"][0]), str(rig), str(mine), "--params",
                                         str(two["params"]), "--metrics", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err == f"error: {mine}: exists, is not empty and holds no renders (no render config.json): use a new " \
                  "or empty folder (nothing was changed)\n"
    assert _snapshot(mine) == {"000000.png": b"a holiday", "index.jsonl": b"mine"}
