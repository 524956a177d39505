"""Ctrl-C and SIGTERM as a clean stop, and sections of work that a signal does not cut.

:class:`StopSignals` (a ``with`` block around a recording or tracking loop):
SIGINT and SIGTERM set a flag that the loop polls between frames, instead of
raising ``KeyboardInterrupt`` (SIGINT) or killing the process (SIGTERM) in
the middle of a write. A second signal while the flag is set raises
``KeyboardInterrupt``: a user who insists gets out.

:func:`deferred_signals` (a ``with`` block around one step that must be
whole, e.g. a frame's two images and its ``times.csv`` row): a signal that
arrives inside is held and delivered to the handler in place before, once
the step is done.

Both change signal handlers only in the main thread (the only one where
Python runs them); elsewhere they do nothing.
"""
from __future__ import annotations

import signal
import threading
from contextlib import contextmanager
from typing import Iterator

__all__ = ["StopSignals", "deferred_signals", "STOP_SIGNALS"]

#: The signals that stop a run cleanly.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)

_NAMES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM"}


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class StopSignals:
    """SIGINT and SIGTERM stop a loop cleanly, for the duration of a ``with`` block.

    Call the object (``stop()``) to know whether a signal came; the handlers
    in place before are restored on leaving the block.

    Attributes
    ----------
    received : int or None
        The first signal received (``signal.SIGINT`` or ``signal.SIGTERM``).

    Examples
    --------
    >>> with StopSignals() as stop:                           # doctest: +SKIP
    ...     run_source(source, stop=stop, ...)
    ...     if stop():
    ...         print(f"stopped ({stop.name})")
    """

    def __init__(self):
        self.received: int | None = None
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:
        if self.received is not None:
            raise KeyboardInterrupt         # a second signal: the user insists
        self.received = signum

    def __call__(self) -> bool:
        return self.received is not None

    @property
    def name(self) -> str | None:
        """``"Ctrl-C"`` or ``"SIGTERM"`` once a signal came, else None."""
        return None if self.received is None else _NAMES.get(self.received, f"signal {self.received}")

    def __enter__(self) -> "StopSignals":
        if _main_thread():
            for sig in STOP_SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        self._previous.clear()


@contextmanager
def deferred_signals() -> Iterator[None]:
    """Hold SIGINT and SIGTERM until the block is done, then deliver them to the handlers in place before.

    A step inside runs whole: a Ctrl-C arriving in it raises (or sets a
    :class:`StopSignals` flag) only after it. An exception of the step itself
    still propagates, and a held signal is then delivered too.
    """
    if not _main_thread():
        yield
        return
    held: list[int] = []
    previous = {}

    def hold(signum, frame):
        held.append(signum)

    for sig in STOP_SIGNALS:
        previous[sig] = signal.signal(sig, hold)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        for sig in dict.fromkeys(held):
            signal.raise_signal(sig)        # to the restored handler
