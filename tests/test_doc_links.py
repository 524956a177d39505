"""The repository stands on its own: its Markdown never points outside it, and every relative link exists."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "calib" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _links(page):
    return [m.group(1) for m in LINK.finditer(page.read_text())]


def test_every_relative_link_exists_inside_the_repository():
    broken = []
    for page in PAGES:
        for target in _links(page):
            if re.match(r"^[a-z]+://", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#")[0]).resolve()
            if not path.exists() or ROOT not in (path, *path.parents):
                broken.append((page.relative_to(ROOT).as_posix(), target))
    assert broken == []


def test_no_page_names_a_path_outside_the_repository():
    outside = [(page.relative_to(ROOT).as_posix(), hit) for page in PAGES
               for hit in re.findall(r"(?:\.\./shared|/work/)[^\s`)]*", page.read_text())]
    assert outside == []


def test_the_pages_are_found():
    names = {p.name for p in PAGES}
    assert {"README.md", "contract.md", "plod-criteria.md", "plod-judge.md"} <= names
