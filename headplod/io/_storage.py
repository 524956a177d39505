"""Reading and writing the files of the headplod contract.

This module is the one place where headplod reads and writes the files that
``spec/conventions.md`` defines: the stereo rig (``rig.yaml``), the marker
model (``markers.yaml``), the screen (``screen.yaml``), a stereo dataset folder
(``left/``, ``right/``, ``times.csv``, ``truth.csv``) and the pose records
(JSON Lines).

Conventions (from the contract)
-------------------------------
- Lengths in mm, times in s, image coordinates in px, angles in degrees in
  every file.
- Camera frame: OpenCV's (x right, y down, z forward). World frame: the left
  camera's frame. A point X in the world (left camera) frame is
  ``R @ X + T`` in the right camera frame.
- Glasses frame G: origin at P1, x toward P0, z out of the wearer's face,
  y = z x x.

Errors
------
Everything that is wrong with a file raises :class:`ContractError` (a
``ValueError``) whose message starts with the file's path, says what is wrong
as expected against actual, and usually ends with ``Hint: ...`` on how to fix
it. Frames of a dataset are the exception: a bad image never raises, it gives
a :class:`Frame` whose ``error`` says what is wrong, so that the other frames
can still be processed. Wrong values handed to a writer by code (NaN in a
pose, a non-rotation) are programming errors and raise ``ValueError``.
"""

from __future__ import annotations

import csv
import json
import math
import operator
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import cv2
import numpy as np

__all__ = [
    "ContractError",
    "Rig",
    "read_rig",
    "write_rig",
    "rig_calibration_std",
    "CALIBRATION_STD_KEYS",
    "MarkerModel",
    "default_marker_model",
    "read_markers",
    "write_markers",
    "Screen",
    "read_screen",
    "write_screen",
    "Frame",
    "Dataset",
    "read_truth",
    "write_truth",
    "read_times",
    "write_times",
    "pose_record",
    "PoseWriter",
    "read_poses",
    "POSE_KEYS",
    "TRUTH_COLUMNS",
    "DEFAULT_FPS",
]

# --------------------------------------------------------------------------
# tolerances and constants
# --------------------------------------------------------------------------

#: Tolerance on ``max |R Rᵀ − I|`` and ``|det R − 1|`` for the rig's R.
ROTATION_TOL = 1e-6
#: Tolerance on the marker model's P1 = origin and P0, P2 on the x axis (mm).
MARKER_TOL_MM = 1e-6
#: Tolerance on the orthonormality of pose axes handed to :func:`pose_record`.
AXES_TOL_WRITE = 1e-6
#: Tolerance on the orthonormality of axes read from text files (truth.csv,
#: pose records), which may have been rounded (6 decimals give ~1e-6).
AXES_TOL_READ = 1e-4
#: A baseline shorter than this (mm) almost surely means T is in metres.
MIN_BASELINE_MM = 1.0
#: Frame rate assumed for frame times when a dataset has no times.csv (Hz).
DEFAULT_FPS = 30.0
#: Numbers of distortion coefficients OpenCV understands.
DIST_COEFF_COUNTS = (4, 5, 8, 12, 14)

#: Keys of a pose record, in the contract's order.
POSE_KEYS = ("frame", "t", "ok", "position", "axes", "cov", "reason")
#: Columns of truth.csv, in order.
TRUTH_COLUMNS = (
    "frame", "x", "y", "z",
    "xi_x", "xi_y", "xi_z",
    "psi_x", "psi_y", "psi_z",
    "v_x", "v_y", "v_z",
)
_TIMES_COLUMNS = ("frame", "t", "t_right")
_RIG_KEYS = ("image_width", "image_height", "K1", "D1", "K2", "D2", "R", "T")
_MARKER_KEYS = ("markers", "diameter")
_SCREEN_KEYS = ("size_px", "top_left", "top_right", "bottom_left")
_FRAME_NAME = re.compile(r"^([0-9]{6})\.png$")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------
# errors
# --------------------------------------------------------------------------


class ContractError(ValueError):
    """A file (or an object) breaks the contract of ``spec/conventions.md``.

    The message names the file (or the object) first, then what is wrong,
    expected against actual, and usually a ``Hint:`` on how to fix it.

    Parameters
    ----------
    message : str
        The full, human-readable message.
    path : str or path-like, optional
        The offending file, ``None`` when the error is about an object built
        in code.

    Attributes
    ----------
    path : str or None
        The offending file as given by the caller, or ``None``.
    """

    def __init__(self, message: str, path: str | Path | None = None):
        super().__init__(message)
        self.path: str | None = None if path is None else str(path)


@dataclass(frozen=True)
class _Ctx:
    """Where a problem is: a file (item 'key') or an object (item 'field')."""

    where: str
    path: str | None
    item: str = "key"

    @classmethod
    def file(cls, path: str | Path) -> "_Ctx":
        return cls(str(path), str(path), "key")

    @classmethod
    def obj(cls, name: str) -> "_Ctx":
        return cls(name, None, "field")

    def name(self, key: str) -> str:
        return f"{self.item} '{key}'"

    def error(self, what: str, hint: str | None = None) -> ContractError:
        msg = f"{self.where}: {what}"
        if hint:
            msg += f". Hint: {hint}"
        return ContractError(msg, self.path)


def _shape_str(a: np.ndarray) -> str:
    if a.ndim == 0:
        return "a scalar"
    if a.ndim == 1:
        return f"a flat list of {a.shape[0]}"
    return "x".join(str(n) for n in a.shape)


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _check_finite(ctx: _Ctx, key: str, a: np.ndarray) -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ctx.error(
            f"{ctx.name(key)} has a non-finite value {a[where]} at index "
            f"{list(where)}, expected finite numbers",
            "recompute or re-export the value; NaN/inf usually means a failed "
            "calibration",
        )


# --------------------------------------------------------------------------
# OpenCV FileStorage helpers
# --------------------------------------------------------------------------


def _cv_message(exc: BaseException) -> str:
    """The useful part of a cv2.error (possibly wrapped in a SystemError)."""
    e: BaseException | None = exc
    while e is not None and not isinstance(e, cv2.error):
        e = e.__cause__ or e.__context__
    text = str(e if e is not None else exc).strip()
    m = re.search(r"in function '(.*)'\s*$", text, re.S)
    if m and ("(" in m.group(1) or ":" in m.group(1)):
        return m.group(1).strip()
    m = re.search(r"error: \(([^)]*)\)\s*(.*)$", text, re.S)
    if m:
        return f"{m.group(2).strip()} ({m.group(1)})"
    return text.splitlines()[-1] if text else type(exc).__name__


def _open_storage(path: str | Path, what: str) -> tuple[cv2.FileStorage, _Ctx]:
    """Open an OpenCV FileStorage file for reading, or raise ContractError."""
    ctx = _Ctx.file(path)
    p = Path(path)
    if not p.exists():
        raise ctx.error("file not found", f"expected {what} here; check the path")
    if p.is_dir():
        raise ctx.error("is a directory, expected a file", f"give the path of {what}")
    if p.stat().st_size == 0:
        raise ctx.error(
            "file is empty, expected OpenCV FileStorage YAML",
            f"write {what} with cv2.FileStorage or headplod.io",
        )
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        raise ctx.error(
            f"cannot be parsed as OpenCV FileStorage YAML: {_cv_message(exc)}",
            "check indentation and brackets near the reported line; the "
            "file should start with '%YAML:1.0' and hold 'key: value' lines "
            "and !!opencv-matrix blocks",
        ) from exc
    if not fs.isOpened():
        raise ctx.error("cannot be opened for reading", "check the file's permissions")
    if not fs.root().isMap():
        raise ctx.error(
            "top level is not a mapping of keys",
            "the file must hold 'key: value' entries at top level",
        )
    return fs, ctx


def _is_matrix_node(node: cv2.FileNode) -> bool:
    if not node.isMap():
        return False
    keys = set(node.keys())
    return {"dt", "data"} <= keys and ({"rows", "cols"} <= keys or "sizes" in keys)


def _node_to_python(node: cv2.FileNode, ctx: _Ctx, key: str) -> Any:
    """Convert a FileNode to int, float, str, ndarray, list or dict."""
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return float(node.real())
    if node.isString():
        return node.string()
    if _is_matrix_node(node):
        try:
            return np.array(node.mat())
        except (cv2.error, SystemError) as exc:
            raise ctx.error(
                f"{ctx.name(key)} is a malformed !!opencv-matrix: {_cv_message(exc)}",
                "rows x cols must equal the number of data values and dt must "
                "be a type code such as 'd'",
            ) from exc
    if node.isSeq():
        return [_node_to_python(node.at(i), ctx, key) for i in range(node.size())]
    if node.isMap():
        return {k: _node_to_python(node.getNode(k), ctx, f"{key}.{k}") for k in node.keys()}
    return None


def _missing_key(ctx: _Ctx, fs: cv2.FileStorage, key: str, hint: str) -> ContractError:
    present = ", ".join(fs.root().keys()) or "none"
    return ctx.error(f"key '{key}' is missing (keys present: {present})", hint)


def _read_numeric(fs: cv2.FileStorage, ctx: _Ctx, key: str, hint: str) -> np.ndarray:
    """A numeric node (matrix, sequence or scalar) as a float64 array."""
    node = fs.getNode(key)
    if node.empty() or node.isNone():
        raise _missing_key(ctx, fs, key, hint)
    value = _node_to_python(node, ctx, key)
    if isinstance(value, str):
        raise ctx.error(f"{ctx.name(key)} is the string {value!r}, expected numbers", hint)
    if isinstance(value, dict):
        raise ctx.error(
            f"{ctx.name(key)} is a mapping with keys {list(value)}, expected a "
            "!!opencv-matrix or a list of numbers",
            hint,
        )
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ctx.error(
            f"{ctx.name(key)} is not a numeric matrix or list ({exc})", hint
        ) from exc
    return arr


def _read_positive_int(fs: cv2.FileStorage, ctx: _Ctx, key: str, hint: str) -> int:
    arr = _read_numeric(fs, ctx, key, hint)
    if arr.size != 1:
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(arr)}, expected one integer", hint)
    return _positive_int(ctx, key, float(arr.reshape(-1)[0]), hint)


def _positive_int(ctx: _Ctx, key: str, value: Any, hint: str | None = None) -> int:
    if isinstance(value, (bool, np.bool_)):
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint)
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint) from None
    if not math.isfinite(f) or f != int(f) or f <= 0:
        raise ctx.error(f"{ctx.name(key)} is {value!r}, expected a positive integer", hint)
    return int(f)


def _open_for_write(path: str | Path) -> cv2.FileStorage:
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    except (cv2.error, SystemError) as exc:
        raise OSError(f"{path}: cannot open for writing: {_cv_message(exc)}") from exc
    if not fs.isOpened():
        raise OSError(f"{path}: cannot open for writing (does the folder exist?)")
    return fs


def _fs_write(fs: cv2.FileStorage, name: str, value: Any) -> None:
    """Write a Python/numpy value to FileStorage (name '' inside sequences)."""
    if isinstance(value, (bool, np.bool_)):
        fs.write(name, int(value))
    elif isinstance(value, (int, np.integer)):
        fs.write(name, int(value))
    elif isinstance(value, (float, np.floating)):
        fs.write(name, float(value))
    elif isinstance(value, str):
        fs.write(name, value)
    elif isinstance(value, np.ndarray):
        a = value
        if a.dtype == np.bool_:
            a = a.astype(np.uint8)
        elif a.dtype.kind in "iu" and a.dtype not in (np.uint8, np.int8, np.uint16, np.int16, np.int32):
            a = a.astype(np.int32) if (a.size == 0 or (a.min() >= -2**31 and a.max() < 2**31)) else a.astype(np.float64)
        elif a.dtype.kind == "f" and a.dtype not in (np.float32, np.float64):
            a = a.astype(np.float64)
        elif a.dtype.kind not in "iuf":
            raise ValueError(f"cannot write array {name!r} of dtype {a.dtype} to FileStorage")
        if a.ndim == 0:
            _fs_write(fs, name, a.item())
            return
        if a.ndim == 1:
            a = a.reshape(1, -1)
        fs.write(name, np.ascontiguousarray(a))
    elif isinstance(value, (list, tuple)):
        flow = all(isinstance(v, (int, float, str, np.number)) for v in value)
        flags = cv2.FileNode_SEQ | (cv2.FileNode_FLOW if flow else 0)
        fs.startWriteStruct(name, flags)
        for v in value:
            _fs_write(fs, "", v)
        fs.endWriteStruct()
    elif isinstance(value, Mapping):
        fs.startWriteStruct(name, cv2.FileNode_MAP)
        for k, v in value.items():
            if not isinstance(k, str):
                raise ValueError(f"cannot write mapping key {k!r} (keys must be str)")
            _fs_write(fs, k, v)
        fs.endWriteStruct()
    else:
        raise ValueError(f"cannot write {name!r} of type {type(value).__name__} to FileStorage")


def _values_equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        try:
            return np.array_equal(np.asarray(a), np.asarray(b))
        except Exception:  # pragma: no cover - odd types
            return False
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return a.keys() == b.keys() and all(_values_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_values_equal(x, y) for x, y in zip(a, b))
    return a == b


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64, copy=True)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------
# Rig
# --------------------------------------------------------------------------

_RIG_HINT = (
    "rig.yaml holds image_width, image_height (px) and K1, D1, K2, D2, R, T "
    "(T in mm) as written by cv2.stereoCalibrate; see spec/conventions.md"
)


def _check_K(ctx: _Ctx, key: str, K: np.ndarray) -> np.ndarray:
    hint = f"{key} is [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in px"
    if K.shape != (3, 3):
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(K)}, expected 3x3", hint)
    _check_finite(ctx, key, K)
    for (i, j) in ((1, 0), (2, 0), (2, 1)):
        if abs(K[i, j]) > 1e-9:
            raise ctx.error(
                f"{ctx.name(key)} is not upper-triangular: {key}[{i},{j}] = "
                f"{_fmt(K[i, j])}, expected 0",
                hint + "; was it written transposed?",
            )
    if abs(K[2, 2] - 1.0) > 1e-9:
        raise ctx.error(f"{ctx.name(key)} has {key}[2,2] = {_fmt(K[2, 2])}, expected 1", hint)
    for (i, label) in ((0, "fx"), (1, "fy")):
        if not K[i, i] > 0:
            raise ctx.error(
                f"{ctx.name(key)} has {label} = {key}[{i},{i}] = {_fmt(K[i, i])}, "
                "expected a positive focal length in px",
                hint,
            )
    return K


def _check_D(ctx: _Ctx, key: str, D: np.ndarray) -> np.ndarray:
    counts = ", ".join(str(n) for n in DIST_COEFF_COUNTS)
    hint = f"{key} holds the distortion coefficients k1 k2 p1 p2 [k3 ...] as a 1xN matrix"
    if D.ndim == 2 and 1 in D.shape:
        flat = D.reshape(-1)
    elif D.ndim == 1:
        flat = D
    else:
        raise ctx.error(
            f"{ctx.name(key)} has shape {_shape_str(D)}, expected 1xN or Nx1 with N in {{{counts}}}",
            hint,
        )
    if flat.size not in DIST_COEFF_COUNTS:
        raise ctx.error(
            f"{ctx.name(key)} has {flat.size} coefficients (shape {_shape_str(D)}), "
            f"expected 1xN or Nx1 with N in {{{counts}}}",
            hint,
        )
    _check_finite(ctx, key, flat)
    return flat


def _check_R(ctx: _Ctx, key: str, R: np.ndarray) -> np.ndarray:
    hint = "R must be the rotation from cv2.stereoCalibrate written with full float64 precision"
    if R.shape != (3, 3):
        extra = "; a 3-vector is a rotation vector: convert it with cv2.Rodrigues" if R.size == 3 else ""
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(R)}, expected 3x3", hint + extra)
    _check_finite(ctx, key, R)
    off = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if off > ROTATION_TOL:
        raise ctx.error(
            f"{ctx.name(key)} is not a rotation: max |R Rᵀ − I| = {off:.3g}, "
            f"expected at most {ROTATION_TOL:g} (det = {det:.9g})",
            hint + "; rounded or hand-edited values are not enough",
        )
    if abs(det - 1.0) > ROTATION_TOL:
        raise ctx.error(
            f"{ctx.name(key)} is not a rotation: det(R) = {det:.9g}, expected +1"
            + (" (a reflection)" if det < 0 else ""),
            hint,
        )
    return R


def _check_vec3(ctx: _Ctx, key: str, v: np.ndarray, hint: str) -> np.ndarray:
    if v.shape not in ((3,), (3, 1), (1, 3)):
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(v)}, expected 3x1 or 1x3", hint)
    v = v.reshape(3)
    _check_finite(ctx, key, v)
    return v


def _check_T(ctx: _Ctx, key: str, T: np.ndarray) -> np.ndarray:
    hint = "T is the left-to-right camera translation of cv2.stereoCalibrate, in mm"
    T = _check_vec3(ctx, key, T, hint)
    b = float(np.linalg.norm(T))
    if b < MIN_BASELINE_MM:
        raise ctx.error(
            f"{ctx.name(key)} gives a baseline |T| = {_fmt(b)} mm, expected at least "
            f"{MIN_BASELINE_MM:g} mm",
            "T must be in mm; if it is in metres, multiply it by 1000",
        )
    return T


def _check_image_size(ctx: _Ctx, size: Any) -> tuple[int, int]:
    hint = "image_size is (width, height) in px"
    try:
        w, h = size
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name('image_size')} is {size!r}, expected (width, height)", hint) from None
    return (_positive_int(ctx, "image_size[0] (width)", w, hint),
            _positive_int(ctx, "image_size[1] (height)", h, hint))


@dataclass(frozen=True, eq=False)
class Rig:
    """A calibrated stereo rig (the content of ``rig.yaml``).

    The world frame is the left camera's (OpenCV) frame. A point ``X`` (mm)
    in the world frame is ``R @ X + T`` in the right camera's frame.

    Parameters
    ----------
    image_size : tuple of int
        ``(width, height)`` of both cameras' images, px.
    K1, K2 : ndarray, shape (3, 3)
        Camera matrices of the left (1) and right (2) cameras, px.
    D1, D2 : ndarray, shape (N,)
        OpenCV distortion coefficients, N in {4, 5, 8, 12, 14}. 1xN and Nx1
        are accepted and flattened.
    R : ndarray, shape (3, 3)
        Rotation from the left to the right camera frame.
    T : ndarray, shape (3,)
        Translation from the left to the right camera frame, mm. 3x1 and
        1x3 are accepted and flattened.
    extra : dict
        Other keys of ``rig.yaml`` (camera identities, rms, ...), kept and
        written back by :func:`write_rig`.
    path : str, optional
        The file the rig was read from.

    Notes
    -----
    The constructor validates like :func:`read_rig` (raising
    :class:`ContractError` naming the object ``Rig``) and stores read-only
    float64 copies of the arrays. Equality compares the values, not ``path``.
    """

    image_size: tuple[int, int]
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    extra: dict = field(default_factory=dict)
    path: str | None = None

    def __post_init__(self) -> None:
        ctx = _Ctx.obj("Rig")
        values = _validate_rig(
            ctx, self.image_size, self.K1, self.D1, self.K2, self.D2, self.R, self.T
        )
        for name, value in values.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "extra", dict(self.extra))
        object.__setattr__(self, "path", None if self.path is None else str(self.path))

    @property
    def baseline_mm(self) -> float:
        """Distance between the two camera centres, mm (``|T|``)."""
        return float(np.linalg.norm(self.T))

    @property
    def right_center_mm(self) -> np.ndarray:
        """Centre of the right camera in the world (left camera) frame, mm.

        Returns
        -------
        ndarray, shape (3,)
            ``-R.T @ T``.
        """
        return -self.R.T @ self.T

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Rig):
            return NotImplemented
        return self.image_size == other.image_size and all(
            np.array_equal(getattr(self, k), getattr(other, k))
            for k in ("K1", "D1", "K2", "D2", "R", "T")
        ) and _values_equal(self.extra, other.extra)

    __hash__ = None  # type: ignore[assignment]


def _validate_rig(ctx: _Ctx, image_size, K1, D1, K2, D2, R, T) -> dict:
    out: dict[str, Any] = {"image_size": _check_image_size(ctx, image_size)}

    def arr(key: str, value: Any) -> np.ndarray:
        try:
            return np.array(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ctx.error(f"{ctx.name(key)} is not numeric ({exc})") from None

    out["K1"] = _check_K(ctx, "K1", arr("K1", K1))
    out["D1"] = _check_D(ctx, "D1", arr("D1", D1))
    out["K2"] = _check_K(ctx, "K2", arr("K2", K2))
    out["D2"] = _check_D(ctx, "D2", arr("D2", D2))
    out["R"] = _check_R(ctx, "R", arr("R", R))
    out["T"] = _check_T(ctx, "T", arr("T", T))
    return {k: (_frozen(v) if isinstance(v, np.ndarray) else v) for k, v in out.items()}


def read_rig(path: str | Path) -> Rig:
    """Read and validate ``rig.yaml``.

    Parameters
    ----------
    path : str or Path
        An OpenCV FileStorage YAML file with ``image_width``,
        ``image_height`` (px, positive integers), ``K1``, ``D1``, ``K2``,
        ``D2``, ``R``, ``T`` (T in mm) and optionally more keys.

    Returns
    -------
    Rig
        With float64 arrays; T as (3,), D as (N,). Other keys are kept in
        ``Rig.extra`` (matrices as ndarrays, sequences as lists).

    Raises
    ------
    ContractError
        If the file is missing, cannot be parsed, lacks a key, or a value
        has the wrong shape, is not finite, K is not upper-triangular with
        positive fx, fy and K[2,2] = 1, R is not a rotation (tolerance
        ``ROTATION_TOL``), or the baseline is under ``MIN_BASELINE_MM``
        (T given in metres). Matrices stored as float32 or integers are
        accepted and converted to float64.
    """
    fs, ctx = _open_storage(path, "the stereo rig (rig.yaml)")
    try:
        w = _read_positive_int(fs, ctx, "image_width", _RIG_HINT)
        h = _read_positive_int(fs, ctx, "image_height", _RIG_HINT)
        raw = {k: _read_numeric(fs, ctx, k, _RIG_HINT) for k in _RIG_KEYS[2:]}
        values = _validate_rig(ctx, (w, h), **raw)
        extra = {
            k: _node_to_python(fs.getNode(k), ctx, k)
            for k in fs.root().keys()
            if k not in _RIG_KEYS
        }
    finally:
        fs.release()
    return Rig(extra=extra, path=str(path), **values)


def write_rig(path: str | Path, rig: Rig) -> None:
    """Write a rig as OpenCV FileStorage YAML (the format of ``rig.yaml``).

    Matrices are written as float64 ``!!opencv-matrix`` with full precision,
    T as 3x1 and D as 1xN, then the keys of ``rig.extra``.

    Parameters
    ----------
    path : str or Path
        Destination file (overwritten).
    rig : Rig

    Raises
    ------
    ValueError
        If ``rig.extra`` reuses a standard key or holds a value FileStorage
        cannot store.
    OSError
        If the file cannot be opened for writing.
    """
    if not isinstance(rig, Rig):
        raise TypeError(f"write_rig needs a Rig, got {type(rig).__name__}")
    clash = [k for k in rig.extra if k in _RIG_KEYS]
    if clash:
        raise ValueError(f"Rig.extra reuses standard rig.yaml keys {clash}")
    fs = _open_for_write(path)
    try:
        fs.write("image_width", int(rig.image_size[0]))
        fs.write("image_height", int(rig.image_size[1]))
        fs.write("K1", np.ascontiguousarray(rig.K1, dtype=np.float64))
        fs.write("D1", np.ascontiguousarray(rig.D1, dtype=np.float64).reshape(1, -1))
        fs.write("K2", np.ascontiguousarray(rig.K2, dtype=np.float64))
        fs.write("D2", np.ascontiguousarray(rig.D2, dtype=np.float64).reshape(1, -1))
        fs.write("R", np.ascontiguousarray(rig.R, dtype=np.float64))
        fs.write("T", np.ascontiguousarray(rig.T, dtype=np.float64).reshape(3, 1))
        for k, v in rig.extra.items():
            _fs_write(fs, k, v)
    except (cv2.error, SystemError) as exc:
        raise ValueError(f"{path}: cannot write rig: {_cv_message(exc)}") from exc
    finally:
        fs.release()


#: Keys of ``rig.yaml`` that ``headplod calibrate`` writes with the
#: calibration's own 1-sigma uncertainty, and the number of values of each:
#: fx, fy, cx, cy of the left / right camera (px); the components of the
#: rotation vector ``cv2.Rodrigues(R)`` (degrees); the components of T (mm).
CALIBRATION_STD_KEYS = {
    "calibration_std_left": 4,
    "calibration_std_right": 4,
    "calibration_std_rotation_deg": 3,
    "calibration_std_translation_mm": 3,
}
_CALIBRATION_STD_MEANING = {
    "calibration_std_left": "fx, fy, cx, cy of the left camera, px",
    "calibration_std_right": "fx, fy, cx, cy of the right camera, px",
    "calibration_std_rotation_deg": "the components of the rotation vector cv2.Rodrigues(R), degrees",
    "calibration_std_translation_mm": "the components of T, mm",
}


def rig_calibration_std(rig: Rig) -> dict[str, np.ndarray] | None:
    """The calibration's own uncertainty stored in a rig's extra keys.

    ``headplod calibrate`` writes the 1-sigma (standard deviation) of the
    estimate into ``rig.yaml`` (see :data:`CALIBRATION_STD_KEYS`) so that
    a tracker can use it as a prior:

    - ``calibration_std_left``, ``calibration_std_right``: (4,) fx, fy, cx,
      cy, px (stored as 1x4 matrices);
    - ``calibration_std_rotation_deg``: (3,) the components of the rotation
      vector ``cv2.Rodrigues(R)``, degrees (1x3);
    - ``calibration_std_translation_mm``: (3,) the components of T, mm
      (1x3).

    Either orientation (1xN, Nx1) or a flat list is accepted.

    Parameters
    ----------
    rig : Rig

    Returns
    -------
    dict of key -> float64 ndarray, or None
        None when the rig has none of these keys (e.g. a hand-made rig.yaml);
        otherwise the keys present, each a flat read-only array of 4 or 3
        finite, non-negative values. Missing keys are absent from the dict.

    Raises
    ------
    ContractError
        A key present with the wrong number of values, a string or a
        mapping, a non-finite or a negative value. The message names the
        file (``rig.path``; ``Rig.extra`` for a rig built in code) and the key.
    """
    if not isinstance(rig, Rig):
        raise TypeError(f"rig_calibration_std needs a Rig, got {type(rig).__name__}")
    ctx = _Ctx.file(rig.path) if rig.path is not None else _Ctx("Rig.extra", None, "key")
    out: dict[str, np.ndarray] = {}
    for key, n in CALIBRATION_STD_KEYS.items():
        if key not in rig.extra:
            continue
        value = rig.extra[key]
        hint = (f"{key} holds the 1-sigma of {_CALIBRATION_STD_MEANING[key]}, as a 1x{n} matrix; "
                "recalibrate with 'headplod calibrate' or delete the key")
        if isinstance(value, (str, Mapping)) or value is None:
            what = f"the string {value!r}" if isinstance(value, str) else (
                "a mapping" if isinstance(value, Mapping) else "empty")
            raise ctx.error(f"{ctx.name(key)} is {what}, expected {n} numbers", hint)
        try:
            a = np.array(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ctx.error(f"{ctx.name(key)} is not numeric ({exc})", hint) from None
        if not (a.ndim <= 2 and a.size == n and (a.ndim < 2 or 1 in a.shape)):
            raise ctx.error(
                f"{ctx.name(key)} has shape {_shape_str(a)}, expected 1x{n}, {n}x1 or a flat list of {n}",
                hint)
        a = a.reshape(n)
        _check_finite(ctx, key, a)
        if (a < 0).any():
            i = int(np.argmax(a < 0))
            raise ctx.error(
                f"{ctx.name(key)} has a negative value {_fmt(a[i])} at index {i}, expected standard "
                "deviations >= 0", hint)
        out[key] = _frozen(a)
    return out or None


# --------------------------------------------------------------------------
# Marker model
# --------------------------------------------------------------------------

_MARKER_HINT = (
    "markers is a 5x3 matrix of P0..P4 in the glasses frame G (mm) with P1 at "
    "the origin and P0 (x > 0), P2 (x < 0) on G's x axis; see spec/conventions.md"
)
#: Triangles whose normals define V (indices into P0..P4).
_V_TRIANGLES = ((0, 1, 3), (1, 2, 4), (1, 3, 4))

_DEFAULT_MARKERS_MM = np.array(
    [[65.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-65.0, 0.0, 0.0], [40.0, -30.0, 0.0], [-40.0, -30.0, 0.0]]
)


def _oriented_normals(P: np.ndarray) -> list[np.ndarray]:
    normals = []
    for a, b, c in _V_TRIANGLES:
        n = np.cross(P[b] - P[a], P[c] - P[a])
        n = n / np.linalg.norm(n)
        normals.append(-n if n[2] < 0 else n)
    return normals


def _validate_markers(ctx: _Ctx, points: Any, diameter: Any) -> tuple[np.ndarray, float]:
    try:
        P = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ctx.error(f"{ctx.name('markers')} is not numeric ({exc})", _MARKER_HINT) from None
    if P.shape != (5, 3):
        hint = _MARKER_HINT + ("; this looks transposed" if P.shape == (3, 5) else "")
        raise ctx.error(f"{ctx.name('markers')} has shape {_shape_str(P)}, expected 5x3", hint)
    _check_finite(ctx, "markers", P)
    tol = MARKER_TOL_MM
    if np.abs(P[1]).max() > tol:
        raise ctx.error(
            f"P1 (the bridge) is at {P[1].tolist()} mm, expected the origin [0, 0, 0] "
            f"(tolerance {tol:g} mm)",
            "subtract P1 from every marker so that G's origin is at P1",
        )
    for i in (0, 2):
        if max(abs(P[i, 1]), abs(P[i, 2])) > tol:
            raise ctx.error(
                f"P{i} is at {P[i].tolist()} mm, expected on G's x axis (y = z = 0, "
                f"tolerance {tol:g} mm)",
                "rotate the model so that P0 - P1 lies along +x; P0, P1, P2 are collinear",
            )
    if not P[0, 0] > 0:
        raise ctx.error(f"P0 has x = {_fmt(P[0, 0])} mm, expected x > 0 (G's x points toward P0)",
                        _MARKER_HINT)
    if not P[2, 0] < 0:
        raise ctx.error(f"P2 has x = {_fmt(P[2, 0])} mm, expected x < 0 (P1 lies between P0 and P2)",
                        _MARKER_HINT)
    for i in (3, 4):
        if math.hypot(P[i, 1], P[i, 2]) <= tol:
            raise ctx.error(
                f"P{i} is at {P[i].tolist()} mm, on G's x axis, expected off the line P0-P1-P2",
                "P3 and P4 sit below the bridge line (default y = -30 mm)",
            )
    for tri in _V_TRIANGLES:
        a, b, c = (P[i] for i in tri)
        n = np.cross(b - a, c - a)
        scale = np.linalg.norm(b - a) * np.linalg.norm(c - a)
        name = "(" + ", ".join(f"P{i}" for i in tri) + ")"
        if np.linalg.norm(n) <= 1e-9 * scale:
            raise ctx.error(f"triangle {name} is degenerate (its markers are collinear)",
                            "the viewing direction V needs three non-collinear markers per triangle")
        if abs(n[2]) <= 1e-6 * np.linalg.norm(n):
            raise ctx.error(
                f"triangle {name} is perpendicular to G's x-y plane (its normal has z = 0), "
                "so its normal cannot be turned to G's +z",
                "move P3/P4 so that each triangle faces forward",
            )
    V = np.mean(_oriented_normals(P), axis=0)
    if np.linalg.norm(V) < 1e-6:
        raise ctx.error("the mean of the triangle normals is zero, so V is undefined", _MARKER_HINT)
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name('diameter')} is {diameter!r}, expected a positive number (mm)") from None
    if not (math.isfinite(d) and d > 0):
        raise ctx.error(f"{ctx.name('diameter')} is {_fmt(d)}, expected a positive marker diameter in mm")
    return P, d


@dataclass(frozen=True, eq=False)
class MarkerModel:
    """The glasses' five markers in the glasses frame G.

    Parameters
    ----------
    points_mm : ndarray, shape (5, 3)
        P0..P4 in G, mm: P1 at the origin, P0 (x > 0) and P2 (x < 0) on G's
        x axis, P3 and P4 off that axis (may lie off z = 0 for a curved frame).
    diameter_mm : float
        Marker disk diameter, mm.

    Notes
    -----
    The constructor validates like :func:`read_markers`. Equality compares
    values.
    """

    points_mm: np.ndarray
    diameter_mm: float = 6.0

    def __post_init__(self) -> None:
        P, d = _validate_markers(_Ctx.obj("MarkerModel"), self.points_mm, self.diameter_mm)
        object.__setattr__(self, "points_mm", _frozen(P))
        object.__setattr__(self, "diameter_mm", d)

    @property
    def view_dir_G(self) -> np.ndarray:
        """The viewing direction V in G (unit, shape (3,)).

        The normalized mean of the unit normals of the triangles
        (P0, P1, P3), (P1, P2, P4) and (P1, P3, P4), each turned to G's +z
        side. ``(0, 0, 1)`` for the default model.
        """
        V = np.mean(_oriented_normals(self.points_mm), axis=0)
        return V / np.linalg.norm(V)

    @property
    def axes_G(self) -> np.ndarray:
        """The head axes in G: rows Ξ, Ψ, V (shape (3, 3)).

        Ξ is P0 − P1 with its component along V removed, normalized;
        Ψ = V × Ξ. For any rotation ``R_wg`` (G to world), the contract's
        ``axes`` are ``axes_G @ R_wg.T``. The identity for the default model.
        """
        V = self.view_dir_G
        x = self.points_mm[0] - self.points_mm[1]
        xi = x - np.dot(x, V) * V
        xi = xi / np.linalg.norm(xi)
        return np.array([xi, np.cross(V, xi), V])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MarkerModel):
            return NotImplemented
        return np.array_equal(self.points_mm, other.points_mm) and self.diameter_mm == other.diameter_mm

    __hash__ = None  # type: ignore[assignment]


def default_marker_model() -> MarkerModel:
    """The contract's default model (P0..P4 of ``spec/conventions.md``, 6 mm disks)."""
    return MarkerModel(_DEFAULT_MARKERS_MM.copy(), 6.0)


def read_markers(path: str | Path) -> MarkerModel:
    """Read and validate ``markers.yaml``.

    Parameters
    ----------
    path : str or Path
        OpenCV FileStorage YAML with key ``markers`` (5x3, rows P0..P4 in G,
        mm) and optional ``diameter`` (mm, default 6).

    Returns
    -------
    MarkerModel

    Raises
    ------
    ContractError
        On a missing or malformed file, a wrong shape, non-finite values,
        P1 not at the origin or P0/P2 off G's x axis (tolerance
        ``MARKER_TOL_MM``), P0.x <= 0 or P2.x >= 0, P3/P4 on the x axis,
        a triangle whose normal cannot be oriented, a non-positive
        diameter, or an unknown key (so that a misspelt ``diameter`` is not
        silently replaced by the default).
    """
    fs, ctx = _open_storage(path, "the marker model (markers.yaml)")
    try:
        unknown = [k for k in fs.root().keys() if k not in _MARKER_KEYS]
        if unknown:
            raise ctx.error(
                f"unknown key(s) {unknown}, expected only 'markers' and optional 'diameter'",
                "fix the spelling or remove the key",
            )
        P = _read_numeric(fs, ctx, "markers", _MARKER_HINT)
        node = fs.getNode("diameter")
        if node.empty() or node.isNone():
            d: Any = 6.0
        else:
            darr = _read_numeric(fs, ctx, "diameter", "diameter is the marker disk diameter in mm")
            if darr.size != 1:
                raise ctx.error(f"key 'diameter' has shape {_shape_str(darr)}, expected one number (mm)")
            d = float(darr.reshape(-1)[0])
        P, d = _validate_markers(ctx, P, d)
    finally:
        fs.release()
    return MarkerModel(P, d)


def write_markers(path: str | Path, model: MarkerModel) -> None:
    """Write a marker model as ``markers.yaml`` (5x3 float64 ``markers``, ``diameter`` mm)."""
    if not isinstance(model, MarkerModel):
        raise TypeError(f"write_markers needs a MarkerModel, got {type(model).__name__}")
    fs = _open_for_write(path)
    try:
        fs.write("markers", np.ascontiguousarray(model.points_mm, dtype=np.float64))
        fs.write("diameter", float(model.diameter_mm))
    finally:
        fs.release()


# --------------------------------------------------------------------------
# Screen
# --------------------------------------------------------------------------

_SCREEN_HINT = (
    "screen.yaml holds size_px (width, height) and the corners top_left, "
    "top_right, bottom_left of the visible image in the world frame, mm"
)


def _validate_screen(ctx: _Ctx, size_px, tl, tr, bl) -> dict:
    try:
        size = np.array(size_px, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ctx.error(f"{ctx.name('size_px')} is {size_px!r}, expected (width, height) in px",
                        _SCREEN_HINT) from None
    if size.size != 2:
        raise ctx.error(f"{ctx.name('size_px')} has {size.size} values, expected 2 (width, height)",
                        _SCREEN_HINT)
    w = _positive_int(ctx, "size_px[0] (width)", size[0], _SCREEN_HINT)
    h = _positive_int(ctx, "size_px[1] (height)", size[1], _SCREEN_HINT)
    corners = {}
    for key, v in (("top_left", tl), ("top_right", tr), ("bottom_left", bl)):
        try:
            a = np.array(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ctx.error(f"{ctx.name(key)} is not numeric", _SCREEN_HINT) from None
        corners[key] = _check_vec3(ctx, key, a, _SCREEN_HINT)
    a = corners["top_right"] - corners["top_left"]
    b = corners["bottom_left"] - corners["top_left"]
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na < 1e-9 or nb < 1e-9 or np.linalg.norm(np.cross(a, b)) <= 1e-9 * na * nb:
        raise ctx.error(
            "the corners do not span a plane: top_right − top_left = "
            f"{a.tolist()} mm and bottom_left − top_left = {b.tolist()} mm are zero or parallel",
            _SCREEN_HINT,
        )
    return {"size_px": (w, h), **{k: _frozen(v) for k, v in corners.items()}}


@dataclass(frozen=True, eq=False)
class Screen:
    """The display: its pixel size and three corners in the world frame.

    Screen pixel (x, y) is at
    ``top_left + (x / w) (top_right − top_left) + (y / h) (bottom_left − top_left)``
    (mm, world frame), with ``(w, h) = size_px``.

    Parameters
    ----------
    size_px : tuple of int
        ``(width, height)`` of the visible image, px.
    top_left, top_right, bottom_left : ndarray, shape (3,)
        Corners of the visible image area in the world frame, mm.
    """

    size_px: tuple[int, int]
    top_left: np.ndarray
    top_right: np.ndarray
    bottom_left: np.ndarray

    def __post_init__(self) -> None:
        v = _validate_screen(_Ctx.obj("Screen"), self.size_px, self.top_left, self.top_right,
                             self.bottom_left)
        for k, x in v.items():
            object.__setattr__(self, k, x)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the screen plane, (top_right − top_left) × (bottom_left − top_left)."""
        n = np.cross(self.top_right - self.top_left, self.bottom_left - self.top_left)
        return n / np.linalg.norm(n)

    def pixel_to_world(self, xy_px: Any) -> np.ndarray:
        """World position (mm) of screen pixels.

        Parameters
        ----------
        xy_px : array_like, shape (..., 2)
            Screen pixel coordinates (x, y), px.

        Returns
        -------
        ndarray, shape (..., 3)
            Points in the world frame, mm.
        """
        xy = np.asarray(xy_px, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"pixel_to_world needs shape (..., 2), got {xy.shape}")
        w, h = self.size_px
        a = (self.top_right - self.top_left) / w
        b = (self.bottom_left - self.top_left) / h
        return self.top_left + xy[..., :1] * a + xy[..., 1:2] * b

    def intersect_ray(self, origin_mm: Any, direction: Any) -> np.ndarray | None:
        """Screen pixel where a ray meets the screen plane.

        Parameters
        ----------
        origin_mm : array_like, shape (3,)
            Ray origin in the world frame, mm (e.g. the head position).
        direction : array_like, shape (3,)
            Ray direction in the world frame (e.g. V); need not be unit.

        Returns
        -------
        ndarray, shape (2,) or None
            Screen pixel (x, y), px, of the intersection with the (infinite)
            screen plane; it may lie outside ``[0, w] x [0, h]``. ``None``
            when the ray is parallel to the plane or the plane is behind the
            origin.
        """
        o = np.asarray(origin_mm, dtype=np.float64).reshape(-1)
        d = np.asarray(direction, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or d.shape != (3,):
            raise ValueError(f"intersect_ray needs two 3-vectors, got {o.shape} and {d.shape}")
        if not (np.isfinite(o).all() and np.isfinite(d).all()):
            raise ValueError("intersect_ray: origin and direction must be finite")
        nd = np.linalg.norm(d)
        if nd == 0:
            raise ValueError("intersect_ray: direction is the zero vector")
        n = self.normal
        denom = float(np.dot(n, d)) / nd
        if abs(denom) < 1e-12:
            return None
        s = float(np.dot(n, self.top_left - o)) / float(np.dot(n, d))
        if not s > 0:
            return None
        w, h = self.size_px
        M = np.column_stack([(self.top_right - self.top_left) / w,
                             (self.bottom_left - self.top_left) / h])
        p = o + s * d - self.top_left
        xy, *_ = np.linalg.lstsq(M, p, rcond=None)
        return xy

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Screen):
            return NotImplemented
        return self.size_px == other.size_px and all(
            np.array_equal(getattr(self, k), getattr(other, k))
            for k in ("top_left", "top_right", "bottom_left")
        )

    __hash__ = None  # type: ignore[assignment]


def read_screen(path: str | Path) -> Screen:
    """Read and validate ``screen.yaml``.

    Parameters
    ----------
    path : str or Path
        OpenCV FileStorage YAML with ``size_px`` (width, height; a sequence
        or a 1x2/2x1 matrix of positive integers, px) and ``top_left``,
        ``top_right``, ``bottom_left`` (3-vectors, world frame, mm). Other
        keys are ignored.

    Returns
    -------
    Screen

    Raises
    ------
    ContractError
        On a missing or malformed file, a missing key, wrong shapes,
        non-finite or non-integer values, or corners that do not span a
        plane.
    """
    fs, ctx = _open_storage(path, "the screen (screen.yaml)")
    try:
        raw = {k: _read_numeric(fs, ctx, k, _SCREEN_HINT) for k in _SCREEN_KEYS}
        v = _validate_screen(ctx, raw["size_px"], raw["top_left"], raw["top_right"], raw["bottom_left"])
    finally:
        fs.release()
    return Screen(**v)


def write_screen(path: str | Path, screen: Screen) -> None:
    """Write ``screen.yaml``: ``size_px`` as ``[w, h]``, corners as 3x1 float64 (mm)."""
    if not isinstance(screen, Screen):
        raise TypeError(f"write_screen needs a Screen, got {type(screen).__name__}")
    fs = _open_for_write(path)
    try:
        _fs_write(fs, "size_px", [int(screen.size_px[0]), int(screen.size_px[1])])
        for k in ("top_left", "top_right", "bottom_left"):
            fs.write(k, np.ascontiguousarray(getattr(screen, k), dtype=np.float64).reshape(3, 1))
    finally:
        fs.release()


# --------------------------------------------------------------------------
# CSV files: times.csv, truth.csv
# --------------------------------------------------------------------------


def _read_csv_rows(path: str | Path, headers: Iterable[tuple[str, ...]], hint: str):
    """Yield (line number, header, fields) of a small CSV file after checks."""
    ctx = _Ctx.file(path)
    p = Path(path)
    if not p.is_file():
        raise ctx.error("file not found" if not p.exists() else "is not a file", hint)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ctx.error(f"is not UTF-8 text ({exc.reason} at byte {exc.start})", hint) from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip()]
    if not lines:
        raise ctx.error("file is empty, expected a header line", hint)
    header_line, header_text = lines[0]
    header = tuple(h.strip() for h in next(csv.reader([header_text])))
    allowed = list(headers)
    if header not in allowed:
        expected = " or ".join(repr(",".join(h)) for h in allowed)
        raise ctx.error(f"header is {','.join(header)!r}, expected {expected}", hint)
    rows = []
    for lineno, line in lines[1:]:
        fields = [f.strip() for f in next(csv.reader([line]))]
        rows.append((lineno, fields))
    return ctx, header, rows


def _csv_frame(ctx: _Ctx, lineno: int, text: str) -> int:
    if not re.fullmatch(r"[0-9]+", text):
        raise ctx.error(f"line {lineno}: frame is {text!r}, expected a non-negative integer")
    return int(text)


def _csv_float(ctx: _Ctx, lineno: int, column: str, text: str, unit: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise ctx.error(f"line {lineno}: column '{column}' is {text!r}, expected a number ({unit})") from None
    if not math.isfinite(v):
        raise ctx.error(f"line {lineno}: column '{column}' is {text!r}, expected a finite number ({unit})")
    return v


def read_times(path: str | Path) -> dict[int, tuple[float, float | None]]:
    """Read ``times.csv``: ``frame,t[,t_right]``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        frame index -> ``(t, t_right)``, s: mid-exposure of the left image and
        of the right one (``None`` when the column is absent or the cell
        empty, meaning the same as ``t``). Sorted by frame.

    Raises
    ------
    ContractError
        On a missing file, a wrong header, a wrong number of fields, a
        non-integer frame, a non-numeric or non-finite time, or a repeated
        frame.
    """
    hint = "times.csv has the header 'frame,t' or 'frame,t,t_right' and one row per frame, times in s"
    ctx, header, rows = _read_csv_rows(path, [_TIMES_COLUMNS[:2], _TIMES_COLUMNS], hint)
    out: dict[int, tuple[float, float | None]] = {}
    for lineno, f in rows:
        if not (len(f) == len(header) or (len(header) == 3 and len(f) == 2)):
            raise ctx.error(f"line {lineno}: {len(f)} fields, expected {len(header)} ({','.join(header)})", hint)
        frame = _csv_frame(ctx, lineno, f[0])
        if frame in out:
            raise ctx.error(f"line {lineno}: frame {frame} appears twice", "keep one row per frame")
        t = _csv_float(ctx, lineno, "t", f[1], "s")
        t_right = _csv_float(ctx, lineno, "t_right", f[2], "s") if len(f) == 3 and f[2] != "" else None
        out[frame] = (t, t_right)
    return dict(sorted(out.items()))


def write_times(path: str | Path, times: Mapping[int, Any]) -> None:
    """Write ``times.csv``.

    Parameters
    ----------
    path : str or Path
    times : mapping
        frame index -> ``t`` or ``(t, t_right)`` (s; ``t_right`` may be
        ``None``). The ``t_right`` column is written only when some frame has
        one. Floats are written with full (round-trip) precision.
    """
    rows = []
    for frame, v in sorted(times.items()):
        t, t_right = (v, None) if np.ndim(v) == 0 else (tuple(v) + (None,))[:2]
        t = float(t)
        t_right = None if t_right is None else float(t_right)
        if not math.isfinite(t) or (t_right is not None and not math.isfinite(t_right)):
            raise ValueError(f"write_times: frame {frame} has a non-finite time {v!r}")
        rows.append((operator.index(frame), t, t_right))
    with_right = any(r[2] is not None for r in rows)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        fh.write(",".join(_TIMES_COLUMNS if with_right else _TIMES_COLUMNS[:2]) + "\n")
        for frame, t, t_right in rows:
            cells = [str(frame), repr(t)]
            if with_right:
                cells.append("" if t_right is None else repr(t_right))
            fh.write(",".join(cells) + "\n")


def _check_axes(axes: np.ndarray, tol: float) -> str | None:
    """None if axes (rows Ξ, Ψ, V) are orthonormal and right-handed, else why not."""
    off = float(np.abs(axes @ axes.T - np.eye(3)).max())
    if off > tol:
        return f"axes rows are not orthonormal: max |A Aᵀ − I| = {off:.3g}, tolerance {tol:g}"
    det = float(np.linalg.det(axes))
    if det < 0:
        return f"axes are left-handed: det = {det:.6g}, expected +1 (Ψ must be V × Ξ)"
    return None


def read_truth(path: str | Path) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Read ``truth.csv``.

    Parameters
    ----------
    path : str or Path
        CSV with header ``frame,x,y,z,xi_x,xi_y,xi_z,psi_x,psi_y,psi_z,v_x,v_y,v_z``.

    Returns
    -------
    dict
        frame index -> ``(position, axes)``: position of P1 in the world
        frame, mm, shape (3,); axes with rows Ξ, Ψ, V in the world frame,
        shape (3, 3). Values as written (not re-orthonormalized). Sorted by
        frame.

    Raises
    ------
    ContractError
        On a missing file, a wrong header or field count, a non-numeric or
        non-finite value, a repeated frame, or axes that are not orthonormal
        (tolerance ``AXES_TOL_READ``) or left-handed.
    """
    hint = "truth.csv has the header " + ",".join(TRUTH_COLUMNS) + " (mm, unit axes rows Ξ, Ψ, V)"
    ctx, header, rows = _read_csv_rows(path, [TRUTH_COLUMNS], hint)
    out: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for lineno, f in rows:
        if len(f) != len(TRUTH_COLUMNS):
            raise ctx.error(f"line {lineno}: {len(f)} fields, expected {len(TRUTH_COLUMNS)}", hint)
        frame = _csv_frame(ctx, lineno, f[0])
        if frame in out:
            raise ctx.error(f"line {lineno}: frame {frame} appears twice", "keep one row per frame")
        vals = np.array([_csv_float(ctx, lineno, c, x, "mm" if c in "xyz" else "unit vector")
                         for c, x in zip(TRUTH_COLUMNS[1:], f[1:])])
        axes = vals[3:].reshape(3, 3)
        why = _check_axes(axes, AXES_TOL_READ)
        if why:
            raise ctx.error(f"line {lineno} (frame {frame}): {why}",
                            "write unit vectors Ξ, Ψ, V with at least 6 decimals")
        out[frame] = (vals[:3].copy(), axes.copy())
    return dict(sorted(out.items()))


def write_truth(path: str | Path, rows: Mapping[int, tuple[Any, Any]] | Iterable[tuple[int, Any, Any]]) -> None:
    """Write ``truth.csv``.

    Parameters
    ----------
    path : str or Path
    rows : mapping or iterable
        Either frame -> ``(position, axes)`` (as :func:`read_truth` returns)
        or an iterable of ``(frame, position, axes)``; position (3,) mm,
        axes (3, 3) rows Ξ, Ψ, V in the world frame. Written sorted by frame
        with full (round-trip) precision.

    Raises
    ------
    ValueError
        On wrong shapes, non-finite values, non-orthonormal or left-handed
        axes (tolerance ``AXES_TOL_WRITE``), or a repeated frame.
    """
    items = list(rows.items()) if isinstance(rows, Mapping) else [(r[0], (r[1], r[2])) for r in rows]
    seen = set()
    lines = [",".join(TRUTH_COLUMNS)]
    for frame, (pos, axes) in sorted(items, key=lambda kv: kv[0]):
        frame = operator.index(frame)
        if frame in seen:
            raise ValueError(f"write_truth: frame {frame} appears twice")
        seen.add(frame)
        p = np.asarray(pos, dtype=np.float64).reshape(-1)
        A = np.asarray(axes, dtype=np.float64)
        if p.shape != (3,) or A.shape != (3, 3):
            raise ValueError(f"write_truth: frame {frame}: position shape {p.shape}, axes shape {A.shape}; "
                             "expected (3,) and (3, 3)")
        if not (np.isfinite(p).all() and np.isfinite(A).all()):
            raise ValueError(f"write_truth: frame {frame}: non-finite values")
        why = _check_axes(A, AXES_TOL_WRITE)
        if why:
            raise ValueError(f"write_truth: frame {frame}: {why}")
        lines.append(",".join([str(frame)] + [repr(float(x)) for x in np.concatenate([p, A.reshape(-1)])]))
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


# --------------------------------------------------------------------------
# Dataset folder
# --------------------------------------------------------------------------


@dataclass
class Frame:
    """One stereo frame of a dataset.

    Attributes
    ----------
    index : int
        Frame index (the six digits of the file names).
    t : float
        Mid-exposure time of the left image, s.
    t_right : float or None
        Mid-exposure time of the right image, s, when it differs from ``t``.
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
        for (f0, (t0, _)), (f1, (t1, _)) in zip(items, items[1:]):
            if not t1 > t0:
                self.warnings.append(
                    f"times.csv: t does not increase from frame {f0} ({t0:g} s) to frame {f1} ({t1:g} s)"
                )
                break

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
            if index not in self._files[side] or not path.exists():
                return None, f"{name}: missing", None
            with open(path, "rb") as fh:
                head = fh.read(8)
            if not head:
                return None, f"{name}: unreadable (empty file)", None
            if head != _PNG_SIGNATURE:
                kind = " (it looks like a JPEG)" if head[:3] == b"\xff\xd8\xff" else ""
                return None, f"{name}: unreadable (not a PNG file{kind}; first bytes {head!r})", None
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
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


# --------------------------------------------------------------------------
# Pose records (JSON Lines)
# --------------------------------------------------------------------------


def _jsonable(value: Any, key: str) -> Any:
    """Convert numpy and containers to JSON-native values; NaN/inf -> None."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist(), key)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v, key) for v in value]
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ValueError(f"pose record key {key!r}: mapping key {k!r} is not a str")
            out[k] = _jsonable(v, key)
        return out
    if isinstance(value, Path):
        return str(value)
    raise ValueError(f"pose record key {key!r}: {type(value).__name__} is not JSON-serializable")


def _as_float_array(value: Any, name: str, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"pose record: {name} is not numeric: {value!r}") from None
    if a.shape != shape:
        if name == "position" and a.size == 3:
            a = a.reshape(3)
        else:
            raise ValueError(f"pose record: {name} has shape {a.shape}, expected {shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"pose record: {name} has NaN or inf: {a.tolist()}")
    return a


def _build_record(frame, t, ok, position, axes, cov, reason, extra, axes_tol) -> dict:
    if isinstance(frame, (bool, np.bool_)):
        raise ValueError(f"pose record: frame is {frame!r}, expected a non-negative int")
    try:
        frame = operator.index(frame)
    except TypeError:
        raise ValueError(f"pose record: frame is {frame!r}, expected a non-negative int") from None
    if frame < 0:
        raise ValueError(f"pose record: frame is {frame}, expected a non-negative int")
    if isinstance(t, (bool, np.bool_)):
        raise ValueError(f"pose record: t is {t!r}, expected a finite time in s")
    try:
        t = float(t)
    except (TypeError, ValueError):
        raise ValueError(f"pose record: t is {t!r}, expected a finite time in s") from None
    if not math.isfinite(t):
        raise ValueError(f"pose record: t is {t}, expected a finite time in s")
    if not isinstance(ok, (bool, np.bool_)):
        raise ValueError(f"pose record: ok is {ok!r}, expected True or False")
    ok = bool(ok)
    if ok:
        if position is None or axes is None or cov is None:
            missing = [n for n, v in (("position", position), ("axes", axes), ("cov", cov)) if v is None]
            raise ValueError(f"pose record: ok=True needs position, axes and cov; missing {missing}")
        p = _as_float_array(position, "position", (3,))
        A = _as_float_array(axes, "axes", (3, 3))
        why = _check_axes(A, axes_tol)
        if why:
            raise ValueError(f"pose record: {why}")
        C = _as_float_array(cov, "cov", (2, 2))
        if abs(C[0, 1] - C[1, 0]) > 1e-9 * max(1.0, float(np.abs(C).max())):
            raise ValueError(f"pose record: cov is not symmetric: {C.tolist()}")
        if not (C[0, 0] > 0 and C[1, 1] > 0 and np.linalg.det(C) > 0):
            raise ValueError(f"pose record: cov is not positive definite: {C.tolist()} (deg²)")
        if reason is not None and not isinstance(reason, str):
            raise ValueError(f"pose record: reason is {reason!r}, expected None or a str")
        pos_out, axes_out, cov_out = p.tolist(), A.tolist(), C.tolist()
    else:
        given = [n for n, v in (("position", position), ("axes", axes), ("cov", cov)) if v is not None]
        if given:
            raise ValueError(
                f"pose record: ok=False must carry no pose, but {given} given; "
                "put diagnostic values in extra keys"
            )
        if not isinstance(reason, str) or not reason.strip():
            raise ValueError(
                f"pose record: ok=False needs a non-empty reason a person can act on, got {reason!r}"
            )
        pos_out = axes_out = cov_out = None
    rec = {
        "frame": frame,
        "t": t,
        "ok": ok,
        "position": pos_out,
        "axes": axes_out,
        "cov": cov_out,
        "reason": reason,
    }
    for k, v in extra.items():
        if k in rec:
            raise ValueError(f"pose record: extra key {k!r} clashes with a standard key")
        rec[k] = _jsonable(v, k)
    return rec


def pose_record(frame: int, t: float, ok: bool, position: Any = None, axes: Any = None,
                cov: Any = None, reason: str | None = None, **extra: Any) -> dict:
    """Build one pose record, JSON-ready, in the contract's key order.

    Parameters
    ----------
    frame : int
        Frame index (>= 0).
    t : float
        Frame time, s (finite).
    ok : bool
        Whether the record carries a pose.
    position : array_like, shape (3,), optional
        P1 in the world frame, mm. Required when ``ok``.
    axes : array_like, shape (3, 3), optional
        Rows Ξ, Ψ, V in the world frame; orthonormal and right-handed
        within ``AXES_TOL_WRITE``. Required when ``ok``.
    cov : array_like, shape (2, 2), optional
        Covariance of (φ, θ), deg², symmetric positive definite. Required
        when ``ok``.
    reason : str, optional
        Required and non-empty when not ``ok`` (something a person can act
        on); may be ``None`` or a note when ``ok``.
    **extra
        More keys (timings, POI, residuals), after the standard ones.
        numpy values become lists/ints/floats; NaN or inf inside extra
        values become ``None`` (JSON null).

    Returns
    -------
    dict
        Keys ``frame, t, ok, position, axes, cov, reason`` then ``extra``;
        arrays as lists of floats; ``None`` for position, axes and cov when
        not ``ok``.

    Raises
    ------
    ValueError
        On NaN/inf or a wrong shape in the pose, a non-rotation ``axes``, a
        non-SPD ``cov``, a missing pose when ``ok``, a pose or no reason
        when not ``ok`` (these are programming errors).
    """
    return _build_record(frame, t, ok, position, axes, cov, reason, extra, AXES_TOL_WRITE)


class PoseWriter:
    """Write pose records as JSON Lines, one object per line, flushed per record.

    Parameters
    ----------
    path : str or Path
        Output file (created or truncated), or ``'-'`` for standard output
        (which is not closed).

    Examples
    --------
    >>> with PoseWriter("poses.jsonl") as out:          # doctest: +SKIP
    ...     out.write(pose_record(0, 0.0, False, reason="left image: 4 marker blobs, 5 needed"))

    Notes
    -----
    Records must come in strictly increasing frame order (the contract's
    "one object per frame, in frame order"); :meth:`write` raises
    ``ValueError`` otherwise.
    """

    def __init__(self, path: str | Path):
        self.path = str(path)
        self._last_frame: int | None = None
        self.count = 0
        if self.path == "-":
            self._fh = sys.stdout
            self._owned = False
        else:
            self._fh = open(self.path, "w", encoding="utf-8", newline="\n")
            self._owned = True

    def write(self, record: Mapping[str, Any] | None = None, **fields: Any) -> dict:
        """Validate and write one record.

        Parameters
        ----------
        record : mapping, optional
            A record as :func:`pose_record` returns (re-validated here).
        **fields
            Alternatively, the arguments of :func:`pose_record`.

        Returns
        -------
        dict
            The record written.
        """
        if self._fh is None:
            raise ValueError(f"{self.path}: PoseWriter is closed")
        if record is not None and fields:
            raise TypeError("PoseWriter.write takes a record or keyword fields, not both")
        rec = pose_record(**dict(record if record is not None else fields))
        if self._last_frame is not None and rec["frame"] <= self._last_frame:
            raise ValueError(
                f"{self.path}: frame {rec['frame']} written after frame {self._last_frame}; "
                "records must be in increasing frame order, one per frame"
            )
        self._fh.write(json.dumps(rec, allow_nan=False) + "\n")
        self._fh.flush()
        self._last_frame = rec["frame"]
        self.count += 1
        return rec

    def close(self) -> None:
        """Close the file (standard output is only flushed)."""
        if self._fh is None:
            return
        if self._owned:
            self._fh.close()
        else:
            self._fh.flush()
        self._fh = None

    def __enter__(self) -> "PoseWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON (NaN/inf are not allowed)")


def read_poses(path: str | Path) -> list[dict]:
    """Read and validate a JSON Lines file of pose records.

    Parameters
    ----------
    path : str or Path
        The file, or ``'-'`` for standard input.

    Returns
    -------
    list of dict
        The records as parsed (JSON-native values, key order as in the
        file), blank lines skipped.

    Raises
    ------
    ContractError
        Naming the file and line: invalid JSON (including NaN/inf), a
        non-object line, a missing standard key, a record that
        :func:`pose_record` would refuse (axes checked with tolerance
        ``AXES_TOL_READ``), or frames not in strictly increasing order.
    """
    ctx = _Ctx.file(path)
    hint = "one JSON object per line with keys " + ", ".join(POSE_KEYS)
    if str(path) == "-":
        text = sys.stdin.read()
    else:
        p = Path(path)
        if not p.is_file():
            raise ctx.error("file not found" if not p.exists() else "is not a file", hint)
        text = p.read_text(encoding="utf-8")
    out: list[dict] = []
    last = None
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line, parse_constant=_reject_constant)
        except ValueError as exc:
            raise ctx.error(f"line {lineno}: invalid JSON ({exc})", hint) from None
        if not isinstance(rec, dict):
            raise ctx.error(f"line {lineno}: a JSON {type(rec).__name__}, expected an object", hint)
        missing = [k for k in POSE_KEYS if k not in rec]
        if missing:
            raise ctx.error(f"line {lineno}: keys {missing} missing", hint + " (null when no pose)")
        std = {k: rec[k] for k in POSE_KEYS}
        try:
            _build_record(std.pop("frame"), std.pop("t"), std.pop("ok"), std["position"],
                          std["axes"], std["cov"], std["reason"], {}, AXES_TOL_READ)
        except ValueError as exc:
            raise ctx.error(f"line {lineno}: {exc}", hint) from None
        if last is not None and rec["frame"] <= last:
            raise ctx.error(
                f"line {lineno}: frame {rec['frame']} after frame {last}, expected increasing frames",
                "records come one per frame, in frame order",
            )
        last = rec["frame"]
        out.append(rec)
    return out
