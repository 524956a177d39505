"""The benchmarks' result files: JSON, charts and pictures, each written into a folder made if missing, whole or
not at all (:func:`~headplod.io.write_atomically`: a special file is never written over)."""
from __future__ import annotations

import json
from pathlib import Path

from ..io import write_atomically, write_image

__all__ = ["write_json", "write_png", "pyplot", "save_figure"]


def write_json(path, data, indent: int = 2, default=None) -> Path:
    """Write ``data`` as JSON to ``path`` (its folder made if missing), atomically; the path.

    ``default``: :func:`json.dumps`'s, for values JSON does not know (e.g. ``float`` for numpy scalars).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(data, indent=indent, default=default)
    return write_atomically(path, lambda name: Path(name).write_text(text))


def write_png(path, image_rgb) -> str:
    """Write an (H, W, 3) uint8 RGB image as PNG (or the format of the ending); the path as text."""
    import cv2

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bgr = cv2.cvtColor(image_rgb, cv2.COLOR_RGB2BGR)
    write_atomically(path, lambda name: write_image(name, bgr, ending=path.suffix), suffix=path.suffix)
    return str(path)


def pyplot():
    """``matplotlib.pyplot`` drawing off screen (imported on use: slow to import)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path, dpi: int = 100, rect=None) -> Path:
    """Lay out ``fig`` (within ``rect``, figure fractions), write it to ``path`` (its folder made if missing) and
    close it; the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout(**({} if rect is None else {"rect": rect}))
    try:
        write_atomically(path, lambda name: fig.savefig(name, dpi=dpi, format=path.suffix.lstrip(".") or "png"),
                         suffix=path.suffix)
    finally:
        pyplot().close(fig)
    return path
