"""What a V4L2 capture device offers: pixel formats, frame sizes and frame rates.

:func:`device_formats` asks the driver with the three enumeration ioctls of
the V4L2 API, the same the ``v4l2-ctl --list-formats-ext`` listing comes
from:

- ``VIDIOC_ENUM_FMT``: the pixel formats (``GREY``, ``YUYV``, ``MJPG``, ...)
  and whether each is compressed (``V4L2_FMT_FLAG_COMPRESSED``);
- ``VIDIOC_ENUM_FRAMESIZES``: per format, its frame sizes, discrete
  (``640x480``) or a stepwise / continuous range;
- ``VIDIOC_ENUM_FRAMEINTERVALS``: per format and size, its frame intervals
  (a fraction of a second), discrete or a range, given here as rates in Hz.

Each ioctl is called with ``index = 0, 1, ...`` until the driver answers
``EINVAL`` (the end of the list). The structs are the kernel's
``<linux/videodev2.h>`` ones, written out with :mod:`ctypes`.

Why hand-written ioctls: no well-kept Python V4L2 binding is among
headplod's dependencies (OpenCV cannot list a device's modes, it only sets
one and reads back what the driver chose), and ``v4l2-ctl`` is often not
installed. Three read-only enumeration calls with fixed, stable structs are
a small surface; nothing here changes the device's state.
"""
from __future__ import annotations

import ctypes
import errno
import fcntl
import os
from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["PixelFormat", "FrameSize", "device_formats", "enumerate_formats", "fourcc_text",
           "VIDIOC_ENUM_FMT", "VIDIOC_ENUM_FRAMESIZES", "VIDIOC_ENUM_FRAMEINTERVALS"]

# ---------------------------------------------------------------------------
# <linux/videodev2.h>
# ---------------------------------------------------------------------------

V4L2_BUF_TYPE_VIDEO_CAPTURE = 1
V4L2_FMT_FLAG_COMPRESSED = 0x0001
V4L2_FRMSIZE_TYPE_DISCRETE = 1
V4L2_FRMSIZE_TYPE_CONTINUOUS = 2
V4L2_FRMSIZE_TYPE_STEPWISE = 3
V4L2_FRMIVAL_TYPE_DISCRETE = 1
V4L2_FRMIVAL_TYPE_CONTINUOUS = 2
V4L2_FRMIVAL_TYPE_STEPWISE = 3

#: Entries read per list at most: a guard against a driver that never answers EINVAL.
MAX_ENTRIES = 256


class v4l2_fmtdesc(ctypes.Structure):
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("description", ctypes.c_char * 32),
        ("pixelformat", ctypes.c_uint32),
        ("mbus_code", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 3),
    ]


class v4l2_frmsize_discrete(ctypes.Structure):
    _fields_ = [("width", ctypes.c_uint32), ("height", ctypes.c_uint32)]


class v4l2_frmsize_stepwise(ctypes.Structure):
    _fields_ = [
        ("min_width", ctypes.c_uint32), ("max_width", ctypes.c_uint32), ("step_width", ctypes.c_uint32),
        ("min_height", ctypes.c_uint32), ("max_height", ctypes.c_uint32), ("step_height", ctypes.c_uint32),
    ]


class _frmsize_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_frmsize_discrete), ("stepwise", v4l2_frmsize_stepwise)]


class v4l2_frmsizeenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("pixel_format", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("u", _frmsize_union),
        ("reserved", ctypes.c_uint32 * 2),
    ]


class v4l2_fract(ctypes.Structure):
    _fields_ = [("numerator", ctypes.c_uint32), ("denominator", ctypes.c_uint32)]


class v4l2_frmival_stepwise(ctypes.Structure):
    _fields_ = [("min", v4l2_fract), ("max", v4l2_fract), ("step", v4l2_fract)]


class _frmival_union(ctypes.Union):
    _fields_ = [("discrete", v4l2_fract), ("stepwise", v4l2_frmival_stepwise)]


class v4l2_frmivalenum(ctypes.Structure):
    _anonymous_ = ("u",)
    _fields_ = [
        ("index", ctypes.c_uint32),
        ("pixel_format", ctypes.c_uint32),
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("type", ctypes.c_uint32),
        ("u", _frmival_union),
        ("reserved", ctypes.c_uint32 * 2),
    ]


def _IOWR(kind: str, nr: int, struct: type) -> int:
    # _IOC(_IOC_READ | _IOC_WRITE, type, nr, size) of <asm-generic/ioctl.h>
    return (3 << 30) | (ctypes.sizeof(struct) << 16) | (ord(kind) << 8) | nr


VIDIOC_ENUM_FMT = _IOWR("V", 2, v4l2_fmtdesc)                     # 0xc0405602
VIDIOC_ENUM_FRAMESIZES = _IOWR("V", 74, v4l2_frmsizeenum)         # 0xc02c564a
VIDIOC_ENUM_FRAMEINTERVALS = _IOWR("V", 75, v4l2_frmivalenum)     # 0xc034564b


# ---------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class FrameSize:
    """One frame size of a pixel format and the rates offered at it.

    Attributes
    ----------
    width, height : int
        px.
    rates : tuple of float
        Frame rates, Hz, highest first. For a stepwise or continuous
        interval range, its two ends (the highest and lowest rate).
    """

    width: int
    height: int
    rates: tuple[float, ...]

    @property
    def max_rate(self) -> float:
        """The highest rate, Hz (0 when the driver listed none)."""
        return max(self.rates, default=0.0)


@dataclass(frozen=True)
class PixelFormat:
    """One pixel format of a capture device.

    Attributes
    ----------
    fourcc : str
        ``GREY``, ``YUYV``, ``MJPG``, ... (trailing spaces stripped).
    description : str
        The driver's name for it (``Motion-JPEG``).
    compressed : bool
        ``V4L2_FMT_FLAG_COMPRESSED``.
    sizes : tuple of FrameSize
        For a stepwise or continuous size range: the range's largest size,
        and each of ``want_sizes`` inside it (see :func:`enumerate_formats`).
    """

    fourcc: str
    description: str
    compressed: bool
    sizes: tuple[FrameSize, ...]

    def rate_at(self, width: int, height: int) -> float:
        """The highest rate at ``width`` x ``height``, Hz; 0 when that size is not offered."""
        return max((s.max_rate for s in self.sizes if (s.width, s.height) == (width, height)), default=0.0)


def fourcc_text(code: int) -> str:
    """The four characters of a V4L2 pixel format code (``0x56595559`` -> ``'YUYV'``)."""
    text = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)).rstrip(" \0")
    return text if text.isprintable() and text else f"0x{code:08x}"


# ---------------------------------------------------------------------------
# enumeration
# ---------------------------------------------------------------------------

Ioctl = Callable[[int, int, Any], Any]


def _each(fd: int, ioctl: Ioctl, request: int, make: Callable[[int], ctypes.Structure]):
    """``make(i)`` filled by the driver for i = 0, 1, ... until EINVAL."""
    for i in range(MAX_ENTRIES):
        s = make(i)
        try:
            ioctl(fd, request, s)
        except OSError as exc:
            if exc.errno == errno.EINVAL:       # the end of the list
                return
            raise
        yield s


def _rate(f: v4l2_fract) -> float | None:
    return f.denominator / f.numerator if f.numerator and f.denominator else None


def _rates(fd: int, ioctl: Ioctl, pixelformat: int, width: int, height: int) -> tuple[float, ...]:
    def make(i):
        return v4l2_frmivalenum(index=i, pixel_format=pixelformat, width=width, height=height)
    rates = []
    for s in _each(fd, ioctl, VIDIOC_ENUM_FRAMEINTERVALS, make):
        if s.type == V4L2_FRMIVAL_TYPE_DISCRETE:
            rates.append(_rate(s.discrete))
        else:                              # a range: its ends (min interval = max rate)
            rates += [_rate(s.stepwise.min), _rate(s.stepwise.max)]
            break
    return tuple(sorted({r for r in rates if r}, reverse=True))


def _in_range(sw: v4l2_frmsize_stepwise, w: int, h: int) -> bool:
    def fits(v, lo, hi, step):
        return lo <= v <= hi and (step <= 1 or (v - lo) % step == 0)
    return fits(w, sw.min_width, sw.max_width, sw.step_width) and \
        fits(h, sw.min_height, sw.max_height, sw.step_height)


def enumerate_formats(fd: int, ioctl: Ioctl = fcntl.ioctl,
                      want_sizes: tuple[tuple[int, int], ...] = ()) -> list[PixelFormat]:
    """The capture formats of an open V4L2 device, with their sizes and rates.

    Parameters
    ----------
    fd : int
        An open file descriptor of the device (``/dev/videoN``).
    ioctl : callable(fd, request, struct)
        ``fcntl.ioctl``; a fake one fills the structs in tests.
    want_sizes : tuple of (width, height)
        Sizes to look up inside a stepwise or continuous size range (a
        discrete list is read whole).

    Returns
    -------
    list of PixelFormat
        In the driver's order; empty for a node that captures no video (a
        UVC metadata node).

    Raises
    ------
    OSError
        If the driver answers an ioctl with an error other than EINVAL
        (ENOTTY: not a V4L2 device).
    """
    formats = []
    for f in _each(fd, ioctl, VIDIOC_ENUM_FMT,
                   lambda i: v4l2_fmtdesc(index=i, type=V4L2_BUF_TYPE_VIDEO_CAPTURE)):
        sizes = []
        for s in _each(fd, ioctl, VIDIOC_ENUM_FRAMESIZES,
                       lambda i: v4l2_frmsizeenum(index=i, pixel_format=f.pixelformat)):
            if s.type == V4L2_FRMSIZE_TYPE_DISCRETE:
                wh = [(s.discrete.width, s.discrete.height)]
            else:
                sw = s.stepwise
                wh = [(sw.max_width, sw.max_height)] + [
                    (w, h) for (w, h) in want_sizes if _in_range(sw, w, h) and (w, h) != (sw.max_width, sw.max_height)]
            for w, h in wh:
                sizes.append(FrameSize(int(w), int(h), _rates(fd, ioctl, f.pixelformat, w, h)))
            if s.type != V4L2_FRMSIZE_TYPE_DISCRETE:
                break
        formats.append(PixelFormat(
            fourcc=fourcc_text(f.pixelformat),
            description=f.description.decode("utf-8", "replace").strip(),
            compressed=bool(f.flags & V4L2_FMT_FLAG_COMPRESSED),
            sizes=tuple(sizes),
        ))
    return formats


def device_formats(device: str, want_sizes: tuple[tuple[int, int], ...] = (),
                   ioctl: Ioctl = fcntl.ioctl) -> list[PixelFormat]:
    """Open ``device`` read/write without blocking, list its formats (:func:`enumerate_formats`), close it.

    Raises
    ------
    OSError
        If the device cannot be opened (EACCES, EBUSY, ENOENT) or an ioctl fails.
    """
    fd = os.open(device, os.O_RDWR | os.O_NONBLOCK)
    try:
        return enumerate_formats(fd, ioctl, want_sizes)
    finally:
        os.close(fd)
