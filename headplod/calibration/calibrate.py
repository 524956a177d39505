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

Conventions (``spec/conventions.md``)
-------------------------------------
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

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Optional, Sequence

import cv2
import numpy as np

from .. import io

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

#: Fewest usable pairs :func:`calibrate_stereo` accepts.
MIN_PAIRS = 6
#: Fewest ChArUco corners a view (and a pair, in common) must have.
MIN_CHARUCO_CORNERS = 6
#: File name endings :func:`find_pairs` takes as images (case-insensitive).
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
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
#: A view counts as tilted for :func:`coverage_guide` beyond this angle.
TILT_DEG = 20.0
#: Views tilted about each axis (up/down, left/right) coverage_guide asks for.
MIN_TILTED_VIEWS = 2
#: The board should span at least this fraction of the image (the larger of
#: its bounding box's width and height fractions) in most views.
MIN_FILL = 0.25

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-3)
_CELL_NAMES = ("top-left", "top", "top-right", "left", "centre", "right",
               "bottom-left", "bottom", "bottom-right")


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


# --------------------------------------------------------------------------
# board
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class BoardSpec:
    """A printed calibration board.

    Parameters
    ----------
    kind : {'chessboard', 'charuco'}
    cols, rows : int
        Inner corners along a row and along a column (a 10 x 7 squares
        chessboard has 9 x 6 inner corners). Use different numbers, one odd
        and one even, for a chessboard: its orientation is then unambiguous.
    square_mm : float
        Side of a square as printed, mm (measure it: printers scale).
    marker_mm : float, optional
        Side of an ArUco marker (ChArUco only), mm; default 0.7 square.
    dictionary : str
        cv2.aruco predefined dictionary (ChArUco only), e.g. 'DICT_5X5_100'.
    legacy_pattern : bool
        ChArUco boards with an even number of rows of squares printed by
        OpenCV before 4.6 use the old layout (ChArUco only).
    """

    kind: str = "chessboard"
    cols: int = 9
    rows: int = 6
    square_mm: float = 25.0
    marker_mm: Optional[float] = None
    dictionary: str = "DICT_5X5_100"
    legacy_pattern: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise ValueError(f"BoardSpec.kind is {self.kind!r}, expected 'chessboard' or 'charuco'")
        for key in ("cols", "rows"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 2:
                raise ValueError(f"BoardSpec.{key} is {v!r}, expected an integer >= 2 (inner corners)")
            object.__setattr__(self, key, int(v))
        if not (isinstance(self.square_mm, (int, float, np.number)) and math.isfinite(self.square_mm)
                and self.square_mm > 0):
            raise ValueError(f"BoardSpec.square_mm is {self.square_mm!r}, expected a length > 0 in mm")
        object.__setattr__(self, "square_mm", float(self.square_mm))
        if self.kind == "chessboard" and self.cols == self.rows:
            raise ValueError(
                f"BoardSpec: a chessboard with {self.cols}x{self.rows} inner corners looks the same "
                "turned by 90 degrees, so the two cameras may number its corners differently; "
                "use a board with different numbers of inner corners (e.g. 9x6)")
        if self.kind == "charuco":
            if self.marker_mm is not None:
                if not (math.isfinite(self.marker_mm) and 0 < self.marker_mm < self.square_mm):
                    raise ValueError(f"BoardSpec.marker_mm is {self.marker_mm!r}, expected 0 < marker_mm "
                                     f"< square_mm ({self.square_mm})")
                object.__setattr__(self, "marker_mm", float(self.marker_mm))
            if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
                raise ValueError(f"BoardSpec.dictionary is {self.dictionary!r}, expected a cv2.aruco "
                                 "predefined dictionary such as 'DICT_5X5_100'")

    @property
    def marker(self) -> float:
        """ArUco marker side, mm (ChArUco)."""
        return 0.7 * self.square_mm if self.marker_mm is None else float(self.marker_mm)

    @property
    def n_corners(self) -> int:
        """Number of inner corners."""
        return self.cols * self.rows

    def object_points(self) -> np.ndarray:
        """(cols*rows, 3) float32 inner corners in the board frame B, mm, by id."""
        j, i = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        xy = np.stack([j.ravel() + 1, i.ravel() + 1], axis=1) * self.square_mm
        return np.column_stack([xy, np.zeros(len(xy))]).astype(np.float32)

    def describe(self) -> str:
        """One line, e.g. 'chessboard 9x6 inner corners, 25 mm squares'."""
        text = f"{self.kind} {self.cols}x{self.rows} inner corners, {self.square_mm:g} mm squares"
        if self.kind == "charuco":
            text += f", {self.marker:g} mm markers, {self.dictionary}"
            if self.legacy_pattern:
                text += ", legacy pattern"
        return text


@functools.lru_cache(maxsize=8)
def _charuco(spec: BoardSpec):
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    board = cv2.aruco.CharucoBoard((spec.cols + 1, spec.rows + 1), spec.square_mm, spec.marker, dictionary)
    if spec.legacy_pattern:
        board.setLegacyPattern(True)
    return board, cv2.aruco.CharucoDetector(board)


@dataclass(frozen=True)
class BoardDetection:
    """The inner corners of a board found in one image, or why not.

    Falsy when the board was not found; ``reason`` then says why. Unpacks
    as ``corners, ids = detection``.

    Attributes
    ----------
    corners : (N, 2) float32 ndarray or None
        Corner positions, px.
    ids : (N,) int32 ndarray or None
        Corner ids (k = row * cols + column), increasing.
    object_mm : (N, 3) float32 ndarray or None
        The corners in the board frame, mm.
    reason : str or None
        Why the board was not found (None when it was).
    """

    corners: Optional[np.ndarray]
    ids: Optional[np.ndarray]
    object_mm: Optional[np.ndarray] = None
    reason: Optional[str] = None

    def __bool__(self) -> bool:
        return self.corners is not None

    def __iter__(self):
        yield self.corners
        yield self.ids

    def __len__(self) -> int:
        return 2

    @classmethod
    def failed(cls, reason: str) -> "BoardDetection":
        return cls(None, None, None, reason)


def _as_gray(image: Any, what: str = "image") -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise TypeError(f"{what}: expected a numpy array, got {type(image).__name__}")
    if image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim != 2:
        raise ValueError(f"{what}: expected a (height, width) gray image, got shape {image.shape}")
    if image.dtype != np.uint8:
        if image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        else:
            raise ValueError(f"{what}: expected uint8 (or uint16) pixels, got {image.dtype}")
    return np.ascontiguousarray(image)


def _sample(gray: np.ndarray, pt: np.ndarray, half: int) -> float:
    patch = cv2.getRectSubPix(gray, (2 * half + 1, 2 * half + 1), (float(pt[0]), float(pt[1])))
    return float(patch.mean())


def _orient_chessboard(gray: np.ndarray, corners: np.ndarray, spec: BoardSpec) -> np.ndarray:
    """Number the corners as the board frame B does (see module notes).

    A detector may return the grid mirrored or turned by 180 degrees. The
    grid's handedness fixes a mirror (seen from its front, B's x and y axes
    appear clockwise in the image), the colours of the squares at corner 0
    fix the turn: the square diagonally inward from it (B's square (1, 1))
    is black, its neighbour across the row (square (0, 1)) is white. With
    cols + rows even both ends look alike; corner 0 is then taken nearer the
    image's top left, which two upright cameras agree on.
    """
    g = corners.reshape(spec.rows, spec.cols, 2).astype(np.float64)
    ex = g[0, 1] - g[0, 0]
    ey = g[1, 0] - g[0, 0]
    if ex[0] * ey[1] - ex[1] * ey[0] < 0:  # mirrored: flip the columns
        g = g[:, ::-1]
    if (spec.cols + spec.rows) % 2 == 1:
        ex = g[0, 1] - g[0, 0]
        ey = g[1, 0] - g[0, 0]
        half = int(max(1, min(4, 0.15 * min(np.hypot(*ex), np.hypot(*ey)))))
        dark = _sample(gray, g[0, 0] + 0.5 * (ex + ey), half)
        light = _sample(gray, g[0, 0] + 0.5 * (ex - ey), half)
        if dark > light:
            g = g[::-1, ::-1]
    else:
        if g[-1, -1].sum() < g[0, 0].sum():
            g = g[::-1, ::-1]
    return g.reshape(-1, 2).astype(np.float32)


def _subpix(gray: np.ndarray, corners: np.ndarray, spec: BoardSpec) -> np.ndarray:
    g = corners.reshape(spec.rows, spec.cols, 2)
    d = min(np.linalg.norm(np.diff(g, axis=1), axis=2).min(), np.linalg.norm(np.diff(g, axis=0), axis=2).min())
    win = int(max(2, min(6, 0.4 * d)))
    c = corners.reshape(-1, 1, 2).astype(np.float32).copy()
    return cv2.cornerSubPix(gray, c, (win, win), (-1, -1), _SUBPIX_CRITERIA).reshape(-1, 2)


def detect_board(gray: np.ndarray, spec: BoardSpec) -> BoardDetection:
    """Find the board's inner corners in one image.

    Chessboard: ``cv2.findChessboardCorners`` (falling back to
    ``cv2.findChessboardCornersSB``), refined with ``cv2.cornerSubPix`` and
    numbered as the board frame (see :func:`_orient_chessboard`); the whole
    board must be visible. ChArUco: ``cv2.aruco.CharucoDetector``; any
    :data:`MIN_CHARUCO_CORNERS` or more corners not all on one line will do.

    Parameters
    ----------
    gray : (H, W) uint8 ndarray
        The image (BGR and uint16 images are converted).
    spec : BoardSpec

    Returns
    -------
    BoardDetection
        Falsy with a ``reason`` when the board was not found.
    """
    gray = _as_gray(gray)
    if spec.kind == "chessboard":
        size = (spec.cols, spec.rows)
        # the classic detector is fast (a few ms) and, refined by cornerSubPix,
        # accurate; the sector-based one finds boards the classic one misses
        found, corners = cv2.findChessboardCorners(
            gray, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            | cv2.CALIB_CB_FAST_CHECK)
        if not found:
            found, corners = cv2.findChessboardCornersSB(
                gray, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE)
        if not found or corners is None or len(corners) != spec.n_corners:
            return BoardDetection.failed(
                f"no {spec.cols}x{spec.rows} chessboard found (the whole board and its white "
                "margin must be in the image, sharp and evenly lit)")
        corners = _subpix(gray, corners.reshape(-1, 2), spec)
        corners = _orient_chessboard(gray, corners, spec)
        ids = np.arange(spec.n_corners, dtype=np.int32)
        return BoardDetection(corners, ids, spec.object_points())
    board, detector = _charuco(spec)
    ch_corners, ch_ids, marker_corners, _ = detector.detectBoard(gray)
    n_markers = 0 if marker_corners is None else len(marker_corners)
    if ch_ids is None or len(ch_ids) < MIN_CHARUCO_CORNERS:
        n = 0 if ch_ids is None else len(ch_ids)
        return BoardDetection.failed(
            f"{n} ChArUco corners found ({n_markers} markers), at least {MIN_CHARUCO_CORNERS} needed "
            f"(is it a {spec.describe()} board? is it sharp and large enough?)")
    ids = ch_ids.reshape(-1).astype(np.int32)
    order = np.argsort(ids)
    ids = ids[order]
    corners = ch_corners.reshape(-1, 2)[order].astype(np.float32)
    if board.checkCharucoCornersCollinear(ids.reshape(-1, 1)):
        return BoardDetection.failed(f"the {len(ids)} ChArUco corners found are all on one line")
    obj = np.asarray(board.getChessboardCorners(), np.float32).reshape(-1, 3)[ids]
    return BoardDetection(corners, ids, obj)


# --------------------------------------------------------------------------
# pairs in a folder
# --------------------------------------------------------------------------


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def _images_in(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                  key=lambda p: _natural_key(p.name))


def _list(names: list[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f", ... ({len(names)} in all)" if len(names) > limit else "")


_SIDE_NAME = re.compile(r"^(left|right)[_\-.]?(.*)$", re.IGNORECASE)


def find_pairs(folder: str | Path) -> list[tuple[str, Path, Path]]:
    """The stereo pairs of a calibration folder.

    Two layouts are recognised:

    - ``left/`` and ``right/`` subfolders holding images with the same
      names (the extension may differ): ``left/07.png`` + ``right/07.png``;
      the pair's name is the file's stem.
    - side by side, as OpenCV's samples: ``left07.jpg`` + ``right07.jpg``
      (also ``left_07``, ``Left-07``); the name is what follows the side.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    list of (name, left_path, right_path), in natural order of the names.

    Raises
    ------
    headplod.io.ContractError
        The folder does not exist, holds no pairs, or has images without a
        partner (all of them listed).
    """
    root = Path(folder)
    if not root.exists():
        raise io.ContractError(f"{root}: folder not found. Hint: give the folder of the calibration "
                               "image pairs", root)
    if not root.is_dir():
        raise io.ContractError(f"{root}: is a file, expected a folder of calibration image pairs", root)
    hint = ("expected left/ and right/ subfolders with images of the same names (left/00.png, "
            "right/00.png, ...) or side-by-side files leftNN.png and rightNN.png")
    sub_l, sub_r = root / "left", root / "right"
    if sub_l.is_dir() or sub_r.is_dir():
        if not (sub_l.is_dir() and sub_r.is_dir()):
            have, missing = (sub_l, sub_r) if sub_l.is_dir() else (sub_r, sub_l)
            raise io.ContractError(f"{root}: has {have.name}/ but no {missing.name}/ subfolder. "
                                   f"Hint: {hint}", root)
        left = {p.stem: p for p in _images_in(sub_l)}
        right = {p.stem: p for p in _images_in(sub_r)}
        where = (f"{sub_l}", f"{sub_r}")
    else:
        left, right = {}, {}
        for p in _images_in(root):
            m = _SIDE_NAME.match(p.stem)
            if m:
                (left if m.group(1).lower() == "left" else right)[m.group(2)] = p
        where = (f"{root}/left*", f"{root}/right*")
    if not left and not right:
        raise io.ContractError(f"{root}: no calibration images found. Hint: {hint} "
                               f"(image types: {', '.join(IMAGE_EXTENSIONS)})", root)
    only_l = sorted(set(left) - set(right), key=_natural_key)
    only_r = sorted(set(right) - set(left), key=_natural_key)
    if only_l or only_r:
        parts = []
        if only_l:
            parts.append(f"{len(only_l)} left image(s) without a right one: "
                         f"{_list([left[k].name for k in only_l])}")
        if only_r:
            parts.append(f"{len(only_r)} right image(s) without a left one: "
                         f"{_list([right[k].name for k in only_r])}")
        raise io.ContractError(
            f"{root}: unmatched images; " + "; ".join(parts)
            + f". Hint: every image in {where[0]} needs a partner of the same name in {where[1]}; "
            "delete or rename the odd ones", root)
    names = sorted(left, key=_natural_key)
    return [(n, left[n], right[n]) for n in names]


# --------------------------------------------------------------------------
# calibration
# --------------------------------------------------------------------------


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
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None, f"{what} {p} cannot be read as an image"
    try:
        return _as_gray(img, f"{what} {p}"), None
    except (TypeError, ValueError) as exc:
        return None, str(exc)


def _size_str(size) -> str:
    return f"{size[0]}x{size[1]}"


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
                     progress: Optional[Callable[[int, int], None]] = None) -> CalibrationResult:
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
        io.write_rig(out, result.rig)
    return result


# --------------------------------------------------------------------------
# coverage
# --------------------------------------------------------------------------


def _corners_of(det: Any) -> tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """(corners (N, 2), object (N, 3) or None) of a detection-like item."""
    if det is None:
        return None, None
    if isinstance(det, BoardDetection):
        return (det.corners, det.object_mm) if det else (None, None)
    if isinstance(det, np.ndarray):
        return det.reshape(-1, 2), None
    if isinstance(det, (tuple, list)) and len(det) >= 1:
        c = det[0]
        return (None, None) if c is None else (np.asarray(c).reshape(-1, 2), None)
    raise TypeError(f"expected a BoardDetection, an (N, 2) array or None, got {type(det).__name__}")


def _tilt(corners: np.ndarray, obj: np.ndarray) -> tuple[float, np.ndarray]:
    """Tilt of the board from the affine map board -> image (weak perspective).

    Returns (angle in degrees, unit image direction along which the board is
    foreshortened)."""
    A = np.column_stack([obj[:, :2], np.ones(len(obj))])
    M, *_ = np.linalg.lstsq(A, corners.astype(np.float64), rcond=None)
    J = M[:2].T  # image = J @ board + c
    U, s, _ = np.linalg.svd(J)
    ratio = float(np.clip(s[1] / s[0], 0.0, 1.0)) if s[0] > 0 else 1.0
    return math.degrees(math.acos(ratio)), U[:, 1]


def coverage_guide(detections_left: Iterable[Any], image_size, min_views: int = MIN_PAIRS) -> list[str]:
    """What poses a calibration still lacks, for a live guide.

    Checks, over the views the board was found in: every ninth of the image
    (3 x 3 grid) has had board corners in it; at least
    :data:`MIN_TILTED_VIEWS` views tilted by more than :data:`TILT_DEG`
    up/down and as many left/right (needs ``BoardDetection`` items, which
    carry the board coordinates); the board spans at least :data:`MIN_FILL`
    of the image in half of the views; there are ``min_views`` views.

    Parameters
    ----------
    detections_left : iterable
        One camera's detections: :class:`BoardDetection` (falsy ones are
        skipped), (N, 2) corner arrays (px), ``(corners, ids)`` tuples or None.
    image_size : (width, height), px.
    min_views : int

    Returns
    -------
    list of str
        One sentence per missing kind of pose; empty when coverage is good.
    """
    w, h = int(image_size[0]), int(image_size[1])
    views = [cv for cv in (_corners_of(d) for d in detections_left) if cv[0] is not None and len(cv[0])]
    if not views:
        return ["no board found yet: hold the whole board in view of both cameras"]
    advice = []
    hit = np.zeros(9, bool)
    fills = []
    tilt_ud = tilt_lr = 0
    n_tilt_known = 0
    for corners, obj in views:
        gx = np.clip((corners[:, 0] + 0.5) * 3 // w, 0, 2).astype(int)
        gy = np.clip((corners[:, 1] + 0.5) * 3 // h, 0, 2).astype(int)
        hit[gy * 3 + gx] = True
        span = corners.max(axis=0) - corners.min(axis=0)
        fills.append(max(span[0] / w, span[1] / h))
        if obj is not None and len(obj) >= 4:
            n_tilt_known += 1
            angle, direction = _tilt(corners, obj)
            if angle > TILT_DEG:
                if abs(direction[1]) > 0.5:
                    tilt_ud += 1
                if abs(direction[0]) > 0.5:
                    tilt_lr += 1
    if len(views) < min_views:
        advice.append(f"{len(views)} view(s) with the board so far, at least {min_views} needed "
                      "(10-20 recommended)")
    missing = [_CELL_NAMES[i] for i in range(9) if not hit[i]]
    if missing:
        advice.append(f"no board corners yet in the {', '.join(missing)} of the image: move the board "
                      "there (keeping it whole in both views)")
    if n_tilt_known:
        if tilt_ud < MIN_TILTED_VIEWS:
            advice.append(f"{tilt_ud} view(s) tilted up/down by more than {TILT_DEG:g} degrees, "
                          f"{MIN_TILTED_VIEWS} needed: turn the board about its horizontal axis by 20-40 degrees")
        if tilt_lr < MIN_TILTED_VIEWS:
            advice.append(f"{tilt_lr} view(s) tilted left/right by more than {TILT_DEG:g} degrees, "
                          f"{MIN_TILTED_VIEWS} needed: turn the board about its vertical axis by 20-40 degrees")
    big = sum(f >= MIN_FILL for f in fills)
    if 2 * big < len(fills):
        advice.append(f"the board is small in the images (it spans {100 * float(np.median(fills)):.0f}% of the "
                      f"image in a typical view): bring it closer, or use a bigger board, so that it spans "
                      f"{100 * MIN_FILL:.0f}-60%")
    return advice


# --------------------------------------------------------------------------
# report
# --------------------------------------------------------------------------


def _convergence_deg(R: np.ndarray) -> float:
    """Angle between the two optical axes, degrees."""
    z_right_in_left = R.T @ np.array([0.0, 0.0, 1.0])
    return math.degrees(math.acos(float(np.clip(z_right_in_left[2], -1.0, 1.0))))


def _std_line(result: CalibrationResult) -> str:
    """One line with the 1-sigma values written to rig.yaml as the tracker's prior."""
    def vec(v) -> str:
        return "n/a" if v is None else " ".join(f"{float(x):.3g}" for x in np.ravel(v))

    parts = []
    for side in ("left", "right"):
        sd = result.std_px.get(side)
        parts.append(f"{side} fx fy cx cy {vec(None if not sd else [sd[k] for k in ('fx', 'fy', 'cx', 'cy')])} px")
    parts.append(f"rotation vector {vec(result.std_rotation_deg)} deg")
    parts.append(f"T {vec(result.std_translation_mm)} mm")
    return "calibration 1-sigma (written to rig.yaml): " + "; ".join(parts)


def format_report(result: CalibrationResult) -> str:
    """A human-readable summary of a calibration, for the command line."""
    rig = result.rig
    lines = [f"board: {result.spec.describe()}",
             f"pairs: {len(result.used)} used, {len(result.rejected)} rejected"]
    for name, reason in result.rejected:
        lines.append(f"  rejected {name}: {reason}")
    lines.append(f"image size: {_size_str(rig.image_size)} px")
    for side, K, D in (("left", rig.K1, rig.D1), ("right", rig.K2, rig.D2)):
        sd = result.std_px.get(side, {})
        lines.append(
            f"{side:5s} camera: fx {K[0, 0]:.1f} ± {sd.get('fx', float('nan')):.1f}, "
            f"fy {K[1, 1]:.1f} ± {sd.get('fy', float('nan')):.1f}, "
            f"cx {K[0, 2]:.1f} ± {sd.get('cx', float('nan')):.1f}, "
            f"cy {K[1, 2]:.1f} ± {sd.get('cy', float('nan')):.1f} px; "
            f"distortion {' '.join(f'{v:+.4f}' for v in D)}")
    c = rig.right_center_mm
    lines.append(f"baseline: {rig.baseline_mm:.1f} mm; right camera at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) mm "
                 f"in the left camera's frame; optical axes converge by {_convergence_deg(rig.R):.1f} deg")
    lines.append(f"reprojection RMS: left {result.rms_left_px:.3f} px, right {result.rms_right_px:.3f} px, "
                 f"stereo {result.rms_stereo_px:.3f} px (single-camera calibrations: "
                 f"{result.rms_zhang_px[0]:.3f}, {result.rms_zhang_px[1]:.3f} px)")
    lines.append(_std_line(result))
    worst = sorted(result.pair_errors_px.items(), key=lambda kv: -max(kv[1]))[:3]
    if worst:
        lines.append("worst pairs: " + ", ".join(f"{n} ({max(e):.2f} px)" for n, e in worst))
    if result.rms_stereo_px > 1.0:
        lines.append("WARNING: stereo RMS over 1 px: check the board's square size, that it is flat, and "
                     "that the two images of a pair were taken at the same moment")
    elif result.rms_stereo_px > 0.5:
        lines.append("note: stereo RMS over 0.5 px; a sharp, flat board usually gives 0.1-0.4 px")
    if result.coverage:
        lines.append("coverage: the poses could be better:")
        lines += [f"  {m}" for m in result.coverage]
    return "\n".join(lines)
