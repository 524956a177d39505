"""The chunk solve of the rig's refinement, step by step, and the checks that keep every covariance it
hands out positive definite.

A chunk is n tracked frames (:class:`~.rig_frames._ChunkData`). Its
unknowns are each frame's pose change (6: a turn, rad, and a shift of P1,
mm, in the world frame) and the rig's error state (9, :mod:`.rig_state`).
One Gauss-Newton pass (run by :meth:`RigEstimator.solve
<.rig_estimator.RigEstimator.solve>`, which stops before each) is:
:func:`chunk_terms` (residuals and derivatives of every frame at once),
:func:`normal_equations` (Cauchy-weighted, rows standardized by each
centre's σ), :func:`_eliminate_poses` and :func:`rig_information` (the
poses marginalized: the rig's system in units of the prior, whitened by
:func:`whiten_prior`'s factor), :func:`observable_directions` (the first
pass decides what the chunk may move), :func:`_whitened_inverse` and
:func:`gauss_newton_step`; after the last, :func:`chunk_posterior` and
:func:`refit_poses` make the :class:`_Solution`.

Definiteness
------------
Every covariance the refiner keeps or hands out (the prior of a chunk, its
posterior, :meth:`RigEstimator.cov <.rig_estimator.RigEstimator.cov>`) is
symmetric positive definite by construction: symmetrized, and its
eigenvalues, in units of the prior's σ per component, floored
(:func:`_positive_definite`). The floor (1e-9 of the prior's variance,
raised where rounding in the prior's own units would otherwise reach it) is
far below what the drift adds per chunk, so it only acts where arithmetic
alone would lose definiteness: identical timestamps (no drift), a chunk
that teaches some direction almost perfectly. A chunk whose system is
singular, ill-conditioned or non-finite, or which teaches nothing
observable, gives no update (:class:`_SkipChunk`): the estimate and its
covariance stay as they were, and the chunk is counted in
:attr:`RigEstimator.skipped_chunks <.rig_estimator.RigEstimator.skipped_chunks>` by reason.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.linalg

from .rig_frames import _ChunkData
from .rig_state import N_RIG, RigState, _skew, _stereo_terms

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

# Reasons for a chunk without an update (keys of RigEstimator.skipped_chunks).
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


@dataclass
class _Solution:
    """What :meth:`RigEstimator.solve <.rig_estimator.RigEstimator.solve>` found for a chunk."""

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


def whiten_prior(prior: np.ndarray):
    """The prior (9, 9)'s Cholesky factor L, its inverse, and the prior's information L⁻ᵀ L⁻¹.

    ``prior`` is SPD by construction (:func:`_positive_definite`), checked
    all the same: raises ``_SkipChunk(SKIP_SINGULAR)`` when it is not.
    """
    try:
        L = np.linalg.cholesky(prior)
    except np.linalg.LinAlgError:
        raise _SkipChunk(SKIP_SINGULAR) from None
    L_inv = scipy.linalg.solve_triangular(L, np.eye(N_RIG), lower=True)
    return L, L_inv, L_inv.T @ L_inv


def chunk_terms(data: _ChunkData, poses: np.ndarray, state: RigState, model_mm: np.ndarray, K1: np.ndarray,
                D: tuple):
    """Residuals (n, 2, 5, 2) px, ∂/∂pose (n, 2, 5, 2, 6) and ∂/∂rig (n, 2, 5, 2, 9) of a chunk's frames.

    ``poses`` (n, 6): each frame's pose change (rad ×3, mm ×3) from the
    pose it was stacked with; ``state``: the rig; ``model_mm`` (5, 3) the
    markers in G; ``K1`` (3, 3) the left camera; ``D`` (left, right) the
    distortions. All frames at once: one ``cv2.projectPoints`` per camera
    over every frame's points (already in the camera's frame, rvec = tvec
    = 0, so the derivatives with respect to tvec are those with respect to
    the point). Each centre is the model point at its row's time
    (:func:`~.rig_state._stereo_terms`): the head moved meanwhile (no
    motion known: not moved, and the offset's and readout's columns are
    zero).
    """
    n, m = len(poses), len(model_mm)
    turn = np.stack([cv2.Rodrigues(np.ascontiguousarray(v))[0] for v in poses[:, :3]])
    R = turn @ data.R                                               # (n, 3, 3)
    p1 = data.p1 + poses[:, 3:]
    lever = np.einsum("mj,nij->nmi", model_mm, R)                   # model @ Rᵀ per frame (n, m, 3)
    world = lever + p1[:, None, :]
    dX_dpose = np.concatenate([-_skew(lever), np.broadcast_to(np.eye(3), (n, m, 3, 3))], axis=3)  # (n, m, 3, 6)
    motion = np.einsum("nij,nmj->nmi", _skew(data.omega), lever) + data.velocity[:, None, :]  # ω × lever + v
    right_dt = np.repeat(data.declared + state.offset_s, m)
    frac = np.swapaxes(data.frac, 0, 1).reshape(2, n * m)
    px, d_world, J_rig = _stereo_terms(world.reshape(-1, 3), motion.reshape(-1, 3), frac, right_dt, state,
                                       K1, D[0], D[1])
    res = np.swapaxes(px.reshape(2, n, m, 2), 0, 1) - data.centers
    J_pose = np.swapaxes(d_world.reshape(2, n, m, 2, 3), 0, 1) @ dX_dpose[:, None]
    return res, J_pose, np.swapaxes(J_rig.reshape(2, n, m, 2, N_RIG), 0, 1)


@dataclass
class _NormalEquations:
    """One pass's weighted least-squares system of a chunk of n frames (rows standardized by their σ)."""

    A: np.ndarray           # (n, 6, 6) each pose's information
    B: np.ndarray           # (n, 6, 9) pose × rig
    C: np.ndarray           # (9, 9) rig × rig (data only)
    g_pose: np.ndarray      # (n, 6) gradient of the poses
    g_rig: np.ndarray       # (9,) gradient of the rig
    chi2: float             # Cauchy-weighted χ² of the rows
    rows_used: int          # centre coordinates used
    seen: np.ndarray        # (n, 2, m) bool: centres whose residual and derivatives are finite
    r2: np.ndarray          # (n, 2, m) each centre's standardized χ² (2 dof), 0 where not seen
    weights: np.ndarray     # (n, 2, m) the Cauchy weights used


def normal_equations(res: np.ndarray, J_pose: np.ndarray, J_rig: np.ndarray, data: _ChunkData,
                     weights: np.ndarray | None, cauchy_scale: float) -> _NormalEquations:
    """The weighted normal equations of :func:`chunk_terms`'s residuals and derivatives.

    Each centre's rows are divided by its σ (``data.sigma``, px) and
    weighted by ``weights`` (n, 2, m), or, None, by the Cauchy weights of
    these residuals (scale ``cauchy_scale`` σ). A centre counts when it is
    visible and its residual and derivatives are finite (a point on a
    camera's plane projects to inf). Raises ``_SkipChunk`` when no centre
    counts, or a term is not finite.
    """
    n = len(res)
    sig = data.sigma
    with np.errstate(invalid="ignore"):
        z = res / sig                                    # (n, 2, m, 2) standardized
        # A centre counts when its residual and derivatives are finite
        # (a point on a camera's plane projects to inf).
        seen = (np.isfinite(z).all(axis=3) & data.visible
                & np.isfinite(J_pose).all(axis=(3, 4)) & np.isfinite(J_rig).all(axis=(3, 4)))
        r2 = np.where(seen, (z ** 2).sum(axis=3), 0.0)          # (n, 2, m)
        if weights is None:
            weights = np.where(seen, 1.0 / (1.0 + r2 / (2 * cauchy_scale ** 2)), 0.0)
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
    return _NormalEquations(A, B, C, g_pose, g_rig, chi2, rows_used, seen, r2, weights)


def rig_information(eq: _NormalEquations, X: np.ndarray, L: np.ndarray) -> np.ndarray:
    """The data's information on the rig (9, 9) with the poses marginalized (C − Σ Bᵀ A⁻¹ B, ``X`` = A⁻¹ B
    (n, 6, 9)), in units of the prior (whitened by its Cholesky factor ``L``: the prior is I there)."""
    data_info = eq.C - np.einsum("nij,nik->jk", eq.B, X)
    white_info = L.T @ data_info @ L
    return 0.5 * (white_info + white_info.T)


def observable_directions(white_info: np.ndarray, L: np.ndarray, L_inv: np.ndarray, fraction: float):
    """What a chunk can teach: the directions (9, k) of the rig, in units of the prior, whose information
    ``white_info`` (9, 9) is at least ``fraction`` of the prior's, and the projection (9, 9) that confines
    the rig's steps to them (δ ← L Π L⁻¹ δ). Raises ``_SkipChunk(SKIP_UNOBSERVABLE)`` when there is none."""
    lam, U = np.linalg.eigh(white_info)
    observable = U[:, lam >= fraction]
    if observable.shape[1] == 0:
        raise _SkipChunk(SKIP_UNOBSERVABLE)
    return observable, L @ observable @ observable.T @ L_inv


def gauss_newton_step(eq: _NormalEquations, X: np.ndarray, y: np.ndarray, rig: np.ndarray,
                      prior_info: np.ndarray, L: np.ndarray, S_white: np.ndarray):
    """One Gauss-Newton step of the rig (9,) and of the poses (n, 6) from the rig's increment so far
    ``rig`` (9,) under the prior (information ``prior_info``), with the poses eliminated (``X`` = A⁻¹ B,
    ``y`` = A⁻¹ g) and ``S_white`` the rig's system inverted in units of the prior. Raises
    ``_SkipChunk(SKIP_NON_FINITE)`` for a step that is not finite."""
    rhs = eq.g_rig + prior_info @ rig - np.einsum("nij,ni->j", eq.B, y)
    step_rig = -(L @ (S_white @ (L.T @ rhs)))
    step_pose = -(y + X @ step_rig)
    if not (np.isfinite(step_rig).all() and np.isfinite(step_pose).all()):
        raise _SkipChunk(SKIP_NON_FINITE)
    return step_rig, step_pose


def chunk_posterior(eq: _NormalEquations, n: int, observable: int, L: np.ndarray, S_white: np.ndarray,
                    scale: np.ndarray):
    """The rig's posterior covariance (9, 9), SPD (floored in units of ``scale``, the prior's σ (9,)),
    and the noise scale, from the last pass of a chunk of ``n`` frames (``observable`` directions taught).

    An honest posterior: residuals larger than their σ say the noise is
    larger. Measured robustly (the median centre's χ² with 2 dof, whose
    median is 1.386, per degree of freedom left), so the few glints the
    Cauchy weights already discount do not inflate it.
    """
    cov = L @ S_white @ L.T
    dof = max(eq.rows_used - 6 * n - observable, 1)
    r2 = eq.r2[eq.seen]                      # the last pass's, of the centres it used
    noise_scale = float(np.median(r2)) / 1.386 * eq.rows_used / dof
    return _positive_definite(cov * max(1.0, noise_scale), scale), noise_scale


def refit_poses(chunk: list, data: _ChunkData, poses: np.ndarray) -> dict:
    """{t: (R_world_G, p1 mm)} of the chunk's frames moved by their pose changes ``poses`` (n, 6)."""
    return {f.t: (cv2.Rodrigues(poses[k, :3])[0] @ data.R[k], data.p1[k] + poses[k, 3:])
            for k, f in enumerate(chunk)}


def run_to_end(steps):
    """Run a solve (a generator, :meth:`RigEstimator.solve <.rig_estimator.RigEstimator.solve>`) through all
    its passes at once; its :class:`_Solution`."""
    while True:
        try:
            next(steps)
        except StopIteration as end:
            return end.value


def bootstrap_agrees(chunk: list, start: RigState, estimate: RigState, prior: np.ndarray, model_mm: np.ndarray,
                     K1: np.ndarray, D: tuple, image_height) -> bool:
    """Whether a bootstrap's joint fit (the rig ``estimate``, the chunk's frames at their refitted poses)
    is one to start from: every frame's every centre within ``_BOOTSTRAP_MAX_Z`` σ of where the fit puts
    it, and the change from ``start`` one the far ``prior`` (9, 9) allows (χ² with 7 dof, 99.9%)."""
    data = _ChunkData.of(chunk, image_height)
    res = chunk_terms(data, np.zeros((len(chunk), 6)), estimate, model_mm, K1, D)[0]
    z = np.hypot(*np.moveaxis(res / data.sigma, -1, 0))[data.visible]
    if not (np.isfinite(z).all() and z.max() <= _BOOTSTRAP_MAX_Z):
        return False
    change = estimate.error_from(start)
    return float(change @ np.linalg.lstsq(prior, change, rcond=None)[0]) <= _CHI2_7DOF_999
