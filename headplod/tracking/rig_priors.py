"""The rig's priors: how far a rig may be from its ``rig.yaml`` (:class:`RigErrorModel`), the rolling
shutter's readout (:func:`readout_prior`), and that error model's scale as the data teach it.

Covariances are over the rig's error state (:mod:`.rig_state`: rad ×3,
mm ×3, log focal, s ×2), times in s.

The rig's error for the uncertainty of V
----------------------------------------
:meth:`RigEstimator.cov <.rig_estimator.RigEstimator.cov>` (P + ddᵀ) keeps the
error model as it is: what the checks must allow. The covariance of V takes
the rig in use's error as the data know it
(:meth:`RigEstimator.error_distribution <.rig_estimator.RigEstimator.error_distribution>`):
the error model's scale (how far off this calibration is, against
calibrations in general) learnt from how far the data find the rig from
rig.yaml (hierarchical Bayes, :func:`scaled_error_distribution`), the data's
noise checked against the updates' innovations (:func:`count_consistency`,
:func:`consistency_scale`), and a mean: what the rig in use is off by. A
right rig.yaml's share shrinks as the data confirm it; a wrong one's stays
P + ddᵀ.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from .rig_state import _FOCAL, _SHIFT, _TURN

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
        (:func:`readout_prior`,
        :meth:`RigRefiner.set_readout_prior <.rig_refine.RigRefiner.set_readout_prior>`).
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


# The error model's scale τ (its σ times τ) over which scaled_error_distribution averages:
# log-spaced, from a rig a ten-thousandth as far off as the error model says to one ten times as far
# (τ's half-normal prior leaves nothing beyond; the data never need it: a parameter they teach keeps
# its posterior whatever τ).
_SCALE_GRID = np.exp(np.linspace(math.log(1e-4), math.log(10.0), 81))


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


# count_consistency (RigEstimator.data_scale): each update's normalized innovation squared is kept with this
# weight per update after it (forgetting over ~10 updates, ~3 s), and the sums start from this many degrees
# of freedom at 1.
_CONSISTENCY_KEEP = 0.9
_CONSISTENCY_PRIOR_DOF = 10.0


def count_consistency(sums: np.ndarray, prior: np.ndarray, posterior: np.ndarray, increment: np.ndarray,
                      scale: np.ndarray) -> np.ndarray:
    """The forgetting sums (2,) of the updates' normalized innovation squared and degrees of freedom, with
    one update's added (``sums`` itself when it adds nothing).

    For a consistent filter the increment Δ (9,) of an update has covariance
    prior − posterior (both (9, 9), the chunk's): Δᵀ (prior − posterior)⁺ Δ
    is χ² with as many degrees of freedom as directions the chunk taught
    (those whose variance fell by more than a thousandth of the largest
    fall, in units of the prior's σ ``scale`` (9,)). The refiner counts it
    only for updates whose prior was a posterior (not the error model's:
    there the increment measures how far off rig.yaml is,
    :func:`scaled_error_distribution`'s business), and not for a bump's (the
    rig changed).
    """
    units = np.outer(scale, scale)
    D = (prior - posterior) / units
    lam, U = np.linalg.eigh(0.5 * (D + D.T))
    keep = lam > 1e-3 * max(float(lam[-1]), 0.0)
    if not keep.any() or not np.isfinite(lam).all():
        return sums
    z = U[:, keep].T @ (increment / scale)
    nis = float(np.sum(z ** 2 / lam[keep]))
    if np.isfinite(nis):
        return _CONSISTENCY_KEEP * sums + np.array([nis, float(keep.sum())])
    return sums


def consistency_scale(sums: np.ndarray) -> float:
    """The data's errors over what the refinement assumed (a variance ratio, 1: as assumed) from the
    forgetting sums (NIS, degrees of freedom) of :func:`count_consistency`, with a prior of
    :data:`_CONSISTENCY_PRIOR_DOF` degrees of freedom at 1; clipped to [0.05, 20]."""
    nis, dof = sums
    return float(np.clip((_CONSISTENCY_PRIOR_DOF + nis) / (_CONSISTENCY_PRIOR_DOF + dof), 0.05, 20.0))
