"""Tests of headplod.capture: frame sources, the fake-camera V4L2 source, the recorder."""
from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture import CaptureFrame, DatasetRecorder, DatasetSource, FrameSource, SourceOpenError, SyntheticSource, V4L2StereoSource, VideoSource, open_source, record

W, H = 64, 48


def small_rig() -> io.Rig:
    K1 = np.array([[60.0, 0, 32], [0, 61, 24], [0, 0, 1]])
    K2 = np.array([[62.0, 0, 31], [0, 63, 23], [0, 0, 1]])
    R = cv2.Rodrigues(np.array([0.01, 0.15, -0.02]))[0]
    return io.Rig((W, H), K1, np.zeros(5), K2, np.zeros(5), R, np.array([-350.0, -4.0, 27.0]))


def noise_images(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(rng.integers(0, 256, (H, W), dtype=np.uint8), rng.integers(0, 256, (H, W), dtype=np.uint8))
            for _ in range(n)]


def make_dataset(folder: Path, n: int = 5, times: dict | None = None) -> Path:
    """A 64x48 dataset of noise images, optionally with times.csv."""
    (folder / "left").mkdir(parents=True)
    (folder / "right").mkdir()
    io.write_rig(folder / "rig.yaml", small_rig())
    for i, (a, b) in enumerate(noise_images(n)):
        cv2.imwrite(str(folder / "left" / f"{i:06d}.png"), a)
        cv2.imwrite(str(folder / "right" / f"{i:06d}.png"), b)
    if times is not None:
        io.write_times(folder / "times.csv", times)
    return folder


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


def test_dataset_replay_equals_io_dataset(tmp_path):
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


def test_dataset_replay_skew_flag_gaps_and_realtime(tmp_path):
    times = {i: (0.02 * i, 0.02 * i + (0.015 if i == 1 else 0.0)) for i in range(4)}
    folder = make_dataset(tmp_path / "d", n=4, times=times)
    for side in ("left", "right"):
        (folder / side / "000002.png").unlink()                 # a gap: frame 2 lost
    start = time.monotonic()
    with DatasetSource(folder, realtime=True) as source:
        got = list(source)
    elapsed = time.monotonic() - start
    assert [f.index for f in got] == [0, 1, 3]
    assert [f.dropped for f in got] == [0, 0, 1]
    assert got[1].flags == ["skew 15.0 ms > 10.0 ms bound"]      # half of the 20 ms period
    assert elapsed >= 0.055                                    # paced: frame 3 is 60 ms after frame 0


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


def test_video_source_count_times_and_images(tmp_path):
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


def test_video_source_times_csv_beside_and_bad_file(tmp_path):
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


def test_record_then_replay_round_trip(tmp_path):
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


def test_recorder_keeps_rows_written_before_a_crash(tmp_path):
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


class FakeDevice:
    """What the test controls about one device node."""

    def __init__(self, t0: float):
        self.t0 = t0
        self.present = True
        self.delay_s = 0.0          # delivery latency after the frame tick (skew)
        self.fail_grabs = 0         # next grabs that fail (device stays present)
        self.grabs = 0              # grab calls so far
        self.skip_at = None         # (grab number, ticks): that grab skips ticks (lost frames)
        self.stalled = threading.Event()
        self.refuse: set[int] = set()
        self.colour = False
        self.opened = 0


class FakeCamera:
    """A VideoCapture-like camera: frames at ticks of a common clock, FPS from set()."""

    def __init__(self, dev: FakeDevice):
        self.dev = dev
        self.open = dev.present
        self.props = {cv2.CAP_PROP_FPS: 30.0, cv2.CAP_PROP_FRAME_WIDTH: W, cv2.CAP_PROP_FRAME_HEIGHT: H,
                      cv2.CAP_PROP_AUTO_EXPOSURE: 3.0, cv2.CAP_PROP_GAIN: 0.0}
        self.n = 0
        dev.opened += 1

    def isOpened(self):
        return self.open and self.dev.present

    def set(self, prop, value):
        if prop in self.dev.refuse:
            return False
        self.props[prop] = value
        return True

    def get(self, prop):
        return float(self.props.get(prop, 0.0))

    def grab(self):
        dev = self.dev
        while dev.stalled.is_set() and self.open:
            time.sleep(0.005)
        if not self.isOpened():
            time.sleep(0.005)
            return False
        dev.grabs += 1
        if dev.fail_grabs:
            dev.fail_grabs -= 1
            return False
        period = 1.0 / self.props[cv2.CAP_PROP_FPS]
        skip = dev.skip_at[1] if dev.skip_at and dev.skip_at[0] == dev.grabs else 0
        k = math.floor((time.monotonic() - dev.t0) / period) + 1 + skip
        time.sleep(max(0.0, dev.t0 + k * period + dev.delay_s - time.monotonic()))
        self.n += 1
        return self.dev.present

    def retrieve(self):
        img = np.full((H, W), self.n % 256, np.uint8)
        img[0, 0] = 7
        if self.dev.colour:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        return True, img

    def release(self):
        self.open = False


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
    deadline = time.monotonic() + 5.0
    while len(frames) < n and time.monotonic() < deadline:
        f = source.read(timeout_s)
        if f is not None and f.ok:
            frames.append(f)
    assert len(frames) == n, f"only {len(frames)} good frames; status {source.status()}"
    return frames


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


def test_v4l2_pairs_skew_flags_colour_and_close(fakes):
    fakes.left.colour = True
    with open_fake(fakes) as source:
        frames = read_good(source, 8)
        status = source.status()
    assert all(f.left.shape == (H, W) and f.left.dtype == np.uint8 for f in frames)   # colour -> gray
    assert all(f.left[0, 0] == 7 for f in frames)
    assert [f.index for f in frames] == sorted(f.index for f in frames)
    skews = np.array([f.skew_ms for f in frames])
    assert np.median(skews) < 5.0 and status.skew_ms_median < 5.0
    assert all(f.t_monotonic_left is not None and f.t_right - f.t == pytest.approx(
        f.t_monotonic_right - f.t_monotonic_left) for f in frames)
    assert status.state == "running" and 0.6 * FPS < status.fps < 1.4 * FPS

    fakes.right.delay_s = 0.7 * PERIOD              # right frames delivered 28 ms late; bound 20 ms
    with open_fake(fakes) as source:
        frames = read_good(source, 8)
        status = source.status()
    skews = np.array([f.skew_ms for f in frames])
    # (loose bounds: thread scheduling on a busy 2-core machine adds a few ms)
    assert 22.0 < np.median(skews) < 45.0
    flagged = [f for f in frames if f.flags]
    assert len(flagged) >= 5 and flagged[0].flags[0].startswith("skew 2")
    assert flagged[0].flags[0].endswith("> 20.0 ms bound")
    assert sum(f.dropped for f in frames) == 0            # late, but no frame lost
    assert status.skew_ms_p95 >= status.skew_ms_median > 22.0


def test_v4l2_dropped_frames_counted(fakes):
    with open_fake(fakes) as source:
        read_good(source, 3)
        fakes.right.fail_grabs = 1                    # one failed grab on the right camera
        read_good(source, 4)
        at = max(fakes.left.grabs, fakes.right.grabs) + 2       # the same round on both cameras
        fakes.left.skip_at = fakes.right.skip_at = (at, 2)        # both cameras lose 2 frames
        frames = read_good(source, 4)
        status = source.status()
    assert status.dropped == 3
    assert max(f.dropped for f in frames) == 2


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
        assert "right camera /dev/video2: no frame for 0.3 s (stalled)" in f.error
        assert source.status().state == "stalled"
        fakes.right.stalled.clear()
        frames = read_good(source, 3, timeout_s=0.3)
        assert source.status().state == "running"
        assert frames[-1].skew_ms < 10.0
        start = time.monotonic()
    assert time.monotonic() - start < 1.0


def test_v4l2_lost_then_reconnect(fakes):
    source = open_fake(fakes, reconnect_s=0.1)
    try:
        read_good(source, 2)
        fakes.right.present = False                 # unplugged
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:
            f = source.read(timeout_s=0.2)
            if not f.ok:
                break
        assert "right camera /dev/video2: lost (" in f.error and "reconnecting every 0.1 s" in f.error
        assert source.status().state == "lost"
        opened = fakes.right.opened
        fakes.right.present = True                  # plugged back in
        read_good(source, 3, timeout_s=0.3)
        status = source.status()
        assert status.state == "running" and status.reconnects == 1
        assert fakes.right.opened == opened + 1
    finally:
        start = time.monotonic()
        source.close()
        assert time.monotonic() - start < 1.0
    assert source.read() is None and source.status().state == "ended"


def test_v4l2_close_is_prompt_while_a_camera_stalls(fakes):
    source = open_fake(fakes)
    read_good(source, 1)
    fakes.left.stalled.set()
    time.sleep(0.1)
    start = time.monotonic()
    source.close()
    assert time.monotonic() - start < 1.0
    assert source.read() is None


def test_v4l2_cannot_open_is_a_clear_error(fakes):
    fakes.right.present = False
    with pytest.raises(SourceOpenError, match="right camera /dev/video2: device not present"):
        open_fake(fakes)


def test_every_source_is_a_frame_source(tmp_path, fakes):
    folder = make_dataset(tmp_path / "d", n=2)
    with open_source(str(folder)) as a, open_fake(fakes) as b:
        assert isinstance(a, FrameSource) and isinstance(b, FrameSource)
        assert isinstance(next(iter(a)), io.Frame)
