"""Frames whose time is zero or not increasing are dropped, per camera, and counted.

The rule is Pupil's (pupil-labs/pupil, ``pupil_src/shared_modules/
video_capture/uvc_backend.py``, ``UVC_Source.recent_events``): a frame whose
timestamp is zero ("This can happen after a disconnect. Frame will be
dropped!") and a frame whose timestamp is not above the last accepted one
("Received non-monotonic timestamps from UVC! Dropping frame.") are dropped,
and the last accepted time only moves with an accepted frame. Pupil logs
them at debug level; here they are counted and the first one is kept, for
the status line and the end of ``headplod track``. Pupil's file playback
(``file_backend.py`` with ``utils.py``, ``Video._fix_negative_time_jumps``)
instead replaces a single backward time by the mean of its neighbours; we
do not, so that a replay drops exactly what the live run would have.

One :class:`TimestampCheck` is applied where every sequence enters the
tracker, :func:`headplod.live.loop.track_frames`, so live cameras,
recordings, videos and the synthetic renderer follow the same rule.

Per camera
----------
The left time is ``t_monotonic_left`` when the frame has one (a live
camera: the monotonic clock reading itself), else ``t``; the right time is
``t_monotonic_right``, else ``t_right`` (not checked when ``None``: the
contract's "same instant as ``t``"). A pair is dropped when either time is
bad; the message names the camera.

Zero
----
A clock reading (live cameras) of exactly 0 means the driver gave no time.
A replayed ``t`` of 0 is the origin of the recording when it is the first
frame read (synthetic datasets and videos without ``times.csv`` start at
``t = 0``): that one is kept; a zero on any later frame is dropped.
Frames with ``error`` set are not checked (their time is when the error was
noticed) and do not move the last accepted time.
"""
from __future__ import annotations

import math
from typing import Any

__all__ = ["TimestampCheck"]


class TimestampCheck:
    """Drops frames whose left or right time is zero or not increasing, and counts them.

    Attributes
    ----------
    dropped : int
        Frames dropped so far.
    zero, not_increasing : int
        Of those, how many for a zero time, and for a time not above the
        camera's last accepted one (equal or backwards).
    first : str or None
        The first drop, e.g. ``"frame 3: right time 0.066 s not after 0.066 s
        (frame 2)"``.
    """

    def __init__(self) -> None:
        self.dropped = 0
        self.zero = 0
        self.not_increasing = 0
        self.first: str | None = None
        self._last: dict[str, tuple[float, Any]] = {}
        self._seen = 0

    @staticmethod
    def _times(frame: Any) -> list[tuple[str, float, bool]]:
        """(camera, time s, is a clock reading) of each camera the frame has a time for."""
        out = []
        for side, clock, plain in (("left", "t_monotonic_left", "t"), ("right", "t_monotonic_right", "t_right")):
            reading = getattr(frame, clock, None)
            if reading is not None:
                out.append((side, float(reading), True))
            elif getattr(frame, plain, None) is not None:
                out.append((side, float(getattr(frame, plain)), False))
        return out

    def check(self, frame: Any) -> str | None:
        """Why ``frame`` is dropped, or None when it is kept (its times then become the last accepted).

        Parameters
        ----------
        frame : io.Frame or CaptureFrame

        Returns
        -------
        str or None
            ``"frame N: left time 0 s (no timestamp)"`` or ``"frame N:
            right time 0.05 s not after 0.066 s (frame M)"``.
        """
        if getattr(frame, "error", None) is not None:
            return None
        first = self._seen == 0
        self._seen += 1
        times = self._times(frame)
        why = None
        for side, t, clock in times:
            if t == 0.0 and (clock or not first):
                why, kind = f"frame {frame.index}: {side} time 0 s (no timestamp)", "zero"
                break
            last = self._last.get(side)
            if not math.isfinite(t) or (last is not None and not t > last[0]):
                after = "" if last is None else f" not after {last[0]:.6g} s (frame {last[1]})"
                why, kind = f"frame {frame.index}: {side} time {t:.6g} s{after}", "not_increasing"
                break
        if why is None:
            for side, t, _ in times:
                self._last[side] = (t, frame.index)
            return None
        self.dropped += 1
        setattr(self, kind, getattr(self, kind) + 1)
        if self.first is None:
            self.first = why
        return why

    def summary(self) -> str | None:
        """One line for the end of a run, or None when nothing was dropped."""
        if not self.dropped:
            return None
        return (f"timestamps: {self.dropped} frames dropped ({self.zero} zero, {self.not_increasing} not "
                f"increasing); first: {self.first}")
