"""Camera identity: a fake sysfs tree and a fake pyusb backend, no hardware.

The sysfs tree mimics a Linux machine with two UVC webcams (a capture node
with index 0 and a metadata node with index 1 each) and a v4l2loopback
device; the backend answers pyusb's enumeration and GET_DESCRIPTOR string
requests from the same description, the way libusb would.
"""
from __future__ import annotations

import array
import os
from pathlib import Path
from types import SimpleNamespace

import pytest
import usb.backend
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core

from headplod.capture import usb as hc
from headplod import io

PCI = "devices/pci0000:00/0000:00:14.0/usb1"

# Two units of one model (Logitech C270 ids) with different serials.
LEFT = dict(port="1-2", devnum=5, vid=0x046D, pid=0x0825, serial="ABC123",
            manufacturer="Logitech", product="C270 HD WEBCAM", name="C270 HD WEBCAM")
RIGHT = dict(port="1-3", devnum=7, vid=0x046D, pid=0x0825, serial="XYZ789",
             manufacturer="Logitech", product="C270 HD WEBCAM", name="C270 HD WEBCAM")


def make_sysfs(root: Path, cams: list[dict], loopback: int | None = None) -> tuple[str, str]:
    """A sysfs tree under root/sys and device nodes under root/dev.

    Each camera dict has ``videos`` (its two node numbers: capture, metadata)
    and the USB fields of LEFT/RIGHT; ``serial=None`` writes no serial file.
    """
    sys_root, dev_root = root / "sys", root / "dev"
    cls = sys_root / "class" / "video4linux"
    cls.mkdir(parents=True)
    dev_root.mkdir()

    def node(target: Path, video: int, name: str, index: int) -> None:
        target.mkdir(parents=True)
        (target / "name").write_text(name + "\n")
        (target / "index").write_text(f"{index}\n")
        os.symlink(os.path.relpath(target, cls), cls / f"video{video}")
        (dev_root / f"video{video}").touch()

    for cam in cams:
        usb_dir = sys_root / PCI / cam["port"]
        intf = usb_dir / f"{cam['port']}:1.0"
        intf.mkdir(parents=True)
        attrs = {"busnum": "1", "devnum": str(cam["devnum"]),
                 "idVendor": f"{cam['vid']:04x}", "idProduct": f"{cam['pid']:04x}",
                 "manufacturer": cam["manufacturer"], "product": cam["product"]}
        if cam.get("serial") is not None:
            attrs["serial"] = cam["serial"]
        for k, v in attrs.items():
            (usb_dir / k).write_text(v + "\n")
        for index, video in enumerate(cam["videos"]):
            target = intf / "video4linux" / f"video{video}"
            node(target, video, cam["name"], index)
            os.symlink(os.path.relpath(intf, target), target / "device")
    if loopback is not None:
        node(sys_root / "devices" / "virtual" / "video4linux" / f"video{loopback}",
             loopback, "Dummy video device (0x0000)", 0)
    return str(sys_root), str(dev_root)


class FakeBackend(usb.backend.IBackend):
    """A pyusb backend presenting USB devices from a description.

    Each device dict has ``bus``, ``devnum``, ``vid``, ``pid`` and the strings
    ``manufacturer``, ``product``, ``serial`` (None: no string descriptor).
    With ``deny_open`` opening a device fails as it does without permission
    on /dev/bus/usb.
    """

    def __init__(self, devices: list[dict], deny_open: bool = False):
        self.devices = devices
        self.deny_open = deny_open
        self.open_handles = 0

    def enumerate_devices(self):
        return iter(range(len(self.devices)))

    def get_device_descriptor(self, dev):
        d = self.devices[dev]
        strings = [d.get(k) for k in ("manufacturer", "product", "serial")]
        i_man, i_prod, i_ser = (i + 1 if s is not None else 0 for i, s in enumerate(strings))
        return SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0xEF,
            bDeviceSubClass=2, bDeviceProtocol=1, bMaxPacketSize0=64,
            idVendor=d["vid"], idProduct=d["pid"], bcdDevice=0x0010,
            iManufacturer=i_man, iProduct=i_prod, iSerialNumber=i_ser,
            bNumConfigurations=1, address=d["devnum"], bus=d.get("bus", 1),
            port_number=None, port_numbers=None, speed=None,
        )

    def get_configuration_descriptor(self, dev, config):
        return SimpleNamespace(
            bLength=9, bDescriptorType=2, wTotalLength=9, bNumInterfaces=0,
            bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80,
            bMaxPower=250, extra_descriptors=[],
        )

    def open_device(self, dev):
        if self.deny_open:
            raise usb.core.USBError("Access denied (insufficient permissions)", -3, 13)
        self.open_handles += 1
        return dev

    def close_device(self, dev_handle):
        self.open_handles -= 1

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        desc_type, desc_index = wValue >> 8, wValue & 0xFF
        if bmRequestType != 0x80 or bRequest != 0x06 or desc_type != 3:
            raise usb.core.USBError("Pipe error (request not supported by the fake)", -9, 32)
        if desc_index == 0:
            payload = bytes([4, 3, 0x09, 0x04])  # language id table: en-US
        else:
            if wIndex != 0x0409:
                raise usb.core.USBError("Pipe error (unknown language id)", -9, 32)
            d = self.devices[dev_handle]
            text = [d.get("manufacturer"), d.get("product"), d.get("serial")][desc_index - 1]
            encoded = text.encode("utf-16-le")
            payload = bytes([2 + len(encoded), 3]) + encoded
        n = min(len(payload), len(data))
        data[:n] = array.array("B", payload[:n])
        return n


def usb_devices(*cams: dict, **changes) -> list[dict]:
    """Backend device dicts for the cameras (plus a hub, as on a real bus)."""
    hub = dict(devnum=1, vid=0x1D6B, pid=0x0002, manufacturer="Linux", product="xHCI Host Controller",
               serial="0000:00:14.0")
    return [hub] + [{**c, **changes} for c in cams]


@pytest.fixture
def boot1(tmp_path):
    """First boot: left camera on /dev/video0 (+video1), right on /dev/video2 (+video3)."""
    sys_root, dev_root = make_sysfs(
        tmp_path / "boot1",
        [dict(LEFT, videos=(0, 1)), dict(RIGHT, videos=(2, 3))], loopback=4)
    return sys_root, dev_root, FakeBackend(usb_devices(LEFT, RIGHT))


def test_lists_capture_nodes_with_usb_identity(boot1):
    sys_root, dev_root, backend = boot1
    cams = hc.list_cameras(sys_root, dev_root, backend=backend)
    assert [c.device for c in cams] == [f"{dev_root}/video{n}" for n in (0, 2, 4)]
    left, right, loop = cams
    assert (left.vendor_id, left.product_id, left.serial) == (0x046D, 0x0825, "ABC123")
    assert (left.bus, left.address, left.port_path) == (1, 5, "1-2")
    assert (left.manufacturer, left.product, left.name) == ("Logitech", "C270 HD WEBCAM", "C270 HD WEBCAM")
    assert left.note is None and right.note is None
    assert (right.serial, right.port_path, right.address) == ("XYZ789", "1-3", 7)
    assert loop.name == "Dummy video device (0x0000)"
    assert not loop.is_usb and loop.port_path is None and loop.serial is None
    assert backend.open_handles == 0, "string reads must release the device"

    every = hc.list_cameras(sys_root, dev_root, backend=backend, all_nodes=True)
    assert [c.index for c in every] == [0, 1, 0, 1, 0]


def test_strings_come_from_usb_when_readable(tmp_path):
    sys_root, dev_root = make_sysfs(tmp_path, [dict(LEFT, videos=(0, 1))])
    backend = FakeBackend(usb_devices(LEFT, product="C270 over USB"))
    (cam,) = hc.list_cameras(sys_root, dev_root, backend=backend)
    assert cam.product == "C270 over USB" and cam.note is None


def test_string_read_failure_falls_back_to_sysfs(tmp_path):
    sys_root, dev_root = make_sysfs(tmp_path, [dict(LEFT, videos=(0, 1))])
    backend = FakeBackend(usb_devices(LEFT, product="C270 over USB"), deny_open=True)
    (cam,) = hc.list_cameras(sys_root, dev_root, backend=backend)
    assert (cam.manufacturer, cam.product, cam.serial) == ("Logitech", "C270 HD WEBCAM", "ABC123")
    assert "sysfs" in cam.note and "manufacturer, product, serial" in cam.note
    assert "root" in cam.note or "udev" in cam.note
    assert cam.device.endswith("video0") and cam.port_path == "1-2"


def test_device_unknown_to_pyusb_keeps_sysfs_identity_with_note(tmp_path):
    sys_root, dev_root = make_sysfs(tmp_path, [dict(LEFT, videos=(0, 1))])
    (cam,) = hc.list_cameras(sys_root, dev_root, backend=FakeBackend(usb_devices()))
    assert cam.serial == "ABC123" and "pyusb does not see bus 1 address 5" in cam.note


def test_identity_and_match(boot1):
    sys_root, dev_root, backend = boot1
    left, right, loop = hc.list_cameras(sys_root, dev_root, backend=backend)
    ident = hc.identity_of(left)
    assert ident == {"vendor_id": "046d", "product_id": "0825", "serial": "ABC123", "port_path": "1-2"}
    cams = [left, right, loop]
    assert hc.match_camera(ident, cams) is left
    assert hc.match_camera(hc.identity_of(right), cams) is right
    # The serial wins over a port path that changed (camera moved to another socket).
    assert hc.match_camera({**ident, "port_path": "1-9"}, cams) is left
    # Integer ids, as a hand-written rig.yaml may have them.
    assert hc.match_camera({**ident, "vendor_id": 0x046D, "product_id": 0x0825}, cams) is left
    with pytest.raises(ValueError, match="not a USB camera"):
        hc.identity_of(loop)
    with pytest.raises(ValueError, match="vendor_id"):
        hc.match_camera({"product_id": "0825"}, cams)


def test_swapped_device_numbers_keep_the_calibration(boot1, tmp_path, small_rig):
    sys_root, dev_root, backend = boot1
    left, right, _ = hc.list_cameras(sys_root, dev_root, backend=backend)
    path = tmp_path / "rig.yaml"
    io.write_rig(path, hc.rig_with_cameras(small_rig(rms_px=0.3), left, right))   # rms_px: kept
    text = path.read_text()
    assert 'left_camera:' in text and 'product_id: "0825"' in text
    rig = io.read_rig(path)
    assert rig.extra["rms_px"] == pytest.approx(0.3)
    assert rig.extra["left_camera"] == hc.identity_of(left)
    assert hc.resolve_rig_cameras(rig, [left, right]) == (left.device, right.device)

    # Reboot: probe order swapped, new USB addresses.
    sys2, dev2 = make_sysfs(tmp_path / "boot2",
                            [dict(LEFT, videos=(2, 3), devnum=9), dict(RIGHT, videos=(0, 1), devnum=8)],
                            loopback=4)
    backend2 = FakeBackend(usb_devices(dict(LEFT, devnum=9), dict(RIGHT, devnum=8)))
    cams2 = hc.list_cameras(sys2, dev2, backend=backend2)
    assert hc.resolve_rig_cameras(rig, cams2) == (f"{dev2}/video2", f"{dev2}/video0")


@pytest.mark.parametrize("serial", ["0001", None], ids=["shared-serial", "no-serial"])
def test_duplicate_or_missing_serials_fall_back_to_port_path(tmp_path, serial, small_rig):
    a, b = dict(LEFT, serial=serial), dict(RIGHT, serial=serial)
    s1, d1 = make_sysfs(tmp_path / "b1", [dict(a, videos=(0, 1)), dict(b, videos=(2, 3))])
    left, right = hc.list_cameras(s1, d1, backend=FakeBackend(usb_devices(a, b)))
    assert left.serial == serial
    rig = hc.rig_with_cameras(small_rig(), left, right)
    path = tmp_path / "rig.yaml"
    io.write_rig(path, rig)
    rig = io.read_rig(path)

    s2, d2 = make_sysfs(tmp_path / "b2", [dict(a, videos=(2, 3)), dict(b, videos=(0, 1))])
    cams2 = hc.list_cameras(s2, d2, backend=FakeBackend(usb_devices(a, b)))
    assert hc.resolve_rig_cameras(rig, cams2) == (f"{d2}/video2", f"{d2}/video0")

    # With the right camera unplugged, the left one is still found by port and
    # the right one is reported missing (the shared serial must not let the
    # right identity grab the left camera).
    s3, d3 = make_sysfs(tmp_path / "b3", [dict(a, videos=(0, 1))])
    cams3 = hc.list_cameras(s3, d3, backend=FakeBackend(usb_devices(a)))
    with pytest.raises(LookupError, match="right camera") as err:
        hc.resolve_rig_cameras(rig, cams3)
    assert f"{d3}/video0" in str(err.value) and "port 1-2" in str(err.value)


def test_missing_camera_names_what_is_present(boot1, small_rig):
    sys_root, dev_root, backend = boot1
    left, right, loop = hc.list_cameras(sys_root, dev_root, backend=backend)
    rig = hc.rig_with_cameras(small_rig(), left, right)
    with pytest.raises(LookupError) as err:
        hc.resolve_rig_cameras(rig, [left, loop])
    msg = str(err.value)
    assert "XYZ789" in msg and "Cameras present:" in msg
    assert left.device in msg and loop.device in msg and "046d:0825" in msg

    # Same model at the right port, but another unit: not taken.
    other = hc.CameraInfo(**{**right.__dict__, "serial": "NEW000"})
    with pytest.raises(LookupError, match="another unit"):
        hc.match_camera(hc.identity_of(right), [left, other])

    with pytest.raises(LookupError, match="No video devices are present"):
        hc.match_camera(hc.identity_of(left), [])
    with pytest.raises(LookupError, match="has no left_camera"):
        hc.resolve_rig_cameras(small_rig(), [left, right])


def test_two_nodes_of_one_camera_are_ambiguous(boot1):
    sys_root, dev_root, backend = boot1
    every = hc.list_cameras(sys_root, dev_root, backend=backend, all_nodes=True)
    with pytest.raises(LookupError, match="2 video devices match"):
        hc.match_camera(hc.identity_of(every[0]), every)


def test_no_libusb_backend_says_how_to_install(tmp_path, monkeypatch, boot1):
    # Simulate a machine without libusb: pyusb's backend modules find no library.
    for mod in (usb.backend.libusb1, usb.backend.openusb, usb.backend.libusb0):
        monkeypatch.setattr(mod, "get_backend", lambda *a, **k: None)
    sys_root, dev_root, _ = boot1
    with pytest.raises(hc.LibusbMissingError) as err:
        hc.list_cameras(sys_root, dev_root)
    assert isinstance(err.value, usb.core.NoBackendError)
    assert "sudo apt-get install libusb-1.0-0" in str(err.value) and "./setup.sh" in str(err.value)
    ok, msg = hc.libusb_available()
    assert not ok and "sudo apt-get install libusb-1.0-0" in msg
    # Without USB cameras libusb is not needed.
    s2, d2 = make_sysfs(tmp_path / "loop", [], loopback=0)
    assert [c.device for c in hc.list_cameras(s2, d2)] == [f"{d2}/video0"]


def test_libusb_available_with_backend(boot1):
    ok, msg = hc.libusb_available(boot1[2])
    assert ok and "3 USB devices" in msg


def test_format_cameras(boot1):
    sys_root, dev_root, backend = boot1
    cams = hc.list_cameras(sys_root, dev_root, backend=backend)
    lines = hc.format_cameras(cams).splitlines()
    assert lines[0].split() == ["device", "name", "vendor:product", "serial", "port"]
    assert f"{dev_root}/video0" in lines[1] and "046d:0825" in lines[1]
    assert "ABC123" in lines[1] and lines[1].endswith("1-2")
    assert "not USB" in lines[3]
    empty = hc.format_cameras([])
    assert "no video devices under /sys/class/video4linux" in empty and "plugged in" in empty
    assert hc.list_cameras(str(Path(sys_root) / "missing")) == []


def test_note_when_device_node_is_missing(tmp_path):
    sys_root, dev_root = make_sysfs(tmp_path, [], loopback=0)
    os.remove(os.path.join(dev_root, "video0"))
    (cam,) = hc.list_cameras(sys_root, dev_root)
    assert "does not exist" in cam.note
    assert f"{cam.device}: " in hc.format_cameras([cam])


def test_real_machine_lists_cameras():
    if not os.path.isdir("/sys/class/video4linux"):
        pytest.skip("no /sys/class/video4linux on this machine (no video devices or no videodev driver)")
    try:
        cams = hc.list_cameras()
    except hc.LibusbMissingError as exc:
        pytest.skip(f"USB cameras present but no libusb: {exc}")
    assert isinstance(cams, list)
    assert all(isinstance(c, hc.CameraInfo) for c in cams)


def test_libusb_available_on_this_machine():
    ok, msg = hc.libusb_available()
    assert isinstance(ok, bool) and msg
    if not ok:
        assert "apt-get install libusb-1.0-0" in msg or "cannot enumerate" in msg


def test_hand_written_identities(boot1, tmp_path, small_rig):
    sys_root, dev_root, backend = boot1
    left, right, loop = hc.list_cameras(sys_root, dev_root, backend=backend)
    # No serial key: the port path decides. An unquoted numeric serial is text.
    assert hc.match_camera({"vendor_id": "046d", "product_id": "0825", "port_path": "1-3"},
                           [left, right]) is right
    numeric = hc.CameraInfo(**{**left.__dict__, "serial": "123"})
    assert hc.match_camera({"vendor_id": "046d", "product_id": "0825", "serial": 123}, [numeric, right]) is numeric
    with pytest.raises(ValueError, match="expected a map"):
        hc.resolve_rig_cameras(io.Rig(**{**small_rig().__dict__, "extra": {
            "left_camera": "/dev/video0", "right_camera": "/dev/video2"}}), [left, right])
    with pytest.raises(ValueError, match="same device"):
        hc.rig_with_cameras(small_rig(), left, left)
    with pytest.raises(LookupError, match="both match"):
        hc.resolve_rig_cameras(
            io.Rig(**{**small_rig().__dict__, "extra": {"left_camera": hc.identity_of(left),
                                                        "right_camera": hc.identity_of(left)}}),
            [left, right])


def test_address_reused_by_another_device_is_noted(tmp_path):
    sys_root, dev_root = make_sysfs(tmp_path, [dict(LEFT, videos=(0, 1))])
    backend = FakeBackend(usb_devices(dict(LEFT, vid=0x1234, pid=0x5678)))
    (cam,) = hc.list_cameras(sys_root, dev_root, backend=backend)
    assert cam.usb_id == "046d:0825" and "pyusb sees 1234:5678" in cam.note


def test_store_identities_in_a_rig_then_auto_resolves_after_a_swap(boot1, tmp_path, small_rig):
    sys_root, dev_root, backend = boot1
    cams = hc.list_cameras(sys_root, dev_root, backend=backend)
    path = tmp_path / "rig.yaml"
    io.write_rig(path, small_rig(rms_px=0.3))
    rig = hc.store_rig_cameras(path, "0", f"{dev_root}/video2", cams)   # a number or a device path
    assert io.read_rig(path).extra["left_camera"] == rig.extra["left_camera"] == hc.identity_of(cams[0])
    assert io.read_rig(path).extra["rms_px"] == pytest.approx(0.3)        # the rest of the rig is kept
    sys2, dev2 = make_sysfs(tmp_path / "boot2",
                            [dict(LEFT, videos=(2, 3), devnum=9), dict(RIGHT, videos=(0, 1), devnum=8)])
    cams2 = hc.list_cameras(sys2, dev2, backend=FakeBackend(usb_devices(dict(LEFT, devnum=9), dict(RIGHT, devnum=8))))
    assert hc.resolve_rig_cameras(io.read_rig(path), cams2) == (f"{dev2}/video2", f"{dev2}/video0")
    with pytest.raises(LookupError, match="video7"):
        hc.store_rig_cameras(path, "7", "0", cams)
