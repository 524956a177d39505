"""Size limits of the product's code: a file a reader can hold, a function a reader can follow.

A file of headplod/ is at most MAX_FILE_LINES lines; a function of the stages
that run per frame or per triangle (tracking/, plod/, render/) is at most
MAX_FUNCTION_LINES lines, nested functions counted in their parent.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MAX_FILE_LINES = 800
MAX_FUNCTION_LINES = 100
FUNCTION_LIMITED = ("tracking", "plod", "render")


def _files():
    files = sorted((ROOT / "headplod").rglob("*.py"))
    assert files, "no module found under headplod/"
    return files


def test_no_file_is_over_the_limit():
    long = [f"{p.relative_to(ROOT)}: {n} lines" for p in _files()
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_FILE_LINES]
    assert not long, f"files over {MAX_FILE_LINES} lines (split them into parts):\n" + "\n".join(long)


def long_functions(path: Path, limit: int, root: Path = ROOT) -> list[str]:
    """``path:line name (N lines)`` (``path`` relative to ``root``) of every function or method of ``path``
    longer than ``limit`` lines."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return [f"{path.relative_to(root)}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > limit]


def test_no_function_of_the_per_frame_stages_is_over_the_limit():
    long = [entry for package in FUNCTION_LIMITED for p in sorted((ROOT / "headplod" / package).rglob("*.py"))
            for entry in long_functions(p, MAX_FUNCTION_LINES)]
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines:\n" + "\n".join(long)


def test_the_function_check_sees_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    path = tmp_path / "probe.py"
    path.write_text(f"def long():\n{body}\n\ndef short():\n    return 1\n", encoding="utf-8")
    found = long_functions(path, MAX_FUNCTION_LINES, root=tmp_path)
    assert len(found) == 1 and " long (" in found[0], found
