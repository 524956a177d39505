"""``headplod track --realtime`` (paced replay) and recentring what is sent to opentrack (issue 25).

Pacing is tested with a fake clock (no wall-clock time is asserted); recentring by its math against
hand-computed values, through a real loopback UDP socket, by SIGUSR1 sent to this process, and by the
key ``c`` in a pseudo-terminal, whose mode must be as it was after the run.
"""
import math
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from headplod import io
from headplod.capture import sources
from headplod.capture.sources import DatasetSource, _Pacer
from headplod.cli import main as cli_main
from headplod.live.loop import run_source
from headplod.live.opentrack import DEFAULT_PIVOT_MM, axes_from_opentrack, decode_opentrack, opentrack_values
from headplod.live.recentre import RecentreControls
from headplod.live.udp import OpentrackSender

REPO = Path(__file__).resolve().parents[1]


class FakeClock:
    """A monotonic clock that moves only when slept on or told to (``advance``)."""

    def __init__(self, start=1000.0):
        self.now = start
        self.sleeps = []

    def __call__(self):
        return self.now

    def sleep(self, s):
        assert s > 0
        self.sleeps.append(s)
        self.now += s

    def advance(self, s):
        self.now += s


def paced(times, work=None, **options):
    """Release frames of ``times`` through a pacer on a fake clock; ``work[i]`` s pass after frame i is
    released (its tracking). Returns the release instants relative to the first, and the clock."""
    clock = FakeClock()
    pacer = _Pacer(True, clock=clock, sleep=clock.sleep, **options)
    released = []
    for i, t in enumerate(times):
        pacer.wait(t)
        released.append(clock.now)
        clock.advance((work or {}).get(i, 0.0))
    return [r - released[0] for r in released], clock, pacer


# ---------------------------------------------------------------------------
# --realtime: the pacer
# ---------------------------------------------------------------------------


def test_frames_are_released_at_their_times_relative_to_the_first():
    times = [5.0, 5.02, 5.04, 5.1, 5.1001]                  # t0 is not zero: only differences count
    released, clock, _ = paced(times, work={0: 0.005, 1: 0.011, 2: 0.002})
    assert released == pytest.approx([t - times[0] for t in times], abs=1e-12)
    # The waits are the spacing less the time the previous frame's work took.
    assert clock.sleeps == pytest.approx([0.015, 0.009, 0.058, 0.0001], abs=1e-12)


def test_slightly_late_frame_keeps_the_schedule_without_a_burst():
    # Frame 1 is 10 ms late (within the 25 ms slack): it goes at once, and frame 2 keeps its own time,
    # waiting 10 ms less; no drift from sleep overshoots.
    released, clock, pacer = paced([0.0, 0.02, 0.04, 0.06], work={0: 0.03})
    assert released == pytest.approx([0.0, 0.03, 0.04, 0.06], abs=1e-12)
    assert pacer.restarts == 0


def test_very_late_frame_restarts_the_schedule_so_the_next_keep_their_spacing():
    # Frame 1 is 200 ms late (a stall): no frame is dropped, none waits for it, and the frames after it
    # are not rushed out back to back to catch up: they keep their 20 ms spacing from frame 1.
    released, clock, pacer = paced([0.0, 0.02, 0.04, 0.06, 0.08], work={0: 0.22})
    assert released == pytest.approx([0.0, 0.22, 0.24, 0.26, 0.28], abs=1e-12)
    assert len(released) == 5 and pacer.restarts == 1
    assert clock.sleeps == pytest.approx([0.02, 0.02, 0.02], abs=1e-12)


def test_slower_than_real_time_never_waits_and_never_drops():
    released, clock, _ = paced([i * 0.01 for i in range(10)], work={i: 0.05 for i in range(10)})
    assert len(released) == 10 and clock.sleeps == []
    assert np.diff(released) == pytest.approx([0.05] * 9)


def test_time_back_non_finite_time_and_long_gap():
    released, clock, pacer = paced([0.0, 0.1, 0.05, math.nan, 0.15, 10.15, 10.25])
    # 0.05 goes back: at once, the schedule restarts there; NaN: at once; 0.15 is 0.1 s after 0.05;
    # the 10 s gap is shortened to max_wait_s (1 s), then 10.25 keeps its 0.1 s spacing.
    assert released == pytest.approx([0.0, 0.1, 0.1, 0.1, 0.2, 1.2, 1.3], abs=1e-12)
    assert max(clock.sleeps) == pytest.approx(1.0)


def test_disabled_pacer_neither_reads_the_clock_nor_sleeps():
    def boom(*a):
        raise AssertionError("clock or sleep used")

    pacer = _Pacer(False, clock=boom, sleep=boom)
    assert pacer.wait(0.0) == 0.0 and pacer.wait(100.0) == 0.0


class FakeTime:
    """Stands in for the ``time`` module of headplod.capture.sources (the pacer's defaults)."""

    def __init__(self):
        self.clock = FakeClock()
        self.monotonic = self.clock
        self.sleep = self.clock.sleep


def test_dataset_source_realtime_paces_every_frame(tmp_path, make_dataset, monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr(sources, "time", fake)
    times = {0: 0.0, 1: 0.04, 2: 0.05, 3: 0.09}
    folder = make_dataset(tmp_path / "d", n=4, times=times)
    with DatasetSource(folder, realtime=True) as source:
        got = [(f.index, fake.clock.now) for f in source]
    assert [i for i, _ in got] == [0, 1, 2, 3]
    assert [now - got[0][1] for _, now in got] == pytest.approx([0.0, 0.04, 0.05, 0.09], abs=1e-12)


@pytest.mark.slow
def test_track_realtime_paces_the_replay(sample, tmp_path, monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr(sources, "time", fake)
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--realtime", "--out", str(out), "-q"]) == 0
    # Read as cameras are (a capture thread, a drop-oldest mailbox): how many frames the tracker had time for
    # is a race, but every frame is tracked or counted as dropped while busy, in order, the last one tracked.
    records = io.read_poses(out)
    assert len(records) + sum(r["dropped_busy"] for r in records) == 12
    frames = [r["frame"] for r in records]
    assert frames == sorted(frames) and frames[-1] == 11
    assert [r["dropped_busy"] for r in records] == [b - a - 1 for a, b in zip([-1] + frames, frames)]
    # The sample's frames are 0.1 s apart (0 .. 1.1 s); the fake clock only moves when slept on.
    assert sum(fake.clock.sleeps) == pytest.approx(1.1, abs=1e-9)
    assert len(fake.clock.sleeps) == 11


@pytest.mark.slow
def test_track_without_realtime_does_not_pace(sample, tmp_path, monkeypatch):
    fake = FakeTime()
    monkeypatch.setattr(sources, "time", fake)
    assert cli_main(["track", "--source", str(sample), "--out", str(tmp_path / "p.jsonl"), "-q"]) == 0
    assert fake.clock.sleeps == []


def test_realtime_is_refused_for_live_cameras(tmp_path, capsys):
    assert cli_main(["track", "--source", "v4l2:0,2", "--calib", str(tmp_path / "rig.yaml"), "--realtime"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--realtime" in err[0] and "live cameras" in err[0]


# ---------------------------------------------------------------------------
# recentring: the math
# ---------------------------------------------------------------------------


def pose_about_neck(neck_mm, yaw, pitch=0.0, roll=0.0, pivot=DEFAULT_PIVOT_MM):
    """(P1, axes) of a head with these opentrack angles whose pivot is at ``neck_mm`` (world, mm)."""
    axes = axes_from_opentrack(yaw, pitch, roll)
    return np.asarray(neck_mm, float) - axes.T @ np.asarray(pivot, float), axes


def rotation(axis_world, deg):
    """Right-handed rotation by deg about a world axis (Rodrigues)."""
    k = np.asarray(axis_world, float) / np.linalg.norm(axis_world)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


A = pose_about_neck([20.0, 40.0, 650.0], yaw=10.0, pitch=-5.0, roll=3.0)


def test_the_centre_itself_is_zero():
    for frame in ("tracker-pt", "opencv"):
        vals = opentrack_values(*A, DEFAULT_PIVOT_MM, frame, centre=A)
        assert vals == pytest.approx((0.0,) * 6, abs=1e-9)


def test_pure_yaw_turn_after_recentring():
    # From A facing 10° right (no pitch or roll), the head turns a further 25° right about its neck: the
    # neck stays, so 0 translation and yaw 25°.
    a = pose_about_neck([20.0, 40.0, 650.0], yaw=10.0)
    b = pose_about_neck([20.0, 40.0, 650.0], yaw=35.0)
    vals = opentrack_values(*b, DEFAULT_PIVOT_MM, centre=a)
    assert vals == pytest.approx((0.0, 0.0, 0.0, 25.0, 0.0, 0.0), abs=1e-9)


def test_yaw_about_the_heads_own_up_axis_when_looking_down():
    # A looks 20° down (at a laptop) and turns 30° to the wearer's right about the head's own up axis:
    # sent as a pure yaw of 30° (the turn in A's frame), not the difference of the angles.
    a = pose_about_neck([0.0, 0.0, 600.0], yaw=0.0, pitch=-20.0)
    up = a[1][1]                                         # Ψ of A, world frame
    axes_b = (rotation(up, -30.0) @ a[1].T).T            # right-handed about up by -30°: a turn to the right
    neck = a[0] + a[1].T @ np.asarray(DEFAULT_PIVOT_MM)
    b = (neck - axes_b.T @ np.asarray(DEFAULT_PIVOT_MM), axes_b)
    vals = opentrack_values(*b, DEFAULT_PIVOT_MM, centre=a)
    assert vals == pytest.approx((0.0, 0.0, 0.0, 30.0, 0.0, 0.0), abs=1e-9)
    raw = np.subtract(opentrack_values(*b, DEFAULT_PIVOT_MM), opentrack_values(*a, DEFAULT_PIVOT_MM))
    assert abs(raw[5]) > 5.0                              # the naive difference would have rolled


def test_pure_translation_after_recentring():
    # The head moves, without turning, 30 mm to the camera's right, 40 mm up (world y is down) and 50 mm
    # away: (3, 4, 5) cm in tracker-pt's axes (y up), (3, -4, 5) in opencv's; no rotation.
    b = (A[0] + np.array([30.0, -40.0, 50.0]), A[1])
    assert opentrack_values(*b, DEFAULT_PIVOT_MM, "tracker-pt", centre=A) == pytest.approx(
        (3.0, 4.0, 5.0, 0.0, 0.0, 0.0), abs=1e-9)
    assert opentrack_values(*b, DEFAULT_PIVOT_MM, "opencv", centre=A) == pytest.approx(
        (3.0, -4.0, 5.0, 0.0, 0.0, 0.0), abs=1e-9)


# ---------------------------------------------------------------------------
# recentring: the sender, the signal, the run
# ---------------------------------------------------------------------------


def record(pose, frame=0, ok=True):
    p, a = pose
    return {"frame": frame, "t": 0.0, "ok": ok, "position": np.asarray(p).tolist(),
            "axes": np.asarray(a).tolist(), "cov": None, "reason": None if ok else "lost"}


@pytest.fixture
def receiver():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    yield sock
    sock.close()


def received(sock):
    return decode_opentrack(sock.recv(64))


def test_sender_recentres_at_the_next_pose_over_loopback(receiver):
    b = (A[0] + np.array([30.0, -40.0, 50.0]), A[1])
    with OpentrackSender("127.0.0.1", receiver.getsockname()[1]) as sender:
        assert sender.send(record(A, 0))
        assert received(receiver) == pytest.approx(opentrack_values(*A, DEFAULT_PIVOT_MM))
        sender.request_recentre("test")
        assert sender.recentre_pending and sender.centre is None
        assert not sender.send(record(A, 1, ok=False))   # tracking lost: nothing sent, the request waits
        assert sender.recentre_pending and "while no pose is tracked" in sender.news()
        assert sender.send(record(A, 2))
        assert received(receiver) == pytest.approx((0.0,) * 6, abs=1e-9)
        assert not sender.recentre_pending and sender.recentred == 1 and sender.recentred_frame == 2
        assert sender.news() == "udp: recentred (test): the pose of frame 2 is now opentrack's zero"
        assert sender.send(record(b, 3))
        assert received(receiver) == pytest.approx((3.0, 4.0, 5.0, 0.0, 0.0, 0.0), abs=1e-9)
        assert sender.news() is None


def test_sigusr1_sets_the_flag_and_the_next_frame_applies_it(receiver):
    b = pose_about_neck([20.0, 40.0, 650.0], yaw=35.0, pitch=-5.0, roll=3.0)
    before = signal.getsignal(signal.SIGUSR1)
    with OpentrackSender("127.0.0.1", receiver.getsockname()[1]) as sender:
        with RecentreControls(sender, stdin=-1) as controls:
            assert not controls.reading_keys                 # no terminal: the signal only
            assert f"kill -USR1 {os.getpid()}" in controls.note()
            assert sender.send(record(A, 0))
            received(receiver)
            os.kill(os.getpid(), signal.SIGUSR1)             # to this process: its handler has run on return
            assert sender.recentre_pending                   # only the flag: nothing was sent or changed
            assert sender.centre is None
            assert sender.send(record(A, 1))
            assert received(receiver) == pytest.approx((0.0,) * 6, abs=1e-9)
            assert sender.send(record(b, 2))
            np.testing.assert_allclose(received(receiver), opentrack_values(*b, DEFAULT_PIVOT_MM, centre=A),
                                       atol=1e-9)
        assert "SIGUSR1" in sender.news()
    assert signal.getsignal(signal.SIGUSR1) == before           # the handler in place before is back


def test_sigusr1_without_a_sender_is_ignored_not_fatal():
    with RecentreControls(None) as controls:
        os.kill(os.getpid(), signal.SIGUSR1)                 # to this process: its handler has run on return
    assert controls.ignored == 1


@pytest.mark.slow
def test_signal_mid_run_recentres_from_the_next_frame(sample, receiver):
    """run_source with a real sender: SIGUSR1 during frame 4's record makes frame 5's pose the zero."""
    got = []
    records = []
    with OpentrackSender("127.0.0.1", receiver.getsockname()[1]) as sender, RecentreControls(sender, stdin=-1):
        def on_record(rec, result):
            records.append(rec)
            got.append(received(receiver))
            if rec["frame"] == 4:
                os.kill(os.getpid(), signal.SIGUSR1)
        with DatasetSource(sample) as source:
            run_source(source, on_record=on_record, sender=sender)
    assert len(got) == len(records) == 12 and all(r["ok"] for r in records)
    pose = {r["frame"]: (r["position"], r["axes"]) for r in records}
    for i in range(5):
        np.testing.assert_allclose(got[i], opentrack_values(*pose[i], DEFAULT_PIVOT_MM), atol=1e-9)
    assert got[5] == pytest.approx((0.0,) * 6, abs=1e-9)
    for i in range(6, 12):
        np.testing.assert_allclose(got[i], opentrack_values(*pose[i], DEFAULT_PIVOT_MM, centre=pose[5]),
                                   atol=1e-9)
    assert sender.recentred_frame == 5


@pytest.mark.slow
def test_recentre_at_start_and_the_records_keep_the_camera_frame(sample, tmp_path, receiver, capsys):
    out, plain = tmp_path / "poses.jsonl", tmp_path / "plain.jsonl"
    port = receiver.getsockname()[1]
    got = []

    def listen():
        try:
            while len(got) < 12:
                got.append(decode_opentrack(receiver.recv(64)))
        except OSError:
            pass

    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    assert cli_main(["track", "--source", str(sample), "--udp", f"127.0.0.1:{port}", "--recentre-at-start",
                     "--out", str(out), "-q"]) == 0
    thread.join(timeout=10)
    err = capsys.readouterr().err
    assert f"kill -USR1 {os.getpid()}" in err
    assert "udp: recentred (--recentre-at-start): the pose of frame 0 is now opentrack's zero" in err
    assert cli_main(["track", "--source", str(sample), "--out", str(plain), "-q"]) == 0
    records = io.read_poses(out)
    keys = ("frame", "t", "ok", "position", "axes", "cov")
    assert [{k: r[k] for k in keys} for r in records] == [{k: r[k] for k in keys} for r in io.read_poses(plain)]
    assert len(got) == 12 and got[0] == pytest.approx((0.0,) * 6, abs=1e-9)
    centre = (records[0]["position"], records[0]["axes"])
    for data, r in zip(got, records):
        np.testing.assert_allclose(data, opentrack_values(r["position"], r["axes"], DEFAULT_PIVOT_MM,
                                                          centre=centre), atol=1e-9)


def test_recentre_at_start_needs_udp(sample, capsys):
    assert cli_main(["track", "--source", str(sample), "--recentre-at-start", "-q"]) == 2
    assert "go with --udp" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# the key c, in a pseudo-terminal
# ---------------------------------------------------------------------------

# The child takes the pty as its controlling terminal (a new session), runs `headplod track`, and says
# whether the terminal's mode after the run is the one before it.
_CHILD = r"""
import os, sys, termios
name = sys.argv[1]
os.setsid()
fd = os.open(name, os.O_RDWR)            # the first terminal opened by a session leader: its controlling one
for target in (0, 1, 2):
    os.dup2(fd, target)
before = termios.tcgetattr(0)
from headplod.cli import main
code = main(sys.argv[2:])
after = termios.tcgetattr(0)
print(f"\nchild: exit {code}; terminal mode {'restored' if after == before else 'CHANGED'}", flush=True)
"""


def _read_until(master, text, timeout_s, buffer, child):
    end = time.monotonic() + timeout_s
    while text not in buffer[0]:
        left = end - time.monotonic()
        if left <= 0:
            raise AssertionError(f"{text!r} not seen; the child wrote:\n{buffer[0]}")
        ready, _, _ = select.select([master], [], [], min(left, 0.2))
        if ready:
            buffer[0] += os.read(master, 4096).decode(errors="replace")
        elif child.poll() is not None:
            raise AssertionError(f"{text!r} not seen; the child ended ({child.returncode}) after:\n{buffer[0]}")


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_key_c_recentres_and_ctrl_c_leaves_the_terminal_as_it_was(long_dataset, receiver):
    master, slave = os.openpty()
    name = os.ttyname(slave)
    port = receiver.getsockname()[1]
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen([sys.executable, "-c", _CHILD, name, "track", "--source", str(long_dataset),
                              "--realtime", "--udp", f"127.0.0.1:{port}", "-q"],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             env=env, cwd=str(REPO))
    buffer = [""]                                         # the slave stays open here: no EIO before the child has it
    try:
        _read_until(master, "recentre: press c here", 60, buffer, child)
        received(receiver)                                # the run is sending (not recentred yet)
        os.write(master, b"c")
        zero = None
        for _ in range(40):                               # the frames until the key is applied
            values = received(receiver)
            if np.allclose(values, 0.0, atol=1e-9):
                zero = values
                break
        assert zero is not None, buffer[0]
        after = received(receiver)                        # relative to the zero: small, not the raw pose
        assert abs(after[2]) < 5.0                        # cm; the raw z is ~60 cm from the camera
        os.write(master, b"\x03")                         # Ctrl-C: SIGINT to the run, a clean stop
        _read_until(master, "child: exit", 30, buffer, child)
    finally:
        try:
            child.wait(timeout=30)
        finally:
            if child.poll() is None:
                child.kill()
            os.close(master)
            os.close(slave)
    out = buffer[0]
    assert "udp: recentred (key c)" in out
    assert "stopped (Ctrl-C)" in out
    assert "child: exit 0; terminal mode restored" in out


def test_a_realtime_replays_latency_leaves_out_its_pacing_wait():
    """--realtime --status used to count each frame's pacing wait as latency (the replay's latency runs from
    the start of reading the frame): a frame held back 490 ms of a 500 ms read is 10 ms late, not 500."""
    from headplod.capture.base import CaptureFrame
    from headplod.live.loop import FrameTimes, _latency_ms

    times = FrameTimes(read_start=100.0, read_end=100.5, read_end_monotonic=50.0)
    paced = CaptureFrame(index=0, t=0.0, t_right=None, left=None, right=None, paced_s=0.49)
    unpaced = CaptureFrame(index=0, t=0.0, t_right=None, left=None, right=None)
    assert _latency_ms(paced, times, now_monotonic=50.002) == pytest.approx(12.0)
    assert _latency_ms(unpaced, times, now_monotonic=50.002) == pytest.approx(502.0)
    live = CaptureFrame(index=0, t=0.0, t_right=None, left=None, right=None, t_monotonic_left=49.99, paced_s=0.3)
    assert _latency_ms(live, times, now_monotonic=50.002) == pytest.approx(12.0)   # a camera's own capture time


def test_a_paced_replay_says_how_long_it_held_each_frame(sample):
    from headplod.capture.sources import DatasetSource

    waits = []
    with DatasetSource(sample, realtime=True) as source:
        source._pacer._clock = lambda: 0.0                  # always early: every frame waits its full period
        source._pacer._sleep = waits.append
        frames = [source.read() for _ in range(3)]
    assert frames[0].paced_s == 0.0
    assert [f.paced_s for f in frames[1:]] == pytest.approx(waits)
    assert all(w > 0 for w in waits)
