"""Camera identity over USB, so the calibration follows the physical camera.

Linux numbers video devices in probe order: after a reboot or a replug the
left camera may come back as ``/dev/video2`` and the right one as
``/dev/video0``. A calibration stored against device paths would then be
applied to the wrong cameras, silently. This module names each camera by
what does not change with the probe order:

- the USB vendor and product ids and the serial number string, read from the
  device with pyusb (libusb-1.0), falling back to the strings the kernel
  already read into sysfs when the device cannot be opened (no permission);
- the USB port path (``1-2.3``: bus 1, root port 2, hub port 3), which stays
  the same as long as the cameras stay in the same sockets.

``rig.yaml`` stores both for each camera under the keys ``left_camera`` and
``right_camera`` (see :func:`rig_with_cameras`); :func:`resolve_rig_cameras`
maps them back to today's device paths.

Video devices are found through sysfs, ``/sys/class/video4linux/videoN``:
``name``, ``index`` (a UVC camera exposes a capture node with index 0 and a
metadata node with index 1) and the ``device`` link into the USB interface
directory, whose parent is the USB device directory (``busnum``, ``devnum``,
``idVendor``, ``idProduct``, ``serial``, ``manufacturer``, ``product``; its
name is the port path).
"""
from __future__ import annotations

import dataclasses
import os
import re
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import usb.backend.libusb0 as libusb0
import usb.backend.libusb1 as libusb1
import usb.backend.openusb as openusb
import usb.core
import usb.util

from headplod import io

__all__ = [
    "CameraInfo",
    "LibusbMissingError",
    "LEFT_KEY",
    "RIGHT_KEY",
    "list_cameras",
    "list_video_nodes",
    "libusb_available",
    "identity_of",
    "match_camera",
    "resolve_rig_cameras",
    "rig_with_cameras",
    "format_cameras",
]

#: ``rig.yaml`` keys holding the identities of the left and right cameras.
LEFT_KEY = "left_camera"
RIGHT_KEY = "right_camera"

LIBUSB_INSTALL_HINT = (
    "install libusb-1.0: sudo apt-get install libusb-1.0-0 (Debian/Ubuntu); "
    "./setup.sh does it"
)

_VIDEO_RE = re.compile(r"^video(\d+)$")
#: Directory levels searched above the video node's ``device`` link for the
#: USB device (interface -> device is one level for UVC cameras).
_USB_PARENT_LEVELS = 3
#: Errors pyusb raises when string descriptors cannot be read (no permission
#: to open the device, no language ids, a backend without control transfers).
_STRING_ERRORS = (usb.core.USBError, ValueError, NotImplementedError, OSError)


class LibusbMissingError(usb.core.NoBackendError):
    """pyusb found no USB backend (libusb-1.0 is not installed).

    A subclass of :class:`usb.core.NoBackendError` whose message says how to
    install libusb.
    """


@dataclass(frozen=True)
class CameraInfo:
    """One video device and, when it is on USB, the identity of its camera.

    Parameters
    ----------
    device : str
        The device node, e.g. ``/dev/video0``.
    name : str
        The V4L2 device name from sysfs (``HD Webcam C270``).
    vendor_id, product_id : int or None
        USB idVendor, idProduct; None when the device is not on USB
        (platform cameras, v4l2loopback).
    manufacturer, product, serial : str or None
        USB string descriptors; None when absent or not on USB.
    bus : int or None
        USB bus number.
    address : int or None
        USB device address on the bus (``devnum``; changes on every replug).
    port_path : str or None
        USB port path, the sysfs name of the USB device: ``1-2.3`` is bus 1,
        root hub port 2, then port 3 of the hub behind it.
    note : str or None
        What could not be read and where the values came from instead.
    index : int or None
        The V4L2 node index: 0 for a camera's capture node, 1 and up for its
        metadata nodes.
    """

    device: str
    name: str
    vendor_id: int | None = None
    product_id: int | None = None
    manufacturer: str | None = None
    product: str | None = None
    serial: str | None = None
    bus: int | None = None
    address: int | None = None
    port_path: str | None = None
    note: str | None = None
    index: int | None = None

    @property
    def is_usb(self) -> bool:
        """Whether the device is a USB camera (vendor and product ids known)."""
        return self.vendor_id is not None and self.product_id is not None

    @property
    def usb_id(self) -> str | None:
        """``vvvv:pppp`` in hex as ``lsusb`` prints it, or None off USB."""
        if not self.is_usb:
            return None
        return f"{self.vendor_id:04x}:{self.product_id:04x}"

    def describe(self) -> str:
        """One line naming the device for messages."""
        if not self.is_usb:
            return f"{self.device} ({self.name}, not on USB)"
        serial = f"serial {self.serial}" if self.serial else "no serial"
        return f"{self.device} ({self.name}, {self.usb_id}, {serial}, port {self.port_path})"


# --------------------------------------------------------------------------
# libusb backend
# --------------------------------------------------------------------------

def _no_backend_error(cause: BaseException | None = None) -> LibusbMissingError:
    detail = f" ({cause})" if cause is not None and str(cause) else ""
    return LibusbMissingError(
        f"pyusb found no USB backend{detail}: camera identity needs libusb-1.0; "
        + LIBUSB_INSTALL_HINT
    )


def _find_usb_devices(backend: Any) -> list:
    """All USB devices pyusb enumerates, or raise LibusbMissingError."""
    try:
        return list(usb.core.find(find_all=True, backend=backend))
    except usb.core.NoBackendError as exc:
        raise _no_backend_error(exc) from exc


def libusb_available(backend: Any = None) -> tuple[bool, str]:
    """Whether pyusb has a USB backend that can enumerate devices.

    Parameters
    ----------
    backend : usb.backend.IBackend, optional
        The backend to check; by default pyusb's own choice (libusb-1.0,
        then OpenUSB, then libusb-0.1).

    Returns
    -------
    ok : bool
    message : str
        The backend and the number of USB devices it sees, or what is wrong
        and how to fix it (the install command when libusb is missing).
    """
    try:
        devices = _find_usb_devices(backend)
    except LibusbMissingError as exc:
        return False, str(exc)
    except usb.core.USBError as exc:
        return False, f"libusb is installed but cannot enumerate USB devices: {exc}"
    if backend is None:
        name = next(
            (m.__name__ for m in (libusb1, openusb, libusb0) if m.get_backend() is not None),
            "unknown",
        )
    else:
        name = type(backend).__name__
    return True, f"pyusb backend {name}: {len(devices)} USB devices"


# --------------------------------------------------------------------------
# sysfs
# --------------------------------------------------------------------------

def _read_text(path: Path) -> str | None:
    """The stripped content of a sysfs attribute, or None when unreadable."""
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _read_int(path: Path, base: int = 10) -> int | None:
    text = _read_text(path)
    if text is None:
        return None
    try:
        return int(text, base)
    except ValueError:
        return None


def _usb_device_dir(node: Path) -> Path | None:
    """The USB device directory behind a video4linux node, or None."""
    link = node / "device"
    if not link.exists():
        return None
    d = Path(os.path.realpath(link))
    for _ in range(_USB_PARENT_LEVELS):
        if (d / "busnum").is_file() and (d / "devnum").is_file() and (d / "idVendor").is_file():
            return d
        d = d.parent
    return None


def _sysfs_camera(node: Path, dev_root: str) -> CameraInfo:
    """A CameraInfo from sysfs alone (USB strings as the kernel read them)."""
    device = os.path.join(dev_root, node.name)
    name = _read_text(node / "name") or node.name
    index = _read_int(node / "index")
    notes = []
    if not os.path.exists(device):
        notes.append(
            f"{device} does not exist (device node not created, or not passed "
            "to this container)"
        )
    usb_dir = _usb_device_dir(node)
    if usb_dir is None:
        return CameraInfo(device=device, name=name, index=index, note="; ".join(notes) or None)
    return CameraInfo(
        device=device,
        name=name,
        vendor_id=_read_int(usb_dir / "idVendor", 16),
        product_id=_read_int(usb_dir / "idProduct", 16),
        manufacturer=_read_text(usb_dir / "manufacturer"),
        product=_read_text(usb_dir / "product"),
        serial=_read_text(usb_dir / "serial"),
        bus=_read_int(usb_dir / "busnum"),
        address=_read_int(usb_dir / "devnum"),
        port_path=usb_dir.name,
        note="; ".join(notes) or None,
        index=index,
    )


def _with_usb_identity(info: CameraInfo, dev: Any | None) -> CameraInfo:
    """Replace the sysfs identity by what pyusb reads from the device."""
    notes = [info.note] if info.note else []
    if dev is None:
        notes.append(
            f"pyusb does not see bus {info.bus} address {info.address}; "
            "identity from sysfs"
        )
        return dataclasses.replace(info, note="; ".join(notes))
    if (dev.idVendor, dev.idProduct) != (info.vendor_id, info.product_id):
        notes.append(
            f"pyusb sees {dev.idVendor:04x}:{dev.idProduct:04x} at bus {info.bus} "
            f"address {info.address}, sysfs {info.usb_id} (replugged while listing?); "
            "identity from sysfs"
        )
        return dataclasses.replace(info, note="; ".join(notes))
    strings: dict[str, str | None] = {}
    failed: list[str] = []
    reason = ""
    try:
        for field, index in (
            ("manufacturer", dev.iManufacturer),
            ("product", dev.iProduct),
            ("serial", dev.iSerialNumber),
        ):
            try:
                strings[field] = usb.util.get_string(dev, index)
            except _STRING_ERRORS as exc:
                failed.append(field)
                reason = reason or str(exc) or type(exc).__name__
    finally:
        try:
            usb.util.dispose_resources(dev)
        except _STRING_ERRORS:
            pass
    if failed:
        notes.append(
            f"{', '.join(failed)} from sysfs: pyusb could not read the USB string "
            f"descriptors ({reason}); run as root or add a udev rule to read them over USB"
        )
    return dataclasses.replace(
        info,
        vendor_id=int(dev.idVendor),
        product_id=int(dev.idProduct),
        note="; ".join(notes) or None,
        **strings,
    )


def list_cameras(
    sysfs_root: str = "/sys",
    dev_root: str = "/dev",
    backend: Any = None,
    all_nodes: bool = False,
) -> list[CameraInfo]:
    """The video capture devices and the identity of their cameras.

    Parameters
    ----------
    sysfs_root : str
        Where sysfs is mounted; devices are read from
        ``{sysfs_root}/class/video4linux/videoN``.
    dev_root : str
        Where the device nodes are; a device is ``{dev_root}/videoN``.
    backend : usb.backend.IBackend, optional
        The pyusb backend; by default pyusb's own choice (libusb-1.0).
    all_nodes : bool
        List every video node. By default only nodes with V4L2 index 0 are
        listed: a UVC camera's capture node; its metadata nodes (index 1)
        cannot capture images.

    Returns
    -------
    list of CameraInfo
        In device number order; empty when there is no
        ``class/video4linux`` (no video devices, or no videodev driver).
        Devices not on USB have None in the USB fields.

    Raises
    ------
    LibusbMissingError
        If there are USB cameras and pyusb finds no libusb backend; the
        message gives the install command. Without USB cameras pyusb is not
        asked.

    Notes
    -----
    The vendor and product ids and the manufacturer, product and serial
    strings are read with pyusb, matching the USB device by bus number and
    address. Reading strings opens the device, which needs write permission
    on ``/dev/bus/usb/BBB/DDD``; when that fails the strings the kernel read
    into sysfs at enumeration (the same descriptors) are used and
    ``CameraInfo.note`` says so.
    """
    class_dir = Path(sysfs_root) / "class" / "video4linux"
    if not class_dir.is_dir():
        return []
    nodes = []
    for entry in class_dir.iterdir():
        m = _VIDEO_RE.match(entry.name)
        if m:
            nodes.append((int(m.group(1)), entry))
    nodes.sort()
    cameras = [_sysfs_camera(node, dev_root) for _, node in nodes]
    if not all_nodes:
        cameras = [c for c in cameras if c.index in (0, None)]
    if not any(c.is_usb for c in cameras):
        return cameras
    by_address = {(d.bus, d.address): d for d in _find_usb_devices(backend)}
    return [
        _with_usb_identity(c, by_address.get((c.bus, c.address))) if c.is_usb else c
        for c in cameras
    ]


def list_video_nodes(sysfs_root: str = "/sys", dev_root: str = "/dev") -> list[CameraInfo]:
    """Every video node as sysfs describes it, without asking pyusb (works without libusb).

    Like :func:`list_cameras` with ``all_nodes=True``, except that the USB
    strings (manufacturer, product, serial) are the ones the kernel read
    into sysfs at enumeration, and no device is opened.

    Returns
    -------
    list of CameraInfo
        In device number order; empty when there is no ``class/video4linux``.
    """
    class_dir = Path(sysfs_root) / "class" / "video4linux"
    if not class_dir.is_dir():
        return []
    nodes = sorted((int(m.group(1)), entry) for entry in class_dir.iterdir()
                   if (m := _VIDEO_RE.match(entry.name)))
    return [_sysfs_camera(node, dev_root) for _, node in nodes]


# --------------------------------------------------------------------------
# identities in rig.yaml
# --------------------------------------------------------------------------

def identity_of(info: CameraInfo) -> dict[str, str]:
    """The identity of a USB camera, as stored in ``rig.yaml``.

    Parameters
    ----------
    info : CameraInfo
        A USB camera from :func:`list_cameras`.

    Returns
    -------
    dict of str to str
        ``vendor_id`` and ``product_id`` as four hex digits, ``serial``
        (``""`` when the camera has none) and ``port_path``, e.g.
        ``{"vendor_id": "046d", "product_id": "0825", "serial": "ABC123",
        "port_path": "1-2.3"}``. All values are strings so that OpenCV
        FileStorage keeps them as written (``"0825"`` stays text).

    Raises
    ------
    ValueError
        If the device is not on USB: it has no identity that survives a
        reboot.
    """
    if not info.is_usb:
        raise ValueError(
            f"{info.device} ({info.name}) is not a USB camera, so it has no vendor, "
            "product, serial or port to recognise it by after a reboot"
        )
    return {
        "vendor_id": f"{info.vendor_id:04x}",
        "product_id": f"{info.product_id:04x}",
        "serial": info.serial or "",
        "port_path": info.port_path or "",
    }


def _parse_id(identity: Mapping, key: str) -> int:
    value = identity.get(key)
    if isinstance(value, str):
        try:
            return int(value, 16)
        except ValueError:
            pass
    elif isinstance(value, int) and not isinstance(value, bool):
        return value
    raise ValueError(
        f"camera identity {key} is {value!r}, expected four hex digits such as '046d' "
        "(the lsusb notation)"
    )


def _parse_text(identity: Mapping, key: str) -> str | None:
    """A string entry; None when missing or empty. Unquoted numbers become text."""
    value = identity.get(key)
    if value is None:
        return None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str):
        raise ValueError(f"camera identity {key} is {value!r}, expected a string")
    return value or None


def _parse_identity(identity: Any) -> tuple[int, int, str | None, str | None]:
    if not isinstance(identity, Mapping):
        raise ValueError(
            f"a camera identity is a mapping with vendor_id, product_id, serial and "
            f"port_path, got {type(identity).__name__} {identity!r}"
        )
    return (
        _parse_id(identity, "vendor_id"),
        _parse_id(identity, "product_id"),
        _parse_text(identity, "serial"),
        _parse_text(identity, "port_path"),
    )


def _describe_identity(vid: int, pid: int, serial: str | None, port: str | None) -> str:
    s = f"serial {serial}" if serial else "no serial"
    return f"{vid:04x}:{pid:04x} ({s}, port {port or '?'})"


def _present(cameras: Sequence[CameraInfo]) -> str:
    if not cameras:
        return "No video devices are present: are the cameras plugged in?"
    return "Cameras present: " + "; ".join(c.describe() for c in cameras)


def _match(
    identity: Any, cameras: Sequence[CameraInfo], use_serial: bool, role: str
) -> CameraInfo:
    vid, pid, serial, port = _parse_identity(identity)
    wanted = f"{role}{_describe_identity(vid, pid, serial, port)}"
    same_model = [c for c in cameras if (c.vendor_id, c.product_id) == (vid, pid)]
    same_unit = [c for c in same_model if c.serial == serial] if serial else same_model
    if serial is not None and use_serial and len(same_unit) == 1:
        return same_unit[0]
    if not same_unit and serial is not None:
        at_port = [c for c in same_model if port is not None and c.port_path == port]
        other = (
            f"; at port {port} there is {at_port[0].describe()}, another unit of "
            "the same model: recalibrate, or edit the identity in rig.yaml if the "
            "camera really is the same"
            if at_port else ""
        )
        raise LookupError(
            f"no camera matches {wanted}: no {vid:04x}:{pid:04x} with serial "
            f"{serial}{other}. {_present(cameras)}"
        )
    # No serial, or several cameras share it: the port path decides.
    if port is None:
        raise LookupError(
            f"no camera can be chosen for {wanted}: without a unique serial the port "
            f"path is needed and the identity has none. {_present(cameras)}"
        )
    by_port = [c for c in same_unit if c.port_path == port]
    if len(by_port) == 1:
        return by_port[0]
    if not by_port:
        moved = (
            f"; {len(same_unit)} camera(s) of that model are on other ports: "
            "plug the cameras back into the sockets used at calibration"
            if same_unit else ""
        )
        raise LookupError(f"no camera matches {wanted}{moved}. {_present(cameras)}")
    raise LookupError(
        f"{len(by_port)} video devices match {wanted}: "
        f"{', '.join(c.device for c in by_port)}; list only capture nodes "
        f"(list_cameras(all_nodes=False)). {_present(cameras)}"
    )


def match_camera(identity: Mapping, cameras: Sequence[CameraInfo]) -> CameraInfo:
    """The camera an identity from ``rig.yaml`` refers to.

    The camera is found by vendor/product id and serial number when the
    serial is present in the identity and exactly one camera of that model
    has it; otherwise by vendor/product id and USB port path. Cheap webcams
    often share one serial across all units (or have none), so the serial
    alone cannot tell two of them apart; the port path can, as long as each
    camera stays in the socket it was calibrated in.

    Parameters
    ----------
    identity : mapping
        As returned by :func:`identity_of` or read back from ``rig.yaml``:
        ``vendor_id``, ``product_id`` (hex strings or ints), ``serial``
        (``""`` or missing: none), ``port_path``.
    cameras : sequence of CameraInfo
        The cameras present, from :func:`list_cameras`.

    Returns
    -------
    CameraInfo

    Raises
    ------
    LookupError
        If no camera matches, or several do; the message lists the cameras
        present. A camera of the right model at the right port but with a
        different serial is not taken: it is another unit, and the
        calibration does not belong to it.
    ValueError
        If the identity is malformed.
    """
    return _match(identity, cameras, use_serial=True, role="")


def _rig_identity(rig: io.Rig, key: str) -> Mapping:
    where = f"{rig.path}: " if rig.path else ""
    if key not in rig.extra:
        raise LookupError(
            f"{where}rig.yaml has no {key} (keys present: {', '.join(rig.extra) or 'none'}), so the cameras "
            "cannot be told apart after a reboot; store their identities with: headplod cameras --store --source "
            f"v4l2:LEFT,RIGHT --rig {shlex.quote(str(rig.path)) if rig.path else 'rig.yaml'}"
        )
    value = rig.extra[key]
    if not isinstance(value, Mapping):
        raise ValueError(
            f"{where}{key} is {value!r}, expected a map with vendor_id, product_id, "
            "serial and port_path"
        )
    return value


def resolve_rig_cameras(rig: io.Rig, cameras: Sequence[CameraInfo]) -> tuple[str, str]:
    """The device paths of the rig's left and right cameras today.

    Parameters
    ----------
    rig : io.Rig
        With ``left_camera`` and ``right_camera`` in ``rig.extra``
        (see :func:`rig_with_cameras`).
    cameras : sequence of CameraInfo
        The cameras present, from :func:`list_cameras`.

    Returns
    -------
    left, right : str
        Device paths such as ``/dev/video2``, ``/dev/video0``.

    Raises
    ------
    LookupError
        If the rig has no identities, a camera is missing or ambiguous
        (see :func:`match_camera`), or both identities name the same device.
    ValueError
        If an identity in the rig is malformed.

    Notes
    -----
    When the two identities carry the same model and serial, the serial
    cannot tell them apart and both are matched by port path: otherwise,
    with one camera unplugged, both would resolve to the other one.
    """
    left_id = _rig_identity(rig, LEFT_KEY)
    right_id = _rig_identity(rig, RIGHT_KEY)
    shared = _parse_identity(left_id)[:3] == _parse_identity(right_id)[:3]
    left = _match(left_id, cameras, use_serial=not shared, role="the left camera ")
    right = _match(right_id, cameras, use_serial=not shared, role="the right camera ")
    if left.device == right.device:
        raise LookupError(
            f"the left and right camera identities both match {left.device}; "
            f"recalibrate with two different cameras. {_present(cameras)}"
        )
    return left.device, right.device


def rig_with_cameras(rig: io.Rig, left_info: CameraInfo, right_info: CameraInfo) -> io.Rig:
    """A copy of the rig with the cameras' identities in ``rig.extra``.

    Parameters
    ----------
    rig : io.Rig
    left_info, right_info : CameraInfo
        The USB cameras the rig was calibrated with (left: the world frame).

    Returns
    -------
    io.Rig
        With ``extra["left_camera"]`` and ``extra["right_camera"]`` set to
        :func:`identity_of` of each camera; :func:`io.write_rig` writes them
        as FileStorage maps::

            left_camera:
               vendor_id: "046d"
               product_id: "0825"
               serial: "ABC123"
               port_path: "1-2"

    Raises
    ------
    ValueError
        If a camera is not on USB, or both are the same device.
    """
    if left_info.device == right_info.device:
        raise ValueError(f"left and right are the same device {left_info.device}")
    extra = dict(rig.extra)
    extra[LEFT_KEY] = identity_of(left_info)
    extra[RIGHT_KEY] = identity_of(right_info)
    return dataclasses.replace(rig, extra=extra)


def store_rig_cameras(rig_path, left_device: str, right_device: str, cameras: Sequence[CameraInfo]) -> io.Rig:
    """Record in ``rig_path`` (rewritten) which USB cameras are its left and right ones.

    Parameters
    ----------
    rig_path : str or Path
        A rig.yaml (contract format), calibrated with these two cameras.
    left_device, right_device : str
        Their device nodes now, e.g. ``/dev/video0`` (or ``0``).
    cameras : sequence of CameraInfo
        :func:`list_cameras`.

    Returns
    -------
    io.Rig
        The rig as written.

    Raises
    ------
    LookupError
        If a device is not among ``cameras`` (the message lists them).
    ValueError
        If a camera is not on USB, or both are the same.
    """
    def find(device):
        text = str(device)
        for info in cameras:
            if info.device == text or (text.isdigit() and Path(info.device).name == f"video{text}"):
                return info
        name = f"/dev/video{text}" if text.isdigit() else text
        raise LookupError(f"{name} is not a video capture device here. {_present(cameras)}")

    rig = rig_with_cameras(io.read_rig(rig_path), find(left_device), find(right_device))
    io.write_atomically(rig_path, lambda name: io.write_rig(name, rig), suffix=".tmp.yaml")   # whole or untouched
    return rig


# --------------------------------------------------------------------------
# printing
# --------------------------------------------------------------------------

def format_cameras(cameras: Sequence[CameraInfo], sysfs_root: str = "/sys") -> str:
    """The table ``headplod cameras`` prints.

    Parameters
    ----------
    cameras : sequence of CameraInfo
    sysfs_root : str
        Named in the message when the list is empty.

    Returns
    -------
    str
        One row per device (device, name, vendor:product, serial, port
        path), then the notes; or a line saying no video device was found
        and what to check. No trailing newline.
    """
    if not cameras:
        where = os.path.join(sysfs_root, "class", "video4linux")
        return (
            f"no video devices under {where}: are the cameras plugged in? Check that "
            "lsusb lists them and the uvcvideo driver is loaded (lsmod | grep uvcvideo); "
            "in a container, pass the devices through (--device /dev/video0)"
        )
    header = ("device", "name", "vendor:product", "serial", "port")
    rows = [header]
    for c in cameras:
        rows.append((
            c.device,
            c.name,
            c.usb_id or "not USB",
            (c.serial or "none") if c.is_usb else "-",
            c.port_path or "-",
        ))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(r, widths)).rstrip() for r in rows]
    lines += [f"{c.device}: {c.note}" for c in cameras if c.note]
    return "\n".join(lines)
