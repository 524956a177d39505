"""The capture interface: :class:`FrameSource`, the frame it returns and its status.

Every source (:mod:`.sources` for replay, :mod:`.v4l2` for live cameras)
subclasses :class:`FrameSource`, and the recorder (:mod:`.record`) reads from
one; this module depends on nothing else in ``capture/``, so that they all
sit on top of it. The conventions (images, times, skew, per-frame errors as
values) are those of :mod:`headplod.capture.sources`.
"""
from __future__ import annotations

import abc
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterator

import cv2
import numpy as np

from .. import io

__all__ = [
    "CaptureFrame",
    "SourceStatus",
    "SourceOpenError",
    "FrameSource",
    "to_gray",
    "SOURCE_STATES",
]

#: The states :meth:`FrameSource.status` reports.
SOURCE_STATES = ("running", "stalled", "lost", "ended")
#: Number of recent frames over which fps and skew percentiles are measured.
STATS_WINDOW = 300
#: A gap between consecutive frame times above this many frame periods means
#: frames were lost (1.5: halfway between one period and two).
GAP_PERIODS = 1.5


class SourceOpenError(OSError):
    """A source (file, camera) named by a valid spec cannot be opened.

    The message names the file or device first and says what is wrong.
    """


# --------------------------------------------------------------------------
# frames and status
# --------------------------------------------------------------------------


@dataclass
class CaptureFrame(io.Frame):
    """A stereo frame with capture diagnostics; an :class:`io.Frame` subclass.

    Attributes
    ----------
    index, t, t_right, left, right, error, warning
        As in :class:`headplod.io.Frame`: ``left`` and ``right`` are 8-bit
        gray images, shape (height, width), px, both ``None`` when ``error``
        is set; ``t`` and ``t_right`` in s.
    t_monotonic_left, t_monotonic_right : float or None
        ``time.monotonic()`` (s) when each image was captured by a live
        camera; ``None`` for replay.
    skew_ms : float or None
        ``|left - right|`` capture-time difference, ms; ``None`` when unknown
        (error frames). Replay of a recording without ``t_right`` gives 0.0:
        the contract says the two images of a frame are the same instant.
    dropped : int
        Stereo pairs lost between the previous frame this source returned and
        this one (timestamp gaps, grab failures, unpaired images).
    flags : list of str
        Notes on a frame that is still usable, e.g.
        ``"skew 21.3 ms > 16.7 ms bound"``.
    time_source : str or None
        What ``t_monotonic_left`` is, for a live camera: ``'driver'`` (the
        V4L2 buffer timestamp: start of exposure or end of frame, as the
        driver decides) or ``'grab'`` (when ``grab()`` returned); ``None``
        for replay. Latencies are measured from it.
    paced_s : float
        Seconds a ``realtime`` replay held the frame back to keep the
        recording's pace (0 otherwise): waiting, not latency, so a replay's
        latency leaves it out.
    dropped_busy : int
        Pairs captured after the previous frame the tracker took and dropped
        before this one, because the tracker was busy (the drop-oldest
        mailbox, :mod:`headplod.capture.mailbox`; live cameras and real-time
        replay only); not counted in ``dropped``, which is the source's own.
    t_delivered : float or None
        ``time.monotonic()`` (s) when the capture thread handed a frame
        without a capture time (replay) to the tracker's mailbox; ``None``
        otherwise. A real-time replay's latency runs from it.
    """

    t_monotonic_left: float | None = None
    t_monotonic_right: float | None = None
    skew_ms: float | None = None
    dropped: int = 0
    flags: list[str] = field(default_factory=list)
    time_source: str | None = None
    paced_s: float = 0.0
    dropped_busy: int = 0
    t_delivered: float | None = None

    @classmethod
    def from_frame(cls, frame: io.Frame, **diagnostics: Any) -> "CaptureFrame":
        """A CaptureFrame with the fields of ``frame`` and the given diagnostics."""
        return cls(index=frame.index, t=frame.t, t_right=frame.t_right, left=frame.left,
                   right=frame.right, error=frame.error, warning=frame.warning, **diagnostics)


@dataclass
class SourceStatus:
    """Health of a source, from :meth:`FrameSource.status`.

    Attributes
    ----------
    state : str
        ``'running'``; ``'stalled'`` (a camera delivered nothing for the last
        read's timeout); ``'lost'`` (a camera vanished, reconnecting);
        ``'ended'`` (replay finished or source closed).
    frames : int
        Good frames (no ``error``) returned so far.
    errors : int
        Error frames returned so far.
    dropped : int
        Stereo pairs lost so far (sum of the frames' ``dropped``).
    fps : float or None
        Frame rate over the last ``STATS_WINDOW`` good frames, Hz, from their
        times (the monotonic clock for live cameras, the recorded ``t`` for
        replay); ``None`` before two frames.
    skew_ms_median, skew_ms_p95 : float or None
        Median and 95th percentile of the pairs' skew over the same window,
        ms; ``None`` before any frame with a known skew.
    last_error : str or None
        The most recent ``error`` of a frame (or of the source).
    reconnects : int
        Times a lost camera was opened again.
    """

    state: str
    frames: int = 0
    errors: int = 0
    dropped: int = 0
    fps: float | None = None
    skew_ms_median: float | None = None
    skew_ms_p95: float | None = None
    last_error: str | None = None
    reconnects: int = 0

    def __str__(self) -> str:
        def num(v: float | None, fmt: str) -> str:
            return "-" if v is None else format(v, fmt)
        return (f"{self.state}: {self.frames} frames, {self.errors} errors, {self.dropped} dropped, "
                f"{num(self.fps, '.1f')} fps, skew median {num(self.skew_ms_median, '.1f')} ms "
                f"p95 {num(self.skew_ms_p95, '.1f')} ms, {self.reconnects} reconnects"
                + (f"; last error: {self.last_error}" if self.last_error else ""))


class _Stats:
    """Counters and recent times/skews behind :class:`SourceStatus` (thread-safe)."""

    def __init__(self, window: int = STATS_WINDOW):
        self._lock = threading.Lock()
        self.frames = 0
        self.errors = 0
        self.dropped = 0
        self.reconnects = 0
        self.last_error: str | None = None
        self._times = deque(maxlen=window)
        self._skews = deque(maxlen=window)

    def note(self, frame: CaptureFrame) -> None:
        with self._lock:
            self.dropped += int(frame.dropped)
            if frame.error is not None:
                self.errors += 1
                self.last_error = frame.error
                return
            self.frames += 1
            clock = frame.t_monotonic_left if frame.t_monotonic_left is not None else frame.t
            self._times.append(float(clock))
            if frame.skew_ms is not None:
                self._skews.append(float(frame.skew_ms))

    def note_reconnect(self) -> None:
        with self._lock:
            self.reconnects += 1

    def note_error(self, message: str) -> None:
        with self._lock:
            self.last_error = message

    def status(self, state: str) -> SourceStatus:
        with self._lock:
            fps = None
            if len(self._times) >= 2:
                span = self._times[-1] - self._times[0]
                fps = (len(self._times) - 1) / span if span > 0 else None
            med = p95 = None
            if self._skews:
                med, p95 = (float(v) for v in np.percentile(np.fromiter(self._skews, float), [50, 95]))
            return SourceStatus(state=state, frames=self.frames, errors=self.errors,
                                dropped=self.dropped, fps=fps, skew_ms_median=med, skew_ms_p95=p95,
                                last_error=self.last_error, reconnects=self.reconnects)


# --------------------------------------------------------------------------
# images
# --------------------------------------------------------------------------


def to_gray(image: np.ndarray) -> np.ndarray:
    """An image from a camera or a video as 8-bit gray, shape (height, width).

    Parameters
    ----------
    image : ndarray
        (H, W) or (H, W, 1) gray; (H, W, 2) packed YUYV (what OpenCV returns
        for a YUYV camera with RGB conversion off); (H, W, 3) BGR; (H, W, 4)
        BGRA. uint8, or uint16 (kept: the 8 most significant bits).

    Returns
    -------
    ndarray, uint8, shape (H, W)
        C-contiguous.

    Raises
    ------
    ValueError
        For another shape or dtype.
    """
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise ValueError(f"image of dtype {img.dtype}, expected uint8 or uint16")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] in (2, 3, 4):
        code = {2: cv2.COLOR_YUV2GRAY_YUY2, 3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}[img.shape[2]]
        return cv2.cvtColor(np.ascontiguousarray(img), code)
    raise ValueError(f"image of shape {img.shape}, expected (H, W) gray or (H, W, 2|3|4) colour")


def _size_error(what: str, image: np.ndarray, rig: io.Rig | None) -> str | None:
    """'WHAT: WxH, rig says W'xH'' when the image does not match the rig."""
    if rig is None:
        return None
    h, w = image.shape[:2]
    rw, rh = rig.image_size
    return None if (w, h) == (rw, rh) else f"{what}: {w}x{h}, rig says {rw}x{rh}"


def _skew_flag(skew_ms: float | None, bound_ms: float | None) -> list[str]:
    if skew_ms is None or bound_ms is None or not skew_ms > bound_ms:
        return []
    return [f"skew {skew_ms:.1f} ms > {bound_ms:.1f} ms bound"]


# --------------------------------------------------------------------------
# the interface
# --------------------------------------------------------------------------


class FrameSource(abc.ABC):
    """A source of stereo frames: the one interface the tracker reads from.

    Attributes
    ----------
    name : str
        What the source reads, for messages (a folder, files, devices).
    rig : io.Rig or None
        The calibrated rig, ``None`` when the source has none (an
        uncalibrated camera pair).
    markers : io.MarkerModel or None
        The marker model that comes with the source, if any.
    screen : io.Screen or None
        The screen that comes with the source, if any.
    warnings : list of str
        Problems that did not stop the source (refused camera settings,
        videos of different lengths, dataset warnings).

    Notes
    -----
    :meth:`read` never raises for a per-frame problem; it returns a
    :class:`CaptureFrame` with ``error`` set and both images ``None``.
    ``for frame in source`` reads until the source ends. A source is a
    context manager that closes itself.
    """

    #: Short name of the kind of source (registry key).
    kind: ClassVar[str] = "source"
    #: Whether frames come at the pace of a clock whatever the reader does (live cameras, a real-time
    #: replay): such a source is read by a capture thread into a drop-oldest mailbox, so the tracker takes
    #: the newest frame (:mod:`headplod.capture.mailbox`); others are read frame by frame, none dropped.
    realtime: bool = False

    def __init__(self, name: str, rig: io.Rig | None = None, markers: io.MarkerModel | None = None,
                 screen: io.Screen | None = None):
        self.name = name
        self.rig = rig
        self.markers = markers
        self.screen = screen
        self.warnings: list[str] = []
        self._stats = _Stats()
        self._closed = False

    @abc.abstractmethod
    def read(self, timeout_s: float = 1.0) -> CaptureFrame | None:
        """The next stereo frame, or ``None`` once the source has ended.

        Parameters
        ----------
        timeout_s : float
            Live sources: how long to wait for a pair, s, before returning an
            error frame that says which camera is late. Replay ignores it.

        Returns
        -------
        CaptureFrame or None
        """

    def status(self) -> SourceStatus:
        """Counters, measured rate and skew, and the state of the source."""
        return self._stats.status(self._state())

    def _state(self) -> str:
        return "ended" if self._closed else "running"

    def close(self) -> None:
        """Release files or cameras; idempotent. ``read`` then returns ``None``."""
        self._closed = True

    @property
    def closed(self) -> bool:
        return self._closed

    def _emit(self, frame: CaptureFrame) -> CaptureFrame:
        self._stats.note(frame)
        return frame

    def __iter__(self) -> Iterator[CaptureFrame]:
        while True:
            frame = self.read()
            if frame is None:
                return
            yield frame

    def __enter__(self) -> "FrameSource":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self._state()})"
