"""Per-frame warnings of a run, reported without flooding: the first of each kind in full, then a count.

A frame that was still usable may carry a ``warning`` (:class:`io.Frame
<headplod.io.Frame>`): a colour image converted to gray, a time interpolated
because ``times.csv`` has no row for it. A sequence of colour images gives
the same warning on every frame; :class:`FrameNotes` shows its first
occurrence, counts the others and says how many at the end of the run::

    warning: frame 0: left/000000.png: 3-channel image converted to gray, expected 8-bit grayscale
      (later frames with this warning are counted, not shown)
    ...
    warning: 120 of 120 frames: left/NNNNNN.png: 3-channel image converted to gray, expected 8-bit grayscale
"""
from __future__ import annotations

import re
import sys
from typing import TextIO

__all__ = ["FrameNotes", "split_frame_warning", "warning_kind"]

# A frame's warning joins its parts with "; " (io.Dataset.frame); a part about an image starts with its file.
_IMAGE_PART = re.compile(r"; (?=(?:left|right)/[0-9]{6}\.png: )")
_FRAME_FILE = re.compile(r"\b[0-9]{6}\.png\b")


def split_frame_warning(warning: str | None) -> list[str]:
    """The separate notes of one frame's ``warning`` (``[]`` for None or empty).

    ``io.Dataset`` joins a frame's notes with ``"; "``; a note about an image
    starts with its file name (``"left/000003.png: ..."``), and a note may
    itself hold ``"; "``, so the text is split only before an image's name.
    """
    if not warning:
        return []
    return [part.strip() for part in _IMAGE_PART.split(warning) if part.strip()]


def warning_kind(note: str) -> str:
    """What makes two notes the same warning: the note with its frame's file index written NNNNNN.

    ``"left/000003.png: 3-channel image converted ..."`` and
    ``"left/000004.png: 3-channel image converted ..."`` are one kind
    (``"left/NNNNNN.png: 3-channel image converted ..."``).
    """
    return _FRAME_FILE.sub("NNNNNN.png", note)


class FrameNotes:
    """Collect the per-frame warnings of a run; show the first of each kind, count the rest.

    Parameters
    ----------
    stream : text stream, optional
        Where the first occurrences and the summary are written (default
        standard error); ``None`` to write nothing (only count).

    Attributes
    ----------
    kinds : dict
        kind (:func:`warning_kind`) -> ``[first note, frame of the first
        note, number of frames]``, in the order first seen.
    frames : int
        Frames seen by :meth:`add`.
    """

    def __init__(self, stream: TextIO | None = sys.stderr):
        self.stream = stream
        self.kinds: dict[str, list] = {}
        self.frames = 0

    def add(self, index: int, warning: str | None) -> list[str]:
        """Account for one frame's ``warning``; return its notes (for the record's ``flags``).

        The first note of a kind is written at once, in full; later ones only
        add to the count.
        """
        self.frames += 1
        notes = split_frame_warning(warning)
        for note in notes:
            kind = warning_kind(note)
            seen = self.kinds.get(kind)
            if seen is not None:
                seen[2] += 1
                continue
            self.kinds[kind] = [note, index, 1]
            self._write(f"warning: frame {index}: {note} (later frames with this warning are counted, not shown)")
        return notes

    def summary(self) -> list[str]:
        """One line per kind seen: in how many frames of the run it occurred."""
        return [f"warning: {count} of {self.frames} frames: {kind}" + ("" if count > 1 else f" (frame {index})")
                for kind, (_, index, count) in self.kinds.items()]

    def report(self) -> None:
        """Write :meth:`summary` to the stream (nothing when there was no warning)."""
        for line in self.summary():
            self._write(line)

    def _write(self, line: str) -> None:
        if self.stream is not None:
            print(line, file=self.stream, flush=True)
