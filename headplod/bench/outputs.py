"""The benchmarks' result files: JSON written whole or not at all, into a folder made if missing."""
from __future__ import annotations

import json
from pathlib import Path

from ..io import write_atomically

__all__ = ["write_json"]


def write_json(path, data, indent: int = 2, default=None) -> Path:
    """Write ``data`` as JSON to ``path`` (its folder made if missing), atomically; the path.

    ``default``: :func:`json.dumps`'s, for values JSON does not know (e.g. ``float`` for numpy scalars).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=indent, default=default)
    return write_atomically(path, lambda name: Path(name).write_text(text))
