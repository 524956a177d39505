"""opentrack output (angles, datagrams, UDP) and the status line."""
import io
import math
import socket
import struct

import numpy as np
import pytest

from headplod.live.output import OPENTRACK_PACKET_BYTES, OpentrackSender, StatusLine, axes_from_opentrack, decode_opentrack, encode_opentrack, opentrack_values, parse_host_port

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
    assert vals[:3] == pytest.approx((1.0, -2.0, 60.0))
    assert vals[3:] == pytest.approx((0, 0, 0), abs=1e-9)


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
    poses = [([12.0, -30.0, 650.0], (0, 0, 0)), ([-50.0, 20.0, 700.0], (25, -10, 5)),
             ([3.0, 4.0, 500.0], (-60, 35, -20))]
    with OpentrackSender("127.0.0.1", port) as out:
        for position, ypr in poses:
            assert out.send(record(position, axes_from_opentrack(*ypr)))
        assert out.sent == 3
    for position, ypr in poses:
        data, _ = receiver.recvfrom(1024)
        vals = decode_opentrack(data)
        assert vals[:3] == pytest.approx(np.array(position) / 10.0)
        assert vals[3:] == pytest.approx(ypr, abs=1e-9)


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
