"""Tests and benchmarks stay apart: what they share lives in ``tests/fixtures/``.

A test module (anything under ``tests/``, fixtures included) never imports ``benchmarks`` nor
loads a benchmark's file by path; a benchmark (anything under ``benchmarks/``) imports from
``tests`` only ``tests.fixtures``, and never a test module by its bare name (``conftest``,
``test_*``, ``fixtures`` through a ``sys.path`` entry of ``tests/``). Imports are read with
:mod:`ast`, wherever they stand (a lazy import inside a function counts).
"""

from __future__ import annotations

import ast
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: calls that load a module from a file path
_LOADERS = {"spec_from_file_location", "run_path", "SourceFileLoader"}


def _imported(tree: ast.AST) -> set[str]:
    """Absolute names a module imports (relative imports stay inside their own package)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def _loads_benchmark_file(tree: ast.AST) -> bool:
    """Whether one function (or the module's top level) both calls a file loader and names
    ``benchmarks`` in a string without spaces (a path part, not prose)."""
    top = [n for s in tree.body if not isinstance(s, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
           for n in ast.walk(s)]
    scopes = [top] + [list(ast.walk(f)) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))]
    for nodes in scopes:
        calls = {c.func.attr if isinstance(c.func, ast.Attribute) else getattr(c.func, "id", None)
                 for c in nodes if isinstance(c, ast.Call)}
        named = any(isinstance(c, ast.Constant) and isinstance(c.value, str) and "benchmarks" in c.value
                    and " " not in c.value for c in nodes)
        if calls & _LOADERS and named:
            return True
    return False


def crossings(root: Path) -> list[str]:
    """Every import between tests and benchmarks under ``root`` that the house rule forbids."""
    test_names = {p.stem for p in (root / "tests").glob("*.py")} | {"fixtures"}
    bad = []
    for path in sorted((root / "tests").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        rel = path.relative_to(root)
        bad += [f"{rel} imports {n}" for n in sorted(_imported(tree)) if n.split(".")[0] == "benchmarks"]
        if _loads_benchmark_file(tree):
            bad.append(f"{rel} loads a file of benchmarks/ by path")
    for path in sorted((root / "benchmarks").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        rel = path.relative_to(root)
        for n in sorted(_imported(tree)):
            parts = n.split(".")
            if parts[0] == "tests" and parts[1:2] != ["fixtures"]:
                bad.append(f"{rel} imports {n} (only tests.fixtures is shared)")
            elif parts[0] in test_names:
                bad.append(f"{rel} imports {n} (a module of tests/ by its bare name)")
    return bad


def test_tests_and_benchmarks_share_only_tests_fixtures():
    bad = crossings(ROOT)
    assert not bad, "move what both use to tests/fixtures/:\n" + "\n".join(bad)


def test_an_injected_crossing_is_found(tmp_path):
    """The check on a copy of tests/ and benchmarks/ with one forbidden import put into each
    side (and one allowed one), and a benchmark file loaded by path."""
    def sources_only(folder, names):
        return [n for n in names if n == "__pycache__" or not (n.endswith(".py") or Path(folder, n).is_dir())]

    for d in ("tests", "benchmarks"):
        shutil.copytree(ROOT / d, tmp_path / d, ignore=sources_only)
    assert crossings(tmp_path) == []
    t = tmp_path / "tests" / "test_injected.py"
    t.write_text("def test_x():\n    from benchmarks.bench_chain import main\n")
    f = tmp_path / "tests" / "fixtures" / "injected.py"
    f.write_text("import benchmarks.run_all\n")
    b = tmp_path / "benchmarks" / "bench_injected.py"
    b.write_text("from tests.fixtures import make_scan\nfrom tests.test_layers import imports\n"
                 "import conftest\n")
    p = tmp_path / "tests" / "test_by_path.py"
    p.write_text("import importlib.util\nfrom pathlib import Path\n\n\ndef load():\n"
                 "    return importlib.util.spec_from_file_location('m', Path('benchmarks') / 'bench_x.py')\n")
    assert crossings(tmp_path) == [
        "tests/fixtures/injected.py imports benchmarks.run_all",
        "tests/test_by_path.py loads a file of benchmarks/ by path",
        "tests/test_injected.py imports benchmarks.bench_chain",
        "tests/test_injected.py imports benchmarks.bench_chain.main",
        "benchmarks/bench_injected.py imports conftest (a module of tests/ by its bare name)",
        "benchmarks/bench_injected.py imports tests.test_layers (only tests.fixtures is shared)",
        "benchmarks/bench_injected.py imports tests.test_layers.imports (only tests.fixtures is shared)",
    ]
