"""The checks of a fitted pose against the images, within what the rig's uncertainty can explain.

:class:`RigChecks` is a part of :class:`~.tracker.Tracker`, with no state
of its own (its settings and the marker model): the reprojection and
outlier checks (:meth:`RigChecks.verify`, :meth:`RigChecks.outlier`), the
robust fit that finds the centres which disagree with the others
(:meth:`RigChecks.suspect`, :meth:`RigChecks.suspects`), the rig's share of
the residuals (:meth:`RigChecks.rig_terms`, :meth:`RigChecks.rig_after_fit`),
whether a rig change explains them (:meth:`RigChecks.rig_explains`: a
bump), the pose corrected for the rig change they show, or refused, or
withheld (:meth:`RigChecks.rig_consistent`), and a pose withheld for an
exposure offset no known motion bridges (:meth:`RigChecks.offset_unbridged`).
Each takes what it needs of the frame as arguments: the match, the fit, the
rig's geometry (:class:`~.tracker_rig.RigGeometry`) and refinement.

Residuals and σ are (2, 5) px per image and marker; residual vectors
(2, 5, 2) px; Jacobian rows (2, 5, 2, k) px per unit of the pose (rad, mm)
or of the rig's error state (:mod:`.rig_state`).
"""
from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.stats import chi2

from . import geometry as geo
from .frame_checks import describe_offset_s
from .lock import MARKER_NAMES, Match, centroid_sigma
from .rig_state import rig_jacobian_rows
from .uncertainty import rig_residual_rows
from ..tol import tol

# A rig correction beyond these (mm, deg: about ten times a clean pose's noise
# at a desk's distance) is refused when the frame cannot tell it from noise or
# a stray blob: with suspect centres, or P1 known to worse than 1.5 mm (1σ)
# after it (RigChecks.rig_consistent).
_AMBIGUOUS_CORRECTION_MM = 5.0
_AMBIGUOUS_CORRECTION_DEG = 0.5
_CORRECTED_P1_SD_MM = 1.5


def _names(mask: np.ndarray) -> str:
    """'P1 left, P3 right' for a (2, 5) bool mask of centres."""
    return ", ".join(f"{MARKER_NAMES[m]} {('left', 'right')[c]}" for c, m in np.argwhere(mask))


def _ambiguous_correction(J, r, M, S, P, G, removed: float, shift: float, turn: float, excess_px):
    """(reason, withheld) for a rig correction of ``shift`` mm and ``turn`` deg (beyond 5 mm or 0.5°) that
    the frame cannot tell from noise or a stray blob, else None (:meth:`RigChecks.rig_consistent`).

    At the fit, whitened: pose rows ``J`` (m, 6), residuals ``r`` (m,),
    ``M`` (m, k) what the fit leaves of a rig change, ``S`` = M P Mᵀ + I,
    ``P`` (k, k) the rig's prior, ``G`` (6, k) the pose's share of a rig
    change, ``removed`` the χ² the MAP rig change explains; ``excess_px``
    (2, 5) px or None: the centres the robust fit found suspect.
    """
    Q = np.linalg.pinv(J.T @ J)                                   # the pose's covariance, (rad, mm)²
    # One wrong centre (a stray blob taken for a marker) against one
    # rig change: the χ² that leaving out each centre would remove
    # (block deletion, r_cᵀ (I − H_cc)⁻¹ r_c, at the fit) beside the
    # χ² the rig change removes. A stale rig moves every centre a
    # little and no single one explains it (a third of it, at most
    # three quarters, on stale rigs up to 3° and 10%).
    Jc = J.reshape(-1, 2, 6)
    rc = r.reshape(-1, 2)
    lever = np.eye(2) - np.einsum("cij,jk,clk->cil", Jc, Q, Jc)
    single = float(np.einsum("ci,ci->c", rc, np.linalg.solve(lever, rc[..., None])[..., 0]).max())
    if single >= removed:
        return (f"one centre explains these residuals as well as a rig error, and the two move "
                f"the pose {shift:.0f} mm, {turn:.1f}° apart: a stray blob taken for a marker? "
                "Not trusted"), None
    # How well this frame alone knows the corrected P1: the pose's own
    # covariance plus what the rig's posterior leaves (mm²).
    rig_post = P - P @ M.T @ np.linalg.solve(S, M @ P)
    p1_var = Q[3:, 3:] + (G @ rig_post @ G.T)[3:, 3:]
    p1_sd = math.sqrt(max(float(np.trace(p1_var)), 0.0))
    if p1_sd > _CORRECTED_P1_SD_MM:
        # Few markers (one hidden) or a weak view: the rig's error and
        # the pose's trade off, and the correction follows noise or a
        # stray blob as readily as the rig.
        return (f"the markers seen do not tell the rig's error from the pose (a correction of "
                f"{shift:.0f} mm, {turn:.1f}°, known to ±{p1_sd:.1f} mm): not trusted"), None
    if excess_px is not None:
        # Some centres disagreed with the others (a glint, an
        # occlusion, a stray blob taken for a marker): what they leave
        # is as well a rig change as not.
        # Withheld, not refused: the markers are identified either way,
        # and the refinement, robust to the few centres that disagree,
        # is what tells the two apart (refused, a stale rig with a
        # glint in every frame was never refined: no pose at all).
        return None, (f"a rig error and the centres that disagree ({_names(excess_px > 0)}) "
                      f"both explain these residuals, and they move the pose {shift:.0f} mm, "
                      f"{turn:.1f}° apart: pose not reported until the rig is refined")
    return None


class RigChecks:
    """The checks of a fitted pose of :class:`~.tracker.Tracker` (module docstring).

    Parameters
    ----------
    config, model_mm
        As :class:`~.acquire.Identifier`'s (the settings; the marker model in G, mm).
    """

    def __init__(self, config, model_mm: np.ndarray):
        self.check_config = config
        self.check_model_mm = model_mm

    def _sigma(self, match: Match) -> np.ndarray:
        return centroid_sigma(match, self.check_config.min_centroid_sigma_px)

    def outlier(self, residuals, match: Match, uncompensated: bool, rig_sd=None):
        """(camera, marker) of the worst centre if it is an outlier, else None.

        ``rig_sd`` (2, 5), px: the rig's share of each centre's expected
        error (a stale rig displaces the right image's centres together).
        ``uncompensated``: the right view's motion could not be compensated.

        Not tested while the right image's exposure offset cannot be
        compensated (no recent pose to take the velocity from): the motion
        then displaces every right centre, and only the absolute tolerance
        applies.
        """
        if match.sigma_px is None or uncompensated:
            return None
        if not np.fmax.reduce(residuals, axis=None) > self.check_config.outlier_floor_px:
            return None                                   # the usual case: nothing near the floor
        sigma = np.where(np.isfinite(match.sigma_px), np.maximum(self._sigma(match), self.check_config.outlier_min_sigma_px),
                         np.inf)
        if rig_sd is not None:
            sigma = np.hypot(sigma, rig_sd)
        score = np.where(np.isfinite(residuals) & (residuals > self.check_config.outlier_floor_px),
                         residuals / sigma, 0.0)
        if score.max() <= self.check_config.outlier_sigma:
            return None
        return np.unravel_index(int(np.argmax(score)), score.shape)

    def suspect(self, residuals, match: Match, uncompensated: bool) -> bool:
        """Whether a centre's residual (2, 5) px exceeds ``robust_suspect_sigma`` times its expected
        noise (floored at ``outlier_min_sigma_px``)."""
        if match.sigma_px is None or uncompensated:
            return False
        if not np.fmax.reduce(residuals, axis=None) > self.check_config.robust_suspect_sigma * self.check_config.outlier_min_sigma_px:
            return False                      # the usual case: every residual within the floor's 3.5σ
        expected = np.maximum(self._sigma(match), self.check_config.outlier_min_sigma_px)
        return bool(np.nanmax(residuals / expected) > self.check_config.robust_suspect_sigma)

    def suspects(self, vectors, match: Match, pose_rows, rig_rows, rig_cov):
        """The centres (2, 5) bool that disagree with the others, and each one's excess error (2, 5) px;
        (None, None) if none do, or too many for the others to be trusted.

        A robust (Cauchy, scale ``robust_cauchy_sigma`` σ) fit of the
        residual vectors (2, 5, 2) px by a pose change and a rig change
        within its prior ``rig_cov``, linearized at the fitted pose
        (``pose_rows`` (2, 5, 2, 6), ``rig_rows`` (2, 5, 2, 9) or None): a
        rig error displaces the centres of a view coherently and is
        explained by the rig's columns; a glint fused with a marker, or a
        partial occlusion, displaces one centre and is not. The centres
        still beyond ``robust_suspect_sigma`` σ of their noise after that
        fit are suspect; their excess, per coordinate, is their residual
        against it over √2.
        """
        cfg = self.check_config
        vis = match.visible
        sigma = np.maximum(self._sigma(match), cfg.outlier_min_sigma_px)[vis]          # (m,)
        r = vectors[vis].reshape(-1)
        J = pose_rows[vis].reshape(-1, 6)
        prior = np.zeros((6, 6))
        if rig_rows is not None and rig_cov is not None:
            J = np.hstack([J, rig_rows[vis].reshape(-1, rig_rows.shape[-1])])
            prior = np.zeros((J.shape[1], J.shape[1]))
            prior[6:, 6:] = np.linalg.inv(rig_cov)
        # Columns in their natural units (rad, mm, ...) differ by orders of
        # magnitude: solve in scaled columns.
        col = np.sqrt((J ** 2).sum(axis=0)) + tol.zero
        Js, prior = J / col, prior / np.outer(col, col)
        weight = np.ones(len(sigma))
        for _ in range(cfg.robust_iterations):
            w = np.repeat(weight / sigma ** 2, 2)
            A = Js.T @ (Js * w[:, None]) + prior + tol.small * np.eye(Js.shape[1])
            left = (r - Js @ np.linalg.solve(A, Js.T @ (w * r))).reshape(-1, 2)
            z = np.hypot(left[:, 0], left[:, 1]) / sigma
            new = 1.0 / (1.0 + (z / cfg.robust_cauchy_sigma) ** 2)
            if np.abs(new - weight).max() < 0.01:
                break
            weight = new
        bad = z > cfg.robust_suspect_sigma
        if not bad.any():
            return None, None
        suspects = np.zeros(vis.shape, bool)
        suspects[vis] = bad
        # The others agree: at most a few suspects, and six centres of four
        # markers among the rest (a pose and its check).
        agree = vis & ~suspects
        if bad.sum() > cfg.robust_max_suspects or agree.sum() < 6 or agree.any(axis=0).sum() < 4:
            return None, None
        excess = np.zeros(vis.shape)
        excess[vis] = np.where(bad, np.hypot(left[:, 0], left[:, 1]) / math.sqrt(2.0), 0.0)   # per coordinate
        return suspects, excess

    def verify(self, R, p1, residuals, outlier, match, rig_sd=None) -> str | None:
        """Why a fitted pose is not to be trusted, or None.

        ``rig_sd`` (2, 5), px: each centre's 1σ displacement from the rig's
        uncertainty, which widens the reprojection tolerance.
        """
        if not np.isfinite(R.sum() + p1.sum()):
            return "pose fit diverged (non-finite result)"
        tol_px = self.check_config.reproj_tol_px
        if rig_sd is not None:
            tol_px = np.hypot(tol_px, self.check_config.rig_gate_sigma * rig_sd)
        excess = residuals / tol_px
        worst = np.fmax.reduce(excess, axis=None)          # ignores hidden markers' NaN
        if np.isnan(worst):
            worst = np.inf
        if worst > 1.0:
            cam, marker = np.unravel_index(np.nanargmax(excess), residuals.shape)
            limit = float(np.broadcast_to(tol_px, residuals.shape)[cam, marker])
            return (f"reprojection error {residuals[cam, marker]:.2f} px of {MARKER_NAMES[marker]} in the "
                    f"{('left', 'right')[cam]} image exceeds {limit:.2f} px: "
                    "the identification is not trusted")
        if outlier is not None:
            cam, marker = outlier
            return (f"{MARKER_NAMES[marker]} in the {('left', 'right')[cam]} image is "
                    f"{residuals[cam, marker]:.2f} px from where the other markers put it "
                    f"({residuals[cam, marker] / match.sigma_px[cam, marker]:.0f}x its expected "
                    "noise): a glint or partial occlusion; pose not trusted")
        return None

    def rig_terms(self, R, p1, t, t_right, velocity, P, match, geometry, refiner, spread: bool = True):
        """Rig Jacobian rows (2, 5, 2, 9) at the pose, each centre's 1σ residual from the rig (2, 5), px
        (None unless ``spread``), and the pose's own Jacobian rows (2, 5, 2, 6)
        (:func:`geometry.reprojection_rows`).

        A rig error e moves the centres by J_r e; the pose fit absorbs part
        of that and leaves r = (I − H) J_r e in the residuals (H the fit's
        hat matrix, with the fit's weights), in both images: that is what
        the checks must allow.
        """
        pose_rows = geo.reprojection_rows(R, p1, self.check_model_mm, match.visible, geometry.cameras)
        if P is None or refiner is None:
            return None, None, pose_rows
        dt = (t_right - t) if (t is not None and t_right is not None) else 0.0
        omega, v = velocity if velocity is not None else (None, None)
        rows = rig_jacobian_rows(R, p1, self.check_model_mm, refiner.estimator.state, geometry.cameras.D[1], dt,
                                 omega, v, rows_px=match.centers[..., 1], image_height=int(geometry.rig.image_size[1]))
        if not spread:
            return rows, None, pose_rows
        M, _ = self.rig_after_fit(pose_rows, rows, match.visible, self._sigma(match))
        var = np.einsum("ij,jk,ik->i", M, P, M).reshape(-1, 2).sum(axis=1)
        sd = np.full(match.visible.shape, np.nan)
        # A spread that cannot be computed (a degenerate fit) widens nothing:
        # NaN would make the checks skip the centre.
        sd[match.visible] = np.sqrt(np.where(np.isfinite(var), np.maximum(var, 0.0), 0.0))
        return rows, sd, pose_rows

    @staticmethod
    def rig_after_fit(pose_rows, rig_rows, visible, sigma_px):
        """(I − H) J_r (2m, 8), what a rig change leaves in the residuals after the pose fit (px per unit),
        and the fit's weights 1/σ² (2m,), over the visible centres."""
        w = np.repeat(1.0 / np.square(sigma_px[visible]), 2)
        return rig_residual_rows(pose_rows[visible].reshape(-1, 6),
                                 rig_rows[visible].reshape(-1, rig_rows.shape[-1]), w), w

    def rig_explains(self, pose_rows, vectors, rig_rows, P, match) -> bool:
        """Whether one change of the rig (within P) explains the residuals down to the image noise.

        A bumped camera displaces every centre of its image coherently; a
        glint or a wrong centre displaces one. The residuals are fitted by a
        rig change e (prior P) after the pose fit's share is removed; what
        is left must pass χ² at 99.9% for the degrees of freedom left, or be
        a tenth of the χ² before.
        """
        vis = match.visible
        sigma = np.maximum(self._sigma(match), self.check_config.outlier_min_sigma_px)
        M, w = self.rig_after_fit(pose_rows, rig_rows, vis, sigma)
        M = M * np.sqrt(w)[:, None]
        r = vectors[vis].reshape(-1) * np.sqrt(w)
        e = np.linalg.solve(M.T @ M + np.linalg.inv(P), M.T @ r)
        before = float(r @ r)
        left = float(np.square(r - M @ e).sum())
        dof = max(len(r) - 6 - P.shape[0], 1)
        # The linear model leaves a little (the fit under the old rig, the σ
        # floor): what is left must be small against what the rig removed.
        return left <= max(float(chi2.ppf(0.999, dof)), 0.1 * before)

    def rig_consistent(self, R, p1, vectors, pose_rows, rig_rows, P, match):
        """The pose of the joint fit of the pose and a rig change e (prior P), from the pose fitted with
        the rig as is: (R, p1, reason, withheld), the last two None for a pose to report.

        The checks let a frame through when the rig's uncertainty can explain
        its residuals; the pose fitted with the rig as is then carries that
        rig error: a camera turned 1° since rig.yaml, or a baseline 5% off,
        moves P1 by tens of mm at 65 cm (the fit trades the two views'
        disagreement off between them), and a motion compensation that
        drifted does the same. Linearized at the fit (residual vectors r
        (2, 5, 2) px, pose rows J (2, 5, 2, 6), rig rows J_r (2, 5, 2, k)):
        the MAP rig change is ê = −P Mᵀ (M P Mᵀ + W⁻¹)⁻¹ r with M = (I − H) J_r
        what the fit leaves of a rig change, and the pose moves by
        −(JᵀWJ)⁻¹ JᵀW J_r ê (what the fit had absorbed of it).

        Applied only where the images show a rig change (the χ² it removes
        beyond ``chi2.ppf(0.999, k)``); noise is left to the plain fit.
        Refused (``reason``: the frame is not trusted at all): a change
        beyond the rig's uncertainty (Mahalanobis² in P beyond the same
        quantile: not a rig error the model allows; e.g. the left and right
        images exchanged), or a correction beyond 5 mm or 0.5° that the
        frame cannot tell from noise or a stray blob: one centre left out
        explains as much, P1 is known to worse than 1.5 mm (1σ) after it (a
        hidden marker, a weak view), or the robust fit found centres suspect. Withheld (``withheld``: tracked from and
        refining the rig, not reported): a correction too large for the
        linearization (``max_rig_correction_mm``, ``max_rig_correction_deg``).
        """
        cfg = self.check_config
        vis = match.visible
        sigma = np.maximum(self._sigma(match), cfg.outlier_min_sigma_px)[vis]
        sw = np.repeat(1.0 / sigma, 2)                                   # √W, px⁻¹
        J = pose_rows[vis].reshape(-1, 6) * sw[:, None]
        Jr = rig_rows[vis].reshape(-1, rig_rows.shape[-1]) * sw[:, None]
        r = vectors[vis].reshape(-1) * sw
        if not (np.isfinite(J).all() and np.isfinite(Jr).all() and np.isfinite(r).all() and np.isfinite(P).all()):
            return R, p1, "the rig's share of the residuals cannot be computed at this pose (degenerate fit)", None
        # G = (JᵀWJ)⁺ JᵀW J_r by least squares (defined when few markers make J rank-deficient).
        G = np.linalg.lstsq(J, Jr, rcond=1e-10)[0]
        M = Jr - J @ G
        S = M @ P @ M.T + np.eye(len(r))                                  # whitened: W⁻¹ = I
        u = np.linalg.solve(S, r)
        removed = float(r @ r - r @ u)                                    # χ² the MAP rig change explains
        k = rig_rows.shape[-1]
        quantile = float(chi2.ppf(0.999, k))
        if not removed > quantile:
            return R, p1, None, None
        MPu = P @ (M.T @ u)
        e = -MPu
        mahalanobis2 = float((M.T @ u) @ MPu)
        delta = -G @ e                                                    # (δ rad, ε mm)
        turn = math.degrees(float(np.linalg.norm(delta[:3])))
        shift = float(np.linalg.norm(delta[3:]))
        if mahalanobis2 > quantile:
            return R, p1, (f"the images disagree with the rig beyond its uncertainty "
                           f"({math.sqrt(mahalanobis2):.1f}σ; the pose would move {shift:.0f} mm, {turn:.1f}°): "
                           "rig.yaml stale or the camera moved?"), None
        if shift > _AMBIGUOUS_CORRECTION_MM or turn > _AMBIGUOUS_CORRECTION_DEG:
            untrusted = _ambiguous_correction(J, r, M, S, P, G, removed, shift, turn, match.excess_px)
            if untrusted is not None:
                return (R, p1, *untrusted)
        if shift > cfg.max_rig_correction_mm or turn > cfg.max_rig_correction_deg:
            return R, p1, None, (f"the rig's error moves this pose by {shift:.0f} mm, {turn:.1f}°, more than a "
                                 f"linear correction is trusted for: pose not reported until the rig is refined")
        return cv2.Rodrigues(delta[:3])[0] @ R, p1 + delta[3:], None, None

    def offset_unbridged(self, t, t_right, compensated: bool) -> str | None:
        """Why the pose is withheld when the right image is known to be exposed at another time than the
        left one and the head's motion over that offset is not known (no recent poses, or none whose
        velocity a head can have): the right view saw the head elsewhere, by an unknown amount. None
        otherwise.

        Only the reproj estimator compensates the offset. The pose is still
        remembered, so the next frame has the velocity.
        """
        c = self.check_config
        if (c.estimator != "reproj" or not c.compensate_offset or t is None or t_right is None
                or compensated or not abs(t_right - t) > c.max_uncompensated_offset_s):
            return None
        return (f"the right image is exposed {describe_offset_s(t_right - t)} the left one and the head's "
                "motion over that is not known (no recent poses give a head's velocity): pose not reported")
