"""Record stereo frames into a dataset folder of the contract.

:class:`DatasetRecorder` writes what :class:`headplod.io.Dataset` reads:
``rig.yaml``, ``markers.yaml`` / ``screen.yaml`` when given,
``left/NNNNNN.png``, ``right/NNNNNN.png`` (8-bit gray, lossless) and
``times.csv`` (``frame,t,t_right``, s). Everything is written as it comes,
so a recording interrupted by a crash keeps every frame written before it:

- each image is written to ``NNNNNN.png.part`` and renamed when complete
  (a reader never sees half a PNG; a leftover ``.part`` file is ignored by
  ``io.Dataset`` with a warning);
- the ``times.csv`` row of a frame is written and flushed after both of its
  images, so a row always has its images.

Frames are numbered 000000, 000001, ... in the order written, whatever their
index in the source. Frames with an ``error`` (a camera stalled, a bad
image) have no images to write: they are skipped, and a line in
``recording.log`` says which source frame was skipped and why, so the gap in
time is explained. Dropped frames and skew flags of written frames are noted
there too. ``recording.log`` lies beside the contract's files and readers
ignore it.
"""
from __future__ import annotations

import math
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import io
from .base import FrameSource

__all__ = ["DatasetRecorder", "RecordingSummary", "record"]

_LOG_NAME = "recording.log"
_TIMES_HEADER = "frame,t,t_right\n"


class DatasetRecorder:
    """Write stereo frames into a dataset folder, frame by frame.

    Parameters
    ----------
    folder : str or Path
        The dataset folder (created with its parents when missing).
    rig : io.Rig
        The rig the images belong to; written as ``rig.yaml``. Images must
        have its ``image_size``.
    markers : io.MarkerModel, optional
        Written as ``markers.yaml``.
    screen : io.Screen, optional
        Written as ``screen.yaml``.
    overwrite : bool
        Allow recording into a folder whose ``left/`` already holds files:
        its ``left/``, ``right/``, ``times.csv``, ``truth.csv`` and
        ``recording.log`` are removed first (``truth.csv`` would describe
        other frames).

    Attributes
    ----------
    count : int
        Frames written.
    skipped : int
        Frames not written (error frames).

    Raises
    ------
    FileExistsError
        When ``left/`` already holds files and ``overwrite`` is False.
    TypeError
        When ``rig`` is not an :class:`io.Rig`.

    Examples
    --------
    >>> with open_source("0,2") as cams, DatasetRecorder("take1", rig) as rec:   # doctest: +SKIP
    ...     for frame in cams:
    ...         rec.write(frame)
    """

    def __init__(self, folder: str | Path, rig: io.Rig, markers: io.MarkerModel | None = None,
                 screen: io.Screen | None = None, overwrite: bool = False):
        if not isinstance(rig, io.Rig):
            raise TypeError(f"rig is a {type(rig).__name__}, expected an io.Rig (a recording needs "
                            "the calibration its images belong to; see headplod.io.read_rig)")
        self.folder = Path(folder)
        self.rig = rig
        left = self.folder / "left"
        if left.is_dir() and any(left.iterdir()):
            if not overwrite:
                raise FileExistsError(
                    f"{self.folder}: already holds a recording ({left} is not empty); "
                    "choose another folder or pass overwrite=True to replace it")
            for name in ("left", "right"):
                shutil.rmtree(self.folder / name, ignore_errors=True)
            for name in ("times.csv", "truth.csv", _LOG_NAME):
                (self.folder / name).unlink(missing_ok=True)
        for name in ("left", "right"):
            (self.folder / name).mkdir(parents=True, exist_ok=True)
        io.write_rig(self.folder / "rig.yaml", rig)
        if markers is not None:
            io.write_markers(self.folder / "markers.yaml", markers)
        if screen is not None:
            io.write_screen(self.folder / "screen.yaml", screen)
        self._times = open(self.folder / "times.csv", "w", newline="", encoding="utf-8")
        self._times.write(_TIMES_HEADER)
        self._times.flush()
        self._log: Any = None
        self.count = 0
        self.skipped = 0

    # -- writing -------------------------------------------------------------

    def _note(self, line: str) -> None:
        if self._log is None:
            self._log = open(self.folder / _LOG_NAME, "a", encoding="utf-8")
        self._log.write(line + "\n")
        self._log.flush()

    def _check_image(self, side: str, image: Any) -> str | None:
        if not isinstance(image, np.ndarray):
            return f"{side} image is {type(image).__name__}, expected an ndarray"
        if image.dtype != np.uint8 or image.ndim != 2:
            return f"{side} image is {image.dtype} of shape {image.shape}, expected uint8 (height, width)"
        h, w = image.shape
        rw, rh = self.rig.image_size
        if (w, h) != (rw, rh):
            return f"{side} image is {w}x{h}, rig says {rw}x{rh}"
        return None

    def _write_png(self, path: Path, image: np.ndarray) -> None:
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"{path}: PNG encoding failed")
        part = path.with_name(path.name + ".part")
        with open(part, "wb") as fh:
            fh.write(data.tobytes())
        os.replace(part, path)

    def write(self, frame: io.Frame) -> int | None:
        """Write one frame (both images and its times.csv row).

        Parameters
        ----------
        frame : io.Frame or CaptureFrame
            ``left`` and ``right`` 8-bit gray, shape (height, width) of the
            rig; ``t`` (and ``t_right`` when not ``None``) finite, s.

        Returns
        -------
        int or None
            The frame's index in the recording, or ``None`` when it was
            skipped (an error frame, or images that do not fit the rig: the
            reason goes to ``recording.log``).

        Raises
        ------
        ValueError
            After :meth:`close`, or for a non-finite time (a programming
            error of the source).
        OSError
            When the disk refuses a write.
        """
        if self._times is None:
            raise ValueError(f"{self.folder}: DatasetRecorder is closed")
        t = float(frame.t)
        t_right = None if frame.t_right is None else float(frame.t_right)
        if not math.isfinite(t) or (t_right is not None and not math.isfinite(t_right)):
            raise ValueError(f"frame {frame.index}: non-finite time t={frame.t!r}, t_right={frame.t_right!r}")
        dropped = int(getattr(frame, "dropped", 0) or 0)
        if dropped:
            self._note(f"before source frame {frame.index} (t={t:.6f} s): {dropped} frames dropped by the source")
        problem = frame.error or self._check_image("left", frame.left) or self._check_image("right", frame.right)
        if problem:
            self.skipped += 1
            self._note(f"source frame {frame.index} (t={t:.6f} s): not recorded: {problem}")
            return None
        index = self.count
        name = f"{index:06d}.png"
        self._write_png(self.folder / "left" / name, frame.left)
        self._write_png(self.folder / "right" / name, frame.right)
        self._times.write(f"{index},{t!r},{'' if t_right is None else repr(t_right)}\n")
        self._times.flush()
        for flag in getattr(frame, "flags", None) or []:
            self._note(f"frame {index:06d} (source frame {frame.index}): {flag}")
        self.count += 1
        return index

    def close(self) -> None:
        """Flush and close ``times.csv`` and ``recording.log``; idempotent."""
        for fh in (self._times, self._log):
            if fh is not None:
                fh.close()
        self._times = None
        self._log = None

    def __enter__(self) -> "DatasetRecorder":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"DatasetRecorder({str(self.folder)!r}, {self.count} frames, {self.skipped} skipped)"


@dataclass
class RecordingSummary:
    """What :func:`record` did.

    Attributes
    ----------
    folder : Path
    frames : int
        Frames written.
    skipped : int
        Error frames not written.
    duration_s : float
        Wall-clock time of the recording, s.
    status : SourceStatus
        The source's status at the end.
    """

    folder: Path
    frames: int
    skipped: int
    duration_s: float
    status: Any


def record(source: FrameSource, folder: str | Path, max_frames: int | None = None,
           duration_s: float | None = None, rig: io.Rig | None = None,
           overwrite: bool = False) -> RecordingSummary:
    """Record a source into a dataset folder until it ends or a limit is reached.

    Parameters
    ----------
    source : FrameSource
        Read with ``source.read()``; not closed here.
    folder : str or Path
    max_frames : int, optional
        Stop after this many frames read (written or skipped).
    duration_s : float, optional
        Stop after this much wall-clock time, s.
    rig : io.Rig, optional
        Overrides ``source.rig`` (required when the source has none).
    overwrite : bool
        As in :class:`DatasetRecorder`.

    Returns
    -------
    RecordingSummary

    Raises
    ------
    ValueError
        When neither ``rig`` nor ``source.rig`` is given.
    """
    rig = rig if rig is not None else source.rig
    if rig is None:
        raise ValueError(f"{source.name}: the source has no rig; pass rig= (a recording needs rig.yaml)")
    start = time.monotonic()
    n = 0
    with DatasetRecorder(folder, rig, source.markers, source.screen, overwrite=overwrite) as rec:
        while max_frames is None or n < max_frames:
            if duration_s is not None and time.monotonic() - start >= duration_s:
                break
            frame = source.read()
            if frame is None:
                break
            rec.write(frame)
            n += 1
    return RecordingSummary(Path(folder), rec.count, rec.skipped, time.monotonic() - start,
                            source.status())
