"""Stereo calibration from image pairs of a planar board (Zhang's method).

A board (a chessboard, or a ChArUco board: a chessboard with ArUco markers
in its white squares) is shown to both cameras in 10-20 poses. For each pair
of images the board's inner corners are detected (:func:`detect_board`);
each camera is calibrated on its own with ``cv2.calibrateCamera`` (Zhang:
homographies of the plane, then a Levenberg-Marquardt refinement of the
intrinsics, 5 distortion coefficients and one board pose per view); then
``cv2.stereoCalibrate`` with the intrinsics fixed finds the rig's R and T;
then, by default, a joint refinement of everything on the corners seen by
both cameras. Pairs that cannot be used, or whose reprojection error is an
outlier, are set aside with a reason (:attr:`CalibrationResult.rejected`)
and the others are calibrated again without them.

This module solves; the board and its detection (:mod:`.board`), the pairs
of a folder (:mod:`.pairs`), the advice while capturing (:mod:`.guide`) and
the report (:mod:`.report`) are their own modules, and their public names
are re-exported here (``__all__``), the calibration's one entry point.

Conventions (``docs/contract.md``)
-----------------------------------
- Pixels: OpenCV's, (0, 0) is the centre of the top-left pixel; every corner
  array is (N, 2) float32 (u, v) px.
- Board frame B: origin at the top-left outer corner of the pattern (the
  corner of its first square), x along the columns, y along the rows, z
  into the board; inner corner k = i * cols + j (row i, column j) is at
  ((j + 1) s, (i + 1) s, 0) mm for square size s. For a ChArUco board this
  is cv2.aruco's ``getChessboardCorners`` and k its corner id.
- Rig: ``X_right = R @ X_left + T``, T in mm (the board is measured in mm),
  the world frame is the left camera's.

Uncertainty
-----------
The rig.yaml written carries the calibration's own 1-sigma, for a tracker
to use as a prior (read them with :func:`headplod.io.rig_calibration_std`):
``calibration_std_left`` / ``calibration_std_right`` (1x4: fx, fy, cx, cy,
px, from ``cv2.calibrateCameraExtended``), ``calibration_std_rotation_deg``
(1x3: the components of the rotation vector ``cv2.Rodrigues(R)``, degrees)
and ``calibration_std_translation_mm`` (1x3: T, mm). The last two come from
the Gauss-Newton information matrix of the whole stereo problem at its
solution (:func:`_stereo_covariance`).

Failures
--------
A pair that cannot be used is a value (a ``(name, reason)`` in ``rejected``),
not an exception. :class:`CalibrationError` (a ``ValueError``) is raised
when fewer than :data:`MIN_PAIRS` pairs remain, with every rejection in its
message. :func:`find_pairs` raises :class:`headplod.io.ContractError` for a
folder without pairs or with unmatched files.
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import cv2
import numpy as np

from .. import io
from .board import MIN_CHARUCO_CORNERS, BoardDetection, BoardSpec, _as_gray, _charuco, detect_board
from .guide import coverage_guide
from .pairs import IMAGE_EXTENSIONS, MIN_PAIRS, find_pairs
from .report import _size_str, format_report

__all__ = [
    "BoardSpec",
    "BoardDetection",
    "CalibrationResult",
    "CalibrationError",
    "find_pairs",
    "detect_board",
    "calibrate_stereo",
    "calibrate_folder",
    "coverage_guide",
    "format_report",
    "MIN_PAIRS",
    "IMAGE_EXTENSIONS",
]

#: A pair is an outlier when its reprojection error exceeds this many times
#: the median of the pairs...
OUTLIER_FACTOR = 3.0
#: ... and this absolute floor (px), so that a very clean set (median 0.05
#: px) does not lose good pairs to noise.
OUTLIER_FLOOR_PX = 0.5
#: A pair whose images disagree by more than GROSS_FACTOR x OUTLIER_FACTOR x
#: the median (and GROSS_FLOOR_PX) under the median relative pose of the
#: pairs is set aside before the stereo fit (a board pose from one image
#: predicts the other image to a few tenths of a px only, hence the margin).
GROSS_FACTOR = 3.0
GROSS_FLOOR_PX = 3.0
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)


class CalibrationError(ValueError):
    """Calibration cannot proceed (too few usable pairs, a failed solve).

    Attributes
    ----------
    rejected : list of (name, reason)
        The pairs set aside so far.
    """

    def __init__(self, message: str, rejected: Sequence[tuple[str, str]] = ()):
        super().__init__(message)
        self.rejected = list(rejected)


@dataclass
class CalibrationResult:
    """What :func:`calibrate_stereo` found.

    Attributes
    ----------
    rig : headplod.io.Rig
        The calibrated rig (T in mm, ``X_right = R @ X_left + T``), with the
        rms values, the board and the number of pairs in ``rig.extra``.
    rms_left_px, rms_right_px : float
        RMS reprojection error of the final rig over the corners of the used
        pairs, in the left and right images, px.
    rms_stereo_px : float
        RMS over both images (what ``cv2.stereoCalibrate`` minimises), px.
    rms_zhang_px : (float, float)
        RMS of the single-camera calibrations (``cv2.calibrateCamera``) on
        all corners each camera saw, px.
    pair_errors_px : dict of name -> (left, right)
        RMS reprojection error of each used pair in each image, px.
    used : list of str
        Names of the pairs the rig was calibrated on.
    rejected : list of (name, reason)
        Pairs set aside, with the reason.
    std_px : dict of 'left'/'right' -> dict
        1-sigma uncertainty of fx, fy, cx, cy (px) from the single-camera
        calibrations.
    coverage : list of str
        :func:`coverage_guide` advice for the left and right images (empty
        when the poses cover the images well).
    spec : BoardSpec
    std_rotation_deg : (3,) ndarray or None
        1-sigma of the components of the rig's rotation vector
        ``cv2.Rodrigues(R)``, degrees (see :func:`_stereo_covariance`); None
        when it could not be computed (a degenerate set of views).
    std_translation_mm : (3,) ndarray or None
        1-sigma of the components of T, mm.

    The same stds are in ``rig.extra`` (and so in the rig.yaml written):
    ``calibration_std_left`` / ``calibration_std_right`` (1x4: fx, fy, cx,
    cy, px), ``calibration_std_rotation_deg`` and
    ``calibration_std_translation_mm`` (1x3); read them back with
    :func:`headplod.io.rig_calibration_std`.
    """

    rig: io.Rig
    rms_left_px: float
    rms_right_px: float
    rms_stereo_px: float
    rms_zhang_px: tuple[float, float]
    pair_errors_px: dict
    used: list
    rejected: list
    std_px: dict
    coverage: list
    spec: BoardSpec
    detections: dict = field(default_factory=dict, repr=False)
    std_rotation_deg: Optional[np.ndarray] = None
    std_translation_mm: Optional[np.ndarray] = None


def _load(item: Any, what: str) -> tuple[Optional[np.ndarray], Optional[str]]:
    if isinstance(item, np.ndarray):
        try:
            return _as_gray(item, what), None
        except (TypeError, ValueError) as exc:
            return None, str(exc)
    p = Path(item)
    if not p.is_file():
        return None, f"{what} {p} not found"
    try:
        img = io.read_image(p)                  # through memory: OpenCV never sees the path
    except OSError as exc:
        return None, f"{what} {p} cannot be read ({exc.strerror or exc})"
    if img is None:
        return None, f"{what} {p} cannot be read as an image"
    try:
        return _as_gray(img, f"{what} {p}"), None
    except (TypeError, ValueError) as exc:
        return None, str(exc)


@dataclass
class _Pair:
    name: str
    left: BoardDetection
    right: BoardDetection
    obj: np.ndarray      # (M, 3) float32, common corners
    img_l: np.ndarray    # (M, 2) float32
    img_r: np.ndarray    # (M, 2) float32


def _calibrate_camera(pairs: list[_Pair], side: str, image_size, flags: int):
    """Zhang calibration of one camera on all the corners it saw in ``pairs``."""
    dets = [getattr(p, side) for p in pairs]
    obj = [d.object_mm.reshape(-1, 1, 3) for d in dets]
    img = [d.corners.reshape(-1, 1, 2) for d in dets]
    rms, K, D, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
        obj, img, tuple(image_size), None, None, flags=flags, criteria=_CRITERIA)
    return (float(rms), K, D.reshape(-1), np.asarray(std_in).reshape(-1), np.asarray(per_view).reshape(-1),
            rvecs, tvecs)


def _robust_stereo_errors(pairs: list[_Pair], K1, D1, K2, D2, rv_l, tv_l, rv_r, tv_r) -> np.ndarray:
    """Error (px) of each pair against the median of the pairs' relative poses.

    Each pair alone gives a relative pose (R_i, T_i) from its two board
    poses; their component-wise median is not dragged by a few bad pairs
    (as a least-squares ``stereoCalibrate`` is). A pair's error is the RMS
    distance between the corners of one image and their prediction from the
    board pose in the other image through the median pose, the smaller of
    the two directions (a view with few corners gives a weak pose, the other
    view then predicts it well); a pair whose two images were not taken at
    the same moment is off both ways."""
    poses_l = [(cv2.Rodrigues(np.asarray(r, np.float64))[0], np.asarray(t, np.float64).reshape(3))
               for r, t in zip(rv_l, tv_l)]
    poses_r = [(cv2.Rodrigues(np.asarray(r, np.float64))[0], np.asarray(t, np.float64).reshape(3))
               for r, t in zip(rv_r, tv_r)]
    rel_r, rel_t = [], []
    for (R1, t1), (R2, t2) in zip(poses_l, poses_r):
        Rk = R2 @ R1.T
        rel_r.append(cv2.Rodrigues(Rk)[0].reshape(3))
        rel_t.append(t2 - Rk @ t1)
    R_med = cv2.Rodrigues(np.median(np.array(rel_r), axis=0))[0]
    T_med = np.median(np.array(rel_t), axis=0)
    out = np.zeros(len(pairs))
    for k, p in enumerate(pairs):
        (R1, t1), (R2, t2) = poses_l[k], poses_r[k]
        _, il, ir = np.intersect1d(p.left.ids, p.right.ids, assume_unique=True, return_indices=True)
        # left board pose -> right camera, and right board pose -> left camera
        to_right = (p.left.object_mm[il].astype(np.float64) @ R1.T + t1) @ R_med.T + T_med
        to_left = ((p.right.object_mm[ir].astype(np.float64) @ R2.T + t2) - T_med) @ R_med
        errs = []
        for X, K, D, seen in ((to_right, K2, D2, p.right.corners[ir]), (to_left, K1, D1, p.left.corners[il])):
            uv, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)
            errs.append(math.sqrt(((uv.reshape(-1, 2) - seen) ** 2).sum(axis=1).mean()))
        out[k] = min(errs)
    return out


def _stereo(pairs: list[_Pair], image_size, K1, D1, K2, D2, flags: int, R=None, T=None):
    obj = [p.obj.reshape(-1, 1, 3) for p in pairs]
    i1 = [p.img_l.reshape(-1, 1, 2) for p in pairs]
    i2 = [p.img_r.reshape(-1, 1, 2) for p in pairs]
    R = np.eye(3) if R is None else np.array(R, np.float64)
    T = np.zeros((3, 1)) if T is None else np.array(T, np.float64).reshape(3, 1)
    out = cv2.stereoCalibrateExtended(
        obj, i1, i2, K1.copy(), D1.reshape(1, -1).copy(), K2.copy(), D2.reshape(1, -1).copy(),
        tuple(image_size), R, T, flags=flags, criteria=_CRITERIA)
    rms, K1, D1, K2, D2, R, T, _, _, rvecs, tvecs, _ = out
    return float(rms), K1, D1.reshape(-1), K2, D2.reshape(-1), R, T.reshape(3), rvecs, tvecs


def _pair_errors(pairs: list[_Pair], K1, D1, K2, D2, R, T, rvecs, tvecs):
    """(n, 2) RMS reprojection error per pair and image; squared sums per image."""
    errs = np.zeros((len(pairs), 2))
    sq = np.zeros(2)
    count = 0
    for k, p in enumerate(pairs):
        R1, _ = cv2.Rodrigues(np.asarray(rvecs[k], np.float64).reshape(3, 1))
        t1 = np.asarray(tvecs[k], np.float64).reshape(3)
        R2 = R @ R1
        t2 = R @ t1 + T
        obj = p.obj.astype(np.float64)
        for side, (Rc, tc, K, D, img) in enumerate(((R1, t1, K1, D1, p.img_l), (R2, t2, K2, D2, p.img_r))):
            uv, _ = cv2.projectPoints(obj, cv2.Rodrigues(Rc)[0], tc, K, D)
            d2 = ((uv.reshape(-1, 2) - img) ** 2).sum(axis=1)
            errs[k, side] = math.sqrt(d2.mean())
            sq[side] += d2.sum()
        count += len(obj)
    return errs, np.sqrt(sq / max(count, 1)), float(np.sqrt(sq.sum() / max(2 * count, 1)))


#: (flag, indices into [fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6, s1..s4, tx, ty]) an
#: intrinsic block loses when the flag holds the parameters fixed (see :func:`_stereo_covariance`).
_FIXED_BY_FLAG = (
    ("CALIB_FIX_FOCAL_LENGTH", (0, 1)),
    ("CALIB_FIX_PRINCIPAL_POINT", (2, 3)),
    ("CALIB_ZERO_TANGENT_DIST", (6, 7)),
    ("CALIB_FIX_TANGENT_DIST", (6, 7)),
    ("CALIB_FIX_K1", (4,)),
    ("CALIB_FIX_K2", (5,)),
    ("CALIB_FIX_K3", (8,)),
    ("CALIB_FIX_K4", (9,)),
    ("CALIB_FIX_K5", (10,)),
    ("CALIB_FIX_K6", (11,)),
    ("CALIB_FIX_S1_S2_S3_S4", (12, 13, 14, 15)),
    ("CALIB_FIX_TAUX_TAUY", (16, 17)),
)


def _intrinsic_columns(J: np.ndarray, K: np.ndarray, flags: int) -> np.ndarray:
    """The columns of a ``cv2.projectPoints`` Jacobian block [fx fy cx cy dist...]
    for the intrinsics that the calibration estimated (fixed ones dropped,
    fx and fy merged under ``CALIB_FIX_ASPECT_RATIO``)."""
    keep = [True] * J.shape[1]
    for name, idx in _FIXED_BY_FLAG:
        if flags & getattr(cv2, name, 0):
            for i in idx:
                if i < len(keep):
                    keep[i] = False
    J = J.copy()
    if flags & cv2.CALIB_FIX_ASPECT_RATIO and keep[0] and keep[1]:
        J[:, 0] += (K[1, 1] / K[0, 0]) * J[:, 1]  # fy = a fx, a fixed
        keep[1] = False
    return J[:, keep]


def _stereo_covariance(pairs: list[_Pair], K1, D1, K2, D2, R, T, rvecs, tvecs,
                       flags: int = 0) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """1-sigma of the rig's rotation vector (deg) and of T (mm), or None.

    Gauss-Newton information matrix of the whole stereo problem at its
    solution: the parameters are both cameras' intrinsics (fx, fy, cx, cy
    and the distortion coefficients that ``flags`` leave free), the rig
    (rvec = Rodrigues(R), T) and the board pose of every pair in the left
    camera; the residuals are the reprojection errors of the corners of
    every pair in both images (the right pose of a board is the left one
    composed with the rig). Then ``cov = s^2 (J^T J)^-1`` with ``s^2`` the
    residual sum of squares over (residuals - parameters), and the rig's
    stds are the square roots of its diagonal. Keeping the intrinsics free
    in J makes their uncertainty part of the rig's (fx errors move T, for
    example), also when they were fixed in the stereo fit. This is the
    standard first-order covariance (what ``cv2.calibrateCameraExtended``
    reports for the intrinsics); it assumes independent corner errors of
    equal variance. Returns None when J^T J cannot be inverted (a
    degenerate set of views).

    Chosen over the spread of per-pair relative poses (sample std /
    sqrt(n)) because that spread misses the intrinsics' errors, which all
    pairs share, and is not the spread of the least-squares estimator
    actually used. On synthetic sets (10 chessboard, 8 ChArUco) the true
    rig's errors divided by these stds gave mean z^2 1.1 and 0.9.

    The rotation std is per component of rvec = Rodrigues(R), OpenCV's own
    parameterization. For a rig whose cameras converge strongly (|rvec| of
    tens of degrees) this is not the same as a small rotation applied to R:
    a change d of rvec turns R by about J(rvec) d (J the SO(3) Jacobian).
    """
    R = np.asarray(R, np.float64)
    r_rig = cv2.Rodrigues(R)[0].reshape(3)
    T = np.asarray(T, np.float64).reshape(3)
    # per view, the Jacobian has columns [global | view]: global = [left
    # intrinsics | right intrinsics | rig r, T], view = that board's (r, t)
    # in the left camera. The views' blocks are eliminated one by one (Schur
    # complement), so memory does not grow with the number of pairs.
    views = []
    ssr, n_res = 0.0, 0
    for k, p in enumerate(pairs):
        rv = np.asarray(rvecs[k], np.float64).reshape(3)
        tv = np.asarray(tvecs[k], np.float64).reshape(3)
        obj = p.obj.astype(np.float64)
        uv1, J1 = cv2.projectPoints(obj, rv, tv, K1, D1)
        # right view = board pose composed with the rig, and its derivatives
        rv2, tv2, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
            rv, tv, r_rig, T)
        uv2, J2 = cv2.projectPoints(obj, rv2, tv2, K2, D2)
        A, B = J2[:, 0:3], J2[:, 3:6]  # d/d(rvec, tvec) of the right view
        i1 = _intrinsic_columns(J1[:, 6:], K1, flags)
        i2 = _intrinsic_columns(J2[:, 6:], K2, flags)
        m = 2 * len(obj)
        g = np.vstack([np.hstack([i1, np.zeros((m, i2.shape[1])), np.zeros((m, 6))]),
                       np.hstack([np.zeros((m, i1.shape[1])), i2,
                                  A @ dr3dr2 + B @ dt3dr2, A @ dr3dt2 + B @ dt3dt2])])
        v = np.vstack([J1[:, 0:6], np.hstack([A @ dr3dr1 + B @ dt3dr1, A @ dr3dt1 + B @ dt3dt1])])
        views.append((g, v))
        for uv, seen in ((uv1, p.img_l), (uv2, p.img_r)):
            ssr += float(((uv.reshape(-1, 2) - seen) ** 2).sum())
        n_res += 2 * m
    n_global = views[0][0].shape[1]
    rig_cols = slice(n_global - 6, n_global)
    dof = n_res - n_global - 6 * len(views)
    if dof <= 0:
        return None
    # scale the columns so that the normal matrices are well conditioned
    g_scale = np.sqrt(sum((g ** 2).sum(axis=0) for g, _ in views))
    if not np.all(g_scale > 0):
        return None
    S = np.zeros((n_global, n_global))
    try:
        for g, v in views:
            v_scale = np.linalg.norm(v, axis=0)
            if not np.all(v_scale > 0):
                return None
            gs, vs = g / g_scale, v / v_scale
            Hgv = gs.T @ vs
            S += gs.T @ gs - Hgv @ np.linalg.solve(vs.T @ vs, Hgv.T)
        cov = np.linalg.inv(S) / np.outer(g_scale, g_scale) * (ssr / dof)
    except np.linalg.LinAlgError:
        return None
    var = np.diag(cov)[rig_cols]
    if not (np.all(np.isfinite(var)) and np.all(var > 0)):
        return None
    std = np.sqrt(var)
    return np.degrees(std[:3]), std[3:]


def calibrate_stereo(pairs: Sequence[tuple[str, Any, Any]], spec: BoardSpec, image_size=None, *,
                     refine: bool = True, flags: int = 0, outlier_factor: float = OUTLIER_FACTOR,
                     outlier_floor_px: float = OUTLIER_FLOOR_PX,
                     progress: Optional[Callable[[int, int], None]] = None,
                     clock: Callable[[], float] = time.time) -> CalibrationResult:
    """Calibrate a stereo rig from image pairs of a board.

    Steps: detect the board in every image; set aside pairs that cannot be
    used (an image missing or unreadable, a size that differs from the
    other images, the board not found in one or both images, fewer than
    :data:`MIN_CHARUCO_CORNERS` ChArUco corners in common); calibrate each
    camera alone (``cv2.calibrateCamera``, Zhang's method, 5 distortion
    coefficients unless ``flags`` say otherwise); find R, T with
    ``cv2.stereoCalibrate`` and ``CALIB_FIX_INTRINSIC``; set aside pairs
    whose error (the largest of their per-camera and stereo RMS) is over
    ``max(outlier_factor x median, outlier_floor_px)`` and start again
    without them; finally (``refine``) refine intrinsics and extrinsics
    together with ``cv2.stereoCalibrate`` on the corners both cameras saw,
    keeping the result only if it lowers the stereo RMS.

    Parameters
    ----------
    pairs : sequence of (name, left, right)
        ``left`` and ``right`` are image paths or (H, W) uint8 arrays, e.g.
        from :func:`find_pairs`.
    spec : BoardSpec
    image_size : (width, height), optional
        Expected size of every image, px; default: the most common size.
    refine : bool
        Do the final joint refinement.
    flags : int
        ``cv2.CALIB_*`` flags for the single-camera calibrations (e.g.
        ``cv2.CALIB_RATIONAL_MODEL`` for a fisheye-like lens, or
        ``cv2.CALIB_FIX_K3`` with few pairs).
    outlier_factor, outlier_floor_px : float
        The outlier rule above.
    clock : callable
        Seconds since the epoch, for the rig's ``calibration_date`` (UTC, ISO 8601: how old the rig is,
        ``headplod doctor``; a copied file's modification time would not tell).
    progress : callable, optional
        ``progress(done, total)`` after each pair's detection.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    CalibrationError
        Fewer than :data:`MIN_PAIRS` usable pairs (the message lists why
        each pair was set aside).
    """
    if not isinstance(spec, BoardSpec):
        raise TypeError(f"spec: expected a BoardSpec, got {type(spec).__name__}")
    pairs = list(pairs)
    for k, item in enumerate(pairs):
        if not (isinstance(item, (tuple, list)) and len(item) == 3):
            raise ValueError(f"pairs[{k}]: expected (name, left, right), got {item!r}")
    rejected: list[tuple[str, str]] = []
    loaded = []
    for name, left, right in pairs:
        gl, el = _load(left, "left image")
        gr, er = _load(right, "right image")
        if el or er:
            rejected.append((str(name), "; ".join(e for e in (el, er) if e)))
            continue
        loaded.append((str(name), gl, gr))
    if image_size is None:
        sizes = [(g.shape[1], g.shape[0]) for _, gl, gr in loaded for g in (gl, gr)]
        image_size = max(set(sizes), key=sizes.count) if sizes else None
    else:
        image_size = (int(image_size[0]), int(image_size[1]))

    good: list[_Pair] = []
    detections = {}
    total = len(loaded)
    for k, (name, gl, gr) in enumerate(loaded):
        sl, sr = (gl.shape[1], gl.shape[0]), (gr.shape[1], gr.shape[0])
        if sl != sr:
            rejected.append((name, f"image sizes differ: left {_size_str(sl)}, right {_size_str(sr)} px"))
        elif sl != tuple(image_size):
            rejected.append((name, f"image size {_size_str(sl)} px, expected {_size_str(image_size)} "
                                   "(the size of the other images)"))
        else:
            dl, dr = detect_board(gl, spec), detect_board(gr, spec)
            detections[name] = (dl, dr)
            if not dl and not dr:
                rejected.append((name, f"board not found in either image: {dl.reason}"))
            elif not dl:
                rejected.append((name, f"board not found in the left image: {dl.reason}"))
            elif not dr:
                rejected.append((name, f"board not found in the right image: {dr.reason}"))
            else:
                common, il, ir = np.intersect1d(dl.ids, dr.ids, assume_unique=True, return_indices=True)
                if spec.kind == "chessboard" and len(common) != spec.n_corners:
                    rejected.append((name, f"different corners in the two images: {len(dl.ids)} left, "
                                           f"{len(dr.ids)} right"))
                elif len(common) < MIN_CHARUCO_CORNERS:
                    rejected.append((name, f"only {len(common)} corners seen in both images "
                                           f"({len(dl.ids)} left, {len(dr.ids)} right), at least "
                                           f"{MIN_CHARUCO_CORNERS} needed"))
                elif spec.kind == "charuco" and _charuco(spec)[0].checkCharucoCornersCollinear(
                        common.reshape(-1, 1).astype(np.int32)):
                    rejected.append((name, "the corners seen in both images are all on one line"))
                else:
                    good.append(_Pair(name, dl, dr, dl.object_mm[il], dl.corners[il], dr.corners[ir]))
        if progress is not None:
            progress(k + 1, total)

    def too_few(what: str) -> CalibrationError:
        lines = [f"{what}: {len(good)} usable pair(s) of {len(pairs)}, at least {MIN_PAIRS} needed "
                 f"(10-20 recommended) for a {spec.describe()}"]
        lines += [f"  {n}: {r}" for n, r in rejected]
        return CalibrationError("\n".join(lines), rejected)

    if len(good) < MIN_PAIRS:
        raise too_few("cannot calibrate")

    def set_aside(out: list[int], worst: np.ndarray, med: float, why: str, factor: float) -> None:
        nonlocal good
        for k in out:
            rejected.append((good[k].name, f"{why} {worst[k]:.2f} px, over {factor:g}x the median "
                                           f"{med:.2f} px (board moved during the pair? images from "
                                           "different moments? a bent board?)"))
        good = [p for k, p in enumerate(good) if k not in set(out)]
        if len(good) < MIN_PAIRS:
            raise too_few("cannot calibrate after setting aside outliers")

    for _ in range(6):  # outlier passes
        (rms_l, K1, D1, std1, view_l, rv_l, tv_l) = _calibrate_camera(good, "left", image_size, flags)
        (rms_r, K2, D2, std2, view_r, rv_r, tv_r) = _calibrate_camera(good, "right", image_size, flags)
        # 1. gross errors (e.g. the two images of different poses), which would
        #    drag a least-squares stereo solution: against the median relative pose
        robust = _robust_stereo_errors(good, K1, D1, K2, D2, rv_l, tv_l, rv_r, tv_r)
        med = float(np.median(robust))
        out = [k for k in range(len(good))
               if robust[k] > max(GROSS_FACTOR * outlier_factor * med, GROSS_FLOOR_PX)]
        if out:
            set_aside(out, robust, med, "the two images disagree: predicting one from the other is off by",
                      GROSS_FACTOR * outlier_factor)
            continue
        # 2. outliers of the fitted rig
        rms_s, _, _, _, _, R, T, rvecs, tvecs = _stereo(good, image_size, K1, D1, K2, D2, cv2.CALIB_FIX_INTRINSIC)
        errs, _, _ = _pair_errors(good, K1, D1, K2, D2, R, T, rvecs, tvecs)
        worst = np.maximum(errs.max(axis=1), np.maximum(view_l, view_r))
        med = float(np.median(worst))
        out = [k for k in range(len(good)) if worst[k] > max(outlier_factor * med, outlier_floor_px)]
        if not out:
            break
        set_aside(out, worst, med, "reprojection error", outlier_factor)

    method = "calibrateCamera + stereoCalibrate(FIX_INTRINSIC)"
    if refine:
        fl = cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_USE_EXTRINSIC_GUESS | flags
        try:
            res = _stereo(good, image_size, K1, D1, K2, D2, fl, R, T)
        except cv2.error:
            res = None
        if res is not None and np.isfinite(res[0]) and res[0] < rms_s and np.all(np.isfinite(res[5])):
            rms_s, K1, D1, K2, D2, R, T, rvecs, tvecs = res
            method += " + joint refinement"
    if not (np.all(np.isfinite(K1)) and np.all(np.isfinite(K2)) and np.all(np.isfinite(T))):
        raise CalibrationError("calibration diverged (non-finite result); check the board size and "
                               "the images", rejected)
    errs, rms_lr, rms_both = _pair_errors(good, K1, D1, K2, D2, R, T, rvecs, tvecs)
    extra = {
        "calibration_rms_left_px": float(rms_lr[0]),
        "calibration_rms_right_px": float(rms_lr[1]),
        "calibration_rms_stereo_px": float(rms_both),
        "calibration_board": spec.describe(),
        "calibration_pairs": int(len(good)),
        "calibration_pairs_rejected": int(len(rejected)),
        "calibration_method": method,
        "calibration_date": _dt.datetime.fromtimestamp(clock(), _dt.timezone.utc).isoformat(timespec="seconds"),
    }
    # Rodrigues round trip makes R orthonormal to machine precision
    R = cv2.Rodrigues(cv2.Rodrigues(np.asarray(R, np.float64))[0])[0]
    std = {}
    for side, s in (("left", std1), ("right", std2)):
        std[side] = {k: float(s[i]) for i, k in enumerate(("fx", "fy", "cx", "cy"))}
        # 1x4 !!opencv-matrix (fx, fy, cx cy), px, like D's 1xN
        extra[f"calibration_std_{side}"] = np.asarray(s[:4], np.float64).reshape(1, 4)
    rig_std = _stereo_covariance(good, K1, D1, K2, D2, R, T, rvecs, tvecs, flags)
    if rig_std is not None:
        extra["calibration_std_rotation_deg"] = rig_std[0].reshape(1, 3)
        extra["calibration_std_translation_mm"] = rig_std[1].reshape(1, 3)
    rig = io.Rig(tuple(int(v) for v in image_size), K1, D1, K2, D2, R, T, extra=extra)
    names = [p.name for p in good]
    coverage = []
    for side, idx in (("left", 0), ("right", 1)):
        dets = [detections[p.name][idx] for p in good]
        coverage += [f"{side} camera: {m}" for m in coverage_guide(dets, image_size)]
    return CalibrationResult(
        rig=rig,
        rms_left_px=float(rms_lr[0]),
        rms_right_px=float(rms_lr[1]),
        rms_stereo_px=float(rms_both),
        rms_zhang_px=(rms_l, rms_r),
        pair_errors_px={n: (float(e[0]), float(e[1])) for n, e in zip(names, errs)},
        used=names,
        rejected=rejected,
        std_px=std,
        coverage=coverage,
        std_rotation_deg=None if rig_std is None else rig_std[0],
        std_translation_mm=None if rig_std is None else rig_std[1],
        spec=spec,
        detections=detections,
    )


def calibrate_folder(folder: str | Path, spec: BoardSpec, out: str | Path | None = None,
                     progress: Optional[Callable[[int, int], None]] = None, **options) -> CalibrationResult:
    """:func:`find_pairs` then :func:`calibrate_stereo`; writes ``out`` (rig.yaml) when given.

    Parameters
    ----------
    folder : str or Path
        A folder in one of :func:`find_pairs`'s layouts.
    spec : BoardSpec
    out : str or Path, optional
        Where to write the rig (``headplod.io.write_rig``; the rms values,
        the board and the calibration's 1-sigma values are in its extra
        keys).
    progress : callable, optional
        ``progress(done, total)`` after each pair's detection.
    **options
        Passed to :func:`calibrate_stereo` (``image_size``, ``refine``,
        ``flags``, ...).
    """
    pairs = find_pairs(folder)
    result = calibrate_stereo(pairs, spec, progress=progress, **options)
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        io.write_atomically(out, lambda name: io.write_rig(name, result.rig), suffix=".tmp.yaml")
    return result

