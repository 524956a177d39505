"""The rig's estimator: a chunked recursive Gauss-Newton filter over the 9 rig parameters (:class:`RigEstimator`).

Every chunk of tracked frames is one update: a Gauss-Newton solve over
those frames' poses (6 each) and the rig's parameters, with the prior from
the last update (its covariance plus the drift expected since), iteratively
reweighted with a Cauchy loss so a frame with a glint or a wrong centre
does not pull the rig (:mod:`.rig_refine`'s docstring, "Estimator").

The estimator owns the estimate, its covariance P, the prior, the rig in
use and the counts of what happened (updates, bumps, skipped chunks). It
does not decide when a chunk is solved: :meth:`RigEstimator.update_steps`
is a generator that stops before each Gauss-Newton pass and returns the
update as a value (:class:`ChunkUpdate`), changing nothing;
:meth:`RigEstimator.apply` applies it. Who runs the passes, and when, is
the scheduler's business (:mod:`.rig_schedule`); :func:`solve_at_once`
runs an update in one go.

Units: the error state's (rad ×3 of the right camera's turn, mm ×3 of its
shift, log focal scale, exposure offset s, readout s; :mod:`.rig_state`).
Times in s; poses R_world_G (3, 3) and P1 (3,) mm in the world (left
camera) frame.
"""
from __future__ import annotations

import copy
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .rig_frames import _INDEPENDENT, _ChunkData, _Frame, refit_velocities
from .rig_priors import RigErrorModel, consistency_scale, count_consistency, scaled_error_distribution
from .rig_refine_config import RigRefineConfig
from .rig_solve import (SKIP_INCONSISTENT, _eliminate_poses, _positive_definite, _SkipChunk, _Solution,
                        _whitened_inverse, bootstrap_agrees, chunk_posterior, chunk_terms, gauss_newton_step,
                        normal_equations, observable_directions, refit_poses, rig_information, run_to_end,
                        whiten_prior)
from .rig_state import _GEOMETRY, _OFFSET, _READOUT, N_RIG, RigState
from ..tol import tol

__all__ = ["ChunkUpdate", "RigEstimator", "RigSummary", "solve_at_once"]


@dataclass(frozen=True, eq=False)
class ChunkUpdate:
    """What one chunk's update found (:meth:`RigEstimator.update_steps`), not applied yet.

    ``skip`` is a ``SKIP_*`` reason when the chunk gives no update (then
    ``solution`` and ``prior`` are None); else ``solution`` is the solve's
    result and ``prior`` (9, 9) the prior it was solved under, ``bumped``
    whether that prior was widened because the rig changed.
    """

    chunk: list                       # the chunk's frames (_Frame), oldest first
    skip: str | None = None
    solution: _Solution | None = None
    prior: np.ndarray | None = None
    bumped: bool = False


@dataclass(frozen=True, eq=False)
class RigSummary:
    """The estimator's values a report is made of (:mod:`.rig_report`).

    ``differences``: :meth:`RigState.differences` of the rig in use
    (turn_deg, baseline_scale, focal_scale, offset_ms, readout_ms);
    ``sigma`` (9,): 1σ of the rig in use's error (error-state units);
    ``refined`` (9,) bool: parameters refined at least once.
    """

    differences: dict
    sigma: np.ndarray
    refined: np.ndarray
    converged: bool
    updates: int
    bumps: tuple


class RigEstimator:
    """The rig's estimate and its covariance, updated one chunk of frames at a time (module docstring).

    Parameters
    ----------
    rig : headplod.io.Rig
        The rig as ``rig.yaml`` describes it.
    model_mm : (5, 3)
        The marker model in G, mm.
    config : RigRefineConfig
    error_model : RigErrorModel
    offset_declared : bool
        Whether the right image's time is given (``t_right``).
    calibration_std : dict, optional
        The calibration's own standard deviations (``headplod calibrate``).
    readout_prior : (mean_s, sd_s), optional
        Prior of the rolling shutter's readout time, s (default
        ``error_model.readout_prior()``).
    """

    def __init__(self, rig, model_mm, config: RigRefineConfig = RigRefineConfig(),
                 error_model: RigErrorModel = RigErrorModel(), offset_declared: bool = False,
                 calibration_std: dict | None = None, readout_prior: tuple[float, float] | None = None):
        self.config = config
        self.error_model = error_model
        self.model_mm = np.asarray(model_mm, np.float64)
        self.calibrated = rig
        self.D = (np.asarray(rig.D1, np.float64), np.asarray(rig.D2, np.float64))
        self.K1 = np.asarray(rig.K1, np.float64)
        self.offset_declared = offset_declared
        size = getattr(rig, "image_size", None)
        self.image_height = int(size[1]) if size is not None else None     # rows, for the rolling shutter
        mean, sd = error_model.readout_prior() if readout_prior is None else readout_prior
        self.readout_mean_s = self._checked_readout(mean, sd)
        self.prior = error_model.covariance(rig, offset_declared, calibration_std, readout_sd_s=float(sd))
        self._set_prior(self.prior)
        self.reset()

    @staticmethod
    def _checked_readout(mean_s, sd_s) -> float:
        if not (math.isfinite(mean_s) and math.isfinite(sd_s) and sd_s > 0):
            raise ValueError(f"the readout's prior needs a finite mean and a finite σ > 0 (got {mean_s}, {sd_s})")
        return float(mean_s)

    def _set_prior(self, prior: np.ndarray) -> None:
        """The prior and what derives from it: the units of every covariance's floor, its Cholesky inverse."""
        scale = np.sqrt(np.diag(prior))
        if not (np.isfinite(prior).all() and np.all(scale > 0)):
            raise ValueError(f"the rig's error model gives no usable prior (σ per parameter {scale.tolist()}): "
                             "every σ must be finite and > 0")
        self.prior = prior
        self._scale = scale                   # (9,) the prior's σ: the units of every covariance's floor
        # The prior in the units the refiner compares in (its Cholesky factor's inverse).
        self._prior_L_inv = scipy.linalg.solve_triangular(np.linalg.cholesky(prior), np.eye(N_RIG), lower=True)

    def set_readout_prior(self, mean_s: float, sd_s: float) -> bool:
        """Set the readout's prior (mean, σ, s); only until the first update (False, nothing changed, after).

        The estimate's and the rig in use's readout become ``mean_s``, the
        prior's σ ``sd_s`` (and with it the units of the floors, the
        comparisons, and P's readout row and column, scaled as its σ: a
        widened P stays as wide). An update under way must start over
        (its generator read the old prior): the caller restarts it.
        """
        mean_s = self._checked_readout(mean_s, sd_s)
        if self.updates:
            return False
        prior = self.prior.copy()
        ratio = np.ones(N_RIG)
        ratio[_READOUT] = sd_s / math.sqrt(prior[_READOUT, _READOUT])
        prior[_READOUT, :] = prior[:, _READOUT] = 0.0
        prior[_READOUT, _READOUT] = sd_s ** 2
        self._set_prior(prior)
        self.P = self.P * np.outer(ratio, ratio)
        self.readout_mean_s = mean_s
        self.state.readout_s = self._estimate.readout_s = mean_s
        self._cov = None
        return True

    def reset(self) -> None:
        """Back to ``rig.yaml`` and its error model (the readout's prior as set last)."""
        # The filter's estimate moves with every update; the rig in use
        # (``state``) follows it only when they differ by more than the
        # estimate's noise, so a still head or a perfect rig does not shake
        # the poses with the refinement's own noise.
        self.state = RigState(self.calibrated, self.readout_mean_s)
        self._estimate = RigState(self.calibrated, self.readout_mean_s)
        self.P = self.prior.copy()
        self.versions = 0           # changes of the rig in use
        self._cov = None            # cov(), until P or either rig changes
        # error_distribution()'s (cov() it was computed with, mean, covariance, has_data()).
        self._error = None
        self._start_t: float | None = None   # time (s) of the first frame kept: the drift is counted from it
        self._consistency = np.zeros(2)      # forgetting sums of the updates' NIS and degrees of freedom
        self._prior_fresh = True             # the next update's prior is the error model's, not a posterior
        self._last_update_t = None
        self.updates = 0
        self.bootstrapped_at: float | None = None   # time (s) of the frame a far-off rig.yaml was replaced from
        self.bumps = []             # times (s) of detected changes of the rig
        self.refined = np.zeros(N_RIG, bool)    # parameters refined at least once
        # Chunks that gave no update, by reason (SKIP_*), and the last one's (t of its last frame, reason).
        self.skipped_chunks: Counter = Counter()
        self.last_skip: tuple[float, str] | None = None
        self.ignored_frames = 0     # frames with a non-finite time, offset or pose, not used
        # {t: (R_world_G, p1)} of the last update's frames, fitted with the rig it gave.
        self.refit_poses = {}

    def widen(self, t: float | None) -> None:
        """The rig changed (frames agree only with the unrefined uncertainty): re-converge from here, the
        prior added to P; ``t`` (s) is remembered as a bump. (The frames collected saw the rig before: the
        caller drops them and any update under way.)"""
        self.P = _positive_definite(self.P + self.prior, self._scale)
        self._cov = None
        self._prior_fresh = True
        self.bumps.append(float(t) if t is not None else float("nan"))

    # ---------------------------------------------------------------- queries
    def sigma(self) -> np.ndarray:
        """1σ of the error of the rig in use (9,): rad ×3, mm ×3, log focal, offset s, readout s."""
        return np.sqrt(np.maximum(np.diag(self.cov()), 0.0))

    def converged(self) -> bool:
        """The turn and shift are known to a tenth of their prior σ."""
        s, s0 = self.sigma(), np.sqrt(np.diag(self.prior))
        return bool(np.all(s[:6] < 0.1 * s0[:6]))

    def summary(self) -> RigSummary:
        """The values a report is made of (:mod:`.rig_report`)."""
        return RigSummary(self.state.differences(), self.sigma(), self.refined.copy(), self.converged(),
                          self.updates, tuple(self.bumps))

    @property
    def estimate(self) -> RigState:
        """The current estimate of the rig (``state`` is the rig in use, which follows it only when they
        differ by more than the estimate's noise)."""
        return self._estimate

    def data_scale(self) -> float:
        """How much the data's errors exceed what the refinement assumed: a variance ratio (1: as assumed).

        Covariance matching on the updates' innovations (Mehra 1972): the
        forgetting sums (``_CONSISTENCY_KEEP`` per update, ~10 updates)
        of their normalized innovations squared over their degrees of
        freedom (:meth:`_count_consistency`), with a prior of
        ``_CONSISTENCY_PRIOR_DOF`` degrees of freedom at 1
        (:func:`~.rig_priors.consistency_scale`). Below 1 when
        the centres' σ the chunks were weighted with overstate their noise
        (the noise model learnt while the rig was off) or the drift allowed
        overstates the rig's: the estimate then moves less than P says. It
        scales the data's information in :meth:`error_distribution` only;
        the refinement itself, its checks and :meth:`cov` keep P as it is."""
        return consistency_scale(self._consistency)

    def has_data(self) -> bool:
        """Whether the refinement has learnt anything of the rig since its error model was (re)set: False
        before the first update and after :meth:`widen` (P then is the error model's, or wider, in
        every direction)."""
        self.error_distribution()
        return self._error[3]

    def cov(self) -> np.ndarray:
        """Covariance (9, 9) of the error of the rig in use: the estimate's, and how far it is from it.

        Symmetric positive definite (floored as :func:`_positive_definite`:
        P plus an outer product can lose it to rounding when the two differ
        by many orders). Computed once per change (the tracker asks for it
        several times a frame)."""
        if self._cov is None:
            d = self._estimate.error_from(self.state)
            try:
                self._cov = _positive_definite(self.P + np.outer(d, d), self._scale)
            except _SkipChunk:
                # Not reachable with finite states (every increment applied is
                # checked finite); P alone is SPD, and the honest fallback.
                self._cov = self.P
        return self._cov

    def error_distribution(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean (9,) and covariance (9, 9) of the error of the rig in use (the true rig minus it, in the
        error state's units: rad ×3, mm ×3, log focal, s ×2), for the uncertainty of V.

        :meth:`cov` (P + ddᵀ, d the estimate minus the rig in use) is what
        the checks allow for: the error model as it is, however well the
        data agree with rig.yaml. Here the error model's scale is learnt
        too (:func:`scaled_error_distribution`): when the data find the rig
        where rig.yaml put it within their noise (a right calibration), d is
        the estimate's own noise and P the error model's σ narrowed by data
        that never saw it wrong; both shrink to what a right rig leaves, and
        the mean is what the rig in use (if it followed the estimate's noise)
        is off from it. A rig found off keeps P and d. The data's
        information is taken :meth:`data_scale` times less than the
        refinement assumed, and the drift since the first frame (config
        ``drift_*``) is added as the data narrow it. Computed once per
        change of :meth:`cov`."""
        cov = self.cov()
        if self._error is None or self._error[0] is not cov:
            reference = RigState(self.calibrated, self.readout_mean_s)
            drift = None
            if self._start_t is not None and self._last_update_t is not None:
                drift = self._process_noise_over(max(self._last_update_t - self._start_t, 0.0))
            try:
                mean, spread = scaled_error_distribution(self.P, self.prior, self._estimate.error_from(reference),
                                                         self.state.error_from(reference), _GEOMETRY, drift,
                                                         self.data_scale())
                spread = _positive_definite(spread, self._scale)
            except (np.linalg.LinAlgError, _SkipChunk):
                # (Not reached with a finite state and an SPD P; the error model as it is, then.)
                mean, spread = self._estimate.error_from(self.state), self.P
            if not (np.isfinite(mean).all() and np.isfinite(spread).all()):
                mean, spread = self._estimate.error_from(self.state), self.P
            A = self._prior_L_inv @ self.P @ self._prior_L_inv.T
            learnt = bool(np.linalg.eigvalsh(0.5 * (A + A.T))[0] < 1.0 - tol.floor)
            self._error = (cov, mean, spread, learnt)
        return self._error[1].copy(), self._error[2].copy()

    # ----------------------------------------------------------------- frames
    def frame(self, t, declared_offset_s, centers, visible, sigma_px, R_world_G, p1_mm, motion_known,
              version) -> "_Frame | None":
        """The frame to keep (a copy of the caller's arrays), or None (no time; a non-finite time, offset
        or pose: counted in ``ignored_frames``). ``version``: :attr:`versions` of the rig its pose was
        fitted with (``_INDEPENDENT``: none)."""
        if t is None:
            return None
        R_world_G = np.array(R_world_G, np.float64)     # copies: the caller may reuse its arrays
        p1_mm = np.array(p1_mm, np.float64).reshape(3)
        if not (math.isfinite(t) and math.isfinite(declared_offset_s)
                and np.isfinite(R_world_G).all() and np.isfinite(p1_mm).all()):
            # No time, offset or pose to learn from (the centres' own NaNs are
            # handled per centre): counted, not used.
            self.ignored_frames += 1
            return None
        if self._start_t is None:
            self._start_t = float(t)
        sig = np.asarray(sigma_px, np.float64)
        if sig.ndim == 2:
            sig = np.repeat(sig[..., None], 2, axis=2)
        sig = np.where(np.isfinite(sig), np.maximum(sig, self.config.min_sigma_px), np.inf)
        return _Frame(float(t), float(declared_offset_s), np.asarray(centers, np.float64).copy(),
                      np.asarray(visible, bool).copy(), sig, R_world_G, p1_mm, motion_known=bool(motion_known),
                      rig_version=version)

    # -------------------------------------------------------------- bootstrap
    def bootstrap(self, frames: list, far: RigErrorModel, rounds: int = 3) -> bool:
        """Start from the rig a few frames show, when ``rig.yaml`` is too far off for its error model.

        Before any update a rig.yaml whose right camera is turned 3°, or whose
        baseline is 10% off, is 6σ or 5σ outside the prior: every frame
        disagrees with it, none is accepted, and the refinement, which
        learns from accepted frames, never starts. Yet one frame decides the
        pose without the rig (the left camera sees five markers of known
        geometry) and the rig from that pose (the right camera sees them
        too). This is the chunk solve (:meth:`solve`) over ``frames`` under
        the prior ``far`` (a turn, shift and focal error model wide enough),
        relinearized ``rounds`` times from where the last ended (the
        directions a solve may move are decided where it starts, and a 3°
        error is far from linear). The exposure offset and the readout keep
        their prior: no velocity is taken (the frames failed, and their
        motion is not known).

        ``frames``: (t s, centers (2, 5, 2) px, visible (2, 5), sigma_px
        (2, 5) or (2, 5, 2) px, R_world_G, p1 mm), consecutive frames, each
        pose fitted with the rig in use. Accepted when every frame's every
        centre comes within ``_BOOTSTRAP_MAX_Z`` σ of where the joint fit
        puts it (a median test would let one stray blob taken for a marker
        through, and a free rig absorbs much), and the change is one ``far``
        allows (χ² with 7 dof, 99.9%): the estimate and the rig in use become
        it, with the solve's posterior as its covariance (the caller drops
        the frames collected and any update under way: they were tracked
        with the old rig). Only before the first update and once: False
        after it, or when the frames do not agree on a rig; nothing is
        changed then.
        """
        if not self.config.enabled or self.updates or self.bootstrapped_at is not None:
            return False
        chunk = [self.frame(t, 0.0, c, v, sg, R, p1, False, self.versions) for t, c, v, sg, R, p1 in frames]
        if not chunk or any(f is None for f in chunk):
            return False
        prior = far.covariance(self.calibrated, self.offset_declared, readout_sd_s=float(self._scale[_READOUT]))
        for k in (_OFFSET, _READOUT):
            prior[k, :] = prior[:, k] = 0.0
            prior[k, k] = self.prior[k, k]
        start = self._estimate
        estimate = copy.copy(start)
        solution = None
        try:
            for _ in range(max(int(rounds), 1)):
                self._estimate = estimate
                solution = run_to_end(self.solve(chunk, prior))
                estimate = estimate.moved(solution.increment)
                for f in chunk:
                    f.R, f.p1 = solution.refit[f.t]
                if solution.noise_scale <= self.config.inconsistency:
                    break
        except _SkipChunk:
            return False
        finally:
            self._estimate = start
        if solution is None or not solution.noise_scale <= self.config.inconsistency:
            return False
        if not bootstrap_agrees(chunk, start, estimate, prior, self.model_mm, self.K1, self.D,
                                self.calibrated.image_size[1]):
            return False
        self._estimate = estimate
        self.state = copy.copy(estimate)
        self.P = _positive_definite(solution.posterior, self._scale)
        self._cov = None
        self.versions += 1
        self.refit_poses = {f.t: (f.R, f.p1) for f in chunk}
        self.bootstrapped_at = chunk[-1].t
        return True

    # ----------------------------------------------------------------- update
    def _process_noise(self, t: float) -> np.ndarray:
        """Drift (9, 9) since the last update: a random walk, variance ∝ elapsed time (0 if none elapsed)."""
        elapsed = 0.0 if self._last_update_t is None else max(t - self._last_update_t, 0.0)
        return self._process_noise_over(elapsed)

    def _process_noise_over(self, elapsed: float) -> np.ndarray:
        """Drift (9, 9) over ``elapsed`` s: the random walk of config ``drift_*``."""
        c = self.config
        q = np.array([math.radians(c.drift_turn_deg_per_sqrt_s)] * 3 + [c.drift_shift_mm_per_sqrt_s] * 3
                     + [c.drift_focal_per_sqrt_s, c.drift_offset_s_per_sqrt_s,
                        c.drift_readout_s_per_sqrt_s]) ** 2 * elapsed
        return np.diag(q)

    def predicted_prior(self, t: float) -> np.ndarray:
        """The prior (9, 9) of a chunk ending at ``t`` (s): the last posterior plus the drift since, SPD.

        Unobservable parameters must not grow without bound while the head
        is still: a variance above the prior's is brought down to it by
        scaling its row and column together (P ← S P S, S diagonal ≤ 1),
        which keeps P positive definite and its correlations as they were.
        (Capping the diagonal alone made P indefinite once an inflated
        posterior's variances passed the prior's: issue 21, a rolling
        shutter's residuals.)
        """
        P = self.P + self._process_noise(t)
        shrink = np.sqrt(np.minimum(1.0, np.diag(self.prior) / np.diag(P)))
        return _positive_definite(P * np.outer(shrink, shrink), self._scale)

    def update_steps(self, chunk: list[_Frame]):
        """One update from a chunk, as a generator that stops (yields None) before each Gauss-Newton pass
        and returns the :class:`ChunkUpdate`; it changes nothing of the estimator (:meth:`apply` does).

        An update takes ``iterations + 1`` passes, twice that when it tests
        for a bump, and once more when the velocities its refitted poses
        give changed (``refit_velocity_change``). The chunk's frames'
        velocities may be taken again from the refitted poses.
        """
        try:
            prior = self.predicted_prior(chunk[-1].t)
            solution = yield from self.solve(chunk, prior)
        except _SkipChunk as skip:
            return ChunkUpdate(chunk, skip.args[0])
        bumped = False
        if solution.noise_scale > self.config.inconsistency:
            # The chunk disagrees with the rig: did the rig change (a bump)?
            try:
                retry = yield from self.solve(chunk, _positive_definite(prior + self.prior, self._scale))
            except _SkipChunk:
                retry = None
            if retry is None or not (solution.chi2 - retry.chi2 > self.config.bump_evidence
                                     and retry.noise_scale <= self.config.inconsistency):
                return ChunkUpdate(chunk, SKIP_INCONSISTENT)
            solution = retry
            bumped = True
            prior = _positive_definite(prior + self.prior, self._scale)
        if refit_velocities(chunk, solution.refit, self.config.max_gap_frames, self.config.refit_velocity_change):
            # The velocities (of the exposure offset's and the readout's
            # columns) were differences of the poses as tracked, one of which
            # a glint or a stale rig may have put a degree off: a velocity of
            # 45°/s that no head had, whose frame then decides the offset.
            # Solved again with the differences of the poses this solve
            # refitted (one rig, glints down-weighted).
            try:
                solution = yield from self.solve(chunk, prior)
            except _SkipChunk as skip:
                return ChunkUpdate(chunk, skip.args[0])
        return ChunkUpdate(chunk, None, solution, prior, bumped)

    def apply(self, update: ChunkUpdate, since: list[_Frame]) -> bool:
        """Apply an update (:meth:`update_steps`'s value); True when the rig in use changed.

        A skipped chunk is counted (``skipped_chunks``, ``last_skip``) and
        changes nothing else. When the rig in use changes, ``since`` (the
        frames given while the update ran, tracked with the old rig) are
        moved onto the new one by the change the update made to its chunk's
        last pose; :attr:`refit_poses` then holds the chunk's poses refitted
        and those moved.
        """
        chunk = update.chunk
        if update.skip is not None:
            self.skipped_chunks[update.skip] += 1
            self.last_skip = (chunk[-1].t, update.skip)
            return False
        solution, bumped = update.solution, update.bumped
        if bumped:                   # (only now: a chunk skipped changes nothing)
            self.bumps.append(chunk[0].t)
        if not (bumped or self._prior_fresh):
            self._count_consistency(update.prior, solution)
        self._prior_fresh = False
        self._estimate.apply(solution.increment)
        self.P = solution.posterior
        self.refined |= solution.moved
        self._cov = None
        self.updates += 1
        self._last_update_t = chunk[-1].t
        if not (bumped or self._departs()):
            return False
        self.state = copy.copy(self._estimate)
        self._cov = None
        self.versions += 1
        # The frames given while the job ran were tracked with the old rig:
        # moved onto the new one by the change the update made to the chunk's
        # last pose (a rigid motion of the world, nearly the same for poses a
        # few frames apart), as the start of their own chunk's solve, for
        # velocities with the frames tracked from now on, and for the tracker
        # (refit_poses).
        last = chunk[-1]
        moved = {}
        if since and last.t in solution.refit:
            R_old, p_old = last.newest()                # the pose the solve started from
            R_new, p_new = solution.refit[last.t]
            turn = R_new @ R_old.T
            shift = p_new - turn @ p_old
            for f in since:
                if f.rig_version != _INDEPENDENT:
                    R, p1 = f.newest()
                    f.refit = (self.versions, turn @ R, turn @ p1 + shift)
                    moved[f.t] = f.refit[1:]
        # The chunk's last frames, kept for the next chunk's velocities, keep
        # their pose refitted with the new rig too (take_velocities differences
        # poses of one rig).
        for f in chunk[-2:]:
            if f.t in solution.refit:
                f.refit = (self.versions, *solution.refit[f.t])
        self.refit_poses = {**solution.refit, **moved}
        return True

    def _count_consistency(self, prior: np.ndarray, solution: "_Solution") -> None:
        """Add an update's normalized innovation squared to the forgetting sums :meth:`data_scale` reads
        (:func:`~.rig_priors.count_consistency`: only for updates whose prior was a posterior, not for a
        bump's)."""
        self._consistency = count_consistency(self._consistency, prior, solution.posterior, solution.increment,
                                              self._scale)

    def _departs(self) -> bool:
        """The estimate differs from the rig in use by more than ``publish_sigma`` σ along some
        direction (eigenvectors of P, in units of the prior)."""
        d = self._estimate.error_from(self.state)
        L_inv = self._prior_L_inv
        lam, U = np.linalg.eigh(L_inv @ self.P @ L_inv.T)
        z = (U.T @ (L_inv @ d)) / np.sqrt(np.maximum(lam, 1e-30))
        return bool(np.abs(z).max() > self.config.publish_sigma)

    def solve(self, chunk: list[_Frame], prior: np.ndarray):
        """Gauss-Newton with Cauchy reweighting over the chunk's poses and the rig: a generator that stops
        (yields None) before each pass over the chunk's frames and returns the
        :class:`~.rig_solve._Solution` (the steps of a pass: :mod:`.rig_solve`).

        ``prior`` (9, 9) is SPD (:meth:`predicted_prior`). Each frame's pose
        (6) is eliminated by its own 6×6 block (the poses share nothing but
        the rig), leaving the rig's 9×9 system: the Schur complement S = data
        information on the rig + prior information, whose inverse is the
        posterior. Both are solved by eigendecomposition in scaled units
        (pose blocks to unit diagonal, the rig in units of the prior), which
        also measures their conditioning.

        Raises ``_SkipChunk(reason)`` when the chunk cannot update: nothing
        observable, no usable centre, a non-finite term, a singular or
        ill-conditioned pose block or rig system (below ``_MIN_CONDITION``).
        """
        c = self.config
        n = len(chunk)
        L, L_inv, prior_info = whiten_prior(prior)
        data = _ChunkData.of(chunk, self.image_height)
        # Which rig parameters can this chunk teach? Decided at the start (linearization point).
        rig = np.zeros(N_RIG)
        poses = np.zeros((n, 6))
        observable = confine = None
        weights = None
        for iteration in range(c.iterations + 1):
            yield
            state = self._estimate.moved(rig)
            res, J_pose, J_rig = chunk_terms(data, poses, state, self.model_mm, self.K1, self.D)
            # The Cauchy weights of the first two passes' residuals, then held.
            eq = normal_equations(res, J_pose, J_rig, data, weights if iteration >= 2 else None, c.cauchy_scale)
            weights = eq.weights
            # Eliminate the poses: X = A⁻¹ B (n, 6, 9), y = A⁻¹ g (n, 6).
            X, y = _eliminate_poses(eq.A, eq.B, eq.g_pose)
            white_info = rig_information(eq, X, L)
            if observable is None:
                observable, confine = observable_directions(white_info, L, L_inv, c.observable_fraction)
            S_white = _whitened_inverse(np.eye(N_RIG) + white_info)      # the rig's system, inverted
            if iteration == c.iterations:
                break
            step_rig, step_pose = gauss_newton_step(eq, X, y, rig, prior_info, L, S_white)
            poses += step_pose
            rig += confine @ step_rig
        posterior, noise_scale = chunk_posterior(eq, n, observable.shape[1], L, S_white, self._scale)
        moved = np.diag(confine @ prior @ confine.T) / np.diag(prior) > 0.5
        return _Solution(rig, posterior, eq.chi2, eq.rows_used, noise_scale, refit_poses(chunk, data, poses), moved)


def solve_at_once(estimator: RigEstimator, chunk: list[_Frame]) -> ChunkUpdate:
    """Run a chunk's update through all its passes at once (no scheduling); its :class:`ChunkUpdate`, not
    applied."""
    return run_to_end(estimator.update_steps(chunk))
