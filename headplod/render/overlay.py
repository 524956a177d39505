"""The point of interest and its uncertainty ellipse, drawn onto a rendered image (OpenCV)."""
from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

# --------------------------------------------------------------------------
# overlay
# --------------------------------------------------------------------------

_SHIFT = 4  # cv2 sub-pixel bits: coordinates in 1/16 px


def overlay_poi(image: np.ndarray, poi_px: Any, cov_deg2: Any, px_per_deg: float,
                color: tuple[int, int, int] = (255, 40, 40), *, n_sigma: float = 2.0,
                cross_px: int = 12, thickness: int = 1, inplace: bool = False,
                min_half_px: float = 0.0) -> np.ndarray:
    """Draw the point of interest and its uncertainty ellipse.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
        Image to draw on (e.g. from :meth:`TerrainRenderer.render`), pixel
        (x, y) = column x, row y.
    poi_px : array_like, shape (2,), or None
        POI in image pixels (x right, y down). ``None`` or non-finite: the
        image is returned unchanged (a frame without a pose).
    cov_deg2 : array_like, shape (2, 2), or None
        Covariance of (φ, θ), deg² (docs/contract.md: φ vertical, positive up;
        θ horizontal, positive right). ``None``: crosshair only.
    px_per_deg : float
        Image pixels per degree of viewing direction at the POI (about
        ``distance_mm * pi / 180 / pixel_pitch_mm``); treats the mapping as
        locally isotropic and the head axes as aligned with the screen's.
    color : tuple of int
        Colour in the image's channel order (RGB for rendered images).
    n_sigma : float
        Ellipse at ``n_sigma`` standard deviations (2: ~86 % of a 2-D
        Gaussian).
    cross_px : int
        Half-length of the crosshair arms, px.
    thickness : int
        Line thickness, px.
    inplace : bool
        Draw into ``image`` itself instead of a copy.
    min_half_px : float
        The ellipse's longer half-axis is drawn at least this long, px (its shape kept): a tracked head's
        ellipse can be smaller than the crosshair. 0: always its true size.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
        The image with the overlay.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"overlay_poi: image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    out = img if inplace else img.copy()
    if poi_px is None:
        return out
    p = np.asarray(poi_px, dtype=np.float64).reshape(-1)
    if p.shape != (2,):
        raise ValueError(f"overlay_poi: poi_px has shape {np.shape(poi_px)}, expected (2,)")
    h, w = out.shape[:2]
    limit = 4.0 * max(h, w)
    if not np.isfinite(p).all() or np.abs(p).max() > limit:
        return out
    col = tuple(int(c) for c in color)
    scale = 1 << _SHIFT
    cx, cy = (int(round(v * scale)) for v in p)
    arm = int(cross_px) * scale
    cv2.line(out, (cx - arm, cy), (cx + arm, cy), col, thickness, cv2.LINE_AA, _SHIFT)
    cv2.line(out, (cx, cy - arm), (cx, cy + arm), col, thickness, cv2.LINE_AA, _SHIFT)
    if cov_deg2 is not None:
        c = np.asarray(cov_deg2, dtype=np.float64)
        if c.shape != (2, 2):
            raise ValueError(f"overlay_poi: cov_deg2 has shape {c.shape}, expected (2, 2) in (φ, θ) order")
        ppd = float(px_per_deg)
        if not (math.isfinite(ppd) and ppd > 0):
            raise ValueError(f"overlay_poi: px_per_deg must be > 0, got {px_per_deg!r}")
        if np.isfinite(c).all():
            # image axes (x, y) = (θ, −φ) * px_per_deg
            c_img = ppd ** 2 * np.array([[c[1, 1], -c[0, 1]], [-c[1, 0], c[0, 0]]])
            c_img = 0.5 * (c_img + c_img.T)
            evals, evecs = np.linalg.eigh(c_img)
            if evals[0] >= 0 and evals[1] > 0:
                half = n_sigma * np.sqrt(evals)
                if 0 < half.max() < min_half_px:
                    half = half * (min_half_px / half.max())
                half = np.minimum(half, limit)
                angle = math.degrees(math.atan2(evecs[1, 0], evecs[0, 0]))  # of the evals[0] axis
                axes = (int(round(half[0] * scale)), int(round(half[1] * scale)))
                cv2.ellipse(out, (cx, cy), axes, angle, 0.0, 360.0, col, thickness, cv2.LINE_AA, _SHIFT)
    return out


#: Colours of the foveation layers' borders (RGB), fovea first.
LAYER_COLORS = ((255, 255, 255), (255, 200, 0), (0, 220, 255), (200, 90, 255), (120, 255, 120), (255, 120, 120))


def overlay_layers(image: np.ndarray, poi_px: Any, layers, px_per_deg: float, *, label: bool = True,
                   thickness: int = 1, inplace: bool = False) -> np.ndarray:
    """Draw the foveation layers' borders: a circle of ``outer_deg`` about the POI per layer (the last has none).

    Parameters
    ----------
    image : (H, W, 3) uint8
    poi_px : (2,)
        The layers' centre, image px (x right, y down).
    layers : sequence of :class:`headplod.render.foveate.Layer`
    px_per_deg : float
        Image pixels per degree at full resolution.
    label : bool
        Write each layer's scale next to its border.

    Returns
    -------
    (H, W, 3) uint8, the image with the borders (a copy unless ``inplace``).
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"overlay_layers: image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    ppd = float(px_per_deg)
    if not (math.isfinite(ppd) and ppd > 0):
        raise ValueError(f"overlay_layers: px_per_deg must be > 0, got {px_per_deg!r}")
    out = img if inplace else img.copy()
    p = np.asarray(poi_px, dtype=np.float64).reshape(2)
    scale = 1 << _SHIFT
    cx, cy = (int(round(v * scale)) for v in p)
    for k, layer in enumerate(layers):
        col = LAYER_COLORS[k % len(LAYER_COLORS)]
        if math.isfinite(layer.outer_deg):
            radius = layer.outer_deg * ppd
            cv2.circle(out, (cx, cy), int(round(radius * scale)), col, thickness, cv2.LINE_AA, _SHIFT)
        if label:
            r_text = 0.5 * (layer.inner_deg + (layer.outer_deg if math.isfinite(layer.outer_deg)
                                               else layer.inner_deg + 4.0)) * ppd
            org = (int(p[0] + r_text * 0.7071), int(p[1] - r_text * 0.7071))
            cv2.putText(out, f"1/{int(round(1 / layer.scale))}" if layer.scale < 1 else "1", org,
                        cv2.FONT_HERSHEY_SIMPLEX, 0.45, col, 1, cv2.LINE_AA)
    return out
