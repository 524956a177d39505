"""The rolling shutter's compensation: each marker centre taken back to its image's time t through the
head's velocity, and the readout it needs.

Row r of an image H rows high is exposed at t + (r − (H − 1)/2) × readout
/ (H − 1) (t is the middle row's time, the dataset contract's
mid-exposure). :class:`RollingShutter` is a part of
:class:`~.tracker.Tracker`; it reads the rig in use and its refinement
(:class:`~.tracker_rig.RigInUse`) and the head's motion
(:class:`~.motion.HeadMotion`), and owns whether the readout's prior was
handed to the refinement: the readout in use (:meth:`RollingShutter.readout_s`:
the refinement's, once it is known to be one, else the given one), each
centre's row time (:meth:`RollingShutter.row_times`), the displacement the
fit takes off the centres and its uncertainty
(:meth:`RollingShutter.compensate`, :func:`~.lock.fit_centers`), and the
readout's prior handed to the rig's refinement
(:meth:`RollingShutter.set_readout_prior`). Times in s, displacements in px.
"""
from __future__ import annotations

import math

import numpy as np

from . import geometry as geo
from .lock import Match
from .rig_priors import readout_prior


class RollingShutter:
    """The rolling shutter's compensation of :class:`~.tracker.Tracker` (module docstring).

    Parameters
    ----------
    config, model_mm
        As :class:`~.acquire.Identifier`'s (the settings; the marker model in G, mm).
    rig : RigInUse
    motion : HeadMotion
    """

    def __init__(self, config, model_mm: np.ndarray, rig, motion):
        self.shutter_config = config
        self.shutter_model_mm = model_mm
        self.shutter_rig = rig
        self.shutter_motion = motion
        self._readout_prior_set = False

    def readout_s(self) -> float:
        """The rolling shutter's readout the centres are compensated for, s (first row to last; 0: a
        global shutter, or none known yet).

        The refinement's estimate once it is known to be a readout: beyond
        twice its σ and ``min_readout_s``. Below that the compensation would
        move the centres by less than their noise (0.5 ms at 300 px/s and
        the image's edge: 0.07 px) or by the estimate's own noise, and costs
        a frame's work; what is unknown of it is the rig's uncertainty,
        through its column, all the same. Without the refinement: the
        configured readout."""
        refiner = self.shutter_rig.refiner
        if refiner is not None and self.shutter_config.rig_refine.enabled:
            readout = float(refiner.estimator.state.readout_s)
            sd = float(refiner.estimator.sigma()[8])
            return readout if readout > max(2.0 * sd, self.shutter_config.min_readout_s) else 0.0
        return self.given_readout_s() or 0.0

    def row_times(self, centers: np.ndarray, readout_s: float) -> np.ndarray:
        """Each centre's exposure time relative to its image's time (2, 5), s, for a readout (s).

        Row r of an image H rows high is exposed at (r − (H − 1)/2) ×
        readout / (H − 1) after the image's time (the middle row's)."""
        height = int(self.shutter_rig.rig.image_size[1])
        return (centers[..., 1] - 0.5 * (height - 1)) * (readout_s / max(height - 1, 1))

    def compensate(self, match: Match, t, current=None) -> bool:
        """Set ``match``'s rolling-shutter terms from the head's velocity at ``t``
        (:meth:`PoseHistory.velocity_at`, with ``current`` = (R, p1) this frame's pose when known);
        True when the centres are compensated.

        A centre at row r was exposed δ_r after t (:meth:`row_times`): the
        head's image there is displaced by u̇ δ_r, u̇ = ∂x/∂pose · (ω, v) its
        image velocity, which the fit takes off (``shutter_shift_px``). What
        is not known of the velocity (its covariance Σ_v, or, when no recent
        poses give one, a head's typical motion ``prior_head_rate_dps``,
        ``prior_head_speed_mm_s``) is a nuisance of the pose: the rows
        δ_r ∂x/∂pose with covariance Σ_v (``shutter_delay_s``,
        ``shutter_cov``), marginalized in the covariance of V like the rig's
        error; each centre's share, ``shutter_sd_px``, widens the checks.
        (The readout's own uncertainty is the rig's, through its column.)
        """
        match.shutter_shift_px = match.shutter_sd_px = match.shutter_cov = match.shutter_delay_s = None
        if not self.shutter_config.compensate_rolling_shutter or self.shutter_config.estimator != "reproj" or t is None:
            return False
        readout = self.readout_s()
        if not readout:
            return False
        motion = self.shutter_motion.history.velocity_at(t, self.shutter_rig.version(), current)
        R, p1 = current if current is not None else (match.R, match.t)
        rows = np.nan_to_num(geo.reprojection_rows(R, p1, self.shutter_model_mm, match.visible,
                                                    self.shutter_rig.geometry.cameras))  # (2,5,2,6)
        delay = self.row_times(match.centers, readout)                                                    # (2, 5) s
        if motion is None:
            cov = self.prior_motion_cov
        else:
            omega, velocity, cov = motion
            match.shutter_shift_px = (rows @ np.concatenate([omega, velocity])) * delay[..., None]
            if cov is None:
                cov = self.prior_motion_cov
        match.shutter_delay_s, match.shutter_cov = delay, cov
        var = np.einsum("cmij,jk,cmik->cm", rows, cov, rows) * 0.5 * delay ** 2                           # per coordinate
        match.shutter_sd_px = np.sqrt(np.maximum(var, 0.0))
        return match.shutter_shift_px is not None

    @property
    def prior_motion_cov(self) -> np.ndarray:
        """A head's motion when no recent poses tell it (6, 6): (rad/s)² ×3, (mm/s)² ×3."""
        c = self.shutter_config
        return np.diag([math.radians(c.prior_head_rate_dps) ** 2] * 3 + [c.prior_head_speed_mm_s ** 2] * 3)

    def given_readout_s(self) -> float | None:
        """The readout known before any frame, s: ``readout_s`` (``--readout-ms``), else the one a rig saved
        by ``--save-rig`` learnt (``refined_readout_ms``: the same cameras read out as they did); None."""
        if self.shutter_config.readout_s is not None:
            return float(self.shutter_config.readout_s)
        saved = self.shutter_rig.calibrated_rig.extra.get("refined_readout_ms")
        try:
            value = float(np.ravel(saved)[0]) * 1e-3
        except (TypeError, ValueError, IndexError):
            return None
        return max(value, 0.0) if math.isfinite(value) and value < 1.0 else None

    def set_readout_prior(self, frame_periods: list) -> None:
        """Give the rig's refinement the rolling shutter's prior once it can be had: the user's readout
        (``readout_s``) at once, else from the frame period once two periods (``frame_periods``, the
        recent ones, s) are known."""
        refiner = self.shutter_rig.refiner
        if refiner is None or self._readout_prior_set:
            return
        period = float(np.median(frame_periods)) if len(frame_periods) >= 2 else None
        given = self.given_readout_s()
        if given is None and period is None:
            return
        if refiner.estimator.updates:
            self._readout_prior_set = True     # learnt already: the prior is the refinement's business
            return
        mean, sd = readout_prior(period, given)
        if given is None:
            # Not given: compensate nothing until the motion shows a readout,
            # σ the longest a webcam's can be (wrongly compensating a global
            # shutter by 30 ms costs as much as not compensating a rolling one).
            mean, sd = 0.0, math.hypot(mean, sd)
        refiner.set_readout_prior(mean, sd)
        self._readout_prior_set = True
