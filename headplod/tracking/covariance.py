"""The covariance of V, a part of :class:`~.tracker.Tracker`: a frame's fit in, the covariance of (φ, θ) of V
out.

:class:`Covariance` owns the configured estimator
(:func:`~.uncertainty.make_covariance_estimator`, whose state, e.g. a
smoothing over frames, it resets), builds what the estimator takes
(:meth:`Covariance.input`, a :class:`~.uncertainty.CovarianceInput`: the
centres and their noise, the fit, and the nuisances beside the image noise,
each as rows with a covariance), runs it (:meth:`Covariance.estimate`: deg²,
(2, 2)) and gives the centres' noise the rig's refinement weighs them by
(:meth:`Covariance.centre_sd`). It takes the rig in use and its refinement
(:class:`~.tracker_rig.RigInUse`) with each frame, and the rig's rows from
:meth:`~.rig_check.RigChecks.rig_terms`.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from .detect import shot_variance
from .lock import Match, centroid_sigma
from .pose_fit import Fit
from .uncertainty import CovarianceInput, make_covariance_estimator


class Covariance:
    """The covariance of V of :class:`~.tracker.Tracker` (module docstring).

    Parameters
    ----------
    config : TrackerConfig
        ``uncertainty`` (the estimator's name), ``min_centroid_sigma_px``.
    model_mm : (5, 3) float
        The marker model, glasses frame, mm.
    axes_G : (3, 3) float
        The model's axes Ξ, Ψ, V (rows), glasses frame.
    rig : headplod.io.Rig
        The rig the estimator starts with (:meth:`use_rig` gives it the next ones).
    checks : RigChecks
    """

    def __init__(self, config, model_mm: np.ndarray, axes_G: np.ndarray, rig, checks):
        self.cov_config = config
        self.cov_axes_G = axes_G
        self.cov_checks = checks
        self.estimator = make_covariance_estimator(config.uncertainty, rig, model_mm, axes_G)

    def reset(self) -> None:
        """Forget the previous frames (an estimator that smooths over them)."""
        self.estimator.reset()

    def use_rig(self, rig) -> None:
        """Give the estimator a rig put in use (an estimator that triangulates with it)."""
        if hasattr(self.estimator, "rig"):
            self.estimator.rig = rig

    @property
    def name(self) -> str:
        """The estimator's name."""
        return self.estimator.name

    def estimate(self, cov_input: CovarianceInput) -> np.ndarray:
        """Covariance (2, 2) of (φ, θ) of V, deg²."""
        return self.estimator(cov_input)

    def centre_sd(self, cov_input: CovarianceInput, match: Match) -> np.ndarray:
        """Each centre's 1σ per coordinate (2, 5, 2) px: the estimator's variances when it has them, else the
        expected centroid noise."""
        inner = getattr(self.estimator, "inner", self.estimator)
        if hasattr(inner, "variances"):
            return np.sqrt(inner.variances(cov_input))
        return np.repeat(centroid_sigma(match, self.cov_config.min_centroid_sigma_px)[..., None], 2, axis=2)

    def input(self, images, match: Match, fit: Fit, t, t_right, motion_gain, motion_cov, backgrounds,
              thresholds, rig) -> CovarianceInput:
        """What the estimator of V's covariance needs: the centres and their noise, the fit, and the nuisances
        the pose is uncertain by beside the image noise (the rig's error, the motion that moved the right
        view, the rolling shutter's velocity), each as rows (2, 5, 2, k) with a covariance (k, k).

        ``motion_gain``, ``motion_cov``: the motion compensation's terms
        (:meth:`PoseFitter.motion_terms`); ``backgrounds``, ``thresholds``:
        each camera's background (level, noise) DN and blob threshold DN
        (:class:`~.detection.Detector`); ``rig``: the rig in use and its refinement
        (:class:`~.tracker_rig.RigInUse`)."""
        R, p1, rig_rows, pose_rows, rig_cov = fit.R, fit.p1, fit.rig_rows, fit.pose_rows, fit.rig_cov
        if pose_rows is None:
            rig_rows, _, pose_rows = self.cov_checks.rig_terms(R, p1, t, t_right, fit.velocity, rig.cov(), match,
                                                               rig.geometry, rig.refiner, spread=False)
        rig_mean, rig_parameters = None, 0
        if rig_rows is not None and rig_cov is not None and rig.refiner is not None and not fit.disagrees:
            # V's uncertainty takes the rig's error as the data know it, the
            # error model's scale learnt too (a right rig.yaml's share shrinks);
            # the checks keep the error model as it is.
            rig_mean, rig_cov = rig.refiner.estimator.error_distribution()
            rig_parameters = len(rig_mean)
        plain_rows = pose_rows                 # ∂x/∂pose, before the motion's gain below
        right_rows = np.zeros_like(pose_rows)
        right_rows[1] = pose_rows[1]
        if motion_gain:
            # The right view's model follows this pose (1 + gain) times (the
            # velocity that moved it was taken from this pose).
            pose_rows = pose_rows + motion_gain * right_rows
        if motion_cov is not None:
            # ... and the earlier poses' errors move it too: as a pose error of
            # the right view alone, another nuisance beside the rig's.
            if rig_rows is None or rig_cov is None:
                rig_rows, rig_cov = right_rows, motion_cov
            else:
                rig_rows = np.concatenate([rig_rows, right_rows], axis=-1)
                rig_cov = scipy.linalg.block_diag(rig_cov, motion_cov)
        if match.shutter_cov is not None:
            # ... and so does what is unknown of the velocity that took each
            # row back to t (the rolling shutter): rows δ_r ∂x/∂pose.
            shutter_rows = np.nan_to_num(plain_rows) * match.shutter_delay_s[..., None, None]
            if rig_rows is None or rig_cov is None:
                rig_rows, rig_cov = shutter_rows, match.shutter_cov
            else:
                rig_rows = np.concatenate([rig_rows, shutter_rows], axis=-1)
                rig_cov = scipy.linalg.block_diag(rig_cov, match.shutter_cov)
        if rig_mean is not None:
            rig_mean = np.concatenate([rig_mean, np.zeros(rig_cov.shape[0] - len(rig_mean))])   # the motion's: 0
        axes = self.cov_axes_G @ R.T
        if match.shot_var is None:      # the tracking path leaves the shot-noise term to this stage
            match.shot_var = shot_variance(images, match.centers, match.size, backgrounds)
        return CovarianceInput(images, match.centers, match.visible, match.sigma_px, fit.residuals, fit.JtJ,
                               R, p1, axes, tuple(thresholds), tuple(backgrounds),
                               fit.vectors, t, match.shot_var,
                               pose_rows, rig_rows, rig_cov, rig.version(), match.excess_px,
                               rig_mean, not (R is fit.fitted[0] and p1 is fit.fitted[1]), rig_parameters,
                               rig.refiner is None or rig.refiner.estimator.has_data())
