"""Tracking any frame source: live cameras, recordings, videos, the synthetic renderer.

One generator, :func:`track_frames`, reads frames (from a capture source or
any iterable of frames, e.g. an :class:`io.Dataset <headplod.io.Dataset>`),
tracks them and applies the per-frame error policy; it yields
``(frame, result)``. Everything that tracks a sequence consumes it:
:func:`run_source` (``headplod track``, ``bench live``), the benchmarks
(``bench track`` and its imperfect-rig sets, ``bench uncertainty``), the
still-head stability run and the demo's tracker poses. So a replayed
recording goes through exactly the code the cameras did.

:func:`run_source`, per frame: read and track (:func:`track_frames`), record
the frame, build the contract's pose record, optionally filter it (One Euro;
off by default), send it to opentrack over UDP, write it, and update the
status line.

A live source (cameras, a ``--realtime`` replay: ``source.realtime``) is read by
a capture thread into a drop-oldest mailbox
(:class:`~headplod.capture.mailbox.CaptureThread`): capture goes on while a
frame is tracked, the tracker takes the newest pair, and the pairs it had no
time for are dropped, oldest first, and counted. Any other source (a replay
for accuracy, ``bench track``, the tests) is read frame by frame: every frame,
in order, the records the same bit for bit from run to run. Either way the
frames go through the one loop, :func:`track_frames`.

Records from a capture source carry, beyond the contract's keys:
``skew_ms`` (left/right capture-time difference), ``dropped`` (pairs the
source lost before this one), ``dropped_busy`` (pairs dropped before this one
because the tracker was busy; 0 when read frame by frame), ``flags`` (e.g. ``"skew 21.3 ms > 16.7 ms bound"``: the
pair was not taken at one instant, so the pose may be off for a moving head;
and the frame's warnings, e.g. ``"left/000003.png: 3-channel image converted
to gray, expected 8-bit grayscale"``)
and ``latency_ms``: from the left image's capture time to the finished
record. For a live camera that is the driver's V4L2 buffer timestamp (start
of exposure or end of frame, as the driver decides; not mid-exposure), or
the time ``grab()`` returned when the driver gives none (the frame's
``time_source``); for a real-time replay, from when the capture thread
delivered the frame (after the pacing); for a replay read frame by frame,
from when the frame was asked for (:data:`LATENCY_FROM`,
``LiveStats.summary()['latency_from']``). Waiting in the mailbox counts.

Every frame read gets a record. A frame whose time is zero, not finite or a
repeat of the last is dropped before tracking (its record says why;
:func:`track_frames`, :mod:`headplod.capture.timestamps`), counted in
``LiveStats.timestamps``; a time that goes back or jumps far forward is a
discontinuity the tracker tracks afresh (the record's ``flags`` say so),
counted in ``LiveStats.time_jumps``. An exception while making a
frame's record is that frame's failure (``internal error: TYPE: message``),
counted in ``LiveStats.internal_errors``; the tracker isolates its own
(:meth:`Tracker.process <headplod.tracking.tracker.Tracker.process>`).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import numpy as np

from .. import io
from ..capture.mailbox import CaptureThread
from ..capture.timestamps import TimestampCheck
from ..tracking.tracker import Tracker, TrackerConfig, TrackResult, internal_error_reason
from .frame_notes import FrameNotes, split_frame_warning


@dataclass
class LiveStats:
    """What a run measured: counts and per-frame times (s)."""

    frames: int = 0
    ok: int = 0
    read_s: list = field(default_factory=list)       # capture layer: source.read()
    track_s: list = field(default_factory=list)      # tracker.process() (tracker.reset() for an error frame)
    output_s: list = field(default_factory=list)     # record, filter, UDP, writing, recording
    latency_ms: list = field(default_factory=list)
    latency_from: dict = field(default_factory=dict)   # instant latencies are measured from -> frames
    timestamps: TimestampCheck = field(default_factory=TimestampCheck)   # frames dropped or reset for their time
    time_jumps: int = 0                              # frames whose time went back or far ahead (the tracker's count)
    first_time_jump: str | None = None
    internal_errors: int = 0                         # frames failed by an exception (the tracker's or the record's)
    first_internal_error: str | None = None
    dropped: int = 0                                 # pairs the source lost (its frames' ``dropped``)
    dropped_busy: int = 0                            # pairs dropped by the mailbox while the tracker was busy
    capture_thread: bool = False                     # read by a capture thread through the drop-oldest mailbox
    capture_stuck: bool = False                      # that thread could not be joined in time
    wall_s: float = 0.0

    def summary(self) -> dict:
        """Counts, rate, latency percentiles, mean times per stage (ms), and the latency's origin.

        ``latency_from`` names the instant the latencies are measured from
        (:data:`LATENCY_FROM`; several, with their frame counts, when they
        changed during the run); ``time_dropped`` counts the frames dropped
        for a zero, non-finite or repeated time and ``time_dropped_first`` is
        the first of them (:class:`~headplod.capture.TimestampCheck`);
        ``time_jumps`` counts the discontinuities (a time gone back or far
        forward, tracked afresh), ``time_jumps_first`` the first; ``internal_errors``
        the frames failed by an exception (``internal error: ...``); ``dropped`` the
        pairs the source lost and ``dropped_busy`` those dropped while the
        tracker was busy (``capture_thread``: read through the drop-oldest
        mailbox); ``offered`` the pairs captured (tracked + dropped while busy).
        ``rate_hz`` is frames tracked per second of the run; latencies are ms
        (p50, p95, p99, max).
        """
        lat = np.asarray(self.latency_ms, dtype=np.float64)
        track = float(np.sum(self.track_s))
        return {
            "frames": self.frames, "ok": self.ok,
            "latency_from": latency_origin(self.latency_from),
            "time_dropped": self.timestamps.dropped, "time_dropped_first": self.timestamps.first,
            "time_jumps": self.time_jumps, "time_jumps_first": self.first_time_jump,
            "internal_errors": self.internal_errors,
            "dropped": self.dropped, "dropped_busy": self.dropped_busy,
            "offered": self.frames + self.dropped_busy,
            "capture_thread": self.capture_thread, "capture_stuck": self.capture_stuck,
            "rate_hz": self.frames / self.wall_s if self.wall_s > 0 else None,
            "latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if lat.size else None,
            "latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else None,
            "latency_ms_max": float(lat.max()) if lat.size else None,
            "read_ms_mean": 1e3 * float(np.mean(self.read_s)) if self.read_s else None,
            "track_ms_mean": 1e3 * float(np.mean(self.track_s)) if self.track_s else None,
            "output_ms_mean": 1e3 * float(np.mean(self.output_s)) if self.output_s else None,
            "capture_over_tracking": float(np.sum(self.read_s)) / track if track > 0 else None,
        }


#: The instants a latency is measured from, by a frame's ``time_source``.
LATENCY_FROM = {
    "driver": "the driver's buffer timestamp (V4L2, CLOCK_MONOTONIC: start of exposure or end of frame, "
              "as the driver decides; not mid-exposure)",
    "grab": "the grab time (time.monotonic() when the camera's grab() returned)",
    "clock": "the tick of the clock that delivered the frame, as a camera would (bench live's clocked replay)",
    "delivered": "when the capture thread delivered the frame to the tracker's mailbox (real-time replay: "
                 "no capture time; after the pacing)",
    None: "the start of reading the frame, less a --realtime replay's pacing wait (replay: no capture time)",
}


def latency_origin(counts: dict) -> str | None:
    """What latencies were measured from, given ``{time_source: frames}``; None without frames."""
    if not counts:
        return None
    if len(counts) == 1:
        return LATENCY_FROM[next(iter(counts))]
    total = sum(counts.values())
    return "; ".join(f"{LATENCY_FROM[k]} for {100.0 * n / total:.0f}% of frames"
                     for k, n in sorted(counts.items(), key=lambda kv: -kv[1]))


@dataclass
class FrameTimes:
    """When the frame that :func:`track_frames` has just yielded was read and tracked.

    Pass one to :func:`track_frames` as ``times``; it is overwritten before
    each ``(frame, result)`` is yielded, so read it inside the loop.

    Attributes
    ----------
    read_start, read_end : float
        ``time.perf_counter()`` just before and just after reading the frame
        (``source.read()`` or the next item of the iterable), s.
    read_end_monotonic : float
        ``time.monotonic()`` just after reading it, s: the clock of a live
        frame's ``t_monotonic_left``, for latencies.
    track_end : float
        ``time.perf_counter()`` just after ``tracker.process()`` returned (or
        ``tracker.reset()``, for an error frame), s.
    """

    read_start: float = math.nan
    read_end: float = math.nan
    read_end_monotonic: float = math.nan
    track_end: float = math.nan

    @property
    def read_s(self) -> float:
        """Time spent reading the frame, s."""
        return self.read_end - self.read_start

    @property
    def track_s(self) -> float:
        """Time spent tracking it (the tracker's call, nothing else), s."""
        return self.track_end - self.read_end


def track_frames(frames: Iterable[io.Frame], tracker: Tracker, *, max_frames: int | None = None,
                 stop: Callable[[], bool] | None = None, timeout_s: float = 1.0,
                 times: FrameTimes | None = None,
                 timestamps: TimestampCheck | None = None) -> Iterator[tuple[io.Frame, TrackResult | None]]:
    """Read and track frames one by one: the one loop of everything that tracks a sequence.

    Parameters
    ----------
    frames : headplod.capture.FrameSource, or iterable of io.Frame
        A source (anything with ``read(timeout_s=...)`` returning a frame, or
        ``None`` once it has ended), read with ``timeout_s``; or any iterable
        of :class:`io.Frame <headplod.io.Frame>` (an ``io.Dataset``, a list of
        preloaded frames, a generator), read in its order until it ends.
    tracker : Tracker
        Called as ``tracker.process(frame.left, frame.right, frame.t,
        frame.t_right)``; its state carries from frame to frame.
    max_frames : int, optional
        End after this many frames (error frames count); nothing more is read.
    stop : callable() -> bool, optional
        Polled before each frame is read, the first one included; the
        generator ends when it returns true.
    timeout_s : float
        How long a live source may wait for a pair, s, before it returns an
        error frame that says which camera is late (a stall). Replay and
        iterables ignore it.
    times : FrameTimes, optional
        Filled in for every frame before it is yielded (read and tracking
        times), for callers that measure.

    Yields
    ------
    frame : io.Frame (a CaptureFrame for capture sources)
        As read.
    result : TrackResult or None
        The tracker's result for the pair; ``None`` when the frame has an
        ``error``.

    Notes
    -----
    The per-frame policy, the same for every caller (every frame read is
    yielded, and counts in ``max_frames``):

    - a frame whose left or right time is zero, not finite, or equal to
      that camera's last time is dropped (:mod:`headplod.capture.timestamps`):
      it is not tracked, the tracker keeps its state, and it is yielded as an
      error frame (``error``: ``"frame dropped: frame 3: left time 0.066 s
      repeats frame 2's (the same image twice)"``, no images) with result
      ``None``; a time that goes back or jumps far ahead is the tracker's to
      handle (it resets its motion and says so in the result's ``notes``);
    - a frame with ``error`` set (an image missing, unreadable or of the
      wrong size; a camera that stalled past ``timeout_s`` or was lost) is
      not tracked: the tracker is reset (the next pair is acquired afresh,
      not tracked from before the gap) and ``(frame, None)`` is yielded;
    - a tracked pair without a pose is a result with ``ok`` false and a
      ``reason`` (the tracker's own; it does not reset the tracker); the
      tracker turns its own exceptions into such a result too
      (``internal error: ...``);
    - exceptions of the source (a broken file, a device gone) are not
      caught: they end the run, whose caller keeps what was made.

    The generator ends when the source or the iterable ends, at
    ``max_frames``, or when ``stop()`` is true.
    """
    read = getattr(frames, "read", None)
    if callable(read):
        def next_frame():
            return read(timeout_s=timeout_s)
    else:
        iterator = iter(frames)

        def next_frame():
            return next(iterator, None)
    check = TimestampCheck() if timestamps is None else timestamps
    count = 0
    while max_frames is None or count < max_frames:
        if stop is not None and stop():
            return
        t_read = time.perf_counter()
        frame = next_frame()
        t_got = time.perf_counter()
        if frame is None:
            return
        read_mono = time.monotonic()
        dropped = check.check(frame)
        result = None
        if dropped is not None:
            t = frame.t if math.isfinite(frame.t) else check.last_time()     # a record's time must be finite
            frame = dataclasses.replace(frame, t=t, left=None, right=None, error=f"frame dropped: {dropped}")
        elif frame.error is None:
            result = tracker.process(frame.left, frame.right, frame.t, frame.t_right)
        else:
            tracker.reset()
        if times is not None:
            times.read_start, times.read_end, times.read_end_monotonic = t_read, t_got, read_mono
            times.track_end = time.perf_counter()
        count += 1
        yield frame, result


def result_record(frame: io.Frame, result: TrackResult | None, screen: io.Screen | None = None,
                  extras: bool = True) -> dict:
    """The contract's pose record for one frame (docs/contract.md), with diagnostics.

    A frame the dataset could not load (``frame.error``) gives ``ok: false``
    with that error as the reason.
    """
    if result is None:
        return io.pose_record(frame.index, frame.t, False, reason=frame.error or "frame not processed")
    more = result.record_extras() if extras else {}
    if not result.ok:
        return io.pose_record(frame.index, frame.t, False, reason=result.reason, **more)
    if screen is not None:
        poi = screen.intersect_ray(result.position_mm, result.axes[2])
        more["poi_px"] = None if poi is None else [round(float(c), 2) for c in poi]
    return io.pose_record(frame.index, frame.t, True, position=result.position_mm, axes=result.axes,
                          cov=result.cov_deg2, reason=None, **more)


def make_tracker(source, config: TrackerConfig = TrackerConfig(), *, rig: io.Rig | None = None,
                 markers: io.MarkerModel | None = None) -> Tracker:
    """The tracker for a source: its rig (or ``rig``), its markers (or ``markers``, else the default model).

    The calibration's own uncertainty, when ``rig.yaml`` carries it
    (``headplod calibrate`` writes it), is the prior of the rig's refinement.

    Raises
    ------
    ValueError
        When neither ``rig`` nor the source has a rig.
    """
    rig = rig or source.rig
    if rig is None:
        raise ValueError(f"{source.name}: no rig (calibration); pass --calib rig.yaml")
    markers = markers or source.markers or io.default_marker_model()
    return Tracker(rig, markers, config, calibration_std=io.rig_calibration_std(rig))


def run_source(source, config: TrackerConfig = TrackerConfig(), *, rig: io.Rig | None = None,
               markers: io.MarkerModel | None = None, screen: io.Screen | None = None,
               on_record: Callable[[dict, object], None] | None = None, recorder=None, sender=None,
               pose_filter=None, status=None, max_frames: int | None = None,
               timeout_s: float = 1.0, stop: Callable[[], bool] | None = None,
               tracker: Tracker | None = None, notes: FrameNotes | None = None,
               stats: LiveStats | None = None, drop_when_busy: bool | None = None,
               mailbox_slots: int = 1) -> LiveStats:
    """Track every frame of a source until it ends (or ``max_frames``, or ``stop()``).

    The frames are read and tracked by :func:`track_frames` (its error
    policy: an error frame resets the tracker and gives an ``ok: false``
    record with the frame's error as the reason); this adds the outputs.

    Parameters
    ----------
    source : headplod.capture.FrameSource
    config : TrackerConfig
    rig, markers, screen : optional
        Override the source's own (e.g. ``--calib rig.yaml`` for cameras).
    on_record : callable(record, TrackResult or None), optional
        Called with each finished record (writing, printing).
    recorder : headplod.capture.DatasetRecorder, optional
        Every frame is recorded as read (its images, not the pose).
    sender : headplod.live.udp.OpentrackSender, optional
    pose_filter : headplod.tracking.filters.PoseFilter, optional
        Applied to the record before it is sent and written.
    status : headplod.live.status.StatusLine, optional
    max_frames : int, optional
    timeout_s : float
        How long a live source may wait for a pair before it reports a stall.
    stop : callable() -> bool, optional
        Polled between frames (Ctrl-C handling lives with the caller).
    tracker : Tracker, optional
        The tracker to use (e.g. :func:`make_tracker`), so that the caller
        can read its refined rig after the run, even one ended by Ctrl-C;
        ``config``, ``rig`` and ``markers`` then only serve when it is None.
    notes : FrameNotes, optional
        Shown the frames' warnings (a colour image converted to gray, an
        interpolated time): the first of each kind in full, then counted.
        With or without it, a frame's warnings are in its record's ``flags``.
    stats : LiveStats, optional
        Filled in as the run goes (and returned), so that a caller whose run
        ends by an exception still has what was measured.
    drop_when_busy : bool, optional
        Read the source with a capture thread into a drop-oldest mailbox of
        ``mailbox_slots`` (:class:`~headplod.capture.mailbox.CaptureThread`):
        the tracker takes the newest pair and those it had no time for are
        dropped and counted (``dropped_busy``). Default: when the source is
        live (``source.realtime``: cameras, a ``--realtime`` replay); else
        every frame is read and tracked in order. The thread is joined
        before this returns or raises; what the source raises in it is
        raised here, after the frames before it.
    mailbox_slots : int
        The mailbox's size (1: always the newest pair).

    Returns
    -------
    LiveStats
    """
    screen = screen if screen is not None else source.screen
    if tracker is None:
        tracker = make_tracker(source, config, rig=rig, markers=markers)
    stats = LiveStats() if stats is None else stats
    if drop_when_busy is None:
        drop_when_busy = bool(getattr(source, "realtime", False))
    stats.capture_thread = bool(drop_when_busy)
    frames = CaptureThread(source, mailbox_slots, timeout_s, stop=stop) if drop_when_busy else source
    try:
        _track_source(frames, tracker, stats, screen=screen, on_record=on_record, recorder=recorder,
                      sender=sender, pose_filter=pose_filter, status=status, max_frames=max_frames,
                      timeout_s=timeout_s, stop=stop, notes=notes)
    finally:
        if drop_when_busy:
            frames.close()
            stats.capture_stuck = frames.stuck
    return stats


def _track_source(frames, tracker: Tracker, stats: LiveStats, *, screen, on_record, recorder, sender,
                  pose_filter, status, max_frames, timeout_s, stop, notes) -> None:
    """:func:`run_source`'s loop over :func:`track_frames`: each frame's record, outputs and counts."""
    times = FrameTimes()
    start = time.perf_counter()
    for frame, result in track_frames(frames, tracker, max_frames=max_frames, stop=stop, timeout_s=timeout_s,
                                      times=times, timestamps=stats.timestamps):
        if recorder is not None:
            recorder.write(frame)                    # an error frame is noted in recording.log, not written
        record = _frame_record(frame, result, screen, pose_filter, notes, stats)
        if sender is not None:
            sender.send(record)
        latency = _latency_ms(frame, times)
        record["latency_ms"] = round(latency, 3)
        if on_record is not None:
            on_record(record, result)
        stats.time_jumps = getattr(tracker, "time_jumps", 0)
        stats.first_time_jump = getattr(tracker, "first_time_jump", None)
        if status is not None:
            status.update(record, latency_ms=latency, skew_ms=getattr(frame, "skew_ms", None),
                          dropped=record["dropped"], time_dropped=stats.timestamps.dropped + stats.time_jumps,
                          time_dropped_first=stats.timestamps.first or stats.first_time_jump,
                          dropped_busy=record["dropped_busy"])
        _count_frame(stats, frame, record, times, latency, start)
    stats.wall_s = time.perf_counter() - start


def _frame_record(frame: io.Frame, result: TrackResult | None, screen: io.Screen | None, pose_filter,
                  notes: FrameNotes | None, stats: LiveStats) -> dict:
    """One frame's record as :func:`run_source` sends and writes it, but for its ``latency_ms``.

    The contract's record (:func:`result_record`, then ``pose_filter``), with the frame's ``skew_ms``
    (left/right capture-time difference, ms, or None), ``dropped`` (pairs the source lost before it),
    ``dropped_busy`` (pairs dropped before it while the tracker was busy) and ``flags``
    (the frame's, its warnings, then the tracker's notes). An exception while making it is the frame's
    failure, ``internal error: TYPE: message``; such failures, the tracker's included, count in ``stats``.
    """
    flags = list(getattr(frame, "flags", []) or [])
    flags += notes.add(frame.index, frame.warning) if notes is not None else split_frame_warning(frame.warning)
    try:
        record = result_record(frame, result, screen)
        if pose_filter is not None:
            record = pose_filter(record, frame.t)
    except Exception as exc:                         # noqa: BLE001 - a bug in one frame's record is that frame's
        record = io.pose_record(frame.index, frame.t, False, reason=internal_error_reason(exc))
    if not record["ok"] and str(record["reason"]).startswith("internal error"):   # the tracker's or the above
        stats.internal_errors += 1
        stats.first_internal_error = stats.first_internal_error or f"frame {frame.index}: {record['reason']}"
    skew = getattr(frame, "skew_ms", None)
    record["skew_ms"] = None if skew is None else round(float(skew), 3)
    record["dropped"] = int(getattr(frame, "dropped", 0) or 0)
    record["dropped_busy"] = int(getattr(frame, "dropped_busy", 0) or 0)
    record["flags"] = flags + list(record.pop("notes", None) or ())   # the frame's, then the tracker's
    return record


def _latency_ms(frame: io.Frame, times: FrameTimes, now_monotonic: float | None = None) -> float:
    """From the frame's capture time (``t_monotonic_left``; without one, when the capture thread delivered it,
    ``t_delivered``; without either, from the start of its reading, less the wait of a realtime replay's
    pacing, ``paced_s``) to ``now_monotonic`` (default: now, ``time.monotonic()``), ms."""
    captured = getattr(frame, "t_monotonic_left", None)
    if captured is None:
        captured = getattr(frame, "t_delivered", None)
    now_mono = time.monotonic() if now_monotonic is None else now_monotonic
    latency = 1e3 * (now_mono - (captured if captured is not None else times.read_end_monotonic))
    if captured is not None:
        return latency
    return latency + 1e3 * max(times.read_s - float(getattr(frame, "paced_s", 0.0) or 0.0), 0.0)


def _count_frame(stats: LiveStats, frame: io.Frame, record: dict, times: FrameTimes, latency: float,
                 start: float) -> None:
    """Count a finished frame in ``stats``: the run's time so far (from ``start``, ``time.perf_counter()``),
    its stages' times (s), its latency (ms) and what that latency was measured from."""
    t_done = time.perf_counter()
    stats.wall_s = time.perf_counter() - start
    stats.frames += 1
    stats.ok += bool(record["ok"])
    stats.read_s.append(times.read_s)
    stats.track_s.append(times.track_s)
    stats.output_s.append(t_done - times.track_end)
    stats.latency_ms.append(latency)
    stats.dropped += int(record["dropped"])
    stats.dropped_busy += int(record["dropped_busy"])
    if frame.error is None:
        origin = getattr(frame, "time_source", None) if getattr(frame, "t_monotonic_left", None) is not None else None
        if origin is None and getattr(frame, "t_delivered", None) is not None:
            origin = "delivered"
        stats.latency_from[origin] = stats.latency_from.get(origin, 0) + 1
