"""Capture that does not wait on the tracker (issue 34): the drop-oldest mailbox, its capture thread, the loop's
drop accounting, and the replays that still track every frame.

No test here sleeps or asserts a race's outcome: the fake source and the fake tracker block on events, and the
test releases them in an order that fixes what the mailbox holds when the tracker comes back for a frame.
"""
from __future__ import annotations

import dataclasses
import os
import signal
import threading
from pathlib import Path

import numpy as np
import pytest

from headplod import io
from headplod.capture import DatasetSource
from headplod.capture.base import CaptureFrame, FrameSource
from headplod.capture.clocked import ClockedReplay
from headplod.capture.mailbox import CaptureThread, FrameMailbox
from headplod.capture.signals import StopSignals
from headplod.live import loop
from headplod.live.loop import make_tracker, run_source

SWEEP = Path(__file__).parent / "data" / "sweep12"
#: Long enough never to expire on a loaded machine: an event that does not come is a failure, not a wait.
WAIT_S = 30.0


def _wait(event: threading.Event) -> None:
    assert event.wait(WAIT_S), "the event never came"


class Ticks:
    """A fake clock: 1.0, 2.0, 3.0, ... one tick per reading."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        self.now += 1.0
        return self.now


# ---------------------------------------------------------------------------
# the mailbox
# ---------------------------------------------------------------------------


def test_a_one_slot_mailbox_keeps_the_newest_and_counts_the_dropped():
    box = FrameMailbox(1, clock=Ticks())
    for name, lost in (("a", 1), ("b", 0), ("c", 2)):
        assert box.put(name, lost=lost)
    got = box.get(0)
    assert got.item == "c" and got.put_s == 3.0          # the third reading of the clock
    assert got.dropped == 2 and got.lost == 3             # a and b pushed out; a's loss is not lost with it
    assert (box.put_count, box.taken, box.dropped) == (3, 1, 2)
    assert box.get(0) is None                             # empty: a zero timeout returns at once


def test_a_larger_mailbox_drops_the_oldest_first_and_hands_out_in_order():
    box = FrameMailbox(2, clock=Ticks())
    for name in "abcd":
        box.put(name)
    first, second = box.get(0), box.get(0)
    assert (first.item, first.dropped) == ("c", 2)        # a then b pushed out, both older than c
    assert (second.item, second.dropped) == ("d", 0)
    assert box.dropped == 2 and len(box) == 0
    box.put("e")
    assert box.get(0).dropped == 0                        # the count restarts after each item taken


def test_a_closed_mailbox_refuses_items_hands_out_what_is_left_then_nothing():
    box = FrameMailbox(2)
    box.put("a")
    box.close()
    assert not box.put("b") and box.put_count == 1
    assert not box.finished and box.get(None).item == "a"
    assert box.finished and box.get(None) is None         # no limit, yet at once: it is finished


def test_close_wakes_a_get_that_waits_without_a_limit():
    box = FrameMailbox(1)
    got = []
    getter = threading.Thread(target=lambda: got.append(box.get(None)))
    getter.start()
    box.close()
    getter.join(WAIT_S)
    assert not getter.is_alive() and got == [None]


def test_the_mailbox_refuses_a_capacity_below_one():
    with pytest.raises(ValueError, match="capacity"):
        FrameMailbox(0)


# ---------------------------------------------------------------------------
# the capture thread, on a fake source whose reads the test releases
# ---------------------------------------------------------------------------


class GatedSource(FrameSource):
    """The frames of sweep12, each read only once the test releases it.

    ``read`` of frame ``i`` sets ``asked[i]`` (so the frame before it has been handed on), then waits for
    ``release[i]``: up to ``stall_s`` (None: as long as it takes), after which it returns a stall error frame
    as a camera would. Past the last frame, or at ``end``, it returns None; ``fail_at`` raises there instead.
    """

    realtime = True

    def __init__(self, n: int, *, end: int | None = None, fail_at: int | None = None,
                 stall_s: float | None = None, ended_by: threading.Event | None = None):
        dataset = io.Dataset(SWEEP)
        super().__init__("gated", dataset.rig, dataset.markers, dataset.screen)
        self.frames = [dataset.frame(i) for i in dataset.indices[:n]]
        self.asked = [threading.Event() for _ in range(n + 1)]
        self.release = [threading.Event() for _ in range(n + 1)]
        self.end, self.fail_at, self.stall_s, self.ended_by = end, fail_at, stall_s, ended_by
        self._next = 0

    def read(self, timeout_s: float = 1.0):
        i = self._next
        self.asked[i].set()
        if self.ended_by is not None and i == self.end:
            self.ended_by.wait()
            return None
        if not self.release[i].wait(self.stall_s):
            return CaptureFrame(index=10_000 + i, t=float("nan"), t_right=None, left=None, right=None,
                                error=f"frame {i}: stalled")
        if i == self.fail_at:
            raise OSError(f"frame {i}: the device is gone")
        if i == self.end or i >= len(self.frames):
            return None
        self._next += 1
        return CaptureFrame.from_frame(self.frames[i], dropped=1 if i == 2 else 0)

    def release_all(self) -> None:
        for event in self.release:
            event.set()


def test_the_capture_thread_hands_the_newest_frame_with_the_drops_before_it():
    source = GatedSource(5, end=3)
    with CaptureThread(source) as reader:
        for i in range(3):                                  # frames 0, 1, 2 read while nobody takes any
            source.release[i].set()
            _wait(source.asked[i + 1])
        frame = reader.read()
        assert frame.index == 2 and frame.dropped_busy == 2
        assert frame.dropped == 1                           # the source's own loss (frame 2 says one) kept apart
        assert frame.t_delivered is not None                # a replay's frame: latency from its delivery
        source.release[3].set()                             # the source ends
        assert reader.read() is None and reader.read() is None
        assert (reader.mailbox.put_count, reader.mailbox.dropped, reader.mailbox.taken) == (3, 2, 1)
    assert not reader.alive and not reader.stuck


def test_a_frame_pushed_out_passes_its_source_losses_to_the_next():
    source = GatedSource(5, end=4)
    with CaptureThread(source) as reader:
        for i in range(4):
            source.release[i].set()
            _wait(source.asked[i + 1])
        frame = reader.read()
        assert (frame.index, frame.dropped_busy, frame.dropped) == (3, 3, 1)   # frame 2's loss went to frame 3
        source.release[4].set()
        assert reader.read() is None


def test_an_exception_of_the_source_reaches_the_reader_after_the_frames_before_it():
    source = GatedSource(5, fail_at=1)
    source.release_all()
    with CaptureThread(source) as reader:
        assert reader.read().index == 0
        with pytest.raises(OSError, match="the device is gone"):
            reader.read()
    assert not reader.alive


def test_stop_ends_a_read_that_waits_and_a_blocked_thread_is_reported_not_waited_for():
    source = GatedSource(3)                                 # nothing released: the thread blocks in read(0)
    stopped = threading.Event()
    reader = CaptureThread(source, stop=stopped.is_set, join_s=0.0)
    _wait(source.asked[0])
    stopped.set()
    assert reader.read() is None
    reader.close()
    assert reader.stuck                                     # blocked in the source: not joined within join_s
    source.release_all()                                    # the read ends, the thread sees it must stop
    reader._thread.join(WAIT_S)                             # (the test's own wait for the thread to end)
    assert not reader.alive and reader.mailbox.put_count == 0


# ---------------------------------------------------------------------------
# the loop: drop accounting, faults, signals
# ---------------------------------------------------------------------------


class GatedTracker:
    """A real tracker whose ``process`` waits, call ``k``, for ``go[k]`` after setting ``busy[k]``."""

    def __init__(self, tracker, calls: int):
        self.tracker = tracker
        self.busy = [threading.Event() for _ in range(calls)]
        self.go = [threading.Event() for _ in range(calls)]
        self.seen: list[float] = []
        self._calls = 0

    def process(self, left, right, t, t_right=None):
        k = self._calls
        self._calls += 1
        self.seen.append(t)
        self.busy[k].set()
        _wait(self.go[k])
        return self.tracker.process(left, right, t, t_right)

    def __getattr__(self, name):
        return getattr(self.tracker, name)


def _run_in_thread(**kwargs):
    out = {}

    def run():
        try:
            out["stats"] = run_source(**kwargs)
        except BaseException as exc:                        # noqa: BLE001 - handed to the test
            out["error"] = exc

    thread = threading.Thread(target=run)
    thread.start()
    return thread, out


def test_frames_that_arrive_while_the_tracker_is_busy_are_dropped_oldest_first_and_counted():
    source = GatedSource(6, end=4)
    tracker = GatedTracker(make_tracker(source), calls=2)
    records = []
    thread, out = _run_in_thread(source=source, tracker=tracker, on_record=lambda r, _: records.append(r))
    source.release[0].set()
    _wait(tracker.busy[0])                                  # frame 0 is being tracked ...
    for i in (1, 2, 3):                                     # ... while frames 1, 2, 3 arrive
        source.release[i].set()
        _wait(source.asked[i + 1])
    tracker.go[0].set()                                     # the tracker comes back: frame 3, the newest
    _wait(tracker.busy[1])
    source.release[4].set()                                 # the source ends
    tracker.go[1].set()
    thread.join(WAIT_S)
    assert not thread.is_alive() and "error" not in out
    stats = out["stats"]
    assert [r["frame"] for r in records] == [0, 3] and [r["dropped_busy"] for r in records] == [0, 2]
    assert records[1]["dropped"] == 1                       # frame 2's own loss, carried by frame 3
    assert all(r["ok"] for r in records)
    s = stats.summary()
    assert (s["frames"], s["dropped_busy"], s["offered"], s["dropped"], s["capture_thread"]) == (2, 2, 4, 1, True)
    assert s["latency_from"] == loop.LATENCY_FROM["delivered"]
    assert not stats.capture_stuck


def test_a_fault_of_the_source_in_the_thread_ends_the_run_after_the_frames_before_it():
    source = GatedSource(5, fail_at=2)
    source.release_all()
    records = []
    with pytest.raises(OSError, match="the device is gone"):
        run_source(source, on_record=lambda r, _: records.append(r))
    assert [r["frame"] for r in records][-1] == 1 and len(records) <= 2   # 0 may be dropped while 1 arrived
    assert not any(t.name == "headplod-capture-mailbox" and t.is_alive() for t in threading.enumerate())


def test_an_exception_in_the_loop_joins_the_capture_thread():
    source = GatedSource(5, stall_s=0.01)                   # a source that reports stalls, as cameras do

    def on_record(record, result):
        raise KeyboardInterrupt                             # e.g. a second Ctrl-C in the middle of a frame

    source.release[0].set()
    stats = loop.LiveStats()
    with pytest.raises(KeyboardInterrupt):
        run_source(source, on_record=on_record, timeout_s=0.01, stats=stats)
    assert stats.capture_thread and not stats.capture_stuck
    assert not any(t.name == "headplod-capture-mailbox" and t.is_alive() for t in threading.enumerate())


class NotedStop(StopSignals):
    """StopSignals that also sets an event when its handler has run."""

    def __init__(self):
        super().__init__()
        self.handled = threading.Event()

    def _handle(self, signum, frame):
        super()._handle(signum, frame)
        self.handled.set()


@pytest.mark.skipif(not hasattr(signal, "pthread_kill"), reason="needs POSIX signals")
def test_sigterm_while_the_loop_waits_for_a_frame_stops_the_run_with_the_records_whole():
    stop = NotedStop()
    source = GatedSource(5, end=1, ended_by=stop.handled)   # after frame 0, the source waits for the signal
    source.release[0].set()
    records, recorded = [], threading.Event()
    sender = threading.Thread(target=lambda: (_wait(recorded), _wait(source.asked[1]),
                                              os.kill(os.getpid(), signal.SIGTERM)))
    with stop:
        sender.start()
        stats = run_source(source, on_record=lambda r, _: (records.append(r), recorded.set()), stop=stop)
    sender.join(WAIT_S)
    assert stop() and stop.name == "SIGTERM"
    assert [r["frame"] for r in records] == [0] and stats.frames == 1
    assert not any(t.name == "headplod-capture-mailbox" and t.is_alive() for t in threading.enumerate())


# ---------------------------------------------------------------------------
# replays for accuracy: every frame, in order, the same bit for bit
# ---------------------------------------------------------------------------


def test_a_replay_for_accuracy_tracks_every_frame_in_order_without_a_thread(monkeypatch):
    def no_thread(*a, **k):
        raise AssertionError("a replay for accuracy must not go through the drop-oldest mailbox")

    monkeypatch.setattr(loop, "CaptureThread", no_thread)
    runs = []
    for _ in range(2):
        records = []
        with DatasetSource(SWEEP) as source:
            stats = run_source(source, on_record=lambda r, _: records.append(r))
        runs.append(records)
        assert not stats.capture_thread and stats.dropped_busy == 0
    assert [r["frame"] for r in runs[0]] == io.Dataset(SWEEP).indices
    assert all(r["dropped_busy"] == 0 for r in runs[0])
    strip = ("latency_ms", "timings_ms")
    assert [{k: v for k, v in r.items() if k not in strip} for r in runs[0]] == \
           [{k: v for k, v in r.items() if k not in strip} for r in runs[1]]


def test_a_live_source_read_frame_by_frame_on_request_drops_nothing():
    source = GatedSource(4)
    source.release_all()
    records = []
    stats = run_source(source, on_record=lambda r, _: records.append(r), drop_when_busy=False)
    assert [r["frame"] for r in records] == [0, 1, 2, 3] and not stats.capture_thread


# ---------------------------------------------------------------------------
# the clocked replay (bench live's camera)
# ---------------------------------------------------------------------------


class FakeClock:
    def __init__(self, now: float = 100.0):
        self.now = now
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += s


def test_the_clocked_replay_releases_a_frame_per_tick_stamped_with_its_tick():
    dataset = io.Dataset(SWEEP)
    frames = [dataset.frame(i) for i in dataset.indices[:4]]
    clock = FakeClock()
    source = ClockedReplay(frames, 120.0, rig=dataset.rig, clock=clock, sleep=clock.sleep)
    first = source.read()
    clock.now += 0.5 / 120                                  # the reader took half a period
    second = source.read()
    clock.now += 3.0 / 120                                  # then fell behind: the next frames are due at once
    rest = [source.read(), source.read()]
    assert source.read() is None and source.closed
    ticks = [f.t_monotonic_left for f in [first, second, *rest]]
    assert ticks == pytest.approx([100.0 + i / 120 for i in range(4)], abs=1e-12)
    assert clock.sleeps == pytest.approx([0.5 / 120])
    assert all(f.time_source == "clock" for f in [first, second, *rest])
    assert [f.t for f in [first, second, *rest]] == [f.t for f in frames]   # the recording's motion kept
    np.testing.assert_array_equal(second.left, frames[1].left)


def test_the_clocked_replay_refuses_a_rate_that_is_not_positive():
    with pytest.raises(ValueError, match="rate_hz"):
        ClockedReplay([], 0.0)


# ---------------------------------------------------------------------------
# the status line
# ---------------------------------------------------------------------------


def test_the_status_line_shows_latency_p50_p99_max_and_the_frames_dropped_while_busy():
    from io import StringIO

    from headplod.live.status import StatusLine

    status = StatusLine(stream=StringIO(), every_s=1.0, window_s=5.0)
    for i in range(100):                                    # latencies 1 .. 100 ms, one slow frame at the end
        status.update({"ok": True}, latency_ms=float(i + 1), dropped_busy=1 if i % 25 == 0 else 0, now=i / 50)
    s = status.summary()
    assert s["dropped_busy"] == 4 and s["dropped"] == 0
    assert (s["latency_ms_median"], s["latency_ms_max"]) == (50.5, 100.0)
    assert s["latency_ms_p99"] == pytest.approx(np.percentile(np.arange(1.0, 101.0), 99))
    line = status.render()
    assert "latency 50.5/99.0/100.0 ms (p50/p99/max)" in line and "dropped 0 | dropped while busy 4" in line
