"""Advice while capturing calibration pairs: which views the set still lacks (coverage, tilt, fill)."""

from __future__ import annotations

import math
from typing import Any, Iterable, Optional

import numpy as np

from .board import BoardDetection
from .pairs import MIN_PAIRS

#: A view counts as tilted for :func:`coverage_guide` beyond this angle.
TILT_DEG = 20.0
#: Views tilted about each axis (up/down, left/right) coverage_guide asks for.
MIN_TILTED_VIEWS = 2
#: The board should span at least this fraction of the image (the larger of
#: its bounding box's width and height fractions) in most views.
MIN_FILL = 0.25
_CELL_NAMES = ("top-left", "top", "top-right", "left", "centre", "right",
               "bottom-left", "bottom", "bottom-right")


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

