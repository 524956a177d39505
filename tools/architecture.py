"""Draw headplod's architecture: one box per package, arrows for the imports between them.

    python tools/architecture.py            # writes docs/architecture.png and docs/architecture.txt
    python tools/architecture.py --check    # exit 1 with one line if the picture is stale
    python tools/architecture.py --list     # print the edges and the modules that make them

Everything drawn is read from the tree, nothing is a hand list:

- the boxes are the packages: each folder of ``headplod/`` with an
  ``__init__.py``, each top-level module of ``headplod/`` (``io.py``,
  ``cli.py``; a module that becomes a package stays the same box), and each
  top-level folder of the repository with an ``__init__.py`` (``synthetic/``,
  ``calib/``); a box's text is the first line of its docstring;
- the arrows are the imports, read statically with :mod:`ast` (relative
  imports resolved): ``A -> B`` when any module of A imports from B.  An
  arrow is solid when at least one of those imports runs at module load,
  dashed when all of them sit inside functions (lazy imports).

Only the layout is fixed here (:data:`PLACES`): data flow left to right in the
middle row, shared contracts below, the commands that use everything above.
A package not in :data:`PLACES` goes to a visible "other" row, so a new
folder shows up without editing this script (give it a place when it has one).

``docs/architecture.txt`` is the picture's content as text (boxes, summaries,
edges); the PNG carries that text's SHA-256 in its metadata.  ``--check``
recomputes the text from the tree and compares both, so a test keeps the
picture honest.
"""
from __future__ import annotations

import argparse
import ast
import hashlib
import re
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "headplod"
PNG = Path("docs/architecture.png")
TXT = Path("docs/architecture.txt")
SIZE_PX = (1600, 900)
DPI = 100
DIGEST_KEY = "headplod-architecture-sha256"
REGENERATE = "python tools/architecture.py"

# (column, row) of every known box.  Row 1: data flow, left to right; row 0:
# the shared contracts below it; row 2: the commands that use it.  Columns
# may be fractional to centre a row.  Unknown boxes go to OTHER_ROW.
PLACES = {
    "synthetic": (0, 1), "capture": (1, 1), "tracking": (2, 1), "live": (3, 1),
    "plod": (4, 1), "render": (5, 1), "demo": (6, 1),
    "calibration": (1, 0), "progress": (2, 0), "io": (3, 0), "filters": (4, 0), "calib": (5, 0),
    "bench": (2, 2), "cli": (4, 2),
}
ROW_NAMES = {2: "commands", 1: "data flow", 0: "contracts", -1: "other"}
OTHER_ROW = -1
SKIP_TOP_LEVEL = {PACKAGE, "tests", "tools", "docs", "build", "dist"}


@dataclass
class Box:
    """One package of the picture.

    name : its id, the folder or module name (``capture``, ``io``, ``synthetic``).
    module : its dotted module name (``headplod.capture``).
    label : how the README names it (``capture/``, ``io.py``).
    summary : the first line of its docstring, '' when it has none.
    files : its ``.py`` files.
    """

    name: str
    module: str
    label: str
    summary: str
    files: list[Path] = field(default_factory=list)


@dataclass(frozen=True)
class Edge:
    """``source`` imports from ``target``; ``lazy`` when only from inside functions."""

    source: str
    target: str
    lazy: bool


def first_doc_line(path: Path) -> str:
    """The first line of a module's docstring as plain text, '' when it has none.

    reST markup is dropped: ``:mod:`.x``` -> ``.x``, double backquotes -> none.
    """
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"), str(path)))
    if not doc or not doc.strip():
        return ""
    line = doc.strip().splitlines()[0].strip()
    return re.sub(r":\w+:`~?([^`]*)`", r"\1", line).replace("``", "")


def discover_boxes(root: Path = ROOT) -> dict[str, Box]:
    """Every package of the tree as a Box, keyed by name, in a stable order.

    The folders of ``headplod/`` with an ``__init__.py``, the modules directly
    in ``headplod/`` (but its ``__init__`` and ``__main__``), and the top-level
    folders of ``root`` with an ``__init__.py``, but ``headplod`` itself.
    """
    root = Path(root)
    boxes: dict[str, Box] = {}

    def add(name, module, label, init, files):
        if name in boxes:
            raise ValueError(f"two packages named {name!r}: {boxes[name].module} and {module}")
        boxes[name] = Box(name, module, label, first_doc_line(init) if init.exists() else "", files)

    pkg = root / PACKAGE
    for path in sorted(pkg.iterdir()):
        if path.is_dir() and (path / "__init__.py").exists():
            add(path.name, f"{PACKAGE}.{path.name}", f"{path.name}/", path / "__init__.py",
                sorted(path.rglob("*.py")))
        elif path.suffix == ".py" and path.stem not in ("__init__", "__main__"):
            add(path.stem, f"{PACKAGE}.{path.stem}", path.name, path, [path])
    for path in sorted(root.iterdir()):
        if (path.is_dir() and path.name not in SKIP_TOP_LEVEL and not path.name.startswith(".")
                and (path / "__init__.py").exists()):
            add(path.name, path.name, f"{path.name}/", path / "__init__.py",
                sorted(path.rglob("*.py")))
    return boxes


def module_of(path: Path, root: Path) -> tuple[str, bool]:
    """The dotted name of a ``.py`` file under root, and whether it is a package's ``__init__``."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    is_init = parts[-1] == "__init__"
    if is_init:
        parts = parts[:-1]
    return ".".join(parts), is_init


def imported_modules(path: Path, root: Path):
    """Yield (dotted name, lazy) for every import in one file, relative ones resolved.

    ``from X import a`` yields ``X.a`` (a may be a submodule or a name in X;
    :func:`box_of` takes the longest known prefix).  ``lazy`` is True for an
    import inside a function.  Only statement bodies are walked (an import is
    a statement, so it never sits inside an expression), which keeps this fast.
    """
    module, is_init = module_of(path, root)
    package = module if is_init else module.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    stack = [(node, False) for node in reversed(tree.body)]
    while stack:
        node, lazy = stack.pop()
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, lazy
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split(".") if package else []
                if node.level > len(parts):
                    raise ValueError(f"{path}:{node.lineno}: relative import beyond the top level")
                base = ".".join(parts[:len(parts) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                yield (f"{base}.{alias.name}" if alias.name != "*" else base), lazy
        else:
            inner = lazy or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            # if/for/while/with/try/class/def bodies, except handlers, match cases.
            for name in ("cases", "handlers", "finalbody", "orelse", "body"):
                children = getattr(node, name, None)
                if isinstance(children, list):
                    stack.extend((child, inner) for child in reversed(children))


def box_of(module: str, boxes: dict[str, Box]) -> str | None:
    """The box a dotted module name falls in (longest prefix), None outside the boxes."""
    best = None
    for box in boxes.values():
        if module == box.module or module.startswith(box.module + "."):
            if best is None or len(box.module) > len(boxes[best].module):
                best = box.name
    return best


def discover_edges(boxes: dict[str, Box], root: Path = ROOT, with_modules: bool = False):
    """The import edges between boxes, sorted; self-imports left out.

    Returns a list of Edge, or with ``with_modules`` a dict Edge -> {module of
    the source box that makes it: whether its imports are all lazy}.
    """
    root = Path(root)
    found: dict[tuple[str, str], dict[str, bool]] = {}   # (source, target) -> {module: lazy}
    for box in boxes.values():
        for path in box.files:
            module = module_of(path, root)[0]
            for name, lazy in imported_modules(path, root):
                target = box_of(name, boxes)
                if target is None or target == box.name:
                    continue
                seen = found.setdefault((box.name, target), {})
                seen[module] = seen.get(module, True) and lazy
    edges = {Edge(s, t, all(mods.values())): dict(sorted(mods.items()))
             for (s, t), mods in sorted(found.items())}
    return edges if with_modules else list(edges)


def describe(boxes: dict[str, Box], edges: list[Edge]) -> str:
    """The picture's content as text: what ``docs/architecture.txt`` holds."""
    lines = [f"# headplod architecture, drawn in {PNG.as_posix()}; written by {REGENERATE}.",
             "# box NAME  LABEL  | first docstring line",
             "# edge SOURCE -> TARGET  import|lazy   (SOURCE imports from TARGET; lazy: only inside functions)"]
    for box in boxes.values():
        lines.append(f"box {box.name}  {box.label}  | {box.summary}")
    for e in edges:
        lines.append(f"edge {e.source} -> {e.target}  {'lazy' if e.lazy else 'import'}")
    return "\n".join(lines) + "\n"


def digest(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def check(root: Path = ROOT, current: str | None = None) -> str | None:
    """None when docs/ matches the tree, else a one-line reason.

    current : :func:`describe` of the tree, when the caller has it already.
    """
    root = Path(root)
    png, txt = root / PNG, root / TXT
    if not png.exists() or not txt.exists():
        return f"{PNG.as_posix()} or {TXT.as_posix()} is missing; run {REGENERATE}"
    if current is None:
        boxes = discover_boxes(root)
        current = describe(boxes, discover_edges(boxes, root))
    stored = txt.read_text(encoding="utf-8")
    if stored != current:
        old, new = set(stored.splitlines()) - {""}, set(current.splitlines()) - {""}
        changes = [f"-{l}" for l in sorted(old - new)] + [f"+{l}" for l in sorted(new - old)]
        first = f", e.g. {changes[0]!r}" if changes else ""
        return f"{PNG.as_posix()} is stale ({len(changes)} lines differ from the tree{first}); run {REGENERATE}"
    from PIL import Image
    with Image.open(png) as image:
        stamped = image.info.get(DIGEST_KEY)
    if stamped != digest(current):
        return f"{PNG.as_posix()} was not drawn from {TXT.as_posix()}; run {REGENERATE}"
    return None


def place(boxes: dict[str, Box]) -> dict[str, tuple[float, int]]:
    """(column, row) of every box: PLACES, unknown ones left to right in the 'other' row."""
    where = {name: PLACES[name] for name in boxes if name in PLACES}
    others = [name for name in boxes if name not in PLACES]
    for i, name in enumerate(others):
        where[name] = (i, OTHER_ROW)
    return where


def bend(p0, p1, rects, area, rads=(0.0, 0.08, -0.08, 0.16, -0.16, 0.25, -0.25, 0.35, -0.35, 0.5, -0.5, 0.7, -0.7)):
    """The arc3 ``rad`` of an arrow from p0 to p1 that crosses the fewest rects.

    The arrow is matplotlib's arc3 curve: a quadratic Bezier whose control
    point is the chord's midpoint moved by ``rad`` times the chord, turned
    -90°.  The first rad of ``rads`` that misses every rect and stays in area
    wins, else the one with the fewest samples inside rects or outside area.
    p0, p1 : (x, y) inches; rects, area : (x0, y0, x1, y1) inches; rects
    without the two end boxes.
    """
    ax0, ay0, ax1, ay1 = area
    (x0, y0), (x1, y1) = p0, p1
    best, best_hits = rads[0], None
    for rad in rads:
        cx, cy = (x0 + x1) / 2 + rad * (y1 - y0), (y0 + y1) / 2 - rad * (x1 - x0)
        hits = 0
        for i in range(1, 80):
            t = i / 80
            x = (1 - t) ** 2 * x0 + 2 * (1 - t) * t * cx + t * t * x1
            y = (1 - t) ** 2 * y0 + 2 * (1 - t) * t * cy + t * t * y1
            hits += (any(a <= x <= c and b <= y <= d for a, b, c, d in rects)
                     or not (ax0 <= x <= ax1 and ay0 <= y <= ay1))
        if hits == 0:
            return rad
        if best_hits is None or hits < best_hits:
            best, best_hits = rad, hits
    return best


def draw(boxes: dict[str, Box], edges: list[Edge], out: Path, stamp: str) -> None:
    """Draw the boxes and arrows into a PNG of SIZE_PX, with ``stamp`` in its metadata."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    where = place(boxes)
    rows = sorted({r for _, r in where.values()}, reverse=True)
    columns = max(c for c, _ in where.values()) + 1
    width, height = SIZE_PX[0] / DPI, SIZE_PX[1] / DPI     # inches; axes in inches, equal scale
    fig = plt.figure(figsize=(width, height), dpi=DPI)
    ax = fig.add_axes([0, 0, 1, 1])
    ax.set_xlim(0, width)
    ax.set_ylim(0, height)
    ax.axis("off")

    # Columns spread over the width, rows over the height below the title; a
    # box is 72% of its cell's width and 55% of its height, which leaves the
    # gaps the arrows are routed through.
    left, right, top, bottom = 0.55, 0.1, 0.8, 0.15
    cell_w = (width - left - right) / columns
    cell_h = (height - top - bottom) / len(rows)
    box_w, box_h = 0.72 * cell_w, 0.55 * cell_h
    centre = {name: (left + (c + 0.5) * cell_w, height - top - (rows.index(r) + 0.5) * cell_h)
              for name, (c, r) in where.items()}
    rect = {name: (x - box_w / 2, y - box_h / 2, x + box_w / 2, y + box_h / 2)
            for name, (x, y) in centre.items()}
    fill = {2: "#fdebd0", 1: "#dceafa", 0: "#e0f2dc", OTHER_ROW: "#f6d5d5"}
    palette = plt.get_cmap("tab10").colors + plt.get_cmap("Dark2").colors
    colour = {name: palette[i % len(palette)] for i, name in enumerate(boxes)}

    ax.text(0.15, height - 0.3, "headplod: one box per package, one arrow per import dependency",
            fontsize=16, weight="bold", va="center")
    ax.text(0.15, height - 0.62,
            f"A → B: a module of A imports from B (arrow in A's colour).   solid: imported at load;   "
            f"dashed: only inside functions.   Drawn from the tree by {REGENERATE}.",
            fontsize=10, va="center", color="#333")
    for r in rows:
        y = height - top - (rows.index(r) + 0.5) * cell_h
        ax.text(0.25, y, ROW_NAMES.get(r, str(r)), fontsize=11, style="italic", color="#555",
                va="center", ha="center", rotation=90)

    patches = {}
    chars = max(12, int(box_w * 72 / (8.5 * 0.6)))      # a character is ~0.55 em at 8.5 pt, and a margin
    for name, box in boxes.items():
        x, y = centre[name]
        row = where[name][1]
        outside = not box.module.startswith(PACKAGE + ".")
        patch = FancyBboxPatch((x - box_w / 2, y - box_h / 2), box_w, box_h,
                               boxstyle="round,pad=0,rounding_size=0.08", fc=fill.get(row, fill[OTHER_ROW]),
                               ec=colour[name], lw=2.5, linestyle="--" if outside else "-", zorder=3)
        ax.add_patch(patch)
        patches[name] = patch
        ax.text(x, y + box_h / 2 - 0.2, box.label, ha="center", va="center", fontsize=13,
                weight="bold", zorder=4)
        summary = textwrap.fill(box.summary or "(no docstring)", chars)
        if outside:
            summary += "\n(top level)"
        ax.text(x, y + box_h / 2 - 0.4, summary, ha="center", va="top", fontsize=8.5,
                color="#222" if box.summary else "#b00000", zorder=4, linespacing=1.2)

    pairs = {(e.source, e.target) for e in edges}
    for e in edges:
        others = [(x0 - 0.1, y0 - 0.1, x1 + 0.1, y1 + 0.1)     # keep 0.1 inch clear of other boxes
                  for n, (x0, y0, x1, y1) in rect.items() if n not in (e.source, e.target)]
        # An arrow whose reverse also exists starts bent, so the two separate.
        rads = (0.15, 0.25, 0.35, 0.5) if (e.target, e.source) in pairs else None
        area = (0.4, 0.05, width - 0.05, height - top + 0.1)    # below the title, right of the row names
        rad = bend(centre[e.source], centre[e.target], others, area, *([rads] if rads else []))
        arrow = FancyArrowPatch(centre[e.source], centre[e.target], patchA=patches[e.source],
                                patchB=patches[e.target], arrowstyle="-|>", mutation_scale=15, lw=1.4,
                                linestyle=(0, (4, 2.5)) if e.lazy else "-", color=colour[e.source],
                                alpha=0.9, connectionstyle=f"arc3,rad={rad}", zorder=2,
                                shrinkA=1, shrinkB=1)
        ax.add_patch(arrow)

    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI, metadata={DIGEST_KEY: stamp})
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="exit 1 if docs/architecture.png does not match the tree")
    parser.add_argument("--list", action="store_true",
                        help="print the edges and the modules that make them, draw nothing")
    parser.add_argument("--root", type=Path, default=ROOT, help="repository root (default: %(default)s)")
    args = parser.parse_args(argv)
    root = args.root
    if args.check:
        problem = check(root)
        if problem:
            print(problem, file=sys.stderr)
            return 1
        print(f"{PNG.as_posix()} matches the tree")
        return 0
    boxes = discover_boxes(root)
    edges = discover_edges(boxes, root, with_modules=True)
    if args.list:
        for e, modules in edges.items():
            made_by = ", ".join(m + (" (lazy)" if lazy else "") for m, lazy in modules.items())
            print(f"{e.source} -> {e.target}  {'lazy' if e.lazy else 'import'}: {made_by}")
        return 0
    text = describe(boxes, list(edges))
    draw(boxes, list(edges), root / PNG, digest(text))
    (root / TXT).write_text(text, encoding="utf-8")
    print(f"wrote {PNG.as_posix()} and {TXT.as_posix()}: {len(boxes)} boxes, {len(edges)} edges")
    return 0


if __name__ == "__main__":
    sys.exit(main())
