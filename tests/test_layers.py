"""The house's floors: each package of ``pipeline/`` imports only the packages below it.

A package imports only packages below it: io at the bottom, then geometry and the shared models,
then the stage packages in DAG order, then blender (docs/layout.md draws the house); this module
holds it and finds no cycles. Read bottom up, the floors are:

0. the tools every floor may use: ``errors`` (the one expected-error type), ``results`` (a
   stage's metrics and timings), ``kernels``, ``fork`` (the process helper) and ``sources``;
1. ``settings``, the settings base, and the package face ``pipeline/__init__.py`` (its version;
   it pins the numeric kernels);
2. ``io``, the ground floor of products: file formats, atomic writes, one typed reader/writer
   per product;
3. ``geometry``, the shared mesh helpers (triangles, mesh graph, sphere fit, frames);
4. the shared models, ``eyeball`` and ``synthetic_head`` (side by side: neither imports the other);
5. the stage packages in DAG order: ``ingest``, ``placement`` (where the eyes are: the
   placement ``remove_eyeballs`` calls), ``remove_eyeballs``, ``retopo``, ``bake``, ``snap``,
   ``rig``, ``usd``, ``render``;
6. ``blender``, everything that imports bpy, and beside it ``params_check``, the check of all of
   ``params.yaml`` (it names every stage package's settings class).

A package may import its own modules and any package on a lower floor, never one on its own
floor or above. Imports are read with :mod:`ast`, wherever they stand (inside functions and
``TYPE_CHECKING`` blocks too: a lazy import is still a dependency). A module run by name as a
subprocess (``-m pipeline.blender.render_worker``) is not an import, and nothing here counts it.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FLOORS = [
    {"errors", "results", "kernels", "fork", "sources"},
    {"settings", "__init__"},
    {"io"},
    {"geometry"},
    {"eyeball", "synthetic_head"},
    {"ingest"}, {"placement"}, {"remove_eyeballs"}, {"retopo"}, {"bake"}, {"snap"}, {"rig"}, {"usd"}, {"render"},
    {"blender", "params_check"},
]
FLOOR = {pkg: k for k, names in enumerate(FLOORS) for pkg in names}

#: Import cycles between modules that are known (none).
KNOWN_CYCLES: list = []


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path) -> set[str]:
    """Absolute names of every module ``path`` imports (``from a import b`` gives ``a`` and
    ``a.b``: b may be a submodule)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = module_name(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package[:len(package) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return out


def module_files() -> dict[str, Path]:
    return {module_name(p): p for p in sorted((ROOT / "pipeline").rglob("*.py"))}


def package_of(name: str, files: dict) -> str:
    """The floor-bearing package of module ``name``: ``pipeline.io.x`` -> ``io``,
    ``pipeline.errors`` -> ``errors``."""
    parts = name.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


def project_imports(files: dict) -> dict[str, set[str]]:
    """module -> the project modules it imports (names that are no module of pipeline/ are
    dropped: ``from pipeline.io.atomic import write_json`` keeps ``pipeline.io.atomic``)."""
    return {m: {n for n in imports(p) if n in files and n != m} for m, p in files.items()}


def test_every_package_has_a_floor():
    files = module_files()
    unknown = sorted({package_of(m, files) for m in files} - set(FLOOR))
    assert not unknown, f"packages with no floor (add them to FLOORS and docs/layout.md): {unknown}"


def test_each_package_imports_only_packages_below_it():
    files = module_files()
    wrong = []
    for m, targets in project_imports(files).items():
        a = package_of(m, files)
        for t in sorted(targets):
            b = package_of(t, files)
            if a != b and FLOOR[b] >= FLOOR[a]:
                wrong.append(f"{files[m].relative_to(ROOT)} ({a}, floor {FLOOR[a]}) imports {t} "
                             f"({b}, floor {FLOOR[b]})")
    assert not wrong, "imports that run up or across the floors:\n" + "\n".join(wrong)


def test_the_library_never_imports_the_scripts_tests_or_benchmarks():
    bad = [f"{p.relative_to(ROOT)} imports {n}" for m, p in module_files().items() for n in sorted(imports(p))
           if n.split(".")[0] in ("stages", "tests", "benchmarks", "conftest")]
    assert not bad, "\n".join(bad)


def cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]
        counter[0] += 1
        stack.append(root)
        on.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(comp)
    return out


def test_no_import_cycles_between_modules():
    found = cycles(project_imports(module_files()))
    new = [sorted(c) for c in found if not any(c <= k for k in KNOWN_CYCLES)]
    assert not new, f"import cycles: {new}"


def test_cycles_finds_a_loop_and_ignores_a_chain():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [{"a", "b", "c"}]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
