"""The heads-up display, drawn with OpenCV onto the rendered RGB image.

The window uploads the composed image as one texture, the headless run
writes it to PNG: both show the same pixels. Everything is a handful of
OpenCV calls per frame (text, boxes, two thumbnails); nothing per triangle.

Image coordinates: (H, W, 3) uint8 RGB, pixel (x, y) = column x, row y,
row 0 at the top; the POI is given in image pixels (screen px scaled by the
image/screen size ratio).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..render import PALETTE, overlay_poi
from .keys import key_help
from ..tol import tol

#: Key help, one line, made from :data:`headplod.demo.keys.KEYMAP`.
KEY_HELP = "keys: " + key_help()

_WHITE = (255, 255, 255)
_GREY = (150, 150, 150)
_GREEN = (110, 235, 110)
_RED = (255, 80, 70)
_YELLOW = (255, 220, 60)
_POI = (255, 40, 40)
#: Marker colours P0..P4 in the camera thumbnails (RGB).
_MARKER_COLOURS = ((255, 80, 80), (80, 255, 80), (80, 160, 255), (255, 230, 60), (230, 80, 255))


@dataclass
class HudInfo:
    """What the HUD shows for one frame (see :meth:`headplod.demo.loop.DemoLoop.hud_info`)."""

    fps: float
    stage_ms: dict
    frame_ms: float
    triangles: int
    mode: str
    uncertainty: str
    viewpoint: str
    view_mode: str
    source: str = ""
    poi_image_px: np.ndarray | None = None      # (2,) image px
    cov_deg2: np.ndarray | None = None          # (2, 2) deg², (φ, θ)
    px_per_deg: float = 1.0                     # image px per degree at the screen centre
    tracking_lost: str | None = None
    lost_s: float = 0.0
    saccade: bool = False
    poi_speed_deg_s: float = 0.0
    images: tuple | None = None                 # (left, right) (H, W) uint8
    markers_px: np.ndarray | None = None        # (2, 5, 2) camera px
    failures: int = 0
    frame: int = 0
    extra: list = field(default_factory=list)   # more text lines


def _scale(image) -> float:
    """Font scale for the image height (0.5 at 720 rows)."""
    return max(0.28, image.shape[0] / 1440.0)


def _text_block(image, lines, origin, scale):
    """Lines of (text, colour) on a darkened box at origin (x, y) top-left; returns the box's bottom y."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    thick = 1
    sizes = [cv2.getTextSize(t, font, scale, thick)[0] for t, _ in lines]
    if not sizes:
        return origin[1]
    line_h = int(max(s[1] for s in sizes) * 1.7) + 2
    pad = max(3, int(6 * scale))
    w = max(s[0] for s in sizes) + 2 * pad
    h = line_h * len(lines) + pad
    x0, y0 = origin
    x1, y1 = min(image.shape[1], x0 + w), min(image.shape[0], y0 + h)
    if x1 > x0 and y1 > y0:
        region = image[y0:y1, x0:x1]
        region >>= 1                     # half as bright: one integer op
    for k, (text, colour) in enumerate(lines):
        y = y0 + pad + line_h * k + int(line_h * 0.6)
        cv2.putText(image, text, (x0 + pad, y), font, scale, colour, thick, cv2.LINE_AA)
    return y1


def _status_line(info: HudInfo):
    if info.tracking_lost is not None:
        sigma = ""
        if info.cov_deg2 is not None:
            sigma = f", sigma {np.sqrt(max(float(np.max(np.diag(info.cov_deg2))), 0.0)):.2f} deg"
        return f"tracking lost: {info.tracking_lost} ({info.lost_s:.1f} s{sigma})", _RED
    if info.saccade:
        return f"saccade ({info.poi_speed_deg_s:.0f} deg/s > 180): previous levels kept", _YELLOW
    return f"tracking ok   POI speed {info.poi_speed_deg_s:.0f} deg/s", _GREEN


def _cross_arm_px(height: int) -> int:
    """Half-length of the POI crosshair's arms for an image ``height`` px high, px."""
    return max(6, int(height) // 60)


def min_ellipse_px(height: int) -> int:
    """The least half-axis the 2σ ellipse is drawn with in an image ``height`` px high, px: half again beyond
    the crosshair's arms, so that a small one is still seen around the cross."""
    return int(round(1.5 * _cross_arm_px(height)))


def ellipse_words(cov_deg2, px_per_deg: float, height: int) -> str:
    """The picture label's words on the 2σ ellipse of ``cov_deg2`` ((2, 2) deg², or None) at ``px_per_deg``:
    its true size (the larger σ in degrees, the 2σ half-axis in px) and, when that is smaller than
    :func:`min_ellipse_px`, that it is drawn enlarged."""
    if cov_deg2 is None:
        return "POI (no covariance)"
    sigma = float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(np.asarray(cov_deg2, float)))), 0.0)))
    half = 2.0 * sigma * px_per_deg
    least = min_ellipse_px(height)
    size = f"sigma {sigma:.2f} deg, 2-sigma {half:.1f} px"
    if half < least:
        return f"POI and 2-sigma ellipse ({size}; drawn enlarged to {least} px to be seen)"
    return f"POI and 2-sigma ellipse ({size})"


def draw_poi(image, info: HudInfo) -> np.ndarray:
    """The POI crosshair and the covariance's 2σ ellipse, drawn at least :func:`min_ellipse_px` (in place)."""
    if info.poi_image_px is None:
        return image
    return overlay_poi(image, info.poi_image_px, info.cov_deg2, max(info.px_per_deg, tol.floor), color=_POI,
                       cross_px=_cross_arm_px(image.shape[0]), thickness=1 if image.shape[0] < 400 else 2,
                       inplace=True, min_half_px=min_ellipse_px(image.shape[0]))


def draw_cameras(image, info: HudInfo) -> np.ndarray:
    """The two camera images with the identified markers, bottom right (in place)."""
    if info.images is None or info.images[0] is None:
        return image
    H, W = image.shape[:2]
    margin = max(2, W // 160)
    x = W - margin
    for cam in (1, 0):                                   # right image rightmost
        gray = info.images[cam]
        if gray is None:
            continue
        h, w = gray.shape[:2]
        # About a sixth of the frame wide, by an integer factor: OpenCV's area
        # average then takes its fast path.
        factor = max(1, int(round(w / max(32, W // 6))))
        thumb = cv2.cvtColor(cv2.resize(gray, None, fx=1.0 / factor, fy=1.0 / factor,
                                        interpolation=cv2.INTER_AREA), cv2.COLOR_GRAY2RGB)
        th, thumb_w = thumb.shape[:2]
        s = thumb_w / w
        if info.markers_px is not None:
            pts = np.asarray(info.markers_px, dtype=np.float64)[cam]
            for k, p in enumerate(pts):
                if np.isfinite(p).all():
                    c = (int(round(p[0] * s)), int(round(p[1] * s)))
                    cv2.circle(thumb, c, max(3, thumb_w // 40), _MARKER_COLOURS[k % 5], 1, cv2.LINE_AA)
                    cv2.putText(thumb, str(k), (c[0] + 4, c[1] - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.3,
                                _MARKER_COLOURS[k % 5], 1, cv2.LINE_AA)
        cv2.putText(thumb, "LR"[cam], (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, _WHITE, 1, cv2.LINE_AA)
        y0 = H - margin - th
        x0 = x - thumb_w
        if x0 < 0 or y0 < 0:
            break
        image[y0:y0 + th, x0:x0 + thumb_w] = thumb
        cv2.rectangle(image, (x0, y0), (x0 + thumb_w - 1, y0 + th - 1), _WHITE, 1)
        x = x0 - margin
    return image


def draw_legend(image, max_level: int, origin=None, present=None) -> np.ndarray:
    """Level colour swatches L0..L{max_level} (the "levels" view's palette), bottom left (in place): each
    swatch with its label beside it, white on a darkened box, never over a colour. ``present``: the levels
    the frame uses (None: all); the others are drawn hollow with a grey label, and the box says so."""
    scale = _scale(image)
    font, text_scale = cv2.FONT_HERSHEY_SIMPLEX, 1.0 * scale
    box = max(10, int(24 * scale))
    gap = max(3, box // 4)
    (tw, th), _ = cv2.getTextSize(f"L{max_level}", font, text_scale, 1)
    step = box + gap + tw + 2 * gap
    pad = gap
    absent = [] if present is None else [lv for lv in range(max_level + 1) if lv not in set(present)]
    note = "grey: not in this frame" if absent else ""
    note_w = cv2.getTextSize(note, font, text_scale, 1)[0][0] + gap if note else 0
    width, height = (max_level + 1) * step + pad + note_w, box + 2 * pad
    H, W = image.shape[:2]
    x0, y0 = origin if origin is not None else (max(2, box // 2), H - height - max(14, int(40 * scale)))
    x1, y1 = min(W, x0 + width), min(H, y0 + height)
    if x1 > x0 and y1 > y0:
        region = image[y0:y1, x0:x1]
        region >>= 2                     # a quarter as bright: the labels' white stands out on any terrain
    x, y = x0 + pad, y0 + pad
    for level in range(max_level + 1):
        colour = tuple(int(c) for c in PALETTE[level % len(PALETTE)])
        label = _GREY if level in absent else _WHITE
        if level not in absent:
            cv2.rectangle(image, (x, y), (x + box, y + box), colour, -1)
        cv2.rectangle(image, (x, y), (x + box, y + box), colour if level in absent else _WHITE, 1)
        cv2.putText(image, f"L{level}", (x + box + gap, y + (box + th) // 2), font, text_scale, label, 1,
                    cv2.LINE_AA)
        x += step
    if note:
        cv2.putText(image, note, (x, y + (box + th) // 2), font, text_scale, _GREY, 1, cv2.LINE_AA)
    return image


def draw_hud(image: np.ndarray, info: HudInfo, inplace: bool = False, max_level: int = 5) -> np.ndarray:
    """Compose the HUD onto a rendered frame.

    Parameters
    ----------
    image : (H, W, 3) uint8
        RGB frame.
    info : HudInfo
    inplace : bool
        Draw into ``image`` itself.
    max_level : int
        Levels shown in the legend of the "levels" view.

    Returns
    -------
    (H, W, 3) uint8
        Frame rate, frame time by stage, triangles, settings with their keys,
        tracking state, the POI with its 2σ ellipse and, with a tracker, the
        camera images with the identified markers.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"draw_hud: image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    out = img if inplace else img.copy()
    draw_poi(out, info)
    scale = _scale(out)
    stages = "  ".join(f"{k} {v:.1f}" for k, v in info.stage_ms.items())
    lines = [(f"{info.fps:5.1f} fps   frame {info.frame_ms:.1f} ms   triangles {info.triangles:,}", _WHITE),
             (f"ms: {stages}", _WHITE),
             (f"criterion {info.mode}   scenario {info.uncertainty}   view {info.view_mode}   "
              f"viewpoint {info.viewpoint}", _WHITE),
             _status_line(info)]
    if info.failures:
        lines.append((f"frames without a pose so far: {info.failures}", _WHITE))
    if info.source:
        lines.append((f"poses: {info.source}"[:110], _WHITE))
    lines += [(t, _WHITE) for t in info.extra]
    margin = max(2, out.shape[1] // 160)
    _text_block(out, lines, (margin, margin), scale)
    draw_cameras(out, info)
    if info.view_mode == "levels":
        draw_legend(out, max_level)
    _text_block(out, [(KEY_HELP, _WHITE)], (margin, out.shape[0] - margin - int(26 * scale) - 8), scale * 0.85)
    return out


def draw_picture_overlay(image: np.ndarray, info: HudInfo, caption: str | None = None, legend: bool = True,
                         max_level: int = 5, present=None) -> np.ndarray:
    """A still for the README: the POI with its 2σ ellipse, a caption and the level legend (in place);
    ``present``: the levels the frame uses (:func:`draw_legend`)."""
    draw_poi(image, info)
    if caption:
        _text_block(image, [(caption, _WHITE)], (4, 4), _scale(image))
    if legend:
        draw_legend(image, max_level, present=present)
    return image
