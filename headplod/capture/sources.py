"""Stereo frame sources: one interface for recordings, videos, the renderer and cameras.

Every source is a :class:`~headplod.capture.base.FrameSource` (the interface,
in :mod:`headplod.capture.base`): :meth:`~FrameSource.read` returns the
next stereo pair as a :class:`CaptureFrame` (an :class:`io.Frame
<headplod.io.Frame>` with capture diagnostics), or ``None`` once the source has
ended. Replay (a dataset folder, two video files, the synthetic renderer) and
live capture (two V4L2 cameras, :mod:`headplod.capture.v4l2`) run through the
same loop::

    with open_source("synthetic:static") as source:
        for frame in source:          # CaptureFrame, usable as an io.Frame
            ...

Conventions
-----------
- Images are 8-bit grayscale, shape ``(height, width)``, px; pixel (u, v) =
  (0, 0) is the centre of the top-left pixel (``docs/contract.md``).
- ``t`` / ``t_right``: times of the left / right image, s. For replay they
  come from the recording (mid-exposure for the synthetic renderer; a
  recording of live cameras holds their capture times). For live cameras
  they are seconds since the source was opened, on the monotonic clock,
  from the driver's buffer timestamp (start of exposure or end of frame, as
  the driver decides) or the time ``grab()`` returned: not mid-exposure
  (:mod:`headplod.capture.v4l2`, "Times").
- A frame whose time is zero or not above the previous one, per camera, is
  dropped and counted where frames enter the tracker, for every source
  alike (:mod:`headplod.capture.timestamps`). Sources return such frames as
  they are; ``times.csv`` that does not increase is a dataset warning, not
  an error, so a replay drops the same frames a live run does.
- Skew: ``|t_right - t|`` in ms, the time between the two images of a pair.
- A per-frame problem is a value, never an exception: the frame comes with
  ``error`` set and both images ``None``; the source goes on. Exceptions are
  for a spec or file that cannot be opened (:class:`SourceOpenError`,
  ``ValueError``, :class:`~headplod.io.ContractError`).
"""
from __future__ import annotations

import itertools
import math
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from collections.abc import Mapping
from typing import Any, Callable

import cv2
import numpy as np

from .. import io
from ..io.dataset import folder_inputs
from ..io.files import Inputs
from .base import CaptureFrame, FrameSource, SourceOpenError, _size_error, _skew_flag, to_gray
from .synthetic import DEFAULT_SEQUENCE, ensure_dataset
from .usb import list_cameras, resolve_rig_cameras
from .v4l2 import V4L2StereoSource

__all__ = [
    "DatasetSource",
    "SyntheticSource",
    "VideoSource",
    "open_source",
    "register_source",
    "source_forms",
    "source_inputs",
    "source_kind",
    "synthetic_preset",
    "v4l2_devices",
]


# --------------------------------------------------------------------------
# replay helpers
# --------------------------------------------------------------------------


class _Pacer:
    """Releases frames at the pace of their times (``realtime=True`` replay).

    The first frame goes at once and fixes the schedule: a frame of time
    ``t`` is due ``t - t0`` after it. :meth:`wait` sleeps until a frame is due.
    The policy, decided for a live consumer (opentrack) that wants the
    recording's motion at its own speed:

    - never drop a frame: every frame is released, in order;
    - behind (the frame is already due: a slow read, slow tracking, a busy
      machine): no wait. Up to ``slack_s`` late, the schedule holds, so
      sleep overshoots do not add up into a drift (the frames that follow
      wait a little less: at most ``slack_s`` of catch-up, never a burst);
      more than ``slack_s`` late, the schedule restarts at that frame (it is
      due now), so the frames after it keep their own spacing instead of
      rushing out back to back to catch up;
    - a frame without a finite time goes at once (the schedule kept); one
      whose time goes back before the schedule's start restarts it; a gap longer than ``max_wait_s`` (a pause
      in the recording) is shortened to ``max_wait_s``, and the schedule
      restarts after it (a Ctrl-C is seen within ``max_wait_s``).

    ``clock`` (s, monotonic) and ``sleep`` are injectable, so that tests use a
    fake clock and never assert wall-clock time. :meth:`wait` returns the time
    it waited (the frame's ``paced_s``); :attr:`restarts` counts how often the
    schedule restarted.
    """

    def __init__(self, enabled: bool, *, clock: Callable[[], float] | None = None,
                 sleep: Callable[[float], None] | None = None, slack_s: float = 0.025,
                 max_wait_s: float = 1.0):
        self.enabled = bool(enabled)
        self._clock = clock or time.monotonic
        self._sleep = sleep or time.sleep
        self.slack_s, self.max_wait_s = float(slack_s), float(max_wait_s)
        self._origin: tuple[float, float] | None = None   # (clock, frame time) the schedule counts from
        self.restarts = 0

    def wait(self, t: float) -> float:
        """Sleep until the frame of time ``t`` (s) is due; the seconds slept (0 when behind or disabled)."""
        if not self.enabled:
            return 0.0
        now = self._clock()
        if not math.isfinite(t):
            return 0.0                                  # no time to pace by: at once, the schedule kept
        if self._origin is None:
            self._origin = (now, t)
            return 0.0
        delay = self._origin[0] + (t - self._origin[1]) - now
        if t < self._origin[1] or delay < -self.slack_s:
            self._restart(now, t)                       # back in time, or too late: due now
            return 0.0
        if delay <= 0:
            return 0.0
        if delay > self.max_wait_s:
            delay = self.max_wait_s
            self._restart(now + delay, t)               # a pause in the recording, shortened
        self._sleep(delay)
        return delay

    def _restart(self, now: float, t: float) -> None:
        self._origin = (now, t)
        self.restarts += 1


class BackAndForth(Mapping):
    """The order of a looped replay, without end: frame ``n`` of the replay (0, 1, 2, ...) is the recording's
    frame ``self[n]``, forward, then backward, then forward, ... (recorded ``0 1 2 1 0 1 2 ...``; the turning
    frames are not repeated). Played back and forth, the motion never jumps, as a wrap from the last frame to
    the first would (the head thrown back to its first pose). A mapping of the replay's frames to the
    recording's (``len``: one cycle)."""

    def __init__(self, indices):
        indices = list(indices)
        self.cycle = tuple(indices + indices[-2:0:-1])

    def __getitem__(self, n: int) -> int:
        if not (isinstance(n, int) and n >= 0 and self.cycle):
            raise KeyError(n)
        return self.cycle[n % len(self.cycle)]

    def __iter__(self):
        return iter(range(len(self.cycle)))

    def __len__(self) -> int:
        return len(self.cycle)


class _LoopedTruth(Mapping):
    """The truth of a looped replay's frames, by the replay's frame numbers: {n: the recording's truth of
    frame ``order[n]``} (:class:`BackAndForth`); iterates over one cycle."""

    def __init__(self, truth: Mapping, order: BackAndForth):
        self._truth, self._order = truth, order

    def __getitem__(self, n: int):
        return self._truth[self._order[n]]

    def __iter__(self):
        return (n for n in self._order if self._order[n] in self._truth)

    def __len__(self) -> int:
        return sum(1 for _ in self)


class _ContinuingTimes:
    """The frame times of a looped replay: each frame is the recording's own spacing after the one before
    (the absolute step between their recorded times), so times keep increasing through every turn, as a
    live camera's do. A step that is not finite or is 0 (a frame repeated: a one-frame recording) is
    ``period_s``. Times in s."""

    def __init__(self, period_s: float):
        self.period_s = float(period_s)
        self._recorded: float | None = None           # the previous frame's recorded time
        self._now: float | None = None                # the previous frame's time as given

    def __call__(self, t: float) -> float:
        if self._now is None:
            self._now = t if math.isfinite(t) else 0.0
        else:
            step = abs(t - self._recorded) if math.isfinite(t) and math.isfinite(self._recorded) else 0.0
            self._now += step if step > 0 else self.period_s
        self._recorded = t
        return self._now


def _median_period_s(times: list[float]) -> float | None:
    if len(times) < 2:
        return None
    d = np.diff(np.asarray(times, dtype=np.float64))
    d = d[d > 0]
    return float(np.median(d)) if d.size else None


# --------------------------------------------------------------------------
# replay: dataset folder, synthetic renderer
# --------------------------------------------------------------------------


class DatasetSource(FrameSource):
    """Replay a dataset folder of the contract through :class:`io.Dataset`.

    Parameters
    ----------
    folder : str, Path or io.Dataset
        A folder with ``rig.yaml``, ``left/``, ``right/`` (``times.csv``,
        ``markers.yaml``, ``screen.yaml`` optional), or a dataset already
        read from one.
    realtime : bool
        Pace the frames by their ``t`` (wall-clock replay: ``headplod track
        --realtime``; behind, no frame is dropped and none waits, see
        :class:`_Pacer`); default as fast as they are read.
    skew_bound_ms : float, optional
        Flag frames whose ``|t_right - t|`` exceeds this, ms. Default half the
        median frame period of the recording.
    loop : bool
        Play the recording back and forth without end (:class:`BackAndForth`; ``headplod track
        --realtime --loop``): the frames are numbered on (0, 1, 2, ...: pose records must be in increasing
        frame order) and get times that keep increasing (:class:`_ContinuingTimes`, ``t_right`` as far from
        ``t`` as recorded). Default once.

    Attributes
    ----------
    dataset : io.Dataset
        The dataset read (``truth``, ``times``, ``indices``, ``warnings``).
    truth : Mapping or None
        The truth by the frame numbers this source gives ({index: (position_mm (3,), axes (3, 3))}): the
        dataset's, or a looped replay's (its frames numbered on); None without ``truth.csv``.
    order : BackAndForth or None
        With ``loop``: the recording's frame of each frame given.

    Raises
    ------
    io.ContractError
        When the folder is not a valid dataset (as :class:`io.Dataset`).

    Notes
    -----
    Frames are exactly those of ``io.Dataset`` (same index, times, images,
    error, warning). ``dropped`` is the number of indices missing before a
    frame (a gap in the recording). A recording without ``t_right`` has skew
    0.0 ms (the contract's "same index is the same instant").
    """

    kind = "dataset"

    def __init__(self, folder: str | Path | io.Dataset, realtime: bool = False,
                 skew_bound_ms: float | None = None, loop: bool = False):
        dataset = folder if isinstance(folder, io.Dataset) else io.Dataset(folder)
        super().__init__(str(dataset.folder), dataset.rig, dataset.markers, dataset.screen)
        self.dataset = dataset
        self.warnings.extend(dataset.warnings)
        self.order = BackAndForth(dataset.indices) if loop else None
        self._iter = (self.order[n] for n in itertools.count()) if loop else iter(dataset.indices)
        self._count = 0                                 # frames given
        self.truth = dataset.truth if not (loop and dataset.truth) else _LoopedTruth(dataset.truth, self.order)
        self._previous: int | None = None
        self._pacer = _Pacer(realtime)
        self.realtime, self.loop = bool(realtime), bool(loop)
        times = [tt[0] for tt in (dataset.times or {}).values()]
        period = _median_period_s(times) or 1.0 / io.DEFAULT_FPS
        self._times = _ContinuingTimes(period) if loop else None
        if skew_bound_ms is None:
            skew_bound_ms = 500.0 * period
        self.skew_bound_ms = float(skew_bound_ms)

    def read(self, timeout_s: float = 1.0) -> CaptureFrame | None:
        if self._closed:
            return None
        index = next(self._iter, None)
        if index is None:
            self._closed = True
            return None
        frame = self.dataset.frame(index)
        if self._times is not None:                     # looped: numbered on, times go on through the turns
            t = self._times(frame.t)
            t_right = None if frame.t_right is None else t + (frame.t_right - frame.t)
            frame = replace(frame, index=self._count, t=t, t_right=t_right)
        self._count += 1
        dropped = 0 if self._previous is None else max(0, abs(index - self._previous) - 1)
        self._previous = index
        skew = None
        if frame.ok:
            skew = 0.0 if frame.t_right is None else abs(frame.t_right - frame.t) * 1000.0
        paced = self._pacer.wait(frame.t)
        return self._emit(CaptureFrame.from_frame(
            frame, skew_ms=skew, dropped=dropped, flags=_skew_flag(skew, self.skew_bound_ms), paced_s=paced))


class SyntheticSource(DatasetSource):
    """Replay a built-in synthetic sequence, rendered once and cached.

    Parameters
    ----------
    preset : str
        A preset of ``synthetic.scenes.PRESETS`` (default the sequence
        ``headplod track`` runs).
    frames : int, optional
        Number of frames (the preset's default when ``None``).
    seed : int
        Random seed of the render.
    realtime : bool
        Pace frames by their times.
    skew_bound_ms : float, optional
        As in :class:`DatasetSource`.
    root : Path, optional
        Cache folder (default ``$HEADPLOD_CACHE`` or ``~/.cache/headplod``).
    **preset_options
        Passed to :func:`headplod.capture.synthetic.ensure_dataset` (e.g.
        ``distance_mm`` for ``static``).

    Raises
    ------
    ValueError
        For an unknown preset (the message lists the presets).
    """

    kind = "synthetic"

    def __init__(self, preset: str | None = None, frames: int | None = None, seed: int = 0,
                 realtime: bool = False, skew_bound_ms: float | None = None,
                 root: str | Path | None = None, **preset_options: Any):
        self.preset = preset or DEFAULT_SEQUENCE
        folder = ensure_dataset(self.preset, frames=frames, seed=seed,
                                root=None if root is None else Path(root), quiet=True,
                                **preset_options)
        super().__init__(folder, realtime=realtime, skew_bound_ms=skew_bound_ms)
        self.name = f"synthetic:{self.preset} ({folder})"


# --------------------------------------------------------------------------
# replay: two video files
# --------------------------------------------------------------------------


def _read_beside(folder: Path, rig: Any) -> tuple[io.Rig | None, io.MarkerModel | None, io.Screen | None]:
    """rig (given, a path, or rig.yaml in folder), markers.yaml and screen.yaml in folder."""
    if isinstance(rig, (str, os.PathLike)):
        rig = io.read_rig(rig)
    elif rig is None and (folder / "rig.yaml").is_file():
        rig = io.read_rig(folder / "rig.yaml")
    markers = io.read_markers(folder / "markers.yaml") if (folder / "markers.yaml").is_file() else None
    screen = io.read_screen(folder / "screen.yaml") if (folder / "screen.yaml").is_file() else None
    return rig, markers, screen


class VideoSource(FrameSource):
    """Replay a stereo pair of video files (left, right), frames as 8-bit gray.

    Parameters
    ----------
    left, right : str or Path
        The two video files; frame ``i`` of one is the same instant as frame
        ``i`` of the other.
    rig : io.Rig or str or Path, optional
        The rig, or the path of a ``rig.yaml``. Default: ``rig.yaml`` in the
        left video's folder when there is one, else ``None``
        (``markers.yaml`` and ``screen.yaml`` there are read too).
    times : str or Path, optional
        A ``times.csv`` (``frame,t[,t_right]``, s) giving each frame's time.
        Default: ``times.csv`` in the left video's folder when there is one;
        otherwise ``t = index / fps`` with the left file's frame rate.
    realtime : bool
        Pace frames by their times.
    skew_bound_ms : float, optional
        Flag frames whose ``|t_right - t|`` exceeds this, ms (default half a
        frame period).

    Attributes
    ----------
    fps : float
        The left file's frame rate, Hz (``DEFAULT_FPS`` when it has none).
    frame_counts : tuple of int
        Frame counts the containers declare (left, right); may be 0 or
        approximate, the source reads until a file ends.

    Raises
    ------
    SourceOpenError
        When a file is missing or cannot be decoded (names the file).

    Notes
    -----
    When the files have different lengths, the source ends with the shorter
    one and adds a warning (to ``warnings`` and to the last frame's
    ``warning`` when possible). Colour videos are converted with
    ``cv2.cvtColor(..., BGR2GRAY)``; lossy codecs (MJPG) change pixel values
    by a few DN, lossless ones (FFV1, PNG) keep them exactly.
    """

    kind = "video"

    def __init__(self, left: str | Path, right: str | Path, rig: Any = None,
                 times: str | Path | None = None, realtime: bool = False,
                 skew_bound_ms: float | None = None):
        self.paths = (Path(left), Path(right))
        folder = self.paths[0].parent
        rig, markers, screen = _read_beside(folder, rig)
        super().__init__(f"{self.paths[0]},{self.paths[1]}", rig, markers, screen)
        if times is None and (folder / "times.csv").is_file():
            times = folder / "times.csv"
        self.times = io.read_times(times) if times is not None else None
        self._caps: list[Any] = []
        try:
            for path in self.paths:
                self._caps.append(self._open(path))
        except BaseException:
            self.close()
            raise
        fps = [float(c.get(cv2.CAP_PROP_FPS) or 0.0) for c in self._caps]
        self.fps = fps[0] if math.isfinite(fps[0]) and fps[0] > 0 else io.DEFAULT_FPS
        if not (math.isfinite(fps[0]) and fps[0] > 0):
            self.warnings.append(f"{self.paths[0]}: no frame rate in the file; assuming {io.DEFAULT_FPS:g} fps")
        elif math.isfinite(fps[1]) and fps[1] > 0 and abs(fps[1] - fps[0]) > 1e-3 * fps[0]:
            self.warnings.append(f"frame rates differ: {self.paths[0]} {fps[0]:g} fps, "
                                 f"{self.paths[1]} {fps[1]:g} fps; times follow the left file")
        counts = [int(c.get(cv2.CAP_PROP_FRAME_COUNT) or 0) for c in self._caps]
        self.frame_counts = tuple(counts)
        if self.times:
            period = _median_period_s([tt[0] for tt in self.times.values()]) or 1.0 / self.fps
        else:
            period = 1.0 / self.fps
        self.skew_bound_ms = 500.0 * period if skew_bound_ms is None else float(skew_bound_ms)
        self._index = 0
        self._pacer = _Pacer(realtime)
        self.realtime = bool(realtime)

    @staticmethod
    def _open(path: Path) -> Any:
        if not path.is_file():
            raise SourceOpenError(f"{path}: video file not found" if not path.exists()
                                  else f"{path}: is not a file, expected a video file")
        cap = cv2.VideoCapture(io.opencv_name(path, "video file"))      # UnnamablePath: refused in one line
        if not cap.isOpened():
            cap.release()
            raise SourceOpenError(f"{path}: cannot be opened as a video (unknown container or codec, "
                                  "or a corrupt file)")
        return cap

    def _time(self, index: int) -> tuple[float, float | None, str | None]:
        if self.times is None:
            return index / self.fps, None, None
        if index in self.times:
            t, t_right = self.times[index]
            return t, t_right, None
        return index / self.fps, None, f"times.csv has no row for frame {index}; t = index / {self.fps:g} fps"

    def read(self, timeout_s: float = 1.0) -> CaptureFrame | None:
        if self._closed:
            return None
        index = self._index
        grabbed = [bool(c.grab()) for c in self._caps]
        if not all(grabbed):
            if any(grabbed):
                longer, shorter = (0, 1) if grabbed[0] else (1, 0)
                self.warnings.append(
                    f"{self.paths[shorter]} ends after {index} frames, {self.paths[longer]} has more: "
                    "the extra frames are ignored")
            self.close()
            return None
        self._index += 1
        t, t_right, note = self._time(index)
        images, errors = [], []
        for side, cap, path in zip(("left", "right"), self._caps, self.paths):
            ok, img = cap.retrieve()
            if not ok or img is None:
                errors.append(f"{path} frame {index}: cannot be decoded")
                images.append(None)
                continue
            try:
                gray = to_gray(img)
            except ValueError as exc:
                errors.append(f"{path} frame {index}: {exc}")
                images.append(None)
                continue
            bad = _size_error(f"{path} frame {index}", gray, self.rig)
            if bad:
                errors.append(bad)
            images.append(gray)
        if errors:
            images = [None, None]
        skew = None if errors else (0.0 if t_right is None else abs(t_right - t) * 1000.0)
        paced = self._pacer.wait(t)
        return self._emit(CaptureFrame(
            index=index, t=t, t_right=t_right, left=images[0], right=images[1],
            error="; ".join(errors) or None, warning=note, skew_ms=skew,
            flags=_skew_flag(skew, self.skew_bound_ms), paced_s=paced))

    def close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []
        super().close()


# --------------------------------------------------------------------------
# registry
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Entry:
    kind: str
    form: str
    accepts: Callable[[str], bool]
    factory: Callable[..., FrameSource]


_REGISTRY: list[_Entry] = []


def register_source(kind: str, form: str, accepts: Callable[[str], bool],
                    factory: Callable[..., FrameSource]) -> None:
    """Add a kind of source to :func:`open_source`.

    Parameters
    ----------
    kind : str
        Short name (replaces an entry of the same name).
    form : str
        The spec form(s) it accepts, for the error message of
        :func:`open_source`.
    accepts : callable(str) -> bool
        Whether a spec is for this kind. Entries are tried in registration
        order; the first that accepts wins.
    factory : callable(spec, **options) -> FrameSource
    """
    _REGISTRY[:] = [e for e in _REGISTRY if e.kind != kind]
    _REGISTRY.append(_Entry(kind, form, accepts, factory))


def source_forms() -> list[str]:
    """The spec forms :func:`open_source` accepts, one line each."""
    return [e.form for e in _REGISTRY]


def open_source(spec: str | os.PathLike, **options: Any) -> FrameSource:
    """Open a frame source from a spec string.

    Parameters
    ----------
    spec : str or path-like
        One of (tried in this order):

        - ``synthetic`` or ``synthetic:PRESET``: the built-in renderer
          (:class:`SyntheticSource`);
        - ``v4l2:/dev/video0,/dev/video2`` or ``v4l2:0,2``, or just two
          integers ``0,2``: two V4L2 cameras, left first
          (:class:`~headplod.capture.v4l2.V4L2StereoSource`); ``v4l2:auto``:
          the two cameras the ``rig`` option names by USB identity
          (``headplod cameras --store``);
        - an existing folder: a dataset folder (:class:`DatasetSource`);
        - ``LEFT.avi,RIGHT.avi``: two video files (:class:`VideoSource`).
    **options
        Passed to the source's constructor (e.g. ``realtime=True``,
        ``frames=30``, ``fps=60``, ``opener=...``).

    Returns
    -------
    FrameSource

    Raises
    ------
    ValueError
        For a spec of none of these forms (the message lists them).
    SourceOpenError, io.ContractError
        When the spec's form is recognised but the files or devices cannot be
        opened.
    """
    text = os.fspath(spec).strip() if not isinstance(spec, str) else spec.strip()
    for entry in _REGISTRY:
        if entry.accepts(text):
            return entry.factory(text, **options)
    forms = "\n  ".join(source_forms())
    why = "no such file or folder" if "," not in text else "expected exactly two comma-separated parts"
    raise ValueError(f"cannot open source {text!r} ({why}). Accepted forms:\n  {forms}")


def source_kind(spec: str | os.PathLike) -> str | None:
    """The kind of source :func:`open_source` would open for ``spec`` (``'v4l2'``, ``'dataset'``, ...), or None."""
    text = os.fspath(spec).strip()
    return next((entry.kind for entry in _REGISTRY if entry.accepts(text)), None)


def synthetic_preset(spec: str | os.PathLike) -> str | None:
    """The preset a ``synthetic`` or ``synthetic:PRESET`` spec names (the default sequence for the former), or None."""
    text = os.fspath(spec).strip()
    if not _accepts_synthetic(text):
        return None
    return text.partition(":")[2].strip() or DEFAULT_SEQUENCE


def _two_parts(text: str) -> list[str] | None:
    parts = [p.strip() for p in text.split(",")]
    return parts if len(parts) == 2 and all(parts) else None


def _is_int(text: str) -> bool:
    return text.isdigit()


def _accepts_v4l2(text: str) -> bool:
    if text.lower().startswith("v4l2:"):
        return True
    parts = _two_parts(text)
    return parts is not None and all(_is_int(p) for p in parts)


def v4l2_devices(spec: str) -> str | tuple | None:
    """The cameras a ``v4l2`` source spec names (with or without its ``v4l2:``): ``"auto"`` (the cameras a rig
    names), ``(left, right)`` (an int for a bare index such as ``0``, else the path as written), or None when
    it names neither. The one reading of the form, for every command that takes cameras."""
    text = spec.strip()
    body = text[5:] if text.lower().startswith("v4l2:") else text
    if body.strip().lower() == "auto":
        return "auto"
    parts = _two_parts(body)
    return None if parts is None else tuple(int(p) if _is_int(p) else p for p in parts)


def _open_v4l2(text: str, **options: Any) -> FrameSource:
    devices = v4l2_devices(text)
    if devices == "auto":
        rig = options.get("rig")
        if rig is None:
            raise ValueError(f"cannot open source {text!r}: v4l2:auto finds the cameras the rig names by USB "
                             "identity; give the rig (--calib rig.yaml, stored with 'headplod cameras --store')")
        if isinstance(rig, (str, os.PathLike)):
            rig = options["rig"] = io.read_rig(Path(rig))
        left, right = resolve_rig_cameras(rig, list_cameras())
        return V4L2StereoSource(left, right, **options)
    if devices is None:
        raise ValueError(f"cannot open source {text!r}: expected two devices, left first, "
                         "as v4l2:/dev/video0,/dev/video2 or v4l2:0,2")
    return V4L2StereoSource(*devices, **options)


def _accepts_synthetic(text: str) -> bool:
    return text == "synthetic" or text.startswith("synthetic:")


def _open_synthetic(text: str, **options: Any) -> FrameSource:
    preset = text.partition(":")[2].strip() or None
    return SyntheticSource(preset, **options)


def _accepts_video(text: str) -> bool:
    parts = _two_parts(text)
    return parts is not None and not Path(text).is_dir() and not all(_is_int(p) for p in parts)


def _open_video(text: str, **options: Any) -> FrameSource:
    left, right = _two_parts(text)  # type: ignore[misc]
    return VideoSource(left, right, **options)


register_source("synthetic", "synthetic or synthetic:PRESET (the built-in renderer, e.g. synthetic:static)",
                _accepts_synthetic, _open_synthetic)
register_source("v4l2", "v4l2:/dev/video0,/dev/video2 or v4l2:0,2 or 0,2 (two V4L2 cameras, left first), "
                "or v4l2:auto (the cameras the rig names)",
                _accepts_v4l2, _open_v4l2)
register_source("dataset", "DATASET_FOLDER (an existing folder with rig.yaml, left/, right/)",
                lambda text: Path(text).is_dir(), lambda text, **o: DatasetSource(text, **o))
register_source("video", "LEFT_VIDEO,RIGHT_VIDEO (two video files, e.g. left.avi,right.avi)",
                _accepts_video, _open_video)


# --------------------------------------------------------------------------
# what a source reads
# --------------------------------------------------------------------------


def source_inputs(spec: str | os.PathLike | None = None, source: FrameSource | None = None) -> Inputs:
    """Every file and folder a replay reads (:class:`~headplod.io.files.Inputs`), for the outputs' checks.

    With ``source`` (opened): what it reads, resolved through links (a
    dataset's folders, files and each frame, :meth:`io.Dataset.inputs`; two
    videos and the files read beside them). With ``spec`` alone (before
    opening): what the spec names (a dataset folder, its ``left/``,
    ``right/`` and files; two videos and the files beside them). Live
    cameras and a synthetic spec not yet opened: nothing a user names.
    """
    if source is not None:
        dataset = getattr(source, "dataset", None)
        if dataset is not None:
            return dataset.inputs()
        paths = getattr(source, "paths", None)
        return _video_inputs(paths) if paths else Inputs()
    if spec is None or source_kind(spec) in ("v4l2", "synthetic"):
        return Inputs()
    text = os.fspath(spec).strip()
    if Path(text).expanduser().is_dir():
        return folder_inputs(Path(text).expanduser())
    parts = _two_parts(text)
    return _video_inputs(parts) if parts else Inputs()


def _video_inputs(paths) -> Inputs:
    """Two videos, and what :class:`VideoSource` reads beside the left one."""
    left, right = (Path(p).expanduser() for p in paths)
    inputs = Inputs().file("the left video being read", left).file("the right video being read", right)
    for name in ("rig.yaml", "markers.yaml", "screen.yaml", "times.csv"):
        if (left.parent / name).is_file():
            inputs = inputs.file(f"the {name} being read beside the videos", left.parent / name)
    return inputs
