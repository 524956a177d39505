"""Ctrl-C, SIGTERM and SIGHUP as a clean stop, and sections of work that a signal does not cut.

:class:`StopSignals` (a ``with`` block around a recording or tracking loop):
SIGINT, SIGTERM and SIGHUP (the terminal that started the run closed) set a
flag that the loop polls between frames, instead of raising
``KeyboardInterrupt`` (SIGINT) or killing the process (SIGTERM, SIGHUP) in
the middle of a write. A second signal while the flag is set raises
``KeyboardInterrupt``: a user who insists gets out. Once the run is closing
its outputs (:meth:`StopSignals.finishing`), further signals are only
noted: the closes are short and must not be cut.

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
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

_NAMES = {signal.SIGINT: "Ctrl-C", signal.SIGTERM: "SIGTERM", signal.SIGHUP: "SIGHUP, the terminal closed"}


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
        self.insisted = False
        self._finishing = False
        self._previous: dict = {}

    def _handle(self, signum, frame) -> None:
        if self.received is not None:
            self.insisted = True
            if not self._finishing:
                raise KeyboardInterrupt     # a second signal: the user insists
            return
        self.received = signum

    def finishing(self) -> None:
        """From now on (the outputs are being closed), a signal is noted and never raises."""
        self._finishing = True

    def __call__(self) -> bool:
        return self.received is not None

    @property
    def name(self) -> str | None:
        """``"Ctrl-C"``, ``"SIGTERM"`` or ``"SIGHUP, the terminal closed"`` once a signal came, else None."""
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
