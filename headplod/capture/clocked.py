"""A recording delivered as a camera would: :class:`ClockedReplay`, decoded frames on a fixed clock.

``bench live`` measures the live loop on it: the frames of a recording are decoded beforehand (a camera
delivers images, not PNG files) and released at ``rate_hz`` whatever the reader does, each stamped with the
tick that released it as its capture time. Read by a :class:`~headplod.capture.mailbox.CaptureThread`, like
live cameras, the tracker then takes the newest frame and the ones it had no time for are dropped.
"""
from __future__ import annotations

import math
import time
from typing import Callable, Sequence

from .. import io
from .base import CaptureFrame, FrameSource

__all__ = ["ClockedReplay"]


class ClockedReplay(FrameSource):
    """Frames held in memory, released one per tick of a ``rate_hz`` clock, stamped with the tick.

    Parameters
    ----------
    frames : sequence of io.Frame
        Decoded frames, in order (e.g. ``[dataset.frame(i) for i in dataset.indices]``).
    rate_hz : float
        The camera's frame rate, Hz (> 0).
    rig, markers, screen : optional
        As for any :class:`FrameSource`.
    name : str
        What it replays, for messages.
    clock : callable() -> float, optional
        Monotonic clock, s (default ``time.monotonic``).
    sleep : callable(float), optional
        Waits that many seconds (default ``time.sleep``); injectable with ``clock`` so that tests need no
        real time.

    Notes
    -----
    Frame ``i`` is due at ``start + i / rate_hz``, ``start`` being the clock at the first :meth:`read`;
    ``read`` waits until it is due and returns it with ``t_monotonic_left`` (and ``t_monotonic_right``,
    offset by the recording's left/right difference) at that tick, ``time_source`` ``"clock"``, so latencies
    run from the tick. A reader behind the clock gets the frames that are already due at once, as a camera's
    driver hands over the buffers it filled: the schedule does not restart. ``t`` and ``t_right`` stay the
    recording's (the motion as recorded). Frames with an ``error`` pass as they are.
    """

    kind = "clocked"
    realtime = True

    def __init__(self, frames: Sequence[io.Frame], rate_hz: float, *, rig: io.Rig | None = None,
                 markers: io.MarkerModel | None = None, screen: io.Screen | None = None,
                 name: str = "clocked replay", clock: Callable[[], float] | None = None,
                 sleep: Callable[[float], None] | None = None):
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be a finite number > 0, got {rate_hz!r}")
        super().__init__(f"{name} at {rate_hz:g} Hz", rig, markers, screen)
        self.frames = list(frames)
        self.rate_hz = float(rate_hz)
        self._clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self._next = 0
        self._start: float | None = None

    def read(self, timeout_s: float = 1.0) -> CaptureFrame | None:
        """The next frame once its tick has come, or None after the last (or once closed)."""
        if self._closed or self._next >= len(self.frames):
            self._closed = True
            return None
        now = self._clock()
        if self._start is None:
            self._start = now
        due = self._start + self._next / self.rate_hz
        if due > now:
            self._sleep(due - now)
        frame = self.frames[self._next]
        self._next += 1
        offset = 0.0 if frame.t_right is None or not frame.ok else frame.t_right - frame.t
        skew = abs(offset) * 1e3 if frame.ok else None
        return self._emit(CaptureFrame.from_frame(
            frame, t_monotonic_left=due, t_monotonic_right=due + offset, skew_ms=skew, time_source="clock"))
