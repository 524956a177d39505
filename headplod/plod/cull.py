"""Frustum culling, the CPU's two tests: the screen's pyramid with a margin, and the camera's clip box.

Two tests, different on purpose:

- **The screen's pyramid** (:func:`screen_pyramid`, :func:`outside_screen`):
  the mesh selectors (:class:`headplod.plod.select.LevelSelector` and the
  quadtree selector of ``headplod.bench.quadtree_selector``) cull a base
  triangle when its centroid's ray from the eye misses the screen rectangle
  widened by a margin of the triangle's own size, because a triangle is
  judged by one point (its centroid) and must keep its level while any part
  of it can still be on the screen; the same test bounds a box of
  centroids (a quadtree node) through its corner that reaches farthest in.
- **The camera's clip box** (:func:`box_outside_clip`, and its
  conservative sphere form :func:`sphere_outside_planes`): the tessellation
  back end (:class:`headplod.plod.patch_tree.PatchTree`, and the GLSL
  ``outside()`` of :mod:`headplod.render.tess_shaders`, the same test in
  float32) culls a patch by its whole height box against the frustum GL
  draws with (near and far planes included, and an optional NDC region),
  because the patch is drawn from that box and nothing of it outside the
  frustum can show.

Frames: world mm for the pyramid (the eye and the screen corners, as
:class:`headplod.io.Screen` gives them); scene for the clip box (``mvp`` is
``T_clip_scene``). Pure numpy, vectorised over points, boxes and planes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ScreenPyramid", "screen_pyramid", "outside_screen", "frustum_planes", "sphere_outside_planes",
           "box_corners", "box_outside_clip"]

#: The 8 corners of a box as fractions of its extent (x fastest, then y, then z); the GLSL ``outside()`` order.
BOX_CORNERS = np.array([[(k & 1) > 0, (k & 2) > 0, (k & 4) > 0] for k in range(8)], np.float64)


@dataclass(frozen=True)
class ScreenPyramid:
    """The four sides of the screen seen from one eye, as linear forms (world frame).

    A point ``p`` projects inside side ``s`` of the screen rectangle widened
    by a margin ``m`` (mm on the screen plane) iff
    ``(p - eye) · (w0[s] + (a[s] + b[s] m) normal) >= 0``: the pixel
    condition of :func:`headplod.plod.contrast.project_to_screen_px`
    multiplied by the positive ``1 / s`` of the ray's parameter. The four
    half-spaces meet in the pyramid in front of the eye only, so a point
    behind the eye (or level with it) is outside.

    Attributes
    ----------
    eye_mm : (3,) float64
    w0 : (4, 3) float64
        Left, right, top, bottom: ``u, -u, v, -v`` (u, v the screen's edges, mm).
    a, b : (4,) float64
        The sides' offsets and the margin's weight, already divided by
        ``(top_left - eye) · normal``.
    normal : (3,) float64
        ``u × v``.
    """

    eye_mm: np.ndarray
    w0: np.ndarray
    a: np.ndarray
    b: np.ndarray
    normal: np.ndarray


def screen_pyramid(screen, eye_mm) -> ScreenPyramid:
    """The :class:`ScreenPyramid` of ``screen`` (:class:`headplod.io.Screen`) seen from ``eye_mm`` (3,) world mm.

    The margin is in mm on the screen plane and converted to pixels with the
    screen's horizontal px per mm on both axes, as the selector's margin is.
    """
    eye = np.asarray(eye_mm, dtype=np.float64)
    tl = np.asarray(screen.top_left, dtype=np.float64)
    u = np.asarray(screen.top_right, dtype=np.float64) - tl
    v = np.asarray(screen.bottom_left, dtype=np.float64) - tl
    n = np.cross(u, v)
    width, height = screen.size_px
    px_per_mm = width / float(np.linalg.norm(u))
    bu, bv = px_per_mm / width * (u @ u), px_per_mm / height * (v @ v)
    k = float((tl - eye) @ n)
    h0u, h0v = float((eye - tl) @ u), float((eye - tl) @ v)
    return ScreenPyramid(eye, np.stack([u, -u, v, -v]), np.array([h0u, u @ u - h0u, h0v, v @ v - h0v]) / k,
                         np.array([bu, bu, bv, bv]) / k, n)


def outside_screen(rel_mm, margin_mm, pyramid: ScreenPyramid, half_mm=None) -> np.ndarray:
    """(k,) bool: points (or boxes) wholly outside the screen rectangle widened by their margins, seen from the eye.

    Parameters
    ----------
    rel_mm : (k, 3)
        Points (boxes' centres) less the pyramid's eye, world frame, mm.
    margin_mm : (k,)
        Each one's margin on the screen plane, mm (>= 0).
    pyramid : ScreenPyramid
    half_mm : (k, 3), optional
        Boxes' half-sizes along the world axes, mm: a box is outside when
        every point of it is (the largest of each side's linear form over
        the box is negative). None: points.
    """
    rel = np.asarray(rel_mm, dtype=np.float64)
    w = pyramid.w0 + ((pyramid.a + pyramid.b * np.asarray(margin_mm, dtype=np.float64)[:, None])[:, :, None]
                      * pyramid.normal)                                              # (k, 4, 3)
    top = np.einsum("kj,ksj->ks", rel, w)
    if half_mm is not None:
        top = top + np.einsum("kj,ksj->ks", np.asarray(half_mm, dtype=np.float64), np.abs(w))
    return (top < 0).any(axis=1)


def frustum_planes(mvp) -> np.ndarray:
    """(6, 4) float64 planes (a, b, c, d) of the frustum of ``mvp`` (4, 4), in its input frame, unit normals.

    ``a x + b y + c z + d >= 0`` inside: left, right, bottom, top, near, far (Gribb & Hartmann).
    """
    m4 = np.asarray(mvp, np.float64)
    planes = np.stack([m4[3] + m4[0], m4[3] - m4[0], m4[3] + m4[1], m4[3] - m4[1], m4[3] + m4[2], m4[3] - m4[2]])
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


def sphere_outside_planes(centre, radius, planes) -> np.ndarray:
    """(m,) bool: spheres (centres (m, 3), radii (m,)) wholly outside one of ``planes`` (p, 4), their frame.

    A sphere around a box culls it only when the box's every corner is
    outside that plane, so this is a cheaper, more conservative form of
    :func:`box_outside_clip` without a region.
    """
    centre = np.asarray(centre, np.float64)
    return ((centre @ planes[:, :3].T + planes[:, 3]) < -np.asarray(radius, np.float64)[:, None]).any(axis=1)


def box_corners(lo, hi) -> np.ndarray:
    """(m, 8, 3) corners of boxes ``lo``, ``hi`` (m, 3), in :data:`BOX_CORNERS` order."""
    lo = np.asarray(lo, np.float64)
    return lo[:, None, :] + (np.asarray(hi, np.float64) - lo)[:, None, :] * BOX_CORNERS


def box_outside_clip(corners, mvp, region_ndc=None) -> np.ndarray:
    """(m,) bool: boxes wholly outside one clip plane, or (all corners in front) missing an NDC region.

    Parameters
    ----------
    corners : (m, 8, 3)
        The boxes' corners (:func:`box_corners`), the frame ``mvp`` takes (scene).
    mvp : (4, 4)
        ``T_clip_scene``.
    region_ndc : (4,) or None
        (x0, y0, x1, y1) in NDC: a box whose corners are all in front of the
        eye and whose NDC bounds miss this rectangle is outside too.

    The GLSL ``outside()`` (:mod:`headplod.render.tess_shaders`) is this test in float32.
    """
    m = len(corners)
    if m == 0:
        return np.zeros(0, bool)
    mvp = np.asarray(mvp, np.float64)
    c = np.asarray(corners, np.float64) @ mvp[:, :3].T + mvp[:, 3]                 # (m, 8, 4)
    w = c[..., 3:]
    out = ((c[..., :3] < -w).all(axis=1) | (c[..., :3] > w).all(axis=1)).any(axis=1)
    if region_ndc is not None:
        front = np.all(w[..., 0] > 0, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ndc = c[..., :2] / w
        mn, mx = ndc.min(axis=1), ndc.max(axis=1)
        r = np.asarray(region_ndc, np.float64)
        miss = (mx[:, 0] < r[0]) | (mn[:, 0] > r[2]) | (mx[:, 1] < r[1]) | (mn[:, 1] > r[3])
        out |= front & miss
    return out
