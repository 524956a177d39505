"""What ``headplod doctor`` looks at and what it reports: the thresholds, one check's line, the machine.

- :class:`DoctorSettings`: where the lines between ok, warn and FAIL are drawn;
- :class:`Result`: one check's printed line (status, what was checked, what was found, the fix);
- :class:`Machine`: every probe of the machine (device lister, opener, group lookup, clock, GL
  context factory, ...), each a callable so that tests simulate machines without hardware;
  :class:`GroupInfo` and :class:`ConfigDefaults` are two of the values it gives;
- :func:`guard`: a check that raises becomes its own FAIL line.

The checks (:mod:`.checks`, :mod:`.rig_checks`) take these and return lists of :class:`Result`.
"""
from __future__ import annotations

import glob
import grp
import os
import pwd
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from .. import io
from ..capture import usb
from ..capture.formats import device_formats
from ..render.context import EGL_PACKAGES, create_context

__all__ = ["DoctorSettings", "Result", "Machine", "GroupInfo", "ConfigDefaults", "video_group_info",
           "config_from_args", "guard", "OK", "WARN", "FAIL", "SKIP", "STATUSES"]


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




def guard(name: str, check: Callable, *args) -> list[Result]:
    """``check(*args)``, or one FAIL line named ``name`` with the error it raised."""
    try:
        return check(*args)
    except Exception as exc:
        return [Result(FAIL, name, f"the check itself failed: {type(exc).__name__}: {exc}",
                       "this is a bug in headplod doctor: please report this line")]
