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
3. ``blender.launch``, the one door to Blender (``pipeline/blender/launch.py``: it builds a
   worker's command line and starts it, importing no bpy and nothing above io), a room of its own
   inside ``blender/`` so that render and the previews reach Blender through it;
4. ``geometry``, the shared mesh helpers (triangles, mesh graph, sphere fit, frames);
5. the shared models, ``eyeball`` and ``synthetic_head`` (side by side: neither imports the other);
6. the stage packages in DAG order: ``ingest``, ``placement`` (where the eyes are: the
   placement ``remove_eyeballs`` calls), ``remove_eyeballs``, ``retopo``, ``bake``, ``snap``,
   ``rig``, ``usd``, then ``render`` and ``preview`` side by side;
7. ``blender``, everything that imports bpy (its workers), and beside it ``params_check``, the
   check of all of ``params.yaml`` (it names every stage package's settings class).

A package may import its own modules and any package on a lower floor, never one on its own
floor or above. Imports are read with :mod:`ast`, wherever they stand (inside functions and
``TYPE_CHECKING`` blocks too: a lazy import is still a dependency). A command line that runs a
module by name (``"-m", "pipeline.blender.render_worker"`` in a list or a call, or
``"python -m pipeline.x"`` in one string) is an import of that module: the child runs it for
this one. The door builds its command lines from the worker its caller names, so no module
holds such an edge, and none may hold one to a Blender worker (:func:`test_only_the_door_starts_blender`).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FLOORS = [
    {"errors", "results", "kernels", "fork", "sources"},
    {"settings", "__init__"},
    {"io"},
    {"blender.launch"},
    {"geometry"},
    {"eyeball", "synthetic_head"},
    {"ingest"}, {"placement"}, {"remove_eyeballs"}, {"retopo"}, {"bake"}, {"snap"}, {"rig"}, {"usd"},
    {"render", "preview"},
    {"blender", "params_check"},
]
FLOOR = {pkg: k for k, names in enumerate(FLOORS) for pkg in names}
#: Modules that are a room of their own inside their package (module -> its floor's name): the
#: door and the face of its package, which imports nothing (``from pipeline.blender import launch``
#: runs it).
ROOMS = {"pipeline.blender": "blender.launch", "pipeline.blender.launch": "blender.launch"}
#: A command line in one string: ``[.../python3 ]-m pipeline.x ...`` at its start (a sentence
#: that names a command further in, or a docstring's usage line, runs nothing).
_DASH_M = re.compile(r"^\s*(?:[\w./-]*python[\w.]*\s+)?-m\s+((?:pipeline|stages)(?:\.[A-Za-z_][A-Za-z0-9_]*)+)")

#: Import cycles between modules that are known (none).
KNOWN_CYCLES: list = []


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def spawned(tree: ast.AST) -> set[str]:
    """Modules a command line in ``tree`` runs by name: a ``"-m"`` constant followed by a string
    constant in a list, tuple or call's arguments, or a string that starts ``[python ]-m pipeline.x``
    (docstrings left out)."""
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
    out = set()
    for node in ast.walk(tree):
        seqs = []
        if isinstance(node, (ast.List, ast.Tuple)):
            seqs.append(node.elts)
        elif isinstance(node, ast.Call):
            seqs.append(node.args)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            out.update(_DASH_M.findall(node.value))
        for seq in seqs:
            for a, b in zip(seq, seq[1:]):
                if (isinstance(a, ast.Constant) and a.value == "-m" and isinstance(b, ast.Constant)
                        and isinstance(b.value, str)):
                    out.add(b.value)
    return out


def imports(path: Path, root: Path = ROOT) -> set[str]:
    """Absolute names of every module ``path`` imports (``from a import b`` gives ``a`` and
    ``a.b``: b may be a submodule) or runs as ``-m`` in a command line (:func:`spawned`)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    here = module_name(path, root).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    out = spawned(tree)
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


def module_files(root: Path = ROOT) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted((root / "pipeline").rglob("*.py"))}


def package_of(name: str, files: dict) -> str:
    """The floor-bearing package of module ``name``: ``pipeline.io.x`` -> ``io``,
    ``pipeline.errors`` -> ``errors``, a room of :data:`ROOMS` -> its own name."""
    if name in ROOMS:
        return ROOMS[name]
    parts = name.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


def project_imports(files: dict, root: Path = ROOT) -> dict[str, set[str]]:
    """module -> the project modules it imports (names that are no module of pipeline/ are
    dropped: ``from pipeline.io.atomic import write_json`` keeps ``pipeline.io.atomic``)."""
    return {m: {n for n in imports(p, root) if n in files and n != m} for m, p in files.items()}


def wrong_floors(root: Path = ROOT) -> list[str]:
    """Every import (or ``-m`` command line) of a module under ``root``/pipeline that runs up or
    across the floors, one line each."""
    files = module_files(root)
    wrong = []
    for m, targets in project_imports(files, root).items():
        a = package_of(m, files)
        for t in sorted(targets):
            b = package_of(t, files)
            if a != b and FLOOR[b] >= FLOOR[a]:
                wrong.append(f"{files[m].relative_to(root)} ({a}, floor {FLOOR[a]}) imports {t} "
                             f"({b}, floor {FLOOR[b]})")
    return wrong


def blender_spawns(root: Path = ROOT) -> list[str]:
    """Command lines that run a Blender worker (``-m pipeline.blender.*``) in any module of
    ``root``'s pipeline/ and stages/: the door builds its own from a name, so there are none."""
    out = []
    for top in ("pipeline", "stages"):
        for p in sorted((root / top).rglob("*.py")):
            for name in sorted(spawned(ast.parse(p.read_text(encoding="utf-8")))):
                if name.startswith("pipeline.blender"):
                    out.append(f"{p.relative_to(root)} runs -m {name}")
    return out


def test_every_package_has_a_floor():
    files = module_files()
    unknown = sorted({package_of(m, files) for m in files} - set(FLOOR))
    assert not unknown, f"packages with no floor (add them to FLOORS and docs/layout.md): {unknown}"


def test_each_package_imports_only_packages_below_it():
    wrong = wrong_floors()
    assert not wrong, "imports that run up or across the floors:\n" + "\n".join(wrong)


def test_only_the_door_starts_blender():
    """Every Blender worker starts through pipeline/blender/launch.py, which takes the worker's
    name from its caller: no module holds a ``-m pipeline.blender.*`` command line of its own."""
    found = blender_spawns()
    assert not found, "start Blender workers through pipeline/blender/launch.py:\n" + "\n".join(found)


def _tree(root: Path, files: dict) -> Path:
    for rel, text in {"pipeline/__init__.py": "", "pipeline/render/__init__.py": "",
                      "pipeline/blender/__init__.py": "", "pipeline/blender/render_worker.py": "",
                      "pipeline/blender/launch.py": "", "pipeline/usd/__init__.py": "", **files}.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def test_a_dash_m_edge_is_an_import(tmp_path):
    """An injected command line that runs a Blender worker from render (below blender) fails both
    checks, as the same import would; through the door, or in a shell line, it is seen alike."""
    assert spawned(ast.parse('cmd = [sys.executable, "-m", "pipeline.blender.render_worker", a]')) \
        == {"pipeline.blender.render_worker"}
    assert spawned(ast.parse('run(py, "-m", "pipeline.x.y")\ns = "python -m pipeline.a.b --n 1"')) \
        == {"pipeline.x.y", "pipeline.a.b"}
    assert spawned(ast.parse('cmd = [py, "-m", worker]; argv[:1] == ["-m"]\n"""python -m pipeline.a"""\n'
                             'msg = "run python -m stages.dataset"; card = "(`python -m stages.dataset`)"')) == set()
    clean = _tree(tmp_path / "clean", {
        "pipeline/render/shard.py": "from pipeline.blender import launch\n"
                                    "p = launch.start('pipeline.blender.render_worker', [])\n"})
    assert wrong_floors(clean) == [] and blender_spawns(clean) == []
    bad = _tree(tmp_path / "bad", {
        "pipeline/render/shard.py": "import subprocess, sys\n"
                                    "subprocess.Popen([sys.executable, '-m', 'pipeline.blender.render_worker'])\n"})
    assert wrong_floors(bad) == [f"pipeline/render/shard.py (render, floor {FLOOR['render']}) imports "
                                 f"pipeline.blender.render_worker (blender, floor {FLOOR['blender']})"]
    assert blender_spawns(bad) == ["pipeline/render/shard.py runs -m pipeline.blender.render_worker"]
    up = _tree(tmp_path / "up", {"pipeline/usd/build.py": "CMD = 'python -m pipeline.render.shard'\n",
                                 "pipeline/render/shard.py": ""})
    assert wrong_floors(up) == [f"pipeline/usd/build.py (usd, floor {FLOOR['usd']}) imports pipeline.render.shard "
                                f"(render, floor {FLOOR['render']})"]


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
