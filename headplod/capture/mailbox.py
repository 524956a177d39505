"""Capture that does not wait on the tracker: a drop-oldest mailbox and the thread that fills it.

A live camera keeps delivering while a frame is tracked. :class:`CaptureThread`
reads a :class:`~headplod.capture.base.FrameSource` in a thread of its own
(OpenCV's grab and decode and numpy release the GIL, so reading goes on while
the tracker computes) and puts every frame into a :class:`FrameMailbox` of one
slot (or a few): a frame that arrives while the slot is full pushes the oldest
one out. The tracking loop takes what is there, so it always tracks the newest
pair and never a stale backlog; every frame pushed out is counted, and the
next frame taken carries the count (``CaptureFrame.dropped_busy``).

:class:`CaptureThread` is itself a frame source (``read(timeout_s)``), so the
one per-frame loop (:func:`headplod.live.loop.track_frames`) reads it as it
reads any source. Only live cameras and a real-time replay go through it
(``FrameSource.realtime``); a replay for accuracy reads its source directly,
every frame in order.

Nothing here asserts or depends on timing: the mailbox's clock is injectable,
and which frames are pushed out follows from the order of ``put`` and ``get``
alone.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from typing import Any, Callable, NamedTuple

from .base import CaptureFrame

__all__ = ["FrameMailbox", "Delivery", "CaptureThread"]

#: How often a wait for a frame wakes to poll ``stop()`` when nothing arrives, s: a Ctrl-C is seen
#: within this even when the source delivers nothing (a signal handler runs, then the wait goes on).
POLL_S = 0.05


class Delivery(NamedTuple):
    """An item taken from a :class:`FrameMailbox`.

    Attributes
    ----------
    item
        What was put.
    put_s : float
        The mailbox's clock when it was put, s (``time.monotonic()`` unless injected).
    dropped : int
        Items pushed out of the mailbox since the previous item taken (all of them older than this one).
    lost : int
        The producer's own losses carried by this item and by the items pushed out before it (the ``lost``
        given to :meth:`FrameMailbox.put`), so that no loss disappears with a dropped item.
    """

    item: Any
    put_s: float
    dropped: int
    lost: int


class FrameMailbox:
    """A bounded mailbox between one producer and one consumer that drops the oldest item when full.

    Parameters
    ----------
    capacity : int
        Items it holds (>= 1). One: the consumer always takes the newest item.
    clock : callable() -> float, optional
        Stamps each item when it is put, s (default ``time.monotonic``).

    Notes
    -----
    ``put`` never blocks: when the mailbox is full, the oldest item is pushed out and its count (and its
    ``lost``) passes to the item after it. ``get`` blocks up to a timeout. After :meth:`close`, ``put`` refuses
    items and ``get`` returns what is left, then ``None`` at once (:attr:`finished`). Thread-safe.
    """

    def __init__(self, capacity: int = 1, clock: Callable[[], float] | None = None):
        if int(capacity) != capacity or capacity < 1:
            raise ValueError(f"capacity must be an integer >= 1, got {capacity!r}")
        self.capacity = int(capacity)
        self._clock = clock or time.monotonic
        self._cond = threading.Condition()
        self._items: deque[list] = deque()       # [item, put_s, dropped before it, lost]
        self._closed = False
        self.put_count = 0
        self.taken = 0
        self.dropped = 0

    def put(self, item: Any, lost: int = 0) -> bool:
        """Add ``item`` (with ``lost``: items the producer lost just before it); False when closed.

        When the mailbox is full, its oldest item is pushed out: counted in :attr:`dropped` and in the next
        item's ``Delivery.dropped``.
        """
        with self._cond:
            if self._closed:
                return False
            self._items.append([item, self._clock(), 0, int(lost)])
            self.put_count += 1
            while len(self._items) > self.capacity:
                _, _, dropped, old_lost = self._items.popleft()
                self._items[0][2] += dropped + 1
                self._items[0][3] += old_lost
                self.dropped += 1
            self._cond.notify_all()
            return True

    def get(self, timeout_s: float | None = None) -> Delivery | None:
        """The oldest item held, waiting up to ``timeout_s`` s (None: no limit); None on timeout or once
        :attr:`finished`."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._items or self._closed, timeout_s):
                return None
            if not self._items:
                return None
            item, put_s, dropped, lost = self._items.popleft()
            self.taken += 1
            return Delivery(item, put_s, dropped, lost)

    def close(self) -> None:
        """Refuse further items and wake a waiting ``get``; idempotent. Items held can still be taken."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def finished(self) -> bool:
        """Closed and empty: ``get`` returns None at once from now on."""
        with self._cond:
            return self._closed and not self._items

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


class CaptureThread:
    """Reads a frame source in a thread into a drop-oldest :class:`FrameMailbox`; read like a source.

    Parameters
    ----------
    source : FrameSource
        Read with ``source.read(timeout_s)`` in the thread, as fast as it delivers, until it returns None,
        raises, or this is closed.
    capacity : int
        The mailbox's slots (1: the tracker always takes the newest frame).
    timeout_s : float
        The timeout of the thread's reads (a live source's stall report), s.
    stop : callable() -> bool, optional
        Polled every :data:`POLL_S` while :meth:`read` waits: when it is true, ``read`` returns None (the
        run stops, as when the loop polls it between frames).
    clock : callable() -> float, optional
        The mailbox's clock (``time.monotonic`` by default), s: a frame's ``t_delivered`` when the source
        gives no capture time.
    join_s : float, optional
        How long :meth:`close` waits for the thread, s (default ``timeout_s + 1``: a read ends within its
        timeout).

    Attributes
    ----------
    mailbox : FrameMailbox
    failure : BaseException or None
        What the source raised in the thread; :meth:`read` raises it in the caller's thread once the frames
        before it are taken.
    stuck : bool
        True when :meth:`close` could not join the thread within ``join_s`` (a read blocked in a driver; the
        thread is a daemon and ends with the read).

    Notes
    -----
    :meth:`read` returns each frame taken from the mailbox with ``dropped_busy`` (frames pushed out before it
    while the tracker was busy) and ``dropped`` increased by the source's own losses of the frames pushed out;
    a frame without a capture time (replay) gets ``t_delivered``, when the thread put it into the mailbox.
    The thread starts on construction and is joined by :meth:`close` (``with CaptureThread(...)``). The name,
    rig, markers and screen are the source's.
    """

    def __init__(self, source, capacity: int = 1, timeout_s: float = 1.0, *,
                 stop: Callable[[], bool] | None = None, clock: Callable[[], float] | None = None,
                 join_s: float | None = None):
        self.source = source
        self.mailbox = FrameMailbox(capacity, clock=clock)
        self.timeout_s = float(timeout_s)
        self.join_s = self.timeout_s + 1.0 if join_s is None else float(join_s)
        self._stop_reading = threading.Event()
        self._poll_stop = stop
        self.failure: BaseException | None = None
        self.stuck = False
        self._thread = threading.Thread(target=self._run, name="headplod-capture-mailbox", daemon=True)
        self._thread.start()

    def __getattr__(self, name: str) -> Any:     # name, rig, markers, screen, status(), ...: the source's
        if name == "source":
            raise AttributeError(name)
        return getattr(self.source, name)

    def _run(self) -> None:
        try:
            while not self._stop_reading.is_set():
                frame = self.source.read(timeout_s=self.timeout_s)
                if frame is None:
                    return
                if not self.mailbox.put(frame, lost=int(getattr(frame, "dropped", 0) or 0)):
                    return
        except BaseException as exc:              # noqa: BLE001 - handed to the reading thread, never lost
            self.failure = exc
        finally:
            self.mailbox.close()

    def read(self, timeout_s: float | None = None) -> CaptureFrame | None:
        """The oldest frame the mailbox holds (the newest captured, with one slot); None once the source has
        ended (or ``stop()`` is true). Waits as long as it takes: the source's own reads report stalls.

        Raises
        ------
        BaseException
            What the source raised in the thread, once the frames before it are taken.
        """
        while True:
            got = self.mailbox.get(POLL_S)
            if got is not None:
                return self._frame(got)
            if self.mailbox.finished:
                if self.failure is not None:
                    raise self.failure
                return None
            if self._poll_stop is not None and self._poll_stop():
                return None

    @staticmethod
    def _frame(got: Delivery) -> Any:
        frame = got.item
        if not isinstance(frame, CaptureFrame):
            frame = CaptureFrame.from_frame(frame)
        # ``lost`` is the frame's own ``dropped`` plus that of the frames pushed out before it
        changes: dict[str, Any] = {"dropped_busy": got.dropped, "dropped": got.lost}
        if frame.t_monotonic_left is None:
            changes["t_delivered"] = got.put_s
        return dataclasses.replace(frame, **changes)

    @property
    def alive(self) -> bool:
        """Whether the thread is still running (reading, or blocked in the source)."""
        return self._thread.is_alive()

    def close(self) -> None:
        """Stop reading and join the thread (within ``join_s``); idempotent. The source is not closed."""
        self._stop_reading.set()
        self.mailbox.close()
        if self._thread is not threading.current_thread():
            self._thread.join(self.join_s)
            self.stuck = self._thread.is_alive()

    def __enter__(self) -> "CaptureThread":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
