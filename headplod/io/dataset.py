"""The stereo dataset folder: ``left/``, ``right/`` and the files beside them.

:class:`Dataset` reads a folder (``rig.yaml``, optional ``markers.yaml``,
``screen.yaml``, ``times.csv``, ``truth.csv``) and loads its frames lazily as
:class:`Frame` objects; a bad image gives a frame with ``error`` set instead
of raising.
"""

from __future__ import annotations

import errno
import operator
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from ._storage import _Ctx
from .files import Inputs
from .images import decode_image
from .markers import MarkerModel, default_marker_model, read_markers
from .rig import Rig, read_rig
from .screen import Screen, read_screen
from .tables import read_times, read_truth

# --------------------------------------------------------------------------
# constants
# --------------------------------------------------------------------------

#: Frame rate assumed for frame times when a dataset has no times.csv (Hz).
DEFAULT_FPS = 30.0
#: t_right farther than this many frame periods (and 0.1 s) from t is a skew of the clocks (a warning).
MAX_RIGHT_OFFSET_PERIODS = 3.0
_FRAME_NAME = re.compile(r"^([0-9]{6})\.png$")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass
class Frame:
    """One stereo frame of a dataset.

    Attributes
    ----------
    index : int
        Frame index (the six digits of the file names).
    t : float
        Time of the left image, s: mid-exposure for synthetic data; for a
        recording of live cameras, their capture time (the driver's buffer
        timestamp or the grab time, :mod:`headplod.capture.v4l2`).
    t_right : float or None
        Time of the right image, s, likewise, when it differs from ``t``.
    left, right : ndarray or None
        8-bit grayscale images, shape (height, width), px. Both ``None``
        when ``error`` is set.
    error : str or None
        Why the frame cannot be used, e.g. ``"left/000007.png: missing"``,
        ``"right/000003.png: 320x240, rig says 640x480"``; ``None`` if fine.
    warning : str or None
        Something to report that did not stop the frame, e.g. a colour image
        converted to gray or an interpolated time.
    """

    index: int
    t: float
    t_right: float | None
    left: np.ndarray | None
    right: np.ndarray | None
    error: str | None = None
    warning: str | None = None

    @property
    def ok(self) -> bool:
        """True when the frame has both images (``error`` is None)."""
        return self.error is None


def _list_names(names: list[str], limit: int = 5) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def _interp_time(known: list[tuple[int, float]], index: int) -> float:
    """Linear inter/extrapolation of a time from (frame, t) pairs."""
    if not known:
        return index / DEFAULT_FPS
    if len(known) == 1:
        f0, t0 = known[0]
        return t0 + (index - f0) / DEFAULT_FPS
    frames = np.array([k[0] for k in known], dtype=np.float64)
    ts = np.array([k[1] for k in known], dtype=np.float64)
    if index < frames[0]:
        i, j = 0, 1
    elif index > frames[-1]:
        i, j = -2, -1
    else:
        return float(np.interp(index, frames, ts))
    slope = (ts[j] - ts[i]) / (frames[j] - frames[i])
    return float(ts[i] + slope * (index - frames[i]))


def _unreachable(path: Path, exc: OSError) -> str | None:
    """Why a listed frame file could not be opened (``exc``), when it is the file's absence: a link that
    loops or points nowhere, or gone since it was listed; None for another reason (no permission, ...)."""
    if exc.errno == errno.ELOOP:
        return "a symbolic link that loops (it leads back to itself); replace it with the image"
    if exc.errno != errno.ENOENT:
        return None
    if path.is_symlink():
        return f"a symbolic link to {os.readlink(path)}, which does not exist"
    return "missing"


class Dataset:
    """A stereo dataset folder of the contract.

    Reads ``rig.yaml`` (required), ``markers.yaml`` (optional: the default
    model when absent), ``screen.yaml`` (optional: ``None`` when absent),
    ``times.csv`` (optional: when absent, frame ``i`` is at
    ``t = i / 30`` s, ``DEFAULT_FPS``) and ``truth.csv`` (optional), and
    lists the frames of ``left/`` and ``right/``. Images are loaded lazily,
    one frame at a time.

    Parameters
    ----------
    folder : str or Path

    Attributes
    ----------
    folder : Path
    rig : Rig
    markers : MarkerModel
    screen : Screen or None
    times : dict or None
        As :func:`read_times` returns, ``None`` without ``times.csv``.
    truth : dict or None
        frame -> ``(position (3,) mm, axes (3, 3) rows Ξ, Ψ, V)`` in the
        world frame, ``None`` without ``truth.csv``.
    indices : list of int
        Sorted union of the frame indices found in ``left/`` and ``right/``
        (files named ``NNNNNN.png``).
    warnings : list of str
        Problems that do not stop the dataset: ignored files, frames present
        on one side only, gaps, frames without a time, truth for absent
        frames.

    Raises
    ------
    ContractError
        If the folder, ``rig.yaml``, ``left/`` or ``right/`` is missing, or
        any of the YAML/CSV files present is invalid.

    Notes
    -----
    Iterating never raises for a bad image: the frame comes with ``error``
    set and both images ``None``. Images must be 8-bit; a 3- or 4-channel
    8-bit image is converted with ``cv2.cvtColor(..., BGR[A]2GRAY)`` and
    the frame gets a ``warning``; 16-bit images are rejected (``error``).
    Frames missing from ``times.csv`` get a time interpolated linearly from
    the rows present (and a warning).
    """

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            ctx = _Ctx.file(self.folder)
            raise ctx.error(
                "dataset folder not found" if not self.folder.exists() else "is not a folder",
                "a dataset folder holds rig.yaml, left/ and right/",
            )
        self.warnings: list[str] = []
        self.rig: Rig = read_rig(self.folder / "rig.yaml")
        mpath = self.folder / "markers.yaml"
        self.markers: MarkerModel = read_markers(mpath) if mpath.exists() else default_marker_model()
        spath = self.folder / "screen.yaml"
        self.screen: Screen | None = read_screen(spath) if spath.exists() else None

        self._files = {side: self._scan(side) for side in ("left", "right")}
        left, right = self._files["left"], self._files["right"]
        self.indices: list[int] = sorted(left | right)
        self._index_set = set(self.indices)
        for side, other in (("right", left), ("left", right)):
            missing = sorted(other - self._files[side])
            if missing:
                names = [f"{side}/{i:06d}.png" for i in missing]
                self.warnings.append(
                    f"left has {len(left)} frames, right has {len(right)}: "
                    f"{_list_names(names)} missing"
                )
        if not self.indices:
            self.warnings.append("no frames: left/ and right/ hold no NNNNNN.png files")
        else:
            gaps = sorted(set(range(self.indices[0], self.indices[-1] + 1)) - self._index_set)
            if gaps:
                self.warnings.append(
                    "frame indices are not contiguous: "
                    f"{_list_names([f'{i:06d}' for i in gaps])} absent from both left/ and right/"
                )

        tpath = self.folder / "times.csv"
        self.times = read_times(tpath) if tpath.exists() else None
        self._time_note: dict[int, str] = {}
        if self.times is not None:
            self._check_times()

        truth_path = self.folder / "truth.csv"
        self.truth = read_truth(truth_path) if truth_path.exists() else None
        if self.truth is not None:
            extra = sorted(set(self.truth) - self._index_set)
            if extra:
                self.warnings.append(
                    f"truth.csv has rows for frames not in left/ or right/: {_list_names([str(i) for i in extra])}"
                )

    # -- construction helpers ------------------------------------------------

    def _scan(self, side: str) -> set[int]:
        d = self.folder / side
        if not d.is_dir():
            raise _Ctx.file(d).error(
                f"frame directory '{side}/' is missing" if not d.exists() else f"'{side}' is not a directory",
                "a dataset folder holds left/ and right/ with 8-bit gray images NNNNNN.png",
            )
        found: set[int] = set()
        for entry in sorted(d.iterdir()):
            m = _FRAME_NAME.match(entry.name)
            if m and not entry.is_dir():
                found.add(int(m.group(1)))
            else:
                kind = "a directory" if entry.is_dir() else "not a frame file"
                self.warnings.append(
                    f"{side}/{entry.name}: ignored ({kind}; frames are named NNNNNN.png, six digits)"
                )
        return found

    def _check_times(self) -> None:
        assert self.times is not None
        missing = [i for i in self.indices if i not in self.times]
        if missing:
            self.warnings.append(
                "times.csv has no row for frames "
                f"{_list_names([str(i) for i in missing])}: their t is interpolated from the rows present"
            )
            for i in missing:
                self._time_note[i] = "times.csv has no row for this frame; t interpolated"
        extra = [i for i in self.times if i not in self._index_set]
        if extra:
            self.warnings.append(
                f"times.csv has rows for frames not in left/ or right/: {_list_names([str(i) for i in extra])}"
            )
        items = list(self.times.items())
        self._check_right_times(items)
        for (f0, (t0, _)), (f1, (t1, _)) in zip(items, items[1:]):
            if not t1 > t0:
                self.warnings.append(
                    f"times.csv: t does not increase from frame {f0} ({t0:g} s) to frame {f1} ({t1:g} s)"
                )
                break

    def _check_right_times(self, items: list) -> None:
        """One warning when times.csv's t_right lies far from t: a skew of the clocks, not of exposure."""
        offsets = np.array([tr - t for _, (t, tr) in items if tr is not None], dtype=np.float64)
        if not offsets.size:
            return
        ts = np.array([t for _, (t, _) in items], dtype=np.float64)
        steps = np.diff(ts)
        steps = steps[steps > 0]
        period_s = float(np.median(steps)) if steps.size else 1.0 / DEFAULT_FPS
        bound_s = max(MAX_RIGHT_OFFSET_PERIODS * period_s, 0.1)
        far = np.abs(offsets) > bound_s
        if not far.any():
            return
        median_s = float(np.median(offsets[far]))
        size = abs(median_s)
        amount = f"{size:.1f} s" if size >= 1.0 else f"{size * 1e3:.0f} ms"
        side = "after" if median_s > 0 else "before"
        self.warnings.append(
            f"times.csv: the right camera's times are {amount} {side} the left's (t_right - t, median of "
            f"{int(far.sum())} of {offsets.size} rows beyond {bound_s * 1e3:.0f} ms, "
            f"{MAX_RIGHT_OFFSET_PERIODS:g} frame periods): check times.csv / the cameras' clocks; "
            "the tracker gives such frames no pose"
        )

    def _time(self, index: int) -> tuple[float, float | None]:
        if self.times is None:
            return index / DEFAULT_FPS, None
        if index in self.times:
            return self.times[index]
        known = [(f, tt[0]) for f, tt in self.times.items()]
        known_r = [(f, tt[1]) for f, tt in self.times.items() if tt[1] is not None]
        t = _interp_time(known, index)
        t_right = _interp_time(known_r, index) if known_r else None
        return t, t_right

    def _load(self, side: str, index: int) -> tuple[np.ndarray | None, str | None, str | None]:
        """(image, error, warning) of one side of one frame; never raises."""
        name = f"{side}/{index:06d}.png"
        path = self.folder / side / f"{index:06d}.png"
        try:
            if index not in self._files[side]:
                return None, f"{name}: missing", None
            try:
                data = path.read_bytes()         # once: the header's checks, then the decoding, from memory
            except OSError as exc:
                unreachable = _unreachable(path, exc)
                if unreachable is None:
                    raise
                return None, f"{name}: {unreachable}", None
            header, head = data[:24], data[:8]
            if not head:
                return None, f"{name}: unreadable (empty file)", None
            if head != _PNG_SIGNATURE:
                kind = " (it looks like a JPEG)" if head[:3] == b"\xff\xd8\xff" else ""
                return None, f"{name}: unreadable (not a PNG file{kind}; first bytes {head!r})", None
            if header[12:16] == b"IHDR":                 # the size, before decoding what may be gigabytes
                w, h = int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")
                if (w, h) != tuple(self.rig.image_size):
                    rw, rh = self.rig.image_size
                    return None, f"{name}: {w}x{h}, rig says {rw}x{rh}", None
            img = decode_image(data)        # OpenCV never sees the path (io/images.py)
            if img is None:
                return None, f"{name}: unreadable (corrupt or truncated PNG)", None
            warning = None
            if img.dtype != np.uint8:
                bits = img.dtype.itemsize * 8
                return None, f"{name}: {bits}-bit {img.dtype} image, expected 8-bit grayscale", None
            if img.ndim == 3:
                channels = img.shape[2]
                if channels == 1:
                    img = img[:, :, 0]
                elif channels in (3, 4):
                    code = cv2.COLOR_BGR2GRAY if channels == 3 else cv2.COLOR_BGRA2GRAY
                    img = cv2.cvtColor(img, code)
                    warning = f"{name}: {channels}-channel image converted to gray, expected 8-bit grayscale"
                else:
                    return None, f"{name}: {channels}-channel image, expected 8-bit grayscale", None
            elif img.ndim != 2:
                return None, f"{name}: image of shape {img.shape}, expected (height, width)", None
            h, w = img.shape
            rw, rh = self.rig.image_size
            if (w, h) != (rw, rh):
                return None, f"{name}: {w}x{h}, rig says {rw}x{rh}", None
            return np.ascontiguousarray(img), None, warning
        except Exception as exc:  # a bad frame must never stop the others
            return None, f"{name}: unreadable ({type(exc).__name__}: {exc})", None

    # -- public --------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.indices)

    def __iter__(self) -> Iterator[Frame]:
        """Frames in index order; a bad frame has ``error`` set, never raises."""
        for index in self.indices:
            yield self.frame(index)

    def frame(self, index: int) -> Frame:
        """Load one frame.

        Parameters
        ----------
        index : int
            A frame index from ``indices``.

        Returns
        -------
        Frame
            With both images, or with ``error`` set and both images ``None``.

        Raises
        ------
        KeyError
            If ``index`` is not one of ``indices``.
        """
        index = operator.index(index)
        if index not in self._index_set:
            span = f"{self.indices[0]}..{self.indices[-1]}" if self.indices else "none"
            raise KeyError(f"frame {index} is not in dataset {self.folder} (indices {span})")
        t, t_right = self._time(index)
        errors, warnings = [], []
        if index in self._time_note:
            warnings.append(self._time_note[index])
        images = {}
        for side in ("left", "right"):
            img, err, warn = self._load(side, index)
            images[side] = img
            if err:
                errors.append(err)
            if warn:
                warnings.append(warn)
        if errors:
            images = {"left": None, "right": None}
        return Frame(
            index=index,
            t=t,
            t_right=t_right,
            left=images["left"],
            right=images["right"],
            error="; ".join(errors) or None,
            warning="; ".join(warnings) or None,
        )

    def __repr__(self) -> str:
        return f"Dataset({str(self.folder)!r}, {len(self)} frames, {len(self.warnings)} warnings)"

    def inputs(self) -> Inputs:
        """Every file and folder this dataset reads, resolved through links (:class:`~headplod.io.files.Inputs`):
        :func:`folder_inputs` and each frame's image."""
        frames = [self.folder / side / f"{i:06d}.png" for side in ("left", "right") for i in sorted(self._files[side])]
        return folder_inputs(self.folder).files("a frame being read", frames)


#: The files of a dataset folder that its reader reads when present, and how messages name them.
_READ_FILES = (("rig.yaml", "the rig being read"),
               *((name, f"the {name} in the dataset folder being read")
                 for name in ("markers.yaml", "screen.yaml", "times.csv", "truth.csv")))


def folder_inputs(folder: str | Path) -> Inputs:
    """What reading the dataset folder ``folder`` reads, by name, before it is read: the folder, its ``left/``
    and ``right/`` folders (wherever their links lead) and the contract's files present beside them."""
    folder = Path(folder)
    inputs = Inputs().folder("the dataset folder being read", folder)
    for side in ("left", "right"):
        inputs = inputs.folder(f"the {side}/ folder in the dataset folder being read", folder / side)
    for name, what in _READ_FILES:
        if (folder / name).exists():
            inputs = inputs.file(what, folder / name)
    return inputs
