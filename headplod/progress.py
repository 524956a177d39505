"""Progress of a long run on standard error, drawn by tqdm: a bar on a terminal, plain lines otherwise.

Shared by every stage that loops over frames (rendering a synthetic
sequence, the benchmarks, the headless demo, board detection in
``headplod calibrate``); it imports nothing from ``headplod``, so any of them
can use it. Each update shows what is being done (the label and the last
note), the count against the total and the rate. A command's ``-q`` /
``--quiet`` makes it silent (``disable=True``, or no Progress at all); the
command line also sets it for the whole run (:func:`quiet`, from
``headplod/cli.py``), so every Progress and :func:`note` of a command run with
``-q`` is silent, however deep in the command it is made.
"""
from __future__ import annotations

import contextlib
import sys

from tqdm import tqdm

__all__ = ["Progress", "quiet", "is_quiet", "note"]

#: The running command's ``-q`` (:func:`quiet`): no progress and no notes on standard error.
_QUIET = [False]


@contextlib.contextmanager
def quiet(on: bool = True):
    """While the block runs, every :class:`Progress` is disabled and :func:`note` prints nothing (a command's
    ``-q``; errors and the command's requested output are not affected)."""
    before = _QUIET[0]
    _QUIET[0] = bool(on) or before
    try:
        yield
    finally:
        _QUIET[0] = before


def is_quiet() -> bool:
    """Whether the running command was given ``-q`` (:func:`quiet`)."""
    return _QUIET[0]


def note(text: str, stream=None) -> None:
    """A line of progress or a note on standard error (or ``stream``), unless the command runs ``-q``."""
    if not _QUIET[0]:
        print(text, file=sys.stderr if stream is None else stream, flush=True)


class _Lines:
    """A text stream for tqdm that turns its carriage-return redraws into one line each (logs, pipes)."""

    def __init__(self, stream):
        self.stream = stream
        self.encoding = getattr(stream, "encoding", None)

    def write(self, text: str) -> None:
        for part in text.replace("\r", "\n").split("\n"):
            if part.strip():
                self.stream.write(part.rstrip() + "\n")

    def flush(self) -> None:
        if hasattr(self.stream, "flush"):
            self.stream.flush()


class Progress:
    """Progress of ``total`` steps: :meth:`step` after each, :meth:`close` (or the last step) at the end.

    Parameters
    ----------
    total : int or None
        Number of steps; 0 or None while unknown (it may be set later through
        :attr:`total`).
    label : str
        What is being done (``render looking_around``, ``demo``).
    stream : text stream, optional
        Where to write (default: standard error as it is when the display starts). On a terminal one line
        redraws itself; otherwise (a pipe, a log file) each update is a line.
    every_s : float
        Least time between two updates, s.
    unit : str
        What a step is (``frame``, ``pair``), for the rate.
    disable : bool
        Show nothing (``--quiet``).
    """

    def __init__(self, total: int | None, label: str, stream=None, every_s: float = 0.5,
                 unit: str = "it", disable: bool = False):
        stream = sys.stderr if stream is None else stream      # the stderr of the moment (tests capture it)
        disable = disable or _QUIET[0]
        tty = hasattr(stream, "isatty") and stream.isatty()
        self._bar = tqdm(total=total or None, desc=label, unit=unit, file=stream if tty else _Lines(stream),
                         mininterval=every_s, maxinterval=max(every_s, 10.0), dynamic_ncols=tty,
                         ncols=None if tty else 100, disable=disable, leave=True)

    @property
    def total(self) -> int | None:
        return self._bar.total

    @total.setter
    def total(self, value: int | None) -> None:
        if value != self._bar.total:
            self._bar.total = value or None
            self._bar.refresh()

    def step(self, note: str = "") -> None:
        """One step done; ``note`` says what (shown after the rate). The last step closes the display."""
        if note:
            self._bar.set_postfix_str(note, refresh=False)
        self._bar.update(1)
        if self._bar.total and self._bar.n >= self._bar.total:
            self.close()

    def close(self) -> None:
        """End the display (its final state and a newline); idempotent."""
        self._bar.close()

