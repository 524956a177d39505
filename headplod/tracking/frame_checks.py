"""What a frame must be before it is tracked, and the pair of images it is tracked from.

- Its images: the rig's size, 8-bit grayscale, and not the very buffer the
  camera delivered last (:meth:`FrameChecks.check_images`,
  :meth:`FrameChecks.repeated_images`).
- Its time against the previous frames' (:meth:`FrameChecks.check_time`,
  a :class:`TimeVerdict`: a jump back or far ahead resets the motion, a
  repeat or a glitch is noted) and the usual frame period
  (:meth:`FrameChecks.frame_period`).
- The right image's time against the left one's: a skew no motion bridges
  refuses the pair (:meth:`FrameChecks.implausible_offset`); the right
  image to use and its exposure time, with the refinement's estimated
  offset (:meth:`RightPairing.pair`).

:class:`FrameChecks` and :class:`RightPairing` are parts of
:class:`~.tracker.Tracker`. The first owns what the checks remember across
frames (the recent frame periods, the last time, the previous images, the
time discontinuities counted); the second the previous right image and the
right camera's recent periods, which a time discontinuity forgets
(:meth:`RightPairing.reset`). Times are in s.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np


def describe_offset_s(offset_s: float) -> str:
    """``t_right - t`` in words: ``"5.0 s after"``, ``"120 ms before"``."""
    side = "after" if offset_s >= 0 else "before"
    size = abs(offset_s)
    if size >= 1e4:                                    # a clock's wild value, not a skew: no 300 digits
        return f"{size:.3g} s {side}"
    return f"{size:.1f} s {side}" if size >= 1.0 else f"{size * 1e3:.0f} ms {side}"


class TimeVerdict(NamedTuple):
    """What :meth:`FrameChecks.check_time` made of a frame's time.

    ``notes``: for a person (the result's notes); ``glitch``: the time is no
    clock's (a repeat, a glitch, jitter): not for the rig's refinement;
    ``time_glitch``: a repeat or a step of a fraction of a period: not for
    the motion history either; ``discontinuity``: back in time or far
    ahead: the motion state is to be forgotten.
    """

    notes: list
    glitch: bool = False
    time_glitch: bool = False
    discontinuity: bool = False


class TimeLimits(NamedTuple):
    """The bounds :class:`FrameChecks` holds frame times to (the same-named ``TrackerConfig`` fields).

    ``max_time_gap_s`` (s) and ``max_time_gap_periods`` (frame periods):
    a step beyond the smaller of the two, once the period is known, is a
    discontinuity; ``max_right_offset_periods``: a right image further than
    that many periods (and 0.1 s) from the left one is not its stereo pair.
    """

    max_time_gap_s: float
    max_time_gap_periods: float
    max_right_offset_periods: float

    @classmethod
    def of(cls, config) -> "TimeLimits":
        """The limits a ``TrackerConfig`` sets."""
        return cls(config.max_time_gap_s, config.max_time_gap_periods, config.max_right_offset_periods)


class FrameChecks:
    """The frame checks of :class:`~.tracker.Tracker` (module docstring), held to ``limits``
    (:class:`TimeLimits`; the images' own checks need no setting)."""

    def __init__(self, limits: TimeLimits):
        self.limits = limits
        self.frame_periods = []       # recent frame periods, s, for the right time's plausibility (kept by reset)
        self._last_t = None
        self._previous_images = None  # (left, right) of the last frame, to recognize a repeated buffer
        self.time_jumps = 0           # discontinuities of the frame time (back, or far ahead): motion reset
        self.first_time_jump: str | None = None

    def check_images(self, left, right, image_size) -> str | None:
        """Why the images (H, W) cannot be tracked with a rig of ``image_size`` (W, H) px, or None."""
        width, height = image_size
        for name, img in (("left", left), ("right", right)):
            if img is None:
                return f"{name} image missing"
            if img.dtype != np.uint8 or img.ndim != 2:
                return f"{name} image is {img.dtype} with shape {img.shape}; expected 8-bit grayscale"
            if img.shape != (height, width):
                return (f"{name} image is {img.shape[1]}x{img.shape[0]} px but the rig is calibrated "
                        f"for {width}x{height}: wrong camera mode or wrong rig.yaml")
        return None

    def repeated_images(self, left: np.ndarray, right: np.ndarray) -> str | None:
        """Why a frame is refused when a camera delivered the very image it delivered last (a driver or
        a capture loop handing the same buffer out twice): that image was exposed a frame earlier than
        its time says, so no pose may be made from it. None for new images. (Two exposures are never
        identical to the bit: sensor noise, and MJPEG's coding of it, differ.)"""
        previous, self._previous_images = self._previous_images, (left, right)
        if previous is None:
            return None
        # One row first: two exposures differ in noise nearly everywhere, so it
        # tells new images at once (the whole images are compared only when it matches).
        # An image without any variation (a covered lens, black or clipped) repeats
        # without being a repeated buffer: it tells nothing either way.
        def repeats(a, b):
            if a.shape != b.shape:
                return False
            row = a[a.shape[0] // 2]          # one contiguous row first: cheaper than a scattered grid
            return (np.array_equal(row, b[b.shape[0] // 2]) and int(row.max()) != int(row.min())
                    and np.array_equal(a, b))

        same = [repeats(a, b) for a, b in zip(previous, (left, right))]
        if not any(same):
            return None
        which = "both cameras" if all(same) else ("the left camera" if same[0] else "the right camera")
        return (f"{which} delivered the same image as in the last frame (a repeated buffer, not a new exposure): "
                "no pose from it")

    def frame_period(self) -> float | None:
        """The usual time between frames, s (None until a step is known): the 75th percentile of the
        last 16 steps, which neither timestamp glitches (steps of a ms) nor a few dropped frames (steps of
        two periods) move far, while up to half of either would move a median."""
        if not self.frame_periods:
            return None
        steps = sorted(self.frame_periods)
        return steps[(3 * (len(steps) - 1)) // 4]

    def check_time(self, t) -> TimeVerdict:
        """This frame's time against the previous frame's; a discontinuity resets the motion.

        Back in time, or forward by more than ``max_time_gap_s`` or
        ``max_time_gap_periods`` frame periods: the poses before it are not
        this motion's past, and no velocity bridges the gap, so the motion
        state is to be forgotten (``discontinuity``) and the markers
        acquired afresh. A time equal to the previous one is noted (the
        motion model gets no velocity from it). Keeps the recent frame
        periods (s) for this and the right time's plausibility.
        """
        if t is None:
            return TimeVerdict([])
        last, self._last_t = self._last_t, t
        if last is None:
            return TimeVerdict([])
        step = float(t) - float(last)
        period = self.frame_period()
        c = self.limits
        known = len(self.frame_periods) >= 4        # a period from fewer steps may be a glitch's
        gap = min(c.max_time_gap_s, c.max_time_gap_periods * period) if known else c.max_time_gap_s
        if 0 < step <= c.max_time_gap_s:
            # Every step within the absolute bound counts towards the period,
            # so that a period first learnt from glitches recovers.
            self.frame_periods = (self.frame_periods + [step])[-16:]
        if 0 < step <= gap:
            # A step under a third of the usual period is a repeat or a late
            # timestamp more likely than a faster camera (until the period is
            # known, a third of the longest step so far). One a tenth of a
            # period off the frame clock (jitter) is a time the rig's
            # refinement must not learn velocities and offsets from.
            usual = period if known else max(self.frame_periods, default=step)
            time_glitch = step < 0.3 * usual
            glitch = time_glitch or (known and abs(step - period * round(step / period)) > 0.1 * period)
            return TimeVerdict([], glitch, time_glitch)
        if step == 0:
            return TimeVerdict([f"time {t:.6f} s repeats the previous frame's: no motion measured over it"],
                               True, True)
        if step < 0:
            note = (f"time went back {describe_offset_s(-step).replace(' after', '')} (t={t:.6g} s after "
                    f"{last:.6g} s): motion state reset, markers acquired afresh")
        else:
            note = (f"time jumped {describe_offset_s(step).replace(' after', '')} ahead (t={t:.6g} s after "
                    f"{last:.6g} s, more than {gap * 1e3:.0f} ms): motion state reset, markers acquired afresh")
        self.time_jumps += 1
        self.first_time_jump = self.first_time_jump or note
        return TimeVerdict([note], discontinuity=True)

    def implausible_offset(self, t, t_right) -> str | None:
        """The reason for refusing a pair whose right time is far from the left one (None if plausible).

        Far: more than ``max_right_offset_periods`` frame periods and 0.1 s.
        No motion model bridges that; compensating it would move the model
        by seconds of head motion, so the frame gets no pose, and the
        reason names the skew rather than the reprojection error it causes.
        """
        if t is None or t_right is None:
            return None
        offset_s = float(t_right) - float(t)
        period_s = self.frame_period() or 1.0 / 30.0
        k = self.limits.max_right_offset_periods
        bound_s = max(k * period_s, 0.1)
        if not abs(offset_s) > bound_s:
            return None
        periods = f", {k:g} frame periods" if self.frame_periods and bound_s > 0.1 else ""
        return (f"right image's time is {describe_offset_s(offset_s)} the left's (t_right - t), more than "
                f"{bound_s * 1e3:.0f} ms{periods}: not a stereo pair; check times.csv / the cameras' clocks")


class RightPairing:
    """The right image paired with each left one, and its exposure time (module docstring)."""

    def __init__(self):
        self._last_right = None        # (image, t, t_right) of the previous frame's right camera
        self.declared_right = None     # the right image's time as given (times.csv, the driver), s
        self._periods = []             # recent frame periods, s
        self.reset()

    def reset(self) -> None:
        """Forget the previous right image and the periods (a time discontinuity)."""
        self._last_right = None
        self.declared_right = None
        self._periods = []

    def pair(self, left, right, t, t_right, refiner):
        """The images to use and the right one's exposure time, with the offset ``refiner`` (the rig's
        refinement, or None) estimated.

        The right time is the given one (or t) plus the offset the
        refinement estimated, once it is known. When the right camera
        exposes more than half a frame period after the left one, the
        previous right image is the one nearest to this left image in
        time: it is used instead (no added latency), and the motion over
        what remains of the offset is compensated as usual.
        """
        previous, self._last_right = self._last_right, (right, t, t_right)
        self.declared_right = t_right
        if t is None or refiner is None:
            return (left, right), t_right
        if previous is not None and previous[1] is not None and 0 < t - previous[1] < 1.0:
            self._periods = (self._periods + [t - previous[1]])[-8:]
        offset = refiner.estimator.state.offset_s
        if not abs(offset) > max(2.0 * refiner.estimator.sigma()[7], 3e-4):
            return (left, right), t_right
        period = float(np.median(self._periods)) if self._periods else None
        if (period and offset > 0.5 * period and previous is not None and previous[1] is not None
                and 0 < t - previous[1] < 1.5 * period):
            right, t_prev, t_right_prev = previous
            self.declared_right = t_right_prev if t_right_prev is not None else t_prev
            return (left, right), self.declared_right + offset
        return (left, right), (t_right if t_right is not None else t) + offset
