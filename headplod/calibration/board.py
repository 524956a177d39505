"""The calibration board: its specification and the detection of its inner corners in one image.

Board frame B (``docs/contract.md``): origin at the top-left outer corner
of the pattern, x along the columns, y along the rows, z into the board;
inner corner k = i * cols + j is at ((j + 1) s, (i + 1) s, 0) mm. Corner
arrays are (N, 2) float32 (u, v) px, OpenCV's pixel convention.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Optional

import cv2
import numpy as np

#: Fewest ChArUco corners a view (and a pair, in common) must have.
MIN_CHARUCO_CORNERS = 6
#: Kinds of board (``BoardSpec.kind``, ``headplod calibrate --board``).
BOARD_KINDS = ("chessboard", "charuco")
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-3)


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
        if self.kind not in BOARD_KINDS:
            raise ValueError(f"BoardSpec.kind is {self.kind!r}, expected one of {', '.join(BOARD_KINDS)}")
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

