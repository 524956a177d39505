"""The fast tier, ``pytest -m "not slow"``: it imports every module, and every test module keeps a test in it.

A test of more than about half a second on a busy two-core machine carries ``@pytest.mark.slow`` (the marker
is registered in pyproject.toml); the full suite (``pytest``, and CI) runs everything. So that the fast tier
still covers every module:

- every module under ``headplod/`` and ``synthetic/`` is imported here, found by walking the packages and
  checked against the ``.py`` files on disk (a module the walk misses, or one that fails to import, fails);
- every test module has at least one test without the mark, except those in :data:`ALL_SLOW`, each with
  why (read from the source with :mod:`ast`, so nothing is run to know it).
"""
from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"

#: Test modules whose every test is slow, and why no fast one is kept there.
ALL_SLOW = {
    "test_docs_example.py": "runs the documented example end to end, as a reader would",
    "test_rig_refine.py": "each test tracks a sequence long enough for the rig's refinement to converge",
    "test_uncertainty.py": "each test tracks enough frames for a covariance's calibration (NEES) to mean something",
}


def _module_files(top: str) -> set[str]:
    """Dotted names of every module of the package ``top``, from the files (a package's __init__ is itself)."""
    names = set()
    for path in (ROOT / top).rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names.add(".".join(parts))
    return names


@pytest.mark.parametrize("top", ["headplod", "synthetic"])
def test_every_module_imports(top):
    package = importlib.import_module(top)
    walked = {top} | {m.name for m in pkgutil.walk_packages(package.__path__, top + ".")}
    assert walked == _module_files(top)                      # no folder without an __init__, no stray file
    for name in sorted(walked):
        importlib.import_module(name)


def _is_slow_mark(node: ast.expr) -> bool:
    """``pytest.mark.slow`` (or a list holding it, as ``pytestmark = [...]``)."""
    if isinstance(node, (ast.List, ast.Tuple)):
        return any(_is_slow_mark(e) for e in node.elts)
    return ast.unparse(node) == "pytest.mark.slow"


def fast_tests(source: str) -> list[str]:
    """The test functions of a test module's source that the fast tier runs (classes' methods as Class.name)."""
    tree = ast.parse(source)
    if any(isinstance(n, ast.Assign) and any(ast.unparse(t) == "pytestmark" for t in n.targets)
           and _is_slow_mark(n.value) for n in tree.body):
        return []

    def fast(fn, prefix=""):
        if fn.name.startswith("test") and not any(_is_slow_mark(d) for d in fn.decorator_list):
            return [prefix + fn.name]
        return []

    out = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            out += fast(node)
        elif isinstance(node, ast.ClassDef) and not any(_is_slow_mark(d) for d in node.decorator_list):
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    out += fast(item, node.name + ".")
    return out


def test_fast_tests_are_read_from_the_marks():
    source = ("import pytest\n\n@pytest.mark.slow\ndef test_a():\n    pass\n\n"
              "@pytest.mark.parametrize('x', [1])\ndef test_b(x):\n    pass\n\n"
              "class TestC:\n    @pytest.mark.slow\n    def test_d(self):\n        pass\n\n"
              "    def test_e(self):\n        pass\n")
    assert fast_tests(source) == ["test_b", "TestC.test_e"]
    assert fast_tests("import pytest\npytestmark = pytest.mark.slow\n\ndef test_a():\n    pass\n") == []


def test_every_test_module_keeps_a_fast_test():
    modules = sorted(p.name for p in TESTS.glob("test_*.py"))
    without = [name for name in modules if not fast_tests((TESTS / name).read_text())]
    assert sorted(without) == sorted(ALL_SLOW), "a test module has no test in the fast tier (or one now has)"
