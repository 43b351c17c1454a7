"""dvc.yaml: every stage's ``deps`` cover its whole import closure, so no output goes stale.

The closure of a stage starts at ``stages/<stage>.py`` and follows, transitively, every import
of a ``pipeline.*`` or ``stages.*`` module (top-level or inside functions, ``from`` imports of
submodules, the packages' ``__init__.py``) and every string naming one (``-m
pipeline.blender.render_worker`` for a Blender worker, ``"pipeline.x:Class"`` looked up with
importlib, ``pipeline/x.py`` paths). Regenerate the code deps of dvc.yaml after changing imports:

    .venv/bin/python tests/test_dvc_deps.py          # rewrites the pipeline/ and stages/ deps
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
CODE = ("pipeline", "stages")
_NAME = re.compile(r"(?:pipeline|stages)(?:[./][A-Za-z_][A-Za-z0-9_]*)*(?:\.py)?")


def module_file(name: str) -> Path | None:
    """``pipeline.a.b`` (or ``pipeline/a/b.py``) -> its file under ROOT, or None."""
    name = name[:-3] if name.endswith(".py") else name
    rel = name.replace(".", "/")
    for p in (ROOT / f"{rel}.py", ROOT / rel / "__init__.py"):
        if p.is_file():
            return p
    return None


def _package_inits(path: Path) -> list[Path]:
    out, d = [], path.parent
    while d != ROOT and d.name:
        init = d / "__init__.py"
        if init.is_file():
            out.append(init)
        d = d.parent
    return out


def imported_files(path: Path) -> set[Path]:
    """Project files ``path`` imports or names (see the module doc)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    pkg = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join([p for p in parts if p] + ([base] if base else []))
            names.append(base)
            names += [f"{base}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            text = node.value.split(":")[0].strip()
            if _NAME.fullmatch(text):
                names.append(text)
    out = set()
    for n in names:
        if n.split(".")[0].split("/")[0] not in CODE:
            continue
        f = module_file(n)
        if f is not None and f != path:
            out.add(f)
            out.update(_package_inits(f))
    return out


def import_closure(stage: str) -> set[str]:
    """Repository-relative paths of every project file stage ``stage`` runs."""
    start = ROOT / "stages" / f"{stage}.py"
    seen, todo = {start, *_package_inits(start)}, [start]
    while todo:
        for f in imported_files(todo.pop()):
            if f not in seen:
                seen.add(f)
                todo.append(f)
    return {p.relative_to(ROOT).as_posix() for p in seen}


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
    assert "pipeline/render/sampling.py" in render                 # imported inside main()
    assert "stages/_common.py" in render and "pipeline/__init__.py" in render
    usd = import_closure("usd")
    assert "pipeline/blender/asset_preview.py" in usd and "pipeline/usd/validate.py" in usd
    assert "pipeline/settings.py" in import_closure("check_params")
    assert "pipeline/render/sampling.py" in import_closure("check_params")   # "module:Class" strings
    assert covered("pipeline/usd/stage.py", ["pipeline/usd"]) and not covered("pipeline/usdx.py", ["pipeline/usd"])
    assert "pipeline/rig" in compact({f"pipeline/rig/{f.name}" for f in (ROOT / "pipeline/rig").glob("*.py")})


def test_render_fingerprint_hashes_the_render_closure():
    """A render folder's config hash covers exactly the renderer source the render stage imports:
    a file it hashes but DVC does not track (or the reverse) makes dvc.lock depend on history."""
    from pipeline.render.asset import renderer_sources

    hashed = {str(p.relative_to(ROOT)) for p in renderer_sources()}
    closure = import_closure("render")
    mine = {p for p in closure if p.startswith(("pipeline/render/", "pipeline/blender/"))}
    assert mine <= hashed, f"render imports but does not hash: {sorted(mine - hashed)}"
    assert hashed <= closure, f"hashed but not a render dep: {sorted(hashed - closure)}"


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
            data = [x for x in items if not x.strip()[2:].split()[0].startswith(CODE)]
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
