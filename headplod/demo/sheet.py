"""The demo's index picture: a contact sheet of its pictures, each under a title and a line saying what it is.

A newcomer opens one file (``out/demo/index.png``) and learns which picture shows what. Pure OpenCV drawing on
RGB arrays: (H, W, 3) uint8, row 0 at the top.
"""
from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

__all__ = ["SheetEntry", "contact_sheet"]

_BACKGROUND = (32, 32, 36)
_TITLE = (255, 255, 255)
_WORDS = (200, 200, 200)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


class SheetEntry(NamedTuple):
    """One picture of the sheet: its ``title`` (the file's name, say), ``words`` (what it shows, one or more
    sentences; wrapped to the cell) and the ``image`` ((H, W, 3) uint8 RGB)."""

    title: str
    words: str
    image: np.ndarray


def _wrap(text: str, width_px: int, scale: float) -> list[str]:
    """``text`` broken into lines no wider than ``width_px`` at font ``scale``."""
    lines, line = [], ""
    for word in text.split():
        trial = f"{line} {word}".strip()
        if line and cv2.getTextSize(trial, _FONT, scale, 1)[0][0] > width_px:
            lines.append(line)
            line = word
        else:
            line = trial
    return lines + ([line] if line else [])


def contact_sheet(entries, heading: str = "", columns: int = 2, cell_px: int = 640) -> np.ndarray:
    """The pictures of ``entries`` (:class:`SheetEntry`) in a grid of ``columns``, each scaled to ``cell_px``
    wide under its title and words, below a ``heading`` line; (H, W, 3) uint8 RGB."""
    if not entries:
        raise ValueError("contact_sheet: no pictures")
    margin, title_scale, word_scale = 16, 0.7, 0.5
    line_h = 22
    cells = []
    for e in entries:
        h, w = e.image.shape[:2]
        thumb = cv2.resize(np.ascontiguousarray(e.image), (cell_px, max(1, round(h * cell_px / w))),
                           interpolation=cv2.INTER_AREA)
        words = _wrap(e.words, cell_px, word_scale)
        cells.append((e.title, words, thumb))
    text_h = max(line_h * (1 + len(words)) + 8 for _, words, _ in cells)
    cell_h = text_h + max(thumb.shape[0] for *_, thumb in cells)
    rows = -(-len(cells) // columns)
    heading_lines = _wrap(heading, columns * (cell_px + margin) - margin, 0.8) if heading else []
    top = margin + (len(heading_lines) + 1) * line_h if heading else margin
    sheet = np.empty((top + rows * (cell_h + margin), margin + columns * (cell_px + margin), 3), np.uint8)
    sheet[:] = _BACKGROUND
    for i, line in enumerate(heading_lines):
        cv2.putText(sheet, line, (margin, margin + line_h * (i + 1)), _FONT, 0.8, _TITLE, 2, cv2.LINE_AA)
    for k, (title, words, thumb) in enumerate(cells):
        x, y = margin + (k % columns) * (cell_px + margin), top + (k // columns) * (cell_h + margin)
        cv2.putText(sheet, title, (x, y + line_h - 4), _FONT, title_scale, _TITLE, 2, cv2.LINE_AA)
        for i, line in enumerate(words):
            cv2.putText(sheet, line, (x, y + line_h * (i + 2) - 4), _FONT, word_scale, _WORDS, 1, cv2.LINE_AA)
        sheet[y + text_h:y + text_h + thumb.shape[0], x:x + cell_px] = thumb
    return sheet
