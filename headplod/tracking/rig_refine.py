"""The rig as the glasses see it: an error model of ``rig.yaml`` and its online refinement.

A real rig is not the one its ``rig.yaml`` describes: the bar gets bumped
(the right camera turns by a fraction of a degree), a board printed at the
wrong scale makes the baseline a few percent off, a focal length is poorly
determined, and two webcams without hardware sync expose milliseconds apart.
The five markers are a rigid object of known size seen by both cameras, so
every tracked frame constrains the rig.


Estimator
---------
An iterated, chunked recursive filter (:class:`RigRefiner`): every
``chunk_frames`` tracked frames, a Gauss-Newton solve over those frames'
poses (6 each) and the 9 rig parameters, with the prior from the last
solve (its covariance plus the drift expected since), iteratively
reweighted with a Cauchy loss so a frame with a glint or a wrong centre
does not pull the rig. The frames' poses are marginalized out; the rig's
posterior covariance carries what they taught. Compared with
``scipy.optimize.least_squares`` over a sliding window of overlapping
frames, this uses every frame once (no double counting between windows),
keeps what a still head cannot teach (the time offset, the readout, the focal scale)
where the motion left it, and costs one small dense solve per chunk.

- Parameters the chunk's motion does not make observable (their
  information from the chunk below ``observable_fraction`` of the prior's)
  are held, not refined.
- The rig in use (:attr:`RigRefiner.state`) follows the filter's estimate
  only when the two differ by more than ``publish_sigma`` σ of the
  estimate: a still head or a right rig does not shake the poses with the
  refinement's own noise.
- A chunk inconsistent with the prior (its residuals far beyond the noise)
  is re-solved with the prior widened to the calibration's error model; if
  that explains it, the rig changed (a bump) and the filter re-converges
  from there, else the chunk is dropped.

Timing
------
No frame waits for a chunk's solve. The ``add_frame`` call that completes
a chunk only takes its frames and their velocities; the update is a job,
a generator that stops before each Gauss-Newton pass (one pass evaluates
the chunk's frames all at once, ~0.4 ms on one core; an update takes
``iterations + 1`` passes, twice that when it tests for a bump), and each
later ``add_frame`` call runs ``passes_per_frame`` passes of it
(:meth:`RigRefiner.advance` runs it from elsewhere, :meth:`RigRefiner.flush`
to its end). The call that finishes it applies the result and returns
True when the rig in use changed. The work per call is a fixed count,
never a time: results are the same whatever the machine's speed. A job
still under way when the next chunk completes (with a small chunk, or a
bump's retry at one pass a frame) is finished first, so each update starts
from the last one's result, as when solved at once (``synchronous``).
``widen``, ``reset`` and ``drop_pending`` drop the job (nothing of it is
applied before its end); ``set_readout_prior`` restarts it. A copy of the
refiner (``copy``, ``pickle``) restarts it from its chunk. No thread: the
GIL would make it compete with the tracking thread for the interpreter
anyway, and when its result landed would depend on the machine's speed.

The frames given while a job runs were tracked with the rig in use before
its result. When the result changes that rig, they are moved onto the new
one by the change the update made to its chunk's last pose (a rigid motion
of the world, nearly the same for poses a few frames apart): that is where
their own chunk's solve starts from, what their velocities are differenced
with, and what :attr:`RigRefiner.refit_poses` gives the tracker for them.
Velocities difference poses of one rig only (a rig's change is not motion).

Modules
-------
This module holds the refiner (:class:`RigRefiner`) and the job it runs
the updates as. The rest of the refinement: the error state, the rig as
estimated and the projections' derivatives (:mod:`.rig_state`); the error
model, the readout's prior and the error model's scale the data teach
(:mod:`.rig_priors`); the frames kept and their velocities
(:mod:`.rig_frames`); the chunk solve's steps and the definiteness of every
covariance (:mod:`.rig_solve`); the settings (:mod:`.rig_refine_config`).
Their public names are importable from here too.
"""
from __future__ import annotations

import copy
import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .rig_frames import _INDEPENDENT, _ChunkData, _Frame, refit_velocities, take_velocities
from .rig_priors import (READOUT_ACTIVE_FRACTION, READOUT_PRIOR_UNKNOWN, RigErrorModel, consistency_scale,
                         count_consistency, readout_prior, scaled_error_distribution)
from .rig_refine_config import RigRefineConfig
from .rig_solve import (SKIP_INCONSISTENT, SKIP_NO_DATA, SKIP_NON_FINITE, SKIP_SINGULAR, SKIP_UNOBSERVABLE,
                        _eliminate_poses, _positive_definite, _SkipChunk, _Solution, _whitened_inverse,
                        bootstrap_agrees, chunk_posterior, chunk_terms, gauss_newton_step, normal_equations,
                        observable_directions, refit_poses, rig_information, run_to_end, whiten_prior)
from .rig_state import (_FOCAL, _GEOMETRY, _OFFSET, _READOUT, _TURN, N_RIG, PARAMETERS, RigState, project_right,
                        rig_jacobian_rows, row_fractions)

__all__ = [
    "RigRefiner",
    # re-exported from the modules the refinement was split into
    "N_RIG", "PARAMETERS", "RigState", "project_right", "rig_jacobian_rows", "row_fractions",       # rig_state
    "READOUT_ACTIVE_FRACTION", "READOUT_PRIOR_UNKNOWN", "RigErrorModel", "readout_prior",           # rig_priors
    "scaled_error_distribution",
    "RigRefineConfig",                                                                              # rig_refine_config
    "SKIP_INCONSISTENT", "SKIP_NO_DATA", "SKIP_NON_FINITE", "SKIP_SINGULAR", "SKIP_UNOBSERVABLE",   # rig_solve
]


class RigRefiner:
    """Online estimate of the rig from the tracked frames (module docstring).

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
        ``error_model.readout_prior()``: the user's value if the error model
        has one, else :data:`READOUT_PRIOR_UNKNOWN` until
        :meth:`set_readout_prior` tells the frame period's).
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
        """Set the readout's prior (mean, σ, s), e.g. :func:`readout_prior` once the frame period is known.

        Only until the first update: the estimate's and the rig in use's
        readout become ``mean_s``, the prior's σ ``sd_s`` (and with it the
        units of the floors, the comparisons, and P's readout row and column,
        scaled as its σ: a widened P stays as wide). Returns False, changing
        nothing, once an update has used the old prior (the estimate has
        learnt since; :meth:`reset` starts over with the prior set last). An
        update under way (none applied yet) starts over on its chunk with the
        new prior.
        """
        mean_s = self._checked_readout(mean_s, sd_s)
        if self.updates:
            return False
        if self._job is not None:
            chunk = self._job.chunk
            self._cancel_job()
            self._job = _Job(chunk, self._update_steps(chunk))
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
        self._pending: list[_Frame] = []
        self._recent: deque = deque(maxlen=3)   # last frames, for velocities across chunks
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
        self._cancel_job()          # the update under way (self._job), if any (module docstring, "Timing")
        # Work done (each pass evaluates every frame of its chunk): in all, and in the last call of
        # add_frame, advance or flush.
        self.passes = 0
        self.frame_terms = 0
        self.last_call_passes = 0
        self._call_start = 0

    def widen(self, t: float | None) -> None:
        """The rig changed (frames agree only with the unrefined uncertainty): re-converge from here.
        The update under way, if any, is dropped with the frames collected (they saw the rig before)."""
        self.P = _positive_definite(self.P + self.prior, self._scale)
        self._cov = None
        self._prior_fresh = True
        self._cancel_job()
        self._pending = []
        self.bumps.append(float(t) if t is not None else float("nan"))

    # ---------------------------------------------------------------- queries
    def sigma(self) -> np.ndarray:
        """1σ of the error of the rig in use (9,): rad ×3, mm ×3, log focal, offset s, readout s."""
        return np.sqrt(np.maximum(np.diag(self.cov()), 0.0))

    def converged(self) -> bool:
        """The turn and shift are known to a tenth of their prior σ."""
        s, s0 = self.sigma(), np.sqrt(np.diag(self.prior))
        return bool(np.all(s[:6] < 0.1 * s0[:6]))

    def describe(self) -> str:
        """One line for a person: how the rig differs from rig.yaml and what the refinement is doing."""
        d = self.state.differences()
        sd = self.sigma()
        parts = [f"rig.yaml: right camera turned ~{d['turn_deg']:.2f}°",
                 f"baseline x{d['baseline_scale']:.3f}"]
        if self.refined[_FOCAL] or abs(d["focal_scale"] - 1) > 1e-4:
            parts.append(f"right focal x{d['focal_scale']:.3f}")
        if self.refined[_OFFSET] or abs(d["offset_ms"]) > 0.05:
            parts.append(f"time offset {d['offset_ms']:.1f} ms ±{sd[_OFFSET] * 1e3:.1f}")
        if self.refined[_READOUT] or abs(d["readout_ms"]) > 0.05:
            # (A readout is never negative; an estimate below 0 is a global shutter seen through noise.)
            parts.append(f"rolling shutter {max(d['readout_ms'], 0.0):.1f} ms ±{sd[_READOUT] * 1e3:.1f}")
        state = "refined" if self.converged() else "refining"
        if self.bumps:
            state += f", rig changed at t={self.bumps[-1]:.1f} s"
        advice = self.advice()
        return ", ".join(parts) + f"; {state}" + (f"; {advice}" if advice else "")

    def advice(self) -> str | None:
        """A recommendation to recalibrate, and what the refinement cannot fix, or None."""
        c = self.config
        d = self.state.differences()
        reasons = []
        if d["turn_deg"] > c.recalibrate_turn_deg:
            reasons.append(f"the right camera is turned {d['turn_deg']:.1f}°")
        if abs(d["baseline_scale"] - 1) > c.recalibrate_scale:
            reasons.append(f"the baseline is {d['baseline_scale']:.3f}x rig.yaml's (check the board's square size)")
        if abs(d["offset_ms"]) * 1e-3 > c.recalibrate_offset_s:
            reasons.append(f"the cameras expose {d['offset_ms']:.0f} ms apart (fast motion will blur depth)")
        if not reasons:
            return None
        return ("recalibrate: " + "; ".join(reasons)
                + " (refined online, but distortion and the left camera are taken from rig.yaml as they are)")

    def status(self) -> dict:
        """JSON-ready state for the pose records."""
        d = self.state.differences()
        sd = self.sigma()
        return {"turn_deg": round(d["turn_deg"], 4), "baseline_scale": round(d["baseline_scale"], 5),
                "focal_scale": round(d["focal_scale"], 5), "offset_ms": round(d["offset_ms"], 3),
                "turn_sd_deg": round(float(np.degrees(sd[_TURN].max())), 4),
                "offset_sd_ms": round(float(sd[_OFFSET] * 1e3), 3),
                "readout_ms": round(d["readout_ms"], 3), "readout_sd_ms": round(float(sd[_READOUT] * 1e3), 3),
                "state": "refined" if self.converged() else "refining", "updates": self.updates,
                "bumps": len(self.bumps)}

    # ----------------------------------------------------------------- update
    def add_frame(self, t: float | None, declared_offset_s: float, centers: np.ndarray, visible: np.ndarray,
                  sigma_px: np.ndarray, R_world_G: np.ndarray, p1_mm: np.ndarray, motion_known: bool = True,
                  independent_pose: bool = False) -> bool:
        """Take one tracked frame; True when the rig in use changed (:attr:`state`, :attr:`refit_poses`).

        ``centers`` (2, 5, 2) px, ``visible`` (2, 5), ``sigma_px`` (2, 5, 2)
        or (2, 5): each centre's noise, px; the pose is the tracker's.
        ``motion_known`` False: the frame's time does not describe the head's
        motion (a clock too fast, independent poses), so no velocity is taken
        from or across it; it still tells the rig's geometry, not the
        exposure offset (which is seen only through a velocity).
        The pose is taken to be fitted with the rig in use (:attr:`state`):
        velocities difference poses of one rig (as tracked, or moved onto a
        newer rig by an update). ``independent_pose``: it does not depend on
        the rig (a simulation's, another system's): used as given, never
        moved.

        The call then runs ``passes_per_frame`` passes of the update under
        way, if any (module docstring, "Timing"): True when that finished it
        and the rig in use changed; :attr:`refit_poses` then holds the poses
        of its chunk's frames refitted with the new rig, and those of the
        frames given since (this one included), tracked with the old rig,
        moved onto the new one. A frame that completes a chunk starts its
        update, to be run by the next calls (in this one with
        ``config.synchronous``).
        """
        if not self.config.enabled:
            return False
        frame = self._frame(t, declared_offset_s, centers, visible, sigma_px, R_world_G, p1_mm, motion_known,
                            _INDEPENDENT if independent_pose else self.versions)
        if frame is not None:
            self._pending.append(frame)
        # The update under way, with this frame among those it moves onto a new rig.
        changed = self._call(self.config.passes_per_frame)
        if len(self._pending) < self.config.chunk_frames:
            return changed
        # A job still under way is finished first: the next one starts from its result.
        changed = self._run(None) or changed
        self._start_job()
        if self.config.synchronous or (self.config.first_at_once and not self.updates):
            changed = self._run(None) or changed
        self.last_call_passes = self.passes - self._call_start
        return changed

    def bootstrap(self, frames: list, far: RigErrorModel, rounds: int = 3) -> bool:
        """Start from the rig a few frames show, when ``rig.yaml`` is too far off for its error model.

        Before any update a rig.yaml whose right camera is turned 3°, or whose
        baseline is 10% off, is 6σ or 5σ outside the prior: every frame
        disagrees with it, none is accepted, and the refinement, which
        learns from accepted frames, never starts. Yet one frame decides the
        pose without the rig (the left camera sees five markers of known
        geometry) and the rig from that pose (the right camera sees them
        too). This is the chunk solve (:meth:`_solve`) over ``frames`` under
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
        it, with the solve's posterior as its covariance, and the pending
        frames and any update under way are dropped (they were tracked with
        the old rig). Only before the first update and once: False after
        it, or when the frames do not agree on a rig; nothing is changed then.
        """
        if not self.config.enabled or self.updates or self.bootstrapped_at is not None:
            return False
        chunk = [self._frame(t, 0.0, c, v, sg, R, p1, False, self.versions) for t, c, v, sg, R, p1 in frames]
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
                solution = run_to_end(self._solve(chunk, prior))
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
        self._cancel_job()
        self._pending = []
        self._recent.clear()
        self._estimate = estimate
        self.state = copy.copy(estimate)
        self.P = _positive_definite(solution.posterior, self._scale)
        self._cov = None
        self.versions += 1
        self.refit_poses = {f.t: (f.R, f.p1) for f in chunk}
        self.bootstrapped_at = chunk[-1].t
        return True

    def _frame(self, t, declared_offset_s, centers, visible, sigma_px, R_world_G, p1_mm, motion_known,
               version) -> "_Frame | None":
        """The frame to keep, or None (no time; a non-finite time, offset or pose: counted)."""
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

    def advance(self, passes: int | None = None) -> bool:
        """Run ``passes`` Gauss-Newton passes of the update under way (None: to its end), e.g. from a frame
        that gives no pose to add; True when that finished it and the rig in use changed."""
        return self._call(passes)

    @property
    def busy(self) -> bool:
        """Whether an update is under way (its chunk taken, its result not applied yet)."""
        return self._job is not None

    def forget_motion(self) -> None:
        """The times of the frames collected so far do not describe the head's motion (a clock glitch, frames
        out of order): they keep telling the geometry, but no velocity is taken from or across them.
        An update under way keeps its chunk's velocities (taken before: a synchronous update would have
        used them already)."""
        for f in self._pending:
            f.motion_known = False
        self._recent.clear()

    def drop_pending(self) -> None:
        """Drop the frames collected towards the next update and the update under way, if any (after a
        failure inside either); the estimate stands."""
        self._cancel_job()
        self._pending = []
        self._recent.clear()

    def flush(self) -> bool:
        """Finish the update under way, then use the frames waiting for a full chunk (end of a recording).
        True when the rig in use changed (:attr:`refit_poses`: the last change's)."""
        self._call_start = self.passes
        changed = self._run(None)
        if len(self._pending) >= 2:
            self._start_job()
            changed = self._run(None) or changed
        self.last_call_passes = self.passes - self._call_start
        return changed

    # ------------------------------------------------------------------ jobs
    def _call(self, passes: int | None) -> bool:
        """Run the update under way for at most ``passes`` passes (None: to its end), as one call's work."""
        self._call_start = self.passes
        changed = self._run(passes)
        self.last_call_passes = self.passes - self._call_start
        return changed

    def _start_job(self) -> None:
        """The pending frames become a chunk and its update a job (not run yet)."""
        chunk, self._pending = self._pending, []
        take_velocities(self._recent, chunk, self.config.max_gap_frames)
        self._recent.extend(chunk[-2:])
        self._job = _Job(chunk, self._update_steps(chunk))

    def _run(self, passes: int | None) -> bool:
        """Run the job for up to ``passes`` more passes (None: to its end); True when it finished and
        changed the rig in use. An exception inside the job ends it (its chunk is lost) and propagates."""
        start = self.passes
        while self._job is not None and (passes is None or self.passes - start < passes):
            try:
                next(self._job.steps)
            except StopIteration as end:
                self._job = None
                return bool(end.value)
            except BaseException:
                self._job = None
                raise
        return False

    def __getstate__(self):
        # A generator cannot be copied or pickled: a copy restarts the update
        # under way from its chunk (the same result; its passes run again).
        state = self.__dict__.copy()
        job = state.pop("_job", None)
        state["_job_chunk"] = None if job is None else job.chunk
        return state

    def __setstate__(self, state):
        chunk = state.pop("_job_chunk", None)
        self.__dict__.update(state)
        self._job = None if chunk is None else _Job(chunk, self._update_steps(chunk))

    def _cancel_job(self) -> None:
        """Forget the update under way (its chunk's frames unused); nothing of it was applied."""
        job = getattr(self, "_job", None)      # (none yet in the first reset)
        self._job = None
        if job is not None:
            job.steps.close()

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

    def _predicted(self, t: float) -> np.ndarray:
        """The prior (9, 9) of a chunk ending at ``t``: the last posterior plus the drift since, SPD.

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

    def _skip(self, chunk: list[_Frame], reason: str) -> bool:
        """Remember a chunk without an update (the estimate and P stay as they were)."""
        self.skipped_chunks[reason] += 1
        self.last_skip = (chunk[-1].t, reason)
        return False

    def _update_steps(self, chunk: list[_Frame]):
        """One update from a chunk, as a generator that stops before each Gauss-Newton pass; it returns
        True when the rig in use changed. A chunk that cannot update (``SKIP_*``) leaves the estimate,
        its covariance and the rig in use unchanged. Nothing is changed before the last pass: a job
        closed before its end leaves no trace."""
        try:
            prior = self._predicted(chunk[-1].t)
            solution = yield from self._solve(chunk, prior)
        except _SkipChunk as skip:
            return self._skip(chunk, skip.args[0])
        bumped = False
        if solution.noise_scale > self.config.inconsistency:
            # The chunk disagrees with the rig: did the rig change (a bump)?
            try:
                retry = yield from self._solve(chunk, _positive_definite(prior + self.prior, self._scale))
            except _SkipChunk:
                retry = None
            if retry is None or not (solution.chi2 - retry.chi2 > self.config.bump_evidence
                                     and retry.noise_scale <= self.config.inconsistency):
                return self._skip(chunk, SKIP_INCONSISTENT)
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
                solution = yield from self._solve(chunk, prior)
            except _SkipChunk as skip:
                return self._skip(chunk, skip.args[0])
        if bumped:                   # (only now: a chunk skipped above changes nothing)
            self.bumps.append(chunk[0].t)
        if not (bumped or self._prior_fresh):
            self._count_consistency(prior, solution)
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
        if self._pending and last.t in solution.refit:
            R_old, p_old = last.newest()                # the pose the solve started from
            R_new, p_new = solution.refit[last.t]
            turn = R_new @ R_old.T
            shift = p_new - turn @ p_old
            for f in self._pending:
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

    def _departs(self) -> bool:
        """The estimate differs from the rig in use by more than ``publish_sigma`` σ along some
        direction (eigenvectors of P, in units of the prior)."""
        d = self._estimate.error_from(self.state)
        L_inv = self._prior_L_inv
        lam, U = np.linalg.eigh(L_inv @ self.P @ L_inv.T)
        z = (U.T @ (L_inv @ d)) / np.sqrt(np.maximum(lam, 1e-30))
        return bool(np.abs(z).max() > self.config.publish_sigma)

    @property
    def estimate(self) -> RigState:
        """The refinement's current estimate of the rig (``state`` is the rig in use, which follows it
        only when they differ by more than the estimate's noise)."""
        return self._estimate

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
            learnt = bool(np.linalg.eigvalsh(0.5 * (A + A.T))[0] < 1.0 - 1e-6)
            self._error = (cov, mean, spread, learnt)
        return self._error[1].copy(), self._error[2].copy()

    def _solve(self, chunk: list[_Frame], prior: np.ndarray):
        """Gauss-Newton with Cauchy reweighting over the chunk's poses and the rig: a generator that stops
        (yields) before each pass over the chunk's frames and returns the :class:`~.rig_solve._Solution`
        (the steps of a pass: :mod:`.rig_solve`).

        ``prior`` (9, 9) is SPD (:meth:`_predicted`). Each frame's pose (6)
        is eliminated by its own 6×6 block (the poses share nothing but the
        rig), leaving the rig's 9×9 system: the Schur complement S = data
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
            self.passes += 1
            self.frame_terms += n
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



@dataclass
class _Job:
    """An update under way: its chunk, and the generator running it (:meth:`RigRefiner._update_steps`)."""

    chunk: list
    steps: object
