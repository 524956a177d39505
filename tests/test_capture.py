"""Tests of headplod.capture: frame sources, the fake-camera V4L2 source, the recorder."""
from __future__ import annotations

import math
import re
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture import CaptureFrame, DatasetRecorder, DatasetSource, FrameSource, SourceOpenError, SyntheticSource, V4L2StereoSource, VideoSource, open_source, record
from headplod.capture.sources import _Pacer

W, H = 64, 48          # the size of small_rig (conftest.py) and of the fake cameras


def noise_images(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(rng.integers(0, 256, (H, W), dtype=np.uint8), rng.integers(0, 256, (H, W), dtype=np.uint8))
            for _ in range(n)]


def same_frames(a: io.Frame, b: io.Frame) -> None:
    assert (a.index, a.t, a.t_right, a.error) == (b.index, b.t, b.t_right, b.error)
    for x, y in ((a.left, b.left), (a.right, b.right)):
        assert (x is None) == (y is None)
        if x is not None:
            assert x.dtype == np.uint8 and x.shape == (H, W)
            assert np.array_equal(x, y)


# ---------------------------------------------------------------------------
# replay
# ---------------------------------------------------------------------------


def test_dataset_replay_equals_io_dataset(tmp_path, small_rig, make_dataset):
    times = {i: (0.1 * i, 0.1 * i + (0.03 if i == 2 else 0.001)) for i in range(5)}
    folder = make_dataset(tmp_path / "d", times=times)
    (folder / "left" / "000003.png").write_bytes(b"not a png")       # a bad frame
    expected = list(io.Dataset(folder))
    with open_source(str(folder)) as source:
        assert isinstance(source, DatasetSource) and source.rig == small_rig()
        got = list(source)
        assert source.read() is None
        status = source.status()
    assert len(got) == 5 and all(isinstance(f, CaptureFrame) and isinstance(f, io.Frame) for f in got)
    for g, e in zip(got, expected):
        same_frames(g, e)
    assert got[3].error and "left/000003.png" in got[3].error and got[3].skew_ms is None
    # skew from t_right; 30 ms is within the default bound (half the 100 ms period)
    assert got[0].skew_ms == pytest.approx(1.0) and got[2].skew_ms == pytest.approx(30.0)
    assert not any(f.flags for f in got)
    assert status.state == "ended" and status.frames == 4 and status.errors == 1
    assert status.fps == pytest.approx(3 / 0.4)         # good frames 0, 1, 2, 4 over 0.4 s


def test_dataset_replay_skew_flag_gaps_and_realtime(tmp_path, make_dataset):
    times = {i: (0.02 * i, 0.02 * i + (0.015 if i == 1 else 0.0)) for i in range(4)}
    folder = make_dataset(tmp_path / "d", n=4, times=times)
    for side in ("left", "right"):
        (folder / side / "000002.png").unlink()                 # a gap: frame 2 lost
    now, slept = [1000.0], []

    def sleep(s):
        slept.append(s)
        now[0] += s

    with DatasetSource(folder, realtime=True) as source:
        assert source._pacer.enabled                             # the replay is paced ...
        source._pacer = _Pacer(True, clock=lambda: now[0], sleep=sleep)   # ... here on a clock that reading
        got = list(source)                                       # and tracking do not move
    assert [f.index for f in got] == [0, 1, 3]
    assert [f.dropped for f in got] == [0, 0, 1]
    assert got[1].flags == ["skew 15.0 ms > 10.0 ms bound"]      # half of the 20 ms period
    # Paced: frame 1 waits 20 ms after frame 0, frame 3 the 40 ms of the gap; each frame says what it waited.
    assert slept == pytest.approx([0.02, 0.04]) and [f.paced_s for f in got] == pytest.approx([0.0, 0.02, 0.04])


def test_synthetic_source_replays_rendered_dataset(tmp_path):
    with open_source("synthetic:static", frames=2, root=tmp_path) as source:
        assert isinstance(source, SyntheticSource) and "static" in source.name
        frames = list(source)
        expected = list(source.dataset)
    assert len(frames) == 2 and all(f.ok for f in frames)
    for g, e in zip(frames, expected):
        assert np.array_equal(g.left, e.left) and g.t == e.t


def test_open_source_rejects_unknown_specs(tmp_path):
    with pytest.raises(ValueError, match="Accepted forms") as err:
        open_source(str(tmp_path / "nothing-here"))
    for form in ("synthetic:PRESET", "v4l2:/dev/video0,/dev/video2", "DATASET_FOLDER", "LEFT_VIDEO,RIGHT_VIDEO"):
        assert form in str(err.value)
    with pytest.raises(SourceOpenError, match="missing.avi: video file not found"):
        open_source(f"{tmp_path}/missing.avi,{tmp_path}/other.avi")
    with pytest.raises(ValueError, match="unknown synthetic preset"):
        open_source("synthetic:no_such_preset", root=tmp_path)


# ---------------------------------------------------------------------------
# videos
# ---------------------------------------------------------------------------


def write_video(path: Path, images: list[np.ndarray], fps: float) -> bool:
    """Write gray images; FFV1 (lossless) when the wheel has it, else MJPG. True if lossless."""
    for codec, lossless in (("FFV1", True), ("MJPG", False)):
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), fps, (W, H), isColor=False)
        if writer.isOpened():
            for img in images:
                writer.write(img)
            writer.release()
            return lossless
    pytest.skip("no video codec available for cv2.VideoWriter")


def test_video_source_count_times_and_images(tmp_path, small_rig):
    pairs = noise_images(6, seed=3)
    lossless = write_video(tmp_path / "left.avi", [a for a, _ in pairs], 25.0)
    write_video(tmp_path / "right.avi", [b for _, b in pairs] + [pairs[0][1]] * 2, 25.0)   # 2 extra
    spec = f"{tmp_path / 'left.avi'},{tmp_path / 'right.avi'}"
    with open_source(spec, rig=small_rig()) as source:
        assert isinstance(source, VideoSource)
        frames = list(source)
        warnings = list(source.warnings)
    assert len(frames) == 6
    assert [f.t for f in frames] == pytest.approx([i / 25.0 for i in range(6)])
    assert any("left.avi ends after 6 frames" in w and "extra frames are ignored" in w for w in warnings)
    tol = 0 if lossless else 40                               # MJPG changes noise by tens of DN
    for f, (a, b) in zip(frames, pairs):
        assert f.ok and f.left.shape == (H, W) and f.left.dtype == np.uint8
        assert np.abs(f.left.astype(int) - a).max() <= tol
        assert np.abs(f.right.astype(int) - b).max() <= tol


def test_video_source_times_csv_beside_and_bad_file(tmp_path, small_rig):
    pairs = noise_images(3)
    write_video(tmp_path / "l.avi", [a for a, _ in pairs], 30.0)
    write_video(tmp_path / "r.avi", [b for _, b in pairs], 30.0)
    io.write_times(tmp_path / "times.csv", {0: 1.0, 1: 1.05, 2: (1.1, 1.102)})
    io.write_rig(tmp_path / "rig.yaml", small_rig())
    with VideoSource(tmp_path / "l.avi", tmp_path / "r.avi") as source:
        frames = list(source)
        assert source.rig == small_rig()
    assert [f.t for f in frames] == [1.0, 1.05, 1.1]
    assert frames[2].t_right == 1.102 and frames[2].skew_ms == pytest.approx(2.0)
    (tmp_path / "broken.avi").write_bytes(b"\x00" * 100)
    with pytest.raises(SourceOpenError, match="broken.avi: cannot be opened as a video"):
        VideoSource(tmp_path / "broken.avi", tmp_path / "r.avi")


# ---------------------------------------------------------------------------
# recorder
# ---------------------------------------------------------------------------


def test_record_then_replay_round_trip(tmp_path, small_rig, make_dataset):
    src_folder = make_dataset(tmp_path / "src", n=4, times={i: (0.5 + i / 30, 0.5 + i / 30 + 1e-3) for i in range(4)})
    out = tmp_path / "rec"
    with DatasetSource(src_folder) as source:
        summary = record(source, out)
    assert summary.frames == 4 and summary.skipped == 0
    for a, b in zip(io.Dataset(src_folder), io.Dataset(out)):
        same_frames(a, b)
    # an error frame is skipped (and logged), indices stay consecutive, times exact
    good = noise_images(2, seed=5)
    frames = [CaptureFrame(index=10, t=1 / 3, t_right=None, left=good[0][0], right=good[0][1]),
              CaptureFrame(index=11, t=0.4, t_right=None, left=None, right=None,
                           error="right camera 2: no frame for 1.0 s (stalled)"),
              io.Frame(index=12, t=0.7, t_right=0.7001, left=good[1][0], right=good[1][1])]
    with pytest.raises(FileExistsError, match="overwrite=True"):
        DatasetRecorder(out, small_rig())
    with DatasetRecorder(out, small_rig(), overwrite=True) as rec:
        assert [rec.write(f) for f in frames] == [0, None, 1]
    back = list(io.Dataset(out))
    assert [(f.index, f.t, f.t_right) for f in back] == [(0, 1 / 3, None), (1, 0.7, 0.7001)]
    assert np.array_equal(back[1].left, good[1][0]) and np.array_equal(back[1].right, good[1][1])
    assert "source frame 11" in (out / "recording.log").read_text()


def test_recorder_keeps_rows_written_before_a_crash(tmp_path, small_rig):
    rec = DatasetRecorder(tmp_path / "r", small_rig())
    for i, (a, b) in enumerate(noise_images(3)):
        rec.write(io.Frame(index=i, t=i * 0.1, t_right=None, left=a, right=b))
    # not closed (a crash): everything written so far is on disk and readable
    ds = io.Dataset(tmp_path / "r")
    assert len(ds) == 3 and ds.times[2] == (0.2, None) and not ds.warnings
    rec.close()


# ---------------------------------------------------------------------------
# V4L2 with fake cameras
# ---------------------------------------------------------------------------

FPS = 25.0
PERIOD = 1.0 / FPS
#: How long the tests wait for something that takes a few frame periods at most. Only a machine
#: stalled for this long fails them; nothing is asserted about how fast it happens.
PATIENCE_S = 10.0


class FakeDevice:
    """What the test controls about one device node.

    Frames follow a clock common to both devices: frame k is exposed at
    ``t0 + k / fps + offset_s`` and delivered ``latency_s`` later. Like a UVC
    driver, the camera reports the exposure time as ``CAP_PROP_POS_MSEC`` (in
    the clock of ``time.monotonic()``), so the times, skews and rates the source
    measures are the fake's, exactly, whatever the load on the machine.
    """

    def __init__(self, t0: float):
        self.t0 = t0
        self.present = True
        self.offset_s = 0.0         # exposure time after the common frame tick (what the skew measures)
        self.latency_s = 0.0        # delivery after the exposure
        self.timestamps = True      # report exposure times as CAP_PROP_POS_MSEC
        self.clock_offset_s = 0.0   # ... in a clock this far ahead of time.monotonic()
        self.fail_grabs = 0         # next grabs that fail (device stays present)
        self.grabs = 0              # grab calls so far
        self.skip_at = None         # (grab number, ticks): that grab skips ticks (lost frames)
        self.stalled = threading.Event()
        self.blocked = threading.Event()    # set while a grab() is held by `stalled`
        self.refuse: set[int] = set()
        self.colour = False
        self.opened = 0
        self.cameras: list[FakeCamera] = []


class FakeCamera:
    """A VideoCapture-like camera: frames at ticks of a common clock, FPS from set().

    Image number n (1, 2, ...) has the value n % 256 in every pixel but the
    first (7); ``exposures[n]`` is its exposure time.
    """

    def __init__(self, dev: FakeDevice):
        self.dev = dev
        self.open = dev.present
        self.props = {cv2.CAP_PROP_FPS: 30.0, cv2.CAP_PROP_FRAME_WIDTH: W, cv2.CAP_PROP_FRAME_HEIGHT: H,
                      cv2.CAP_PROP_AUTO_EXPOSURE: 3.0, cv2.CAP_PROP_GAIN: 0.0}
        self.n = 0
        self.exposures: dict[int, float] = {}
        self.released = threading.Event()
        dev.opened += 1
        dev.cameras.append(self)

    def isOpened(self):
        return self.open and self.dev.present

    def set(self, prop, value):
        if prop in self.dev.refuse:
            return False
        self.props[prop] = value
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_POS_MSEC:
            if not (self.dev.timestamps and self.n):
                return 0.0
            return 1000.0 * (self.exposures[self.n] + self.dev.clock_offset_s)
        return float(self.props.get(prop, 0.0))

    def grab(self):
        dev = self.dev
        if dev.stalled.is_set():
            dev.blocked.set()
            while dev.stalled.is_set() and self.open:
                time.sleep(0.005)
            dev.blocked.clear()
        if not self.isOpened():
            time.sleep(0.005)
            return False
        dev.grabs += 1
        if dev.fail_grabs:
            dev.fail_grabs -= 1
            return False
        period = 1.0 / self.props[cv2.CAP_PROP_FPS]
        skip = dev.skip_at[1] if dev.skip_at and dev.skip_at[0] == dev.grabs else 0
        # The next frame not yet delivered. When both devices deliver at the same moment
        # (equal offset + latency) the rendezvous releases both threads right after a delivery,
        # a whole period before the next: both then ask for the same frame unless one is held
        # up by more than a period.
        ready = dev.offset_s + dev.latency_s
        k = math.floor((time.monotonic() - dev.t0 - ready) / period) + 1 + skip
        exposure = dev.t0 + k * period + dev.offset_s
        time.sleep(max(0.0, exposure + dev.latency_s - time.monotonic()))
        self.n += 1
        self.exposures[self.n] = exposure
        return self.dev.present

    def retrieve(self):
        img = np.full((H, W), self.n % 256, np.uint8)
        img[0, 0] = 7
        if self.dev.colour:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        return True, img

    def release(self):
        self.open = False
        self.released.set()


def exposure_of(dev: FakeDevice, image: np.ndarray) -> float:
    """The exposure time of an image the device's latest camera delivered (its number is its value)."""
    return dev.cameras[-1].exposures[int(image[1, 1])]


def released_all(fakes) -> bool:
    """Every camera the source opened is released, waiting up to PATIENCE_S for the capture threads."""
    return all(cam.released.wait(PATIENCE_S) for dev in fakes.devices.values() for cam in dev.cameras)


class FakeRig:
    """Two fake devices and the opener / presence functions the source takes."""

    def __init__(self):
        t0 = time.monotonic()
        self.devices = {"/dev/video0": FakeDevice(t0), "/dev/video2": FakeDevice(t0)}
        self.left, self.right = self.devices.values()

    def opener(self, device):
        return FakeCamera(self.devices[device])

    def exists(self, device):
        return self.devices[device].present


@pytest.fixture
def fakes():
    rig = FakeRig()
    yield rig
    for dev in rig.devices.values():         # let blocked fake threads finish
        dev.stalled.clear()
        dev.present = True


def open_fake(fakes, **options) -> V4L2StereoSource:
    options.setdefault("fps", FPS)
    return open_source("v4l2:/dev/video0,/dev/video2", opener=fakes.opener,
                       device_exists=fakes.exists, **options)


def read_good(source, n, timeout_s=1.0):
    frames = []
    deadline = time.monotonic() + PATIENCE_S
    while len(frames) < n and time.monotonic() < deadline:
        f = source.read(timeout_s)
        if f is not None and f.ok:
            frames.append(f)
    assert len(frames) == n, f"only {len(frames)} good frames; status {source.status()}"
    return frames


def missing_frames(frames) -> list[int]:
    """Frames lost before each pair but the first, from the gaps in the exposure times (ground truth)."""
    return [max(round((f.t_monotonic_left - e.t_monotonic_left) / PERIOD),
                round((f.t_monotonic_right - e.t_monotonic_right) / PERIOD)) - 1
            for e, f in zip(frames, frames[1:])]


def test_v4l2_settings_read_back_and_refused_reported(fakes):
    fakes.right.refuse.add(cv2.CAP_PROP_GAIN)
    with open_fake(fakes, width=W, height=H, fourcc="GREY", exposure=50, gain=4) as source:
        report = source.settings_report()
        text = source.settings_report(text=True)
        warnings = list(source.warnings)
    left, right = report["left"], report["right"]
    assert left["auto_exposure"]["actual"] == 1.0           # manual exposure for V4L2
    assert left["fourcc"]["actual"] == "GREY" and left["fourcc"]["accepted"]
    assert left["exposure"] == {"requested": 50.0, "actual": 50.0, "set_ok": True, "accepted": True}
    assert left["gain"]["accepted"] and left["fps"]["actual"] == FPS
    assert right["gain"] == {"requested": 4.0, "actual": 0.0, "set_ok": False, "accepted": False}
    assert warnings == ["right camera /dev/video2: gain requested 4.0, camera reports 0.0 (set() refused it)"]
    assert "REFUSED" in text and text.count("REFUSED") == 1
    with pytest.raises(ValueError, match="fourcc is 'H264'"):
        open_fake(fakes, fourcc="H264")


@pytest.mark.slow
def test_v4l2_pairs_skew_flags_colour_and_times(fakes):
    fakes.left.colour = True
    with open_fake(fakes) as source:
        frames = read_good(source, 8)
        status = source.status()
    assert all(f.left.shape == (H, W) and f.left.dtype == np.uint8 for f in frames)   # colour -> gray
    assert all(f.left[0, 0] == 7 for f in frames)
    assert [f.index for f in frames] == sorted(f.index for f in frames)
    for f in frames:            # the capture times are the driver's timestamps: the exposures
        assert f.t_monotonic_left == pytest.approx(exposure_of(fakes.left, f.left), abs=1e-9)
        assert f.t_monotonic_right == pytest.approx(exposure_of(fakes.right, f.right), abs=1e-9)
        assert f.t_right - f.t == pytest.approx(f.t_monotonic_right - f.t_monotonic_left)
    skews = np.array([f.skew_ms for f in frames])
    # Both cameras expose at the frame ticks: a pair of one tick has no skew at all.
    assert np.median(skews) == pytest.approx(0.0, abs=1e-6)
    assert status.skew_ms_median == pytest.approx(0.0, abs=1e-6)
    # Exact frame times: below 0.6 FPS would take 3 of 8 frames lost.
    assert status.state == "running" and 0.6 * FPS < status.fps < 1.4 * FPS

    # The right camera exposes 0.7 periods (28 ms) after the left one; the bound is half the
    # 40 ms period. Both images are delivered together (the left one 28 ms after its exposure).
    fakes.right.offset_s = fakes.left.latency_s = 0.7 * PERIOD
    with open_fake(fakes) as source:
        frames = read_good(source, 8)
        status = source.status()
    skews = np.array([f.skew_ms for f in frames])
    assert np.median(skews) == pytest.approx(28.0, abs=1e-6)
    flagged = [f for f in frames if f.flags]
    assert len(flagged) >= 5
    for f in frames:
        if f.skew_ms == pytest.approx(28.0, abs=1e-6):
            assert f.flags == ["skew 28.0 ms > 20.0 ms bound"]
    # Late, but no frame lost: the pairs count as dropped exactly the frames missing from the exposure
    # times, none unless the machine holds a capture thread up for a whole frame period.
    assert [f.dropped for f in frames[1:]] == missing_frames(frames)
    assert status.skew_ms_median == pytest.approx(28.0, abs=1e-6)
    assert status.skew_ms_p95 >= status.skew_ms_median


@pytest.mark.parametrize("device, options", [
    (dict(timestamps=False), {}),                 # the driver gives none (POS_MSEC 0)
    (dict(clock_offset_s=3600.0), {}),            # another clock, an hour ahead of time.monotonic()
    (dict(clock_offset_s=-5.0), {}),              # a stale buffer, older than DEVICE_TIME_WINDOW_S
    ({}, dict(device_timestamps=False)),          # good timestamps, turned off
], ids=["no-timestamp", "clock-ahead", "stale", "turned-off"])
def test_v4l2_uses_the_grab_time_without_a_plausible_device_timestamp(fakes, device, options):
    for dev in (fakes.left, fakes.right):
        dev.latency_s = 0.005                     # delivered 5 ms after the exposure
        for key, value in device.items():
            setattr(dev, key, value)
    with open_fake(fakes, **options) as source:
        frames = read_good(source, 4)
    now = time.monotonic()
    for f in frames:
        # grab() returns after the delivery, so the grab time is at least 5 ms after the exposure
        # (the device's time would be the exposure itself), and not later than now; how much later
        # than the exposure depends on the machine.
        assert exposure_of(fakes.left, f.left) + 0.005 <= f.t_monotonic_left <= now
        assert exposure_of(fakes.right, f.right) + 0.005 <= f.t_monotonic_right <= now
        assert f.time_source == "grab"            # what the latency is measured from


def test_v4l2_frames_say_they_carry_the_driver_timestamp(fakes):
    with open_fake(fakes) as source:
        frames = read_good(source, 3)
    from headplod.capture.v4l2 import DEVICE_TIME_WINDOW_S

    for f in frames:
        exposure = exposure_of(fakes.left, f.left)
        if f.time_source == "driver":
            # The fake reports it in ms as OpenCV does (CAP_PROP_POS_MSEC): s -> ms -> s rounds in the last bit.
            assert f.t_monotonic_left == pytest.approx(exposure, rel=0, abs=1e-9)
        else:        # a loaded machine held the grab past the window: the rule falls back to the grab time
            assert f.time_source == "grab" and f.t_monotonic_left - exposure > DEVICE_TIME_WINDOW_S


@pytest.mark.slow
def test_v4l2_dropped_frames_counted(fakes):
    with open_fake(fakes) as source:
        frames = read_good(source, 3)
        fakes.right.fail_grabs = 1                    # one failed grab on the right camera
        frames += read_good(source, 4)
        at = max(fakes.left.grabs, fakes.right.grabs) + 2       # the same round on both cameras
        fakes.left.skip_at = fakes.right.skip_at = (at, 2)        # both cameras lose 2 frames
        frames += read_good(source, 4)
        status = source.status()
    missing = missing_frames(frames)
    # Each pair counts the frames lost before it, no more and no fewer: the failed grab (its round's
    # left image has no partner) and the 2 skipped frames, 3 in all; more only if the machine held a
    # capture thread up for a whole frame period, which loses frames as a slow reader of a camera would.
    assert [f.dropped for f in frames[1:]] == missing
    assert sum(missing) >= 3 and max(missing) >= 2
    assert status.dropped == frames[0].dropped + sum(missing)


@pytest.mark.slow
def test_v4l2_stall_then_recovery(fakes):
    with open_fake(fakes) as source:
        read_good(source, 2)
        fakes.right.stalled.set()
        errors = []
        for _ in range(10):
            f = source.read(timeout_s=0.3)
            if not f.ok:
                errors.append(f)
                break
        assert errors, "no error frame while the right camera stalled"
        f = errors[0]
        assert f.left is None and f.right is None and f.skew_ms is None
        # Silent for at least the read's 0.3 s timeout (longer when the machine is slow).
        silent = re.search(r"right camera /dev/video2: no frame for (\d+\.\d) s \(stalled\)", f.error)
        assert silent and float(silent.group(1)) >= 0.3, f.error
        assert source.status().state == "stalled"
        fakes.right.stalled.clear()
        # (a long read timeout: it is also the silence after which the state says 'stalled')
        frames = read_good(source, 3, timeout_s=PATIENCE_S)
        assert source.status().state == "running"
        assert frames[-1].skew_ms == pytest.approx(0.0, abs=1e-6)
    assert released_all(fakes)          # closed: the capture threads ended and released the cameras
    assert source.read() is None and source.status().state == "ended"


@pytest.mark.slow
def test_v4l2_lost_then_reconnect(fakes):
    source = open_fake(fakes, reconnect_s=0.1)
    try:
        read_good(source, 2)
        fakes.right.present = False                 # unplugged
        lost = None
        deadline = time.monotonic() + PATIENCE_S
        while lost is None and time.monotonic() < deadline:
            f = source.read(timeout_s=0.2)
            if not f.ok and "lost (" in f.error:
                lost = f
        assert lost is not None, f"no 'lost' error frame; status {source.status()}"
        assert "right camera /dev/video2: lost (" in lost.error and "reconnecting every 0.1 s" in lost.error
        assert source.status().state == "lost"
        opened = fakes.right.opened
        fakes.right.present = True                  # plugged back in
        read_good(source, 3, timeout_s=PATIENCE_S)
        status = source.status()
        assert status.state == "running" and status.reconnects == 1
        assert fakes.right.opened == opened + 1
    finally:
        source.close(timeout_s=PATIENCE_S)          # waits for the capture threads (none is stalled)
    # Released when close() returns: the camera lost, the one reopened, and the left one.
    assert all(cam.released.is_set() for dev in fakes.devices.values() for cam in dev.cameras)
    assert source.read() is None and source.status().state == "ended"


@pytest.mark.slow
def test_v4l2_close_does_not_wait_for_a_stalled_camera(fakes):
    """close() gives up on a capture thread stuck in a driver call (it cannot be interrupted) instead of
    hanging with it: the fake's grab() stays blocked until the test ends, so a close() that waited for
    it would never return."""
    source = open_fake(fakes)
    read_good(source, 1)
    fakes.left.stalled.set()
    assert fakes.left.blocked.wait(PATIENCE_S), "the left capture thread never reached grab()"
    closer = threading.Thread(target=source.close, daemon=True)
    closer.start()
    closer.join(PATIENCE_S)
    assert not closer.is_alive(), "close() is waiting for the stalled camera"
    assert fakes.left.blocked.is_set()              # the driver call is still blocked
    assert source.read() is None and source.status().state == "ended"


def test_v4l2_cannot_open_is_a_clear_error(fakes):
    fakes.right.present = False
    with pytest.raises(SourceOpenError, match="right camera /dev/video2: device not present"):
        open_fake(fakes)


def test_every_source_is_a_frame_source(tmp_path, fakes, make_dataset):
    folder = make_dataset(tmp_path / "d", n=2)
    with open_source(str(folder)) as a, open_fake(fakes) as b:
        assert isinstance(a, FrameSource) and isinstance(b, FrameSource)
        assert isinstance(next(iter(a)), io.Frame)
