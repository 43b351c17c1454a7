"""dvc.yaml: every stage's ``deps`` cover its whole import closure, so no output goes stale.

The closure of a stage is :func:`pipeline.sources.stage_closure` (the one definition the render
fingerprint uses too): ``stages/<stage>.py`` and, transitively, every ``pipeline.*`` / ``stages.*``
module it imports or names. Regenerate the code deps of dvc.yaml after changing imports:

    .venv/bin/python tests/test_dvc_deps.py          # rewrites the pipeline/ and stages/ deps
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


def compact(paths: set[str]) -> list[str]:
    """``paths`` with each package folder whose every ``.py`` file is listed written as the folder."""
    paths = set(paths)
    for pkg in sorted({str(Path(p).parent) for p in paths}, key=lambda d: -d.count("/")):
        if pkg in (".", "pipeline", "stages") or not (ROOT / pkg / "__init__.py").is_file():
            continue
        files = {f.relative_to(ROOT).as_posix() for f in (ROOT / pkg).rglob("*.py")}
        if files and files <= paths:
            paths = (paths - files) | {pkg}
    return sorted(paths)


def stage_deps() -> dict[str, list[str]]:
    """stage name -> its deps in dvc.yaml (``${item}`` left as is)."""
    doc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    out = {}
    for name, st in doc["stages"].items():
        body = st.get("do", st)
        out[name] = [d if isinstance(d, str) else next(iter(d)) for d in body.get("deps", [])]
    return out


def covered(path: str, deps: list[str]) -> bool:
    return any(path == d or path.startswith(d.rstrip("/") + "/") for d in deps)


def test_every_stage_lists_its_import_closure():
    missing = {}
    for stage, deps in stage_deps().items():
        need = import_closure(stage)
        lack = sorted(p for p in need if not covered(p, deps))
        if lack:
            missing[stage] = lack
    assert not missing, ("dvc.yaml deps miss modules the stages import (regenerate: "
                         f".venv/bin/python tests/test_dvc_deps.py): {missing}")


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
    assert covered("pipeline/usd/stage.py", ["pipeline/usd"]) and not covered("pipeline/usdx.py", ["pipeline/usd"])
    assert "pipeline/rig" in compact({f"pipeline/rig/{f.name}" for f in (ROOT / "pipeline/rig").glob("*.py")})


def test_render_fingerprint_hashes_the_render_closure():
    """A render folder's config hash covers exactly the source the render stage runs: a file it
    hashes but DVC does not track (or the reverse) keeps stale images or makes dvc.lock depend
    on history."""
    from pipeline.render.asset import renderer_sources

    hashed = {p.relative_to(ROOT).as_posix() for p in renderer_sources(ROOT)}
    assert hashed == import_closure("render")
    deps = stage_deps()["render"]
    assert all(covered(p, deps) for p in hashed)
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
    """Is the dvc.yaml dep ``dep`` code (a module or a package folder under pipeline/ or stages/),
    which :func:`write_dvc_yaml` regenerates, rather than data it keeps (the eye-region prior)?"""
    return dep.startswith(CODE) and (dep.endswith(".py") or (ROOT / dep / "__init__.py").is_file()
                                     or not (ROOT / dep).exists())


def write_dvc_yaml() -> list[str]:
    """Rewrite the pipeline/ and stages/ deps of every stage in dvc.yaml as its exact closure
    (data deps and everything else untouched); returns the stages whose deps changed."""
    lines = (ROOT / "dvc.yaml").read_text().splitlines(keepends=True)
    stage_re = re.compile(r"^  ([A-Za-z_][A-Za-z0-9_]*):\s*$")
    out, changed, stage, i = [], [], None, 0
    while i < len(lines):
        line = lines[i]
        m = stage_re.match(line)
        if m:
            stage = m.group(1)
        if stage and re.match(r"^\s+deps:\s*$", line):
            indent = len(line) - len(line.lstrip()) + 2
            out.append(line)
            i += 1
            items = []
            while i < len(lines) and re.match(rf"^ {{{indent}}}- ", lines[i]):
                items.append(lines[i])
                i += 1
            data = [x for x in items if not _is_code(x.strip()[2:].split()[0])]
            code = compact(import_closure(stage))
            new = data + [f"{' ' * indent}- {p}\n" for p in code]
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
