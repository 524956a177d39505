"""The rig as the glasses see it: an error model of ``rig.yaml`` and its online refinement.

A real rig is not the one its ``rig.yaml`` describes: the bar gets bumped
(the right camera turns by a fraction of a degree), a board printed at the
wrong scale makes the baseline a few percent off, a focal length is poorly
determined, and two webcams without hardware sync expose milliseconds apart.
The five markers are a rigid object of known size seen by both cameras, so
every tracked frame constrains the rig.

Error state (9 parameters, relative to the current estimate)
--------------------------------------------------------------
``ω`` (3, rad)
    Turn of the right camera about its own centre, in its frame:
    ``R ← exp([ω]×) R``, ``T ← exp([ω]×) T``.
``τ`` (3, mm)
    Shift of the right camera's translation: ``T ← T + τ`` (a baseline
    scale is ``τ`` along ``T``).
``s`` (1)
    Log scale of the right camera's focal lengths: ``fx, fy ← e^s fx, e^s fy``.
    The left camera's focal length is the reference: together with the
    markers' size it fixes the depth scale, and a common focal scale of both
    cameras is observable only through perspective, which five markers 14 cm
    apart at 65 cm barely show.
``δt`` (1, s)
    Exposure of the right image minus that of the left one, added to what
    ``times.csv`` or the driver says (``t_right``).
``ρ`` (1, s)
    Readout time of the cameras' rolling shutter: the time from the
    exposure of an image's first row to that of its last (0: a global
    shutter; USB webcams 15-33 ms). Both cameras are taken to be the same
    model with the same readout. A frame's time (``t``, and ``t_right``)
    is the exposure of the image's MIDDLE row: row ``r`` of an image ``H``
    rows high (``rig.image_size`` is (width, height)) is exposed at
    ``t + (r − (H−1)/2) ρ/(H−1)``. Each marker centre is the model point
    moved by the head's motion over that time (the centre's measured row
    gives its time: known, and no circular dependency), so ρ is seen only
    when the head moves, through how the markers' rows spread in time
    (a time common to all of a frame's markers is a pose). Its prior
    (:func:`readout_prior`) comes from the frame period (most webcams read
    out for ~92% of it) or from the user.

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

The rig's error for the uncertainty of V
----------------------------------------
:meth:`RigRefiner.cov` (P + ddᵀ) keeps the error model as it is: what the
checks must allow. The covariance of V takes the rig in use's error as the
data know it (:meth:`RigRefiner.error_distribution`): the error model's
scale (how far off this calibration is, against calibrations in general)
learnt from how far the data find the rig from rig.yaml (hierarchical
Bayes, :func:`scaled_error_distribution`), the data's noise checked against
the updates' innovations (:meth:`RigRefiner.data_scale`), and a mean: what
the rig in use is off by. A right rig.yaml's share shrinks as the data
confirm it; a wrong one's stays P + ddᵀ.

Definiteness
------------
Every covariance the refiner keeps or hands out (the prior of a chunk, its
posterior, :meth:`RigRefiner.cov`) is symmetric positive definite by
construction: symmetrized, and its eigenvalues, in units of the prior's σ
per component, floored (:func:`_positive_definite`). The floor (1e-9 of the
prior's variance, raised where rounding in the prior's own units would
otherwise reach it) is far below what the drift adds per chunk, so it only
acts where arithmetic alone would lose definiteness: identical
timestamps (no drift), a chunk that teaches some direction almost
perfectly. A chunk whose system is singular, ill-conditioned or
non-finite, or which teaches nothing observable, gives no update: the
estimate and its covariance stay as they were, and the chunk is counted in
:attr:`RigRefiner.skipped_chunks` by reason.
"""
from __future__ import annotations

import copy
import math
from collections import Counter, deque
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.linalg

from .. import io
from .motion import pose_rates

PARAMETERS = ("turn_x_rad", "turn_y_rad", "turn_z_rad", "shift_x_mm", "shift_y_mm", "shift_z_mm",
              "log_focal_right", "time_offset_s", "readout_s")
N_RIG = len(PARAMETERS)
_TURN, _SHIFT, _FOCAL, _OFFSET, _READOUT = slice(0, 3), slice(3, 6), 6, 7, 8
# The parameters a calibration gets more or less right (error_distribution learns their error model's
# scale): the right camera's turn, shift and focal length.
_GEOMETRY = np.arange(N_RIG) < 7

# A webcam's sensor reads its rows out over the active part of the frame
# period and idles over the vertical blanking: active rows / total rows is
# typically ~0.92 (e.g. 480 of 525 lines for VGA timing, 720 of 750 for
# 720p, 1080 of 1125 for 1080p), so the readout is ~92% of the frame period.
READOUT_ACTIVE_FRACTION = 0.92
# The readout's prior until the frame period (or the user) tells better:
# centred on a global shutter, wide enough for any webcam's 15-33 ms.
READOUT_PRIOR_UNKNOWN = (0.0, 0.015)


def readout_prior(frame_period_s: float | None, user_readout_s: float | None) -> tuple[float, float]:
    """Prior (mean, σ), s, of the cameras' rolling-shutter readout time.

    A value the user gives (``user_readout_s``; 0 = global shutter
    cameras) is taken as known: σ 5% of it or 0.5 ms, whichever is larger
    (0.2 ms for a global shutter). Else, from the frame period: mean =
    period × :data:`READOUT_ACTIVE_FRACTION`, σ 50% of that (cameras read
    out faster than their frame rate needs, and some drivers add blanking).
    Neither known (or not finite and > 0): :data:`READOUT_PRIOR_UNKNOWN`.
    """
    if user_readout_s is not None and math.isfinite(user_readout_s) and user_readout_s >= 0:
        if user_readout_s == 0:
            return 0.0, 2e-4
        return float(user_readout_s), max(0.05 * float(user_readout_s), 5e-4)
    if frame_period_s is not None and math.isfinite(frame_period_s) and frame_period_s > 0:
        mean = READOUT_ACTIVE_FRACTION * float(frame_period_s)
        return mean, 0.5 * mean
    return READOUT_PRIOR_UNKNOWN

# Smallest eigenvalue of a covariance, in units of the prior's variance per
# component (σ ≥ 3e-5 of the prior's σ): far below the drift one chunk adds
# (~1e-5..1e-3 of the prior's variance), so it acts only where arithmetic
# would otherwise lose definiteness.
_VARIANCE_FLOOR = 1e-9
# Eigenvalues within this many rounding errors of the largest are not
# trusted (see _positive_definite).
_ROUNDING_MARGIN = 64 * np.finfo(float).eps
# A frame's pose block (its 6x6 information, unit diagonal) or the rig's
# system (in units of the prior) whose smallest eigenvalue is below this
# fraction of its largest is ill-conditioned: the chunk gives no update.
_MIN_CONDITION = 1e-12

# 99.9th percentile of χ² with 7 degrees of freedom (scipy.stats.chi2.ppf(0.999, 7)): the most a
# bootstrap may move the rig, in its far prior's σ (turn 3, shift 3, focal 1).
_CHI2_7DOF_999 = 24.32
# Most a centre of a bootstrap's frames may be off its joint fit, in its σ (both coordinates).
_BOOTSTRAP_MAX_Z = 5.0

# The error model's scale τ (its σ times τ) over which scaled_error_distribution averages:
# log-spaced, from a rig a ten-thousandth as far off as the error model says to one ten times as far
# (τ's half-normal prior leaves nothing beyond; the data never need it: a parameter they teach keeps
# its posterior whatever τ).
_SCALE_GRID = np.exp(np.linspace(math.log(1e-4), math.log(10.0), 81))

# RigRefiner.data_scale: each update's normalized innovation squared is kept with this weight per update
# after it (forgetting over ~10 updates, ~3 s), and the sums start from this many degrees of freedom at 1.
_CONSISTENCY_KEEP = 0.9
_CONSISTENCY_PRIOR_DOF = 10.0

# Reasons for a chunk without an update (keys of RigRefiner.skipped_chunks).
SKIP_UNOBSERVABLE = "nothing observable"        # e.g. a still head: the usual case, not a fault
SKIP_NO_DATA = "no usable centres"
SKIP_NON_FINITE = "non-finite terms"
SKIP_SINGULAR = "singular or ill-conditioned system"
SKIP_INCONSISTENT = "inconsistent with the rig"  # residuals far beyond the noise, and no bump explains them


class _SkipChunk(Exception):
    """A chunk that cannot update the rig; ``args[0]`` is one of the ``SKIP_*`` reasons."""


def _positive_definite(M: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``M`` (k, k) made symmetric positive definite: symmetrized, eigenvalues floored in units of ``scale``.

    ``scale`` (k,) is the prior's σ per component (rad, mm, log focal, s):
    in those units the eigenvalues are floored at ``_VARIANCE_FLOOR``, or
    higher where rounding in ``M``'s own units could reach them
    (``_ROUNDING_MARGIN`` × the largest eigenvalue × the spread of the
    prior's variances), so that ``eigvalsh`` and ``cholesky`` of the result
    see it positive definite, not only exact arithmetic. A matrix already
    above the floor is returned symmetrized, otherwise unchanged. Raises
    ``_SkipChunk`` for a non-finite ``M`` (or one eigh cannot decompose).
    """
    if not np.isfinite(M).all():
        raise _SkipChunk(SKIP_NON_FINITE)
    sym = 0.5 * (M + M.T)
    units = np.outer(scale, scale)
    try:
        lam, U = np.linalg.eigh(sym / units)
    except np.linalg.LinAlgError:           # eigh did not converge (finite but absurd values)
        raise _SkipChunk(SKIP_SINGULAR) from None
    spread = float(scale.max() / scale.min()) ** 2
    floor = max(_VARIANCE_FLOOR, _ROUNDING_MARGIN * spread * float(lam[-1]))
    if lam[0] >= floor:
        return sym
    out = (U * np.maximum(lam, floor)) @ U.T * units
    return 0.5 * (out + out.T)


def scaled_error_distribution(P: np.ndarray, prior: np.ndarray, estimate_from_reference: np.ndarray,
                              in_use_from_reference: np.ndarray, scaled: np.ndarray,
                              drift: np.ndarray | None = None, data_scale: float = 1.0):
    """Mean (k,) and covariance (k, k) of the error of the rig in use (the true rig minus it, error
    state) when the error model's scale is learnt from the data too (hierarchical Bayes).

    The refinement's estimate and its covariance ``P`` (k, k) are the
    posterior of the rig under the prior ``prior`` (k, k), centred on the
    reference (rig.yaml, the readout's prior mean): the data's information
    on the rig is P⁻¹ − prior⁻¹, and its information vector P⁻¹ (estimate −
    reference). The error model's σ of the parameters ``scaled`` (k,) bool
    (the geometry: how far a bumped bar turns, how far off a printed board
    is) are a guess about calibrations in general; this rig's may be
    smaller (a right calibration) or larger: they are taken as τ times the
    model's, τ half-normal with scale 1 (E τ² = 1: without data, the error
    model as it is). The data give τ's likelihood (the marginal likelihood
    of the linear-Gaussian model, on a grid :data:`_SCALE_GRID`), and the
    rig's posterior is averaged over τ's posterior: for each τ, Gaussian
    with covariance (S(τ)⁻¹ + data)⁻¹, S(τ) the prior with the scaled
    parameters' σ times τ, and mean that times the information vector. The
    other parameters (the exposure offset, the readout: priors that only
    say how little is known) keep their prior. A rig the data find off by
    as much as the error model says (or more) keeps P and the estimate; one
    the data find where rig.yaml put it, within their noise, shrinks both
    to what a rig right all along would leave. ``data_scale``: the data's
    noise over what the refinement assumed (a variance ratio; the data's
    information is divided by it). ``drift`` (k, k), diagonal: the drift
    since the refinement began, which τ does not scale, part of the prior
    (the posterior P is taken to be the prior plus the drift, narrowed by the
    data).

    ``estimate_from_reference``, ``in_use_from_reference`` (k,): the
    estimate and the rig in use minus the reference (error state). Works in
    units of the prior (whitened by its Cholesky factor; ``prior`` is
    diagonal, so the whitening keeps ``scaled`` apart). With τ = 1 and
    ``data_scale`` 1 the result is the refinement's own: P, and the
    estimate minus the rig in use.
    """
    k = len(P)
    L0 = np.linalg.cholesky(prior)
    Li = scipy.linalg.solve_triangular(L0, np.eye(k), lower=True)
    # The drift since the start, in units of the prior: added to the prior's variances (P0 and the drift
    # are diagonal), whatever τ (a rig's drift is not its calibration's error).
    q = np.zeros(k) if drift is None else np.maximum(np.diag(Li @ drift @ Li.T), 0.0)
    A = Li @ P @ Li.T
    a, U = np.linalg.eigh(0.5 * (A + A.T))
    a = np.maximum(a, 1e-15)
    # The data's information: P⁻¹ less the prior's (with the drift), whitened; where P is the prior's or
    # wider (an inflated posterior, a widened prior) nothing was learnt.
    info = (U / a) @ U.T - np.diag(1.0 / (1.0 + q))
    lam, V = np.linalg.eigh(0.5 * (info + info.T))
    if not np.any(lam > 0.0):
        # No data: the error model as it is (τ's prior has E τ² = 1).
        return estimate_from_reference - in_use_from_reference, 0.5 * (P + P.T)
    info = (V * (np.maximum(lam, 0.0) / data_scale)) @ V.T
    b = (U / (a * data_scale)) @ (U.T @ (Li @ estimate_from_reference))   # its information vector
    s = Li @ in_use_from_reference
    tau2 = _SCALE_GRID ** 2
    var = np.where(np.asarray(scaled, bool)[None, :], tau2[:, None], 1.0) + q[None, :]   # (grid, k) prior
    root = np.sqrt(var)
    # (S⁻¹ + info)⁻¹ = D (I + D info D)⁻¹ D with D = S^½; det(I + D info D) gives the likelihood.
    M = np.eye(k)[None] + root[:, :, None] * info[None] * root[:, None, :]
    Lm = np.linalg.cholesky(M)
    logdet = 2.0 * np.log(np.diagonal(Lm, axis1=1, axis2=2)).sum(axis=1)
    Minv = np.linalg.inv(M)
    cov = root[:, :, None] * Minv * root[:, None, :]                      # (grid, k, k)
    mean = cov @ b                                                          # (grid, k)
    log_w = -0.5 * logdet + 0.5 * mean @ b - 0.5 * tau2 + np.log(_SCALE_GRID)   # half-normal(1), d log τ
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    err = mean - s[None, :]                                                 # truth − rig in use
    first = w @ err
    second = np.einsum("g,gij->ij", w, cov) + (err * w[:, None]).T @ err
    spread = second - np.outer(first, first)
    out = L0 @ spread @ L0.T
    return L0 @ first, 0.5 * (out + out.T)


@dataclass
class _Solution:
    """What :meth:`RigRefiner._solve` found for a chunk."""

    increment: np.ndarray       # (9,) rig error-state increment
    posterior: np.ndarray       # (9, 9) its covariance, SPD, inflated by the noise scale
    chi2: float                 # Cauchy-weighted χ² of the data rows
    rows_used: int              # centre coordinates used
    noise_scale: float          # the median centre's χ² per degree of freedom
    refit: dict                 # {t: (R_world_G, p1)} of the chunk's poses refitted with the increment
    moved: np.ndarray           # (9,) bool: parameters the increment was free to move


def _eliminate_poses(A: np.ndarray, B: np.ndarray, g: np.ndarray):
    """A⁻¹ B (n, 6, 9) and A⁻¹ g (n, 6) for the frames' pose blocks A (n, 6, 6), B (n, 6, 9), g (n, 6).

    Each block is scaled to unit diagonal and inverted by its
    eigendecomposition (batched, no loop). Raises
    ``_SkipChunk(SKIP_SINGULAR)`` for a pose parameter no centre moves, or
    a block whose smallest eigenvalue is not above ``_MIN_CONDITION`` of its
    largest (too few centres in a frame, degenerate geometry).
    """
    d = np.sqrt(np.diagonal(A, axis1=1, axis2=2))                   # (n, 6)
    if not np.all(d > 0):
        raise _SkipChunk(SKIP_SINGULAR)
    units = d[:, :, None] * d[:, None, :]
    lam, U = np.linalg.eigh(A / units)
    if not np.all(lam[:, 0] > _MIN_CONDITION * lam[:, -1]):      # (the largest is ≥ 1: unit diagonal)
        raise _SkipChunk(SKIP_SINGULAR)
    A_inv = (U / lam[:, None, :]) @ np.swapaxes(U, 1, 2) / units
    return A_inv @ B, np.einsum("nij,nj->ni", A_inv, g)


def _whitened_inverse(S: np.ndarray) -> np.ndarray:
    """Inverse (k, k) of the rig's system S in units of the prior (S = I + the data's information there).

    By eigendecomposition; raises ``_SkipChunk`` when S is not finite, or
    its smallest eigenvalue is not above ``_MIN_CONDITION`` of its largest
    (the chunk would pin some direction to a millionth of its prior σ:
    absurd data, not a measurement).
    """
    if not np.isfinite(S).all():
        raise _SkipChunk(SKIP_NON_FINITE)
    lam, U = np.linalg.eigh(0.5 * (S + S.T))
    if not lam[0] > _MIN_CONDITION * lam[-1]:
        raise _SkipChunk(SKIP_SINGULAR)
    inv = (U / lam) @ U.T
    return 0.5 * (inv + inv.T)


@dataclass(frozen=True)
class RigErrorModel:
    """How far a rig may be from its ``rig.yaml``: the prior of the refinement (1σ per axis).

    Attributes
    ----------
    turn_deg : float
        Turn of the right camera since calibration (a bumped bar), deg.
    shift_fraction : float
        Error of the translation, fraction of the baseline (a board printed
        at the wrong scale, a poor calibration).
    focal_fraction : float
        Relative error of the right camera's focal length.
    offset_undeclared_s, offset_declared_s : float
        Exposure offset between the cameras when ``times.csv``/the driver
        gives no right time (webcams without sync), and when it does.
    readout_s : float or None
        The cameras' rolling-shutter readout time if the user knows it
        (0: global shutter cameras), s; None: from the frame period
        (:func:`readout_prior`, :meth:`RigRefiner.set_readout_prior`).
    """

    turn_deg: float = 0.5
    shift_fraction: float = 0.02
    focal_fraction: float = 0.01
    offset_undeclared_s: float = 0.025
    offset_declared_s: float = 0.002
    readout_s: float | None = None

    def readout_prior(self, frame_period_s: float | None = None) -> tuple[float, float]:
        """Prior (mean, σ), s, of the readout time (:func:`readout_prior` with the user's value, if any)."""
        return readout_prior(frame_period_s, self.readout_s)

    def covariance(self, rig, offset_declared: bool, calibration_std: dict | None = None,
                   readout_sd_s: float | None = None) -> np.ndarray:
        """Prior covariance (9, 9) of the error state; the calibration's own σ (if written) add in quadrature.

        ``readout_sd_s``: the readout's σ, s (default: :meth:`readout_prior`'s
        before the frame period is known)."""
        baseline = float(np.linalg.norm(rig.T))
        if readout_sd_s is None:
            readout_sd_s = self.readout_prior()[1]
        sd = np.array([math.radians(self.turn_deg)] * 3 + [self.shift_fraction * baseline] * 3
                      + [self.focal_fraction, self.offset_declared_s if offset_declared else self.offset_undeclared_s,
                         readout_sd_s])
        if calibration_std:
            # (headplod.io.rig_calibration_std.) The calibration's σ of the rotation
            # vector's components stands, at this size, for the σ of a small turn
            # about each axis (their difference is well below the prior's).
            rot = calibration_std.get("calibration_std_rotation_deg")
            if rot is not None:
                sd[_TURN] = np.hypot(sd[_TURN], np.radians(float(np.max(rot))))
            shift = calibration_std.get("calibration_std_translation_mm")
            if shift is not None:
                sd[_SHIFT] = np.hypot(sd[_SHIFT], np.asarray(shift, float).reshape(3))
            right = calibration_std.get("calibration_std_right")
            if right is not None:
                sd[_FOCAL] = math.hypot(sd[_FOCAL], float(right[0]) / float(rig.K2[0, 0]))
        return np.diag(sd ** 2)


@dataclass(frozen=True)
class RigRefineConfig:
    """Settings of the online rig refinement, each with its unit.

    Attributes
    ----------
    enabled : bool
        Refine the rig from the tracked frames (``track --refine-rig``).
    chunk_frames : int
        Tracked frames per update (an update costs one small solve).
    iterations : int
        Gauss-Newton steps per update.
    cauchy_scale : float
        Residual (in units of its σ) beyond which a centre's weight falls
        (Cauchy loss): a glint or a bad frame does not pull the rig.
    min_sigma_px : float
        Floor of a centre's σ, px.
    drift_turn_deg_per_sqrt_s, drift_shift_mm_per_sqrt_s, drift_focal_per_sqrt_s,
    drift_offset_s_per_sqrt_s, drift_readout_s_per_sqrt_s : float
        Random-walk drift of the rig allowed between updates: what lets the
        estimate follow a slowly changing rig (warming cameras, a webcam's
        clock drift).
    first_at_once : bool
        Solve the first update at once, in the call that completes its
        chunk: until then the rig is only rig.yaml, and frames that only a
        refined rig can tell from a glint are withheld (one frame a run
        pays a solve, a few ms; the 99th percentile is not moved).
    refit_velocity_change : float
        After a chunk's solve, its frames' velocities are taken again from
        the poses it refitted; when one changed by more than this (rad/s of
        the turn rate, or 100 times it in mm/s: 6°/s, 10 mm/s; a refitted
        pose's own noise makes up to ~3°/s), the chunk is solved again with
        them.
    observable_fraction : float
        A parameter is refined only when the chunk's information on it is at
        least this fraction of the prior's.
    inconsistency : float
        A chunk whose noise scale (the median centre's standardized χ²,
        per degree of freedom: robust to the few glints) exceeds this is
        tested for a change of the rig (a bump).
    publish_sigma : float
        The rig in use follows the refinement's estimate when they differ by
        more than this many σ of the estimate along some direction.
    bump_evidence : float
        Fall of the chunk's cost (χ², 9 dof) that re-solving with the
        widened prior must bring to accept a change of the rig.
    max_gap_frames : float
        Velocities (for the time offset) come from neighbours at most this
        many frame periods apart.
    recalibrate_turn_deg, recalibrate_scale, recalibrate_offset_s : float
        Beyond these, the status recommends recalibrating.
    synchronous : bool
        Solve a chunk in the ``add_frame`` call that completes it (offline
        use, tests) instead of over the next calls (module docstring,
        "Timing").
    passes_per_frame : int
        Gauss-Newton passes (each over all of a chunk's frames) of the update
        under way run per ``add_frame`` call: a chunk's update takes
        ``iterations + 1`` passes (twice that to test for a bump).
    """

    enabled: bool = True
    chunk_frames: int = 8
    iterations: int = 4
    cauchy_scale: float = 3.0
    min_sigma_px: float = 0.02
    drift_turn_deg_per_sqrt_s: float = 0.005
    drift_shift_mm_per_sqrt_s: float = 0.02
    drift_focal_per_sqrt_s: float = 1e-4
    drift_offset_s_per_sqrt_s: float = 2e-4
    drift_readout_s_per_sqrt_s: float = 1e-5
    refit_velocity_change: float = 0.1
    first_at_once: bool = True
    observable_fraction: float = 0.05
    inconsistency: float = 4.0
    publish_sigma: float = 3.0
    bump_evidence: float = 60.0
    max_gap_frames: float = 2.5
    recalibrate_turn_deg: float = 1.0
    recalibrate_scale: float = 0.03
    recalibrate_offset_s: float = 0.02
    synchronous: bool = False
    passes_per_frame: int = 2


@dataclass
class _Frame:
    t: float
    declared_offset_s: float      # t_right − t from times.csv / the driver (0 when not given)
    centers: np.ndarray           # (2, 5, 2) px
    visible: np.ndarray           # (2, 5) bool
    sigma: np.ndarray             # (2, 5, 2) px per coordinate
    R: np.ndarray                 # (3, 3) tracked R_world_G
    p1: np.ndarray                # (3,) tracked P1, mm
    omega: np.ndarray | None = None   # (3,) head angular velocity, world, rad/s
    velocity: np.ndarray | None = None  # (3,) P1 velocity, mm/s
    motion_known: bool = True     # False: its time does not fit the motion; no velocity from or across it
    rig_version: int = 0          # RigRefiner.versions of the rig its pose was fitted with (_INDEPENDENT: none)
    refit: tuple | None = None    # (version, R, p1): its pose refitted with a newer rig, by an update

    def newest(self):
        """(R, p1): the pose fitted with the newest rig known for this frame."""
        if self.refit is not None and self.refit[0] > self.rig_version:
            return self.refit[1], self.refit[2]
        return self.R, self.p1


# _Frame.rig_version of a pose that does not depend on the rig (add_frame(independent_pose=True)).
_INDEPENDENT = -1


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]× for v (..., 3) → (..., 3, 3)."""
    v = np.asarray(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


class RigState:
    """The rig as currently estimated: the right camera's R, T, focal scale, the exposure offset and readout.

    Attributes
    ----------
    R : (3, 3), T : (3,) mm
        World (left camera) → right camera.
    log_focal : float
        Log scale of the right camera's focal lengths relative to ``rig.yaml``.
    offset_s : float
        Right exposure minus left, beyond what the timestamps say, s.
    readout_s : float
        Rolling-shutter readout time of both cameras (first row to last), s.
    """

    def __init__(self, rig, readout_s: float = 0.0):
        self.calibrated = rig
        self.R = np.asarray(rig.R, np.float64).copy()
        self.T = np.asarray(rig.T, np.float64).reshape(3).copy()
        self.log_focal = 0.0
        self.offset_s = 0.0
        self.readout_s = float(readout_s)

    def apply(self, increment: np.ndarray) -> None:
        """Add an error-state increment (9,) to the estimate."""
        turn = cv2.Rodrigues(np.asarray(increment[_TURN], np.float64))[0]
        self.R = turn @ self.R
        self.R = cv2.Rodrigues(cv2.Rodrigues(self.R)[0])[0]
        self.T = turn @ self.T + increment[_SHIFT]
        self.log_focal += float(increment[_FOCAL])
        self.offset_s += float(increment[_OFFSET])
        self.readout_s += float(increment[_READOUT])

    def K2(self) -> np.ndarray:
        K = np.asarray(self.calibrated.K2, np.float64).copy()
        K[0, 0] *= math.exp(self.log_focal)
        K[1, 1] *= math.exp(self.log_focal)
        return K

    def error_from(self, other: "RigState") -> np.ndarray:
        """The error-state increment (9,) that moves ``other`` onto this estimate."""
        turn = cv2.Rodrigues(self.R @ other.R.T)[0].ravel()
        out = np.zeros(N_RIG)
        out[_TURN] = turn
        out[_SHIFT] = self.T - cv2.Rodrigues(turn)[0] @ other.T
        out[_FOCAL] = self.log_focal - other.log_focal
        out[_OFFSET] = self.offset_s - other.offset_s
        out[_READOUT] = self.readout_s - other.readout_s
        return out

    def moved(self, increment: np.ndarray) -> "RigState":
        """A copy moved by an error-state increment (9,); this estimate is left as it is."""
        out = copy.copy(self)
        out.apply(increment)
        return out

    def rig(self):
        """This estimate as a :class:`headplod.io.Rig` (intrinsics of the left camera and distortions unchanged)."""
        cal = self.calibrated
        extra = dict(cal.extra)
        extra["refined_time_offset_ms"] = round(self.offset_s * 1e3, 4)
        extra["refined_readout_ms"] = round(self.readout_s * 1e3, 4)
        if cal.path:
            extra["refined_from"] = str(cal.path)
        return io.Rig(cal.image_size, cal.K1, cal.D1, self.K2(), cal.D2, self.R, self.T, extra=extra)

    def differences(self) -> dict:
        """How the estimate differs from ``rig.yaml``: turn (deg), baseline scale, focal scale, offset (ms),
        and the rolling shutter's readout (ms)."""
        cal = self.calibrated
        turn = cv2.Rodrigues(self.R @ np.asarray(cal.R, np.float64).T)[0].ravel()
        centre = -self.R.T @ self.T
        centre_cal = -np.asarray(cal.R).T @ np.asarray(cal.T).reshape(3)
        return {"turn_deg": float(np.degrees(np.linalg.norm(turn))),
                "turn_axis": (turn / max(np.linalg.norm(turn), 1e-12)).tolist(),
                "baseline_scale": float(np.linalg.norm(self.T) / np.linalg.norm(cal.T)),
                "centre_shift_mm": float(np.linalg.norm(centre - centre_cal)),
                "focal_scale": float(math.exp(self.log_focal)),
                "offset_ms": self.offset_s * 1e3,
                "readout_ms": self.readout_s * 1e3}


def project_right(points_world: np.ndarray, R: np.ndarray, T: np.ndarray, K: np.ndarray, D: np.ndarray):
    """Right-camera projections (n, 2) px and their derivatives.

    Returns
    -------
    px : (n, 2)
    d_cam : (n, 2, 3)
        ∂px/∂X_cam (the right camera's frame, mm).
    d_logf : (n, 2)
        ∂px/∂s for a common log scale s of fx and fy.
    cam : (n, 3)
        The points in the right camera's frame, mm.
    """
    cam = points_world @ R.T + T
    px, jac = cv2.projectPoints(cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    jac = jac.reshape(-1, 2, jac.shape[1])
    d_cam = jac[:, :, 3:6]
    d_logf = jac[:, :, 6] * K[0, 0] + jac[:, :, 7] * K[1, 1]
    return px.reshape(-1, 2), d_cam, d_logf, cam


def row_fractions(rows_px: np.ndarray, image_height: int | None) -> np.ndarray:
    """Each centre's exposure relative to its frame's time, in readouts: (r − (H−1)/2) / (H−1).

    ``rows_px`` (any shape): the centres' measured rows (y), px. A
    non-finite row (a centre not seen), or no height (H ≤ 1), gives 0: the
    frame's time; a row beyond the image (no measured centre is) its edge's,
    ±0.5.
    """
    rows = np.asarray(rows_px, np.float64)
    if image_height is None or not image_height > 1:
        return np.zeros(rows.shape)
    frac = (rows - 0.5 * (image_height - 1)) / (image_height - 1)
    return np.where(np.isfinite(frac), np.clip(frac, -0.5, 0.5), 0.0)


def _stereo_terms(world: np.ndarray, motion: np.ndarray, frac: np.ndarray, right_dt, state: RigState,
                  K1: np.ndarray, D1: np.ndarray, D2: np.ndarray, left: bool = True):
    """Both cameras' projections of points seen through rolling shutters, and their derivatives.

    ``world`` (k, 3) mm: the points at the frame's time (its images' middle
    rows); ``motion`` (k, 3) mm/s: their world velocity (zeros: unknown);
    ``frac`` (2, k): each centre's row time in readouts (:func:`row_fractions`);
    ``right_dt`` (k,) or scalar, s: the right image's time minus the left's
    (declared + offset). Left camera: the points at ``frac[0] ρ``; right:
    at ``right_dt + frac[1] ρ`` (ρ = ``state.readout_s``), moved linearly.

    Returns px (2, k, 2), ∂px/∂(world point) (2, k, 2, 3), and
    ∂px/∂(rig error state) (2, k, 2, 9): the left rows' only non-zero column
    is the readout's. ``left`` False: the left camera's px and derivatives
    are left NaN, its rig rows zero (for callers that need the right's only).
    """
    k = len(world)
    readout = state.readout_s
    px = np.full((2, k, 2), np.nan)
    d_world = np.full((2, k, 2, 3), np.nan)
    J_rig = np.zeros((2, k, 2, N_RIG))
    if left:
        world_l = world + (frac[0] * readout)[:, None] * motion
        pl, jac = cv2.projectPoints(world_l.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K1, D1)
        d_left = jac.reshape(k, 2, -1)[..., 3:6]                        # the left camera's frame is the world's
        px[0], d_world[0] = pl.reshape(k, 2), d_left
        J_rig[0, :, :, _READOUT] = np.einsum("kij,kj->ki", d_left, motion) * frac[0][:, None]
    world_r = world + (right_dt + frac[1] * readout)[:, None] * motion
    pr, d_cam, d_logf, cam = project_right(world_r, state.R, state.T, state.K2(), D2)
    px[1], d_world[1] = pr, d_cam @ state.R
    J_rig[1] = _right_rig_columns(d_cam, d_logf, cam, state.R, motion, frac[1])
    return px, d_world, J_rig


def rig_jacobian_rows(R_world_G: np.ndarray, p1_mm: np.ndarray, model_mm: np.ndarray, state: RigState,
                      D2: np.ndarray, right_dt_s: float = 0.0, omega: np.ndarray | None = None,
                      velocity: np.ndarray | None = None, rows_px: np.ndarray | None = None,
                      image_height: int | None = None) -> np.ndarray:
    """∂(projected centre)/∂(rig error state) at a pose: (2, 5, 2, 9).

    ``omega`` (rad/s) and ``velocity`` (mm/s) are the head's motion in the
    world frame; without them the time offset's and the readout's columns
    are zero. ``right_dt_s``: the right image's time minus the left's (the
    declared offset plus the estimated one). ``rows_px`` (2, 5): the
    centres' measured rows (y, px; NaN for a centre not seen), with
    ``image_height`` (px; default ``state.calibrated.image_size[1]``):
    each point is moved by the head's motion over its row's time in each
    camera (:func:`_stereo_terms`, with ``state.readout_s``), and the
    readout's column is filled in both cameras. Without ``rows_px`` the
    left rows are zero and the readout's column too (no rolling shutter
    modelled), as before the readout was a parameter.
    """
    lever = model_mm @ R_world_G.T
    world = lever + p1_mm
    m = len(model_mm)
    moving = omega is not None and velocity is not None
    motion = np.cross(omega, lever) + velocity if moving else np.zeros((m, 3))
    if rows_px is not None and moving:
        if image_height is None:
            image_height = state.calibrated.image_size[1]
        frac = row_fractions(np.asarray(rows_px, np.float64).reshape(2, m), image_height)
    else:
        frac = np.zeros((2, m))
    cal = state.calibrated
    _, _, J_rig = _stereo_terms(world, motion, frac, right_dt_s, state, np.asarray(cal.K1, np.float64),
                                np.asarray(cal.D1, np.float64), D2, left=rows_px is not None and moving)
    return J_rig


def _right_rig_columns(d_cam, d_logf, cam, R_right, motion, frac=None):
    """∂(right projections)/∂(rig error state) (n, 2, 9) from :func:`project_right`'s derivatives.

    ``motion`` (n, 3), mm/s: each point's world velocity (None: the time
    offset's and readout's columns are zero); ``frac`` (n,): its row's
    time in readouts (:func:`row_fractions`; None: the readout's column is
    zero).
    """
    cols = np.zeros(d_cam.shape[:2] + (N_RIG,))
    cols[:, :, _TURN] = np.einsum("nij,njk->nik", d_cam, -_skew(cam))
    cols[:, :, _SHIFT] = d_cam
    cols[:, :, _FOCAL] = d_logf
    if motion is not None:
        speed = np.einsum("nij,jk,nk->ni", d_cam, R_right, motion)        # ∂px/∂t
        cols[:, :, _OFFSET] = speed
        if frac is not None:
            cols[:, :, _READOUT] = speed * np.asarray(frac)[:, None]
    return cols


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
                steps = self._solve(chunk, prior)
                while True:
                    try:
                        next(steps)
                    except StopIteration as end:
                        solution = end.value
                        break
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
        data = _ChunkData.of(chunk, self.calibrated.image_size[1])
        res = self._chunk_terms(data, np.zeros((len(chunk), 6)), estimate)[0]
        z = np.hypot(*np.moveaxis(res / data.sigma, -1, 0))[data.visible]
        if not (np.isfinite(z).all() and z.max() <= _BOOTSTRAP_MAX_Z):
            return False
        change = estimate.error_from(start)
        if not float(change @ np.linalg.lstsq(prior, change, rcond=None)[0]) <= _CHI2_7DOF_999:
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
        self._velocities(chunk)
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

    def _velocities(self, chunk: list[_Frame]) -> None:
        """Head velocities by central differences of the tracked poses (one-sided at the ends).

        The poses differenced are of one rig (a change of the rig is not
        motion): a neighbour's as tracked, or as refitted by the update that
        changed the rig (:attr:`_Frame.refit`), whichever was fitted with the
        rig of the frame's own pose. A frame with no such neighbour (a lone
        frame tracked with the old rig while the update that changed it ran)
        takes its neighbours' poses as tracked all the same: a rig's step is
        a smaller error than no velocity at all, which would tell the solve
        the head stood still while the right image was exposed later.
        """
        frames = list(self._recent) + chunk
        times = np.array([f.t for f in frames])
        gaps = np.diff(times)
        period = float(np.median(gaps)) if len(gaps) else 0.0
        limit = self.config.max_gap_frames * period
        known = [f.motion_known for f in frames]

        def pose(f: _Frame, version: int | None):
            if version is None or f.rig_version in (version, _INDEPENDENT):
                return f.R, f.p1
            if f.refit is not None and f.refit[0] == version:
                return f.refit[1], f.refit[2]
            return None

        for i in range(len(frames) - len(chunk), len(frames)):
            if not known[i]:
                continue
            near_lo = i > 0 and known[i - 1] and 0 < times[i] - times[i - 1] <= limit
            near_hi = i + 1 < len(frames) and known[i + 1] and 0 < times[i + 1] - times[i] <= limit
            if not (near_lo or near_hi):
                continue
            f = frames[i]
            version = f.refit[0] if f.refit is not None and f.refit[0] > f.rig_version else f.rig_version
            lo = pose(frames[i - 1], version) if near_lo else None
            hi = pose(frames[i + 1], version) if near_hi else None
            if lo is None and hi is None:
                version = None                  # no neighbour of this rig: the poses as tracked
                lo = pose(frames[i - 1], None) if near_lo else None
                hi = pose(frames[i + 1], None) if near_hi else None
            a = (times[i - 1], *lo) if lo is not None else (times[i], *pose(f, version))
            b = (times[i + 1], *hi) if hi is not None else (times[i], *pose(f, version))
            f.omega, f.velocity = pose_rates(a[1], a[2], b[1], b[2], b[0] - a[0])

    def _refit_velocities(self, chunk: list[_Frame], refit: dict) -> bool:
        """The chunk's velocities as central differences of its refitted poses ({t: (R, p1)}, one rig), where a
        frame has a refitted neighbour (else its velocity stays); True when one changed by more than
        ``refit_velocity_change`` (rad/s of the turn rate, or 100x that in mm/s)."""
        times = np.array([f.t for f in chunk])
        gaps = np.diff(times)
        if not len(gaps):
            return False
        limit = self.config.max_gap_frames * float(np.median(gaps))
        new = {}
        changed = False
        for i, f in enumerate(chunk):
            if not f.motion_known or f.omega is None or f.t not in refit:
                continue
            lo = i - 1 if (i > 0 and chunk[i - 1].motion_known and chunk[i - 1].t in refit
                           and 0 < times[i] - times[i - 1] <= limit) else i
            hi = i + 1 if (i + 1 < len(chunk) and chunk[i + 1].motion_known and chunk[i + 1].t in refit
                           and 0 < times[i + 1] - times[i] <= limit) else i
            if lo == hi:
                continue
            omega, velocity = pose_rates(*refit[chunk[lo].t], *refit[chunk[hi].t], times[hi] - times[lo])
            change = max(float(np.abs(omega - f.omega).max()), float(np.abs(velocity - f.velocity).max()) / 100.0)
            changed |= change > self.config.refit_velocity_change
            new[i] = (omega, velocity)
        if changed:                  # else the velocities stay: those the solve used
            for i, (omega, velocity) in new.items():
                chunk[i].omega, chunk[i].velocity = omega, velocity
        return changed

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
        if self._refit_velocities(chunk, solution.refit):
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
        # their pose refitted with the new rig too (_velocities differences
        # poses of one rig).
        for f in chunk[-2:]:
            if f.t in solution.refit:
                f.refit = (self.versions, *solution.refit[f.t])
        self.refit_poses = {**solution.refit, **moved}
        return True

    def _count_consistency(self, prior: np.ndarray, solution: "_Solution") -> None:
        """Add an update's normalized innovation squared to the forgetting sums :meth:`data_scale` reads.

        For a consistent filter the increment Δ of an update has covariance
        prior − posterior (both (9, 9), the chunk's): Δᵀ (prior − posterior)⁺ Δ
        is χ² with as many degrees of freedom as directions the chunk taught
        (those whose variance fell by more than a thousandth of the largest
        fall, in units of the prior's σ). Counted only for updates whose
        prior was a posterior (not the error model's: there the increment
        measures how far off rig.yaml is, :func:`scaled_error_distribution`'s
        business), and not for a bump's (the rig changed).
        """
        units = np.outer(self._scale, self._scale)
        D = (prior - solution.posterior) / units
        lam, U = np.linalg.eigh(0.5 * (D + D.T))
        keep = lam > 1e-3 * max(float(lam[-1]), 0.0)
        if not keep.any() or not np.isfinite(lam).all():
            return
        z = U[:, keep].T @ (solution.increment / self._scale)
        nis = float(np.sum(z ** 2 / lam[keep]))
        if np.isfinite(nis):
            self._consistency = _CONSISTENCY_KEEP * self._consistency + np.array([nis, float(keep.sum())])

    def data_scale(self) -> float:
        """How much the data's errors exceed what the refinement assumed: a variance ratio (1: as assumed).

        Covariance matching on the updates' innovations (Mehra 1972): the
        forgetting sums (:data:`_CONSISTENCY_KEEP` per update, ~10 updates)
        of their normalized innovations squared over their degrees of
        freedom (:meth:`_count_consistency`), with a prior of
        :data:`_CONSISTENCY_PRIOR_DOF` degrees of freedom at 1. Below 1 when
        the centres' σ the chunks were weighted with overstate their noise
        (the noise model learnt while the rig was off) or the drift allowed
        overstates the rig's: the estimate then moves less than P says. It
        scales the data's information in :meth:`error_distribution` only;
        the refinement itself, its checks and :meth:`cov` keep P as it is."""
        nis, dof = self._consistency
        return float(np.clip((_CONSISTENCY_PRIOR_DOF + nis) / (_CONSISTENCY_PRIOR_DOF + dof), 0.05, 20.0))

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
        (yields) before each pass over the chunk's frames and returns the :class:`_Solution`.

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
        try:
            L = np.linalg.cholesky(prior)      # SPD by construction (_positive_definite): checked all the same
        except np.linalg.LinAlgError:
            raise _SkipChunk(SKIP_SINGULAR) from None
        L_inv = scipy.linalg.solve_triangular(L, np.eye(N_RIG), lower=True)
        prior_info = L_inv.T @ L_inv
        data = _ChunkData.of(chunk, self.image_height)
        # Which rig parameters can this chunk teach? Decided at the start (linearization point).
        rig = np.zeros(N_RIG)
        poses = np.zeros((n, 6))
        observable = confine = None
        weights = None
        for iteration in range(c.iterations + 1):
            yield
            state = self._estimate.moved(rig)
            res, J_pose, J_rig = self._chunk_terms(data, poses, state)
            self.passes += 1
            self.frame_terms += n
            sig = data.sigma
            with np.errstate(invalid="ignore"):
                z = res / sig                                    # (n, 2, m, 2) standardized
                # A centre counts when its residual and derivatives are finite
                # (a point on a camera's plane projects to inf).
                seen = (np.isfinite(z).all(axis=3) & data.visible
                        & np.isfinite(J_pose).all(axis=(3, 4)) & np.isfinite(J_rig).all(axis=(3, 4)))
                r2 = np.where(seen, (z ** 2).sum(axis=3), 0.0)          # (n, 2, m)
                if weights is None or iteration < 2:
                    weights = np.where(seen, 1.0 / (1.0 + r2 / (2 * c.cauchy_scale ** 2)), 0.0)
                # Unseen centres' rows are zeros (weight 0, and no NaN to multiply by it).
                w = np.repeat(np.where(seen, weights, 0.0)[..., None], 2, axis=3).reshape(n, -1)   # (n, k)
                r = np.where(seen[..., None], z, 0.0).reshape(n, -1)
                scaled = 1.0 / sig[..., None]
                Jp = np.where(seen[..., None, None], J_pose * scaled, 0.0).reshape(n, -1, 6)
                Jr = np.where(seen[..., None, None], J_rig * scaled, 0.0).reshape(n, -1, N_RIG)
            Jp_t = np.swapaxes(Jp, 1, 2)
            A = Jp_t @ (Jp * w[..., None])                        # each pose's information (n, 6, 6)
            B = Jp_t @ (Jr * w[..., None])                        # pose × rig (n, 6, 9)
            Jr_all, w_all, r_all = Jr.reshape(-1, N_RIG), w.reshape(-1), r.reshape(-1)
            C = Jr_all.T @ (Jr_all * w_all[:, None])              # rig × rig (data only)
            g_pose = np.einsum("nki,nk->ni", Jp, w * r)
            g_rig = Jr_all.T @ (w_all * r_all)
            chi2 = float((w_all * r_all * r_all).sum())
            rows_used = 2 * int(seen.sum())
            if rows_used == 0:
                raise _SkipChunk(SKIP_NO_DATA)
            if not (np.isfinite(A).all() and np.isfinite(B).all() and np.isfinite(C).all()
                    and np.isfinite(g_pose).all() and np.isfinite(g_rig).all() and math.isfinite(chi2)):
                raise _SkipChunk(SKIP_NON_FINITE)
            # Eliminate the poses: X = A⁻¹ B (n, 6, 9), y = A⁻¹ g (n, 6).
            X, y = _eliminate_poses(A, B, g_pose)
            data_info = C - np.einsum("nij,nik->jk", B, X)
            # In units of the prior (whitened by L: the prior is I there).
            white_info = L.T @ data_info @ L
            white_info = 0.5 * (white_info + white_info.T)
            if observable is None:
                # What can this chunk teach? The data's information on the rig (poses
                # marginalized), in units of the prior's: directions (eigenvectors)
                # with less than `observable_fraction` are held.
                lam, U = np.linalg.eigh(white_info)
                observable = U[:, lam >= c.observable_fraction]
                if observable.shape[1] == 0:
                    raise _SkipChunk(SKIP_UNOBSERVABLE)
                # Rig steps are confined to the observable directions: δ ← L Π L⁻¹ δ.
                confine = L @ observable @ observable.T @ L_inv
            S_white = _whitened_inverse(np.eye(N_RIG) + white_info)      # the rig's system, inverted
            if iteration == c.iterations:
                break
            rhs = g_rig + prior_info @ rig - np.einsum("nij,ni->j", B, y)
            step_rig = -(L @ (S_white @ (L.T @ rhs)))
            step_pose = -(y + X @ step_rig)
            if not (np.isfinite(step_rig).all() and np.isfinite(step_pose).all()):
                raise _SkipChunk(SKIP_NON_FINITE)
            poses += step_pose
            rig += confine @ step_rig
        cov = L @ S_white @ L.T
        # An honest posterior: residuals larger than their σ say the noise is
        # larger. Measured robustly (the median centre's χ² with 2 dof, whose
        # median is 1.386, per degree of freedom left), so the few glints the
        # Cauchy weights already discount do not inflate it.
        dof = max(rows_used - 6 * n - observable.shape[1], 1)
        r2 = r2[seen]                            # the last pass's, of the centres it used
        noise_scale = float(np.median(r2)) / 1.386 * rows_used / dof
        posterior = _positive_definite(cov * max(1.0, noise_scale), self._scale)
        moved = np.diag(confine @ prior @ confine.T) / np.diag(prior) > 0.5
        refit = {f.t: (cv2.Rodrigues(poses[k, :3])[0] @ data.R[k], data.p1[k] + poses[k, 3:])
                 for k, f in enumerate(chunk)}
        return _Solution(rig, posterior, chi2, rows_used, noise_scale, refit, moved)

    def _chunk_terms(self, data: "_ChunkData", poses: np.ndarray, state: RigState):
        """Residuals (n, 2, 5, 2) px, ∂/∂pose (n, 2, 5, 2, 6) and ∂/∂rig (n, 2, 5, 2, 9) of a chunk's frames.

        All frames at once: one ``cv2.projectPoints`` per camera over every
        frame's points (already in the camera's frame, rvec = tvec = 0, so the
        derivatives with respect to tvec are those with respect to the point).
        Each centre is the model point at its row's time (:func:`_stereo_terms`):
        the head moved meanwhile (no motion known: not moved, and the offset's
        and readout's columns are zero).
        """
        model = self.model_mm
        n, m = len(poses), len(model)
        turn = np.stack([cv2.Rodrigues(np.ascontiguousarray(v))[0] for v in poses[:, :3]])
        R = turn @ data.R                                               # (n, 3, 3)
        p1 = data.p1 + poses[:, 3:]
        lever = np.einsum("mj,nij->nmi", model, R)                      # model @ Rᵀ per frame (n, m, 3)
        world = lever + p1[:, None, :]
        dX_dpose = np.concatenate([-_skew(lever), np.broadcast_to(np.eye(3), (n, m, 3, 3))], axis=3)  # (n, m, 3, 6)
        motion = np.einsum("nij,nmj->nmi", _skew(data.omega), lever) + data.velocity[:, None, :]  # ω × lever + v
        right_dt = np.repeat(data.declared + state.offset_s, m)
        frac = np.swapaxes(data.frac, 0, 1).reshape(2, n * m)
        px, d_world, J_rig = _stereo_terms(world.reshape(-1, 3), motion.reshape(-1, 3), frac, right_dt, state,
                                           self.K1, self.D[0], self.D[1])
        res = np.swapaxes(px.reshape(2, n, m, 2), 0, 1) - data.centers
        J_pose = np.swapaxes(d_world.reshape(2, n, m, 2, 3), 0, 1) @ dX_dpose[:, None]
        return res, J_pose, np.swapaxes(J_rig.reshape(2, n, m, 2, N_RIG), 0, 1)


@dataclass
class _Job:
    """An update under way: its chunk, and the generator running it (:meth:`RigRefiner._update_steps`)."""

    chunk: list
    steps: object


@dataclass
class _ChunkData:
    """A chunk's frames stacked for :meth:`RigRefiner._chunk_terms` (n frames)."""

    R: np.ndarray            # (n, 3, 3) tracked R_world_G
    p1: np.ndarray           # (n, 3) mm
    centers: np.ndarray      # (n, 2, 5, 2) px
    visible: np.ndarray      # (n, 2, 5)
    sigma: np.ndarray        # (n, 2, 5, 2) px
    declared: np.ndarray     # (n,) s
    omega: np.ndarray        # (n, 3) rad/s, zero where the motion is unknown
    velocity: np.ndarray     # (n, 3) mm/s, likewise
    frac: np.ndarray         # (n, 2, 5) each centre's row time in readouts (row_fractions)

    @classmethod
    def of(cls, chunk: list[_Frame], image_height: int | None) -> "_ChunkData":
        moving = [f.omega is not None and f.velocity is not None for f in chunk]
        zero = np.zeros(3)
        centers = np.stack([f.centers for f in chunk])
        start = [f.newest() for f in chunk]              # each pose from the newest rig it is known with
        return cls(np.stack([R for R, _ in start]), np.stack([p1 for _, p1 in start]),
                   centers, np.stack([f.visible for f in chunk]),
                   np.stack([f.sigma for f in chunk]), np.array([f.declared_offset_s for f in chunk]),
                   np.stack([f.omega if k else zero for f, k in zip(chunk, moving)]),
                   np.stack([f.velocity if k else zero for f, k in zip(chunk, moving)]),
                   row_fractions(centers[..., 1], image_height))
