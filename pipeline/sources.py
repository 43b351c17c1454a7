"""The project source files a program runs: the import closure of a ``stages/`` script.

One definition serves two readers that must agree file for file: dvc.yaml's code deps (each
stage's ``build/code/<stage>.sha256``, :func:`closure_digest`, written by the ``code`` stage;
``tests/test_dvc_deps.py`` holds and regenerates them) and the render fingerprint
(:func:`pipeline.render.asset.renderer_sources`), whose change marks a resumable render folder's
images stale. A file one of them saw and the other did not would either keep stale images or
make ``dvc.lock`` depend on history.

The closure starts at a file and follows, transitively, every import of a ``pipeline.*`` or
``stages.*`` module (top-level or inside functions, relative or absolute, ``from`` imports of
submodules, and the ``__init__.py`` of every package on the way) and every string constant that
names one: ``-m pipeline.blender.render_worker`` for a Blender worker, ``"pipeline.x:Class"``
looked up with importlib, ``pipeline/x.py`` paths. A package whose ``__init__.py`` imports the
modules it finds in its own folder (``pkgutil.iter_modules(__path__)``: the label writers of
pipeline/render/formats/) brings every module of that folder. It reads the sources with
:mod:`ast` and imports nothing, so it costs no Blender, pxr or numpy start-up.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

__all__ = ["ROOT", "CODE", "module_file", "package_inits", "imported_files", "import_closure",
           "stage_closure", "closure_digest"]

#: The folder holding ``pipeline/`` and ``stages/`` (the repository root, or site-packages).
ROOT = Path(__file__).resolve().parents[1]
#: Top-level packages whose files are project code.
CODE = ("pipeline", "stages")
_NAME = re.compile(r"(?:pipeline|stages)(?:[./][A-Za-z_][A-Za-z0-9_]*)*(?:\.py)?")


def module_file(name: str, root: Path = ROOT) -> Path | None:
    """``pipeline.a.b`` (or ``pipeline/a/b.py``) -> its file under ``root``, or None."""
    name = name[:-3] if name.endswith(".py") else name
    rel = name.replace(".", "/")
    for p in (root / f"{rel}.py", root / rel / "__init__.py"):
        if p.is_file():
            return p
    return None


def package_inits(path: Path, root: Path = ROOT) -> list[Path]:
    """The ``__init__.py`` of every package containing ``path`` (Python runs each on import)."""
    out, d = [], path.parent
    while d != root and d.name:
        init = d / "__init__.py"
        if init.is_file():
            out.append(init)
        d = d.parent
    return out


_PARSED: dict = {}


def imported_files(path: Path, root: Path = ROOT) -> set[Path]:
    """Project files that ``path`` imports or names (see the module docstring).

    Remembered per file, size and modification time: a fingerprint taken again in the same
    process re-reads only what changed (one parse of the render closure costs ~0.3 s)."""
    st = path.stat()
    key = (path, root, st.st_size, st.st_mtime_ns)
    hit = _PARSED.get(path)
    if hit is not None and hit[0] == key:
        return set(hit[1])
    out = _imported_files(path, root)
    _PARSED[path] = (key, frozenset(out))
    return out


def _discovers_its_folder(tree: ast.AST) -> bool:
    """Does a package's ``__init__`` call ``pkgutil.iter_modules(__path__)`` (a plugin folder)?"""
    for node in ast.walk(tree):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr == "iter_modules" and node.args
                and isinstance(node.args[0], ast.Name) and node.args[0].id == "__path__"):
            return True
    return False


def _imported_files(path: Path, root: Path) -> set[Path]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    pkg = ".".join(path.relative_to(root).with_suffix("").parts[:-1])
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
    if path.name == "__init__.py" and _discovers_its_folder(tree):
        out.update(p for p in path.parent.glob("*.py") if p != path)
    for n in names:
        if n.split(".")[0].split("/")[0] not in CODE:
            continue
        f = module_file(n, root)
        if f is not None and f != path:
            out.add(f)
            out.update(package_inits(f, root))
    return out


def import_closure(start: Path, root: Path = ROOT) -> set[str]:
    """``root``-relative POSIX paths of ``start`` and every project file it runs."""
    start = Path(start)
    seen, todo = {start, *package_inits(start, root)}, [start]
    while todo:
        for f in imported_files(todo.pop(), root):
            if f not in seen:
                seen.add(f)
                todo.append(f)
    return {p.relative_to(root).as_posix() for p in seen}


def stage_closure(stage: str, root: Path = ROOT) -> set[str]:
    """:func:`import_closure` of ``stages/<stage>.py``: the code a DVC stage runs."""
    return import_closure(root / "stages" / f"{stage}.py", root)


def closure_digest(stage: str, root: Path = ROOT) -> str:
    """One line naming the code DVC stage ``stage`` runs: the sha256 of its closure's files (each
    file's path, a NUL, its length, a NUL and its bytes, in path order), then the file count.

    ``build/code/<stage>.sha256`` (``stages/code.py``) holds it, and the stage depends on that one
    file instead of listing its ~50 modules: the same invalidation (a change to any file of the
    closure, and only to one, changes the line), at a fraction of the lock file DVC parses again
    for every stage it runs."""
    import hashlib

    files = sorted(stage_closure(stage, root))
    h = hashlib.sha256()
    for rel in files:
        data = (Path(root) / rel).read_bytes()
        h.update(rel.encode() + b"\0" + str(len(data)).encode() + b"\0" + data)
    return f"{h.hexdigest()}  {len(files)} files\n"
