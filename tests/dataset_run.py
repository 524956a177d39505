"""Running the tracker over a dataset folder, for tests: the live loop over a :class:`DatasetSource`.

A test helper, not a test module (pytest collects only ``test_*.py``); test modules import it as
``from dataset_run import track_dataset``, as they import ``conftest``.
"""
from __future__ import annotations

from typing import Callable

from headplod import io
from headplod.capture import DatasetSource
from headplod.live.loop import run_source
from headplod.tracking.tracker import TrackerConfig, TrackResult

__all__ = ["track_dataset"]


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
