"""tools/architecture.py: the picture's boxes are the tree's packages, and docs/ is up to date.

The discovery functions are imported and run directly; nothing is drawn here
(``--check`` compares the edge list and the PNG's stamp, it does not render).
"""
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _load():
    spec = importlib.util.spec_from_file_location("architecture", ROOT / "tools" / "architecture.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("architecture", module)    # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


arch = _load()


@pytest.fixture(scope="module")
def tree():
    """The repository's boxes and edges, read once (parsing every module is most of the time)."""
    boxes = arch.discover_boxes(ROOT)
    return boxes, arch.discover_edges(boxes, ROOT)


@pytest.mark.slow
def test_every_package_folder_is_a_box(tree):
    boxes, _ = tree
    folders = {p.parent.name for p in (ROOT / "headplod").glob("*/__init__.py")}
    assert folders, "no package folder found under headplod/"
    missing = folders - set(boxes)
    assert not missing, f"folders of headplod/ without a box: {sorted(missing)}"
    for name in ("io", "cli", "synthetic", "calib"):
        assert name in boxes, f"{name} is not a box; boxes: {sorted(boxes)}"


def test_edges_are_between_boxes(tree):
    boxes, edges = tree
    assert edges, "no import edge found"
    for e in edges:
        assert e.source in boxes and e.target in boxes and e.source != e.target, e
    # synthetic/ never imports headplod (its README promise), so no edge leaves it.
    assert not [e for e in edges if e.source == "synthetic"]


def test_check_passes_on_the_committed_picture(tree):
    problem = arch.check(ROOT, arch.describe(*tree))
    assert problem is None, problem


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def _stamp_png(path, text):
    """A 1x1 PNG carrying the digest, as draw() would write it, without matplotlib."""
    from PIL import Image, PngImagePlugin
    info = PngImagePlugin.PngInfo()
    info.add_text(arch.DIGEST_KEY, arch.digest(text))
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.new("RGB", (1, 1)).save(path, pnginfo=info)


def test_relative_lazy_imports_and_a_stale_picture(tmp_path):
    _write(tmp_path / "headplod" / "__init__.py", "")
    _write(tmp_path / "headplod" / "io.py", '"""Files."""\n')
    _write(tmp_path / "headplod" / "a" / "__init__.py", '"""Stage A.\n\nMore."""\nfrom .x import f\n')
    _write(tmp_path / "headplod" / "a" / "x.py", "from .. import io\n\ndef f():\n    from ..b.y import g\n")
    _write(tmp_path / "headplod" / "b" / "__init__.py", "")
    _write(tmp_path / "headplod" / "b" / "y.py", "import headplod.a.x\nfrom shared import z\n")
    _write(tmp_path / "shared" / "__init__.py", '"""Top level."""\n')
    _write(tmp_path / "tests" / "test_x.py", "import headplod\n")       # tests/ is no box

    boxes = arch.discover_boxes(tmp_path)
    assert sorted(boxes) == ["a", "b", "io", "shared"]
    assert boxes["a"].summary == "Stage A." and boxes["b"].summary == ""
    edges = {(e.source, e.target): e.lazy for e in arch.discover_edges(boxes, tmp_path)}
    assert edges == {("a", "io"): False, ("a", "b"): True, ("b", "a"): False, ("b", "shared"): False}

    assert "missing" in arch.check(tmp_path)
    text = arch.describe(boxes, arch.discover_edges(boxes, tmp_path))
    _write(tmp_path / arch.TXT, text)
    _stamp_png(tmp_path / arch.PNG, text)
    assert arch.check(tmp_path) is None

    _write(tmp_path / "headplod" / "io.py", '"""Files."""\nfrom .a import x\n')
    problem = arch.check(tmp_path)
    assert problem and "stale" in problem and "edge io -> a" in problem and "\n" not in problem
    assert arch.main(["--check", "--root", str(tmp_path)]) == 1

    _write(tmp_path / arch.TXT, arch.describe(boxes, arch.discover_edges(boxes, tmp_path)))
    problem = arch.check(tmp_path)        # the text is new, the picture is not
    assert problem and "was not drawn from" in problem

