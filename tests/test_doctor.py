"""``headplod doctor`` (issue 25): simulated machines, each check's status and fix, and one real run.

A :class:`~headplod.doctor.machine.Machine` made of fakes stands for a machine: two
UVC webcams (a capture and a metadata node each), a user outside the video
group, a stale or poor rig, no libusb, no EGL, a camera that offers only
MJPG at 60 fps. The V4L2 enumeration ioctls are tested against a fake driver
that fills the kernel's structs as ``uvcvideo`` does.
"""
from __future__ import annotations

import argparse
import errno
import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from headplod import doctor as dr
from headplod.doctor.checks import judge_formats
from headplod.doctor.machine import (ConfigDefaults, DoctorSettings, GroupInfo, Machine, config_from_args,
                                    video_group_info)
from headplod import io
from headplod.capture import formats as v4l2fmt
from headplod.capture.formats import FrameSize, PixelFormat
from headplod.capture.usb import CameraInfo, LibusbMissingError
from headplod.cli import main as cli_main

NOW = 1_800_000_000.0            # the fake clock, s since the epoch


def _parses(fix: str) -> None:
    """A fix that is a headplod command line is one the parser takes, in today's spelling (no old-spelling
    note), with numbers for its placeholders N, M, S."""
    import contextlib
    import io as _io
    import shlex

    from headplod.cli import build_parser

    words = ["8" if w in ("N", "M", "S") else w for w in shlex.split(fix[fix.index("headplod "):].split(";")[0])]
    assert words[0] == "headplod", fix
    err = _io.StringIO()
    with contextlib.redirect_stderr(err):
        build_parser().parse_args(words[1:])
    assert "note:" not in err.getvalue(), (fix, err.getvalue())
DAY = 86400.0


# ---------------------------------------------------------------------------
# a simulated machine
# ---------------------------------------------------------------------------

def _node(n, index, serial="ABC123", port="1-2"):
    return CameraInfo(device=f"/dev/video{n}", name="C270 HD WEBCAM", vendor_id=0x046D, product_id=0x0825,
                      serial=serial, port_path=port, bus=1, address=5 + n, index=index)


LEFT_NODES = [_node(0, 0, "ABC123", "1-2"), _node(1, 1, "ABC123", "1-2")]
RIGHT_NODES = [_node(2, 0, "XYZ789", "1-3"), _node(3, 1, "XYZ789", "1-3")]


def good_formats(device, sizes):
    """A camera offering GREY and YUYV at 60 fps and MJPG at 90 fps at 640x480."""
    return [PixelFormat("YUYV", "YUYV 4:2:2", False, (FrameSize(640, 480, (60.0, 30.0)),
                                                      FrameSize(1280, 720, (10.0,)))),
            PixelFormat("GREY", "8-bit Greyscale", False, (FrameSize(640, 480, (60.0,)),)),
            PixelFormat("MJPG", "Motion-JPEG", True, (FrameSize(640, 480, (90.0, 60.0)),))]


class FakeGL:
    def __init__(self, renderer="llvmpipe (LLVM 15.0.6, 256 bits)"):
        self.info = {"GL_RENDERER": renderer, "GL_VERSION": "4.5 (Core Profile) Mesa 22.3.6"}
        self.released = False

    def release(self):
        self.released = True


def machine(nodes=None, **changes) -> Machine:
    """Two cameras, everything in order; ``changes`` replaces any input."""
    nodes = LEFT_NODES + RIGHT_NODES if nodes is None else nodes
    base = dict(
        video_nodes=lambda: list(nodes),
        node_exists=lambda path: path in {n.device for n in nodes},
        open_rw=lambda path: None,
        formats=good_formats,
        usb_cameras=lambda: [n for n in nodes if n.index == 0],
        libusb=lambda: (True, "pyusb backend usb.backend.libusb1: 5 USB devices"),
        groups=lambda: GroupInfo("alice", in_group_db=True, in_session=True),
        clock=lambda: NOW,
        gl_context=FakeGL,
        config=lambda: ConfigDefaults(),
        find_rig=lambda: None,
    )
    base.update(changes)
    return Machine(**base)


def rig_file(tmp_path, name="rig.yaml", age_days=3.0, rms=0.3, cameras=(LEFT_NODES[0], RIGHT_NODES[0]), **extra):
    """A 640x480 rig.yaml calibrated ``age_days`` before NOW (its mtime) with stereo RMS ``rms`` px."""
    K = np.array([[700.0, 0, 320], [0, 700, 240], [0, 0, 1]])
    if rms is not None:
        extra.update(calibration_rms_stereo_px=rms, calibration_rms_left_px=rms * 0.8,
                     calibration_rms_right_px=rms * 0.9)
    if cameras:
        from headplod.capture.usb import identity_of
        extra.update(left_camera=identity_of(cameras[0]), right_camera=identity_of(cameras[1]))
    path = tmp_path / name
    io.write_rig(path, io.Rig((640, 480), K, np.zeros(5), K, np.zeros(5), np.eye(3), np.array([-300.0, 0, 0]),
                              extra=extra))
    stamp = NOW - age_days * DAY
    os.utime(path, (stamp, stamp))
    return path


def by_check(results):
    out = {}
    for r in results:
        assert r.check not in out, f"two lines for {r.check}"
        out[r.check] = r
    return out


def run(m, **kw):
    return by_check(dr.doctor(m, **kw))


def _oserror(code):
    def open_rw(path):
        raise OSError(code, os.strerror(code), path)
    return open_rw


# ---------------------------------------------------------------------------
# whole machines
# ---------------------------------------------------------------------------

def test_a_machine_in_order_is_all_ok_and_exits_0(tmp_path, capsys):
    rig = rig_file(tmp_path)
    results = run(machine(), calib=str(rig))
    assert {k: r.status for k, r in results.items()} == {
        "config": "skip", "video devices": "ok", "video group": "ok", "device access": "ok",
        "formats /dev/video0": "ok", "formats /dev/video2": "ok", "libusb": "ok", "camera identity": "ok",
        "rig": "ok", "rig age": "ok", "rig RMS": "ok", "rig cameras": "ok", "EGL": "ok"}
    assert "2 capture devices" in results["video devices"].found
    assert "/dev/video1 metadata" in results["video devices"].found
    assert "GREY 60 fps" in results["formats /dev/video0"].found
    assert "046d:0825 serial ABC123" in results["camera identity"].found
    assert "left /dev/video0, right /dev/video2" in results["rig cameras"].found
    assert "0.30 px" in results["rig RMS"].found and "3 days ago" in results["rig age"].found
    assert "llvmpipe" in results["EGL"].found and "4.5" in results["EGL"].found

    code = dr.run_doctor(argparse.Namespace(calib=str(rig), source=None, quiet=False), machine=machine())
    out = capsys.readouterr().out
    assert code == 0 and "fix:" not in out
    assert out.strip().splitlines()[-1] == "headplod doctor: 13 checks: 12 ok, 0 warn, 0 FAIL, 1 skip"
    assert dr.run_doctor(argparse.Namespace(calib=str(rig), source=None, quiet=True), machine=machine()) == 0
    assert capsys.readouterr().out == ""          # -q: nothing when all is well


def test_no_cameras_skips_the_camera_checks_with_a_reason_and_exits_0(capsys):
    m = machine(nodes=[])
    results = run(m)
    assert results["video devices"].status == "warn" and "lsusb" in results["video devices"].fix
    for name in ("device access", "formats", "camera identity"):
        assert results[name].status == "skip" and "no capture device" in results[name].found
    assert all(results[n].status == "skip" for n in ("rig", "rig age", "rig RMS", "rig cameras"))
    assert "no --calib" in results["rig"].found
    assert dr.run_doctor(argparse.Namespace(calib=None, source=None, quiet=False), machine=m) == 0


def test_user_not_in_the_video_group_cannot_open_the_cameras(capsys):
    m = machine(groups=lambda: GroupInfo("bob"), open_rw=_oserror(errno.EACCES))
    results = run(m)
    group, access = results["video group"], results["device access"]
    assert group.status == "warn" and "bob is not in group video" in group.found
    assert group.fix == "sudo usermod -aG video $USER, then log out and in"
    assert access.status == "FAIL" and "/dev/video0: permission denied" in access.found
    assert access.fix == group.fix
    assert results["formats /dev/video0"].status == "skip" and "permission denied" in results["formats /dev/video0"].found

    code = dr.run_doctor(argparse.Namespace(calib=None, source=None, quiet=True), machine=m)
    out = capsys.readouterr().out.splitlines()
    assert code == 1
    assert out[0].startswith("warn  video group") and out[1].strip() == f"fix: {group.fix}"
    assert out[2].startswith("FAIL  device access")
    assert all(line.split()[0] in ("warn", "FAIL", "fix:") for line in out)


def test_added_to_the_group_but_not_logged_in_again():
    r = run(machine(groups=lambda: GroupInfo("carol", in_group_db=True, in_session=False)))["video group"]
    assert r.status == "warn" and "log out and in" in r.fix and "usermod" not in r.fix


def test_a_group_file_member_is_told_apart_from_a_session_member():
    gr = SimpleNamespace(gr_gid=44, gr_mem=["dave"])
    pw = SimpleNamespace(pw_name="dave", pw_gid=1000)
    kw = dict(getgrnam=lambda name: gr, getpwuid=lambda uid: pw, getuid=lambda: 1000, geteuid=lambda: 1000,
              getegid=lambda: 1000)
    assert video_group_info(getgroups=lambda: [1000, 44], **kw) == GroupInfo("dave", False, True, True, True)
    assert video_group_info(getgroups=lambda: [1000], **kw) == GroupInfo("dave", False, True, True, False)
    eve = SimpleNamespace(pw_name="eve", pw_gid=1001)
    info = video_group_info(**{**kw, "getpwuid": lambda uid: eve}, getgroups=lambda: [1001])
    assert (info.in_group_db, info.in_session) == (False, False)

    def no_group(name):
        raise KeyError(name)
    assert video_group_info(**{**kw, "getgrnam": no_group}, getgroups=lambda: []).group_exists is False
    assert run(machine(groups=lambda: GroupInfo("x", group_exists=False)))["video group"].status == "skip"


def test_a_busy_camera_is_a_warning_and_a_missing_node_a_failure():
    busy = run(machine(open_rw=_oserror(errno.EBUSY)))["device access"]
    assert busy.status == "warn" and "fuser -v /dev/video0" in busy.fix
    # a container: sysfs lists the cameras, /dev lacks the nodes
    gone = run(machine(node_exists=lambda path: False))["video devices"]
    assert gone.status == "FAIL" and "--device /dev/video0 --device /dev/video2" in gone.fix


def test_a_stale_rig_is_a_warning_with_the_calibrate_fix(tmp_path):
    rig = rig_file(tmp_path, age_days=45)
    age = run(machine(), calib=str(rig))["rig age"]
    assert age.status == "warn" and "45 days ago" in age.found and "older than 30 days" in age.found
    assert "headplod calibrate --source v4l2:/dev/video0,/dev/video2" in age.fix and str(rig) in age.fix
    _parses(age.fix)
    # a calibration_date in the file wins over the modification time
    dated = rig_file(tmp_path, "dated.yaml", age_days=45, calibration_date="2027-01-10T12:00:00Z")
    r = run(machine(), calib=str(dated))["rig age"]
    assert r.status == "ok" and "from its calibration_date" in r.found and "2027-01-10" in r.found
    # the threshold is a setting
    assert run(machine(), settings=DoctorSettings(rig_max_age_days=60), calib=str(rig))["rig age"].status == "ok"


@pytest.mark.parametrize("rms, status", [(0.3, "ok"), (0.7, "warn"), (1.3, "FAIL"), (None, "warn")])
def test_rig_rms_thresholds(tmp_path, rms, status):
    results = run(machine(), calib=str(rig_file(tmp_path, rms=rms)))
    r = results["rig RMS"]
    assert r.status == status
    if status != "ok":
        assert r.fix.startswith("headplod calibrate") or "headplod calibrate" in r.fix
    if rms is None:
        assert "calibration_rms_stereo_px" in r.found


def test_an_unreadable_rig_fails_and_skips_the_rest(tmp_path):
    bad = tmp_path / "rig.yaml"
    bad.write_text("%YAML:1.0\nimage_width: 640\n")
    results = run(machine(), calib=str(bad))
    assert results["rig"].status == "FAIL" and "image_height" in results["rig"].found
    assert "headplod calibrate" in results["rig"].fix
    assert {results[n].status for n in ("rig age", "rig RMS", "rig cameras")} == {"skip"}
    missing = run(machine(), calib=str(tmp_path / "none.yaml"))["rig"]
    assert missing.status == "FAIL" and "no such file" in missing.found


def test_the_rig_found_without_calib(tmp_path):
    rig = rig_file(tmp_path)
    here = run(machine(find_rig=lambda: rig))["rig"]
    assert here.status == "ok" and "from the current folder" in here.found
    cfg = run(machine(config=lambda: ConfigDefaults(path=tmp_path / "headplod.toml", calib=rig)))["rig"]
    assert cfg.status == "ok" and "from config" in cfg.found


def test_the_config_file_gives_calib_and_source(tmp_path, capsys):
    """Doctor reads the config file as every command does (headplod.config): checked, relative paths from the
    file's folder, [doctor] over the top level, the command line over both."""
    from headplod import config
    from headplod.cli import build_parser

    (tmp_path / "cams").mkdir()
    rig = rig_file(tmp_path / "cams")
    toml = tmp_path / "headplod.toml"
    toml.write_text('source = "v4l2:auto"\ncalib = "elsewhere.yaml"\n[doctor]\ncalib = "cams/rig.yaml"\n')
    args = config.parse_args(build_parser(), ["doctor", "--config", str(toml)])
    got = config_from_args(args)
    assert got.path == toml and got.calib == rig.resolve() and got.source == "v4l2:auto"
    r = run(machine(config=lambda: got))
    assert r["config"].status == "ok" and "calib" in r["config"].found
    assert r["rig"].status == "ok" and "from config" in r["rig"].found
    # the command line wins, and is reported as the command line's
    given = config.parse_args(build_parser(), ["doctor", "--config", str(toml), "--calib", str(rig)])
    assert config_from_args(given).calib is None and given.calib == str(rig)
    assert config_from_args(config.parse_args(build_parser(), ["doctor", "--no-config"])) == ConfigDefaults()
    # a broken file is one line naming it, before any check
    toml.write_text("source = [\n")
    with pytest.raises(SystemExit) as stop:
        config.parse_args(build_parser(), ["doctor", "--config", str(toml)])
    assert stop.value.code == 2 and str(toml) in capsys.readouterr().err
    toml.write_text('[doctor]\nudp = "127.0.0.1"\n')
    with pytest.raises(SystemExit):
        config.parse_args(build_parser(), ["doctor", "--config", str(toml)])
    assert "not a key of 'headplod doctor'" in capsys.readouterr().err


def test_rig_cameras_other_than_the_connected_ones(tmp_path):
    stranger = _node(9, 0, "QQQ000", "1-4")
    rig = rig_file(tmp_path, cameras=(LEFT_NODES[0], stranger))
    r = run(machine(), calib=str(rig))["rig cameras"]
    assert r.status == "warn" and "QQQ000" in r.found and "headplod cameras --store" in r.fix
    # with --source v4l2:auto tracking would fail: so does the check
    r = run(machine(), calib=str(rig), source="v4l2:auto")["rig cameras"]
    assert r.status == "FAIL"
    # no identities stored
    r = run(machine(), calib=str(rig_file(tmp_path, "bare.yaml", cameras=None)))["rig cameras"]
    assert r.status == "warn" and r.fix == f"headplod cameras --store --source v4l2:LEFT,RIGHT --rig {tmp_path / 'bare.yaml'}"
    _parses(r.fix)
    # after a reboot the device numbers swapped: still the rig's cameras, found by identity
    swapped = [_node(2, 0, "ABC123", "1-2"), _node(0, 0, "XYZ789", "1-3")]
    r = run(machine(nodes=swapped), calib=str(rig_file(tmp_path, "r2.yaml")))["rig cameras"]
    assert r.status == "ok" and "left /dev/video2, right /dev/video0" in r.found
    # ... but --source names them the old way round
    r = run(machine(nodes=swapped), calib=str(tmp_path / "r2.yaml"), source="v4l2:0,2")["rig cameras"]
    assert r.status == "warn" and "v4l2:auto" in r.fix


def test_v4l2_auto_without_a_rig_fails():
    r = run(machine(), source="v4l2:auto")
    assert r["source"].status == "ok"
    assert r["rig"].status == "FAIL" and "--calib" in r["rig"].fix


def test_named_devices_missing_or_metadata_fail():
    r = run(machine(nodes=LEFT_NODES), source="v4l2:0,2")["video devices"]
    assert r.status == "FAIL" and "/dev/video2" in r.found
    r = run(machine(), source="v4l2:/dev/video0,/dev/video1")["video devices"]
    assert r.status == "FAIL" and "/dev/video1 is a metadata node" in r.found
    r = run(machine(), source="v4l2:/dev/video0")["source"]
    assert r.status == "FAIL"
    r = run(machine(), source="no-such-thing")["source"]
    assert r.status == "FAIL" and "v4l2:auto" in r.found
    # one camera only: a warning without --source, a failure when live cameras are asked for
    assert run(machine(nodes=LEFT_NODES))["video devices"].status == "warn"


def test_cameras_sharing_a_serial_make_v4l2_auto_ambiguous():
    twins = [_node(0, 0, "0001", "1-2"), _node(2, 0, "0001", "1-3")]
    r = run(machine(nodes=twins))["camera identity"]
    assert r.status == "warn" and "/dev/video0 and /dev/video2" in r.found and "serial 0001" in r.found
    assert "USB port only" in r.found and "v4l2:/dev/video0,/dev/video2" in r.fix
    no_serial = [_node(0, 0, None, "1-2"), _node(2, 0, None, "1-3")]
    r = run(machine(nodes=no_serial))["camera identity"]
    assert r.status == "warn" and "no serial" in r.found


def test_missing_libusb_fails_with_the_install_command_and_identity_falls_back_to_sysfs():
    def no_libusb():
        raise LibusbMissingError("pyusb found no USB backend: camera identity needs libusb-1.0")
    m = machine(libusb=lambda: (False, "pyusb found no USB backend: camera identity needs libusb-1.0; "
                                       "install libusb-1.0: sudo apt-get install libusb-1.0-0"),
                usb_cameras=no_libusb)
    r = run(m)
    assert r["libusb"].status == "FAIL" and r["libusb"].fix == "sudo apt-get install libusb-1.0-0"
    assert "install" not in r["libusb"].found
    assert r["camera identity"].status == "ok" and "from sysfs" in r["camera identity"].found


def test_no_egl_fails_with_the_packages_to_install():
    def no_egl():
        raise RuntimeError("cannot create a headless OpenGL 3.3 context through EGL: Exception: "
                           "libEGL.so.1 not found. Hint: install EGL")
    r = run(machine(gl_context=no_egl))["EGL"]
    assert r.status == "FAIL" and r.fix == "sudo apt-get install libegl1 libgl1-mesa-dri"
    assert "libEGL.so.1 not found" in r.found and "Hint" not in r.found
    ctx = FakeGL("Mesa Intel(R) UHD Graphics 620")
    r = run(machine(gl_context=lambda: ctx))["EGL"]
    assert r.status == "ok" and "software" not in r.found and ctx.released


def test_a_check_that_raises_is_its_own_fail_line(capsys):
    def broken():
        raise RuntimeError("sysfs exploded")

    def bad_groups():
        raise KeyError("no passwd entry")
    m = machine(video_nodes=broken, groups=bad_groups, config=broken)
    results = run(m)
    assert results["video devices"].status == "FAIL" and "sysfs exploded" in results["video devices"].found
    assert results["video group"].status == "FAIL" and "KeyError" in results["video group"].found
    assert results["config"].status == "FAIL"
    assert results["EGL"].status == "ok" and results["libusb"].status == "ok"     # the others still ran
    assert dr.run_doctor(argparse.Namespace(calib=None, source=None, quiet=False), machine=m) == 1
    assert "Traceback" not in capsys.readouterr().out


# ---------------------------------------------------------------------------
# formats and rates
# ---------------------------------------------------------------------------

def _fmt(code, rate, compressed=False, size=(640, 480)):
    return PixelFormat(code, code, compressed, (FrameSize(*size, (rate,)),))


SETTINGS = DoctorSettings()


def test_only_mjpg_at_60_fps_is_a_warning_naming_the_uncompressed_rate():
    r = judge_formats("/dev/video0", [_fmt("YUYV", 30), _fmt("MJPG", 60, True)], (640, 480), SETTINGS)
    assert r.status == "warn" and "only MJPG, compressed" in r.found
    assert r.fix == "headplod track --fourcc MJPG --fps 60 takes it; uncompressed: --fourcc YUYV --fps 30"


@pytest.mark.parametrize("formats, status, fix", [
    ([_fmt("GREY", 59.94)], "ok", None),                                  # drivers round 60 Hz
    ([_fmt("YUYV", 30)], "warn", "headplod track --fourcc YUYV --fps 30"),
    ([_fmt("MJPG", 30, True)], "warn", "headplod track --fourcc MJPG --fps 30"),
    ([_fmt("YUYV", 15), _fmt("MJPG", 15, True)], "FAIL", "use a camera with 640x480 at 30 fps or more"),
    ([_fmt("YUYV", 60, size=(1280, 720))], "FAIL", "use a camera with 640x480"),
    ([_fmt("H264", 60, True)], "FAIL", "use a camera with 640x480"),
    ([], "warn", "name a capture node"),
])
def test_format_verdicts(formats, status, fix):
    r = judge_formats("/dev/video0", formats, (640, 480), SETTINGS)
    assert r.status == status
    assert (r.fix is None) if fix is None else r.fix.startswith(fix)


def test_formats_are_judged_at_the_rigs_size(tmp_path):
    seen = []

    def formats(device, sizes):
        seen.append(sizes)
        return [_fmt("GREY", 60, size=(1280, 720))]
    K = np.array([[1400.0, 0, 640], [0, 1400, 360], [0, 0, 1]])
    path = tmp_path / "rig.yaml"
    io.write_rig(path, io.Rig((1280, 720), K, np.zeros(5), K, np.zeros(5), np.eye(3), np.array([-300.0, 0, 0])))
    r = run(machine(formats=formats), calib=str(path))
    assert seen == [((1280, 720),)] * 2 and r["formats /dev/video0"].status == "ok"
    assert run(machine(formats=formats))["formats /dev/video0"].status == "FAIL"        # 640x480 by default


# ---------------------------------------------------------------------------
# the V4L2 ioctls against a fake driver
# ---------------------------------------------------------------------------

def _code(text):
    return sum(ord(c) << (8 * i) for i, c in enumerate(text.ljust(4)))


class FakeDriver:
    """Answers VIDIOC_ENUM_FMT / ENUM_FRAMESIZES / ENUM_FRAMEINTERVALS from a table, EINVAL past its end."""

    def __init__(self):
        self.formats = [  # (fourcc, description, flags, sizes)
            ("YUYV", b"YUYV 4:2:2", 0, {(640, 480): [(1, 30), (1, 15)], (320, 240): [(1, 60)]}),
            ("MJPG", b"Motion-JPEG", 1, {(640, 480): [(1, 60), (1, 30)]}),
            ("GREY", b"8-bit Greyscale", 0, "stepwise"),
        ]
        self.calls = []

    def __call__(self, fd, request, s):
        self.calls.append(request)
        if request == v4l2fmt.VIDIOC_ENUM_FMT:
            assert s.type == v4l2fmt.V4L2_BUF_TYPE_VIDEO_CAPTURE
            if s.index >= len(self.formats):
                raise OSError(errno.EINVAL, "end")
            code, desc, flags, _ = self.formats[s.index]
            s.pixelformat, s.description, s.flags = _code(code), desc, flags
            return 0
        fmt = next(f for f in self.formats if _code(f[0]) == s.pixel_format)
        sizes = fmt[3]
        if request == v4l2fmt.VIDIOC_ENUM_FRAMESIZES:
            if sizes == "stepwise":
                if s.index > 0:
                    raise OSError(errno.EINVAL, "end")
                s.type = v4l2fmt.V4L2_FRMSIZE_TYPE_STEPWISE
                sw = s.stepwise
                sw.min_width, sw.max_width, sw.step_width = 160, 1280, 16
                sw.min_height, sw.max_height, sw.step_height = 120, 960, 8
                return 0
            keys = list(sizes)
            if s.index >= len(keys):
                raise OSError(errno.EINVAL, "end")
            s.type = v4l2fmt.V4L2_FRMSIZE_TYPE_DISCRETE
            s.discrete.width, s.discrete.height = keys[s.index]
            return 0
        if request == v4l2fmt.VIDIOC_ENUM_FRAMEINTERVALS:
            if sizes == "stepwise":
                if s.index > 0:
                    raise OSError(errno.EINVAL, "end")
                s.type = v4l2fmt.V4L2_FRMIVAL_TYPE_CONTINUOUS
                s.stepwise.min.numerator, s.stepwise.min.denominator = 1, 90
                s.stepwise.max.numerator, s.stepwise.max.denominator = 1, 5
                return 0
            ivals = sizes[(s.width, s.height)]
            if s.index >= len(ivals):
                raise OSError(errno.EINVAL, "end")
            s.type = v4l2fmt.V4L2_FRMIVAL_TYPE_DISCRETE
            s.discrete.numerator, s.discrete.denominator = ivals[s.index]
            return 0
        raise OSError(errno.ENOTTY, "not a V4L2 ioctl")


def test_ioctl_numbers_and_struct_sizes_are_the_kernels():
    assert (v4l2fmt.VIDIOC_ENUM_FMT, v4l2fmt.VIDIOC_ENUM_FRAMESIZES, v4l2fmt.VIDIOC_ENUM_FRAMEINTERVALS) == \
        (0xC0405602, 0xC02C564A, 0xC034564B)
    import ctypes
    assert [ctypes.sizeof(s) for s in (v4l2fmt.v4l2_fmtdesc, v4l2fmt.v4l2_frmsizeenum,
                                       v4l2fmt.v4l2_frmivalenum)] == [64, 44, 52]


def test_enumerate_formats_reads_the_drivers_lists():
    driver = FakeDriver()
    fmts = v4l2fmt.enumerate_formats(3, ioctl=driver, want_sizes=((640, 480),))
    assert [(f.fourcc, f.compressed) for f in fmts] == [("YUYV", False), ("MJPG", True), ("GREY", False)]
    yuyv, mjpg, grey = fmts
    assert yuyv.description == "YUYV 4:2:2"
    assert yuyv.sizes == (FrameSize(640, 480, (30.0, 15.0)), FrameSize(320, 240, (60.0,)))
    assert yuyv.rate_at(640, 480) == 30.0 and mjpg.rate_at(640, 480) == 60.0 and yuyv.rate_at(800, 600) == 0
    # a stepwise size range: its largest size and the wanted one inside it, at the range's rates
    assert grey.sizes == (FrameSize(1280, 960, (90.0, 5.0)), FrameSize(640, 480, (90.0, 5.0)))
    verdict = judge_formats("/dev/video0", fmts, (640, 480), SETTINGS)
    assert verdict.status == "ok" and "GREY 90 fps" in verdict.found


def test_enumerate_formats_passes_other_errors_on():
    def not_v4l2(fd, request, s):
        raise OSError(errno.ENOTTY, "Inappropriate ioctl for device")
    with pytest.raises(OSError) as info:
        v4l2fmt.enumerate_formats(3, ioctl=not_v4l2)
    assert info.value.errno == errno.ENOTTY
    r = run(machine(formats=lambda d, s: not_v4l2(0, 0, None)))["formats /dev/video0"]
    assert r.status == "FAIL" and "ENOTTY" in r.found
    assert v4l2fmt.fourcc_text(_code("GREY")) == "GREY" and v4l2fmt.fourcc_text(_code("Y8")) == "Y8"


def test_video_nodes_are_listed_from_sysfs_without_libusb(tmp_path):
    from test_cameras import LEFT, RIGHT, make_sysfs
    from headplod.capture.usb import list_video_nodes
    sys_root, dev_root = make_sysfs(tmp_path, [dict(LEFT, videos=(0, 1)), dict(RIGHT, videos=(2, 3))], loopback=4)
    nodes = list_video_nodes(sys_root, dev_root)
    assert [(Path(n.device).name, n.index, n.serial, n.port_path) for n in nodes] == [
        ("video0", 0, "ABC123", "1-2"), ("video1", 1, "ABC123", "1-2"), ("video2", 0, "XYZ789", "1-3"),
        ("video3", 1, "XYZ789", "1-3"), ("video4", 0, None, None)]
    assert list_video_nodes(str(tmp_path / "nothing"), dev_root) == []


# ---------------------------------------------------------------------------
# the real command on this machine
# ---------------------------------------------------------------------------

def test_headplod_doctor_runs_here(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)                          # no ./rig.yaml, no ./headplod.toml
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    from headplod import cli
    assert list(cli.COMMANDS)[0] == "doctor"             # the webcam user's first step, first in --help
    code = cli_main(["doctor"])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line and not line.startswith(" ")]
    statuses = [line.split()[0] for line in lines[:-1]]
    assert set(statuses) <= {"ok", "warn", "FAIL", "skip"}
    assert code == (1 if "FAIL" in statuses else 0)
    for name in ("config", "video devices", "video group", "device access", "formats", "libusb",
                 "camera identity", "rig", "rig age", "rig RMS", "rig cameras", "EGL"):
        assert any(line.split(None, 1)[1].startswith(name) for line in lines[:-1]), name
    assert lines[-1].startswith(f"headplod doctor: {len(lines) - 1} checks:")
    assert "Traceback" not in out
