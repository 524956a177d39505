"""Frame times that no camera gives: such a frame is dropped, with a record that says why, and counted.

Every frame read gets a record. A frame is **dropped** (not tracked; its
record has ``ok: false`` and the reason; the tracker keeps its state) when
a camera's time is zero (a driver that gave none, "This can happen after a
disconnect", as Pupil's UVC source puts it), not finite, or *equal* to that
camera's last time (the same image delivered twice, as webcams do when
they miss a frame).

A time that goes back (a clock reset, frames out of order) or jumps far
ahead (a far-future time) is not dropped: it is a **discontinuity** of the
motion, which the tracker handles where its motion model lives
(:meth:`FrameChecks.check_time <headplod.tracking.frame_checks.FrameChecks.check_time>`: the
motion state is reset, the markers acquired afresh, the record's ``flags``
say so, ``Tracker.time_jumps`` counts them). A single wild time (1e300 s)
thus costs one reset on the way there and one on the way back, never the
rest of the run. Pupil (``pupil_src/shared_modules/video_capture/
uvc_backend.py``) drops every non-monotonic time, and so every frame after
a clock reset; its file playback averages a single backward time with its
neighbours. We neither lose the rest of the run nor invent a time.

One :class:`TimestampCheck` is applied where every sequence enters the
tracker, :func:`headplod.live.loop.track_frames`, so live cameras,
recordings, videos and the synthetic renderer follow the same rule.

Per camera
----------
The left time is ``t_monotonic_left`` when the frame has one (a live
camera: the monotonic clock reading itself), else ``t``; the right time is
``t_monotonic_right``, else ``t_right`` (not checked when ``None``: the
contract's "same instant as ``t``"). The message names the camera.

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
    """Drops frames whose left or right time is zero, not finite, or a repeat of the camera's last; counts them.

    Attributes
    ----------
    dropped : int
        Frames dropped so far.
    zero, not_finite, repeated : int
        Of those, how many for a zero time, a non-finite one, and a time
        equal to the camera's last.
    first : str or None
        The first drop, e.g. ``"frame 3: right time 0.066 s repeats frame
        2's (the same image twice)"``.
    """

    def __init__(self) -> None:
        self.zero = self.not_finite = self.repeated = 0
        self.first: str | None = None
        self._last: dict[str, tuple[float, Any]] = {}
        self._seen = 0

    @property
    def dropped(self) -> int:
        return self.zero + self.not_finite + self.repeated

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
        """Why ``frame`` is dropped, or None when it is kept (its times then become the cameras' last).

        Parameters
        ----------
        frame : io.Frame or CaptureFrame

        Returns
        -------
        str or None
            ``"frame N: left time 0 s (no timestamp)"``, ``"frame N: right
            time 0.05 s repeats frame M's (the same image twice)"``, ...
        """
        if getattr(frame, "error", None) is not None:
            return None
        first = self._seen == 0
        self._seen += 1
        times = self._times(frame)
        for side, t, clock in times:
            name = f"frame {frame.index}: {side} time"
            last = self._last.get(side)
            if not math.isfinite(t):
                why, kind = f"{name} {t} (not a time)", "not_finite"
            elif t == 0.0 and (clock or not first):
                why, kind = f"{name} 0 s (no timestamp)", "zero"
            elif last is not None and t == last[0]:
                why, kind = f"{name} {t:.6g} s repeats frame {last[1]}'s (the same image twice)", "repeated"
            else:
                continue
            setattr(self, kind, getattr(self, kind) + 1)
            self.first = self.first or why
            return why
        for side, t, _ in times:
            self._last[side] = (t, frame.index)
        return None

    def last_time(self) -> float:
        """The left camera's last accepted time, s (0.0 before any): a stand-in for a time that is not one."""
        last = self._last.get("left")
        return 0.0 if last is None else float(last[0])

    def summary(self) -> str | None:
        """One line for the end of a run, or None when no frame was dropped."""
        if not self.dropped:
            return None
        kinds = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in
                          (("zero", self.zero), ("not_finite", self.not_finite), ("repeated", self.repeated)) if n)
        return f"timestamps: {self.dropped} frames dropped ({kinds}); first: {self.first}"
