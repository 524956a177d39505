"""A frame's pose: fitted to its markers, checked against the images and the rig, and what the covariance
of V needs from it.

:class:`PoseFitter` is a part of :class:`~.tracker.Tracker`: markers (a
:class:`~.lock.Match`) and the rig in use in, a :class:`Fit` out. The
configured estimator's pose and residuals (:meth:`PoseFitter.estimate`, the
reproj estimator with the exposure offset's and the rolling shutter's
motion taken afresh from its own pose), the fit and its checks
(:meth:`PoseFitter.fit`; the checks themselves: :class:`~.rig_check.RigChecks`).
It has no state of its own: it reads the rig in use
(:class:`~.tracker_rig.RigInUse`), the head's motion
(:class:`~.motion.HeadMotion`) and the rolling shutter's compensation
(:class:`~.rolling_shutter.RollingShutter`), and what it found out about
the frame (whether the right view's motion was compensated, the rates it
checked) is in the :class:`Fit`. Poses are R_world_G (3, 3) and P1 (3,) mm
in the world (left camera) frame; residuals px.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import geometry as geo
from .lock import Match, centroid_sigma, fit_centers


@dataclass(frozen=True)
class Fit:
    """A frame's pose as fitted and checked: what the fit stage (:meth:`PoseFitter.fit`) hands on.

    ``R``, ``p1``: the pose to report (corrected for the rig error its
    residuals show, when that applies); ``fitted``: (R, p1) as fitted with
    the rig in use, which the motion history and the refinement keep;
    ``residuals`` (2, 5) px, ``vectors`` (2, 5, 2) px, ``JtJ`` (6, 6) of the
    fit; ``velocity`` the head's (ω, v) for the rig's terms, or None;
    ``rig_rows`` (2, 5, 2, k), ``rig_sd`` (2, 5) px, ``pose_rows`` (2, 5, 2,
    6), ``rig_cov`` (k, k): the rig's share, when computed; ``reason``: why
    no pose at all; ``withheld``: why a pose that is tracked from and refines
    the rig is not reported; ``disagrees``: it fits only the rig's wider,
    unrefined uncertainty (a bump?); ``compensated``: the fit moved the
    right view's model by the head's motion; ``uncompensated``: the right
    image's exposure offset could not be compensated (no recent pose);
    ``checked_rates``: (R, p1, rates) when the fit checked the head's rates
    (:meth:`PoseHistory.rates_to`) to this pose, for the motion history to
    reuse.
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
    compensated: bool = False
    uncompensated: bool = False
    checked_rates: tuple | None = None


class PoseFitter:
    """The pose stage of :class:`~.tracker.Tracker` (module docstring).

    Parameters
    ----------
    config, model_mm, axes_G
        As :class:`~.acquire.Identifier`'s (the settings, the marker model in G, mm, and its axes).
    rig : RigInUse
    motion : HeadMotion
    shutter : RollingShutter
    checks : RigChecks
    """

    def __init__(self, config, model_mm: np.ndarray, axes_G: np.ndarray, rig, motion, shutter, checks):
        self.fitter_config = config
        self.fitter_model_mm = model_mm
        self.fitter_axes_G = axes_G
        self.normal_signs = geo.normal_signs(model_mm)
        self.fitter_rig = rig
        self.fitter_motion = motion
        self.fitter_shutter = shutter
        self.fitter_checks = checks

    def fit(self, match: Match, t, t_right, timings: dict) -> Fit:
        """Fit the pose to the markers and check it against the images and the rig (:class:`Fit`).

        ``t``, ``t_right``: the images' times, s (or None); ``timings``: the
        stages' seconds, to which ``pose`` and ``verify`` are added.
        """
        t_pose = time.perf_counter()
        motion, rig, checks = self.fitter_motion.history, self.fitter_rig, self.fitter_checks
        uncompensated = (t_right is not None and t is not None and t_right != t
                         and self._right_motion(t, t_right) is None
                         and (not motion or t - motion.last_time() > 0.2))
        R, p1, residuals, JtJ, vectors, compensated = self.estimate(match, t, t_right)
        velocity, checked = motion.velocity(), None
        if velocity is not None and t is not None:
            # The velocity of the last poses is this frame's motion only if
            # this pose continues it: one a head cannot reach from them (the
            # check HeadMotion.remember makes afterwards) says the motion here is not
            # known. The rig's exposure offset, not yet learnt, times that
            # velocity would otherwise widen the checks by pixels (25 ms at
            # 1000°/s) and let a glint or an occlusion through.
            rates = motion.rates_to(t, R, p1, rig.version())
            checked = (R, p1, rates)       # HeadMotion.remember's check, if the pose stays
            if rates is not None and not rates[2]:
                velocity = None
        rig_rows = rig_sd = pose_rows = None
        # The rig's share only widens the checks: a frame that passes them on
        # image noise alone (the usual case) needs no rig terms before its covariance.
        outlier = checks.outlier(residuals, match, uncompensated)
        suspect = checks.suspect(residuals, match, uncompensated)
        plain = checks.verify(R, p1, residuals, None, match)          # the image noise alone
        if suspect or outlier is not None or plain is not None:
            rig_rows, rig_sd, pose_rows = self.rig_terms(R, p1, t, t_right, velocity, rig.cov(), match)
            outlier = checks.outlier(residuals, match, uncompensated, rig_sd)
        if suspect and self.fitter_config.estimator == "reproj":
            # Centres that disagree with the others beyond what the rig's
            # uncertainty explains (glints fused with markers, partial
            # occlusions) are down-weighted rather than the frame refused,
            # if the others agree.
            suspects, excess = checks.suspects(vectors, match, pose_rows, rig_rows, rig.cov())
            if suspects is not None:
                match.excess_px = excess        # their variance gets the excess
                R, p1, residuals, JtJ, vectors, compensated = self.estimate(match, t, t_right)
                rig_rows, rig_sd, pose_rows = self.rig_terms(R, p1, t, t_right, velocity, rig.cov(), match)
                outlier = checks.outlier(residuals, match, uncompensated, rig_sd)
        timings["pose"] = time.perf_counter() - t_pose

        t_ver = time.perf_counter()
        # (With no rig terms and no outlier the checks are the plain ones, done above.)
        reason = plain if (rig_sd is None and outlier is None) else checks.verify(R, p1, residuals, outlier, match,
                                                                                  rig_sd)
        rig_cov = rig.cov()
        disagrees = False
        if reason is not None and rig.refiner is not None:
            # Not consistent with the rig as refined: is it with the rig as
            # uncertain as before any refinement (the rig changed: a bump)?
            wide = rig.cov(wide=True)
            wide_rows, wide_sd, _ = self.rig_terms(R, p1, t, t_right, velocity, wide, match)
            if (checks.verify(R, p1, residuals, checks.outlier(residuals, match, uncompensated, wide_sd), match,
                              wide_sd) is None
                    and checks.rig_explains(pose_rows, vectors, wide_rows, wide, match)):
                reason, rig_cov, disagrees = None, wide, True
        withheld = None
        fitted = (R, p1)               # the pose fitted with the rig in use, before any correction
        if (reason is None and rig_rows is not None and rig_cov is not None
                and self.fitter_config.estimator == "reproj"
                and checks.verify(R, p1, residuals, checks.outlier(residuals, match, uncompensated), match)
                is not None):
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
            R, p1, reason, withheld = checks.rig_consistent(R, p1, vectors, pose_rows, rig_rows, rig_cov, match)
        if reason is None and withheld is None:
            withheld = checks.offset_unbridged(t, t_right, compensated)
        timings["verify"] = time.perf_counter() - t_ver
        return Fit(R, p1, fitted, residuals, vectors, JtJ, velocity, rig_rows, rig_sd, pose_rows, rig_cov,
                   reason, withheld, disagrees, compensated, uncompensated, checked)

    def rig_terms(self, R, p1, t, t_right, velocity, P, match: Match, spread: bool = True):
        """:meth:`RigChecks.rig_terms` on the rig in use and its refinement."""
        rig = self.fitter_rig
        return self.fitter_checks.rig_terms(R, p1, t, t_right, velocity, P, match, rig.geometry, rig.refiner,
                                            spread)

    def estimate(self, match: Match, t, t_right):
        """Pose (R_world_G, p1), reprojection residuals (2, 5), JᵀJ (6, 6) and residual vectors (2, 5, 2) px
        with the configured estimator, and whether the right view's model was moved by the head's motion."""
        c, g = self.fitter_config, self.fitter_rig.geometry
        est = c.estimator
        if est in ("rigid", "paper"):
            R, p1 = match.R, match.t
            if est == "paper" and np.isfinite(match.points).all():
                axes = geo.axes_from_points(match.points, self.normal_signs)
                R = axes.T @ self.fitter_axes_G     # rotation taking the model's axes onto the measured ones
                p1 = match.points[1]
            vectors = self._residuals(R, p1, match, g.rig)
            residuals = np.hypot(vectors[..., 0], vectors[..., 1])
            JtJ = geo.reprojection_jacobian(R, p1, self.fitter_model_mm, match.visible[0], match.visible[1], g.rig,
                                            cameras=g.cameras, sigma_px=self._sigma(match))
            return R, p1, residuals, JtJ, vectors, False
        sigma = self._sigma(match) if c.weighted_fit else None
        motion = self._right_motion(t, t_right) if c.compensate_offset else None
        compensated = motion is not None
        rolling = self.fitter_shutter.compensate(match, t)
        fit = geo.refine_reprojection(match.R, match.t, self.fitter_model_mm, *fit_centers(match),
                                      match.visible[0], match.visible[1], g.rig, right_motion=motion,
                                      sigma_px=sigma, cameras=g.cameras)
        offset = c.compensate_offset and t_right is not None and t_right != t
        if offset or rolling:
            fit, compensated = self._passes(fit, match, t, t_right, offset, rolling, sigma, compensated)
        return (*fit, compensated)

    def _passes(self, fit, match: Match, t, t_right, offset: bool, rolling: bool, sigma, compensated: bool):
        """The reproj fit's passes after the first, the motion taken afresh from its own pose: (fit,
        compensated)."""
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
        g = self.fitter_rig.geometry
        for _ in range(max(self.fitter_config.offset_passes, 1)):
            motion, gain = None, 0.0
            if offset:
                motion = self._right_motion(t, t_right, current=fit[:2])
                if motion is not None:
                    compensated = True
                    gain, _ = self.motion_terms(t, t_right, fit[:2], covariance=False)
            if rolling:
                rolling = self.fitter_shutter.compensate(match, t, current=fit[:2])
            if motion is None and not rolling:
                break
            before_R, before_p = fit[0], fit[1]
            fit = geo.refine_reprojection(fit[0], fit[1], self.fitter_model_mm, *fit_centers(match),
                                          match.visible[0], match.visible[1], g.rig, right_motion=motion,
                                          sigma_px=sigma, cameras=g.cameras, right_gain=gain,
                                          iterations=0)
            # Settled: a step of 0.01 mm and 1e-5 rad, far below the noise.
            if np.abs(fit[1] - before_p).max() < 0.01 and np.abs(fit[0] - before_R).max() < 1e-5:
                break
        return fit, compensated

    def _sigma(self, match: Match) -> np.ndarray:
        return centroid_sigma(match, self.fitter_config.min_centroid_sigma_px)

    def _residuals(self, R, p1, match: Match, rig) -> np.ndarray:
        """Residual vectors (2, 5, 2), projected minus measured centre, px (NaN if hidden)."""
        pts = (R @ self.fitter_model_mm.T).T + p1
        res = np.full((2, 5, 2), np.nan)
        pl = geo.project(pts, np.eye(3), np.zeros(3), rig.K1, rig.D1)
        pr = geo.project(pts, rig.R, rig.T, rig.K2, rig.D2)
        centers = fit_centers(match)
        for cam, proj in ((0, pl), (1, pr)):
            vis = match.visible[cam]
            res[cam, vis] = proj[vis] - centers[cam][vis]
        return res

    def _right_motion(self, t, t_right, current=None):
        """The head's motion over the right image's exposure offset (:meth:`PoseHistory.right_motion`)."""
        return self.fitter_motion.history.right_motion(t, t_right, self.fitter_rig.version(), current)

    def motion_terms(self, t, t_right, current, covariance: bool = True):
        """(gain, cov) of the motion compensation (:meth:`PoseHistory.motion_terms`); (0, None) if off."""
        if not self.fitter_config.compensate_offset:
            return 0.0, None
        return self.fitter_motion.history.motion_terms(t, t_right, self.fitter_rig.version(), current, covariance)
