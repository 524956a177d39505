"""Running the tracker over a dataset folder and writing pose records."""
from __future__ import annotations

import sys
import time
from typing import Callable

from .. import io
from ..tracking.tracker import TrackerConfig, TrackResult


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


def track_dataset(dataset: io.Dataset, config: TrackerConfig = TrackerConfig(),
                  on_record: Callable[[dict, TrackResult | None], None] | None = None) -> list[dict]:
    """Track every frame of a dataset, in frame order, through the live loop.

    A frame that cannot be loaded becomes an ``ok: false`` record with the
    loader's reason; the other frames are still processed. This is
    :func:`headplod.live.loop.run_source` over the dataset's folder, so a dataset
    and a live session give the same records.

    Parameters
    ----------
    dataset : io.Dataset
    config : TrackerConfig
    on_record : callable(record, result), optional
        Called after each frame (progress, writing).

    Returns
    -------
    list of pose records (dicts)
    """
    from ..capture import DatasetSource
    from .loop import run_source

    records = []

    def collect(record, result):
        records.append(record)
        if on_record is not None:
            on_record(record, result)

    source = DatasetSource(dataset)
    try:
        run_source(source, config, rig=dataset.rig, markers=dataset.markers, screen=dataset.screen,
                   on_record=collect)
    finally:
        source.close()
    return records


class Progress:
    """A one-line progress display on a terminal, plain lines otherwise."""

    def __init__(self, total: int, label: str, stream=sys.stderr, every_s: float = 0.5):
        self.total, self.label, self.stream = total, label, stream
        self.every_s = every_s
        self.count = 0
        self.start = time.perf_counter()
        self._last = 0.0
        self._tty = hasattr(stream, "isatty") and stream.isatty()

    def step(self, note: str = "") -> None:
        self.count += 1
        now = time.perf_counter()
        if now - self._last < self.every_s and self.count < self.total:
            return
        self._last = now
        rate = self.count / max(now - self.start, 1e-9)
        text = f"{self.label}: {self.count}/{self.total} ({rate:.0f}/s) {note}"
        if self._tty:
            self.stream.write("\r" + text[:150].ljust(150))
            if self.count >= self.total:
                self.stream.write("\n")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()
