"""The stereo rig: ``rig.yaml``.

:class:`Rig`, :func:`read_rig`, :func:`write_rig` and the calibration's own
uncertainty stored in the rig's extra keys (:func:`rig_calibration_std`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import cv2
import numpy as np

from ._storage import (
    _Ctx,
    _check_finite,
    _check_vec3,
    _cv_message,
    _fmt,
    _frozen,
    _fs_write,
    _node_to_python,
    _open_storage,
    _positive_int,
    _read_numeric,
    _read_positive_int,
    _shape_str,
    _values_equal,
    writing_storage,
)
from ..tol import tol

# --------------------------------------------------------------------------
# tolerances and constants
# --------------------------------------------------------------------------

#: Tolerance on ``max |R Rᵀ − I|`` and ``|det R − 1|`` for the rig's R.
ROTATION_TOL = 1e-6
#: A baseline shorter than this (mm) almost surely means T is in metres.
MIN_BASELINE_MM = 1.0
#: Plausible focal lengths (fx, fy), as multiples of the image width: 0.05 is a field of view of ~170°
#: (a fisheye's), 100 one of ~0.6° (a long telephoto); outside, the number is a mistake (units, a typo).
FOCAL_RANGE_WIDTHS = (0.05, 100.0)
#: How far the principal point (cx, cy) may lie outside the image, as a fraction of its width / height.
PRINCIPAL_POINT_MARGIN = 0.5
#: Numbers of distortion coefficients OpenCV understands.
DIST_COEFF_COUNTS = (4, 5, 8, 12, 14)
#: How much a lens may stretch or shrink distances from the image centre within the image: the distorted
#: radius over the undistorted one, anywhere up to the image's corners. Fisheyes modelled with OpenCV's
#: rational model stay well inside; a value outside is a typo or a failed calibration.
DISTORTION_SCALE_RANGE = (0.25, 4.0)
_RIG_KEYS = ("image_width", "image_height", "K1", "D1", "K2", "D2", "R", "T")


_RIG_HINT = (
    "rig.yaml holds image_width, image_height (px) and K1, D1, K2, D2, R, T "
    "(T in mm) as written by cv2.stereoCalibrate; see docs/contract.md"
)


def _check_K(ctx: _Ctx, key: str, K: np.ndarray) -> np.ndarray:
    hint = f"{key} is [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in px"
    if K.shape != (3, 3):
        raise ctx.error(f"{ctx.name(key)} has shape {_shape_str(K)}, expected 3x3", hint)
    _check_finite(ctx, key, K)
    for (i, j) in ((1, 0), (2, 0), (2, 1)):
        if abs(K[i, j]) > tol.small:
            raise ctx.error(
                f"{ctx.name(key)} is not upper-triangular: {key}[{i},{j}] = "
                f"{_fmt(K[i, j])}, expected 0",
                hint + "; was it written transposed?",
            )
    if abs(K[2, 2] - 1.0) > tol.small:
        raise ctx.error(f"{ctx.name(key)} has {key}[2,2] = {_fmt(K[2, 2])}, expected 1", hint)
    for (i, label) in ((0, "fx"), (1, "fy")):
        if not K[i, i] > 0:
            raise ctx.error(
                f"{ctx.name(key)} has {label} = {key}[{i},{i}] = {_fmt(K[i, i])}, "
                "expected a positive focal length in px",
                hint,
            )
    return K


def _check_K_plausible(ctx: _Ctx, key: str, K: np.ndarray, image_size: tuple[int, int]) -> None:
    """Refuse focal lengths and a principal point no camera of ``image_size`` (width, height) px has."""
    w, h = image_size
    lo, hi = (f * w for f in FOCAL_RANGE_WIDTHS)
    hint = (f"{key} is [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in px, for the image of "
            f"image_width x image_height = {w}x{h} px; recalibrate, or check the file for a typo")
    for (i, label) in ((0, "fx"), (1, "fy")):
        f = K[i, i]
        if not lo <= f <= hi:
            raise ctx.error(
                f"{ctx.name(key)} has {label} = {key}[{i},{i}] = {_fmt(f)} px, {_fmt(f / w)} times the image "
                f"width; expected {_fmt(lo)} to {_fmt(hi)} px ({_fmt(FOCAL_RANGE_WIDTHS[0])} to "
                f"{_fmt(FOCAL_RANGE_WIDTHS[1])} times the width)",
                hint,
            )
    m = PRINCIPAL_POINT_MARGIN
    for (i, label, size) in ((0, "cx", w), (1, "cy", h)):
        c = K[i, 2]
        if not -m * size <= c <= (1 + m) * size:
            raise ctx.error(
                f"{ctx.name(key)} has {label} = {key}[{i},2] = {_fmt(c)} px, far outside the image "
                f"(0 to {size} px); expected {_fmt(-m * size)} to {_fmt((1 + m) * size)} px",
                hint,
            )


def _check_D_plausible(ctx: _Ctx, key: str, D: np.ndarray, K: np.ndarray, image_size: tuple[int, int]) -> None:
    """Refuse distortion coefficients ``D`` no lens of camera matrix ``K`` and ``image_size`` (width, height)
    px has: along the rays from the principal point to the image's corners (pinhole radii, normalized), the
    distorted radius must stay within :data:`DISTORTION_SCALE_RANGE` of the undistorted one and grow with
    it (a model that folds the image back maps two directions onto one pixel)."""
    w, h = image_size
    corners = np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]) - K[:2, 2]
    ends = corners / np.array([K[0, 0], K[1, 1]])                     # normalized, pinhole
    fractions = np.linspace(0.02, 1.0, 50)
    rays = ends[:, None, :] * fractions[None, :, None]                  # (4, 50, 2)
    points = np.concatenate([rays.reshape(-1, 2), np.ones((rays.size // 2, 1))], axis=1)
    with np.errstate(all="ignore"):
        distorted, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), np.eye(3), D.astype(np.float64))
        radius = np.linalg.norm(distorted.reshape(4, -1, 2), axis=2)
        scale = radius / np.linalg.norm(rays, axis=2)
    lo, hi = DISTORTION_SCALE_RANGE
    bad = ~np.isfinite(scale) | (scale < lo) | (scale > hi)
    folds = np.diff(radius, axis=1) <= 0
    if bad.any() or folds.any():
        worst = scale.flat[int(np.nanargmax(np.abs(np.log(np.where(np.isfinite(scale) & (scale > 0), scale,
                                                                           np.inf)))))]
        what = ("folds the image back on itself" if folds.any() and not bad.any()
                else f"scales distances from the image centre by {_fmt(worst)} within the image")
        raise ctx.error(
            f"{ctx.name(key)} = {np.array2string(D, precision=4, separator=', ')} {what}; a lens stays within "
            f"{_fmt(lo)} to {_fmt(hi)}: recalibrate (headplod calibrate), or check the file for a typo",
            f"{key} holds the distortion coefficients k1 k2 p1 p2 [k3 ...] of the camera of {key.replace('D', 'K')}")


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
    _check_K_plausible(ctx, "K1", out["K1"], out["image_size"])
    out["D1"] = _check_D(ctx, "D1", arr("D1", D1))
    _check_D_plausible(ctx, "D1", out["D1"], out["K1"], out["image_size"])
    out["K2"] = _check_K(ctx, "K2", arr("K2", K2))
    _check_K_plausible(ctx, "K2", out["K2"], out["image_size"])
    out["D2"] = _check_D(ctx, "D2", arr("D2", D2))
    _check_D_plausible(ctx, "D2", out["D2"], out["K2"], out["image_size"])
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
        positive fx, fy and K[2,2] = 1, fx or fy lies outside
        ``FOCAL_RANGE_WIDTHS`` times the image width or the principal point
        more than ``PRINCIPAL_POINT_MARGIN`` of the image size outside it
        (e.g. ``fx = 1e308``), R is not a rotation (tolerance
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
    with writing_storage(path) as fs:            # nothing is written when a value cannot be stored
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
