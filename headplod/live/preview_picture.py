"""The picture of a frame of ``headplod preview``: a :class:`~headplod.live.preview_analysis.FrameAnalysis`
drawn as the two images side by side, annotated, with a panel of text under them.

:func:`render` takes the analysis and returns the picture, (H, W, 3) uint8 BGR, of the size
:func:`composite_size` gives. Coordinates: image pixels (u, v), u right, v down, (0, 0) the *centre* of
the top-left pixel (docs/contract.md), which is also the convention of OpenCV's drawing functions at
integer (and, with ``shift``, fixed-point) coordinates, so nothing is shifted by half a pixel. In the
composite picture the right image's pixel (u, v) is at (u + width, v).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .preview_analysis import SIDES, FrameAnalysis, ViewAnalysis

__all__ = ["render", "composite_size", "NO_RIG_NOTE", "PANEL_LINES"]

#: What the pictures say when there is no rig.
NO_RIG_NOTE = "no rig: epipolar lines and identification after 'headplod calibrate'"
#: Lines of text in the panel under the images.
PANEL_LINES = 8

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
            _draw_view(canvas, view, SIDES[cam], cam * w, analysis)
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
