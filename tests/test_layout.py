"""The package's layering, read from the source without importing it.

Every ``import`` and ``from ... import`` statement of every module under
``headplod/`` is parsed with :mod:`ast`, wherever it sits (module level,
inside a function, a method or an ``if``), relative imports are resolved, and
the edges make the module import graph. A package's ``__init__`` is a module
of its own: importing ``headplod.capture.v4l2`` from outside ``capture/``
runs ``headplod/capture/__init__.py`` first, so such an import is also an
edge to ``headplod.capture``.

The tests:

- the graph has no cycle (a cycle hidden by an import inside a function is
  still a cycle: the two modules cannot be understood, tested or moved
  apart);
- ``headplod/plod/`` imports neither ``headplod.render`` nor
  ``headplod.tracking`` nor ``headplod.demo``, directly or through other
  modules (PLOD is pure numpy: the tracker and the GL renderer sit on top of
  it, not under it);
- ``synthetic/`` imports nothing from ``headplod`` (the test data is made by
  separate code);
- every package of ``headplod/`` imports only the packages :data:`LAYERS`
  allows it (one table for all; a new package must be added to it), and the
  table itself is a layering (no package reaches itself through it);
- only command modules know the command line: ``argparse`` is imported only
  by modules named ``cli.py``, ``command.py``, ``*_command.py`` or listed in
  :data:`ARGPARSE_MODULES`; nothing under ``headplod/plod/`` imports
  ``argparse`` or writes to ``sys.stderr`` (the library raises typed errors).

Imports through ``importlib.import_module`` or ``__import__`` cannot be seen
this way, so the package must not use them (checked too).
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "headplod"

#: What ``headplod/plod/`` must not reach, directly or through other modules.
ABOVE_PLOD = ("headplod.render", "headplod.tracking", "headplod.demo")

#: The packages (and top-level modules) of ``headplod/`` each one may import directly, the allowed
#: directions of the whole package. Below: the pure stages (``plod``: PLOD, pure numpy; ``tracking``: the
#: tracker; ``filters``, ``io``) import no stage above them; ``render`` draws PLOD; ``capture``,
#: ``calibration`` and ``live`` are the cameras' side; ``demo``, ``bench``, ``doctor`` and ``cli`` sit on top.
#: ``argtypes`` and ``progress`` are the commands' shared argument types and notes; ``tol`` the generic
#: numerical tolerances and ``angles`` the angle between directions, ``cache`` the cache folder and ``streams``
#: the command line's standard streams, below everything.
LAYERS = {
    "headplod": (),
    "tol": (),
    "angles": (),
    "filters": (),
    "io": ("tol",),
    "argtypes": (),
    "progress": (),
    "cache": (),
    "streams": (),
    "plod": ("angles", "cache", "filters", "io", "tol"),
    "tracking": ("angles", "filters", "io", "tol"),
    "capture": ("argtypes", "cache", "io", "progress", "tol"),
    "calibration": ("angles", "argtypes", "capture", "io", "progress", "tol"),
    "render": ("argtypes", "io", "plod", "progress", "tol"),
    "live": ("argtypes", "capture", "io", "progress", "streams", "tol", "tracking"),
    "config": ("argtypes", "capture", "live"),
    "demo": ("argtypes", "capture", "io", "live", "plod", "progress", "render", "tol", "tracking"),
    "doctor": ("argtypes", "capture", "io", "render"),
    "bench": ("angles", "argtypes", "capture", "demo", "io", "live", "plod", "progress", "render", "tol", "tracking"),
    "cli": ("argtypes", "bench", "cache", "calibration", "capture", "config", "demo", "doctor", "io", "live",
            "progress", "render", "streams"),
}

#: Modules that may import argparse besides those named ``cli.py``, ``command.py`` and ``*_command.py``:
#: the commands' shared argument types, the config file (it fills the parsers' defaults) and command
#: modules of their own (``doctor``). Listed by dotted name; the list only shrinks.
ARGPARSE_MODULES = ("headplod.argtypes", "headplod.config", "headplod.doctor", "headplod.calibration.printouts",
                    "headplod.live.preview")

@dataclass(frozen=True)
class Edge:
    """One import statement's edge: ``source`` imports ``target`` at ``path:line``."""

    source: str
    target: str
    path: str            # relative to the root
    line: int
    local: bool          # inside a function (or method)

    def __str__(self) -> str:
        where = ", inside a function" if self.local else ""
        return f"{self.source} -> {self.target}  ({self.path}:{self.line}{where})"


def module_files(top: str, root: Path = ROOT) -> dict[str, Path]:
    """Every module of the package ``top`` by dotted name; a package's ``__init__.py`` is the package."""
    files = {}
    for path in sorted((root / top).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        files[".".join(parts)] = path
    return files


def _statements(tree: ast.AST):
    """Import nodes with whether they sit inside a function (at any depth)."""
    def walk(node, local):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)):
                yield child, local
            inner = local or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            yield from walk(child, inner)
    yield from walk(tree, False)


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute name of a ``from X import ...`` statement's X."""
    if node.level == 0:
        return node.module
    parts = module.split(".") if is_package else module.split(".")[:-1]
    if node.level - 1 > len(parts) - 1:
        raise ValueError(f"{module}: relative import beyond the top-level package (level {node.level})")
    base = parts[:len(parts) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def import_edges(top: str = PACKAGE, root: Path = ROOT) -> tuple[dict[str, Path], list[Edge]]:
    """The modules of ``top`` and every import edge between them (``top`` only)."""
    files = module_files(top, root)
    edges = []
    for module, path in files.items():
        is_package = path.name == "__init__.py"
        for node, local in _statements(ast.parse(path.read_text(), filename=str(path))):
            targets = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = _resolve(module, is_package, node)
                # ``from package import submodule`` imports the submodule; the package's
                # own namespace is only read for the other names.
                submodules = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in files]
                targets = submodules if len(submodules) == len(node.names) else [base, *submodules]
            mine = set(_ancestors(module))
            for target in targets:
                if target != top and not target.startswith(top + "."):
                    continue
                # Importing a.b.c runs a/__init__ and a/b/__init__ first, unless they are
                # packages of the importer itself (already being imported by then).
                for name in [*_ancestors(target), target]:
                    explicit = name == target
                    if name == module or (not explicit and name in mine) or name not in files:
                        continue
                    edges.append(Edge(module, name, str(path.relative_to(root)), node.lineno, local))
    unique = {(e.source, e.target, e.line): e for e in edges}
    return files, list(unique.values())


def _strongly_connected(nodes, graph) -> list[list[str]]:
    """Tarjan's components of more than one node (or with a self-loop), iteratively."""
    index, low, on_stack, stack, found = {}, {}, set(), [], []
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(graph.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in graph.get(node, ()):
                    found.append(sorted(component))
    return found


def _shortest_path(start, goal, graph, members) -> list[str]:
    """A shortest path ``start`` ... ``goal`` inside ``members`` (breadth first)."""
    parent, queue = {start: None}, [start]
    for node in queue:
        if node == goal:
            path = [node]
            while parent[path[-1]] is not None:
                path.append(parent[path[-1]])
            return path[::-1]
        for child in sorted(graph.get(node, ())):
            if child in members and child not in parent:
                parent[child] = node
                queue.append(child)
    raise AssertionError(f"no path from {start} to {goal} inside {sorted(members)}")


def import_cycles(top: str = PACKAGE, root: Path = ROOT) -> list[list[Edge]]:
    """Cycles of the import graph, as edges, so that every edge inside a cycle is named in one.

    Per strongly connected component, each of its edges not yet shown is
    closed into a shortest cycle (the edge, then a shortest way back).
    """
    files, edges = import_edges(top, root)
    graph, by_pair = {}, {}
    for e in edges:
        graph.setdefault(e.source, set()).add(e.target)
        by_pair.setdefault((e.source, e.target), e)
    cycles = []
    for component in _strongly_connected(sorted(files), graph):
        members, shown = set(component), set()
        for a in component:
            for b in sorted(graph.get(a, set()) & members):
                if (a, b) in shown:
                    continue
                names = [a, *_shortest_path(b, a, graph, members)] if a != b else [a, a]
                pairs = list(zip(names, names[1:]))
                shown.update(pairs)
                cycles.append([by_pair[pair] for pair in pairs])
    return cycles


def _describe(cycles) -> str:
    blocks = []
    for cycle in cycles:
        chain = " -> ".join([cycle[0].source, *(e.target for e in cycle)])
        blocks.append(chain + "\n" + "\n".join(f"    {e}" for e in cycle))
    return "\n".join(blocks)


# ----------------------------------------------------------------------------
# the walker itself, on small made-up packages
# ----------------------------------------------------------------------------

def _write_package(tmp_path, files: dict[str, str]):
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_walker_finds_a_cycle_hidden_in_a_function(tmp_path):
    _write_package(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/a.py": "from . import b\n",
        "pkg/b.py": "def f():\n    from .sub.c import x\n",
        "pkg/sub/__init__.py": "",
        "pkg/sub/c.py": "import pkg.a as a\n",
    })
    cycles = import_cycles("pkg", tmp_path)
    assert len(cycles) == 1
    assert [e.source for e in cycles[0]] == ["pkg.a", "pkg.b", "pkg.sub.c"]
    assert [e.local for e in cycles[0]] == [False, True, False]


def test_walker_counts_a_package_init_as_a_module(tmp_path):
    # b imports a sibling through the package; the package's __init__ imports b.
    _write_package(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/cap/__init__.py": "from .b import *\nfrom .c import *\n",
        "pkg/cap/b.py": "from ..other import y\n",
        "pkg/cap/c.py": "from . import b\n",          # the parent package is already running: no edge
        "pkg/other.py": "from pkg.cap.c import z\n",   # runs pkg/cap/__init__ first: an edge to it
    })
    _, edges = import_edges("pkg", tmp_path)
    cycles = import_cycles("pkg", tmp_path)
    pairs = {(e.source, e.target) for e in edges}
    assert ("pkg.other", "pkg.cap") in pairs and ("pkg.other", "pkg.cap.c") in pairs
    assert ("pkg.cap.c", "pkg.cap") not in pairs
    # One tangle: cap -> b -> other -> cap, and cap -> c -> b; every edge in it is shown in a cycle.
    assert {e.source for cycle in cycles for e in cycle} == {"pkg.cap", "pkg.cap.b", "pkg.cap.c", "pkg.other"}
    assert {(e.source, e.target) for cycle in cycles for e in cycle} == \
        {(a, b) for a, b in pairs if a != "pkg" and b != "pkg"}
    for cycle in cycles:
        assert cycle[0].source == cycle[-1].target
        assert all(x.target == y.source for x, y in zip(cycle, cycle[1:]))


def test_walker_sees_no_cycle_in_layers(tmp_path):
    _write_package(tmp_path, {
        "pkg/__init__.py": "",
        "pkg/low.py": "import numpy\n",
        "pkg/mid.py": "from .low import x\ndef f():\n    from . import low\n",
        "pkg/top/__init__.py": "from .app import run\n",
        "pkg/top/app.py": "from ..mid import f\nfrom pkg import low\n",
    })
    assert import_cycles("pkg", tmp_path) == []


# ----------------------------------------------------------------------------
# the package
# ----------------------------------------------------------------------------

@pytest.mark.slow
def test_no_import_cycles():
    cycles = import_cycles()
    assert not cycles, (f"import cycles in {PACKAGE}/ (every import inside a cycle is shown in one; "
                        f"move the shared piece to the lower module):\n" + _describe(cycles))


@pytest.mark.slow
def test_no_dynamic_imports():
    """The graph above only sees import statements."""
    found = []
    for module, path in module_files(PACKAGE).items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                name = getattr(node.func, "attr", None) or getattr(node.func, "id", None)
                if name in ("import_module", "__import__"):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, "dynamic imports the layout tests cannot see: " + ", ".join(found)


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


@pytest.mark.slow
def test_plod_is_below_render_tracking_and_demo():
    """No module of plod/ reaches render, tracking or demo, directly or through any chain of imports."""
    files, edges = import_edges()
    graph = {}
    for e in edges:
        graph.setdefault(e.source, []).append(e)
    bad, reported = [], set()
    for start in (m for m in files if _within(m, "headplod.plod")):
        # Breadth first, so the chain reported is a shortest one.
        via, queue = {start: None}, [start]
        for node in queue:
            for e in graph.get(node, ()):
                if e.target in via:
                    continue
                via[e.target] = e
                if any(_within(e.target, f) for f in ABOVE_PLOD):
                    if (e.path, e.line) in reported:     # one statement: a module and its packages
                        continue
                    reported.add((e.path, e.line))
                    chain = [e]
                    while via[chain[-1].source] is not None:
                        chain.append(via[chain[-1].source])
                    bad.append("\n".join(f"    {x}" for x in reversed(chain)))
                else:
                    queue.append(e.target)
    assert not bad, (f"headplod/plod/ must not import {', '.join(ABOVE_PLOD)} (PLOD is pure numpy: they sit "
                     "on top of it); move the code up, or the shared piece down:\n" + "\n\n".join(bad))


def test_synthetic_imports_nothing_from_headplod():
    bad = []
    for module, path in module_files("synthetic").items():
        for node, local in _statements(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                names = [node.module or ""] if node.level == 0 else []
            bad += [f"{path.relative_to(ROOT)}:{node.lineno} imports {n}" for n in names
                    if n == PACKAGE or n.startswith(PACKAGE + ".")]
    assert not bad, "synthetic/ must not import headplod:\n" + "\n".join(bad)


def _package(module: str) -> str:
    """The entry of :data:`LAYERS` a module belongs to: headplod.X.y -> X; headplod -> headplod."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def test_every_package_imports_only_what_the_table_allows():
    files, edges = import_edges()
    unknown = sorted({_package(m) for m in files} - set(LAYERS))
    assert not unknown, f"packages of {PACKAGE}/ missing from LAYERS (say what they may import): {unknown}"
    bad = [f"    {e}" for e in edges
           if _package(e.source) != _package(e.target) and _package(e.target) not in LAYERS[_package(e.source)]]
    assert not bad, ("imports against the layering (tests/test_layout.py LAYERS); move the code to a package "
                     "that may import it, or the shared piece down:\n" + "\n".join(bad))


def test_the_layer_table_is_a_layering():
    """No package reaches itself through the allowed directions (else the table allows a cycle)."""
    graph = {k: [t for t in v if t != k] for k, v in LAYERS.items()}
    for k, targets in graph.items():
        assert set(targets) <= set(LAYERS), (k, set(targets) - set(LAYERS))
    assert not _strongly_connected(sorted(graph), graph), "LAYERS allows a cycle"


def test_the_layering_check_finds_a_forbidden_import(tmp_path):
    _write_package(tmp_path, {"headplod/__init__.py": "", "headplod/plod/__init__.py": "",
                              "headplod/plod/a.py": "from ..render import b\n", "headplod/render/__init__.py": "",
                              "headplod/render/b.py": "from ..plod import a\n"})
    _, edges = import_edges(root=tmp_path)
    wrong = [e for e in edges if _package(e.target) not in LAYERS[_package(e.source)]
             and _package(e.source) != _package(e.target)]
    assert [(e.source, e.target) for e in wrong] == [("headplod.plod.a", "headplod.render"),
                                                      ("headplod.plod.a", "headplod.render.b")]


def _imports_argparse(path: Path) -> list[int]:
    lines = []
    for node, _ in _statements(ast.parse(path.read_text(), filename=str(path))):
        names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
        lines += [node.lineno for n in names if n == "argparse" or n.startswith("argparse.")]
    return lines


def _is_command_module(module: str, path: Path) -> bool:
    stem = path.stem
    return stem in ("cli", "command") or stem.endswith("_command") or module in ARGPARSE_MODULES


def test_only_command_modules_import_argparse():
    bad = [f"{path.relative_to(ROOT)}:{line}" for module, path in module_files(PACKAGE).items()
           if not _is_command_module(module, path) for line in _imports_argparse(path)]
    assert not bad, ("argparse outside the command modules (cli.py, command.py, *_command.py; library code takes "
                     "typed values and raises typed errors): " + ", ".join(bad))


def test_plod_neither_imports_argparse_nor_writes_to_stderr():
    bad = []
    for module, path in module_files(PACKAGE).items():
        if not _within(module, "headplod.plod"):
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        bad += [f"{path.relative_to(ROOT)}:{line} imports argparse" for line in _imports_argparse(path)]
        bad += [f"{path.relative_to(ROOT)}:{node.lineno} uses sys.{node.attr}" for node in ast.walk(tree)
                if isinstance(node, ast.Attribute) and node.attr in ("stderr", "stdout", "exit")
                and isinstance(node.value, ast.Name) and node.value.id == "sys"]
    assert not bad, "headplod/plod/ is the library: no command line in it:\n" + "\n".join(bad)


def test_the_argparse_check_sees_a_local_import(tmp_path):
    _write_package(tmp_path, {"m.py": "def f():\n    import argparse\n    from argparse import ArgumentTypeError\n"})
    assert _imports_argparse(tmp_path / "m.py") == [2, 3]
    assert _is_command_module("headplod.x.y_command", Path("y_command.py"))
    assert not _is_command_module("headplod.plod.terrain_file", Path("terrain_file.py"))
