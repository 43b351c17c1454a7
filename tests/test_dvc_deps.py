"""dvc.yaml: every stage's code dep is the fingerprint of its whole import closure, so no output
goes stale.

The closure of a stage is :func:`pipeline.sources.stage_closure` (the one definition the render
fingerprint uses too): ``stages/<stage>.py`` and, transitively, every ``pipeline.*`` / ``stages.*``
module it imports or names. The ``code`` stage (``stages/code.py``) writes its hash to
``build/code/<stage>.sha256``, the stage's one code dep. Regenerate dvc.yaml's code deps and the
``code`` stage after adding a stage:

    .venv/bin/python tests/test_dvc_deps.py
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
if __name__ == "__main__":              # run as a script: this checkout's pipeline/, not an installed one
    sys.path.insert(0, str(ROOT))

from pipeline import sources  # noqa: E402
from pipeline.sources import CODE  # noqa: E402


def import_closure(stage: str) -> set[str]:
    """Repository-relative paths of every project file stage ``stage`` runs."""
    return sources.stage_closure(stage, ROOT)


def stage_deps() -> dict[str, list[str]]:
    """stage name -> its deps in dvc.yaml (``${item}`` left as is)."""
    doc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    out = {}
    for name, st in doc["stages"].items():
        body = st.get("do", st)
        out[name] = [d if isinstance(d, str) else next(iter(d)) for d in body.get("deps", [])]
    return out


def test_every_stage_depends_on_its_fingerprint_and_the_code_stage_writes_them():
    """Each stage's one code dep is build/code/<stage>.sha256 (no module listed one by one), the
    ``code`` stage writes exactly those files, untracked by the cache, from the pipeline/ and
    stages/ folders, and dvc.yaml is what the generator writes (regenerate: ``.venv/bin/python
    tests/test_dvc_deps.py``)."""
    doc = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    code = doc.pop("code")
    assert code["deps"] == list(CODE)
    outs = [next(iter(o)) for o in code["outs"]]
    assert outs == [fingerprint(s) for s in doc]
    assert all(o[next(iter(o))] == {"cache": False} for o in code["outs"])
    assert code["cmd"] == f"python -m stages.code '{FINGERPRINTS}' " + " ".join(doc)
    for stage, deps in stage_deps().items():
        if stage == "code":
            continue
        assert (ROOT / "stages" / f"{stage}.py").is_file(), stage
        assert deps[0] == fingerprint(stage), stage
        assert not [d for d in deps[1:] if _is_code(d)], (stage, deps)
    text = (ROOT / "dvc.yaml").read_text()
    try:
        assert write_dvc_yaml() == []
        assert (ROOT / "dvc.yaml").read_text() == text
    finally:
        (ROOT / "dvc.yaml").write_text(text)


def test_a_stage_fingerprint_changes_with_its_closure_and_only_with_it(tmp_path):
    """Editing any file of a stage's closure (in a copy of the code) changes that stage's
    fingerprint line; editing a module outside it does not, and neither does the copy's place."""
    copy = _copy_code(tmp_path / "code")
    before = sources.closure_digest("snap", copy)
    assert before == sources.closure_digest("snap", ROOT)
    assert before.endswith(f" {len(import_closure('snap'))} files\n")
    closure = sorted(import_closure("snap"))
    assert "pipeline/snap/snap.py" in closure and "stages/_common.py" in closure
    for rel in closure[::7] + ["pipeline/snap/snap.py", "stages/render.py", "pipeline/render/dataset.py"]:
        f = copy / rel
        text = f.read_bytes()
        f.write_bytes(text + b"\n# edited\n")
        try:
            changed = sources.closure_digest("snap", copy) != before
        finally:
            f.write_bytes(text)
        assert changed == (rel in closure), rel
    assert sources.closure_digest("snap", copy) == before


def test_code_stage_writes_one_line_per_stage_and_refuses_an_unknown_one(tmp_path):
    import subprocess
    import sys

    out = tmp_path / "code"
    r = subprocess.run([sys.executable, "-m", "stages.code", str(out), "snap", "rig"], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["rig.sha256", "snap.sha256"]
    assert (out / "snap.sha256").read_text() == sources.closure_digest("snap")
    r = subprocess.run([sys.executable, "-m", "stages.code", str(out), "snap", "../etc"], cwd=ROOT,
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "stages/../etc.py" in r.stderr


def test_the_closure_follows_function_imports_strings_and_workers():
    render = import_closure("render")
    assert "pipeline/blender/render_worker.py" in render           # -m pipeline.blender.render_worker
    assert "pipeline/render/settings.py" in render                 # imported inside main()
    assert "stages/_common.py" in render and "pipeline/__init__.py" in render
    usd = import_closure("usd")
    assert "pipeline/usd/validate.py" in usd
    assert not [p for p in usd | import_closure("eyeball") if p.startswith("pipeline/blender/")]   # no Blender
    preview = import_closure("preview")
    assert "pipeline/blender/asset_preview.py" in preview                  # launch.run(WORKER, ...)
    assert "pipeline/blender/render_worker.py" not in preview              # only the worker it names
    assert "pipeline/blender/eyeball_preview.py" in import_closure("eyeball_preview")
    assert "pipeline/settings.py" in import_closure("check_params")
    assert "pipeline/render/settings.py" in import_closure("check_params")   # "module:Class" strings


def test_render_fingerprint_hashes_the_render_closure():
    """A render folder's config hash covers exactly the source the render stage runs: a file it
    hashes but DVC does not track (or the reverse) keeps stale images or makes dvc.lock depend
    on history."""
    from pipeline.render.asset import renderer_sources

    hashed = {p.relative_to(ROOT).as_posix() for p in renderer_sources(ROOT)}
    assert hashed == import_closure("render")
    assert stage_deps()["render"][0] == fingerprint("render")     # DVC tracks the same files
    for module in ("pipeline/rig/lids.py", "pipeline/rig/landmarks.py", "pipeline/eyeball/geometry.py",
                   "pipeline/eyeball/textures.py", "pipeline/geometry/frame.py", "pipeline/io/rig_file.py",
                   "pipeline/settings.py", "stages/render.py"):
        assert module in hashed


def _copy_code(dst: Path) -> Path:
    for top in CODE:
        for f in (ROOT / top).rglob("*.py"):
            out = dst / f.relative_to(ROOT)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(f.read_bytes())
    return dst


def test_editing_any_module_the_render_stage_runs_changes_the_render_fingerprint(tmp_path, monkeypatch):
    """Each file of the render closure, edited in a copy of the code, changes the asset fingerprint
    (and so the config hash a resumed render compares); a module outside it does not."""
    import numpy as np

    from pipeline.render import asset as ra
    from pipeline.render import run
    from pipeline.render.settings import RenderSettings

    copy = _copy_code(tmp_path / "code")
    monkeypatch.setattr(sources, "ROOT", copy)
    usda = tmp_path / "a.usda"
    usda.write_text("#usda 1.0\n")
    rig = tmp_path / "rig.npz"
    rig.write_bytes(b"rig")
    asset = ra.RenderAsset(name="a", usda=usda, rig_npz=rig, skin_rest=np.zeros((0, 3)),
                           skin_faces_edge_mm=1.0, lid_shapes=[], rig_arrays={}, eyes={})
    closure = sorted(import_closure("render"))
    assert len(closure) > 40
    before = asset.fingerprint()
    for rel in closure + ["pipeline/render/dataset.py", "stages/dataset.py"]:
        f = copy / rel
        text = f.read_bytes()
        f.write_bytes(text + b"\n# edited\n")
        try:
            changed = asset.fingerprint() != before
        finally:
            f.write_bytes(text)
        assert changed == (rel in closure), rel
    assert asset.fingerprint() == before
    # the settings are the config hash's other half
    s0, s1 = RenderSettings.from_dict({}), RenderSettings.from_dict({"seed": 1})
    assert run.config_hash(s0, before) != run.config_hash(s1, before)


def _is_code(dep: str) -> bool:
    """Is the dvc.yaml dep ``dep`` code (a module or a package folder under pipeline/ or stages/,
    or a stage's fingerprint file), which :func:`write_dvc_yaml` regenerates, rather than data it
    keeps (the eye-region prior)?"""
    if dep.startswith(FINGERPRINTS + "/"):
        return True
    return dep.startswith(CODE) and (dep.endswith(".py") or (ROOT / dep / "__init__.py").is_file()
                                     or not (ROOT / dep).exists())


#: Where the ``code`` stage writes each stage's fingerprint (``stages/code.py``).
FINGERPRINTS = "build/code"


def fingerprint(stage: str) -> str:
    return f"{FINGERPRINTS}/{stage}.sha256"


def code_block(stages: list[str]) -> list[str]:
    """The ``code`` stage of dvc.yaml: one fingerprint file for each of ``stages``."""
    quoted = " ".join(stages)
    out = ["  code:\n",
           f"    cmd: python -m stages.code '{FINGERPRINTS}' {quoted}\n",
           "    deps:\n"] + [f"      - {top}\n" for top in CODE] + ["    outs:\n"]
    for st in stages:
        out += [f"      - {fingerprint(st)}:\n", "          cache: false\n"]
    return out


def write_dvc_yaml() -> list[str]:
    """Give every stage of dvc.yaml its fingerprint file as its one code dep (data deps and
    everything else untouched) and write the ``code`` stage that makes them (after the header
    comment, before the first other stage); returns the stages whose deps changed."""
    lines = (ROOT / "dvc.yaml").read_text().splitlines(keepends=True)
    stage_re = re.compile(r"^  ([A-Za-z_][A-Za-z0-9_]*):\s*$")
    # drop the code stage (its comment lines above it stay) and find the other stages
    kept, i = [], 0
    while i < len(lines):
        if lines[i] == "  code:\n":
            i += 1
            while i < len(lines) and (lines[i].startswith("    ") or lines[i].strip() == ""):
                i += 1
            continue
        kept.append(lines[i])
        i += 1
    lines = kept
    names = [m.group(1) for m in map(stage_re.match, lines) if m]
    out, changed, stage, i, placed = [], [], None, 0, False
    while i < len(lines):
        line = lines[i]
        m = stage_re.match(line)
        if m:
            stage = m.group(1)
            if not placed:
                # the code stage goes before the first stage, after that stage's comment lines
                j = len(out)
                while j > 0 and out[j - 1].startswith("  #"):
                    j -= 1
                out[j:j] = code_block(names)
                placed = True
        if stage and re.match(r"^\s+deps:\s*$", line):
            indent = len(line) - len(line.lstrip()) + 2
            out.append(line)
            i += 1
            items = []
            while i < len(lines) and re.match(rf"^ {{{indent}}}- ", lines[i]):
                items.append(lines[i])
                i += 1
            data = [x for x in items if not _is_code(x.strip()[2:].split()[0].rstrip(":"))]
            new = [f"{' ' * indent}- {fingerprint(stage)}\n"] + data
            if new != items:
                changed.append(stage)
            out += new
            continue
        out.append(line)
        i += 1
    (ROOT / "dvc.yaml").write_text("".join(out))
    return changed



if __name__ == "__main__":
    print("regenerated deps of:", ", ".join(write_dvc_yaml()) or "none", file=sys.stderr)
