"""Tracking any frame source: live cameras, recordings, videos, the synthetic renderer.

One loop (:func:`run_source`) serves ``headplod track`` for every source, so
a replayed recording goes through exactly the code the cameras did. Per
frame: read (the capture layer), track, build the contract's pose record,
optionally filter it (One Euro; off by default), send it to opentrack over
UDP, write it, record the frame, and update the status line.

Records from a capture source carry, beyond the contract's keys:
``skew_ms`` (left/right capture-time difference), ``dropped`` (pairs lost
before this one), ``flags`` (e.g. ``"skew 21.3 ms > 16.7 ms bound"``: the
pair was not taken at one instant, so the pose may be off for a moving head)
and ``latency_ms`` (from the capture of the left image, or from when the
frame was read for replay, to the finished record).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .. import io
from ..tracking.tracker import Tracker, TrackerConfig, TrackResult


@dataclass
class LiveStats:
    """What a run measured: counts and per-frame times (s)."""

    frames: int = 0
    ok: int = 0
    read_s: list = field(default_factory=list)       # capture layer: source.read()
    track_s: list = field(default_factory=list)      # tracker.process()
    output_s: list = field(default_factory=list)     # record, filter, UDP, writing, recording
    latency_ms: list = field(default_factory=list)
    wall_s: float = 0.0

    def summary(self) -> dict:
        lat = np.asarray(self.latency_ms, dtype=np.float64)
        track = float(np.sum(self.track_s))
        return {
            "frames": self.frames, "ok": self.ok,
            "rate_hz": self.frames / self.wall_s if self.wall_s > 0 else None,
            "latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if lat.size else None,
            "latency_ms_max": float(lat.max()) if lat.size else None,
            "read_ms_mean": 1e3 * float(np.mean(self.read_s)) if self.read_s else None,
            "track_ms_mean": 1e3 * float(np.mean(self.track_s)) if self.track_s else None,
            "output_ms_mean": 1e3 * float(np.mean(self.output_s)) if self.output_s else None,
            "capture_over_tracking": float(np.sum(self.read_s)) / track if track > 0 else None,
        }


def result_record(frame: io.Frame, result: TrackResult | None, screen: io.Screen | None = None,
                  extras: bool = True) -> dict:
    """The contract's pose record for one frame (conventions.md), with diagnostics.

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
               tracker: Tracker | None = None) -> LiveStats:
    """Track every frame of a source until it ends (or ``max_frames``, or ``stop()``).

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
    sender : headplod.live.loop.output.OpentrackSender, optional
    pose_filter : headplod.tracking.filters.PoseFilter, optional
        Applied to the record before it is sent and written.
    status : headplod.live.loop.output.StatusLine, optional
    max_frames : int, optional
    timeout_s : float
        How long a live source may wait for a pair before it reports a stall.
    stop : callable() -> bool, optional
        Polled between frames (Ctrl-C handling lives with the caller).
    tracker : Tracker, optional
        The tracker to use (e.g. :func:`make_tracker`), so that the caller
        can read its refined rig after the run, even one ended by Ctrl-C;
        ``config``, ``rig`` and ``markers`` then only serve when it is None.

    Returns
    -------
    LiveStats
    """
    screen = screen if screen is not None else source.screen
    if tracker is None:
        tracker = make_tracker(source, config, rig=rig, markers=markers)
    stats = LiveStats()
    start = time.perf_counter()
    while max_frames is None or stats.frames < max_frames:
        if stop is not None and stop():
            break
        t_read = time.perf_counter()
        frame = source.read(timeout_s=timeout_s)
        t_got = time.perf_counter()
        if frame is None:
            break
        read_mono = time.monotonic()
        result = None
        if frame.error is None:
            result = tracker.process(frame.left, frame.right, frame.t, frame.t_right)
        else:
            tracker.reset()
        t_tracked = time.perf_counter()
        if recorder is not None and frame.error is None:
            recorder.write(frame)
        record = result_record(frame, result, screen)
        skew = getattr(frame, "skew_ms", None)
        dropped = int(getattr(frame, "dropped", 0) or 0)
        flags = list(getattr(frame, "flags", []) or [])
        captured = getattr(frame, "t_monotonic_left", None)
        if pose_filter is not None:
            record = pose_filter(record, frame.t)
        record["skew_ms"] = None if skew is None else round(float(skew), 3)
        record["dropped"] = dropped
        record["flags"] = flags
        if sender is not None:
            sender.send(record)
        now_mono = time.monotonic()
        latency = 1e3 * (now_mono - (captured if captured is not None else read_mono))
        latency += 1e3 * (t_got - t_read) if captured is None else 0.0
        record["latency_ms"] = round(latency, 3)
        if on_record is not None:
            on_record(record, result)
        if status is not None:
            status.update(record, latency_ms=latency, skew_ms=skew, dropped=dropped)
        t_done = time.perf_counter()
        stats.frames += 1
        stats.ok += bool(record["ok"])
        stats.read_s.append(t_got - t_read)
        stats.track_s.append(t_tracked - t_got)
        stats.output_s.append(t_done - t_tracked)
        stats.latency_ms.append(latency)
    stats.wall_s = time.perf_counter() - start
    return stats
