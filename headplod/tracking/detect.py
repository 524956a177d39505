"""Marker blob detection in one IR image.

Pixel convention (the whole project, docs/contract.md): pixel (u, v) = (0, 0) is
the centre of the top-left pixel, u to the right, v down. Every centre this
module returns is in full-image pixel coordinates, even when detection ran on a
sub-region.

Pipeline (Martinez et al. 2008, §4.1, with the changes that make it accurate):

1. threshold: the paper used a fixed 100 DN; the default adapts to the image
   (background median + max(k·σ, min contrast)), so dim IR still works;
2. optional Gaussian smoothing (the paper's 9x9), off by default: on these
   small blobs it merges neighbours and adds nothing the centroid needs;
3. blobs are the external contours of the thresholded image (OpenCV's
   findContours is 25x faster here than connectedComponentsWithStats);
4. centre = intensity-weighted centroid over a window around each blob, with
   the local background subtracted (the paper weighted raw intensities, which
   pulls the centre toward the window's middle by the background's weight);
5. small sharp blobs (glints: effective area flux/peak near the point-spread
   function's) are flagged, not dropped; identification uses them only when it
   must, and the 3D checks reject them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
from ..tol import tol

# Scale from the median absolute deviation to σ for Gaussian noise.
_MAD_TO_SIGMA = 1.4826
_CLOSE_KERNEL = np.ones((3, 3), np.uint8)


@dataclass(frozen=True)
class DetectionParams:
    """Settings of blob detection.

    Attributes
    ----------
    threshold_dn : float or None
        Fixed threshold in DN (the paper: 100). None: adaptive,
        ``background + max(k_sigma·σ, min_contrast_dn)`` (5σ and 10 DN by default:
        σ is pixel noise only, see :func:`estimate_background`).
    k_sigma : float
        Adaptive threshold in noise standard deviations above the background.
    min_contrast_dn : float
        Adaptive threshold's least height above the background, DN.
    smooth_px : int
        Side of the Gaussian kernel applied to each blob window before
        centroiding (the paper: 9); 0 disables it.
    subtract_background : bool
        Weight pixels by intensity minus the local background (default) rather
        than by raw intensity of the thresholded pixels (the paper).
    min_area_px : int
        Blobs with fewer pixels above threshold are noise.
    glint_max_area_px : int
        Glints have at most this many pixels above threshold ...
    glint_max_effective_area_px : float
        ... and an effective area, flux / peak in px, at most this (a point
        source blurred by the optics has about 2π σ_psf² ≈ 2.3 px).
    pad_px : int
        Margin around a blob's thresholded box for centroiding, px.
    local_background : bool
        With the adaptive threshold, measure each pixel's height above a map
        of the local background (:func:`background_map`) rather than above
        the image's median: ambient IR gradients then neither hide dim
        markers nor raise noise above the threshold.
    """

    threshold_dn: float | None = None
    k_sigma: float = 5.0
    min_contrast_dn: float = 10.0
    smooth_px: int = 0
    subtract_background: bool = True
    min_area_px: int = 2
    glint_max_area_px: int = 6
    glint_max_effective_area_px: float = 2.6
    pad_px: int = 3
    local_background: bool = True

    @classmethod
    def paper(cls) -> "DetectionParams":
        """Martinez et al.'s settings: fixed threshold 100, 9x9 smoothing, raw weights."""
        return cls(threshold_dn=100.0, smooth_px=9, subtract_background=False)


@dataclass
class Blobs:
    """Blobs found in one image; every array has one row per blob.

    Attributes
    ----------
    centers_px : (n, 2) float64
        Intensity-weighted centroids (u, v), full-image pixels.
    area_px : (n,) int
        Pixels above threshold.
    peak_dn : (n,) float64
        Highest intensity above the local background, DN.
    flux_dn : (n,) float64
        Sum of the centroid weights, DN·px.
    glint : (n,) bool
        Small and sharp: probably a specular reflection, not a marker.
    bbox_px : (n, 4) int
        Thresholded bounding box x, y, w, h in full-image pixels.
    sigma_px : (n,) float64
        Expected standard deviation of each centroid coordinate from the
        background noise, px: first-order propagation of pixel noise σ_n.
    shot_var : (n, 2) float64
        Centroid variance of x and of y per unit shot-noise factor κ (pixel
        variance κ·I for intensity I), px²/DN; NaN where not measured. It is
        anisotropic: an elongated (foreshortened) blob's centre is noisier
        along its length.
    threshold_dn, background_dn, noise_dn : float
        The threshold used, the background level and noise σ it came from.
    """

    centers_px: np.ndarray
    area_px: np.ndarray
    peak_dn: np.ndarray
    flux_dn: np.ndarray
    glint: np.ndarray
    bbox_px: np.ndarray
    sigma_px: np.ndarray = None
    threshold_dn: float = 0.0
    background_dn: float = 0.0
    noise_dn: float = 0.0
    pixels: list = field(default_factory=list)
    shot_var: np.ndarray = None

    def __len__(self) -> int:
        return len(self.centers_px)

    def subset(self, index) -> "Blobs":
        """The blobs selected by ``index`` (an index array or boolean mask)."""
        idx = np.asarray(index)
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        shot = self.shot_var if self.shot_var is not None else np.full((len(self.centers_px), 2), np.nan)
        return Blobs(self.centers_px[idx], self.area_px[idx], self.peak_dn[idx],
                     self.flux_dn[idx], self.glint[idx], self.bbox_px[idx], self.sigma_px[idx],
                     self.threshold_dn, self.background_dn, self.noise_dn,
                     [self.pixels[i] for i in idx] if self.pixels else [], shot[idx])


def estimate_background(image: np.ndarray, step: int = 16) -> tuple[float, float]:
    """Background level and pixel noise σ (DN) of a dark IR image.

    Uses a sparse grid of pixels (every ``step``-th row, every other column):
    markers cover far less than half of them, so the median is the
    background. σ comes from the median absolute difference of horizontally
    adjacent pixels (divided by √2): unlike the spread of the levels
    themselves it ignores slow ambient gradients, which a global threshold
    must not mistake for noise.
    """
    rows = image[::step].astype(np.int16)
    sample = rows[:, ::step].ravel()
    half = sample.size // 2
    median = float(np.partition(sample, half)[half])
    diff = np.abs(rows[::2, 1::2] - rows[::2, 0:-1:2]).ravel()
    mid = diff.size // 2
    mad = float(np.partition(diff, mid)[mid])
    # The median of integer differences is too coarse (1, 2, 3 DN): use the
    # mean absolute difference, with markers' edges clipped, for a half-normal
    # law E|d| = σ_d √(2/π) and σ_d = √2 σ.
    mean_abs = float(np.minimum(diff, 4 * mad + 2).mean())
    return median, max(mean_abs * np.sqrt(np.pi / 2) / np.sqrt(2.0), 0.5)


def background_map(image: np.ndarray, cell_px: int = 16) -> np.ndarray:
    """The slowly varying background under an IR image, (H, W) uint8.

    Block means over ``cell_px`` cells, then the minimum of each 3x3
    neighbourhood of cells (a marker or a lamp raises its own cells' means,
    not their darkest neighbour's), smoothed back to full size.
    """
    height, width = image.shape
    coarse = cv2.resize(image, (max(width // cell_px, 1), max(height // cell_px, 1)), interpolation=cv2.INTER_AREA)
    coarse = cv2.erode(coarse, _CLOSE_KERNEL)
    coarse = cv2.blur(coarse, (3, 3))
    return cv2.resize(coarse, (width, height), interpolation=cv2.INTER_LINEAR)


def above_threshold(image: np.ndarray, threshold_dn: float, background_dn: float,
                    params: DetectionParams = DetectionParams(), whole_image: bool = True) -> np.ndarray:
    """The pixels detection counts as bright: (H, W) uint8, 255 above the threshold, else 0.

    ``image`` (H, W) uint8; ``threshold_dn`` and ``background_dn`` as :func:`detect_blobs` found them. With the
    adaptive threshold and ``params.local_background`` on a whole image, a pixel's height above the local
    background map (:func:`background_map`) is compared with ``threshold - background``; otherwise the pixel
    itself with the threshold. A pixel counts when it exceeds the floor of the threshold (cv2.THRESH_BINARY is
    strict): above a fractional threshold, and from one DN above a whole one. :func:`detect_blobs` and
    ``headplod preview``'s mask both use this one rule.
    """
    if params.threshold_dn is None and params.local_background and whole_image:
        # Ambient IR varies across the image by more than the noise: compare
        # each pixel with the background around it, not with the median.
        height = cv2.subtract(image, background_map(image))
        _, binary = cv2.threshold(height, np.floor(threshold_dn - background_dn), 255, cv2.THRESH_BINARY)
    else:
        _, binary = cv2.threshold(image, np.floor(threshold_dn), 255, cv2.THRESH_BINARY)
    return binary


def detect_blobs(image: np.ndarray, params: DetectionParams = DetectionParams(),
                 roi: tuple[int, int, int, int] | None = None,
                 background: tuple[float, float] | None = None,
                 keep_pixels: bool = False) -> Blobs:
    """Find bright blobs in an 8-bit IR image.

    Parameters
    ----------
    image : (H, W) uint8
        The whole camera image.
    params : DetectionParams
    roi : (x, y, w, h), optional
        Search only this region (full-image pixels); centres stay full-image.
    background : (level_dn, sigma_dn), optional
        Reuse a background estimate (e.g. the previous frame's) instead of
        measuring it again.
    keep_pixels : bool
        Also return, per blob, the pixel coordinates (k, 2) and weights (k,)
        used for its centroid (for pixel-cloud uncertainty).
    """
    if background is None:
        background = estimate_background(image)
    bg, sigma = background
    if params.threshold_dn is not None:
        threshold = float(params.threshold_dn)
    else:
        threshold = bg + max(params.k_sigma * sigma, params.min_contrast_dn)

    height, width = image.shape
    if roi is None:
        x_off, y_off, sub = 0, 0, image
    else:
        x_off, y_off = max(int(roi[0]), 0), max(int(roi[1]), 0)
        x_end = min(int(roi[0] + roi[2]), width)
        y_end = min(int(roi[1] + roi[3]), height)
        sub = image[y_off:y_end, x_off:x_end]
    if sub.size == 0:
        return _empty(threshold, bg, sigma)

    binary = above_threshold(sub, threshold, bg, params, whole_image=roi is None)
    # A dim, foreshortened marker can break into pieces at the threshold;
    # closing one-pixel gaps keeps it one blob (markers lie far further apart).
    grouped = cv2.dilate(binary, _CLOSE_KERNEL)
    contours, _ = cv2.findContours(grouped, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return _empty(threshold, bg, sigma)
    boxes = np.array([cv2.boundingRect(c) for c in contours], dtype=np.int64)
    boxes[:, 0] += x_off
    boxes[:, 1] += y_off
    # A blob cut by the search region's edge (not the image's) has a biased centre.
    sub_h, sub_w = sub.shape
    truncated = (((boxes[:, 0] == x_off) & (x_off > 0))
                 | ((boxes[:, 1] == y_off) & (y_off > 0))
                 | ((boxes[:, 0] + boxes[:, 2] == x_off + sub_w) & (x_off + sub_w < width))
                 | ((boxes[:, 1] + boxes[:, 3] == y_off + sub_h) & (y_off + sub_h < height)))
    sides = boxes[:, 2:].max(axis=1) + 2 * params.pad_px
    small = sides <= min(_FAST_WINDOW_PX, width, height)
    if small.any() and not params.smooth_px and params.subtract_background and not keep_pixels:
        # The blobs that fit a small window all at once; the few larger ones
        # (a lamp, a fused reflection) one at a time, so that one large blob
        # does not put every other on the slow path.
        side = int(sides[small].max())
        stats = _centroids_fixed_windows(image, boxes, side, threshold, 2.0 * sigma, np.flatnonzero(small))
        if stats is not None:
            centers, area, peak, flux, spread, shot = stats
            if not small.all():
                large = _centroids_per_blob(image, binary, contours, boxes, (x_off, y_off), params, threshold,
                                            bg, sigma, False, only=np.flatnonzero(~small))
                for fast, slow in zip((centers, area, peak, flux, spread, shot), large[:5] + large[6:]):
                    fast[~small] = slow[~small]
            return _finish(centers, area, peak, flux, spread, boxes, truncated, params, threshold, bg, sigma, [],
                           2.0 * sigma, shot)
    centers, area, peak, flux, spread, pixels, shot = _centroids_per_blob(
        image, binary, contours, boxes, (x_off, y_off), params, threshold, bg, sigma, keep_pixels)
    noise_floor = 2.0 * sigma if params.subtract_background else 0.0
    return _finish(centers, area, peak, flux, spread, boxes, truncated, params, threshold, bg, sigma, pixels,
                   noise_floor, shot)


# Blobs up to this window side (px) take the vectorized path: one array op per
# statistic for all blobs instead of a Python iteration per blob.
_FAST_WINDOW_PX = 40


def _centroids_fixed_windows(image, boxes, side, threshold, noise_floor, which):
    """Centroids of the blobs ``which`` (indices into ``boxes`` (n, 4)) at once from equal square windows
    (len(which), side, side); statistics (n,) for every blob, NaN / 0 where not measured.

    Returns None when a window would hold part of another blob (then the
    per-blob path masks it out).
    """
    height, width = image.shape
    chosen = boxes[which]
    cx = chosen[:, 0] + chosen[:, 2] // 2
    cy = chosen[:, 1] + chosen[:, 3] // 2
    ox = np.clip(cx - side // 2, 0, width - side)
    oy = np.clip(cy - side // 2, 0, height - side)
    # Another blob's box inside this window would bias the centroid.
    inside = ((boxes[None, :, 0] < (ox + side)[:, None]) & (boxes[None, :, 0] + boxes[None, :, 2] > ox[:, None])
              & (boxes[None, :, 1] < (oy + side)[:, None]) & (boxes[None, :, 1] + boxes[None, :, 3] > oy[:, None]))
    if inside.sum() > len(chosen):
        return None
    stats = _window_stats((image,), ox, oy, side, threshold, noise_floor)
    n = len(boxes)
    centers, area, peak = np.full((n, 2), np.nan), np.zeros(n, np.int64), np.zeros(n)
    flux, spread, shot = np.zeros(n), np.zeros(n), np.full((n, 2), np.nan)
    centers[which], flux[which], peak[which], area[which], _, spread[which], shot[which] = stats
    return centers, area, peak, flux, spread, shot


def _window_view(image: np.ndarray, side: int) -> np.ndarray:
    """All side x side windows of an image as a read-only view (H−s+1, W−s+1, s, s).

    ``np.ndarray`` over the image's buffer: the same view as numpy's
    sliding_window_view at a tenth of its call overhead (it runs per frame).
    """
    image = np.ascontiguousarray(image)
    h, w = image.shape
    return np.ndarray((h - side + 1, w - side + 1, side, side), dtype=image.dtype, buffer=image,
                      strides=(image.strides[0], image.strides[1], image.strides[0], image.strides[1]))


def _window_stats(images, ox, oy, side, threshold, noise_floor, which=None, border=False, window_iterations=2):
    """Background-subtracted centroid statistics of n square windows at once.

    Parameters
    ----------
    images : sequence of (H, W) uint8
        The images the windows lie in (one or both cameras).
    ox, oy : (n,) int
        Top-left corners of the windows, inside their image.
    side : int
        Window side, px.
    threshold : float or (n,) array
        Absolute threshold, DN, for the count of bright pixels.
    noise_floor : float or (n,) array
        Subtracted above the local background (2σ) so noise adds no weight.
    which : (n,) int, optional
        Image index of each window (default: all in images[0]).
    border : bool
        Also return the highest weight on each window's edge.

    Returns
    -------
    centers (n, 2) px, flux (n,), peak (n,), area (n,) px above threshold,
    border_peak (n,) or None: a blob cut by its window has a large one,
    spread (n,): Σ (x − cx)² + (y − cy)² over the pixels with weight, px².
    """
    if which is None:
        windows = _window_view(images[0], side)[oy, ox]
    else:
        windows = np.concatenate([_window_view(img, side)[oy[which == k], ox[which == k]]
                                  for k, img in enumerate(images)])
    windows = windows.astype(np.float32)
    total = windows.sum(axis=(1, 2))
    inner = windows[:, 1:-1, 1:-1].sum(axis=(1, 2))
    level = (total - inner) / (4 * side - 4) + noise_floor       # local background + noise floor
    weights = windows - level[:, None, None]
    np.maximum(weights, 0, out=weights)
    cols = weights.sum(axis=1)
    rows = weights.sum(axis=2)
    flux = cols.sum(axis=1, dtype=np.float64)
    ramp = np.arange(side, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        centers = np.stack([ox + cols @ ramp / flux, oy + rows @ ramp / flux], axis=1)
    centers[flux <= 0] = np.nan
    support = weights > 0
    dx = ramp[None, :] - (centers[:, :1] - ox[:, None])
    dy = ramp[None, :] - (centers[:, 1:] - oy[:, None])
    spread = (support.sum(axis=1) * dx ** 2).sum(axis=1) + (support.sum(axis=2) * dy ** 2).sum(axis=1)
    peak = weights.max(axis=(1, 2)) + noise_floor
    shot = np.full((len(centers), 2), np.nan)
    if window_iterations:
        signal = windows - (level - noise_floor)[:, None, None]
        size = np.sqrt(np.maximum(flux / np.maximum(peak - noise_floor, tol.floor), 1.0) / (2 * np.pi))
        origin = np.stack([ox, oy], axis=1)
        start = centers - origin
        local, spread_w, _, shot_w = _gaussian_windowed_centroid(signal, start, np.maximum(size, 0.7),
                                                                 window_iterations, with_total=True)
        good = np.isfinite(local).all(axis=1) & (np.abs(local - start).max(axis=1) < 2)
        centers = np.where(good[:, None], local + origin, centers)
        spread = np.where(good, spread_w * flux ** 2, spread)    # callers divide by flux²
        shot = np.where(good[:, None], shot_w, np.nan)
    area = np.count_nonzero(windows >= np.reshape(threshold, (-1, 1, 1)), axis=(1, 2))
    border_peak = None
    if border:
        weights[:, 1:-1, 1:-1] = 0
        border_peak = weights.max(axis=(1, 2)) + noise_floor
    return centers, flux, peak, area, border_peak, spread, shot


def _window_constants(side: int):
    """Per window side (px), cached: the offsets ``arange(side)`` (side,) float32 and the border mask
    (side², ) float32, 1 on the window's one-pixel edge."""
    constants = _WINDOW_CONSTANTS.get(side)
    if constants is None:
        border = np.ones((side, side), np.float32)
        border[1:-1, 1:-1] = 0
        constants = _WINDOW_CONSTANTS[side] = (np.arange(side, dtype=np.float32), border.reshape(-1))
    return constants


_WINDOW_CONSTANTS: dict = {}


def _border_levels(windows: np.ndarray) -> np.ndarray:
    """Mean of each window's one-pixel edge (n,) float32, DN, of integer-valued windows (n, s, s) float32.

    One matrix-vector product with the edge's mask: the pixels are whole DN,
    so every partial sum is an integer below 2²⁴ (s ≤ 256) and exact in
    float32 in any order (the same value as summing the edge any other way).
    """
    n, side = windows.shape[:2]
    if side > 256:              # partial sums could round: the plain sums (never met: windows are ~30 px)
        total = windows.sum(axis=(1, 2)) - windows[:, 1:-1, 1:-1].sum(axis=(1, 2))
    else:
        total = windows.reshape(n, side * side) @ _window_constants(side)[1]
    return total * np.float32(1.0 / (4 * side - 4))


def _gaussian_windowed_centroid(signal, start, size, iterations, with_total=False, with_shot=True,
                                converged_px=0.0):
    """Gaussian-windowed centroids of background-subtracted windows (n, s, s).

    The centre c solves Σ g(x − c) I(x) (x − c) = 0 per axis, g a Gaussian of
    the blob's own size s (SExtractor's XWIN): unbiased for any symmetric
    blob, and far pixels, where noise dominates, get almost no weight; nothing
    is clipped, so noise does not pull the centre toward the window's middle.
    Each step is Newton's: Δc = Σ g I (x − c) / D, D = Σ g I − Σ g I (x − c)² / s²
    per axis (= half of Σ g I for a round Gaussian blob, XWIN's factor 2;
    smaller along the length of an elongated blob, whose centre is noisier
    that way). Iterations stop early once no centre moved by more than
    ``converged_px`` in a step: from a start δ off, one step leaves about
    δ³/(2 s²), far below the noise for δ ≤ 0.05 px.

    Parameters
    ----------
    signal : (n, s, s) float32
        Windows less their background, DN.
    start : (n, 2) float32
        Starting centres (x, y) in window pixels.
    size : (n,)
        Gaussian σ of each blob, px.

    Returns centres (n, 2) in window pixels and ``spread`` (n,), with
    var(c_x) + var(c_y) = σ_n² · spread for pixel noise σ_n: first-order
    propagation, var(c_x) = σ_n² Σ g² (x − c)² / D_x²; with ``with_total``
    also Σ g I, the Gaussian-weighted flux (DN·px), and (``with_shot``) the
    variance of c_x and c_y per unit shot-noise factor κ (pixel variance κ I),
    Σ g² (x − c)² I / D_x², shape (n, 2).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        c, spread, total, shot = _windowed_centroid(signal, start, size, iterations, with_total, with_shot,
                                                    converged_px)
    if with_total:
        return c.astype(np.float64), spread, total, shot
    return c.astype(np.float64), spread


def _windowed_centroid(signal, start, size, iterations, with_total, with_shot, converged_px):
    """:func:`_gaussian_windowed_centroid` without its ``np.errstate`` (the caller holds one: it
    costs a context switch of numpy's error state per call): centres (n, 2) float32, spread (n,),
    total (n,) float64 and shot (n, 2) or None, whatever ``with_total``."""
    # The arithmetic is float32 and runs per frame on ~10 windows: numpy's
    # per-call overhead, not the pixels, sets its time, so the sums of both
    # axes share calls. Each number is still computed by the same operations
    # in the same order as one sum per quantity would (rows are summed one by
    # one either way), so the centres are the same to the bit.
    n, side = signal.shape[:2]
    ramp = _window_constants(side)[0]
    c = np.asarray(start, dtype=np.float32)
    inv_size2 = 1.0 / np.square(size, dtype=np.float32)                # (n,) 1/s², px⁻², s in float32
    inv_size2_col = inv_size2[:, None]
    # −½/s² is exact (a power of two), so d² · (−½/s²) rounds as (−½ d²)/s² would.
    neg_half = (-0.5 * inv_size2)[:, None, None]
    # Per window and axis the offsets' powers (1, d, d²) side by side: one
    # product and one sum give Σ w, Σ w d and Σ w d² of weights w (n, 2, s).
    powers = np.empty((n, 2, 3, side), np.float32)
    powers[:, :, 0] = 1.0
    d, d2 = powers[:, :, 1], powers[:, :, 2]                          # (n, 2, side): x then y offsets
    g = np.empty((n, 2, side), np.float32)
    proj = np.empty((n, 2, side), np.float32)
    passes = max(iterations, 1)
    for i in range(passes):
        np.subtract(ramp, c[:, :, None], out=d)
        np.multiply(d, d, out=d2)
        np.multiply(d2, neg_half, out=g)
        np.exp(g, out=g)
        np.matmul(g[:, 1, None, :], signal, out=proj[:, 0:1, :])      # Σ_y g(y) I(y, x)
        np.matmul(signal, g[:, 0, :, None], out=proj[:, 1, :, None])  # Σ_x g(x) I(y, x)
        proj *= g
        moments = (proj[:, :, None, :] * powers).sum(axis=3)          # (n, 2, 3): Σ w, Σ w d, Σ w d²
        total = moments[:, 0, 0]
        # Newton's derivative per axis, kept ≥ T/4 (a blob much longer
        # than the window would otherwise make the step explode).
        slope = total[:, None] - moments[:, :, 2] * inv_size2_col
        slope = np.maximum(slope, 0.25 * total[:, None])
        if not iterations:          # 0: only the weights at the given centres
            break
        step = moments[:, :, 1] / slope
        np.minimum(step, 1.0, out=step)
        np.maximum(step, -1.0, out=step)
        c = c + step
        # Converged when no step exceeds converged_px (after the last
        # pass the test would change nothing); a NaN step (an empty
        # window) never has. On 2n numbers Python's builtins beat two
        # numpy reductions.
        if converged_px and i + 1 < passes:
            moves = step.ravel().tolist()
            if not math.isnan(sum(moves)) and max(map(abs, moves)) <= converged_px:
                break
    # Noise propagation at the last weights (the final step is far below σ_c).
    g2 = np.multiply(g, g, out=g)
    squares = g2[:, :, None, :] * powers                              # g², g² d, g² d²
    sums = squares.sum(axis=3)                                         # (n, 2, 3)
    total = total.astype(np.float64)
    slope2 = np.square(slope, dtype=np.float64)                        # D², squared in float64
    # var(c_x) ∝ Σ g(x)² (x − c)² · Σ g(y)² / D_x², and likewise for y.
    shares = sums[:, :, 2] * sums[:, ::-1, 0] / slope2
    spread = shares[:, 0] + shares[:, 1]
    shot = None
    if with_total and with_shot:
        positive = np.maximum(signal, 0)
        right = np.stack([squares[:, 0, 2], g2[:, 0]], axis=2)        # (n, side, 2): gx² dx², gx²
        left = np.ascontiguousarray(squares[:, 1, ::2])               # (n, 2, side): gy², gy² dy²
        terms = left @ (positive @ right)                              # (n, 2, 2)
        shot = np.stack([terms[:, 0, 0], terms[:, 1, 1]], axis=1).astype(np.float64) / slope2
    return c, spread, total, shot


def centroids_near(images, guesses_px: np.ndarray, side_px: int, backgrounds, thresholds_dn,
                   size_px: np.ndarray, with_shot: bool = False):
    """Re-measure known blobs near predicted positions, without a full detection.

    The tracking fast path: one square window per blob around its predicted
    centre, the window's edge as the local background, and Gaussian-windowed
    centroid iterations started at the prediction; a few array operations
    for all markers of both images, and no threshold, contour or clipping.

    Parameters
    ----------
    images : sequence of k (H, W) uint8
    guesses_px : (k, n, 2)
        Predicted centres per image, px.
    side_px : int
        Window side, px: the blob plus the prediction's error must fit.
    backgrounds : sequence of k (level_dn, sigma_dn)
    thresholds_dn : sequence of k float
        A blob whose peak does not reach 0.6 of its image's threshold above
        the background is not found.
    size_px : (k, n)
        Gaussian σ of each blob (from the previous frame), px.

    Returns
    -------
    centers_px (k, n, 2), found (k, n) bool, flux (k, n) Gaussian-weighted
    flux (DN·px), sigma_px (k, n) expected centroid noise per coordinate,
    size_px (k, n) the blobs' Gaussian σ measured now, and the centroid
    variance per coordinate per unit pixel-noise variance (k, n) and of x
    and y per unit shot-noise factor (k, n, 2) (see :func:`_gaussian_windowed_centroid`;
    None unless ``with_shot``: the tracking path leaves it to the covariance
    stage, :func:`shot_variance`).
    """
    # Runs every tracked frame on 2 x 5 windows of ~27² px: numpy's per-call
    # overhead sets its time, so per-image values broadcast as (k, 1) rather
    # than being repeated per window, and no sum is taken that a cheaper
    # exact one can replace.
    k, n = np.shape(guesses_px)[:2]
    m = k * n
    height, width = images[0].shape
    side = int(min(side_px, width, height))
    ramp = _window_constants(side)[0]
    # Per image (k, 1) float32: pixel noise σ, the noise floor 2σ and the
    # least peak, 0.6 of the detection contrast, DN.
    noise, contrast = np.array([backgrounds[0][1], backgrounds[-1][1]][:k]
                               + [thresholds_dn[j] - backgrounds[j][0] for j in range(k)], np.float32).reshape(2, k, 1)
    noise_floor = 2.0 * noise
    least_peak = 0.6 * contrast
    guesses = np.reshape(guesses_px, (m, 2))
    found = np.isfinite(guesses).all(axis=1)
    origin = np.where(found[:, None], guesses, 0.0).astype(np.int64)
    origin -= side // 2
    np.minimum(np.maximum(origin, 0, out=origin), (width - side, height - side), out=origin)
    ox, oy = origin[:, 0], origin[:, 1]
    windows = np.empty((m, side, side), np.float32)
    for j, img in enumerate(images):             # one gather per image (k ≤ 2)
        np.copyto(windows[j * n:(j + 1) * n], _window_view(img, side)[oy[j * n:(j + 1) * n], ox[j * n:(j + 1) * n]])
    level = _border_levels(windows)
    signal = np.subtract(windows, level[:, None, None], out=windows)
    # Start from the plain centroid of what stands above the noise: robust to
    # a prediction several pixels off, which the Gaussian window is not.
    # Its column sums add the rows one after another whatever the layout;
    # rows first (side, m, side) makes that a few long additions instead of
    # m·side short ones (the same additions in the same order: the same bits).
    bright = np.subtract(signal.reshape(k, n, side, side), noise_floor[:, :, None, None]).reshape(m, side, side)
    np.maximum(bright, 0, out=bright)
    bright_rows = np.ascontiguousarray(bright.transpose(1, 0, 2))     # (side, m, side)
    start = np.empty((m, 2), np.float32)
    # One error state for the rest (an empty window divides by zero: its NaNs are not found).
    with np.errstate(invalid="ignore", divide="ignore"):
        mass = bright.sum(axis=(1, 2))
        np.matmul(bright_rows.sum(axis=0), ramp, out=start[:, 0])
        np.matmul(bright.sum(axis=2), ramp, out=start[:, 1])
        start /= mass[:, None]
        # From the plain centroid one Newton step is enough for a still head
        # (the start is within ~0.05 px); a moving or asymmetric blob needs the
        # second. (The constant-velocity prediction is a worse start: measured
        # 0.08 px off for a still head, about a pixel in the yaw sweep.)
        local, spread, total, shot = _windowed_centroid(signal, start, np.reshape(size_px, -1), 2, True, with_shot,
                                                        0.08)
        peak = signal.max(axis=(1, 2))
        signal[:, 1:-1, 1:-1] = 0
        edge = signal.max(axis=(1, 2))
        # Found: converged inside the window, bright enough, and wholly inside it
        # (nothing bright on the window's edge).
        # Where a marker is expected, a peak of 0.6 of the detection contrast
        # (3σ with the default 5σ) is enough: nothing else is being searched for.
        # The centre must stay inside the window, and nothing bright may touch
        # the window's edge (the blob lies wholly inside).
        offset = np.abs(np.subtract(local, 0.5 * (side - 1), dtype=np.float64))
        peak = peak.reshape(k, n)
        found = (found.reshape(k, n) & (peak >= least_peak) & (edge.reshape(k, n) <= 0.15 * peak + noise_floor)
                 & (np.maximum(offset[:, 0], offset[:, 1]).reshape(k, n) < 0.5 * side - 2))
        half_spread = (spread / 2).reshape(k, n)
        total = total.reshape(k, n)
        centroid_sigma = noise * np.sqrt(half_spread)
        size = np.sqrt(np.maximum(2 * total / peak, 1.0) / (2 * np.pi))
    return (np.add(local, origin, dtype=np.float64).reshape(k, n, 2), found, total, centroid_sigma, size, half_spread,
            None if shot is None else shot.reshape(k, n, 2))


def shot_variance(images, centers_px: np.ndarray, size_px: np.ndarray, backgrounds) -> np.ndarray:
    """Centroid variance of x and y per unit shot-noise factor (k, n, 2), px²/DN.

    The Gaussian-windowed centroid's propagation of a pixel noise whose
    variance is κ times the pixel's signal, at given centres (k, n, 2) and
    blob sizes (k, n) px; for the covariance stage, after the tracking path
    measured the centres without it.
    """
    k, n = np.shape(centers_px)[:2]
    height, width = images[0].shape
    side = 2 * int(np.ceil(3 * np.nanmax(size_px))) + 3
    side = int(min(side, width, height))
    guesses = np.reshape(centers_px, (k * n, 2))
    found = np.isfinite(guesses).all(axis=1)
    origin = np.where(found[:, None], guesses, 0.0).astype(np.int64) - side // 2
    np.minimum(np.maximum(origin, 0, out=origin), (width - side, height - side), out=origin)
    windows = np.concatenate([_window_view(img, side)[origin[j * n:(j + 1) * n, 1], origin[j * n:(j + 1) * n, 0]]
                              for j, img in enumerate(images)]).astype(np.float32)
    level = (windows.sum(axis=(1, 2)) - windows[:, 1:-1, 1:-1].sum(axis=(1, 2))) * (1.0 / (4 * side - 4))
    signal = windows - level[:, None, None]
    start = (np.where(found[:, None], guesses, 0.0) - origin).astype(np.float32)
    size = np.nan_to_num(np.reshape(size_px, -1), nan=1.0)
    # Zero iterations of the centre: the weights at the given centres.
    _, _, _, shot = _gaussian_windowed_centroid(signal, start, np.maximum(size, 0.7), 0, with_total=True)
    return np.where(found[:, None], shot, np.nan).reshape(k, n, 2)


def _centroids_per_blob(image, binary, contours, boxes, offset, params, threshold, bg, sigma, keep_pixels,
                        only=None):
    """Centroids one blob at a time: masks out neighbours, smooths (paper), keeps pixel clouds.
    ``only``: the indices of the blobs to measure (default all; the others keep NaN / 0)."""
    height, width = image.shape
    x_off, y_off = offset
    pad = params.pad_px
    x0 = np.maximum(boxes[:, 0] - pad, 0)
    y0 = np.maximum(boxes[:, 1] - pad, 0)
    x1 = np.minimum(boxes[:, 0] + boxes[:, 2] + pad, width)
    y1 = np.minimum(boxes[:, 1] + boxes[:, 3] + pad, height)
    # Windows that overlap another blob's window need that blob masked out.
    overlaps = ((x0[:, None] < x1[None, :]) & (x0[None, :] < x1[:, None])
                & (y0[:, None] < y1[None, :]) & (y0[None, :] < y1[:, None]))
    np.fill_diagonal(overlaps, False)
    crowded = overlaps.any(axis=1)

    n = len(contours)
    centers = np.full((n, 2), np.nan)
    area = np.zeros(n, dtype=np.int64)
    peak = np.zeros(n)
    flux = np.zeros(n)
    spread = np.zeros(n)
    shot = np.full((n, 2), np.nan)
    pixels = []
    noise_floor = 2.0 * sigma if params.subtract_background else 0.0
    for i in range(n) if only is None else only:  # a few blobs; per-pixel work inside is OpenCV/numpy
        win = image[y0[i]:y1[i], x0[i]:x1[i]].astype(np.float32)
        if crowded[i]:
            mask = np.zeros(win.shape, np.uint8)
            cv2.drawContours(mask, contours, i, 1, thickness=-1, offset=(x_off - int(x0[i]), y_off - int(y0[i])))
            mask = cv2.dilate(mask, np.ones((2 * pad + 1, 2 * pad + 1), np.uint8))
            win *= mask
        if params.smooth_px:
            k = params.smooth_px | 1
            win = cv2.GaussianBlur(win, (k, k), 0)
        if params.subtract_background:
            level = _border_mean(win) if not crowded[i] else bg
            weights = win - (level + noise_floor)
        else:
            weights = np.where(win >= threshold, win, 0.0).astype(np.float32)
        np.maximum(weights, 0, out=weights)
        m = cv2.moments(weights)
        if m["m00"] <= 0:
            if keep_pixels:
                pixels.append(None)
            continue
        centers[i] = (x0[i] + m["m10"] / m["m00"], y0[i] + m["m01"] / m["m00"])
        flux[i] = m["m00"]
        ys, xs = np.nonzero(weights)
        offsets2 = (xs + x0[i] - centers[i, 0]) ** 2 + (ys + y0[i] - centers[i, 1]) ** 2
        spread[i] = np.sum(offsets2)
        # Shot noise (pixel variance ∝ its signal), per axis: Σ (x − c)² I / F².
        signal_px = weights[ys, xs]
        shot[i] = (np.sum((xs + x0[i] - centers[i, 0]) ** 2 * signal_px) / m["m00"] ** 2,
                   np.sum((ys + y0[i] - centers[i, 1]) ** 2 * signal_px) / m["m00"] ** 2)
        peak[i] = float(weights.max()) + noise_floor
        bx, by, bw, bh = boxes[i, 0] - x_off, boxes[i, 1] - y_off, boxes[i, 2], boxes[i, 3]
        area[i] = cv2.countNonZero(binary[by:by + bh, bx:bx + bw])
        if keep_pixels:
            pixels.append((np.column_stack([xs + x0[i], ys + y0[i]]).astype(np.float64),
                           weights[ys, xs].astype(np.float64)))
    return centers, area, peak, flux, spread, pixels, shot


def _finish(centers, area, peak, flux, spread, boxes, truncated, params, threshold, bg, sigma, pixels, noise_floor,
            shot=None):
    with np.errstate(invalid="ignore", divide="ignore"):
        centroid_sigma = sigma * np.sqrt(spread / 2) / flux
    effective_area = flux / np.maximum(peak - noise_floor, tol.small)
    glint = (area <= params.glint_max_area_px) & (effective_area <= params.glint_max_effective_area_px)
    keep = np.isfinite(centers[:, 0]) & (area >= params.min_area_px) & ~truncated
    blobs = Blobs(centers, area, peak, flux, glint, boxes, centroid_sigma, threshold, bg, sigma, pixels)
    blobs.shot_var = shot if shot is not None else np.full((len(centers), 2), np.nan)
    return blobs.subset(keep)


def _border_mean(win: np.ndarray) -> float:
    """Mean of a window's one-pixel border: the local background under a blob."""
    if win.shape[0] < 3 or win.shape[1] < 3:
        return float(win.min())
    total = win[0].sum() + win[-1].sum() + win[1:-1, 0].sum() + win[1:-1, -1].sum()
    return float(total) / (2 * win.shape[1] + 2 * (win.shape[0] - 2))


def _empty(threshold: float, bg: float, sigma: float) -> Blobs:
    return Blobs(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0),
                 np.zeros(0, bool), np.zeros((0, 4), np.int64), np.zeros(0), threshold, bg, sigma, [])
