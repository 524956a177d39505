"""Two live V4L2 cameras as one stereo :class:`~headplod.capture.base.FrameSource`.

One capture thread per camera. The threads meet at a rendezvous before
every ``grab()`` so that both cameras are asked for a frame at the same
moment, then ``retrieve()`` (decode) afterwards, as OpenCV recommends for
cameras without hardware synchronisation. Each image gets a monotonic
capture time; :meth:`V4L2StereoSource.read` pairs the nearest left and right
images, measures their skew, flags pairs beyond the skew bound and counts
lost frames. A camera that stops delivering gives error frames and the state
``'stalled'``; one that vanishes gives ``'lost'`` and is reopened every
``reconnect_s`` until it returns. Nothing raises after the source is open.

The device opener is injectable: ``opener(device)`` returns an object with
the methods of ``cv2.VideoCapture`` used here (``isOpened``, ``grab``,
``retrieve``, ``set``, ``get``, ``release``), so a fake camera drops in for
tests.

Times
-----
A capture time is the driver's buffer timestamp when the camera reports a
plausible one (at most ``DEVICE_TIME_WINDOW_S`` before ``grab()`` returned);
otherwise the ``time.monotonic()`` at which ``grab()`` returned. Frame
times ``t`` and ``t_right`` are seconds since the source was opened; the
frame's ``time_source`` says which of the two the left time is
(``'driver'`` or ``'grab'``), and so where the latency is measured from.

The buffer timestamp is OpenCV's ``CAP_PROP_POS_MSEC`` for a V4L2 camera:
the ``timestamp`` of the dequeued ``v4l2_buffer``, on the kernel's
``CLOCK_MONOTONIC`` for UVC cameras (the clock of ``time.monotonic()``), 0
before the first frame. Which instant of the frame it is, the driver
decides and states in the buffer's flags: ``V4L2_BUF_FLAG_TSTAMP_SRC_SOE``
(start of exposure) or ``V4L2_BUF_FLAG_TSTAMP_SRC_EOF`` (end of frame, the
last byte received). OpenCV does not pass the flags on, so headplod does
not know which. Either way it is not the middle of the exposure: SOE is
half an exposure before it, EOF half an exposure plus the read-out and
transfer after it, and the grab time later still (when OpenCV had the
frame). A latency measured from SOE is half an exposure longer than from
mid-exposure; from EOF or the grab time it is shorter.

A zero, repeated or backward capture time is not corrected here: the
tracking loop drops such frames, per camera, for every source
(:mod:`headplod.capture.timestamps`).
"""
from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from .. import io
from .base import GAP_PERIODS, CaptureFrame, FrameSource, SourceOpenError, _size_error, _skew_flag, to_gray
from ..tol import tol

__all__ = ["V4L2StereoSource", "CameraSetting", "default_opener", "DEVICE_TIME_WINDOW_S", "FOURCCS"]

log = logging.getLogger(__name__)

#: A driver timestamp older than this before grab() returned (s) is not
#: believed (another clock, or a stale buffer) and the grab time is used.
DEVICE_TIME_WINDOW_S = 0.5
#: Frame rate assumed for period-based checks when neither the request nor
#: the camera gives one, Hz.
FALLBACK_FPS = 30.0
#: Consecutive failed grabs, on a device still present and open, after which
#: the camera is treated as lost and reopened.
MAX_GRAB_FAILURES = 3
#: Images kept per camera waiting to be paired; older ones are dropped
#: (counted) when the reader is slower than the cameras.
QUEUE_LENGTH = 4

#: Pixel formats a camera may be asked for (``fourcc``, ``headplod track --fourcc``).
FOURCCS = ("GREY", "YUYV", "MJPG")


def default_opener(device: int | str) -> Any:
    """``cv2.VideoCapture(device, cv2.CAP_V4L2)`` (a device path as :func:`headplod.io.opencv_name` gives it)."""
    return cv2.VideoCapture(io.opencv_name(device, "camera device") if isinstance(device, str) else device,
                            cv2.CAP_V4L2)


def _device_exists(device: int | str) -> bool:
    """Whether a device node is present (``/dev/videoN`` paths; integers are assumed present)."""
    if isinstance(device, int):
        return os.path.exists(f"/dev/video{device}")
    return os.path.exists(device) if str(device).startswith("/dev/") else True


def _fourcc_int(code: str) -> int:
    return int(cv2.VideoWriter_fourcc(*code))


def _fourcc_str(value: float) -> str:
    v = int(value) if math.isfinite(value) and value > 0 else 0
    text = "".join(chr((v >> (8 * i)) & 0xFF) for i in range(4))
    return text if v and text.isprintable() else f"{value:g}"


@dataclass
class CameraSetting:
    """One requested camera setting and what the camera reports back.

    Attributes
    ----------
    name : str
        ``fourcc``, ``width`` (px), ``height`` (px), ``fps`` (Hz),
        ``auto_exposure`` (V4L2 menu value: 1 manual, 3 aperture priority),
        ``exposure`` (camera units, usually 100 µs for UVC), ``gain``
        (camera units), ``buffer_size`` (frames).
    requested : float or str
    set_ok : bool
        What ``set`` returned.
    actual : float or str or None
        What ``get`` reads back (``None`` when ``get`` failed; V4L2 gives -1
        for an unsupported control).
    accepted : bool
        ``actual`` equals ``requested`` within the setting's tolerance.
    """

    name: str
    requested: float | str
    set_ok: bool
    actual: float | str | None
    accepted: bool

    def describe(self, camera: str) -> str:
        how = "set() refused it" if not self.set_ok else "set() accepted it"
        return (f"{camera}: {self.name} requested {self.requested}, camera reports "
                f"{self.actual if self.actual is not None else 'nothing'} ({how})")


_PROPS = {
    "fourcc": cv2.CAP_PROP_FOURCC,
    "width": cv2.CAP_PROP_FRAME_WIDTH,
    "height": cv2.CAP_PROP_FRAME_HEIGHT,
    "fps": cv2.CAP_PROP_FPS,
    "buffer_size": cv2.CAP_PROP_BUFFERSIZE,
    "auto_exposure": cv2.CAP_PROP_AUTO_EXPOSURE,
    "exposure": cv2.CAP_PROP_EXPOSURE,
    "gain": cv2.CAP_PROP_GAIN,
}


def _accepted(name: str, requested: Any, actual: Any) -> bool:
    if actual is None:
        return False
    if name == "fourcc":
        return actual == requested
    if name == "fps":                     # drivers round frame intervals
        return abs(actual - requested) <= 0.01 * requested
    return abs(actual - requested) <= tol.text * max(1.0, abs(requested))


def _apply_settings(cap: Any, requested: dict[str, Any]) -> list[CameraSetting]:
    """Set each requested property in order, then read every one back."""
    set_ok = {}
    for name, value in requested.items():
        raw = _fourcc_int(value) if name == "fourcc" else float(value)
        try:
            set_ok[name] = bool(cap.set(_PROPS[name], raw))
        except Exception:            # a driver error is a refused setting
            set_ok[name] = False
    report = []
    for name, value in requested.items():
        try:
            got = float(cap.get(_PROPS[name]))
            actual: Any = _fourcc_str(got) if name == "fourcc" else got
        except Exception:
            actual = None
        report.append(CameraSetting(name, value, set_ok[name], actual, _accepted(name, value, actual)))
    return report


class _Rendezvous:
    """Lets the active camera threads call grab() together.

    ``wait(side, timeout_s)`` returns the round number when every active side
    has arrived (the cameras grab together; their images of one round form a
    pair), or ``None`` after ``timeout_s`` (the other camera is late: grab
    alone, an image that cannot be paired). A lost camera is made inactive
    so the other one never waits for it.
    """

    def __init__(self, sides: tuple[str, ...]):
        self._cond = threading.Condition()
        self._active = set(sides)
        self._arrived: set[str] = set()
        self._generation = 0
        self._stopped = False

    def _release_if_complete(self) -> bool:
        if self._arrived and self._arrived >= self._active:
            self._generation += 1
            self._arrived.clear()
            self._cond.notify_all()
            return True
        return False

    def wait(self, side: str, timeout_s: float) -> int | None:
        """Wait for the other active cameras; the round number, or None (grab alone)."""
        with self._cond:
            if self._stopped:
                return None
            self._arrived.add(side)
            generation = self._generation
            if self._release_if_complete():
                return generation
            self._cond.wait_for(lambda: self._generation != generation or self._stopped, timeout_s)
            if self._generation == generation:
                self._arrived.discard(side)
                return None
            return None if self._stopped else generation

    def set_active(self, side: str, active: bool) -> None:
        with self._cond:
            if active:
                self._active.add(side)
            else:
                self._active.discard(side)
                self._arrived.discard(side)
                self._release_if_complete()

    def stop(self) -> None:
        with self._cond:
            self._stopped = True
            self._cond.notify_all()


@dataclass
class _Shot:
    """One image from one camera."""

    t_mono: float          # capture time, s, monotonic clock
    clock: str             # what t_mono is: 'driver' (buffer timestamp) or 'grab' (grab() returned)
    image: np.ndarray      # (H, W) uint8
    dropped: int           # frames this camera lost just before this one
    round: int | None      # rendezvous round (None: grabbed alone, unpairable)


class _Camera:
    """One camera, its capture thread and its queue of images to pair."""

    def __init__(self, side: str, device: int | str, source: "V4L2StereoSource"):
        self.side = side
        self.device = device
        self.label = f"{side} camera {device}"
        self.src = source
        self.cap: Any = None
        self.state = "closed"              # 'running' | 'lost' | 'closed'
        self.reason: str | None = None     # why lost
        self.queue: deque[_Shot] = deque()
        self.failed_grabs = 0              # failed grabs since the last image
        self.carry_dropped = 0             # unpaired images not yet reported (source lock)
        self.last_frame_mono = time.monotonic()
        self.next_try = 0.0
        self.settings: list[CameraSetting] = []
        self.thread: threading.Thread | None = None
        self._prev_t: float | None = None
        self._failures = 0
        #: Held around the device's grab/retrieve and a control's change: a VideoCapture is not thread-safe.
        self.device_lock = threading.Lock()

    # -- open / close (camera thread, or the constructor before threads start) --

    def open(self) -> str | None:
        """Open and configure the device; None on success, else why not."""
        if not self.src._device_exists(self.device):
            return "device not present"
        try:
            cap = self.src._opener(self.device)
        except Exception as exc:
            return f"cannot be opened ({type(exc).__name__}: {exc})"
        try:
            opened = bool(cap.isOpened())
        except Exception:
            opened = False
        if not opened:
            self._release(cap)
            return "cannot be opened (busy, no permission, or not a capture device)"
        self.settings = _apply_settings(cap, self.src._requested)
        for s in self.settings:
            if not s.accepted:
                self.src._warn(s.describe(self.label))
        self.cap = cap
        self.state = "running"
        self.reason = None
        self._prev_t = None
        self._failures = 0
        self.last_frame_mono = time.monotonic()
        return None

    @staticmethod
    def _release(cap: Any) -> None:
        try:
            cap.release()
        except Exception:
            pass

    def _lose(self, reason: str) -> None:
        if self.cap is not None:
            self._release(self.cap)
        self.cap = None
        self.state = "lost"
        self.reason = reason
        self.next_try = time.monotonic() + self.src.reconnect_s
        self.src._sync.set_active(self.side, False)
        self.src._stats.note_error(f"{self.label}: lost ({reason})")
        log.warning("%s: lost (%s); retrying every %.1f s", self.label, reason, self.src.reconnect_s)

    # -- the capture thread --------------------------------------------------

    def run(self) -> None:
        stop = self.src._stop
        while not stop.is_set():
            try:
                if self.cap is None:
                    self._reconnect()
                else:
                    self._capture_once()
            except Exception as exc:       # never let a driver error kill the thread
                self._lose(f"{type(exc).__name__}: {exc}")
        if self.cap is not None:
            self._release(self.cap)
            self.cap = None
        self.state = "closed"

    def _reconnect(self) -> None:
        """Try to reopen a lost camera every ``reconnect_s``."""
        now = time.monotonic()
        if now < self.next_try:
            self.src._stop.wait(min(self.next_try - now, 0.05))
            return
        why = self.open()
        if why is None:
            self.src._stats.note_reconnect()
            self.src._sync.set_active(self.side, True)
            log.warning("%s: reconnected", self.label)
        else:
            self.reason = why
            self.next_try = time.monotonic() + self.src.reconnect_s

    def _capture_once(self) -> None:
        src = self.src
        round_ = src._sync.wait(self.side, src._sync_timeout_s)
        if src._stop.is_set():
            return
        with self.device_lock:
            ok = bool(self.cap.grab())
            t_grab = time.monotonic()
            if ok:
                t_mono, clock = self._capture_time(t_grab)
                ok_image, image = self.cap.retrieve()
        if not ok:
            self._failures += 1
            still_open = bool(self.cap.isOpened())
            if not still_open or not src._device_exists(self.device):
                self._lose("device gone" if still_open else "grab failed and the device closed")
            elif self._failures >= MAX_GRAB_FAILURES:
                self._lose(f"{self._failures} grabs failed in a row")
            else:
                self.failed_grabs += 1
            return
        self._failures = 0
        ok = ok_image
        try:
            gray = to_gray(image) if ok and image is not None else None
        except ValueError as exc:
            src._stats.note_error(f"{self.label}: {exc}")
            gray = None
        if gray is None:
            self.failed_grabs += 1
            return
        # frames lost since the previous image: the time gap, or at least the failed grabs
        gap_lost = 0
        if self._prev_t is not None:
            gap = t_mono - self._prev_t
            if gap > GAP_PERIODS * src.period_s:
                gap_lost = int(round(gap / src.period_s)) - 1
        dropped = max(gap_lost, self.failed_grabs)
        self._prev_t = t_mono
        self.failed_grabs = 0
        with src._lock:
            if len(self.queue) >= src.queue_length:      # reader too slow
                old = self.queue.popleft()
                dropped += old.dropped + 1
            self.queue.append(_Shot(t_mono, clock, gray, dropped, round_))
            self.last_frame_mono = t_grab
            src._lock.notify_all()

    def _capture_time(self, t_grab: float) -> tuple[float, str]:
        """(time s, monotonic; ``'driver'`` or ``'grab'``): the driver's timestamp when plausible, else the grab time."""
        if not self.src.device_timestamps:
            return t_grab, "grab"
        try:
            ms = float(self.cap.get(cv2.CAP_PROP_POS_MSEC))
        except Exception:
            return t_grab, "grab"
        t_dev = ms / 1000.0
        if math.isfinite(t_dev) and 0.0 <= t_grab - t_dev <= DEVICE_TIME_WINDOW_S:
            return t_dev, "driver"
        return t_grab, "grab"


class V4L2StereoSource(FrameSource):
    """Two V4L2 cameras (left, right) as a live stereo source.

    Parameters
    ----------
    left, right : int or str
        Devices: an index (``0``) or a node (``'/dev/video0'``).
    width, height : int, optional
        Requested image size, px.
    fps : float, optional
        Requested frame rate, Hz. Also sets the frame period used for the
        skew bound and the dropped-frame count (else the camera's reported
        rate, else 30 Hz).
    fourcc : {'GREY', 'YUYV', 'MJPG'}, optional
        Requested pixel format; colour or YUYV images are converted to gray.
    manual_exposure : bool, optional
        Turn auto exposure off (V4L2 ``CAP_PROP_AUTO_EXPOSURE`` = 1, manual)
        or on (3, aperture priority). Default: off when ``exposure`` is
        given, untouched otherwise. IR marker tracking wants it off: auto
        exposure brightens the background between markers.
    exposure : float, optional
        Exposure in the camera's units (UVC: 100 µs).
    gain : float, optional
        Gain in the camera's units.
    buffer_size : int, optional
        Driver buffers (``CAP_PROP_BUFFERSIZE``); 1-2 keeps latency low.
    skew_bound_ms : float, optional
        Pairs whose capture times differ by more are flagged, ms. Default
        half a frame period.
    reconnect_s : float
        How often a lost camera is reopened, s.
    rig : io.Rig or str or Path, optional
        Calibration of this pair (or the path of its ``rig.yaml``); images of
        another size then give error frames.
    markers : io.MarkerModel, optional
    screen : io.Screen, optional
    opener : callable(device) -> VideoCapture-like, optional
        Opens a device (default ``cv2.VideoCapture(device, cv2.CAP_V4L2)``).
    device_exists : callable(device) -> bool, optional
        Whether the device is present (default: its ``/dev`` node exists).
        Checked before each (re)open and after a failed grab.
    device_timestamps : bool
        Use the driver's buffer timestamps when plausible (see module notes).
    queue_length : int
        Images kept per camera for pairing.

    Raises
    ------
    SourceOpenError
        When a camera cannot be opened at construction (names the camera).
    ValueError
        For an unknown ``fourcc`` or a non-positive number.

    Notes
    -----
    :meth:`read` waits up to ``timeout_s`` for a pair. Without one it returns
    an error frame saying which camera is late, e.g.
    ``"right camera /dev/video2: no frame for 1.0 s (stalled)"`` or
    ``"left camera 0: lost (device gone); reconnecting every 1.0 s"``, so a
    reader loop keeps its pace and never blocks for long. ``dropped`` of a
    pair is the larger of the two cameras' lost-frame counts since the
    previous pair (a frame lost on both cameras at once is one pair); a
    camera's lost frames are the gap between its capture times in frame
    periods (gaps above ``GAP_PERIODS``), or its failed grabs when more.
    Images of one rendezvous round form a pair; a pair more than
    ``pair_limit_s`` (a frame period, or twice the skew bound when larger)
    apart is discarded as not the same instant, one within it but beyond
    the skew bound is returned with a flag.
    """

    kind = "v4l2"
    realtime = True          # cameras deliver at their own pace: read by a capture thread (capture.mailbox)

    def __init__(self, left: int | str, right: int | str, *, width: int | None = None,
                 height: int | None = None, fps: float | None = None, fourcc: str | None = None,
                 manual_exposure: bool | None = None, exposure: float | None = None,
                 gain: float | None = None, buffer_size: int | None = None,
                 skew_bound_ms: float | None = None, reconnect_s: float = 1.0,
                 rig: Any = None, markers: io.MarkerModel | None = None, screen: io.Screen | None = None,
                 opener: Callable[[Any], Any] | None = None,
                 device_exists: Callable[[Any], bool] | None = None,
                 device_timestamps: bool = True, queue_length: int = QUEUE_LENGTH):
        if isinstance(rig, (str, os.PathLike)):
            rig = io.read_rig(Path(rig))
        for device in (left, right):            # a name OpenCV cannot take: refused before any camera opens
            if isinstance(device, str):
                io.opencv_name(device, "camera device")
        super().__init__(f"v4l2:{left},{right}", rig, markers, screen)
        self._requested = self._requests(width, height, fps, fourcc, manual_exposure, exposure,
                                         gain, buffer_size)
        for name, value in (("reconnect_s", reconnect_s), ("queue_length", queue_length)):
            if not value > 0:
                raise ValueError(f"{name} is {value!r}, expected a positive number")
        self.reconnect_s = float(reconnect_s)
        self.queue_length = int(queue_length)
        self.device_timestamps = bool(device_timestamps)
        self._opener = opener or default_opener
        self._device_exists = device_exists or _device_exists
        self._lock = threading.Condition()
        self._stop = threading.Event()
        self._sync = _Rendezvous(("left", "right"))
        self._cameras = (_Camera("left", left, self), _Camera("right", right, self))
        for cam in self._cameras:
            why = cam.open()
            if why is not None:
                self._release_all()
                hint = " (is it plugged in? `v4l2-ctl --list-devices` lists the cameras)"
                raise SourceOpenError(f"{cam.label}: {why}{hint}")
        self.period_s = 1.0 / self._frame_rate(fps)
        self.skew_bound_ms = 500.0 * self.period_s if skew_bound_ms is None else float(skew_bound_ms)
        #: Images of one round further apart than this are not a pair, s.
        self.pair_limit_s = max(self.period_s, 2e-3 * self.skew_bound_ms)
        self._sync_timeout_s = max(2.0 * self.period_s, 0.05)
        self._stall_s = 1.0
        self._index = 0
        self._t0 = time.monotonic()
        for cam in self._cameras:
            cam.thread = threading.Thread(target=cam.run, name=f"headplod-capture-{cam.side}",
                                          daemon=True)
            cam.thread.start()

    @property
    def devices(self) -> tuple[int | str, int | str]:
        """The (left, right) devices as opened (``/dev/videoN`` or an index)."""
        return self._cameras[0].device, self._cameras[1].device

    # -- construction helpers ------------------------------------------------

    @staticmethod
    def _requests(width, height, fps, fourcc, manual_exposure, exposure, gain, buffer_size) -> dict:
        req: dict[str, Any] = {}
        if fourcc is not None:
            code = str(fourcc).upper()
            if code not in FOURCCS:
                raise ValueError(f"fourcc is {fourcc!r}, expected one of {', '.join(FOURCCS)}")
            req["fourcc"] = code
        for name, value in (("width", width), ("height", height), ("fps", fps),
                            ("buffer_size", buffer_size)):
            if value is not None:
                if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                    raise ValueError(f"{name} is {value!r}, expected a positive number")
                req[name] = int(value) if name != "fps" else float(value)
        if manual_exposure is None and exposure is not None:
            manual_exposure = True
        if manual_exposure is not None:
            req["auto_exposure"] = 1 if manual_exposure else 3
        if exposure is not None:
            req["exposure"] = float(exposure)
        if gain is not None:
            req["gain"] = float(gain)
        return req

    def _frame_rate(self, fps: float | None) -> float:
        if fps is not None:
            return float(fps)
        for s in self._cameras[0].settings:
            if s.name == "fps" and isinstance(s.actual, float) and s.actual > 0:
                return s.actual
        try:
            got = float(self._cameras[0].cap.get(cv2.CAP_PROP_FPS))
        except Exception:
            got = 0.0
        return got if math.isfinite(got) and got > 0 else FALLBACK_FPS

    def _warn(self, message: str) -> None:
        with self._lock:
            if message not in self.warnings:
                self.warnings.append(message)
        log.warning("%s", message)

    def _release_all(self) -> None:
        for cam in self._cameras:
            if cam.cap is not None:
                cam._release(cam.cap)
                cam.cap = None

    # -- public --------------------------------------------------------------

    def settings_report(self, text: bool = False) -> dict | str:
        """Requested against actual settings of both cameras.

        Parameters
        ----------
        text : bool
            Return a printable table instead of a dict.

        Returns
        -------
        dict or str
            ``{'left': {name: {'requested', 'actual', 'set_ok', 'accepted'}},
            'right': {...}}`` (from the latest (re)open), or the same as
            lines ``"left  fps  requested 60  actual 30  NOT ACCEPTED"``.
        """
        report = {cam.side: {s.name: {"requested": s.requested, "actual": s.actual,
                                      "set_ok": s.set_ok, "accepted": s.accepted}
                             for s in cam.settings}
                  for cam in self._cameras}
        if not text:
            return report
        lines = []
        for cam in self._cameras:
            if not cam.settings:
                lines.append(f"{cam.label}: no settings requested")
            for s in cam.settings:
                verdict = "ok" if s.accepted else ("REFUSED" if not s.set_ok else "NOT ACCEPTED")
                lines.append(f"{cam.label}: {s.name:<13} requested {s.requested!s:<8} "
                             f"actual {s.actual!s:<8} {verdict}")
        return "\n".join(lines)

    def control(self, name: str) -> float | None:
        """The left camera's current value of a control (``exposure``, ``gain``, ... as :class:`CameraSetting`
        names them), in the camera's units; None when the camera is not open or reports none (V4L2 gives -1 for
        an unsupported control)."""
        cam = self._cameras[0]
        with cam.device_lock:
            if cam.cap is None:
                return None
            try:
                value = float(cam.cap.get(_PROPS[name]))
            except Exception:           # a driver error is no value
                return None
        return value if math.isfinite(value) and value >= 0 else None

    def set_controls(self, exposure: float | None = None, gain: float | None = None) -> dict[str, list[CameraSetting]]:
        """Change the exposure and gain of both cameras while they run (what ``headplod preview``'s keys do).

        Parameters
        ----------
        exposure : float, optional
            In the camera's units (UVC: 100 µs); turns auto exposure off.
        gain : float, optional
            In the camera's units.

        Returns
        -------
        dict
            ``{'left': [CameraSetting, ...], 'right': [...]}``, what each camera reported back (a camera that is
            lost reports nothing; it gets the values when it is reopened, as they are kept with the others).
        """
        req = self._requests(None, None, None, None, None, exposure, gain, None)
        with self._lock:
            self._requested = {**self._requested, **req}
        report = {}
        for cam in self._cameras:
            with cam.device_lock:
                report[cam.side] = _apply_settings(cam.cap, req) if cam.cap is not None else []
            for s in report[cam.side]:
                if not s.accepted:
                    self._warn(s.describe(cam.label))
        return report

    def read(self, timeout_s: float = 1.0) -> CaptureFrame | None:
        """The next stereo pair, or an error frame after ``timeout_s`` s without one.

        Returns ``None`` only once the source is closed.
        """
        if self._closed:
            return None
        self._stall_s = float(timeout_s)
        deadline = time.monotonic() + timeout_s
        with self._lock:
            while True:
                if self._closed:
                    return None
                pair = self._pair()
                if pair is not None:
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return self._emit(self._error_frame())
                self._lock.wait(min(remaining, 0.05))
        return self._emit(self._frame(*pair))

    def _pair(self) -> tuple[_Shot, _Shot, int] | None:
        """Pop the next left/right pair of one rendezvous round (lock held).

        Images that cannot be paired (grabbed alone, their round's partner
        lost, or more than ``pair_limit_s`` apart) are discarded and counted
        as dropped on the next pair.
        """
        left, right = self._cameras
        qa, qb = left.queue, right.queue

        def discard(cam: _Camera) -> None:
            shot = cam.queue.popleft()
            cam.carry_dropped += shot.dropped + 1

        while qa or qb:
            for cam in (left, right):              # grabbed alone: never pairable
                while cam.queue and cam.queue[0].round is None:
                    discard(cam)
            if not (qa and qb):
                return None
            a, b = qa[0], qb[0]
            if a.round != b.round:                 # the older round lost its partner
                discard(left if a.round < b.round else right)
                continue
            if abs(a.t_mono - b.t_mono) > self.pair_limit_s:
                discard(left)
                discard(right)
                continue
            qa.popleft()
            qb.popleft()
            dropped = max(a.dropped + left.carry_dropped, b.dropped + right.carry_dropped)
            left.carry_dropped = right.carry_dropped = 0
            return a, b, dropped
        return None

    def _frame(self, a: _Shot, b: _Shot, dropped: int) -> CaptureFrame:
        index = self._index
        self._index += 1
        skew_ms = abs(a.t_mono - b.t_mono) * 1000.0
        errors = [e for e in (_size_error(f"{self._cameras[0].label}", a.image, self.rig),
                              _size_error(f"{self._cameras[1].label}", b.image, self.rig)) if e]
        ok = not errors
        return CaptureFrame(
            index=index, t=a.t_mono - self._t0, t_right=b.t_mono - self._t0,
            left=a.image if ok else None, right=b.image if ok else None,
            error="; ".join(errors) or None, t_monotonic_left=a.t_mono, t_monotonic_right=b.t_mono,
            skew_ms=skew_ms, dropped=dropped, flags=_skew_flag(skew_ms, self.skew_bound_ms),
            time_source=a.clock)

    def _error_frame(self) -> CaptureFrame:
        now = time.monotonic()
        reasons = []
        for cam in self._cameras:
            if cam.state == "lost" or cam.cap is None:
                reasons.append(f"{cam.label}: lost ({cam.reason}); reconnecting every {self.reconnect_s:g} s")
            elif now - cam.last_frame_mono >= self._stall_s and not cam.queue:
                reasons.append(f"{cam.label}: no frame for {now - cam.last_frame_mono:.1f} s (stalled)")
        if not reasons:
            qa, qb = self._cameras[0].queue, self._cameras[1].queue
            if qa and qb:
                gap = abs(qa[-1].t_mono - qb[-1].t_mono) * 1000.0
                reasons.append(f"no left/right pair within {self._stall_s:g} s: latest images "
                               f"{gap:.0f} ms apart")
            else:
                reasons.append(f"no left/right pair within {self._stall_s:g} s")
        index = self._index
        self._index += 1
        return CaptureFrame(index=index, t=now - self._t0, t_right=None, left=None, right=None,
                            error="; ".join(reasons))

    def _state(self) -> str:
        if self._closed:
            return "ended"
        now = time.monotonic()
        if any(cam.state == "lost" or cam.cap is None for cam in self._cameras):
            return "lost"
        if any(now - cam.last_frame_mono >= self._stall_s for cam in self._cameras):
            return "stalled"
        return "running"

    def close(self, timeout_s: float = 0.5) -> None:
        """Stop the capture threads and release the cameras; returns within ~``timeout_s``.

        A thread blocked inside a driver call (a stalled camera) cannot be
        interrupted: it is a daemon thread, releases its camera when the call
        returns, and is not waited for beyond ``timeout_s``.
        """
        if self._closed:
            return
        self._stop.set()
        self._sync.stop()
        with self._lock:
            self._closed = True
            self._lock.notify_all()
        deadline = time.monotonic() + timeout_s
        for cam in self._cameras:
            if cam.thread is not None:
                cam.thread.join(max(0.0, deadline - time.monotonic()))
