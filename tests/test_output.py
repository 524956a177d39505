"""opentrack output (angles, datagrams, UDP) and the status line."""
import io
import math
from io import StringIO
import socket
import struct

import numpy as np
import pytest

from headplod.live.opentrack import (OPENTRACK_PACKET_BYTES, axes_from_opentrack, decode_opentrack, encode_opentrack,
                                     opentrack_values, parse_host_port)
from headplod.live.status import StatusLine
from headplod.live.udp import OpentrackSender

# Head facing the cameras: V toward -z, Ψ (up) = -y, Ξ (wearer's left) = +x.
FACING = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def rotation(axis_world, deg):
    """Right-handed rotation by deg about a world axis (Rodrigues)."""
    k = np.asarray(axis_world, float) / np.linalg.norm(axis_world)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


def turned(R_world):
    """Axes of the facing head rotated by R_world (a rotation in the world frame)."""
    return (R_world @ FACING.T).T


def record(position_mm, axes, ok=True):
    return {"frame": 0, "t": 0.0, "ok": ok, "position": list(position_mm),
            "axes": np.asarray(axes).tolist(), "cov": [[1, 0], [0, 1]], "reason": None}


def test_facing_cameras_is_zero():
    vals = opentrack_values([10.0, -20.0, 600.0], FACING)
    assert vals[:3] == pytest.approx((1.0, 2.0, 60.0))  # tracker-pt's axes: y up (world y is down)
    assert vals[3:] == pytest.approx((0, 0, 0), abs=1e-9)


def test_position_axes_are_tracker_pt_or_opencv():
    # tracker-pt (pt-api.cpp to_screen_pos negates the pixel row): x right, y UP, z away from the camera.
    up_right_far = [30.0, -40.0, 700.0]  # world (OpenCV): right of the camera, above it (y < 0), 70 cm away
    x, y, z = opentrack_values(up_right_far, FACING)[:3]
    assert x > 0 and y > 0 and z > 0
    assert opentrack_values(up_right_far, FACING, frame="opencv")[:3] == pytest.approx((3.0, -4.0, 70.0))
    with pytest.raises(ValueError, match="frame"):
        opentrack_values(up_right_far, FACING, frame="opengl")


def test_pivot_is_the_point_sent():
    # Facing the cameras, the head frame (Ξ, Ψ, V) is (+x, -y, -z) of the world: a pivot 80 mm down and
    # 90 mm back of the bridge lies 80 mm lower (world +y) and 90 mm farther (world +z).
    vals = opentrack_values([0.0, 0.0, 600.0], FACING, pivot_mm=(0.0, -80.0, -90.0))
    assert vals[:3] == pytest.approx((0.0, -8.0, 69.0))
    # Turning about the pivot leaves the point sent where it was.
    pivot = np.array([0.0, -80.0, -90.0])
    p1 = np.array([0.0, 0.0, 600.0])
    neck = p1 + FACING.T @ pivot
    for R in (rotation([0, -1, 0], 30), rotation([1, 0, 0], 15)):
        axes = turned(R)
        p1_turned = neck - axes.T @ pivot
        assert np.linalg.norm(p1_turned - p1) > 20.0  # the bridge swings
        assert opentrack_values(p1_turned, axes, pivot_mm=pivot)[:3] == pytest.approx(vals[:3], abs=1e-9)


def test_yaw_sign_turning_left_is_negative():
    # Turning to the wearer's left moves V toward the wearer's left, the world's +x.
    # The wearer's up axis is world -y; a right-handed rotation about -y by +25 deg takes -z to +x.
    axes = turned(rotation([0, -1, 0], 25))
    assert axes[2, 0] > 0  # V now points partly to +x (the cameras' right, the wearer's left)
    yaw, pitch, roll = opentrack_values([0, 0, 500], axes)[3:]
    assert yaw == pytest.approx(-25)
    assert pitch == pytest.approx(0, abs=1e-9)
    assert roll == pytest.approx(0, abs=1e-9)


def test_pitch_sign_looking_up_is_positive():
    # Looking up: V gains a -y (up) component. Rotation about the wearer's left axis (+x) by -20
    # deg takes -z toward -y.
    axes = turned(rotation([1, 0, 0], -20))
    assert axes[2, 1] < 0
    yaw, pitch, roll = opentrack_values([0, 0, 500], axes)[3:]
    assert pitch == pytest.approx(20)
    assert yaw == pytest.approx(0, abs=1e-9)
    assert roll == pytest.approx(0, abs=1e-9)


def test_roll_sign_tilting_left_is_positive():
    # Left ear toward the left shoulder: Ξ (the wearer's left) gains a +y (down) component and Ψ
    # (up) leans toward +x. That is a rotation about the forward axis V = -z.
    axes = turned(rotation([0, 0, -1], -15))
    assert axes[0, 1] > 0 and axes[1, 0] > 0
    yaw, pitch, roll = opentrack_values([0, 0, 500], axes)[3:]
    assert roll == pytest.approx(15)
    assert yaw == pytest.approx(0, abs=1e-9)
    assert pitch == pytest.approx(0, abs=1e-9)


@pytest.mark.parametrize("ypr", [(30, 20, 10), (-120, -45, 170), (5, 80, -60), (179, -1, -179)])
def test_angles_round_trip(ypr):
    axes = axes_from_opentrack(*ypr)
    assert axes @ axes.T == pytest.approx(np.eye(3), abs=1e-12)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    assert opentrack_values([0, 0, 0], axes)[3:] == pytest.approx(ypr, abs=1e-9)


def test_order_is_yaw_then_pitch_then_roll():
    # Intrinsic: yaw about the head's up, then pitch about the yawed lateral axis.
    axes = turned(rotation([0, -1, 0], -40) @ rotation([1, 0, 0], -30))  # turn right 40, then look up 30
    assert opentrack_values([0, 0, 0], axes)[3:] == pytest.approx((40, 30, 0), abs=1e-9)


def test_encode_decode():
    vals = (1.5, -2.25, 60.0, 10.0, -5.0, 3.0)
    data = encode_opentrack(vals)
    assert len(data) == OPENTRACK_PACKET_BYTES == 48
    assert data == struct.pack("<6d", *vals)  # little-endian doubles, TX first
    assert decode_opentrack(data) == vals


@pytest.mark.parametrize("call, match", [
    (lambda: encode_opentrack((1.5, -2.25, 60.0, 10.0, -5.0)), "6 values"),
    (lambda: encode_opentrack((math.nan, -2.25, 60.0, 10.0, -5.0, 3.0)), "finite"),
    (lambda: decode_opentrack(struct.pack("<6d", 1.5, -2.25, 60.0, 10.0, -5.0, 3.0)[:40]), "48 bytes"),
], ids=["five-values", "nan", "short-datagram"])
def test_encode_decode_reject_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.fixture
def receiver():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(2.0)
    yield sock
    sock.close()


def test_udp_round_trip(receiver):
    port = receiver.getsockname()[1]
    # The second pose is 50 mm higher than the first (world y is down), the third 24 mm lower.
    poses = [([12.0, -30.0, 650.0], (0, 0, 0)), ([-50.0, -80.0, 700.0], (25, -10, 5)),
             ([3.0, -6.0, 500.0], (-60, 35, -20))]
    with OpentrackSender("127.0.0.1", port, pivot_mm=(0, 0, 0)) as out:
        for position, ypr in poses:
            assert out.send(record(position, axes_from_opentrack(*ypr)))
        assert out.sent == 3 and out.failed == 0 and out.failure_summary() is None
    received = []
    for position, ypr in poses:
        data, _ = receiver.recvfrom(1024)
        vals = decode_opentrack(data)
        received.append(vals)
        assert vals[:3] == pytest.approx(np.array(position) * [1, -1, 1] / 10.0)
        assert vals[3:] == pytest.approx(ypr, abs=1e-9)
    # Head up, TY up; head down, TY down (tracker-pt's sign).
    assert received[1][1] - received[0][1] == pytest.approx(5.0)
    assert received[2][1] - received[1][1] == pytest.approx(-7.4)


def test_udp_round_trip_truth_head_up_is_ty_up(receiver):
    """Against a synthetic sequence's truth: when the head (P1) rises (world y decreases), TY increases."""
    from headplod import io as hio
    from headplod.capture.synthetic import ensure_dataset

    truth = hio.read_truth(ensure_dataset("pitch_sweep", frames=12, quiet=True) / "truth.csv")
    frames = sorted(truth)
    port = receiver.getsockname()[1]
    with OpentrackSender("127.0.0.1", port, pivot_mm=(0, 0, 0)) as out:  # tracker-pt's axes (the default)
        for f in frames:
            assert out.send(record(*truth[f]))
    ty_cm = np.array([decode_opentrack(receiver.recvfrom(1024)[0])[1] for _ in frames])
    y_world_mm = np.array([truth[f][0][1] for f in frames])
    rises, falls = np.diff(y_world_mm) < -0.5, np.diff(y_world_mm) > 0.5
    assert rises.sum() >= 2 and falls.sum() >= 2  # the head nods: P1 goes up and down
    assert np.all(np.diff(ty_cm)[rises] > 0) and np.all(np.diff(ty_cm)[falls] < 0)
    assert ty_cm == pytest.approx(-y_world_mm / 10.0)


def test_send_failures_are_counted_and_shown():
    # A socket the system refuses every datagram on (PermissionError, as a firewall's EPERM or EACCES).
    class Refusing:
        def __init__(self, sock):
            self._sock = sock

        def send(self, packet):
            raise PermissionError(13, "Permission denied")

        def __getattr__(self, name):
            return getattr(self._sock, name)

    out = StringIO()
    status = StatusLine(stream=out, every_s=0.5)
    with OpentrackSender("255.255.255.255", 4242) as sender:
        sender._sock = Refusing(sender._sock)
        status.sender = sender
        for i in range(5):
            assert sender.send(record([0.0, 0.0, 600.0], FACING)) is False
            status.update({"ok": True}, now=i * 0.2)
        assert sender.failed == 5 and sender.sent == 0
        assert sender.first_error.startswith("255.255.255.255:4242: ") and "ermission" in sender.first_error
        summary = sender.failure_summary()
    assert summary.startswith("udp: 5 of 5 datagrams not sent; first: 255.255.255.255:4242:")
    assert "udp: sending to 255.255.255.255:4242 fails: [Errno 13] Permission denied (" in out.getvalue()
    assert status.summary()["udp_failed"] == 5


def test_opentrack_not_listening_shows_as_it_happens_and_recovery_too():
    """Issue 21: a closed port (opentrack not running) answers with ICMP "port unreachable"; through a
    connected socket that is seen at the next send, and said at once, in the status line and by news()."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()                                         # nothing listens on the port now
    out = StringIO()
    status = StatusLine(stream=out, every_s=1e-9)
    with OpentrackSender("127.0.0.1", port) as sender:
        status.sender = sender
        news = []
        for i in range(4):
            sender.send(record([0.0, 0.0, 600.0], FACING))
            news.append(sender.news())
            status.update({"ok": True}, now=i * 0.1)
        assert sender.refused >= 1 and not sender.listening
        assert news[0] is None                            # the first datagram's refusal is known at the second
        assert news[1] == f"udp: opentrack not listening on 127.0.0.1:{port}; poses are not received (the run goes on)"
        assert news[2:] == [None, None]                   # said once, not per frame
        assert f"udp: opentrack not listening on 127.0.0.1:{port}" in out.getvalue().splitlines()[-1]
        listener = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        listener.bind(("127.0.0.1", port))                # opentrack starts
        try:
            for _ in range(5):
                assert sender.send(record([0.0, 0.0, 600.0], FACING))
                news.append(sender.news())
            assert sender.listening
            assert [n for n in news[4:] if n] == [f"udp: 127.0.0.1:{port} receives the poses again "
                                                  f"({sender.failed} not sent before)"]
            assert len(listener.recv(64)) == OPENTRACK_PACKET_BYTES
        finally:
            listener.close()
    assert "refused: opentrack was not listening" in sender.failure_summary()


def test_failed_record_sends_nothing(receiver):
    port = receiver.getsockname()[1]
    receiver.settimeout(0.2)
    with OpentrackSender("127.0.0.1", port) as out:
        bad = {"frame": 1, "t": 0.0, "ok": False, "position": None, "axes": None, "cov": None,
               "reason": "left image: 4 marker blobs, 5 needed"}
        assert out.send(bad) is False
        assert out.send(record([0, 0, math.nan], FACING)) is False
        # ok false wins even when a (distrusted) pose is present.
        assert out.send(record([0, 0, 600], FACING, ok=False)) is False
        assert out.sent == 0 and out.skipped == 3
    with pytest.raises(socket.timeout):
        receiver.recvfrom(1024)


def test_parse_host_port():
    assert parse_host_port("127.0.0.1:5555") == ("127.0.0.1", 5555)
    assert parse_host_port("gamepc") == ("gamepc", 4242)
    assert parse_host_port("[::1]:4243") == ("::1", 4243)
    assert parse_host_port("::1") == ("::1", 4242)


@pytest.mark.parametrize("text, match", [
    (":4242", "empty host"),
    ("", "empty host"),
    ("host:abc", "integer"),
    ("host:70000", "1..65535"),
    ("host:0", "1..65535"),
], ids=["port-only", "empty", "port-not-a-number", "port-too-large", "port-zero"])
def test_parse_host_port_rejects(text, match):
    with pytest.raises(ValueError, match=match):
        parse_host_port(text)


def test_status_line_rate_and_stats():
    out = io.StringIO()  # not a TTY: one line per rendering
    status = StatusLine(stream=out, every_s=1.0, window_s=5.0)
    lines = []
    for i in range(91):  # 3 s at 30 Hz
        rec = {"ok": i % 10 != 0, "reason": None if i % 10 else f"left image: frame {i} too dark"}
        line = status.update(rec, latency_ms=10.0 + (i % 5), skew_ms=-0.5, dropped=1 if i == 50 else 0,
                             now=100.0 + i / 30.0)
        if line:
            lines.append(line)
    s = status.summary()
    assert s["rate_hz"] == pytest.approx(30.0)
    assert s["frames"] == 91 and s["failed"] == 10 and s["dropped"] == 1
    assert s["latency_ms_median"] == pytest.approx(12.0)
    assert s["skew_ms_max"] == pytest.approx(0.5)
    assert s["last_failure"] == "left image: frame 90 too dark"
    assert len(lines) == 3  # at most once a second
    assert out.getvalue().count("\n") == 3 and "\r" not in out.getvalue()
    assert lines[-1].startswith("30.0 Hz")
    assert "dropped 1" in lines[-1] and "last failure: left image: frame 90 too dark" in lines[-1]
    status.close()


def test_status_line_overwrites_on_a_tty():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    status = StatusLine(stream=out, every_s=0.5)
    for i in range(20):
        status.update({"ok": True}, now=i * 0.1)
    status.close()
    text = out.getvalue()
    assert text.count("\r") == 3 and text.endswith("\n") and text.count("\n") == 1
    assert "10.0 Hz" in text


def test_track_reports_udp_failures_at_the_end(capsys, monkeypatch):
    from headplod.cli import main

    def refused(self, packet):                          # the system refuses every datagram (a firewall)
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(socket.socket, "send", refused)
    code = main(["track", "--source", "synthetic:static", "--frames", "4", "-q", "--udp", "127.0.0.1:4242"])
    err = capsys.readouterr().err
    assert code == 0
    assert "udp: 4 of 4 datagrams not sent; first: 127.0.0.1:4242:" in err
    assert "axes tracker-pt" in err and "(0, -80, -90) mm" in err


@pytest.mark.parametrize("argv, match", [
    (["--pivot", "0,-80"], "X,Y,Z"),
    (["--pivot", "0,-800,-900"], "300 mm"),
    (["--pivot", "0,nan,0"], "finite"),
])
def test_track_pivot_option_refused(capsys, argv, match):
    from headplod.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["track", "--source", "synthetic:static", "--udp", "127.0.0.1:4242", *argv])
    assert exc.value.code == 2 and match in capsys.readouterr().err


def test_track_pivot_without_udp_is_refused(capsys):
    from headplod.cli import main

    assert main(["track", "--source", "synthetic:static", "--pivot", "0,-80,-90"]) == 2
    assert "go with --udp" in capsys.readouterr().err
