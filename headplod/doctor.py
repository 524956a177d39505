"""``headplod doctor``: is this machine ready for two webcams? One line per check, and the fix.

    headplod doctor [--calib rig.yaml] [--source SPEC] [-q]

A webcam user's first step (issue 25). Each check prints one line: its
status (``ok``, ``warn``, ``FAIL``, ``skip``), what it checked and found,
and under a warning or a failure the fix, a command to run:

- ``video devices``: the ``/dev/video*`` nodes, capture or metadata nodes
  (the V4L2 index sysfs gives, as ``headplod cameras`` tells them apart);
- ``video group``: whether the user is in the ``video`` group, in the group
  file and in this login session;
- ``device access``: whether each capture node opens read/write;
- ``formats DEVICE``: per capture node, the GREY / YUYV / MJPG rates it
  offers at the rig's image size (else 640x480), through the V4L2
  enumeration ioctls (:mod:`headplod.capture.formats`);
- ``libusb``: whether pyusb can load libusb-1.0;
- ``camera identity``: each camera's USB vendor:product and serial, and
  whether two share one (``v4l2:auto`` can then tell them apart by USB port
  only);
- ``rig``, ``rig age``, ``rig RMS``, ``rig cameras``: the rig.yaml of
  ``--calib`` (else the dataset folder's of ``--source``, else the config
  file's ``calib``, else ``rig.yaml`` in the current folder): readable, how old, its RMS reprojection error,
  whether the cameras it names are the ones connected;
- ``EGL``: a headless OpenGL context, its renderer and version;
- ``config``: the config file (``headplod.toml``) and the ``calib`` and V4L2
  ``source`` doctor takes from it when not given;
- ``source``: with ``--source``, whether the spec is one ``track`` opens.

The thresholds are :class:`DoctorSettings`. Checks take everything they look
at from a :class:`Machine` (device lister, opener, group lookup, clock, GL
context factory, ...), so tests simulate machines without hardware. A check
that raises is reported as its own ``FAIL`` line; doctor itself never
raises. Exit status: 0 when no check FAILs, 1 when one does.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import errno
import glob
import grp
import os
import pwd
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from . import io
from .argtypes import add_quiet_argument
from .capture import usb
from .capture.formats import PixelFormat, device_formats
from .capture.sources import source_forms, source_kind, v4l2_devices
from .render.context import EGL_PACKAGES, create_context

__all__ = ["DoctorSettings", "Result", "Machine", "GroupInfo", "ConfigDefaults", "video_group_info",
           "config_from_args", "judge_formats", "doctor", "format_results",
           "add_doctor_arguments", "run_doctor", "OK", "WARN", "FAIL", "SKIP"]

OK, WARN, FAIL, SKIP = "ok", "warn", "FAIL", "skip"
STATUSES = (OK, WARN, FAIL, SKIP)

#: The pixel formats ``headplod track --fourcc`` asks for that are not compressed.
UNCOMPRESSED = ("GREY", "YUYV")
COMPRESSED = "MJPG"

USERMOD_FIX = "sudo usermod -aG video $USER, then log out and in"
LIBUSB_FIX = "sudo apt-get install libusb-1.0-0"
EGL_FIX = f"sudo apt-get install {EGL_PACKAGES}"
NO_CAMERA_FIX = ("plug the cameras in; 'lsusb' should list them and 'lsmod | grep uvcvideo' show the driver "
                 "(sudo modprobe uvcvideo)")


@dataclass(frozen=True)
class DoctorSettings:
    """Where ``headplod doctor`` draws its lines between ok, warn and FAIL.

    Attributes
    ----------
    width_px, height_px : int
        Image size whose modes are judged when no rig gives one, px.
    fps_wanted_hz : float
        Frame rate the tracker is built for (``track --fps``'s default), Hz;
        below it (but at least ``fps_min_hz``) a camera is a warning.
    fps_min_hz : float
        Slowest usable frame rate, Hz; no GREY/YUYV/MJPG mode at the size
        this fast is a FAIL.
    fps_tolerance : float
        Relative slack on a rate (drivers list 59.94 Hz for 60), fraction.
    cameras_needed : int
        Capture devices stereo tracking needs; fewer is a warning (a FAIL when
        ``--source`` names v4l2 cameras).
    rig_max_age_days : float
        A rig older than this is a warning (cameras get bumped), days.
    rms_warn_px, rms_fail_px : float
        The rig's stereo RMS reprojection error above which it is a warning
        / a FAIL, px.
    """

    width_px: int = 640
    height_px: int = 480
    fps_wanted_hz: float = 60.0
    fps_min_hz: float = 30.0
    fps_tolerance: float = 0.01
    cameras_needed: int = 2
    rig_max_age_days: float = 30.0
    rms_warn_px: float = 0.5
    rms_fail_px: float = 1.0


@dataclass(frozen=True)
class Result:
    """One check's line.

    Attributes
    ----------
    status : {'ok', 'warn', 'FAIL', 'skip'}
    check : str
        What was checked (``video group``, ``formats /dev/video0``).
    found : str
        What was found, or why the check was skipped.
    fix : str or None
        A command to run (with a warning or a failure).
    """

    status: str
    check: str
    found: str
    fix: str | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status is {self.status!r}, expected one of {STATUSES}")


@dataclass(frozen=True)
class GroupInfo:
    """The user and the ``video`` group.

    Attributes
    ----------
    user : str
    root : bool
        Effective uid 0 (opens any device whatever the groups).
    group_exists : bool
        The system has a ``video`` group.
    in_group_db : bool
        The group file lists the user in it (or it is the user's primary group).
    in_session : bool
        This process has the group (a login after ``usermod`` gives it).
    """

    user: str
    root: bool = False
    group_exists: bool = True
    in_group_db: bool = False
    in_session: bool = False


def video_group_info(group: str = "video", *, getgrnam=grp.getgrnam, getpwuid=pwd.getpwuid,
                     getgroups=os.getgroups, getuid=os.getuid, geteuid=os.geteuid,
                     getegid=os.getegid) -> GroupInfo:
    """The user's membership of ``group``, from the group and passwd files and this process's groups."""
    uid = getuid()
    try:
        pw = getpwuid(uid)
        user, primary = pw.pw_name, pw.pw_gid
    except KeyError:
        user, primary = os.environ.get("USER") or f"uid {uid}", None
    try:
        gr = getgrnam(group)
    except KeyError:
        return GroupInfo(user, root=geteuid() == 0, group_exists=False)
    in_db = user in gr.gr_mem or primary == gr.gr_gid
    in_session = gr.gr_gid in getgroups() or getegid() == gr.gr_gid
    return GroupInfo(user, root=geteuid() == 0, in_group_db=in_db, in_session=in_session)


def _default_video_nodes() -> list[usb.CameraInfo]:
    """sysfs's video nodes, plus any ``/dev/video*`` sysfs does not list (index unknown)."""
    nodes = usb.list_video_nodes()
    known = {n.device for n in nodes}
    extra = sorted((p for p in glob.glob("/dev/video*") if p not in known and p[10:].isdigit()),
                   key=lambda p: int(p[10:]))
    return nodes + [usb.CameraInfo(device=p, name="?") for p in extra]


def _open_rw(device: str) -> None:
    """Open ``device`` read/write without blocking and close it; raises OSError."""
    os.close(os.open(device, os.O_RDWR | os.O_NONBLOCK))


def _cwd_rig() -> Path | None:
    path = Path.cwd() / "rig.yaml"
    return path if path.is_file() else None


@dataclass(frozen=True)
class ConfigDefaults:
    """What the config file (``headplod.toml``, :mod:`headplod.config`) gives doctor.

    Attributes
    ----------
    path : Path or None
        The file read; None when there is none.
    calib : Path or None
        The ``calib`` it gave doctor (``[doctor]``, else the top level), relative to the file's folder.
    source : str or None
        The ``source`` it gave doctor (``[doctor]``, else the top level).
    error : str or None
        Why the file cannot be used.
    """

    path: Path | None = None
    calib: Path | None = None
    source: str | None = None
    error: str | None = None


def config_from_args(args) -> ConfigDefaults:
    """What the config file gave ``headplod doctor``'s parsed ``args``: :func:`headplod.config.parse_args` reads
    and checks the file as for every command (the command's table over the top level, a bad file refused in one
    line) and records the file and the keys it applied (``config_file``, ``config_used``)."""
    path = getattr(args, "config_file", None)
    used = getattr(args, "config_used", ())
    calib = getattr(args, "calib", None) if "calib" in used else None
    return ConfigDefaults(path=path, calib=Path(calib) if calib is not None else None,
                          source=getattr(args, "source", None) if "source" in used else None)


def _file_mtime(path: Path) -> float:
    return os.stat(path).st_mtime


@dataclass
class Machine:
    """What doctor looks at, each a callable so that tests can simulate a machine.

    Attributes
    ----------
    video_nodes : () -> list of CameraInfo
        Every video node (capture and metadata), USB fields from sysfs
        (default :func:`headplod.capture.usb.list_video_nodes` and
        ``/dev/video*``).
    node_exists : (path) -> bool
        Whether the device node is there (a container may lack it).
    open_rw : (path) -> None
        Open read/write and close; raises OSError (EACCES, EBUSY, ENOENT).
    formats : (path, sizes) -> list of PixelFormat
        The device's modes (:func:`headplod.capture.formats.device_formats`).
    usb_cameras : () -> list of CameraInfo
        Capture nodes with identities read over USB
        (:func:`headplod.capture.usb.list_cameras`); may raise
        :class:`~headplod.capture.usb.LibusbMissingError`.
    libusb : () -> (bool, str)
        :func:`headplod.capture.usb.libusb_available`.
    groups : () -> GroupInfo
    clock : () -> float
        Now, s since the epoch (the rig's age).
    gl_context : () -> context
        A headless moderngl context (:func:`headplod.render.create_context`).
    config : () -> ConfigDefaults
        The config file's ``calib`` and ``source`` (:func:`config_from_args`; default: no file).
    find_rig : () -> Path or None
        The rig.yaml to check without ``--calib`` or a config file's
        ``calib`` (default ``./rig.yaml``).
    read_rig : (path) -> io.Rig
    file_mtime : (path) -> float
    """

    video_nodes: Callable[[], list] = _default_video_nodes
    node_exists: Callable[[str], bool] = os.path.exists
    open_rw: Callable[[str], None] = _open_rw
    formats: Callable[[str, tuple], list] = field(default=lambda path, sizes: device_formats(path, sizes))
    usb_cameras: Callable[[], list] = field(default=lambda: usb.list_cameras())
    libusb: Callable[[], tuple] = field(default=lambda: usb.libusb_available())
    groups: Callable[[], GroupInfo] = field(default=lambda: video_group_info())
    clock: Callable[[], float] = time.time
    gl_context: Callable[[], Any] = create_context
    config: Callable[[], ConfigDefaults] = field(default=ConfigDefaults)
    find_rig: Callable[[], Path | None] = _cwd_rig
    read_rig: Callable[[Any], Any] = io.read_rig
    file_mtime: Callable[[Any], float] = _file_mtime


# ---------------------------------------------------------------------------
# what the checks share
# ---------------------------------------------------------------------------

_NOT_READ = object()


class _Survey:
    """The inputs of one run, each read once, and what earlier checks found."""

    def __init__(self, machine: Machine, settings: DoctorSettings, calib: str | None, source: str | None):
        self.m, self.s = machine, settings
        try:
            self.config = machine.config()
        except Exception as exc:                 # reported by the 'config' line
            self.config = ConfigDefaults(error=f"{type(exc).__name__}: {exc}")
        self.calib, self.source = calib, source
        self.source_origin = "--source"
        if not source and self.config.source:
            self.source, self.source_origin = self.config.source, f"config {self.config.path}"
        self.kind: str | None = None          # source_kind(source)
        self.auto = False                     # --source v4l2:auto
        self.named: list[str] | None = None   # --source v4l2:A,B -> [/dev/videoA, /dev/videoB]
        self.nodes: list | None = None        # every video node; None: not listed
        self.capture: list = []               # the capture nodes to check
        self.openable: dict[str, str | None] = {}   # device -> None (opens) or why not
        self.not_in_group = False
        self._rig: Any = _NOT_READ
        self.rig_error: str | None = None
        self.rig_path: Path | None = None
        self._cams: Any = _NOT_READ
        self.cams_note = ""
        self.source_error: str | None = None
        try:
            self._parse_source()
        except Exception as exc:                 # reported by the 'source' line
            self.kind, self.source_error = None, f"{type(exc).__name__}: {exc}"

    def _parse_source(self) -> None:
        if not self.source:
            return
        self.kind = source_kind(self.source)
        if self.kind != "v4l2":
            return
        devices = v4l2_devices(self.source)
        if devices == "auto":
            self.auto = True
        elif devices is not None:
            self.named = [f"/dev/video{d}" if isinstance(d, int) else d for d in devices]

    @property
    def live(self) -> bool:
        return self.kind == "v4l2"

    # -- the rig -----------------------------------------------------------

    def rig_location(self) -> tuple[Path | None, str]:
        """The rig.yaml to check and where it comes from."""
        if self.calib:
            return Path(self.calib).expanduser(), "--calib"
        if self.kind == "dataset":
            return Path(self.source) / "rig.yaml", "the --source dataset"
        if self.config.calib is not None:
            return self.config.calib, f"config {self.config.path}"
        found = self.m.find_rig()
        return (Path(found), "the current folder") if found else (None, "")

    def rig(self):
        """The rig (io.Rig), or None when there is none or it cannot be read (``rig_error`` says why)."""
        if self._rig is _NOT_READ:
            self._rig = None
            try:
                path, _ = self.rig_location()
                self.rig_path = path
                if path is not None:
                    self._rig = self.m.read_rig(path)
            except Exception as exc:                # ContractError, OSError, anything: reported by 'rig'
                self.rig_error = str(exc) or type(exc).__name__
        return self._rig

    def size(self) -> tuple[int, int]:
        rig = self.rig()
        return tuple(rig.image_size) if rig is not None else (self.s.width_px, self.s.height_px)

    def calibrate_fix(self) -> str:
        devs = list(self.named) if self.named else [c.device for c in self.capture][:2]
        cams = ",".join(devs) if len(devs) == 2 else "LEFT,RIGHT"
        out = self.rig_path or "rig.yaml"
        return f"headplod calibrate --source v4l2:{cams} --cols N --rows M --square-mm S --out {out}"

    # -- the cameras' USB identities ------------------------------------------

    def usb_cameras(self) -> list:
        """Capture nodes with identities: over USB, else (no libusb) from sysfs (``cams_note`` says so)."""
        if self._cams is _NOT_READ:
            try:
                self._cams = list(self.m.usb_cameras())
            except Exception as exc:             # no libusb (LibusbMissingError), a USB error
                why = ("pyusb has no libusb, see 'libusb'" if isinstance(exc, usb.LibusbMissingError)
                       else f"pyusb failed: {type(exc).__name__}: {exc}")
                self.cams_note = f" (from sysfs: {why})"
                self._cams = [c for c in (self.nodes or []) if c.index in (0, None)]
        return self._cams


# ---------------------------------------------------------------------------
# the checks
# ---------------------------------------------------------------------------

def _check_config(sv: _Survey) -> list[Result]:
    c = sv.config
    if c.error:
        return [Result(FAIL, "config", c.error, "fix the file, or run with --no-config")]
    if c.path is None:
        return [Result(SKIP, "config", "no config file (./headplod.toml, ~/.config/headplod/config.toml)")]
    used = [f"calib {c.calib}"] * (c.calib is not None) + [f"source {c.source}"] * (c.source is not None)
    return [Result(OK, "config", f"{c.path}" + (f": {', '.join(used)}" if used else ": no calib or source for doctor"))]


def _check_source(sv: _Survey) -> list[Result]:
    if not sv.source:
        return []
    where = f" (from {sv.source_origin})" if sv.source_origin != "--source" else ""
    if sv.kind is None:
        forms = "; ".join(source_forms())
        why = sv.source_error or f"no source headplod opens (accepted: {forms})"
        return [Result(FAIL, "source", f"{sv.source!r}{where}: {why}",
                       "headplod doctor --source v4l2:/dev/video0,/dev/video2 (or v4l2:auto with --calib)")]
    if sv.auto:
        return [Result(OK, "source", f"v4l2:auto{where}: the two cameras the rig names, found by USB identity")]
    if sv.live and sv.named is None:
        return [Result(FAIL, "source", f"{sv.source!r}{where}: expected two devices, left first",
                       "headplod doctor --source v4l2:/dev/video0,/dev/video2")]
    if sv.live:
        return [Result(OK, "source", f"v4l2{where}: left {sv.named[0]}, right {sv.named[1]}")]
    return [Result(OK, "source", f"{sv.kind} {sv.source} (not live cameras: the camera checks are advice)")]


def _role(node) -> str:
    return {0: "capture", None: "index unknown"}.get(node.index, "metadata")


def _check_devices(sv: _Survey) -> list[Result]:
    name, need = "video devices", sv.s.cameras_needed
    sv.nodes = list(sv.m.video_nodes())
    nodes = sv.nodes
    by_device = {n.device: n for n in nodes}
    if sv.named is not None:
        sv.capture = [by_device.get(d) or usb.CameraInfo(device=d, name="?") for d in sv.named]
    else:
        sv.capture = [n for n in nodes if n.index in (0, None)]
    if not nodes and sv.named is None:
        status = FAIL if sv.live else WARN
        return [Result(status, name, "no /dev/video* device and none under /sys/class/video4linux", NO_CAMERA_FIX)]
    listed = ", ".join(f"{n.device} {_role(n)}" + (f" ({n.name})" if n.index in (0, None) and n.name != "?" else "")
                       for n in nodes) or "none"
    missing = [c.device for c in sv.capture if not sv.m.node_exists(c.device)]
    if missing:
        in_sysfs = [d for d in missing if d in by_device]
        fix = ("pass the devices into the container (docker run --device " + " --device ".join(in_sysfs) + ")"
               if in_sysfs else NO_CAMERA_FIX)
        return [Result(FAIL, name, f"{', '.join(missing)} missing; nodes: {listed}", fix)]
    if sv.named is not None:
        meta = [c.device for c in sv.capture if c.index not in (0, None)]
        if meta:
            return [Result(FAIL, name, f"{', '.join(meta)} is a metadata node, it captures no images; nodes: {listed}",
                           "name the capture nodes (index 0) in --source; 'headplod cameras' lists them")]
    count = len(sv.capture)
    found = f"{len(nodes)} node{'s' * (len(nodes) != 1)}: {listed}"
    if count < need:
        return [Result(FAIL if sv.live else WARN, name,
                       f"{count} capture device{'s' * (count != 1)}, stereo tracking needs {need}; {found}",
                       "plug in the second camera; 'lsusb' should list both")]
    return [Result(OK, name, f"{count} capture devices; {found}")]


def _check_group(sv: _Survey) -> list[Result]:
    name = "video group"
    g = sv.m.groups()
    if g.root:
        who = "root" if g.user == "root" else f"{g.user} with root's rights"
        return [Result(OK, name, f"running as {who}: every device opens; run doctor as the user who "
                                 "tracks to check theirs")]
    if not g.group_exists:
        return [Result(SKIP, name, "this system has no 'video' group ('device access' tells whether the "
                                   "cameras open)")]
    if g.in_session:
        return [Result(OK, name, f"{g.user} is in group video")]
    sv.not_in_group = True
    if g.in_group_db:
        return [Result(WARN, name, f"{g.user} was added to group video, but this login session predates it",
                       "log out and in (or run 'newgrp video' in this shell)")]
    return [Result(WARN, name, f"{g.user} is not in group video: the cameras open only through the desktop "
                               "seat's access list, not over ssh or from a service", USERMOD_FIX)]


_ERRNO_TEXT = {errno.EACCES: "permission denied", errno.EPERM: "permission denied", errno.EBUSY: "busy",
               errno.ENOENT: "no such device node", errno.ENODEV: "no such device", errno.ENXIO: "no such device"}


def _check_access(sv: _Survey) -> list[Result]:
    name = "device access"
    if not sv.capture:
        return [Result(SKIP, name, "no capture device to open")]
    parts, worst, fix = [], OK, None
    rank = {OK: 0, WARN: 1, FAIL: 2}
    for cam in sv.capture:
        try:
            sv.m.open_rw(cam.device)
        except OSError as exc:
            why = _ERRNO_TEXT.get(exc.errno, exc.strerror or str(exc))
            sv.openable[cam.device] = why
            if exc.errno in (errno.EACCES, errno.EPERM):
                status = FAIL
                this_fix = USERMOD_FIX if sv.not_in_group else (
                    f"ls -l {cam.device}: group video should have rw (check /etc/udev/rules.d for a rule "
                    "changing it)")
            elif exc.errno == errno.EBUSY:
                status, this_fix = WARN, f"another program holds it: 'fuser -v {cam.device}' names it; close it"
            else:
                status, this_fix = FAIL, NO_CAMERA_FIX
            parts.append(f"{cam.device}: {why}")
            if rank[status] > rank[worst]:
                worst, fix = status, this_fix
        else:
            sv.openable[cam.device] = None
            parts.append(f"{cam.device} opens read/write")
    return [Result(worst, name, "; ".join(parts), fix)]


def _fps(rate: float) -> str:
    return f"{rate:.3g} fps"


def judge_formats(device: str, formats: Sequence[PixelFormat], size: tuple[int, int],
                  settings: DoctorSettings) -> Result:
    """The ``formats DEVICE`` line for a device's modes at ``size`` (width, height), px."""
    name = f"formats {device}"
    w, h = size
    wanted, low = settings.fps_wanted_hz, settings.fps_min_hz
    slack = 1.0 - settings.fps_tolerance
    if not formats:
        return Result(WARN, name, "offers no video capture format (a metadata node, or not a camera)",
                      "name a capture node: 'headplod cameras' lists them")
    rates = {}
    for f in formats:
        if f.fourcc in (*UNCOMPRESSED, COMPRESSED):
            rates[f.fourcc] = max(rates.get(f.fourcc, 0.0), f.rate_at(w, h))
    offered = ", ".join(f"{k} {_fps(v)}" for k, v in rates.items() if v > 0)
    all_fourccs = ", ".join(f.fourcc for f in formats)
    unc = max(((rates.get(k, 0.0), k) for k in UNCOMPRESSED), default=(0.0, None))
    mj = rates.get(COMPRESSED, 0.0)
    fix_list = f"v4l2-ctl -d {device} --list-formats-ext lists every mode"
    if not offered:
        largest = max(((s.width * s.height, s.width, s.height) for f in formats for s in f.sizes), default=None)
        where = f" (largest {largest[1]}x{largest[2]})" if largest else ""
        return Result(FAIL, name, f"no GREY/YUYV/MJPG mode at {w}x{h}; offers {all_fourccs}{where}",
                      f"use a camera with {w}x{h} at {low:g} fps or more ({fix_list})")
    found = f"at {w}x{h}: {offered}"
    if unc[0] >= wanted * slack:
        return Result(OK, name, found)
    if mj >= wanted * slack:
        alt = (f"; uncompressed: --fourcc {unc[1]} --fps {unc[0]:g}" if unc[0] >= low * slack else "")
        return Result(WARN, name, f"{found}: at {wanted:g} fps only MJPG, compressed (JPEG blurs the markers' "
                                  "edges and costs decoding time)",
                      f"headplod track --fourcc MJPG --fps {wanted:g} takes it{alt}")
    best = max(unc[0], mj)
    if best >= low * slack:
        code = unc[1] if unc[0] >= mj else COMPRESSED
        only = " (only MJPG, compressed)" if code == COMPRESSED else ""
        return Result(WARN, name, f"{found}: at most {_fps(best)}{only}, {wanted:g} wanted",
                      f"headplod track --fourcc {code} --fps {best:g}")
    return Result(FAIL, name, f"{found}: none reaches {low:g} fps",
                  f"use a camera with {w}x{h} at {low:g} fps or more ({fix_list})")


def _check_formats(sv: _Survey) -> list[Result]:
    if not sv.capture:
        return [Result(SKIP, "formats", "no capture device")]
    size = sv.size()
    out = []
    for cam in sv.capture:
        why = sv.openable.get(cam.device)
        if why is not None:
            out.append(Result(SKIP, f"formats {cam.device}", f"cannot be opened: {why} (see 'device access')"))
            continue
        try:
            formats = sv.m.formats(cam.device, (size,))
        except OSError as exc:
            if exc.errno == errno.ENOTTY:
                out.append(Result(FAIL, f"formats {cam.device}", "not a V4L2 device (ENOTTY)",
                                  "'headplod cameras' lists the video devices"))
            else:
                out.append(Result(FAIL, f"formats {cam.device}", f"cannot list its formats: {exc}",
                                  f"v4l2-ctl -d {cam.device} --list-formats-ext"))
            continue
        out.append(judge_formats(cam.device, formats, size, sv.s))
    return out


def _check_libusb(sv: _Survey) -> list[Result]:
    ok, message = sv.m.libusb()
    if ok:
        return [Result(OK, "libusb", message)]
    return [Result(FAIL, "libusb", message.split("; install libusb")[0], LIBUSB_FIX)]


def _check_identity(sv: _Survey) -> list[Result]:
    name = "camera identity"
    if not sv.capture:
        return [Result(SKIP, name, "no capture device")]
    wanted = {c.device for c in sv.capture}
    cams = [c for c in sv.usb_cameras() if c.device in wanted]
    if not cams:
        return [Result(SKIP, name, f"no USB identity for {', '.join(sorted(wanted))}")]
    parts = []
    for c in cams:
        if c.is_usb:
            parts.append(f"{c.device} {c.usb_id} serial {c.serial or 'none'} port {c.port_path or '?'}")
        else:
            parts.append(f"{c.device} not on USB")
    found = "; ".join(parts) + sv.cams_note
    groups: dict = {}
    for c in cams:
        if c.is_usb:
            groups.setdefault((c.vendor_id, c.product_id, c.serial or None), []).append(c)
    same = [g for g in groups.values() if len(g) > 1]
    if same:
        g = same[0]
        what = f"serial {g[0].serial}" if g[0].serial else "no serial"
        return [Result(WARN, name, f"{found}: {' and '.join(c.device for c in g)} are {g[0].usb_id} with {what}, "
                                   "so v4l2:auto tells them apart by USB port only",
                       "keep each camera in the USB socket it had when 'headplod cameras --store' ran, or name "
                       "them: --source v4l2:" + ",".join(c.device for c in g[:2]))]
    return [Result(OK, name, found)]


def _check_rig(sv: _Survey) -> list[Result]:
    names = ("rig", "rig age", "rig RMS", "rig cameras")
    path, origin = sv.rig_location()
    if path is None:
        if sv.auto:
            return [Result(FAIL, "rig", "v4l2:auto finds the cameras the rig names, and no rig is given",
                           f"headplod doctor --source {sv.source} --calib rig.yaml")] + \
                [Result(SKIP, n, "no rig") for n in names[1:]]
        why = "no --calib, no calib in a config file and no rig.yaml in the current folder"
        return [Result(SKIP, n, why) for n in names]
    rig = sv.rig()
    if rig is None:
        missing = not Path(path).exists()
        found = f"{path} (from {origin}): " + ("no such file" if missing else sv.rig_error)
        fix = sv.calibrate_fix() if missing else f"fix the file, or recalibrate: {sv.calibrate_fix()}"
        return [Result(FAIL, "rig", found, fix)] + [Result(SKIP, n, "the rig cannot be read") for n in names[1:]]
    w, h = rig.image_size
    out = [Result(OK, "rig", f"{path} (from {origin}): {w}x{h} px, baseline {rig.baseline_mm:.0f} mm")]
    for check in (_rig_age, _rig_rms, _rig_cameras):
        out.append(_guard(names[len(out)], check, sv, rig, path)[0])
    return out


def _calibration_time(rig) -> float | None:
    """``calibration_date`` of the rig (ISO 8601; UTC when no zone is given), s since the epoch, or None."""
    value = rig.extra.get("calibration_date")
    if not isinstance(value, str) or not value.strip():
        return None
    when = _dt.datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.timezone.utc)
    return when.timestamp()


def _rig_age(sv: _Survey, rig, path) -> list[Result]:
    stamp = _calibration_time(rig)
    origin = "its calibration_date"
    if stamp is None:
        stamp, origin = sv.m.file_mtime(path), "the file's modification time"
    days = (sv.m.clock() - stamp) / 86400.0
    when = _dt.datetime.fromtimestamp(stamp, _dt.timezone.utc).strftime("%Y-%m-%d")
    found = f"dated {when}, {days:.0f} days ago (from {origin})"
    if days < -1:
        return [Result(WARN, "rig age", f"dated {when}, in the future (from {origin}): is the clock right?",
                       "date; timedatectl status")]
    if days > sv.s.rig_max_age_days:
        return [Result(WARN, "rig age", f"{found}, older than {sv.s.rig_max_age_days:g} days: cameras get bumped",
                       f"if 'rig cameras' or tracking looks off, recalibrate: {sv.calibrate_fix()}")]
    return [Result(OK, "rig age", found)]


def _rig_rms(sv: _Survey, rig, path) -> list[Result]:
    values = {k: rig.extra.get(f"calibration_rms_{k}_px") for k in ("stereo", "left", "right")}
    values = {k: float(v) for k, v in values.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    if "stereo" not in values:
        return [Result(WARN, "rig RMS", "rig.yaml records no calibration_rms_stereo_px (not written by "
                                        "'headplod calibrate'): its accuracy is unknown",
                       sv.calibrate_fix())]
    rms = values["stereo"]
    sides = ", ".join(f"{k} {values[k]:.2f}" for k in ("left", "right") if k in values)
    found = f"stereo reprojection RMS {rms:.2f} px" + (f" ({sides})" if sides else "")
    if rms > sv.s.rms_fail_px:
        return [Result(FAIL, "rig RMS", f"{found}, above {sv.s.rms_fail_px:g} px",
                       f"recalibrate with more, sharper pairs: {sv.calibrate_fix()}")]
    if rms > sv.s.rms_warn_px:
        return [Result(WARN, "rig RMS", f"{found}, above {sv.s.rms_warn_px:g} px",
                       f"recalibrate with more, sharper pairs: {sv.calibrate_fix()}")]
    return [Result(OK, "rig RMS", f"{found}, at most {sv.s.rms_warn_px:g} px")]


def _rig_cameras(sv: _Survey, rig, path) -> list[Result]:
    name = "rig cameras"
    store = f"headplod cameras --store --source v4l2:LEFT,RIGHT --rig {path}"
    if not sv.capture:
        return [Result(FAIL if sv.auto else SKIP, name, "no camera connected to compare with the rig's")]
    if usb.LEFT_KEY not in rig.extra or usb.RIGHT_KEY not in rig.extra:
        return [Result(FAIL if sv.auto else WARN, name,
                       f"the rig names no cameras ({usb.LEFT_KEY}, {usb.RIGHT_KEY}): v4l2:auto cannot find them",
                       store)]
    try:
        left, right = usb.resolve_rig_cameras(rig, sv.usb_cameras())
    except LookupError as exc:
        return [Result(FAIL if sv.auto else WARN, name, f"not the connected cameras: {exc}",
                       "plug the calibrated cameras into the sockets they had; if these are other cameras, "
                       f"recalibrate: {sv.calibrate_fix()}, then {store}")]
    except ValueError as exc:
        return [Result(FAIL, name, f"the rig's camera identities are malformed: {exc}", store)]
    found = f"left {left}, right {right} (by USB identity{sv.cams_note})"
    if sv.named is not None and [left, right] != sv.named:
        return [Result(WARN, name, f"{found}, but --source names {sv.named[0]}, {sv.named[1]}",
                       f"headplod track --source v4l2:auto --calib {path} (or --source v4l2:{left},{right})")]
    return [Result(OK, name, found)]


def _check_egl(sv: _Survey) -> list[Result]:
    try:
        ctx = sv.m.gl_context()
    except Exception as exc:
        text = str(exc).split(". Hint:")[0]
        return [Result(FAIL, "EGL", f"no headless OpenGL context: {text}", EGL_FIX)]
    try:
        info = ctx.info
        renderer, version = info.get("GL_RENDERER", "?"), info.get("GL_VERSION", "?")
    finally:
        ctx.release()
    soft = any(k in str(renderer).lower() for k in ("llvmpipe", "softpipe", "swrast"))
    return [Result(OK, "EGL", f"{renderer}, OpenGL {version}" + (" (software rendering)" if soft else ""))]


#: The checks in the order they run and print.
CHECKS = (_check_config, _check_source, _check_devices, _check_group, _check_access, _check_formats, _check_libusb,
          _check_identity, _check_rig, _check_egl)
_CHECK_NAMES = {_check_config: "config", _check_source: "source", _check_devices: "video devices", _check_group: "video group",
                _check_access: "device access", _check_formats: "formats", _check_libusb: "libusb",
                _check_identity: "camera identity", _check_rig: "rig", _check_egl: "EGL"}


def _guard(name: str, check: Callable, *args) -> list[Result]:
    """``check(*args)``, or one FAIL line naming the error it raised."""
    try:
        return check(*args)
    except Exception as exc:
        return [Result(FAIL, name, f"the check itself failed: {type(exc).__name__}: {exc}",
                       "this is a bug in headplod doctor: please report this line")]


def doctor(machine: Machine | None = None, settings: DoctorSettings | None = None, *,
           calib: str | None = None, source: str | None = None) -> list[Result]:
    """Run every check; their lines, in order. Never raises (a check's error is its FAIL line).

    Parameters
    ----------
    machine : Machine, optional
        What to look at (default: this machine).
    settings : DoctorSettings, optional
    calib : str, optional
        The rig.yaml to check (``--calib``).
    source : str, optional
        The source spec ``track`` would be given (``--source``).
    """
    machine = machine or Machine()
    settings = settings or DoctorSettings()
    sv = _Survey(machine, settings, calib, source)
    return [r for check in CHECKS for r in _guard(_CHECK_NAMES[check], check, sv)]


def format_results(results: Sequence[Result], quiet: bool = False) -> str:
    """The printed report: one line per result, its fix indented below, then a count (no trailing newline).

    With ``quiet`` only the warn and FAIL lines (and nothing when there are none).
    """
    shown = [r for r in results if not quiet or r.status in (WARN, FAIL)]
    width = max((len(r.check) for r in shown), default=0)
    lines = []
    for r in shown:
        lines.append(f"{r.status:<4}  {r.check:<{width}}  {r.found}")
        if r.fix and r.status in (WARN, FAIL):
            lines.append(f"{'':<4}  {'':<{width}}  fix: {r.fix}")
    if not quiet:
        counts = ", ".join(f"{sum(r.status == s for r in results)} {s}" for s in STATUSES)
        lines.append(f"headplod doctor: {len(results)} checks: {counts}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# the command
# ---------------------------------------------------------------------------

def add_doctor_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``doctor``'s options to a (sub)parser; returns it."""
    parser.add_argument("--calib", metavar="RIG_YAML",
                        help="the rig.yaml to check (age, RMS, its cameras); without it the --source dataset's, "
                             "else ./rig.yaml, else the rig checks are skipped")
    parser.add_argument("--source", metavar="SPEC",
                        help="the source you will track: v4l2:/dev/video0,/dev/video2 checks those two devices, "
                             "v4l2:auto the ones --calib names (as 'headplod track --source')")
    add_quiet_argument(parser, help="print only the warn and FAIL lines")
    return parser


def run_doctor(args, machine: Machine | None = None, settings: DoctorSettings | None = None) -> int:
    """Run ``headplod doctor`` from parsed arguments; 0 when no check FAILs, else 1."""
    given = config_from_args(args)
    if machine is None:
        machine = Machine(config=lambda: given)
    # what the command line gave; the config file's values are reported as the config's
    calib = None if given.calib is not None else getattr(args, "calib", None)
    source = None if given.source is not None else getattr(args, "source", None)
    results = doctor(machine, settings, calib=calib, source=source)
    text = format_results(results, quiet=getattr(args, "quiet", False))
    if text:
        print(text)
    sys.stdout.flush()
    return 1 if any(r.status == FAIL for r in results) else 0
