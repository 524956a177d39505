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
- The rig in use (:attr:`RigEstimator.state <.rig_estimator.RigEstimator.state>`)
  follows the filter's estimate only when the two differ by more than
  ``publish_sigma`` σ of the estimate: a still head or a right rig does not
  shake the poses with the refinement's own noise.
- A chunk inconsistent with the prior (its residuals far beyond the noise)
  is re-solved with the prior widened to the calibration's error model; if
  that explains it, the rig changed (a bump) and the filter re-converges
  from there, else the chunk is dropped.

Timing
------
No frame waits for a chunk's solve. The ``add_frame`` call that completes
a chunk only takes its frames and their velocities; the update is a job,
a generator that stops before each Gauss-Newton pass (one pass evaluates
the chunk's frames all at once; an update takes ``iterations + 1`` passes,
twice that when it tests for a bump), and each later ``add_frame`` call
runs ``passes_per_frame`` passes of it (:meth:`RigRefiner.flush` runs it
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
with, and what :attr:`RigEstimator.refit_poses <.rig_estimator.RigEstimator.refit_poses>`
gives the tracker for them.
Velocities difference poses of one rig only (a rig's change is not motion).

Parts
-----
:class:`RigRefiner` is what the tracker holds; it owns no state of its
own and composes three parts:

- the estimator (:class:`~.rig_estimator.RigEstimator`): the estimate, its
  covariance, the prior, the rig in use and the counts; a chunk's update
  as a generator of passes that returns the update as a value, and the
  method that applies it;
- the scheduler (:class:`~.rig_schedule.SolveScheduler`): the frames
  collected into chunks and each chunk's update run a fixed number of
  passes per call ("Timing");
- the report (:mod:`.rig_report`): pure functions from the estimator's
  values (:class:`~.rig_estimator.RigSummary`) to a line for a person, a
  recommendation and the pose records' status.

Modules
-------
The rest of the refinement: the error state, the rig as estimated and the
projections' derivatives (:mod:`.rig_state`); the error model, the
readout's prior and the error model's scale the data teach
(:mod:`.rig_priors`); the frames kept and their velocities
(:mod:`.rig_frames`); the chunk solve's steps and the definiteness of every
covariance (:mod:`.rig_solve`); the settings (:mod:`.rig_refine_config`).
Their public names are importable from here too.
"""
from __future__ import annotations

import numpy as np

from . import rig_report
from .rig_estimator import RigEstimator
from .rig_frames import _INDEPENDENT
from .rig_priors import (READOUT_ACTIVE_FRACTION, READOUT_PRIOR_UNKNOWN, RigErrorModel, readout_prior,
                         scaled_error_distribution)
from .rig_refine_config import RigRefineConfig
from .rig_schedule import SolveScheduler
from .rig_solve import SKIP_INCONSISTENT, SKIP_NO_DATA, SKIP_NON_FINITE, SKIP_SINGULAR, SKIP_UNOBSERVABLE
from .rig_state import N_RIG, PARAMETERS, RigState, project_right, rig_jacobian_rows, row_fractions

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
    """Online estimate of the rig from the tracked frames (module docstring): the estimator, the scheduler
    and the report composed, with no state of its own.

    Parameters
    ----------
    rig, model_mm, config, error_model, offset_declared, calibration_std, readout_prior
        As :class:`~.rig_estimator.RigEstimator`'s, which keeps them.

    Attributes
    ----------
    estimator : RigEstimator
        The estimate and what it knows: the rig in use (``state``), the
        estimate, its covariance, the prior, the counts, the refitted poses;
        read them there.
    scheduler : SolveScheduler
        The frames collected into chunks and the update under way
        (``last_step.passes``: Gauss-Newton passes of the last call).
    """

    def __init__(self, rig, model_mm, config: RigRefineConfig = RigRefineConfig(),
                 error_model: RigErrorModel = RigErrorModel(), offset_declared: bool = False,
                 calibration_std: dict | None = None, readout_prior: tuple[float, float] | None = None):
        self.estimator = RigEstimator(rig, model_mm, config, error_model, offset_declared, calibration_std,
                                      readout_prior)
        self.scheduler = SolveScheduler.from_config(self.estimator, config)

    # ----------------------------------------------------------------- report
    def describe(self) -> str:
        """One line for a person: how the rig differs from rig.yaml and what the refinement is doing."""
        return rig_report.describe(self.estimator.summary(), self.estimator.config)

    def advice(self) -> str | None:
        """A recommendation to recalibrate, and what the refinement cannot fix, or None."""
        return rig_report.advice(self.estimator.summary(), self.estimator.config)

    def status(self) -> dict:
        """JSON-ready state for the pose records."""
        return rig_report.status(self.estimator.summary())

    # ----------------------------------------------------------------- frames
    def add_frame(self, t: float | None, declared_offset_s: float, centers: np.ndarray, visible: np.ndarray,
                  sigma_px: np.ndarray, R_world_G: np.ndarray, p1_mm: np.ndarray, motion_known: bool = True,
                  independent_pose: bool = False) -> bool:
        """Take one tracked frame; True when the rig in use changed (``estimator.state``,
        ``estimator.refit_poses``).

        ``centers`` (2, 5, 2) px, ``visible`` (2, 5), ``sigma_px`` (2, 5, 2)
        or (2, 5): each centre's noise, px; the pose is the tracker's.
        ``motion_known`` False: the frame's time does not describe the head's
        motion (a clock too fast, independent poses), so no velocity is taken
        from or across it; it still tells the rig's geometry, not the
        exposure offset (which is seen only through a velocity).
        The pose is taken to be fitted with the rig in use (``estimator.state``):
        velocities difference poses of one rig (as tracked, or moved onto a
        newer rig by an update). ``independent_pose``: it does not depend on
        the rig (a simulation's, another system's): used as given, never
        moved. ``t`` None: no frame to keep; the update under way still
        runs its passes.

        The call then runs ``passes_per_frame`` passes of the update under
        way, if any (module docstring, "Timing"): True when that finished it
        and the rig in use changed; ``estimator.refit_poses`` then holds the
        poses of its chunk's frames refitted with the new rig, and those of the
        frames given since (this one included), tracked with the old rig,
        moved onto the new one. A frame that completes a chunk starts its
        update, to be run by the next calls (in this one with
        ``config.synchronous``).
        """
        estimator = self.estimator
        if not estimator.config.enabled:
            return False
        frame = estimator.frame(t, declared_offset_s, centers, visible, sigma_px, R_world_G, p1_mm,
                                motion_known, _INDEPENDENT if independent_pose else estimator.versions)
        return self.scheduler.add(frame).changed

    def flush(self) -> bool:
        """Finish the update under way, then use the frames waiting for a full chunk (end of a recording).
        True when the rig in use changed (``estimator.refit_poses``: the last change's)."""
        return self.scheduler.flush().changed

    def forget_motion(self) -> None:
        """The times of the frames collected so far do not describe the head's motion (a clock glitch, frames
        out of order): they keep telling the geometry, but no velocity is taken from or across them.
        An update under way keeps its chunk's velocities (taken before: a synchronous update would have
        used them already)."""
        self.scheduler.forget_motion()

    def drop_pending(self) -> None:
        """Drop the frames collected towards the next update and the update under way, if any (after a
        failure inside either); the estimate stands."""
        self.scheduler.drop()

    # ------------------------------------------------------------ the rig's changes
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
        if not self.estimator.set_readout_prior(mean_s, sd_s):
            return False
        self.scheduler.restart()
        return True

    def reset(self) -> None:
        """Back to ``rig.yaml`` and its error model (the readout's prior as set last); nothing collected."""
        self.estimator.reset()
        self.scheduler.reset()

    def widen(self, t: float | None) -> None:
        """The rig changed (frames agree only with the unrefined uncertainty): re-converge from here.
        The update under way, if any, is dropped with the frames collected (they saw the rig before)."""
        self.estimator.widen(t)
        self.scheduler.drop(recent=False)

    def bootstrap(self, frames: list, far: RigErrorModel, rounds: int = 3) -> bool:
        """Start from the rig a few frames show, when ``rig.yaml`` is too far off for its error model
        (:meth:`RigEstimator.bootstrap`). When accepted, the frames collected and any update under way
        are dropped (they were tracked with the old rig)."""
        if not self.estimator.bootstrap(frames, far, rounds):
            return False
        self.scheduler.drop()
        return True
