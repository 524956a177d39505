"""Contrast of the terrain over each base triangle, read back from a rendered frame.

Martinez et al. (eq. 2) read a 10x10 pixel window around each triangle's
centroid back from the frame buffer and took the Michelson contrast
``(L_max − L_min) / (L_max + L_min)`` of its luminance. This module does the
same for all triangles at once: a min and a max filter over the frame's
luminance (two OpenCV passes, whatever the number of triangles), sampled at
the triangles' projected centroids. The alternative the selector uses by
default needs no read-back: the contrast of the Lambertian shading over each
base triangle's finest vertices, computed once with the mesh
(:meth:`headplod.plod.mesh.AdaptiveMesh.shading_contrast`);
``headplod bench plod`` compares the two.
"""
from __future__ import annotations

import cv2
import numpy as np
from ..tol import tol


def project_to_screen_px(points_mm, eye_mm, screen) -> np.ndarray:
    """Where the rays from the eye through points meet the screen, screen pixels.

    Parameters
    ----------
    points_mm : (N, 3)
        Points, world frame, mm.
    eye_mm : (3,)
        Eye position, world frame, mm.
    screen : headplod.io.Screen

    Returns
    -------
    (N, 2) float64
        Screen pixels (x right, y down, docs/contract.md); NaN for points not
        in front of the eye through the screen's plane.
    """
    points = np.asarray(points_mm, dtype=np.float64).reshape(-1, 3)
    eye = np.asarray(eye_mm, dtype=np.float64).reshape(3)
    tl = np.asarray(screen.top_left, dtype=np.float64)
    u = np.asarray(screen.top_right, dtype=np.float64) - tl
    v = np.asarray(screen.bottom_left, dtype=np.float64) - tl
    normal = np.cross(u, v)
    rel = points - eye
    along = rel @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((tl - eye) @ normal) / along
        hit = eye + rel * s[:, None] - tl
    width, height = screen.size_px
    out = np.stack([hit @ u / (u @ u) * width, hit @ v / (v @ v) * height], axis=1)
    out[~(s > 0)] = np.nan
    return out


def luminance(image_rgb: np.ndarray) -> np.ndarray:
    """Relative luminance (H, W) float32 in [0, 1] of an 8-bit sRGB image (H, W, 3).

    The sRGB transfer is undone first: contrast is a ratio of luminances,
    not of code values.
    """
    if image_rgb.ndim != 3 or image_rgb.shape[2] != 3 or image_rgb.dtype != np.uint8:
        raise ValueError(f"luminance: expected an (H, W, 3) uint8 RGB image, got {image_rgb.dtype} {image_rgb.shape}")
    code = np.arange(256, dtype=np.float64) / 255.0
    linear = np.where(code <= 0.04045, code / 12.92, ((code + 0.055) / 1.055) ** 2.4).astype(np.float32)
    lin = cv2.LUT(image_rgb, linear.reshape(256, 1).repeat(3, axis=1).reshape(256, 1, 3))
    return cv2.transform(lin, np.array([[0.2126, 0.7152, 0.0722]], dtype=np.float32))


def readback_contrast(image_rgb: np.ndarray, points_screen_px, screen_size_px, window_px: int = 10,
                      fallback=None) -> np.ndarray:
    """Michelson contrast of the frame's luminance in a window around each point (eq. 2).

    Parameters
    ----------
    image_rgb : (H, W, 3) uint8
        The rendered frame (row 0 at the top of the screen), covering the
        screen's visible area.
    points_screen_px : (N, 2)
        The triangles' projected centroids, screen pixels (NaN: not seen).
    screen_size_px : (2,)
        Width and height of the screen in its own pixels; the image may be
        smaller or larger (it is scaled).
    window_px : int
        Side of the square window, image pixels (the paper: 10).
    fallback : (N,) optional
        The value for points outside the image (default NaN).

    Returns
    -------
    (N,) float64
        ``(L_max − L_min) / (L_max + L_min)`` over the window.
    """
    lum = luminance(image_rgb)
    kernel = np.ones((window_px, window_px), np.uint8)
    hi = cv2.dilate(lum, kernel)
    lo = cv2.erode(lum, kernel)
    h, w = lum.shape
    pts = np.asarray(points_screen_px, dtype=np.float64).reshape(-1, 2)
    scale = np.array([w, h], dtype=np.float64) / np.asarray(screen_size_px, dtype=np.float64)
    px = np.floor(pts * scale)
    inside = np.isfinite(px).all(axis=1) & (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    xi = np.where(inside, px[:, 0], 0).astype(np.int64)
    yi = np.where(inside, px[:, 1], 0).astype(np.int64)
    mx, mn = hi[yi, xi].astype(np.float64), lo[yi, xi].astype(np.float64)
    contrast = (mx - mn) / np.maximum(mx + mn, tol.zero)
    missing = np.full(len(pts), np.nan) if fallback is None else np.asarray(fallback, dtype=np.float64)
    return np.where(inside, contrast, missing)
