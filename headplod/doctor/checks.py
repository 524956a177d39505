"""The checks of ``headplod doctor`` but the rig's: config, source, video devices, group, access, formats,
libusb, camera identity, EGL.

Each check takes the run's :class:`Survey` (the inputs, each read once from the :class:`~.machine.Machine`,
and what earlier checks found) and returns its lines, a list of :class:`~.machine.Result`;
:func:`judge_formats` is the pure judgement of one device's modes at an image size (px).
"""
from __future__ import annotations

import errno
from pathlib import Path
from typing import Any, Sequence

from ..capture import usb
from ..capture.formats import PixelFormat
from ..capture.sources import source_forms, source_kind, v4l2_devices
from .machine import (COMPRESSED, EGL_FIX, FAIL, LIBUSB_FIX, NO_CAMERA_FIX, OK, SKIP, UNCOMPRESSED, USERMOD_FIX, WARN,
                      ConfigDefaults, DoctorSettings, Machine, Result)

__all__ = ["Survey", "judge_formats", "check_config", "check_source", "check_devices", "check_group",
           "check_access", "check_formats", "check_libusb", "check_identity", "check_egl"]

_NOT_READ = object()


class Survey:
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

def check_config(sv: Survey) -> list[Result]:
    c = sv.config
    if c.error:
        return [Result(FAIL, "config", c.error, "fix the file, or run with --no-config")]
    if c.path is None:
        return [Result(SKIP, "config", "no config file (./headplod.toml, ~/.config/headplod/config.toml)")]
    used = [f"calib {c.calib}"] * (c.calib is not None) + [f"source {c.source}"] * (c.source is not None)
    return [Result(OK, "config", f"{c.path}" + (f": {', '.join(used)}" if used else ": no calib or source for doctor"))]


def check_source(sv: Survey) -> list[Result]:
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


def check_devices(sv: Survey) -> list[Result]:
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


def check_group(sv: Survey) -> list[Result]:
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


def check_access(sv: Survey) -> list[Result]:
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


def check_formats(sv: Survey) -> list[Result]:
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


def check_libusb(sv: Survey) -> list[Result]:
    ok, message = sv.m.libusb()
    if ok:
        return [Result(OK, "libusb", message)]
    return [Result(FAIL, "libusb", message.split("; install libusb")[0], LIBUSB_FIX)]


def check_identity(sv: Survey) -> list[Result]:
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


def check_egl(sv: Survey) -> list[Result]:
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
