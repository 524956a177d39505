"""``headplod preview``'s window (issue 36): under a virtual X server it opens, draws the labelled markers where
the truth puts them (read back from its own framebuffer), and closes on its key sent as a real X event; its keys
change a fake V4L2 camera's exposure, the threshold, and write the config file.

Xvfb and xdotool come from setup.sh (Debian's xvfb and xdotool); without them those tests skip, saying so.
"""
import os
import re
import shutil
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture.v4l2 import V4L2StereoSource
from headplod.tracking.detect import DetectionParams
from headplod.live.preview import Previewer
from headplod.live.preview_controls import Controls
from headplod.live.preview_picture import _BLOB, _MARKER_NO_POSE, _MARKER_OK, _font_scale, _text, composite_size

ROOT = Path(__file__).resolve().parents[1]
#: The virtual screen: larger than the preview of a 640x480 pair (1280 x 658 px).
SCREEN = "1600x1200x24"
#: Longest wait for a subprocess or the X server, s (a bound on a hang, not a measured figure).
HANG_S = 120


def _truth_px(dataset: io.Dataset, index: int) -> np.ndarray:
    """The true P0..P4 of a frame in both images, (2, 5, 2) px, from truth.csv through the rig."""
    rig, model = dataset.rig, np.asarray(dataset.markers.points_mm, float)
    position, axes = dataset.truth[index]
    world = position + model @ axes
    left = cv2.projectPoints(world, np.zeros(3), np.zeros(3), rig.K1, rig.D1)[0].reshape(-1, 2)
    right = cv2.projectPoints(world, cv2.Rodrigues(rig.R)[0], rig.T, rig.K2, rig.D2)[0].reshape(-1, 2)
    return np.stack([left, right])


@pytest.fixture(scope="module")
def display():
    """A virtual X server on a free display number (Xvfb picks it: -displayfd); its DISPLAY."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("no Xvfb binary (setup.sh installs Debian's xvfb package)")
    read, write = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write), "-screen", "0", SCREEN, "-nolisten", "tcp"],
                            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.close(write)
    with os.fdopen(read) as f:            # Xvfb writes the number once it accepts clients
        number = f.readline().strip()
    if not number.isdigit():
        proc.kill()
        pytest.fail(f"Xvfb did not start: {proc.communicate()[1].decode(errors='replace')[-500:]}")
    yield f":{number}"
    proc.terminate()
    proc.wait(HANG_S)


def _headplod(args, display, cwd, **kwargs):
    env = dict(os.environ, DISPLAY=display, PYTHONPATH=str(ROOT))
    return subprocess.Popen([sys.executable, "-c", "import sys; from headplod.cli import main; sys.exit(main())",
                             *args], env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **kwargs)


def _cross_centres(picture: np.ndarray) -> np.ndarray:
    """The centres (u, v) px of the blob crosses drawn in ``picture`` (a pixel of the blob colour whose four
    neighbours are of it too: the crosses' 5 px arms), (n, 2)."""
    blob = np.all(picture == np.array(_BLOB, np.uint8), axis=2)
    centre = blob[1:-1, 1:-1] & blob[:-2, 1:-1] & blob[2:, 1:-1] & blob[1:-1, :-2] & blob[1:-1, 2:]
    v, u = np.nonzero(centre)
    return np.column_stack([u + 1, v + 1]).astype(float)


def _label_offset(picture: np.ndarray, label: str, u: float, v: float, width: int):
    """Where the label ``label`` of a marker at (u, v) px lies in ``picture`` against where the preview draws it
    for a marker exactly there: the best (du, dv) px within 2 px and the fraction of its box's pixels that match."""
    scale = _font_scale(width)
    best = (None, 0.0)
    for colour in (_MARKER_OK, _MARKER_NO_POSE):
        template = np.zeros_like(picture)
        _text(template, label, int(round(u - 12 * scale)), int(round(v - 14 * scale - 4)), scale, colour)
        ys, xs = np.nonzero(np.any(template != 0, axis=2) | _box(template))
        for dv in range(-2, 3):
            for du in range(-2, 3):
                got = picture[ys + dv, xs + du].astype(int)
                match = float(np.mean(np.all(np.abs(got - template[ys, xs]) <= 8, axis=1)))
                if match > best[1]:
                    best = ((du, dv), match)
    return best


def _box(template: np.ndarray) -> np.ndarray:
    """The text's black box: the bounding rectangle of the drawn text, grown by its 2 px margin."""
    drawn = np.any(template != 0, axis=2)
    box = np.zeros_like(drawn)
    ys, xs = np.nonzero(drawn)
    box[ys.min() - 2:ys.max() + 1, xs.min() - 2:xs.max() + 3] = True
    return box


def test_the_window_draws_the_labelled_markers_where_the_truth_is(display, sweep12_dir, tmp_path):
    """--frames N closes the window by itself; its framebuffer, read back, holds each true marker's cross within
    1 px and its label P0..P4 where the preview draws it for the true position (within 1 px)."""
    snapshot = tmp_path / "window.png"
    proc = _headplod(["preview", "--source", str(sweep12_dir), "--frames", "3", "--snapshot", str(snapshot),
                      "--no-config", "-q"], display, tmp_path)
    out, err = proc.communicate(timeout=HANG_S)
    assert proc.returncode == 0, err
    shown = re.search(r"showed 3 frames \(the last: frame (\d+)\)", out)
    assert shown, out
    picture = io.read_image(snapshot, cv2.IMREAD_COLOR)
    dataset = io.Dataset(sweep12_dir)
    w, h = dataset.rig.image_size
    assert (picture.shape[1], picture.shape[0]) == composite_size(w, h)      # drawn 1:1
    truth = _truth_px(dataset, int(shown.group(1)))
    for cam in range(2):
        view = picture[:h, cam * w:(cam + 1) * w]
        crosses = _cross_centres(view)
        for k, (u, v) in enumerate(truth[cam]):
            nearest = crosses[np.argmin(np.linalg.norm(crosses - (u, v), axis=1))]
            assert np.abs(nearest - (u, v)).max() <= 1.0, (cam, k, nearest, (u, v))
            labels = {j: _label_offset(view, f"P{j}", u, v, w) for j in range(5)}
            (du, dv), match = labels[k]
            assert match >= 0.9 and max(abs(du), abs(dv)) <= 1, (cam, k, labels[k])
            assert all(labels[j][1] < match for j in labels if j != k), (cam, k, labels)


def test_the_window_closes_on_its_key_and_its_keys_write_the_config(display, sweep12_dir, tmp_path):
    """Real X key events (xdotool): T raises the threshold, w writes it into ./headplod.toml, q closes the window
    (without --frames, a replay's last picture stays up until then, drawn again at the new threshold: the
    window's last picture is the preview's own of the last frame at 45 DN, not at 40)."""
    xdotool = shutil.which("xdotool")
    if xdotool is None:
        pytest.skip("no xdotool binary (setup.sh installs Debian's xdotool package)")
    snapshot = tmp_path / "window.png"
    proc = _headplod(["preview", "--source", str(sweep12_dir), "--no-config", "-q", "--threshold", "40",
                      "--snapshot", str(snapshot)], display, tmp_path)
    try:
        env = dict(os.environ, DISPLAY=display)
        found = subprocess.run([xdotool, "search", "--sync", "--name", "^headplod preview: "], env=env,
                               capture_output=True, text=True, timeout=HANG_S)
        window = found.stdout.split()[0]      # the title has the values once a picture is up: keys are heard
        subprocess.run([xdotool, "search", "--sync", "--name", "the recording ended"], env=env, check=True,
                       capture_output=True, timeout=HANG_S)
        assert proc.poll() is None            # without --frames only a key ends it
        subprocess.run([xdotool, "key", "--window", window, "shift+t"], env=env, check=True, timeout=HANG_S)
        # The title says 45 DN once the key was handled: a picture at it is drawn before the next keys are.
        subprocess.run([xdotool, "search", "--sync", "--name", "threshold 45 DN"], env=env, check=True,
                       capture_output=True, timeout=HANG_S)
        sent = [subprocess.run([xdotool, "key", "--window", window, key], env=env, capture_output=True, text=True,
                               timeout=HANG_S) for key in ("w", "q")]
        out, err = proc.communicate(timeout=HANG_S)
        assert all(k.returncode == 0 for k in sent), ([k.stderr for k in sent], out, err)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "closed with q" in out
    assert "preview: threshold 45 DN" in err
    assert tomllib.loads((tmp_path / "headplod.toml").read_text()) == {"threshold": 45}
    last = int(re.search(r"\(the last: frame (\d+)\)", out).group(1))
    dataset = io.Dataset(sweep12_dir)
    frame = next(f for f in dataset if f.index == last)
    w, h = dataset.rig.image_size
    shown = io.read_image(snapshot, cv2.IMREAD_COLOR)[:h]          # the images; the panel has the rate
    for threshold, same in ((45.0, True), (40.0, False)):
        own = Previewer(dataset.rig, dataset.markers, DetectionParams(threshold_dn=threshold)).picture(frame)[0]
        assert np.array_equal(shown, own[:h]) == same, threshold


# ---------------------------------------------------------------------------
# the keys on a fake V4L2 camera
# ---------------------------------------------------------------------------

class FakeCapture:
    """A V4L2 camera as OpenCV's VideoCapture: records every set(prop, value); frames of a 64x48 gray image."""

    def __init__(self, values):
        self.values = dict(values)
        self.sets: list[tuple[int, float]] = []
        self.frame = threading.Event()

    def isOpened(self):
        return True

    def set(self, prop, value):
        self.sets.append((prop, float(value)))
        self.values[prop] = float(value)
        return True

    def get(self, prop):
        return self.values.get(prop, -1.0)

    def grab(self):
        self.frame.wait(0.01)     # a camera's pace, without spinning; nothing sets it
        return True

    def retrieve(self):
        return True, np.zeros((48, 64), np.uint8)

    def release(self):
        pass


@pytest.fixture
def fake_cameras():
    caps = []

    def opener(device):
        caps.append(FakeCapture({cv2.CAP_PROP_EXPOSURE: 100.0, cv2.CAP_PROP_GAIN: 4.0, cv2.CAP_PROP_FPS: 30.0}))
        return caps[-1]
    source = V4L2StereoSource("/dev/fake0", "/dev/fake1", opener=opener, device_exists=lambda d: True)
    yield source, caps
    source.close()


def test_the_exposure_key_reaches_a_fake_v4l2_camera_through_the_window(display, fake_cameras, tmp_path,
                                                                       monkeypatch):
    """E on the window (its own key handler, the pyglet window on the virtual X server: moderngl-window's
    headless backend has no letter keys) sets manual exposure and 100 x 1.25 on both cameras; e brings it back;
    the values are kept for a camera that reopens."""
    pytest.importorskip("moderngl_window")
    from headplod.live.preview_window import PreviewWindow

    monkeypatch.setenv("DISPLAY", display)
    source, caps = fake_cameras
    controls = Controls(source, config_path=lambda: tmp_path / "headplod.toml")
    window = PreviewWindow((64, 48), controls)
    try:
        keys = window.wnd.keys
        window.on_key(keys.E, keys.ACTION_PRESS, SimpleNamespace(shift=True, ctrl=False, alt=False))
        for cap in caps:
            assert (cv2.CAP_PROP_AUTO_EXPOSURE, 1.0) in cap.sets and cap.sets[-1] == (cv2.CAP_PROP_EXPOSURE, 125.0)
        assert window.messages == ["exposure 125 (cameras report 125, 125)"]
        window.on_key(keys.E, keys.ACTION_PRESS, SimpleNamespace(shift=False, ctrl=False, alt=False))
        assert all(cap.sets[-1] == (cv2.CAP_PROP_EXPOSURE, 100.0) for cap in caps)
        assert source._requested["exposure"] == 100.0 and source._requested["auto_exposure"] == 1
        window.on_key(keys.Q, keys.ACTION_PRESS, SimpleNamespace(shift=False, ctrl=False, alt=False))
        assert window.closed_by == "q" and window.wnd.is_closing
    finally:
        window.close()


def test_the_keys_change_gain_and_threshold_and_write_only_their_keys(fake_cameras, tmp_path):
    """g/G step the gain from the camera's own value, t/T the threshold from the one the frame used; w sets
    exposure, gain and threshold at the config's top level (and in the table that would win) and keeps the rest."""
    source, caps = fake_cameras
    config = tmp_path / "headplod.toml"
    config.write_text('# my cameras\nsource = "v4l2:0,2"\ngain = 1\n\n[preview]\ngain = 2\nfps = 60\n')
    applied = []
    controls = Controls(source, set_threshold=applied.append, measured_threshold=lambda: 23.4,
                        config_path=lambda: config)
    assert controls.press("G").message == "gain 5 (cameras report 5, 5)"
    assert all(cap.sets[-1] == (cv2.CAP_PROP_GAIN, 5.0) for cap in caps)
    assert controls.press("t").message == "threshold 18 DN" and applied == [18.0]
    assert controls.press("w").message.startswith("wrote threshold 18, gain 5 to ")
    text = config.read_text()
    assert text.startswith("# my cameras\n")
    assert tomllib.loads(text) == {"source": "v4l2:0,2", "gain": 5, "threshold": 18,
                                   "preview": {"gain": 5, "fps": 60}}
    replay = Controls(None)
    assert replay.press("e").message.startswith("exposure: live cameras only") and not replay.press("x").message


def test_a_config_that_is_not_toml_is_left_as_it_is(tmp_path):
    config = tmp_path / "headplod.toml"
    config.write_text("gain = 1\ngain = 2\n")
    result = Controls(None, measured_threshold=lambda: 30.0, config_path=lambda: config).press("w")
    assert result.message.startswith("config not written: ") and "not valid TOML" in result.message
    assert config.read_text() == "gain = 1\ngain = 2\n"


# ---------------------------------------------------------------------------
# no window
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("display_value, status, says", [
    (None, 2, "no window can be shown: there is no display (DISPLAY is not set); write the pictures with --out DIR"),
    (":999", 1, "the window: cannot open a window on DISPLAY :999 ("),
])
def test_without_a_display_the_preview_says_to_use_out(sweep12_dir, tmp_path, display_value, status, says):
    """No DISPLAY: a usage refusal (2) before the source is opened; a DISPLAY with no X server there: one line
    naming it (1). Both say to write the pictures with --out DIR."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if display_value:
        env["DISPLAY"] = display_value
    env["PYTHONPATH"] = str(ROOT)
    done = subprocess.run([sys.executable, "-c", "import sys; from headplod.cli import main; sys.exit(main())",
                           "preview", "--source", str(sweep12_dir), "--no-config", "-q"], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=HANG_S)
    lines = done.stderr.splitlines()
    assert done.returncode == status and len(lines) == 1, done.stderr
    assert lines[0].startswith("headplod: preview: " + says) and "--out DIR" in lines[0], lines[0]
    assert list(tmp_path.iterdir()) == []


def test_what_w_writes_is_what_the_next_run_reads(tmp_path):
    """The keys w writes go through the config file's own checks: preview and track on live cameras take the
    threshold (a number, or 'adaptive'), exposure and gain; a recording keeps its own."""
    from headplod import cli, config

    path = tmp_path / "headplod.toml"
    path.write_text('source = "v4l2:0,2"\n')
    Controls(None, threshold_dn=45.0, config_path=lambda: path).press("w")
    io.set_toml_keys(path, {"exposure": 120, "gain": 3})
    for command in ("preview", "track"):
        args = config.parse_args(cli.build_parser(), [command, "--config", str(path), "-q"])
        assert (args.threshold, args.exposure, args.gain) == (45.0, 120.0, 3.0)
        replay = config.parse_args(cli.build_parser(), [command, "--config", str(path), "--source", "synthetic",
                                                        "-q"])
        assert (replay.threshold, replay.exposure) == (None, None)
    Controls(None, config_path=lambda: path).press("w")
    assert config.parse_args(cli.build_parser(), ["preview", "--config", str(path), "-q"]).threshold is None
    assert tomllib.loads(path.read_text())["threshold"] == "adaptive"
