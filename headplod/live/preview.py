"""``headplod preview``: both cameras side by side, annotated, to set up the cameras and the light (issue 25).

    headplod preview [--source SPEC] [--calib rig.yaml] [--out DIR [--frames N]] [-q]
                     [--fps F] [--fourcc GREY|YUYV|MJPG] [--exposure E] [--gain G] [--markers FILE]

Each frame of the source (any ``--source SPEC``, as ``headplod track`` takes it)
becomes one picture: the left image on the left, the right image on the right,
and a panel of text under them. On each image:

- the pixels above the detection threshold, tinted red (the mask detection
  thresholded), and the threshold used, in DN, with the background and noise
  it came from;
- every blob: a circle around its centroid (radius from its area), its area in
  px; red when it is saturated, yellow when it is a glint;
- the markers P0..P4 as the tracker identified them (green: a verified pose;
  orange: identified, no pose, the panel says why);
- with a rig (``--calib``, or the dataset's own ``rig.yaml``): the epipolar
  line of every blob of the other image (magenta), from ``F`` of the rig
  through ``cv2.computeCorrespondEpilines`` on undistorted pixels, drawn
  through the lens distortion as a curve. A marker and its partner lie on each
  other's line when the rig is right.

The panel gives the frame, the frame rate measured from the frames' times, the
stereo skew ``|t_right - t|`` and advice derived from the measurements
(:class:`AdviceSettings` holds every threshold): saturated markers, no blobs,
too many blobs, too few, dim markers, a large skew, a rate below the one
requested.

Without a rig (cameras not calibrated yet) the threshold and the blobs are
still shown; identification needs the rig (the tracker picks the left/right
pair of labelings by the epipolar geometry), so the images say "no rig:
epipolar lines and identification after 'headplod calibrate'".

Detection and identification are the tracker's own: :class:`~headplod.tracking.tracker.Tracker`
(re-detecting every frame, the rig's online refinement off) and, without a
rig, :func:`~headplod.tracking.detect.detect_blobs` with the same parameters.

Where the pictures go: with ``--out DIR``, one PNG per frame,
``DIR/preview_0000.png``, ``preview_0001.png``, ... (each written under a
temporary name, then renamed), ``--frames N`` of them (default
:data:`HEADLESS_FRAMES`); without it an OpenCV window (q or Esc closes it).
The installed OpenCV may have no GUI (``opencv-contrib-python-headless``), or
there may be no display: then the command refuses in one line and says to
use ``--out DIR``.

Coordinates: image pixels (u, v), u right, v down, (0, 0) the *centre* of the
top-left pixel (docs/contract.md), which is also the convention of OpenCV's
projection functions and of its drawing functions at integer (and, with
``shift``, fixed-point) coordinates, so nothing is shifted by half a pixel. In
the composite picture the right image's pixel (u, v) is at (u + width, v).

Exit status: 0 success (a fault in one frame is that frame's picture, saying
so, and counted); 1 unreadable input (a source, rig or marker file that
cannot be read, a source that gives no frame) or an output that cannot be
written; 2 bad usage. Every option is checked and the source opened before
anything is written; nothing is ever written into the dataset folder being
read.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import sys
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .. import io
from ..argtypes import add_quiet_argument, frame_count
from ..capture import open_source, source_kind, synthetic_preset, v4l2_devices
from ..capture.synthetic import ensure_dataset
from ..capture.command import DEFAULT_FPS, add_camera_settings
from ..progress import Progress
from ..tracking.detect import Blobs, DetectionParams, above_threshold, detect_blobs, estimate_background
from ..tracking.geometry import essential_matrix

__all__ = ["add_preview_arguments", "run_preview", "AdviceSettings", "Advice", "ViewAnalysis", "FrameAnalysis",
           "Previewer", "threshold_mask", "fundamental_matrix", "epipolar_curves", "render", "composite_size",
           "HEADLESS_FRAMES", "OUT_NAME", "NO_RIG_NOTE"]

#: Frames written with ``--out`` when ``--frames`` is not given.
HEADLESS_FRAMES = 10
#: The name of frame k's picture in ``--out DIR`` (k counts the frames shown, from 0).
OUT_NAME = "preview_{:04d}.png"
#: The names OUT_NAME gives, with the frame number as group 1 (pictures past 9999 take more digits).
_OUT_PATTERN = re.compile(r"preview_(\d{4,})\.png")
#: Frame rate requested from live cameras when ``--fps`` is not given, Hz (as ``headplod track``).
LIVE_FPS = DEFAULT_FPS
#: What the pictures say when there is no rig.
NO_RIG_NOTE = "no rig: epipolar lines and identification after 'headplod calibrate'"
#: Title of the window.
WINDOW_NAME = "headplod preview"
#: Lines of text in the panel under the images.
PANEL_LINES = 8
#: Most epipolar lines drawn in an image (the other image's blobs beyond these, brightest first, are left out).
MAX_EPILINES = 16
#: Points along each epipolar curve.
EPILINE_SAMPLES = 96

# Colours, BGR.
_MASK_TINT = (0, 0, 255)
_MASK_ALPHA = 0.45
_BLOB = (255, 255, 0)
_GLINT = (0, 255, 255)
_SATURATED = (0, 0, 255)
_EPILINE = (255, 0, 255)
_MARKER_OK = (0, 255, 0)
_MARKER_NO_POSE = (0, 165, 255)
_TEXT = (255, 255, 255)
_ADVICE = (0, 255, 255)
_FAULT = (60, 60, 255)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_SHIFT = 4                                   # fixed-point bits of the sub-pixel drawing
_SIDES = ("left", "right")


# ---------------------------------------------------------------------------
# settings and advice
# ---------------------------------------------------------------------------

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
    for side, view in zip(_SIDES, views):
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


# ---------------------------------------------------------------------------
# what a frame shows
# ---------------------------------------------------------------------------

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


def _box_counts(flags: np.ndarray, boxes: np.ndarray) -> np.ndarray:
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


class Previewer:
    """Analyses frames and draws their pictures, with the tracker's detection and identification.

    Parameters
    ----------
    rig : io.Rig or None
        Without one: blobs only (no epipolar lines, no identification).
    markers : io.MarkerModel, optional
        The glasses (default: the contract's model).
    detection : DetectionParams
        As the tracker's (its defaults: the adaptive threshold).
    settings : AdviceSettings
    requested_fps : float, optional
        The rate asked of live cameras, Hz (None for a replay: no rate advice).
    """

    def __init__(self, rig: io.Rig | None, markers: io.MarkerModel | None = None,
                 detection: DetectionParams = DetectionParams(), settings: AdviceSettings = AdviceSettings(),
                 requested_fps: float | None = None):
        self.rig, self.detection, self.settings, self.requested_fps = rig, detection, settings, requested_fps
        self.size = tuple(rig.image_size) if rig is not None else None
        self.tracker = None
        if rig is not None:
            # Imported on use: the tracker pulls in scipy (`headplod --help` imports this module).
            from ..tracking.rig_refine_config import RigRefineConfig
            from ..tracking.tracker import Tracker, TrackerConfig

            config = TrackerConfig(detection=detection, track=False, rig_refine=RigRefineConfig(enabled=False))
            self.tracker = Tracker(rig, markers or io.default_marker_model(), config,
                                   calibration_std=io.rig_calibration_std(rig))
        self._times = deque(maxlen=settings.rate_window_frames)

    # -- analysis ------------------------------------------------------------

    def analyse(self, frame: io.Frame) -> FrameAnalysis:
        """What ``frame`` shows (raises on a fault; :meth:`picture` turns one into the frame's failure)."""
        base = dict(index=int(frame.index), t=frame.t, rig=self.rig is not None, warning=frame.warning)
        if frame.error is not None or frame.left is None or frame.right is None:
            return FrameAnalysis(views=None, size=self.size or (640, 480), error=frame.error or "no images", **base)
        images = (frame.left, frame.right)
        self.size = (images[0].shape[1], images[0].shape[0])
        skew = getattr(frame, "skew_ms", None)
        if skew is None:
            skew = 0.0 if frame.t_right is None else abs(frame.t_right - frame.t) * 1000.0
        if frame.t is not None and math.isfinite(frame.t):
            self._times.append(float(frame.t))
        rate = self._rate()

        result = None
        if self.tracker is not None:
            result = self.tracker.process(images[0], images[1], frame.t, frame.t_right)
        blobs = tuple(b if b is not None else detect_blobs(img, self.detection, background=estimate_background(img))
                      for b, img in zip(result.blobs if result is not None else (None, None), images))
        views = []
        for img, b in zip(images, blobs):
            clipped = _box_counts(img >= self.settings.saturated_dn, b.bbox_px)
            views.append(ViewAnalysis(img, b, threshold_mask(img, b, self.detection), clipped,
                                      clipped >= self.settings.saturated_min_px))
        identified = result is not None and result.marker_blob is not None
        if identified:
            for cam in range(2):
                views[cam].markers_px = np.asarray(result.centers_px[cam], np.float64)
        if self.rig is not None and all(tuple(v.image.shape[::-1]) == tuple(self.rig.image_size) for v in views):
            for cam in range(2):
                other = views[1 - cam].blobs
                order = np.argsort(-other.flux_dn)[:MAX_EPILINES]
                views[cam].epilines = epipolar_curves(other.centers_px[order], self.rig, 1 - cam)[1]
        analysis = FrameAnalysis(views=tuple(views), size=self.size, skew_ms=skew, rate_hz=rate,
                                 identified=identified, pose_ok=bool(result is not None and result.ok),
                                 position_mm=None if result is None or not result.ok else result.position_mm,
                                 reason=None if result is None else result.reason, **base)
        analysis.advice = advise(views, skew, rate, len(self._times), self.requested_fps, self.settings)
        return analysis

    def _rate(self) -> float | None:
        """Frames per second over the recent frames' times, Hz; None before two frames or for times that
        do not advance."""
        if len(self._times) < 2:
            return None
        span = self._times[-1] - self._times[0]
        return (len(self._times) - 1) / span if span > 0 else None

    def picture(self, frame: io.Frame) -> tuple[np.ndarray, FrameAnalysis]:
        """The frame's annotated picture (:func:`render`) and its analysis; never raises for the frame's
        own fault: an exception while analysing or drawing it gives a picture saying so (``error`` set)."""
        try:
            analysis = self.analyse(frame)
            return render(analysis), analysis
        except Exception as exc:            # noqa: BLE001 -- one frame's fault is that frame's failure
            from ..tracking.tracker import internal_error_reason

            analysis = FrameAnalysis(index=int(getattr(frame, "index", -1)), t=getattr(frame, "t", None),
                                     views=None, size=self.size or (640, 480), rig=self.rig is not None,
                                     error=internal_error_reason(exc))
            return render(analysis), analysis


# ---------------------------------------------------------------------------
# drawing
# ---------------------------------------------------------------------------

def _font_scale(width: int) -> float:
    """Text size for images ``width`` px wide (OpenCV's Hershey scale)."""
    return float(np.clip(width / 1200.0, 0.35, 1.2))


def _line_px(width: int) -> int:
    """Height of a line of text, px."""
    return int(round(40 * _font_scale(width)))


def composite_size(width: int, height: int) -> tuple[int, int]:
    """(width, height) of the picture of two ``width`` x ``height`` px images: side by side, the panel under."""
    return 2 * width, height + PANEL_LINES * _line_px(width) + _line_px(width) // 2


def _fixed(u: float, v: float) -> tuple[int, int]:
    return int(round(u * (1 << _SHIFT))), int(round(v * (1 << _SHIFT)))


def _text(image, s: str, u: int, v: int, scale: float, colour) -> None:
    """``s`` (ASCII) with its baseline at (u, v) px, on a black box so it reads on any background."""
    thick = max(1, int(round(2 * scale)))
    (w, h), base = cv2.getTextSize(s, _FONT, scale, thick)
    cv2.rectangle(image, (u - 2, v - h - 2), (u + w + 2, v + base), (0, 0, 0), -1)
    cv2.putText(image, s, (u, v), _FONT, scale, colour, thick, cv2.LINE_AA)


def _draw_view(canvas: np.ndarray, view: ViewAnalysis, side: str, offset: int, analysis: FrameAnalysis) -> None:
    """One camera's image and its annotations into ``canvas`` at column ``offset``."""
    h, w = view.image.shape
    gray = cv2.cvtColor(view.image, cv2.COLOR_GRAY2BGR)
    tinted = cv2.addWeighted(gray, 1.0 - _MASK_ALPHA, np.full_like(gray, _MASK_TINT), _MASK_ALPHA, 0.0)
    np.copyto(gray, tinted, where=view.mask[:, :, None])
    canvas[:h, offset:offset + w] = gray
    sub = canvas[:h, offset:offset + w]
    scale = _font_scale(w)
    for curve in view.epilines:
        if len(curve) >= 2:
            pts = np.round(curve * (1 << _SHIFT)).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(sub, [pts], False, _EPILINE, 1, cv2.LINE_AA, _SHIFT)
    b = view.blobs
    for i in range(len(b)):
        u, v = b.centers_px[i]
        radius = math.sqrt(b.area_px[i] / math.pi) + 4.0
        colour = _SATURATED if view.saturated[i] else (_GLINT if b.glint[i] else _BLOB)
        cv2.circle(sub, _fixed(u, v), int(round(radius * (1 << _SHIFT))), colour, 1, cv2.LINE_AA, _SHIFT)
        cv2.drawMarker(sub, (int(round(u)), int(round(v))), colour, cv2.MARKER_CROSS, 5, 1)
        _text(sub, f"{int(b.area_px[i])}", int(round(u + radius)), int(round(v + radius + 10 * scale)),
              0.8 * scale, colour)
    colour = _MARKER_OK if analysis.pose_ok else _MARKER_NO_POSE
    for k, (u, v) in enumerate(view.markers_px):
        if np.isfinite(u) and np.isfinite(v):
            _text(sub, f"P{k}", int(round(u - 12 * scale)), int(round(v - 14 * scale - 4)), scale, colour)
    line = _line_px(w)
    _text(sub, f"{side}: threshold {b.threshold_dn:.1f} DN (background {b.background_dn:.1f}, noise "
               f"{b.noise_dn:.1f} DN), {len(b)} blobs", 8, line, scale, _TEXT)
    if not analysis.rig:
        _text(sub, NO_RIG_NOTE, 8, h - line // 2, scale, _ADVICE)


def render(analysis: FrameAnalysis) -> np.ndarray:
    """The picture of a frame, (height + panel, 2 width, 3) uint8 BGR (:func:`composite_size`).

    The left image at columns [0, width), the right at [width, 2 width), the
    panel of text under them; a failed frame (``error``) is a dark picture of
    the same size saying why.
    """
    w, h = analysis.size
    cw, ch = composite_size(w, h)
    canvas = np.zeros((ch, cw, 3), np.uint8)
    scale, line = _font_scale(w), _line_px(w)
    rows = []
    if analysis.views is None:
        canvas[:h] = 40
        rows.append((f"frame {analysis.index}: FAILED: {analysis.error}", _FAULT))
    else:
        for cam, view in enumerate(analysis.views):
            _draw_view(canvas, view, _SIDES[cam], cam * w, analysis)
        rate = "-" if analysis.rate_hz is None else f"{analysis.rate_hz:.1f} Hz"
        skew = "-" if analysis.skew_ms is None else f"{analysis.skew_ms:.1f} ms"
        t = "-" if analysis.t is None else f"{analysis.t:.3f} s"
        rows.append((f"frame {analysis.index}  t {t}  rate {rate} (from frame times)  skew |t_right - t| {skew}",
                     _TEXT))
        if not analysis.rig:
            rows.append((NO_RIG_NOTE, _ADVICE))
        elif analysis.pose_ok:
            p = analysis.position_mm
            rows.append((f"markers P0..P4 identified; pose: P1 ({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f}) mm", _MARKER_OK))
        elif analysis.identified:
            rows.append((f"markers P0..P4 identified, no pose: {analysis.reason}", _MARKER_NO_POSE))
        else:
            rows.append((f"markers not identified: {analysis.reason}", _MARKER_NO_POSE))
        if analysis.warning:
            rows.append((f"warning: {analysis.warning}", _ADVICE))
        rows += [(a.text, _ADVICE) for a in analysis.advice]
        if not analysis.advice:
            rows.append(("advice: none; the images look right", _MARKER_OK))
        rows.append(("red: above threshold; circles: blobs (area px), red saturated, yellow glint; "
                     "magenta: epipolar lines of the other image's blobs", (200, 200, 200)))
    if len(rows) > PANEL_LINES:
        rows = rows[:PANEL_LINES - 1] + [(f"(+{len(rows) - PANEL_LINES + 1} more lines)", _TEXT)]
    for k, (s, colour) in enumerate(rows):
        _text(canvas, _ascii(s), 8, h + (k + 1) * line, scale, colour)
    return canvas


def _ascii(s: str) -> str:
    """OpenCV's Hershey fonts draw ASCII only: the rest becomes '?'."""
    return s.encode("ascii", "replace").decode("ascii")


# ---------------------------------------------------------------------------
# where the pictures go
# ---------------------------------------------------------------------------

def window_problem() -> str | None:
    """Why no OpenCV window can be opened here (no GUI in the OpenCV build, no display), or None."""
    gui = re.search(r"^\s*GUI:\s*(\S+)", cv2.getBuildInformation(), re.MULTILINE)
    if gui is not None and gui.group(1).upper() == "NONE":
        return "the installed OpenCV has no GUI (opencv-python-headless)"
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "there is no display (DISPLAY is not set)"
    return None


class _Folder:
    """``--out DIR``: frame k's picture as ``DIR/preview_kkkk.png``, whole or not at all."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.written: list[Path] = []

    def show(self, k: int, picture: np.ndarray) -> bool:
        path = self.folder / OUT_NAME.format(k)

        def write(name: str) -> None:
            if not cv2.imwrite(name, picture):
                raise OSError(f"{path}: OpenCV could not write the PNG")
        io.write_atomically(path, write, suffix=".png")
        self.written.append(path)
        return True

    def remove_stale(self) -> int:
        """Remove the pictures of an earlier, longer run (``preview_kkkk.png`` past the last one this run wrote), so
        the folder holds one run; the number removed. Called when the run ends as it should: a run that fails
        halfway leaves the earlier pictures."""
        stale = [p for p in self.folder.glob("preview_*.png")
                 if (m := _OUT_PATTERN.fullmatch(p.name)) and int(m.group(1)) >= len(self.written)]
        for path in stale:
            path.unlink(missing_ok=True)
        return len(stale)

    def close(self) -> None:
        pass


class _Window:
    """An OpenCV window; q or Esc, or closing it, ends the preview."""

    def __init__(self):
        cv2.namedWindow(WINDOW_NAME, cv2.WINDOW_AUTOSIZE)

    def show(self, k: int, picture: np.ndarray) -> bool:
        cv2.imshow(WINDOW_NAME, picture)
        key = cv2.waitKey(1) & 0xFF
        return key not in (ord("q"), 27) and cv2.getWindowProperty(WINDOW_NAME, cv2.WND_PROP_VISIBLE) >= 1

    def close(self) -> None:
        cv2.destroyWindow(WINDOW_NAME)


# ---------------------------------------------------------------------------
# the command
# ---------------------------------------------------------------------------

PREVIEW_EPILOG = (f"Headless (--out DIR): one PNG per frame, DIR/{OUT_NAME.format(0)}, ..., written under a "
                  f"temporary name and renamed; {HEADLESS_FRAMES} frames unless --frames N. Without --out: an "
                  "OpenCV window (q or Esc closes it); where OpenCV has no GUI or there is no display, use --out. "
                  "Exit status: 0 success (a fault in one frame is that frame's picture, saying so); 1 unreadable "
                  "input or an output that cannot be written; 2 bad usage (nothing is written).")


class _Usage(Exception):
    """A command-line mistake (exit status 2); the message says what to do."""


def add_preview_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """``headplod preview``'s options; returns the parser."""
    parser.add_argument("--source", metavar="SPEC", default="synthetic",
                        help="what to show: a dataset folder, LEFT.avi,RIGHT.avi, 'synthetic[:PRESET]' (default: "
                             "the built-in synthetic sequence), or live cameras 'v4l2:/dev/video0,/dev/video2' "
                             "(v4l2:0,2) or 'v4l2:auto' (the cameras --calib names)")
    parser.add_argument("--calib", metavar="rig.yaml",
                        help="the cameras' rig: epipolar lines and identification (default: the dataset's own "
                             "rig.yaml, or rig.yaml beside the videos; without one, blobs only)")
    parser.add_argument("--markers", metavar="FILE",
                        help="markers.yaml of the glasses (default: the source's, else the contract's model)")
    parser.add_argument("--out", metavar="DIR",
                        help=f"write the annotated frames as DIR/{OUT_NAME.format(0)}, ... instead of a window "
                             "(DIR is made if missing; its parent must exist; not inside the dataset folder "
                             "being read; an earlier preview's pictures there are replaced, and those past this "
                             "run's last removed)")
    parser.add_argument("--frames", type=frame_count, metavar="N",
                        help=f"stop after N frames (default with --out: {HEADLESS_FRAMES}; in a window: until "
                             "the source ends or q)")
    add_quiet_argument(parser, help="no progress on standard error")
    live = parser.add_argument_group("live cameras (--source v4l2:...)")
    add_camera_settings(live, fps_default=None)
    parser.epilog = PREVIEW_EPILOG
    return parser


def _one_line(exc: BaseException) -> str:
    """An exception's message on one line (a source spec's list of forms is left to --help)."""
    text = str(exc).split("Accepted forms:")[0].strip()
    if "Accepted forms:" in str(exc):
        text += " (the forms: headplod preview --help)"
    return " ".join(text.split()) or type(exc).__name__


def _check_usage(args) -> tuple[str, Path | None, int | None]:
    """(source spec, --out folder or None, frames or None); raises _Usage. Reads the file system, writes
    nothing."""
    spec = args.source.strip()
    kind = source_kind(spec)
    live = kind == "v4l2"
    given = [name for name, value in (("--fps", args.fps), ("--fourcc", args.fourcc),
                                      ("--exposure", args.exposure), ("--gain", args.gain)) if value is not None]
    if given and not live and not args.quiet:
        # Not refused: the config file's shared camera settings apply to preview too (headplod.toml).
        print(f"note: {', '.join(given)} set live cameras; ignored for the replay {spec!r}", file=sys.stderr)
    if live and v4l2_devices(spec) == "auto" and not args.calib:
        raise _Usage("--source v4l2:auto finds the cameras --calib rig.yaml names; give --calib "
                     "(or name the devices, v4l2:0,2)")
    out = None
    if args.out:
        out = Path(args.out).expanduser()
        if out.exists() and not out.is_dir():
            raise _Usage(f"--out {args.out}: is a file; give a folder for the pictures")
        if not out.resolve().parent.is_dir():
            raise _Usage(f"--out {args.out}: the folder {out.parent} does not exist; create it first")
        if Path(spec).expanduser().is_dir():
            _check_not_inside(out, Path(spec).expanduser(), args.out)
    else:
        problem = window_problem()
        if problem:
            raise _Usage(f"no window can be shown: {problem}; write the pictures with --out DIR "
                         f"(e.g. --out preview, {HEADLESS_FRAMES} frames unless --frames N)")
    frames = args.frames if args.frames is not None else (HEADLESS_FRAMES if out is not None else None)
    return spec, out, frames


def _check_not_inside(out: Path, folder: Path, given: str) -> None:
    resolved, folder = out.resolve(), folder.resolve()
    if resolved == folder or folder in resolved.parents:
        raise _Usage(f"--out {given}: lies inside the dataset folder being read ({folder}), which is never "
                     "written to; write the pictures elsewhere")


def _open(args, spec: str, windowed: bool):
    """(source, rig, requested fps or None); raises ValueError, OSError, LookupError, io.ContractError."""
    rig = io.read_rig(args.calib) if args.calib else None
    if source_kind(spec) == "v4l2":
        options = dict(fps=args.fps or LIVE_FPS, fourcc=args.fourcc, exposure=args.exposure, gain=args.gain)
        if rig is not None:
            options.update(width=rig.image_size[0], height=rig.image_size[1], rig=rig)
        source = open_source(spec, **options)
        if not args.quiet:
            print(source.settings_report(text=True), file=sys.stderr)
        return source, rig, args.fps or LIVE_FPS
    preset = synthetic_preset(spec)
    if preset is not None:
        spec = str(ensure_dataset(preset, quiet=args.quiet))
    source = open_source(spec, realtime=windowed)        # a window plays a recording at its own pace
    return source, rig or source.rig, None


def run_preview(args) -> int:
    """Run ``headplod preview`` from parsed arguments; the exit status (module docstring)."""
    try:
        spec, out, frames = _check_usage(args)
    except _Usage as exc:
        print(f"headplod: preview: {exc}", file=sys.stderr)
        return 2
    try:
        markers = io.read_markers(args.markers) if args.markers else None
        source, rig, requested = _open(args, spec, windowed=out is None)
    except (ValueError, OSError, LookupError) as exc:       # io.ContractError is a ValueError
        print(f"headplod: preview: {_one_line(exc)}", file=sys.stderr)
        return 1
    try:
        return _run(args, source, rig, markers, requested, out, frames)
    finally:
        source.close()


def _run(args, source, rig, markers, requested, out: Path | None, frames: int | None) -> int:
    """The frames of an open source to the folder or the window; the exit status."""
    dataset = getattr(source, "dataset", None)
    if out is not None and dataset is not None:
        try:
            _check_not_inside(out, Path(dataset.folder), args.out)
        except _Usage as exc:
            print(f"headplod: preview: {exc}", file=sys.stderr)
            return 2
    for warning in source.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    try:
        previewer = Previewer(rig, markers or source.markers, requested_fps=requested)
    except ValueError as exc:                                 # a marker model the rule cannot use
        print(f"headplod: preview: {_one_line(exc)}", file=sys.stderr)
        return 1
    try:
        if out is not None:
            out.mkdir(exist_ok=True)
            output = _Folder(out)
        else:
            output = _Window()
    except (OSError, cv2.error) as exc:
        where = f"--out {args.out}" if out is not None else "the window"
        print(f"headplod: preview: {where}: {_one_line(exc)}", file=sys.stderr)
        return 1
    if rig is None and not args.quiet:
        print(f"note: {NO_RIG_NOTE}", file=sys.stderr)
    count, failed, first_failure, advice = 0, 0, None, {}
    progress = Progress(frames, "preview", unit="frame", disable=args.quiet)
    try:
        while frames is None or count < frames:
            frame = source.read()
            if frame is None:
                break
            picture, analysis = previewer.picture(frame)
            if analysis.error is not None:
                failed += 1
                first_failure = first_failure or f"frame {analysis.index}: {analysis.error}"
            for a in analysis.advice:
                advice.setdefault((a.kind, a.side), [0, a.text])[0] += 1
            try:
                going = output.show(count, picture)
            except OSError as exc:
                print(f"headplod: preview: --out {args.out}: {exc.strerror or _one_line(exc)} "
                      f"({exc.filename or out}); {count} pictures were written before it", file=sys.stderr)
                return 1
            count += 1
            progress.step(f"frame {analysis.index}" + (": failed" if analysis.error else ""))
            if not going:
                break
    finally:
        progress.close()
        output.close()
    if count == 0:
        print(f"headplod: preview: the source gave no frame ({source.name})", file=sys.stderr)
        return 1
    if isinstance(output, _Folder):
        removed = output.remove_stale()
        if removed and not args.quiet:
            print(f"note: removed {removed} pictures of an earlier, longer preview from {out}", file=sys.stderr)
    _summary(count, failed, first_failure, advice, out, previewer)
    return 0


def _summary(count, failed, first_failure, advice, out, previewer) -> None:
    """The run's lines on standard output: what was written, the frames that failed, the advice by kind."""
    if out is not None:
        w, h = composite_size(*previewer.size) if previewer.size else (0, 0)
        names = OUT_NAME.format(0) + ("" if count == 1 else f" .. {OUT_NAME.format(count - 1)}")
        print(f"wrote {count} annotated frames to {out}: {names} ({w}x{h} px)")
    else:
        print(f"showed {count} frames")
    if failed:
        print(f"{failed} of {count} frames failed (first: {first_failure}); each picture says why")
    for times, text in advice.values():
        print(f"advice ({times} of {count} frames): {text}")
