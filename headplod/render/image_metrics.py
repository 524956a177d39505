"""Image error measures of a frame against a reference (the benchmarks, render --compare): PSNR (whole, masked, in a disc) and FLIP."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["psnr_db", "disc_mask", "poi_disc", "flip_error", "quality"]


def psnr_db(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    """PSNR (dB, 8-bit peak) of two images (H, W[, C]), optionally over a boolean mask (H, W); inf when identical.

    NaN for an empty mask.
    """
    diff = a.astype(np.float64) - b.astype(np.float64)
    if mask is not None:
        if not mask.any():
            return float("nan")
        diff = diff[mask]
    mse = float(np.mean(diff ** 2))
    return float("inf") if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


def disc_mask(shape, centre_px, radius_px: float) -> np.ndarray:
    """Boolean (H, W) mask of the pixels whose centres lie within ``radius_px`` of ``centre_px`` (x, y), image px."""
    h, w = shape[:2]
    yy, xx = np.ogrid[:h, :w]
    return (xx - centre_px[0]) ** 2 + (yy - centre_px[1]) ** 2 <= radius_px ** 2


def flip_error(reference: np.ndarray, test: np.ndarray, px_per_deg: float) -> float:
    """Mean FLIP error (0 identical … 1) of two 8-bit sRGB images (H, W, 3) seen at ``px_per_deg``."""
    if np.array_equal(reference, test):
        return 0.0
    import flip_evaluator       # imported on use: about 0.3 s, and only the benchmarks and --compare judge images

    ref = reference.astype(np.float32) / 255.0
    tst = test.astype(np.float32) / 255.0
    _, mean, _ = flip_evaluator.evaluate(ref, tst, "LDR", applyMagma=False, parameters={"ppd": float(px_per_deg)})
    return float(mean)


def poi_disc(shape, poi_image_px, radius_px: float) -> np.ndarray:
    """(H, W) bool: pixels whose centres (index + 0.5, GL's) lie within ``radius_px`` of the POI (image px)."""
    return disc_mask(shape, np.asarray(poi_image_px, dtype=np.float64) - 0.5, radius_px)


def quality(image, reference, disc=None, px_per_deg=None, flip: bool = True) -> dict:
    """``psnr_db`` over the image; ``psnr_disc_5deg_db`` in ``disc`` (H, W) bool; ``flip`` at ``px_per_deg``."""
    q = {"psnr_db": psnr_db(image, reference)}
    if disc is not None:
        q["psnr_disc_5deg_db"] = psnr_db(image, reference, disc)
    if flip:
        q["flip"] = flip_error(reference, image, px_per_deg)
    return q
