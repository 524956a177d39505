"""Progress of a long run on standard error: one updating line on a terminal, plain lines otherwise.

Shared by every stage that loops over frames (rendering a synthetic
sequence, tracking a dataset, the benchmarks, the headless demo); it imports
nothing from ``headplod``, so any of them can use it.
"""
from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """A one-line progress display on a terminal, plain lines otherwise."""

    def __init__(self, total: int, label: str, stream=sys.stderr, every_s: float = 0.5):
        self.total, self.label, self.stream = total, label, stream
        self.every_s = every_s
        self.count = 0
        self.start = time.perf_counter()
        self._last = 0.0
        self._tty = hasattr(stream, "isatty") and stream.isatty()

    def step(self, note: str = "") -> None:
        self.count += 1
        now = time.perf_counter()
        if now - self._last < self.every_s and self.count < self.total:
            return
        self._last = now
        rate = self.count / max(now - self.start, 1e-9)
        text = f"{self.label}: {self.count}/{self.total} ({rate:.0f}/s) {note}"
        if self._tty:
            self.stream.write("\r" + text[:150].ljust(150))
            if self.count >= self.total:
                self.stream.write("\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
