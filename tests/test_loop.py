"""The one tracking loop, :func:`headplod.live.loop.track_frames`: what it yields, when it stops, error frames.

Everything runs on ``tests/data/sweep12`` (12 frames with truth, 0.1 s apart;
the tracker acquires in frames 0-1 and tracks from frame 2 on), copied to a
temporary folder when a test damages it.
"""
import shutil
from pathlib import Path

import numpy as np
import pytest

from headplod import io
from headplod.capture import open_source
from headplod.capture.base import CaptureFrame, FrameSource
from headplod.live.loop import FrameTimes, make_tracker, result_record, run_source, track_frames
from headplod.tracking.tracker import Tracker

DATA = Path(__file__).parent / "data"
SWEEP = DATA / "sweep12"
#: The frame damaged in the error tests (the tracker is in tracking mode by then).
BAD = 5


def _tracker(dataset: io.Dataset) -> Tracker:
    return Tracker(dataset.rig, dataset.markers or io.default_marker_model(),
                   calibration_std=io.rig_calibration_std(dataset.rig))


def _same_result(a, b) -> None:
    """Two TrackResults are the same pose, bit for bit (the tracker is deterministic)."""
    assert (a.ok, a.reason, a.mode) == (b.ok, b.reason, b.mode)
    for name in ("position_mm", "axes", "cov_deg2", "centers_px"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)


class ListSource(FrameSource):
    """A frame source over a list of frames; notes every read and its timeout."""

    kind = "list"

    def __init__(self, frames, rig):
        super().__init__("list", rig=rig)
        self.frames = list(frames)
        self.timeouts = []

    def read(self, timeout_s: float = 1.0):
        self.timeouts.append(timeout_s)
        if self.closed or not self.frames:
            return None
        return self._emit(CaptureFrame.from_frame(self.frames.pop(0)))


@pytest.fixture
def damaged(tmp_path) -> Path:
    """sweep12 with the left image of frame BAD overwritten by bytes that are not a PNG."""
    folder = tmp_path / "damaged"
    shutil.copytree(SWEEP, folder)
    (folder / "left" / f"{BAD:06d}.png").write_bytes(b"not a png")
    return folder


@pytest.mark.slow
def test_same_results_as_process_frame_by_frame():
    dataset = io.Dataset(SWEEP)
    by_hand = _tracker(dataset)
    expected = [by_hand.process(f.left, f.right, f.t, f.t_right) for f in dataset]
    got = list(track_frames(dataset, _tracker(dataset)))
    assert [f.index for f, _ in got] == list(range(12))
    for (frame, result), ref in zip(got, expected):
        assert frame.error is None
        _same_result(result, ref)
    assert all(r.ok for _, r in got)
    assert [r.mode for _, r in got][2:] == ["track"] * 10          # the state carried over between frames


@pytest.mark.slow
def test_a_frame_source_gives_the_same_results_and_is_read_with_the_timeout():
    dataset = io.Dataset(SWEEP)
    source = ListSource(dataset, dataset.rig)
    times = FrameTimes()
    got, spans = [], []
    for frame, result in track_frames(source, _tracker(dataset), timeout_s=0.25, times=times):
        got.append((frame, result))
        spans.append((times.read_s, times.track_s))
    assert isinstance(got[0][0], CaptureFrame) and len(got) == 12
    for (_, a), (_, b) in zip(got, track_frames(io.Dataset(SWEEP), _tracker(dataset))):
        _same_result(a, b)
    assert source.timeouts == [0.25] * 13                          # 12 frames, then the None that ends it
    read_s, track_s = np.array(spans).T
    assert np.all(read_s >= 0) and np.all(track_s > 0)


def test_stops_at_max_frames_without_reading_more():
    dataset = io.Dataset(SWEEP)
    source = ListSource(dataset, dataset.rig)
    got = list(track_frames(source, _tracker(dataset), max_frames=4))
    assert [f.index for f, _ in got] == [0, 1, 2, 3]
    assert len(source.timeouts) == 4 and len(source.frames) == 8
    assert list(track_frames(source, _tracker(dataset), max_frames=0)) == []
    assert len(source.timeouts) == 4


def test_stop_ends_it_between_frames():
    dataset = io.Dataset(SWEEP)
    source = ListSource(dataset, dataset.rig)
    seen = []
    polls = []

    def stop():
        polls.append(len(seen))
        return len(seen) >= 3

    for frame, _ in track_frames(source, _tracker(dataset), stop=stop):
        seen.append(frame.index)
    assert seen == [0, 1, 2]
    assert polls == [0, 1, 2, 3]                                   # polled before every read, the first too
    assert len(source.timeouts) == 3                               # the fourth frame was never read
    assert list(track_frames(source, _tracker(dataset), stop=lambda: True)) == []
    assert len(source.timeouts) == 3


@pytest.mark.slow
def test_an_unreadable_frame_is_reported_and_resets_the_tracker(damaged):
    dataset = io.Dataset(damaged)
    got = list(track_frames(dataset, _tracker(dataset)))
    assert [f.index for f, _ in got] == list(range(12))            # the frames after it are still tracked
    frame, result = got[BAD]
    assert result is None
    assert frame.error.startswith(f"left/{BAD:06d}.png: unreadable")
    assert frame.left is None and frame.right is None
    assert all(r is not None and r.ok for i, (_, r) in enumerate(got) if i != BAD)
    assert got[BAD - 1][1].mode == "track"
    assert got[BAD + 1][1].mode == "acquire"                       # reset: acquired afresh after the gap
    assert got[BAD + 3][1].mode == "track"
    # What every loop did by hand before: reset on an error frame, process the others.
    by_hand = _tracker(dataset)
    for (frame, result), again in zip(got, dataset):
        if again.error is not None:
            by_hand.reset()
            continue
        _same_result(result, by_hand.process(again.left, again.right, again.t, again.t_right))


@pytest.mark.slow
def test_run_source_reports_the_unreadable_frame_as_it_did(damaged):
    dataset = io.Dataset(damaged)
    generator = list(track_frames(dataset, _tracker(dataset)))
    records, results = [], []
    with open_source(str(damaged)) as source:
        stats = run_source(source, tracker=make_tracker(source),
                           on_record=lambda record, result: (records.append(record), results.append(result)))
    assert stats.frames == 12 and stats.ok == 11 and len(stats.track_s) == 12
    bad = records[BAD]
    assert bad["ok"] is False and bad["frame"] == BAD and results[BAD] is None
    assert bad["reason"] == generator[BAD][0].error
    assert bad["position"] is None and bad["axes"] is None
    assert (bad["skew_ms"], bad["dropped"], bad["flags"]) == (None, 0, [])
    for record, (frame, result) in zip(records, generator):
        expected = result_record(frame, result, dataset.screen)
        kept = {k: v for k, v in record.items() if k not in ("timings_ms", "latency_ms", "skew_ms", "dropped",
                                                               "dropped_busy", "flags")}
        expected.pop("timings_ms", None)
        assert kept == expected


def test_a_stalled_camera_frame_resets_the_tracker_and_the_loop_goes_on():
    dataset = io.Dataset(SWEEP)
    frames = list(dataset)
    stall = io.Frame(index=BAD, t=frames[BAD].t, t_right=None, left=None, right=None,
                     error="right camera: no frame for 0.25 s")
    source = ListSource(frames[:BAD] + [stall] + frames[BAD + 1:], dataset.rig)
    got = list(track_frames(source, _tracker(dataset), timeout_s=0.25))
    assert len(got) == 12 and got[BAD][1] is None and got[BAD][0].error == stall.error
    assert got[BAD + 1][1].ok and got[BAD + 1][1].mode == "acquire"
    assert source.status().errors == 1


@pytest.mark.slow
def test_demo_tracker_poses_go_through_the_loop(damaged):
    from headplod.demo.loop import TrackerPoses

    dataset = io.Dataset(damaged)
    expected = list(track_frames(dataset, _tracker(dataset)))
    poses = TrackerPoses(str(damaged))
    got = []
    while (pose := poses.read()) is not None:
        got.append(pose)
    poses.close()
    assert len(got) == 12
    assert not got[BAD].ok and got[BAD].reason == expected[BAD][0].error
    assert "track" not in got[BAD].timings_ms and got[BAD].timings_ms["capture"] >= 0
    for pose, (frame, result) in zip(got, expected):
        assert pose.t == frame.t
        if result is not None:
            np.testing.assert_array_equal(pose.eye_mm, result.position_mm)


def test_demo_tracker_poses_loop_with_times_continuing():
    from headplod.demo.loop import TrackerPoses

    poses = TrackerPoses(str(SWEEP), loop=True, max_frames=15)
    got = []
    while (pose := poses.read()) is not None:
        got.append(pose)
    poses.close()
    assert len(got) == 15 and all(p.ok for p in got)
    t = np.array([p.t for p in got])
    assert np.all(np.diff(t) > 0)
    # The replay goes on one frame period later: the running estimate (from 1/30 s, 0.9 old + 0.1 new)
    # after the 11 gaps of 0.1 s of the first pass.
    period = 1 / 30
    for _ in range(11):
        period = 0.9 * period + 0.1 * 0.1
    assert t[12] == pytest.approx(t[11] + period, abs=1e-12)
    np.testing.assert_allclose(t[13:] - t[12], [0.1, 0.2], atol=1e-12)
