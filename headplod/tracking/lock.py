"""The markers of a frame, and the *track* state's lock on them.

- :class:`_Match`: the marker centres of one measurement of a frame,
  (2, 5, 2) px (camera 0 left, 1 right; markers P0..P4), with their
  visibility and what the fit needs of them (noise, flux, size, the rolling
  shutter's displacement).
- :class:`_Lock`: what tracking re-measures: the last accepted frame's
  centres. The tracker is in its *track* state while it has one, and
  *acquires* (:mod:`.acquire`) while it has none.
- :class:`_Tracking`, a part of :class:`~.tracker.Tracker` (a mixin): the
  re-measure of the locked markers in small windows around where they
  should be (:meth:`_Tracking._track_fast`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .detect import centroids_near

# Read-only constants of the tracking path (copied before any change).
_ALL_VISIBLE = np.ones((2, 5), bool)
_NO_BLOB = np.full((2, 5), -1)
_NAN5 = np.full(5, np.nan)
_NAN53 = np.full((5, 3), np.nan)
for _constant in (_ALL_VISIBLE, _NO_BLOB, _NAN5, _NAN53):
    _constant.flags.writeable = False
MARKER_NAMES = ("P0", "P1", "P2", "P3", "P4")


@dataclass
class _Match:
    """Marker centres of one identification: (2, 5, 2) px and visibility (2, 5)."""

    centers: np.ndarray
    visible: np.ndarray
    blob_index: np.ndarray      # (2, 5) blob index per image, -1 if hidden
    epipolar: np.ndarray        # (5,)
    points: np.ndarray          # (5, 3) triangulated, NaN if hidden in a view
    R: np.ndarray
    t: np.ndarray
    fit_rms: float
    sigma_px: np.ndarray = None     # (2, 5) expected centroid noise, px
    flux: np.ndarray = None         # (2, 5) blob flux, DN·px
    size: np.ndarray = None         # (2, 5) Gaussian σ of each blob as re-measured while tracking, px
    shot_var: np.ndarray = None     # (2, 5, 2) centroid variance of x, y per unit shot-noise factor, px²/DN
    excess_px: np.ndarray = None    # (2, 5) error of a suspect centre beyond its noise (a fused glint), px
    # A rolling shutter exposes each row at its own time: each centre's
    # displacement by the head's motion from the image's time t to its row's
    # time (2, 5, 2) px, which the fit takes off the measured centre, and
    # that displacement's 1σ from the velocity's uncertainty (2, 5) px, per
    # coordinate. None: not compensated (a global shutter, no motion known).
    shutter_shift_px: np.ndarray = None
    shutter_sd_px: np.ndarray = None
    shutter_delay_s: np.ndarray = None   # (2, 5) each centre's row time after t, s
    shutter_cov: np.ndarray = None       # (6, 6) covariance of the head's velocity over those delays


@dataclass
class _Lock:
    """What tracking re-measures: the markers of the last accepted frame (the tracker is in its *track*
    state while it has one, and *acquires* — detects and identifies from scratch — while it has none)."""

    centers: np.ndarray                 # (2, 5, 2) last accepted centres, px
    previous: np.ndarray | None         # (2, 5, 2) the ones before, for a constant-velocity prediction
    size: np.ndarray                    # (2, 5) Gaussian σ of each marker's blob, px
    flux: np.ndarray | None             # (2, 5) fluxes, DN·px; None after a full detection (measured otherwise)

    def predicted(self) -> np.ndarray:
        """Where the markers should be in this frame (2, 5, 2) px: at constant image velocity."""
        return self.centers if self.previous is None else 2 * self.centers - self.previous


class _Tracking:
    """The *track* state's measurement of :class:`~.tracker.Tracker` (module docstring)."""

    def _track_fast(self, images) -> _Match | None:
        """Re-measure the previous frame's markers in small windows; None to re-acquire."""
        lock = self._lock
        predicted, size = lock.predicted(), lock.size
        # Window: the blob (±3 σ) plus the prediction's error.
        side = 2 * int(np.ceil(3 * size.max() + self.config.track_margin_px / 2)) + 1
        centers, found, flux, sigma, size, _, shot_var = centroids_near(images, predicted, side, self._prev_background,
                                                                        self._prev_threshold, size)
        if not found.all():
            return None
        # (Two windows locked onto one blob leave a residual of a marker
        # spacing, tens of pixels: verification rejects that frame.)
        # A glint or a neighbour entering a window adds flux to one marker:
        # re-identify rather than let it pull the centroid. Head motion
        # changes all markers of a view alike, so compare with the median.
        if lock.flux is not None:
            # Allowed: the configured change plus 3σ of the relative flux
            # noise of the dimmest marker (Gaussian-weighted flux: σ_n √π s,
            # s the blob's σ), around the median change of the five.
            changes = np.sort(flux / lock.flux, axis=1).tolist()
            dimmest = (flux.min(axis=1) / size.max(axis=1)).tolist()
            for cam in (0, 1):
                low, _, median, _, high = changes[cam]
                if not dimmest[cam] > 0:
                    return None                       # a window with no flux: re-detect
                rel = self._prev_background[cam][1] * 1.7725 / dimmest[cam]
                # 3√2 σ of a ratio; beyond a factor e⁵ the check says nothing anyway.
                limit = self.config.track_flux_change * math.exp(min(4.24 * rel, 5.0))
                if not (median / limit <= low and high <= median * limit):
                    return None
        visible, index = _ALL_VISIBLE, _NO_BLOB
        if self.config.estimator == "reproj":
            # The labels are carried over, and the reprojection fit started
            # from the last pose verifies them: no triangulation needed.
            R, t = self._predicted_pose()
            return _Match(centers, visible, index, _NAN5, _NAN53, R, t, float("nan"), sigma, flux, size, shot_var)
        match = self._match_from_centers(centers, visible, index)
        if match is not None:
            match.sigma_px, match.flux, match.size, match.shot_var = sigma, flux, size, shot_var
        return match

    def _predicted_pose(self):
        """This frame's pose by constant velocity from the last two (the last one if unknown)."""
        return self._motion.predicted(*self._prev_pose)
