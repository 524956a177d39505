"""Frame times that no camera gives: dropped or taken as a discontinuity, per camera, counted and said.

Every frame read gets a record; what a bad time does to it:

- **dropped** (not tracked; its record says why, ``ok: false``; the tracker
  keeps its state): a time of zero (a driver that gave none, "This can
  happen after a disconnect", as Pupil's UVC source puts it), a time that
  is not finite, and a time *equal* to that camera's last one (the same
  image delivered twice, as webcams do when they miss a frame);
- **a discontinuity** (tracked from scratch; its record's ``flags`` say so):
  a time that goes back (a clock reset, a replay's frames out of order) or
  jumps forward by more than :data:`MAX_GAP_S` (a far-future time, a
  clock that jumped). No motion model bridges it, so the tracker's motion
  state is reset and the run goes on. A single wild time (1e300 s) thus
  costs one reset on the way there and one on the way back, never the
  rest of the run.

Pupil (``pupil_src/shared_modules/video_capture/uvc_backend.py``) drops both
zero and non-monotonic times and so loses every frame after a clock reset;
its file playback instead averages a single backward time with its
neighbours. We neither lose the rest of the run nor invent a time.

One :class:`TimestampCheck` is applied where every sequence enters the
tracker, :func:`headplod.live.loop.track_frames`, so live cameras,
recordings, videos and the synthetic renderer follow the same rule.

Per camera
----------
The left time is ``t_monotonic_left`` when the frame has one (a live
camera: the monotonic clock reading itself), else ``t``; the right time is
``t_monotonic_right``, else ``t_right`` (not checked when ``None``: the
contract's "same instant as ``t``"). The worse verdict of the two cameras
is the frame's; the message names the camera.

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
from typing import Any, NamedTuple

__all__ = ["TimestampCheck", "TimeVerdict", "MAX_GAP_S"]

#: A forward step of a camera's time longer than this (s) is a discontinuity: no head motion model bridges
#: a second (a stalled live camera gives error frames well before: its read times out after 1 s).
MAX_GAP_S = 1.0


class TimeVerdict(NamedTuple):
    """What a frame's times mean: ``drop`` (not tracked) or not (a discontinuity: tracked from scratch)."""

    kind: str          # "zero", "not_finite", "repeated" (dropped); "back", "gap" (discontinuity)
    why: str           # e.g. "frame 3: left time 0.05 s before 0.066 s (frame 2)"

    @property
    def drop(self) -> bool:
        return self.kind in DROP_KINDS


DROP_KINDS = ("zero", "not_finite", "repeated")
_SEVERITY = {"zero": 3, "not_finite": 3, "repeated": 2, "back": 1, "gap": 1}


class TimestampCheck:
    """Classifies each frame's times (dropped, a discontinuity, or fine) and counts them.

    Attributes
    ----------
    dropped : int
        Frames dropped so far.
    zero, not_finite, repeated : int
        Of those, how many for a zero time, a non-finite one, and a time
        equal to the camera's last.
    jumps : int
        Discontinuities so far (tracked from scratch).
    back, gap : int
        Of those, how many for a time that went back, and one that jumped
        forward more than ``max_gap_s``.
    first : str or None
        The first drop, e.g. ``"frame 3: right time 0.066 s repeats frame
        2's"``.
    first_jump : str or None
        The first discontinuity.

    Parameters
    ----------
    max_gap_s : float
        A forward step longer than this, s, is a discontinuity
        (:data:`MAX_GAP_S`).
    """

    def __init__(self, max_gap_s: float = MAX_GAP_S) -> None:
        if not max_gap_s > 0:
            raise ValueError(f"max_gap_s must be > 0 s, got {max_gap_s}")
        self.max_gap_s = float(max_gap_s)
        self.zero = self.not_finite = self.repeated = 0
        self.back = self.gap = 0
        self.first: str | None = None
        self.first_jump: str | None = None
        self._last: dict[str, tuple[float, Any]] = {}
        self._seen = 0

    @property
    def dropped(self) -> int:
        return self.zero + self.not_finite + self.repeated

    @property
    def jumps(self) -> int:
        return self.back + self.gap

    @property
    def not_increasing(self) -> int:
        """Frames whose time did not increase: repeated (dropped) or gone back (discontinuities)."""
        return self.repeated + self.back

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

    def _verdict(self, frame: Any, side: str, t: float, clock: bool, first: bool) -> TimeVerdict | None:
        name = f"frame {frame.index}: {side} time"
        if not math.isfinite(t):
            return TimeVerdict("not_finite", f"{name} {t} (not a time)")
        if t == 0.0 and (clock or not first):
            return TimeVerdict("zero", f"{name} 0 s (no timestamp)")
        last = self._last.get(side)
        if last is None:
            return None
        if t == last[0]:
            return TimeVerdict("repeated", f"{name} {t:.6g} s repeats frame {last[1]}'s (the same image twice)")
        if t < last[0]:
            return TimeVerdict("back", f"{name} {t:.6g} s before {last[0]:.6g} s (frame {last[1]})")
        if t - last[0] > self.max_gap_s:
            return TimeVerdict("gap", f"{name} {t:.6g} s jumps {t - last[0]:.6g} s after {last[0]:.6g} s "
                                      f"(frame {last[1]}), more than {self.max_gap_s:g} s")
        return None

    def check(self, frame: Any) -> TimeVerdict | None:
        """The verdict on ``frame``'s times, or None when they are fine.

        A frame that is not dropped (fine, or a discontinuity) moves the
        cameras' last accepted times to its own.

        Parameters
        ----------
        frame : io.Frame or CaptureFrame

        Returns
        -------
        TimeVerdict or None
        """
        if getattr(frame, "error", None) is not None:
            return None
        first = self._seen == 0
        self._seen += 1
        times = self._times(frame)
        verdicts = [v for v in (self._verdict(frame, side, t, clock, first) for side, t, clock in times) if v]
        verdict = max(verdicts, key=lambda v: _SEVERITY[v.kind]) if verdicts else None
        if verdict is not None:
            setattr(self, verdict.kind, getattr(self, verdict.kind) + 1)
            if verdict.drop:
                self.first = self.first or verdict.why
                return verdict
            self.first_jump = self.first_jump or verdict.why
        for side, t, _ in times:
            self._last[side] = (t, frame.index)
        return verdict

    def last_time(self) -> float:
        """The left camera's last accepted time, s (0.0 before any): a stand-in for a time that is not one."""
        last = self._last.get("left")
        return 0.0 if last is None else float(last[0])

    def summary(self) -> str | None:
        """One line for the end of a run, or None when every time was fine."""
        parts = []
        if self.dropped:
            kinds = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in
                              (("zero", self.zero), ("not_finite", self.not_finite), ("repeated", self.repeated)) if n)
            parts.append(f"{self.dropped} frames dropped ({kinds}); first: {self.first}")
        if self.jumps:
            kinds = ", ".join(f"{n} {k}" for k, n in (("back", self.back), (f"forward > {self.max_gap_s:g} s", self.gap))
                              if n)
            parts.append(f"{self.jumps} discontinuities ({kinds}), tracked afresh after each; first: {self.first_jump}")
        return "timestamps: " + "; ".join(parts) if parts else None
