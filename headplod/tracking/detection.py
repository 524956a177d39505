"""Detection, a part of :class:`~.tracker.Tracker`: the marker blobs of a frame's two images.

- *acquire*: every blob of each whole image (:meth:`Detector.detect`,
  :func:`~.detect.detect_blobs` on the image's estimated background);
- *track*: the locked markers re-measured in small windows around where
  they should be (:meth:`Detector.remeasure`, a :class:`Remeasured`), or
  None when that fails (the tracker then acquires).

:class:`Detector` owns the image statistics it carries from frame to frame:
each camera's background (level and noise, DN) from its last full detection
and its blob threshold (DN) from the last accepted frame
(:meth:`Detector.keep_thresholds`). Camera 0 is the left one, 1 the right;
centres in px.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .detect import Blobs, centroids_near, detect_blobs, estimate_background
from .lock import Lock


# The prediction error a re-measure's second, smaller window leaves room for, px (2 px each side).
_NEIGHBOUR_MARGIN_PX = 4.0
# A hidden marker is back when a blob at its place has this fraction of its view's median marker flux.
_REAPPEARED_FLUX = 0.25


def _window_side(size_px: float, margin_px: float) -> int:
    """A re-measure window's side, px (odd): a blob of Gaussian σ ``size_px`` (±3 σ) plus ``margin_px`` of
    prediction error in all (half on each side)."""
    return 2 * int(np.ceil(3 * size_px + margin_px / 2)) + 1


def _crowded(predicted_px: np.ndarray, which: np.ndarray, side_px: float) -> bool:
    """Whether each marker ``which`` (2, 5) bool has another marker's predicted place (2, 5, 2) px inside
    a square of ``side_px`` around its own (its window, widened by a blob's extent)."""
    gap = np.abs(predicted_px[:, :, None, :] - predicted_px[:, None, :, :]).max(axis=-1)     # (2, 5, 5)
    gap[:, np.arange(5), np.arange(5)] = np.inf
    return bool((gap.min(axis=2)[which] <= side_px / 2).all())


class Remeasured(NamedTuple):
    """The locked markers re-measured in a frame: centres (2, 5, 2) px, flux (2, 5) DN·px, expected
    centroid noise ``sigma`` (2, 5) px, Gaussian σ ``size`` (2, 5) px, shot-noise variance per unit factor
    ``shot_var`` (2, 5, 2) px²/DN."""

    centers: np.ndarray
    flux: np.ndarray
    sigma: np.ndarray
    size: np.ndarray
    shot_var: np.ndarray


class Detector:
    """The marker blobs of both images (module docstring).

    Parameters
    ----------
    config : TrackerConfig
        ``detection``, ``track_margin_px``, ``track_flux_change``.
    """

    def __init__(self, config):
        self.detect_config = config
        self._background = [None, None]
        self._threshold = [None, None]

    def reset(self) -> None:
        """Forget the image statistics (a seek, an exception)."""
        self._background = [None, None]
        self._threshold = [None, None]

    @property
    def backgrounds(self) -> tuple:
        """Each camera's background (level, noise) DN from its last full detection, or None."""
        return tuple(self._background)

    @property
    def thresholds(self) -> tuple:
        """Each camera's blob threshold (DN) of the last accepted frame, or None."""
        return tuple(self._threshold)

    def detect(self, images) -> tuple[Blobs, Blobs]:
        """Every blob of the left and right (H, W) uint8 images."""
        return tuple(self._detect_full(img, i) for i, img in enumerate(images))

    def _detect_full(self, image, cam) -> Blobs:
        background = estimate_background(image)
        self._background[cam] = background
        return detect_blobs(image, self.detect_config.detection, background=background)

    def keep_thresholds(self, blobs) -> None:
        """Keep the blob threshold of each camera whose full detection found blobs (an accepted frame's)."""
        for cam in range(2):
            if blobs[cam] is not None and len(blobs[cam]):
                self._threshold[cam] = blobs[cam].threshold_dn

    def remeasure(self, images, lock: Lock, hidden_px: np.ndarray | None = None) -> Remeasured | None:
        """Re-measure the locked markers in small windows; None to re-acquire.

        A lock with a marker hidden in one view (``lock.visible``): the other
        nine are re-measured (NaN for the hidden one), and the hidden one is
        looked for at ``hidden_px`` (2, 5, 2) px, where the predicted pose
        puts it: found there, it is back, and the frame re-acquires all five.
        """
        if lock.visible is not None:
            return self._remeasure_partial(images, lock, hidden_px)
        predicted, size = lock.predicted(), lock.size
        # Window: the blob (±3 σ) plus the prediction's error.
        side = _window_side(size.max(), self.detect_config.track_margin_px)
        centers, found, flux, sigma, measured_size, _, shot_var = centroids_near(
            images, predicted, side, self._background, self._threshold, size)
        if not found.all():
            if not _crowded(predicted, ~found, side + 6 * size.max()):
                return None
            # Each marker not found has another marker's predicted place in
            # its window (markers crowd together as the head turns away):
            # once more with windows that leave room for a small error only.
            side = _window_side(size.max(), _NEIGHBOUR_MARGIN_PX)
            centers, found, flux, sigma, measured_size, _, shot_var = centroids_near(
                images, predicted, side, self._background, self._threshold, size)
            if not found.all():
                return None
        if not self._fluxes_agree(flux, measured_size, lock.flux):
            return None
        return Remeasured(centers, flux, sigma, measured_size, shot_var)

    def _remeasure_partial(self, images, lock: Lock, hidden_px) -> Remeasured | None:
        """:meth:`remeasure` of a lock with a marker hidden in one view."""
        hidden = ~lock.visible
        guesses = np.where(hidden[..., None], np.nan if hidden_px is None else hidden_px, lock.predicted())
        typical = np.nanmedian(lock.size)
        size = np.where(hidden, typical, lock.size)
        side = _window_side(np.nanmax(size), self.detect_config.track_margin_px)
        centers, found, flux, sigma, size, _, shot_var = centroids_near(images, guesses, side, self._background,
                                                                        self._threshold, size)
        if not found[lock.visible].all():
            return None                         # a marker lost: acquire
        # Back: a blob at the hidden marker's place about as bright as the
        # other markers of its view (a fraction of their median flux), not a
        # noise peak. (Each view has four markers or more seen, found.)
        typical_flux = np.nanmedian(np.where(hidden, np.nan, flux), axis=1, keepdims=True)
        if (found & hidden & (flux >= _REAPPEARED_FLUX * typical_flux)).any():
            return None                         # the hidden marker back: acquire all five
        centers, flux, sigma, size = (np.where(hidden[..., None] if a.ndim == 3 else hidden, np.nan, a)
                                      for a in (centers, flux, sigma, size))
        if not self._fluxes_agree(flux, size, lock.flux):
            return None
        return Remeasured(centers, flux, sigma, size, shot_var)

    def _fluxes_agree(self, flux, size, locked_flux) -> bool:
        """Whether each view's fluxes (2, 5) (NaN: hidden) changed alike since the lock's."""
        # (Two windows locked onto one blob leave a residual of a marker
        # spacing, tens of pixels: verification rejects that frame.)
        # A glint or a neighbour entering a window adds flux to one marker:
        # re-identify rather than let it pull the centroid. Head motion
        # changes all markers of a view alike, so compare with the median.
        if locked_flux is None:
            return True
        # Allowed: the configured change plus 3σ of the relative flux
        # noise of the dimmest marker (Gaussian-weighted flux: σ_n √π s,
        # s the blob's σ), around the median change of the view's markers.
        for cam in (0, 1):
            changes = flux[cam] / locked_flux[cam]
            seen = np.isfinite(changes)
            changes = np.sort(changes[seen])
            low, median, high = changes[0], changes[len(changes) // 2], changes[-1]
            dimmest = float(flux[cam][seen].min() / size[cam][seen].max())
            if not dimmest > 0:
                return False                      # a window with no flux: re-detect
            rel = self._background[cam][1] * 1.7725 / dimmest
            # 3√2 σ of a ratio; beyond a factor e⁵ the check says nothing anyway.
            limit = self.detect_config.track_flux_change * math.exp(min(4.24 * rel, 5.0))
            if not (median / limit <= low and high <= median * limit):
                return False
        return True
