"""A frame's pose: fitted to its markers, checked against the images and the rig, and what the covariance
of V needs from it.

:class:`_PoseFit` is a part of :class:`~.tracker.Tracker` (a mixin): the
configured estimator's pose and residuals (:meth:`_PoseFit._estimate`, the
reproj estimator with the exposure offset's and the rolling shutter's
motion taken afresh from its own pose), the fit and its checks
(:meth:`_PoseFit._fit`, which hands a :class:`_Fit` on; the checks
themselves: :mod:`.rig_check`), and the covariance input
(:meth:`_PoseFit._covariance_input`). Poses are R_world_G (3, 3) and P1
(3,) mm in the world (left camera) frame; residuals px.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from . import geometry as geo
from .detect import shot_variance
from .lock import _Match
from .uncertainty import CovarianceInput


@dataclass
class _Fit:
    """A frame's pose as fitted and checked: what the fit stage (:meth:`Tracker._fit`) hands on.

    ``R``, ``p1``: the pose to report (corrected for the rig error its
    residuals show, when that applies); ``fitted``: (R, p1) as fitted with
    the rig in use, which the motion history and the refinement keep;
    ``residuals`` (2, 5) px, ``vectors`` (2, 5, 2) px, ``JtJ`` (6, 6) of the
    fit; ``velocity`` the head's (ω, v) for the rig's terms, or None;
    ``rig_rows`` (2, 5, 2, k), ``rig_sd`` (2, 5) px, ``pose_rows`` (2, 5, 2,
    6), ``rig_cov`` (k, k): the rig's share, when computed; ``reason``: why
    no pose at all; ``withheld``: why a pose that is tracked from and refines
    the rig is not reported; ``disagrees``: it fits only the rig's wider,
    unrefined uncertainty (a bump?).
    """

    R: np.ndarray
    p1: np.ndarray
    fitted: tuple
    residuals: np.ndarray
    vectors: np.ndarray
    JtJ: np.ndarray
    velocity: tuple | None
    rig_rows: np.ndarray | None
    rig_sd: np.ndarray | None
    pose_rows: np.ndarray | None
    rig_cov: np.ndarray | None
    reason: str | None = None
    withheld: str | None = None
    disagrees: bool = False


class _PoseFit:
    """The pose stage of :class:`~.tracker.Tracker` (module docstring)."""

    def _fit(self, match: _Match, t, t_right, timings: dict) -> _Fit:
        """Fit the pose to the markers and check it against the images and the rig (:class:`_Fit`)."""
        t_pose = time.perf_counter()
        self._uncompensated = (t_right is not None and t is not None and t_right != t
                               and self._right_motion(t, t_right) is None
                               and (not self._motion or t - self._motion.last_time() > 0.2))
        R, p1, residuals, JtJ, vectors = self._estimate(match, t, t_right)
        velocity = self._motion.velocity()
        if velocity is not None and t is not None:
            # The velocity of the last poses is this frame's motion only if
            # this pose continues it: one a head cannot reach from them (the
            # check _remember makes afterwards) says the motion here is not
            # known. The rig's exposure offset, not yet learnt, times that
            # velocity would otherwise widen the checks by pixels (25 ms at
            # 1000°/s) and let a glint or an occlusion through.
            rates = self._motion.rates_to(t, R, p1, self._rig_version())
            self._rates = (t, R, p1, self._rig_version(), rates)       # _remember's check, if the pose stays
            if rates is not None and not rates[2]:
                velocity = None
        rig_rows = rig_sd = pose_rows = None
        # The rig's share only widens the checks: a frame that passes them on
        # image noise alone (the usual case) needs no rig terms before its covariance.
        outlier = self._outlier(residuals, match)
        suspect = self._suspect(residuals, match)
        plain = self._verify(R, p1, residuals, None, match)          # the image noise alone
        if suspect or outlier is not None or plain is not None:
            rig_rows, rig_sd, pose_rows = self._rig_terms(R, p1, t, t_right, velocity, self._rig_cov(), match)
            outlier = self._outlier(residuals, match, rig_sd)
        if suspect and self.config.estimator == "reproj":
            # Centres that disagree with the others beyond what the rig's
            # uncertainty explains (glints fused with markers, partial
            # occlusions) are down-weighted rather than the frame refused,
            # if the others agree.
            suspects, excess = self._suspects(vectors, match, pose_rows, rig_rows, self._rig_cov())
            if suspects is not None:
                match.excess_px = excess        # their variance gets the excess
                R, p1, residuals, JtJ, vectors = self._estimate(match, t, t_right)
                rig_rows, rig_sd, pose_rows = self._rig_terms(R, p1, t, t_right, velocity, self._rig_cov(), match)
                outlier = self._outlier(residuals, match, rig_sd)
        timings["pose"] = time.perf_counter() - t_pose

        t_ver = time.perf_counter()
        # (With no rig terms and no outlier the checks are the plain ones, done above.)
        reason = plain if (rig_sd is None and outlier is None) else self._verify(R, p1, residuals, outlier, match, rig_sd)
        rig_cov = self._rig_cov()
        disagrees = False
        if reason is not None and self.refiner is not None:
            # Not consistent with the rig as refined: is it with the rig as
            # uncertain as before any refinement (the rig changed: a bump)?
            wide = self._rig_cov(wide=True)
            wide_rows, wide_sd, _ = self._rig_terms(R, p1, t, t_right, velocity, wide, match)
            if (self._verify(R, p1, residuals, self._outlier(residuals, match, wide_sd), match, wide_sd) is None
                    and self._rig_explains(pose_rows, vectors, wide_rows, wide, match)):
                reason, rig_cov, disagrees = None, wide, True
        withheld = None
        fitted = (R, p1)               # the pose fitted with the rig in use, before any correction
        if (reason is None and rig_rows is not None and rig_cov is not None and self.config.estimator == "reproj"
                and self._verify(R, p1, residuals, self._outlier(residuals, match), match) is not None):
            # The checks passed only with the rig's uncertainty: report the
            # pose that uncertainty implies, not the one fitted with the rig
            # as is, or none. A withheld pose is still the markers' and the
            # rig's evidence: it is tracked from and refines the rig (which
            # is what brings the next poses back), it is only not reported.
            # The motion history and the refinement keep the pose fitted with
            # the rig in use, as for every other frame: a correction that
            # comes and goes would be motion to the one and, to the other,
            # a pose of another rig than the one it linearizes at.
            # (The rigid and paper estimators' poses are not reprojection
            # fits, which the correction starts from: they stay as they are.)
            R, p1, reason, withheld = self._rig_consistent(R, p1, vectors, pose_rows, rig_rows, rig_cov, match)
        if reason is None and withheld is None:
            withheld = self._offset_unbridged(t, t_right)
        timings["verify"] = time.perf_counter() - t_ver
        return _Fit(R, p1, fitted, residuals, vectors, JtJ, velocity, rig_rows, rig_sd, pose_rows, rig_cov,
                    reason, withheld, disagrees)

    def _covariance_input(self, images, match: _Match, fit: _Fit, t, t_right, motion_gain,
                          motion_cov) -> CovarianceInput:
        """What the estimator of V's covariance needs: the centres and their noise, the fit, and the nuisances
        the pose is uncertain by beside the image noise (the rig's error, the motion that moved the right
        view, the rolling shutter's velocity), each as rows (2, 5, 2, k) with a covariance (k, k)."""
        R, p1, rig_rows, pose_rows, rig_cov = fit.R, fit.p1, fit.rig_rows, fit.pose_rows, fit.rig_cov
        if pose_rows is None:
            rig_rows, _, pose_rows = self._rig_terms(R, p1, t, t_right, fit.velocity, self._rig_cov(), match,
                                                     spread=False)
        rig_mean, rig_parameters = None, 0
        if rig_rows is not None and rig_cov is not None and self.refiner is not None and not fit.disagrees:
            # V's uncertainty takes the rig's error as the data know it, the
            # error model's scale learnt too (a right rig.yaml's share shrinks);
            # the checks keep the error model as it is.
            rig_mean, rig_cov = self.refiner.error_distribution()
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
        axes = self.axes_G @ R.T
        if match.shot_var is None:      # the tracking path leaves the shot-noise term to this stage
            match.shot_var = shot_variance(images, match.centers, match.size, self._prev_background)
        return CovarianceInput(images, match.centers, match.visible, match.sigma_px, fit.residuals, fit.JtJ,
                               R, p1, axes, tuple(self._prev_threshold), tuple(self._prev_background),
                               fit.vectors, t, match.shot_var,
                               pose_rows, rig_rows, rig_cov, self._rig_version(), match.excess_px,
                               rig_mean, not (R is fit.fitted[0] and p1 is fit.fitted[1]), rig_parameters,
                               self.refiner is None or self.refiner.has_data())

    def _estimate(self, match: _Match, t, t_right):
        """Pose (R_world_G, p1), reprojection residuals (2, 5) and JᵀJ (6, 6) with the configured estimator."""
        est = self.config.estimator
        if est in ("rigid", "paper"):
            R, p1 = match.R, match.t
            if est == "paper" and np.isfinite(match.points).all():
                axes = geo.axes_from_points(match.points, self.normal_signs)
                R = axes.T @ self.axes_G     # rotation taking the model's axes onto the measured ones
                p1 = match.points[1]
            vectors = self._residuals(R, p1, match)
            residuals = np.hypot(vectors[..., 0], vectors[..., 1])
            JtJ = geo.reprojection_jacobian(R, p1, self.model_mm, match.visible[0], match.visible[1], self.rig,
                                            cameras=self._cameras, sigma_px=self._sigma(match))
            return R, p1, residuals, JtJ, vectors
        sigma = self._sigma(match) if self.config.weighted_fit else None
        motion = self._right_motion(t, t_right) if self.config.compensate_offset else None
        self._compensated = motion is not None
        rolling = self._rolling_shutter(match, t)
        fit = geo.refine_reprojection(match.R, match.t, self.model_mm, *self._fit_centers(match),
                                      match.visible[0], match.visible[1], self.rig, right_motion=motion,
                                      sigma_px=sigma, cameras=self._cameras)
        offset = self.config.compensate_offset and t_right is not None and t_right != t
        if offset or rolling:
            # Second pass: the velocity from the last pose to this one lags by
            # half a frame instead of one and a half.
            # The velocity is taken from this pose too: the fit's right rows
            # carry that gain, which makes it the maximum-likelihood fit.
            # refine_reprojection holds the motion fixed while it steps the
            # pose, so a fit of several steps ends where the motion of its
            # starting pose, not of its own, fits best: a first pose
            # displaced by a lagging velocity (a turning head, a late right
            # image) was carried on by the gain instead of corrected. One
            # Gauss-Newton step per pass, the motion taken afresh from the
            # pose before each, is Gauss-Newton on the consistent model.
            # The rolling shutter's displacements are taken afresh likewise
            # (their gain, the rows' time over the velocity's base, is below
            # a half and left out of the rows).
            for _ in range(max(self.config.offset_passes, 1)):
                motion, gain = None, 0.0
                if offset:
                    motion = self._right_motion(t, t_right, current=fit[:2])
                    if motion is not None:
                        self._compensated = True
                        gain, _ = self._motion_terms(t, t_right, fit[:2], covariance=False)
                if rolling:
                    rolling = self._rolling_shutter(match, t, current=fit[:2])
                if motion is None and not rolling:
                    break
                before_R, before_p = fit[0], fit[1]
                fit = geo.refine_reprojection(fit[0], fit[1], self.model_mm, *self._fit_centers(match),
                                              match.visible[0], match.visible[1], self.rig, right_motion=motion,
                                              sigma_px=sigma, cameras=self._cameras, right_gain=gain,
                                              iterations=0)
                # Settled: a step of 0.01 mm and 1e-5 rad, far below the noise.
                if np.abs(fit[1] - before_p).max() < 0.01 and np.abs(fit[0] - before_R).max() < 1e-5:
                    break
        return fit

    def _sigma(self, match: _Match) -> np.ndarray:
        """Expected centroid error (2, 5), px: the noise, floored (a perfect image is never perfect),
        with a suspect centre's excess."""
        sigma = np.maximum(match.sigma_px, self.config.min_centroid_sigma_px)
        if match.excess_px is not None:
            sigma = np.hypot(sigma, match.excess_px)
        if match.shutter_sd_px is not None:
            sigma = np.hypot(sigma, match.shutter_sd_px)
        return sigma

    def _residuals(self, R, p1, match: _Match) -> np.ndarray:
        """Residual vectors (2, 5, 2), projected minus measured centre, px (NaN if hidden)."""
        pts = (R @ self.model_mm.T).T + p1
        res = np.full((2, 5, 2), np.nan)
        pl = geo.project(pts, np.eye(3), np.zeros(3), self.rig.K1, self.rig.D1)
        pr = geo.project(pts, self.rig.R, self.rig.T, self.rig.K2, self.rig.D2)
        centers = self._fit_centers(match)
        for cam, proj in ((0, pl), (1, pr)):
            vis = match.visible[cam]
            res[cam, vis] = proj[vis] - centers[cam][vis]
        return res

    def _right_motion(self, t, t_right, current=None):
        """The head's motion over the right image's exposure offset (:meth:`PoseHistory.right_motion`)."""
        return self._motion.right_motion(t, t_right, self._rig_version(), current)

    def _motion_terms(self, t, t_right, current, covariance: bool = True):
        """(gain, cov) of the motion compensation (:meth:`PoseHistory.motion_terms`); (0, None) if off."""
        if not self.config.compensate_offset:
            return 0.0, None
        return self._motion.motion_terms(t, t_right, self._rig_version(), current, covariance)
