"""Record stereo frames into a dataset folder of the contract.

:class:`DatasetRecorder` writes what :class:`headplod.io.Dataset` reads:
``rig.yaml``, ``markers.yaml`` / ``screen.yaml`` when given,
``left/NNNNNN.png``, ``right/NNNNNN.png`` (8-bit gray, lossless) and
``times.csv`` (``frame,t,t_right``, s). Everything is written as it comes,
so a recording interrupted by a crash keeps every frame written before it,
and a recording is consistent whenever it stops (every ``times.csv`` row has
both images, no image is without its row):

- a frame is one step: both images are written to ``NNNNNN.png.part``,
  renamed, and then its ``times.csv`` row is written and flushed, with
  SIGINT and SIGTERM held until the step is done
  (:func:`~headplod.capture.signals.deferred_signals`); a step that fails
  (a full disk) removes what it wrote of its frame;
- :meth:`DatasetRecorder.close` removes any image without a row and any
  ``.part`` file left behind (there are none unless the process was killed
  outright; ``io.Dataset`` then warns about them).

A folder that already holds a recording is only replaced when asked
(``overwrite=True``). The recording is always written in the folder itself,
so that a run killed outright keeps every frame before it where the user
looks; the old recording's entries are first moved to a visible folder
beside it (``rec.previous/``), deleted when the new recording is closed
whole and kept when it ends early (``close(complete=False)``). A killed
run's recording found in the folder is set aside as
``rec.unfinished-<start>/``, made consistent, and named in ``notes``
(:mod:`headplod.io.progressive`).

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
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import io
from ..io.progressive import claim_output, killed_run
from .base import FrameSource
from .signals import deferred_signals

__all__ = ["DatasetRecorder", "RecordingSummary", "record", "holds_recording", "recording_held", "RECORDING_ENTRIES"]

_LOG_NAME = "recording.log"
_TIMES_HEADER = "frame,t,t_right\n"
_IMAGE_NAME = re.compile(r"^([0-9]{6})\.png(\.part)?$")
#: The entries of a dataset folder that a recording owns (replaced with it; everything else is left alone).
RECORDING_ENTRIES = ("left", "right", "times.csv", "truth.csv", _LOG_NAME, "rig.yaml", "markers.yaml", "screen.yaml")


def _times_rows(folder: Path) -> int:
    """Whole rows of a recording's times.csv (0 when it is missing)."""
    try:
        data = (Path(folder) / "times.csv").read_bytes()
    except OSError:
        return 0
    return max(data.count(b"\n") - 1, 0)


def _drop_orphans(folder: Path, rows: int) -> list[str]:
    """Remove a recording's images without a times.csv row (index >= rows) and ``.part`` files; their names."""
    dropped = []
    for side in ("left", "right"):
        d = Path(folder) / side
        if not d.is_dir():
            continue
        for entry in d.iterdir():
            m = _IMAGE_NAME.match(entry.name)
            if m and (m.group(2) or int(m.group(1)) >= rows):
                entry.unlink(missing_ok=True)
                dropped.append(f"{side}/{entry.name}")
    return dropped


def tidy_recording(folder: str | Path) -> list[str]:
    """Make a recording cut short by a killed process consistent: drop images without a times.csv row and
    ``.part`` files (a cut last row is dropped too). Returns the names dropped."""
    folder = Path(folder)
    times = folder / "times.csv"
    if times.is_file():
        data = times.read_bytes()
        if data and not data.endswith(b"\n"):          # a row cut by the kill: not a frame
            times.write_bytes(data[: data.rfind(b"\n") + 1])
    return _drop_orphans(folder, _times_rows(folder))


def _count_frames(folder: Path) -> str:
    return f"{_times_rows(folder)} frames"


def recording_held(folder: str | Path) -> str | None:
    """What recording ``folder`` already holds, in words for a refusal (None when it holds none).

    ``"already holds a recording"``, or, for the recording of a killed run
    (:func:`headplod.io.progressive.killed_run`), whose it is and how to
    replay it; replacing it keeps it as ``NAME.unfinished-<start>``.
    """
    if not holds_recording(folder):
        return None
    run = killed_run(folder, folder=True)
    if run is not None and not run.alive:
        return (f"holds the recording of {run.describe()}, kept as it was (replay it with 'headplod track "
                f"--source {folder}'; replacing it keeps it as {Path(folder).name}.unfinished-...)")
    return "already holds a recording"


def holds_recording(folder: str | Path) -> bool:
    """True when ``folder`` already holds a recording: images in ``left/`` or ``right/``, or a ``times.csv``."""
    folder = Path(folder)
    for side in ("left", "right"):
        d = folder / side
        if d.is_dir() and any(d.iterdir()):
            return True
    return (folder / "times.csv").exists()


class DatasetRecorder(io.ProgressiveOutput):
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
        Allow recording into a folder that already holds a recording
        (:func:`holds_recording`). Its entries (:data:`RECORDING_ENTRIES`:
        ``left/``, ``right/``, ``times.csv``, ``truth.csv``, which would
        describe other frames, ``recording.log`` and the YAML files) are
        moved to a visible folder beside it (``NAME.previous``), deleted by
        :meth:`close` and kept by ``close(complete=False)`` and (put back)
        by :meth:`discard`; other files in the folder are kept.

    Attributes
    ----------
    count : int
        Frames written.
    skipped : int
        Frames not written (error frames).
    replacing : bool
        True when an existing recording is being replaced (``overwrite``).
    notes : list of str
        Leftovers of killed runs found and kept, one line each, for the
        caller to show.

    Raises
    ------
    FileExistsError
        When the folder already holds a recording and ``overwrite`` is False.
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
        self._times: Any = None
        self._log: Any = None
        self._claim = None
        self.count = 0
        self.skipped = 0
        if self.folder.exists() and not self.folder.is_dir():
            raise FileExistsError(f"{self.folder}: is a file, not a folder; choose a folder for the recording")
        held = recording_held(self.folder)
        if held and not overwrite:
            raise FileExistsError(f"{self.folder}: {held}; choose another folder, or replace it (overwrite=True; on "
                                  "the command line --overwrite)")
        self._claim = claim_output(self.folder, what=str(self.folder), folder=True, entries=RECORDING_ENTRIES,
                                   holds_output=holds_recording, describe=_count_frames, tidy=tidy_recording)
        self.notes = list(self._claim.notes)
        self.replacing = self._claim.previous is not None
        try:
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
        except BaseException:
            if self._times is not None:
                self._times.close()
                self._times = None
            self._claim.restore(self._remove_entries)
            raise

    @property
    def previous(self) -> Path | None:
        """Where the recording this one replaces was moved (``rec.previous``), until :meth:`close`."""
        return self._claim.previous

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

    @staticmethod
    def _encode_png(path: Path, image: np.ndarray) -> bytes:
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"{path}: PNG encoding failed")
        return data.tobytes()

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
        busy = int(getattr(frame, "dropped_busy", 0) or 0)
        if busy:
            self._note(f"before source frame {frame.index} (t={t:.6f} s): {busy} frames dropped while the tracker "
                       "was busy")
        problem = frame.error or self._check_image("left", frame.left) or self._check_image("right", frame.right)
        if problem:
            self.skipped += 1
            self._note(f"source frame {frame.index} (t={t:.6f} s): not recorded: {problem}")
            return None
        index = self.count
        name = f"{index:06d}.png"
        paths = [self.folder / side / name for side in ("left", "right")]
        data = [self._encode_png(path, image) for path, image in zip(paths, (frame.left, frame.right))]
        parts = [path.with_name(name + ".part") for path in paths]
        row = f"{index},{t!r},{'' if t_right is None else repr(t_right)}\n"
        with deferred_signals():                     # the pair and its row: one step
            done = False
            try:
                for part, blob in zip(parts, data):
                    with open(part, "wb") as fh:
                        fh.write(blob)
                for part, path in zip(parts, paths):
                    os.replace(part, path)
                self._times.write(row)
                self.count += 1                      # the frame is in: a held signal comes after this step
                done = True
                self._times.flush()
            except BaseException:
                if not done:                         # drop the pair in progress
                    for path in (*parts, *paths):
                        path.unlink(missing_ok=True)
                raise
        for flag in getattr(frame, "flags", None) or []:
            self._note(f"frame {index:06d} (source frame {frame.index}): {flag}")
        return index

    def _drop_orphans(self) -> list[str]:
        """Remove images without a times.csv row (index >= count) and ``.part`` files; their names."""
        return _drop_orphans(self.folder, self.count)

    def _remove_entries(self) -> None:
        for name in RECORDING_ENTRIES:
            path = self.folder / name
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)

    def close(self, complete: bool = True) -> str | None:
        """Flush and close ``times.csv`` and ``recording.log`` and drop any image without its row; idempotent.

        Parameters
        ----------
        complete : bool
            True when the run ended as it should: the recording this one
            replaced (``overwrite``) is deleted. False: it is kept.

        Returns
        -------
        str or None
            Where the replaced recording is kept (``complete`` false), else None.
        """
        if self._claim is None:
            return None
        with deferred_signals():
            try:
                for fh in (self._times, self._log):
                    if fh is not None:
                        fh.close()
            except OSError:
                complete = False
                raise
            finally:
                self._times = None
                self._log = None
                if self.folder.is_dir():
                    self._drop_orphans()
                claim, self._claim = self._claim, None
                kept = claim.finish(complete)
        return kept

    def _undo(self) -> None:
        if self._claim is None:
            return
        for fh in (self._times, self._log):
            if fh is not None:
                fh.close()
        self._times = self._log = None
        claim, self._claim = self._claim, None
        claim.restore(self._remove_entries)

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
