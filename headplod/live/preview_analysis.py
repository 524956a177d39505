"""What a frame of ``headplod preview`` shows: each camera's blobs, mask and saturated blobs, the epipolar
curves of a rig, and the advice those measurements call for.

- :class:`AdviceSettings` holds every threshold of the advice, :func:`advise` turns two
  :class:`ViewAnalysis` and the frame's skew (ms) and rate (Hz) into a list of :class:`Advice`;
- :class:`ViewAnalysis` (one camera) and :class:`FrameAnalysis` (the frame) are what a picture shows;
- :func:`threshold_mask`, :func:`fundamental_matrix`, :func:`epipolar_curves` are the measurements.

Image pixels (u, v): u right, v down, (0, 0) the centre of the top-left pixel (docs/contract.md), as in
OpenCV's projection functions. :class:`~headplod.live.preview.Previewer` composes these with the tracker,
and :mod:`headplod.live.preview_picture` draws them.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .. import io
from ..tracking.detect import Blobs, DetectionParams, above_threshold
from ..tracking.geometry import essential_matrix

__all__ = ["AdviceSettings", "Advice", "advise", "ViewAnalysis", "FrameAnalysis", "threshold_mask", "box_counts",
           "fundamental_matrix", "epipolar_curves", "EPILINE_SAMPLES", "SIDES"]

#: Points along each epipolar curve.
EPILINE_SAMPLES = 96
#: The two cameras' names, in the order of the views.
SIDES = ("left", "right")

@dataclass(frozen=True)
class AdviceSettings:
    """When the preview gives advice: every threshold, with its unit.

    Attributes
    ----------
    saturated_dn : int
        A pixel at or above this value is clipped, DN (255 for 8-bit images).
    saturated_min_px : int
        A blob with at least this many clipped pixels is saturated, px: its
        centre is then a plateau's, less precise than a peak's.
    markers : int
        Blobs an image should hold: the glasses' five markers.
    dim_peak_dn : float
        Markers whose median peak above the local background is below this are
        dim, DN: noise then moves their centres.
    max_skew_ms : float
        A stereo skew ``|t_right - t|`` above this is advised on, ms (half a
        period at 60 Hz).
    min_rate_fraction : float
        A measured frame rate below this fraction of the requested one is
        advised on.
    rate_window_frames : int
        The frame rate is measured over the times of this many recent frames.
    rate_min_frames : int
        ... and judged against the requested one from this many frames on.
    """

    saturated_dn: int = 255
    saturated_min_px: int = 4
    markers: int = 5
    dim_peak_dn: float = 40.0
    max_skew_ms: float = 8.0
    min_rate_fraction: float = 0.9
    rate_window_frames: int = 30
    rate_min_frames: int = 10


@dataclass(frozen=True)
class Advice:
    """One piece of advice: ``kind`` (e.g. ``'saturated'``), the camera it is about (``'left'``,
    ``'right'``, or None for the pair) and the line shown. (kind, side) is what is counted over frames."""

    kind: str
    text: str
    side: str | None = None


def advise(views, skew_ms, rate_hz, rate_frames: int, requested_fps, settings: AdviceSettings) -> list[Advice]:
    """The advice a frame's measurements call for.

    Parameters
    ----------
    views : sequence of 2 ViewAnalysis
        Left, right.
    skew_ms : float or None
        ``|t_right - t|``, ms.
    rate_hz : float or None
        Frame rate measured from the frames' times, Hz, over ``rate_frames`` frames.
    requested_fps : float or None
        The rate asked of live cameras, Hz; None for a replay.
    settings : AdviceSettings
    """
    s = settings
    out = []
    for side, view in zip(SIDES, views):
        b = view.blobs
        n = len(b)
        if n == 0:
            out.append(Advice("no_blobs", f"{side}: no blobs above threshold ({b.threshold_dn:.0f} DN): raise "
                                          "--exposure or --gain, or check the IR light", side))
            continue
        saturated = view.saturated
        if saturated.any():
            out.append(Advice("saturated", f"{side}: markers saturated ({int(saturated.sum())} of {n} blobs with "
                                           f"{s.saturated_min_px}+ px at {s.saturated_dn} DN): lower --exposure "
                                           "(or --gain)", side))
        if n > s.markers:
            out.append(Advice("too_many", f"{side}: more than {s.markers} blobs ({n}): glints or lamps; move shiny "
                                          "things and IR lamps out of view, or lower --gain", side))
        elif n < s.markers:
            out.append(Advice("too_few", f"{side}: {n} blobs, {s.markers} needed: a marker hidden, turned away or "
                                         "too dim; face the cameras, or raise --exposure or --gain", side))
        if not saturated.any():
            peak = float(np.median(b.peak_dn))
            if peak < s.dim_peak_dn:
                out.append(Advice("dim", f"{side}: markers dim (median peak {peak:.0f} DN above the background): "
                                         "raise --exposure or --gain, or bring the IR light closer", side))
    if skew_ms is not None and skew_ms > s.max_skew_ms:
        out.append(Advice("skew", f"skew {skew_ms:.1f} ms above {s.max_skew_ms:g} ms: the cameras do not expose "
                                  "together; give each camera its own USB controller and the same --fps"))
    if (requested_fps and rate_hz is not None and rate_frames >= s.rate_min_frames
            and rate_hz < s.min_rate_fraction * requested_fps):
        out.append(Advice("rate", f"frame rate {rate_hz:.1f} Hz below the {requested_fps:g} Hz requested: lower "
                                  "--exposure (a long one caps the rate), try --fourcc MJPG, or another USB port"))
    return out


@dataclass
class ViewAnalysis:
    """One camera's image and what was found in it.

    Attributes
    ----------
    image : (H, W) uint8
        The camera's image, px.
    blobs : Blobs
        The detection's blobs (centres in this image's pixels, u right, v down).
    mask : (H, W) bool
        The pixels above the detection threshold.
    saturated_px : (n,) int
        Pixels at or above ``AdviceSettings.saturated_dn`` in each blob's box, px.
    saturated : (n,) bool
        The blobs with at least ``AdviceSettings.saturated_min_px`` of them.
    markers_px : (5, 2) float64
        P0..P4 as identified, px; NaN where not identified.
    epilines : list of (k, 2) float64
        The epipolar curves of the other image's blobs in this image, px
        (points along each, through the lens distortion); empty without a rig.
    """

    image: np.ndarray
    blobs: Blobs
    mask: np.ndarray
    saturated_px: np.ndarray
    saturated: np.ndarray
    markers_px: np.ndarray = field(default_factory=lambda: np.full((5, 2), np.nan))
    epilines: list = field(default_factory=list)


@dataclass
class FrameAnalysis:
    """Everything a frame's picture shows.

    Attributes
    ----------
    index : int
        The source's frame index.
    t : float or None
        The left image's time, s.
    views : tuple of 2 ViewAnalysis, or None
        Left and right; None when the frame failed (``error``).
    size : (width, height)
        One image's size, px.
    rig : bool
        A rig was there (epipolar lines, identification).
    skew_ms : float or None
        ``|t_right - t|``, ms.
    rate_hz : float or None
        Frame rate from the recent frames' times, Hz.
    identified : bool
        The tracker labeled the markers P0..P4.
    pose_ok : bool
        ... and verified a pose.
    position_mm : (3,) or None
        P1 in the world (left camera) frame, mm, when ``pose_ok``.
    reason : str or None
        Why there is no pose (the tracker's reason).
    advice : list of Advice
    warning : str or None
        The frame's own warning (e.g. a colour image converted to gray).
    error : str or None
        Why the frame could not be shown (the source's error, or a fault while annotating it).
    """

    index: int
    t: float | None
    views: tuple | None
    size: tuple
    rig: bool
    skew_ms: float | None = None
    rate_hz: float | None = None
    identified: bool = False
    pose_ok: bool = False
    position_mm: np.ndarray | None = None
    reason: str | None = None
    advice: list = field(default_factory=list)
    warning: str | None = None
    error: str | None = None


def threshold_mask(image: np.ndarray, blobs: Blobs, params: DetectionParams) -> np.ndarray:
    """The pixels :func:`~headplod.tracking.detect.detect_blobs` found above its threshold, (H, W) bool: its own
    rule (:func:`~headplod.tracking.detect.above_threshold`) at the threshold and background ``blobs`` holds."""
    return above_threshold(image, blobs.threshold_dn, blobs.background_dn, params) > 0


def box_counts(flags: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Count of true pixels of ``flags`` (H, W) inside each box (n, 4) x, y, w, h px (summed-area table)."""
    if len(boxes) == 0:
        return np.zeros(0, np.int64)
    table = cv2.integral(flags.astype(np.uint8)).astype(np.int64)     # (H + 1, W + 1)
    x, y, w, h = (np.asarray(boxes, np.int64)[:, i] for i in range(4))
    return table[y + h, x + w] - table[y, x + w] - table[y + h, x] + table[y, x]


def fundamental_matrix(rig: io.Rig) -> np.ndarray:
    """F (3, 3) of the rig for undistorted pixels: ``x_rightᵀ F x_left = 0`` for homogeneous pixel
    coordinates (u, v, 1) of the two images' ideal (distortion-free) cameras K1, K2."""
    E = essential_matrix(rig.R, rig.T)
    return np.linalg.inv(rig.K2).T @ E @ np.linalg.inv(rig.K1)


def epipolar_curves(points_px: np.ndarray, rig: io.Rig, from_camera: int,
                    samples: int = EPILINE_SAMPLES) -> tuple[np.ndarray, list]:
    """The epipolar lines of points of one image in the other image.

    Parameters
    ----------
    points_px : (n, 2)
        Pixels (u, v) in the image of ``from_camera`` (0 left, 1 right), as
        detected (with the lens distortion).
    rig : io.Rig
    from_camera : {0, 1}
    samples : int
        Points along each curve.

    Returns
    -------
    lines : (n, 3) float64
        ``a u + b v + c = 0`` with ``a² + b² = 1`` in the other image's
        undistorted pixels (``cv2.computeCorrespondEpilines`` on the points
        undistorted through ``cv2.undistortPoints(..., P=K)``, with
        :func:`fundamental_matrix`).
    curves : list of n (k, 2) float64
        Each line through the other camera's distortion, in its image's pixels
        as detected (k ≤ ``samples``: the points that fall within the lens
        model's reach, the undistorted image corners' radius).
    """
    pts = np.asarray(points_px, np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 3)), []
    K_from, D_from = (rig.K1, rig.D1) if from_camera == 0 else (rig.K2, rig.D2)
    K_to, D_to = (rig.K2, rig.D2) if from_camera == 0 else (rig.K1, rig.D1)
    ideal = cv2.undistortPoints(pts, K_from, D_from, P=K_from)
    lines = cv2.computeCorrespondEpilines(ideal, from_camera + 1, fundamental_matrix(rig)).reshape(-1, 3)
    lines = lines.astype(np.float64)
    width, height = rig.image_size
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], np.float64)
    reach = 1.05 * np.linalg.norm(cv2.undistortPoints(corners.reshape(-1, 1, 2), K_to, D_to).reshape(-1, 2),
                                  axis=1).max()
    margin = 0.25 * max(width, height)
    K_inv = np.linalg.inv(K_to)
    curves = []
    for a, b, c in lines:
        if abs(b) >= abs(a):        # more horizontal: sample along u
            u = np.linspace(-margin, width - 1 + margin, samples)
            v = -(a * u + c) / b
        else:
            v = np.linspace(-margin, height - 1 + margin, samples)
            u = -(b * v + c) / a
        normalized = np.column_stack([u, v, np.ones_like(u)]) @ K_inv.T       # rays, z = 1
        normalized = normalized[np.linalg.norm(normalized[:, :2], axis=1) <= reach]
        if len(normalized) < 2:
            curves.append(np.zeros((0, 2)))
            continue
        seen, _ = cv2.projectPoints(normalized, np.zeros(3), np.zeros(3), K_to, D_to)
        curves.append(seen.reshape(-1, 2))
    return lines, curves
