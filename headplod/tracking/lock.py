"""The markers of a frame, and the *track* state's lock on them.

- :class:`Match`: the marker centres of one measurement of a frame,
  (2, 5, 2) px (camera 0 left, 1 right; markers P0..P4), with their
  visibility and what the fit needs of them (noise, flux, size, the rolling
  shutter's displacement).
- :class:`Lock`: what tracking re-measures: the last accepted frame's
  centres. The tracker is in its *track* state while it has one, and
  *acquires* (:mod:`.acquire`) while it has none.
- :func:`centroid_sigma`, :func:`fit_centers`: what the fit and its checks take of a match.

The re-measure of the locked markers is :meth:`.detection.Detector.remeasure`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


# Read-only constants of the tracking path (copied before any change).
_ALL_VISIBLE = np.ones((2, 5), bool)
_NO_BLOB = np.full((2, 5), -1)
_NAN5 = np.full(5, np.nan)
_NAN53 = np.full((5, 3), np.nan)
for _constant in (_ALL_VISIBLE, _NO_BLOB, _NAN5, _NAN53):
    _constant.flags.writeable = False
MARKER_NAMES = ("P0", "P1", "P2", "P3", "P4")


@dataclass
class Match:
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
class Lock:
    """What tracking re-measures: the markers of the last accepted frame (the tracker is in its *track*
    state while it has one, and *acquires* — detects and identifies from scratch — while it has none)."""

    centers: np.ndarray                 # (2, 5, 2) last accepted centres, px
    previous: np.ndarray | None         # (2, 5, 2) the ones before, for a constant-velocity prediction
    size: np.ndarray                    # (2, 5) Gaussian σ of each marker's blob, px
    flux: np.ndarray | None             # (2, 5) fluxes, DN·px; None after a full detection (measured otherwise)
    # (2, 5) which markers were seen; None: all ten. One marker hidden in one view (a hand, a hinge) is
    # tracked through: the other nine are re-measured, and the hidden one looked for where the pose puts it.
    visible: np.ndarray | None = None

    def predicted(self) -> np.ndarray:
        """Where the markers should be in this frame (2, 5, 2) px: at constant image velocity."""
        return self.centers if self.previous is None else 2 * self.centers - self.previous


def centroid_sigma(match: Match, floor_px: float) -> np.ndarray:
    """Expected centroid error (2, 5), px: the noise, floored at ``floor_px`` (a perfect image is never
    perfect), with a suspect centre's excess and the rolling shutter's share."""
    sigma = np.maximum(match.sigma_px, floor_px)
    if match.excess_px is not None:
        sigma = np.hypot(sigma, match.excess_px)
    if match.shutter_sd_px is not None:
        sigma = np.hypot(sigma, match.shutter_sd_px)
    return sigma


def fit_centers(match: Match):
    """The centres the pose is fitted to (left (5, 2), right (5, 2)) px: measured, less the rolling
    shutter's displacement when compensated."""
    centers = match.centers if match.shutter_shift_px is None else match.centers - match.shutter_shift_px
    return centers[0], centers[1]
