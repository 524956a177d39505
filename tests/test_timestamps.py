"""Frame times no camera gives: zero or repeated times dropped, jumps tracked afresh; every frame a record
(issue 15, item 8; issue 21: a clock reset or one far-future time no longer drops the rest of the run).

The rule (``headplod.capture.timestamps``) is applied where every sequence
enters the tracker, so a fake live source, a replayed recording and the
command line treat the same frames the same way. Images are
those of the shared sample dataset (tests/data/sweep12), so the tracker has
something to track; only the times are made bad.
"""
from __future__ import annotations

import io as textio
import shutil
from pathlib import Path

import pytest

from headplod import io
from headplod.capture import DatasetSource, TimestampCheck
from headplod.capture.base import CaptureFrame, FrameSource
from headplod.cli import main as cli_main
from headplod.live.loop import LATENCY_FROM, make_tracker, run_source, track_frames
from headplod.live.status import StatusLine

SWEEP = Path(__file__).parent / "data" / "sweep12"
#: The brief's times, s: a zero, two good ones, a repeat, a backward one, a good one.
TIMES = [0.0, 0.033, 0.066, 0.066, 0.05, 0.1]
DROPPED = [0, 3]          # zero, repeated: not tracked
JUMPED = [4]              # gone back: tracked afresh
KEPT = [1, 2, 4, 5]


class ClockSource(FrameSource):
    """A fake live source: sweep12's images with the given capture times on a camera clock.

    ``left`` / ``right`` are the clock readings (s) of each camera, as a V4L2
    source gives them in ``t_monotonic_left`` / ``t_monotonic_right``, here
    with ``time_source`` ``'driver'`` (the buffer timestamp).
    """

    kind = "clock"

    def __init__(self, left, right=None):
        self.dataset = io.Dataset(SWEEP)
        super().__init__("clock", rig=self.dataset.rig, markers=self.dataset.markers)
        self.times = list(zip(left, right if right is not None else left))
        self.index = 0

    def read(self, timeout_s: float = 1.0):
        if self.index >= len(self.times):
            return None
        i, (tl, tr) = self.index, self.times[self.index]
        self.index += 1
        frame = self.dataset.frame(i)
        return self._emit(CaptureFrame(index=i, t=tl, t_right=tr, left=frame.left, right=frame.right,
                                       t_monotonic_left=tl, t_monotonic_right=tr, skew_ms=abs(tr - tl) * 1e3,
                                       time_source="driver"))


def _dataset(tmp_path: Path, times: list[float]) -> Path:
    """sweep12 cut to len(times) frames, with these times in times.csv (no truth: it needs increasing t)."""
    folder = tmp_path / "bad_times"
    shutil.copytree(SWEEP, folder)
    for side in ("left", "right"):
        for png in (folder / side).glob("*.png"):
            if int(png.stem) >= len(times):
                png.unlink()
    (folder / "truth.csv").unlink(missing_ok=True)
    io.write_times(folder / "times.csv", dict(enumerate(times)))
    return folder


def _run(source):
    status = StatusLine(stream=textio.StringIO(), every_s=1e-9)
    records = []
    stats = run_source(source, on_record=lambda r, _: records.append(r), status=status)
    return stats, status, records


def test_the_check_drops_zero_and_repeated_times_and_leaves_a_backward_one_to_the_tracker():
    check = TimestampCheck()
    frames = [CaptureFrame(index=i, t=t, t_right=t, left=None, right=None, t_monotonic_left=t,
                           t_monotonic_right=t) for i, t in enumerate(TIMES)]
    why = [check.check(f) for f in frames]
    assert [i for i, w in enumerate(why) if w is not None] == DROPPED
    assert (check.dropped, check.zero, check.repeated) == (2, 1, 1)
    assert check.first == "frame 0: left time 0 s (no timestamp)"
    assert check.summary() == ("timestamps: 2 frames dropped (1 zero, 1 repeated); first: frame 0: left time 0 s "
                               "(no timestamp)")


def test_each_camera_is_checked_and_the_message_names_it():
    # The left times are fine; the right camera repeats at frame 2 and goes backwards at frame 3.
    check = TimestampCheck()
    left = [0.01, 0.02, 0.03, 0.04, 0.05]
    right = [0.011, 0.021, 0.021, 0.015, 0.051]
    why = [check.check(CaptureFrame(index=i, t=a, t_right=b, left=None, right=None,
                                    t_monotonic_left=a, t_monotonic_right=b)) for i, (a, b) in
           enumerate(zip(left, right))]
    assert why == [None, None, "frame 2: right time 0.021 s repeats frame 1's (the same image twice)", None, None]
    assert check.check(CaptureFrame(index=5, t=float("nan"), t_right=None, left=None, right=None)) == \
        "frame 5: left time nan (not a time)"


def test_error_frames_are_not_checked_and_do_not_move_the_last_time():
    check = TimestampCheck()
    good = CaptureFrame(index=0, t=1.0, t_right=None, left=None, right=None)
    late_error = CaptureFrame(index=1, t=9.0, t_right=None, left=None, right=None, error="stalled")
    assert check.check(good) is None and check.check(late_error) is None
    assert check.check(CaptureFrame(index=2, t=1.1, t_right=None, left=None, right=None)) is None
    assert check.dropped == 0


def test_a_live_source_gives_every_frame_a_record_and_says_where_latency_starts():
    source = ClockSource(TIMES)
    stats, status, records = _run(source)
    # Every frame read has a record; dropped frames say why and are not tracked; the jump is tracked afresh.
    assert [r["frame"] for r in records] == list(range(len(TIMES)))
    assert [r["frame"] for r in records if r["ok"]] == KEPT
    assert records[0]["reason"] == "frame dropped: frame 0: left time 0 s (no timestamp)"
    assert records[3]["reason"] == "frame dropped: frame 3: left time 0.066 s repeats frame 2's (the same image twice)"
    assert any(f.startswith("time went back 16 ms (t=0.05 s after 0.066 s): motion state reset") for f in records[4]["flags"])
    assert stats.frames == 6 and stats.ok == 4
    s = stats.summary()
    assert (s["time_dropped"], s["time_dropped_first"]) == (2, "frame 0: left time 0 s (no timestamp)")
    assert s["time_jumps"] == 1
    assert s["latency_from"] == LATENCY_FROM["driver"]
    assert "buffer timestamp" in s["latency_from"] and "not mid-exposure" in s["latency_from"]
    # The status line shows the count and the first.
    line = status.render()
    assert "bad time 3 (first: frame 0: left time 0 s (no timestamp))" in line


@pytest.mark.slow
def test_a_replayed_recording_treats_the_same_frames_the_same_way(tmp_path):
    # times.csv: frame 0 at 0 s is the recording's origin (kept); then the brief's times from frame 1:
    # a zero (dropped: not the first frame), two good, a repeat, a backward one, a good one.
    folder = _dataset(tmp_path, [0.0] + TIMES)
    source = DatasetSource(folder)
    assert any("does not increase" in w for w in source.warnings)     # a warning, not a refusal
    stats, status, records = _run(source)
    assert [r["frame"] for r in records] == list(range(len(TIMES) + 1))
    assert [r["frame"] for r in records if r["ok"]] == [0] + [k + 1 for k in KEPT]
    s = stats.summary()
    assert (stats.timestamps.zero, stats.timestamps.repeated, stats.time_jumps) == (1, 1, 1)
    assert s["time_dropped_first"] == "frame 1: left time 0 s (no timestamp)"
    assert s["latency_from"] == LATENCY_FROM[None]
    assert "bad time 3" in status.render()

    # The same images tracked live and replayed give the same poses for the frames kept.
    _, _, live = _run(ClockSource([0.5] + [t + 0.5 if t else 0.0 for t in TIMES]))
    assert [r["frame"] for r in live] == [r["frame"] for r in records]
    for a, b in zip(live, records):
        assert a["ok"] == b["ok"] and a["position"] == b["position"]


def test_track_frames_yields_dropped_frames_as_error_frames_for_a_plain_iterable_too():
    dataset = io.Dataset(SWEEP)
    frames = [dataset.frame(i) for i in range(len(TIMES))]
    for f, t in zip(frames, [0.01, 0.02, 0.02, 0.03, 0.025, 0.04]):
        f.t, f.t_right = t, None
    check = TimestampCheck()
    out = list(track_frames(frames, make_tracker(DatasetSource(SWEEP)), timestamps=check))
    assert [f.index for f, _ in out] == list(range(6))
    assert [f.index for f, r in out if r is None] == [2]                  # the repeat: not tracked
    assert out[2][0].error.startswith("frame dropped: frame 2: left time 0.02 s repeats")
    assert any(n.startswith("time went back") for n in out[4][1].notes)  # 0.025 after 0.03: tracked afresh
    assert check.dropped == 1


@pytest.mark.slow
def test_headplod_track_reports_them_at_the_end(tmp_path, capsys):
    folder = _dataset(tmp_path, [0.0] + TIMES)
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(folder), "--out", str(out), "--status"]) == 0
    err = capsys.readouterr().err
    assert ("timestamps: 2 frames dropped (1 zero, 1 repeated); first: frame 1: left time 0 s "
            "(no timestamp)") in err
    assert "timestamps: 1 discontinuities (a time gone back or far ahead), tracked afresh" in err
    assert "from the start of reading the frame, less a --realtime replay's pacing wait (replay: no capture time)" in err
    assert f"bad_times: 5/{len(TIMES) + 1} frames tracked" in err        # an honest summary: 2 frames dropped
    assert len(out.read_text().splitlines()) == len(TIMES) + 1            # every frame read has its record
