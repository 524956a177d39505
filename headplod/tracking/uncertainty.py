"""Uncertainty of the viewing direction: cov of (φ, θ) in deg² (docs/contract.md).

Estimators, all fed the same :class:`CovarianceInput` by the tracker:

- ``paper``: Martinez et al. (2008, §4.3). Each marker is the cloud of its
  thresholded pixels in each image; pixel pairs across the images whose rays
  pass within ``gap_mm`` (2.0 mm, the first peak of the reconstruction-error
  histogram) and whose normalized distances to their blob centres agree (the
  structural constraint) are triangulated; each 3D cloud is sub-sampled
  uniformly (ratio 0.3, random as in the paper); combinations of one point per
  marker give V by the paper's three normals; their (φ, θ) about the reported
  head frame give the sample covariance.
- ``paper_deterministic``: the same with a sub-sampling and a choice of
  combinations that do not change between frames (strided sub-samples, a
  fixed draw of combinations): the paper blames its LOD jitter on random
  sampling.
- ``first_order``: the noise of each centre (from the image noise, blob
  size, shape and flux: :mod:`headplod.tracking.detect`) propagated through the
  reprojection fit to (φ, θ); the noise model's two coefficients (pixel
  noise, shot noise) are fitted to the residuals' frame-to-frame changes, so
  it follows the physics of the images rather than one renderer's settings
  (:class:`FirstOrder`). Beside the noise, the nuisances the pose is fitted
  with as they are (the rig's error as the refinement knows it, the motion
  that moved the right view, the rolling shutter's velocity): their
  uncertainty, and the bias this frame's residuals show of them
  (:func:`pose_error_covariance`).
- ``*_smoothed``: for ``first_order``, each centre's noise variance is
  averaged over ~5 frames while the Jacobian stays the current frame's (a
  steady input for the PLOD module that still follows a moving head); for
  ``paper``, an exponential moving average of its covariances.
- ``*_fixed``: the largest covariance (by trace) measured so far, the
  paper's "fixed" scenario.

Why the paper's estimator is off (measured by ``headplod bench uncertainty``:
its mean NEES is about 0.001, i.e. its variances are some thousand times too
large): its spread is that of single pixels, not of the centroids the pose is
made from. Pairing whole pixel clouds measures the size of the marker's image
(a 6 mm disk spans ±10° of V over the 30 mm between the markers' rows),
while the centroid of that disk is known to a few hundredths of a pixel; the
pixel noise barely changes which pixels pass the threshold, so the estimate
hardly follows the noise either.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from . import geometry as geo
from ..tol import tol

COVARIANCE_ESTIMATORS = ("first_order", "first_order_smoothed", "first_order_fixed",
                         "paper", "paper_deterministic", "paper_smoothed", "paper_fixed")
DEFAULT_COVARIANCE = "first_order_smoothed"

# rig_residual_rows: LAPACK's Cholesky factor/solve called directly (np.linalg.solve
# costs several times more on a 6×6 system; this is on the per-frame path).
_potrf, _potrs = lapack.dpotrf, lapack.dpotrs
# Smallest Cholesky pivot, as a fraction of its column's weighted norm², for
# the normal equations to be trusted (a column 1e-4 from the others' span:
# the solve's relative error stays ~1e-8); below it, the SVD path.
_HAT_MIN_PIVOT = 1e-8
# Singular values (of the column-scaled, weighted J) below this fraction of
# the largest are the fit's undetermined directions.
_HAT_RCOND = 1e-8


@dataclass
class CovarianceInput:
    """What a covariance estimator may use, for one tracked frame.

    Attributes
    ----------
    images : (left, right) (H, W) uint8
    centers_px : (2, 5, 2)
        Marker centres per image, px (NaN if hidden).
    visible : (2, 5) bool
    sigma_px : (2, 5)
        Expected centroid noise per coordinate from the image noise, px.
    residuals_px : (2, 5)
        Reprojection residual of each centre after the fit, px.
    info : (6, 6)
        Jᵀ Σ⁻¹ J of the fit w.r.t. (δ rad, ε mm), with Σ from ``sigma_px``.
    R_world_G, p1_mm, axes : the fitted pose (axes rows Ξ, Ψ, V).
    thresholds_dn : (2,)
        Marker segmentation threshold per image, DN.
    backgrounds : ((level, σ), (level, σ)) DN
    residual_vectors_px : (2, 5, 2)
        Projected minus measured centre, px.
    t : float or None
        Frame time, s.
    shot_var : (2, 5, 2)
        Centroid variance of x and of y per unit shot-noise factor κ
        (pixel variance κ·I), px²/DN; NaN where unknown.
    jacobian_rows : (2, 5, 2, 6)
        ∂(projected centre)/∂(δ, ε) of each marker image at the fitted pose.
    rig_rows : (2, 5, 2, k), optional
        ∂(projected centre)/∂(nuisance parameters): the rig's error state
        (8, :mod:`headplod.tracking.rig_refine`) and, when the right view
        was moved to its exposure time, that motion's error (6 more: a pose
        error of the right view alone).
    rig_cov : (k, k), optional
        Their covariance: how far the rig used may be from the true one (the
        calibration's uncertainty, its drift, the time offset), as the
        online refinement knows it, and the motion's (:mod:`.motion`).
    rig_version : int
        Changes whenever the rig used changes (a refinement step): the
        residuals then jump by the change, which is not image noise.
    excess_px : (2, 5), optional
        Error of a suspect centre beyond its noise (a glint fused with the
        marker), px, 0 for the others: added to its variance, and kept out
        of the noise model's learning.
    rig_mean : (k,), optional
        Mean of the nuisance parameters' error (the rig's: what the
        refinement believes the rig in use is off by; 0 for the motion's),
        in ``rig_rows``' units; None: 0 (``rig_cov`` is then their second
        moment).
    rig_parameters : int
        How many of the leading nuisance parameters are the rig's (their
        error is the same in every frame while the rig in use and what is
        known of it are); 0: none (``rig_mean`` then refers to no rig).
    rig_known : bool
        Whether the refinement has taught anything of the rig yet; False:
        the rig's covariance is its error model's, whose scale this frame's
        residuals then tell (:func:`rig_scale_from_frame`).
    pose_corrected : bool
        The pose reported is the joint fit of the pose and a rig change,
        not the fit with the rig as is (the tracker corrects it when the
        residuals show the rig's error): what the residuals show of the
        nuisances is then taken off the pose already.
    """

    images: tuple
    centers_px: np.ndarray
    visible: np.ndarray
    sigma_px: np.ndarray
    residuals_px: np.ndarray
    info: np.ndarray
    R_world_G: np.ndarray
    p1_mm: np.ndarray
    axes: np.ndarray
    thresholds_dn: tuple
    backgrounds: tuple
    residual_vectors_px: np.ndarray = None
    t: float | None = None
    shot_var: np.ndarray = None
    jacobian_rows: np.ndarray = None
    rig_rows: np.ndarray = None
    rig_cov: np.ndarray = None
    rig_version: int = 0
    excess_px: np.ndarray = None
    rig_mean: np.ndarray = None
    pose_corrected: bool = False
    rig_parameters: int = 0
    rig_known: bool = True


def rig_residual_rows(pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(I − H) J_r (n, k): what a rig change leaves in the residuals after the weighted pose fit.

    ``pose_rows`` J (n, p) (p = 6: δ rad, ε mm) and ``rig_rows`` J_r (n, k),
    px per unit, of the n visible centre coordinates (both images, world =
    left camera frame); ``weights`` (n,) = 1/σ², px⁻². H = J (Jᵀ W J)⁺ Jᵀ W
    is the fit's hat matrix: the result is J_r minus its W-weighted
    least-squares projection onto the columns of J, which is defined even
    when J is rank-deficient (few visible markers, degenerate geometry, a
    pose whose projections blow up): the fit then absorbs what its
    determined directions can, and nothing along the others.

    Fast path: Cholesky of the normal equations (LAPACK potrf/potrs, a
    fraction of ``np.linalg.solve``'s overhead on 6×6), used only when every
    pivot keeps at least ``_HAT_MIN_PIVOT`` of its column's weighted norm²
    (scale-free; catches non-finite and near-dependent columns). Otherwise
    a column-scaled SVD least-squares solve whose singular values below
    ``_HAT_RCOND`` of the largest count as zero. Rows whose weight is
    negative or non-finite, or whose J or J_r has a non-finite entry, are
    left out of the fit; a row whose own J or J_r is non-finite comes back
    NaN, every other row is finite for finite inputs (below ~1e150). Never
    raises for a rank-deficient or non-finite system.
    """
    Jw = pose_rows * weights[:, None]
    A = pose_rows.T @ Jw
    B = Jw.T @ rig_rows
    if len(weights) and weights.min() >= 0.0:          # no negative weight (NaN fails too)
        c, info = _potrf(A, 1, 0)                        # lower, upper triangle left as is
        # Pivot over its column's norm²: scale-free; NaN fails the comparison.
        if info == 0 and min(map(operator.truediv, (c.diagonal() ** 2).tolist(), A.diagonal().tolist()),
                             default=1.0) > _HAT_MIN_PIVOT:
            X, info = _potrs(c, B, 1)
            if info == 0 and math.isfinite(X.sum()):
                return rig_rows - pose_rows @ X
    return rig_rows - pose_rows @ _weighted_lstsq(pose_rows, rig_rows, weights)


def _weighted_lstsq(J: np.ndarray, Y: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """argmin_X Σ w (J X − Y)² (p, k) over the valid rows, minimum-norm on J's (near-)null space.

    Columns are scaled to unit max first (rad and mm columns differ by
    orders of magnitude, and huge rows must not overflow when weighted).
    """
    valid = (np.isfinite(weights) & (weights >= 0) & np.isfinite(J).all(axis=1) & np.isfinite(Y).all(axis=1))
    s = np.sqrt(np.where(valid, weights, 0.0))[:, None]
    Jv = np.where(valid[:, None], J, 0.0)
    Yv = np.where(valid[:, None], Y, 0.0)
    cj = np.abs(Jv).max(axis=0, initial=0.0)
    cy = np.abs(Yv).max(axis=0, initial=0.0)
    cj = np.where(cj > 0, cj, 1.0)
    cy = np.where(cy > 0, cy, 1.0)
    try:
        Xs = np.linalg.lstsq(Jv / cj * s, Yv / cy * s, rcond=_HAT_RCOND)[0]
    except np.linalg.LinAlgError:
        # SVD without convergence (finite but absurd inputs): the fit is taken
        # to absorb nothing, which overstates the rig's share rather than hide it.
        return np.zeros((J.shape[1], Y.shape[1]))
    return Xs / cj[:, None] * cy


def with_rig_uncertainty(info: np.ndarray, pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray,
                         rig_cov: np.ndarray) -> np.ndarray:
    """The pose's information (6, 6) once the rig's own uncertainty is marginalized.

    The rig's error e ~ N(0, P) moves every centre by J_r e, correlated
    across centres and frames alike; with the rig as k nuisance parameters
    beside the pose (prior information P⁻¹), the pose's information is the
    Schur complement I_pp − I_pr (I_rr + P⁻¹)⁻¹ I_rp, which equals
    Jᵀ (Σ + J_r P J_rᵀ)⁻¹ J. ``pose_rows`` (m, 2, 6), ``rig_rows``
    (m, 2, k) (any nuisance parameters, ``rig_cov`` (k, k)), ``weights``
    (m, 2) = 1/σ² of each centre coordinate. That is the covariance of the
    joint fit of the pose and e; the pose fitted with e as it is carries
    more (:func:`pose_error_covariance`, which the estimators use).
    """
    i_pr = np.einsum("mij,mik,mi->jk", pose_rows, rig_rows, weights)
    i_rr = np.einsum("mij,mik,mi->jk", rig_rows, rig_rows, weights)
    keep = np.diag(rig_cov) > 0
    if not keep.any():
        return info
    i_rr = i_rr[np.ix_(keep, keep)] + np.linalg.inv(rig_cov[np.ix_(keep, keep)])
    i_pr = i_pr[:, keep]
    return info - i_pr @ np.linalg.solve(i_rr, i_pr.T)


# The scales τ of an error model's σ over which rig_scale_from_frame averages: log-spaced from a
# ten-thousandth to ten times (τ's half-normal prior leaves nothing beyond). The same prior as the rig
# refinement's (rig_refine.scaled_error_distribution).
_SCALE_GRID = np.exp(np.linspace(math.log(1e-4), math.log(10.0), 81))


def _frame_information(info: np.ndarray, pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray,
                       residuals: np.ndarray):
    """What one frame's residuals say of the nuisances' error e, the pose marginalized: (X (6, k) = G J_r,
    F (k, k) = Mᵀ W M its information, h (k,) = −Mᵀ W r its information vector), M = (I − H) J_r.

    Shapes and units as :func:`nuisance_posterior`. The residuals r are
    projected minus measured: r = −M e − (I − H) n, hence the sign of h.
    """
    i_pr = np.einsum("mij,mik,mi->jk", pose_rows, rig_rows, weights)
    i_rr = np.einsum("mij,mik,mi->jk", rig_rows, rig_rows, weights)
    X = np.linalg.solve(info, i_pr)                         # G J_r: what the fit absorbs of e
    F = i_rr - i_pr.T @ X
    # −Mᵀ W r = −(J_rᵀ W r − (G J_r)ᵀ Jᵀ W r)
    wr = weights * residuals
    h = -(np.einsum("mik,mi->k", rig_rows, wr) - X.T @ np.einsum("mij,mi->j", pose_rows, wr))
    return X, 0.5 * (F + F.T), h


def nuisance_posterior(info: np.ndarray, pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray,
                       rig_cov: np.ndarray, residuals: np.ndarray, rig_mean: np.ndarray | None = None):
    """What one frame's residuals say of the nuisance parameters' error e, beside their prior.

    The pose is fitted with the nuisances as they are (the rig in use, the
    motion as extrapolated): an error e moves the centres by J_r e, the fit
    absorbs part of it, δp = G (J_r e + n) with G = (Jᵀ W J)⁻¹ Jᵀ W, and
    leaves the rest in the residuals, r = −(I − H)(J_r e + n) (projected
    minus measured), H = J G. With e's prior N(μ, C) (``rig_mean`` μ,
    default 0; ``rig_cov`` C), given r: e ~ N(ê, C_post), C_post = (C⁻¹ +
    Mᵀ W M)⁻¹ and ê = C_post (C⁻¹ μ − Mᵀ W r), M = (I − H) J_r.

    ``info`` (6, 6) = Jᵀ W J; ``pose_rows`` (m, 2, 6) J, ``rig_rows``
    (m, 2, k) J_r, ``weights`` (m, 2) W = 1/σ², px⁻², ``residuals`` (m, 2)
    px, of the m centres used. Returns (X (6, k) = G J_r, C_post (k, k), ê
    (k,)); parameters whose variance is 0 are held at their mean (their
    rows and columns of C_post are 0, ê is μ there).
    """
    k = rig_rows.shape[-1]
    keep = np.diag(rig_cov) > 0
    mu = np.zeros(k) if rig_mean is None else np.asarray(rig_mean, np.float64).reshape(k)
    X = np.zeros((6, k))
    C_post = np.zeros((k, k))
    e = mu.copy()
    if not keep.any():
        return X, C_post, e
    Xk, F, h = _frame_information(info, pose_rows, rig_rows[..., keep], weights, residuals)
    C_inv = np.linalg.inv(rig_cov[np.ix_(keep, keep)])
    post = np.linalg.inv(C_inv + F)
    post = 0.5 * (post + post.T)
    X[:, keep] = Xk
    C_post[np.ix_(keep, keep)] = post
    e[keep] = post @ (C_inv @ mu[keep] + h)
    return X, C_post, e


def rig_scale_from_frame(info: np.ndarray, pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray,
                         rig_cov: np.ndarray, residuals: np.ndarray, rig_mean: np.ndarray | None = None) -> float:
    """E[τ² | this frame's residuals] for a rig whose error is N(μ, τ² C), known only by its error model.

    Before the refinement has taught anything (the first frames, and after
    the rig was found changed), the rig's covariance C is the error model's
    (a turn of 0.5°, a baseline 2% off, an exposure offset of 25 ms...):
    right for calibrations in general, and several times what a right
    rig.yaml is off by. This frame's residuals show the rig's error along
    the directions the pose fit does not absorb (:func:`_frame_information`),
    most of them at many times the image noise: they tell how far off this
    rig is against its error model. With τ half-normal of scale 1 (E τ² =
    1: the error model as it is without data; the same prior as the rig
    refinement's) and the linear-Gaussian likelihood of the residuals,
    τ's posterior is evaluated on :data:`_SCALE_GRID`; its mean of τ² is
    returned, the factor for C.

    ``info`` (6, 6) = Jᵀ W J; ``pose_rows`` (m, 2, 6), ``rig_rows`` (m, 2, k)
    of the rig's parameters alone, ``weights`` (m, 2) 1/σ², px⁻²;
    ``rig_cov`` C (k, k), SPD, and ``rig_mean`` μ (k,) (default 0) in the
    rig's units; ``residuals`` (m, 2) px, projected minus measured.
    """
    k = rig_rows.shape[-1]
    mu = np.zeros(k) if rig_mean is None else np.asarray(rig_mean, np.float64).reshape(k)
    _, F, h = _frame_information(info, pose_rows, rig_rows, weights, residuals)
    # In units of C (e = μ + L z, z ~ N(0, τ² I)), in the eigenbasis of the frame's information there,
    # the frame's estimate of each component is c ~ N(0, τ² + 1/f).
    L = np.linalg.cholesky(rig_cov)
    f, V = np.linalg.eigh(L.T @ F @ L)
    taught = f > tol.small * max(float(f[-1]), 1e-300)
    if not taught.any():
        return 1.0
    c = (V.T @ (L.T @ (h - F @ mu)))[taught] / f[taught]
    v = 1.0 / f[taught]
    tau2 = _SCALE_GRID ** 2
    total = tau2[:, None] + v[None, :]
    log_w = -0.5 * (np.log(total) + c ** 2 / total).sum(axis=1) - 0.5 * tau2 + np.log(_SCALE_GRID)
    w = np.exp(log_w - log_w.max())
    return float((w * tau2).sum() / w.sum())


def pose_error_covariance(info: np.ndarray, pose_rows: np.ndarray, rig_rows: np.ndarray, weights: np.ndarray,
                          rig_cov: np.ndarray, residuals: np.ndarray, rig_mean: np.ndarray | None = None,
                          corrected: bool = False) -> np.ndarray:
    """Second moment (6, 6) of the error of the pose fitted with the nuisance parameters as they are
    (δ rad, ε mm), given this frame's residuals.

    With e | r ~ N(ê, C_post) (:func:`nuisance_posterior`, whose arguments
    these are) and the pose's noise G n independent of the residuals (a
    weighted fit's residuals are orthogonal to its parameters), δp = G (J_r
    e + n) has second moment (Jᵀ W J)⁻¹ + G J_r (C_post + ê êᵀ) J_rᵀ Gᵀ.
    Without the ê êᵀ term this is :func:`with_rig_uncertainty`'s Schur
    complement, the covariance of the joint fit of the pose and e: the fit
    with e as it is also carries what the residuals show of e. A frame
    whose residuals show the rig off (a stale rig before the refinement
    caught up, an exposure offset not yet learnt at 1 m/s) gets that bias
    in its covariance; one whose residuals show nothing, the nuisances'
    uncertainty alone. ``corrected``: the pose reported was moved by that
    estimate already (the tracker's joint fit): the term is left out.
    """
    cov_pose = np.linalg.inv(info)
    X, C_post, e = nuisance_posterior(info, pose_rows, rig_rows, weights, rig_cov, residuals, rig_mean)
    spread = C_post if corrected else C_post + np.outer(e, e)
    out = cov_pose + X @ spread @ X.T
    return 0.5 * (out + out.T)


def view_angles_deg(directions: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(φ, θ) in degrees of unit directions (M, 3) in the head frame ``axes`` (rows Ξ, Ψ, V)."""
    local = directions @ axes.T
    return np.degrees(np.stack([np.arctan2(local[:, 1], local[:, 2]), np.arctan2(local[:, 0], local[:, 2])], axis=1))


class FirstOrder:
    """First-order propagation of the centroid noise, with the noise model fitted from the residuals.

    The variance of each centre's x and y is a·v_bg + κ·v_shot,x|y: v_bg
    propagates the image's pixel noise σ_n through the Gaussian-windowed
    centroid (isotropic: the window is round), v_shot a shot noise whose
    pixel variance is proportional to the pixel's signal (anisotropic: a
    foreshortened blob's centre is noisier along its length, and along the
    stereo baseline that is what sets depth and V). a (≈ 1 if σ_n is right)
    and κ (1/gain, DN) are not assumed: they are fitted per camera, by least
    squares over recent frames, to the change of each centre's residual from
    one frame to the next, E Δr_c² = f (σ_c,k² + σ_c,k−1²), f the fraction of
    the residual space the pose fit leaves (1 − 6/2m). Differencing keeps the
    noise, new in every frame, and cancels what is constant from frame to
    frame (a centroid bias). Markers differ in brightness and blobs in shape,
    which separates a from κ. Then cov(δ) = (Σ Jᵀ diag(1/σ²) J)⁻¹ is mapped
    to (φ, θ).

    The nuisances (``rig_rows``, ``rig_cov``, ``rig_mean``: the rig's error,
    the motion's) add their share: the second moment of what they move the
    pose fitted with them as they are, given this frame's residuals
    (:func:`pose_error_covariance`). While the rig is known only by its
    error model, this frame's residuals tell that model's scale
    (:func:`rig_scale_from_frame`). A centre's residual that the nuisances'
    error explains does not count against the centre.

    Parameters
    ----------
    axes_G : (3, 3)
        The model's head axes in G.
    calibration_frames : int
        Time constant of the exponential average of the fit's normal
        equations, frames.
    smoothing_frames : int
        Time constant of an exponential average of each centre's variance
        (0: none).
    """

    name = "first_order"

    def __init__(self, axes_G: np.ndarray, calibration_frames: int = 60, smoothing_frames: int = 0):
        self.axes_G = axes_G
        self.calibration_frames = calibration_frames
        self.smoothing_frames = smoothing_frames
        if smoothing_frames:
            self.name = "first_order_smoothed"
        self.reset()

    def reset(self) -> None:
        # One noise model per camera: the two views of a marker differ in
        # angle, distance and sensor.
        self.normal = np.zeros((2, 2, 2))
        self.rhs = np.zeros((2, 2))
        self.frames = 0
        self.coefficients = np.array([[2.0, 0.0], [2.0, 0.0]])   # prior until the residuals speak: a = 2, κ = 0
        self._previous = None
        self._smoothed = None
        self._smoothed_share = None       # (2, 2) deg²: the nuisances' share of V's covariance, averaged
        self._share_key = None            # what was known of the rig when it was

    @staticmethod
    def _terms(x: CovarianceInput):
        """v_bg (2, 5, 1) and v_shot (2, 5, 2), px² per unit a and κ."""
        v_bg = (np.maximum(x.sigma_px, _SIGMA_FLOOR_PX) ** 2)[..., None]
        v_shot = np.nan_to_num(x.shot_var) if x.shot_var is not None else np.zeros(v_bg.shape[:2] + (2,))
        return v_bg, v_shot

    def variances(self, x: CovarianceInput) -> np.ndarray:
        """Variance of each centre's x and y (2, 5, 2), px², under the current noise model,
        with a suspect centre's excess."""
        return self._with_excess(self._noise_variances(x), x)

    def _noise_variances(self, x: CovarianceInput) -> np.ndarray:
        v_bg, v_shot = self._terms(x)
        a, kappa = self.coefficients[:, 0, None, None], self.coefficients[:, 1, None, None]
        return a * v_bg + kappa * v_shot

    @staticmethod
    def _with_excess(variance: np.ndarray, x: CovarianceInput) -> np.ndarray:
        if x.excess_px is None:
            return variance
        return variance + np.nan_to_num(x.excess_px)[..., None] ** 2

    def __call__(self, x: CovarianceInput) -> np.ndarray:
        self._update(x)
        variance = self._noise_variances(x)
        if self.smoothing_frames:
            # Smooth each centre's noise (it changes slowly with the pose),
            # not the covariance: the Jacobian stays this frame's, so the
            # covariance follows a moving head without lag but does not
            # flicker with the noise of the noise estimates.
            if self._smoothed is None:
                self._smoothed = variance.copy()
            else:
                rate = 1.0 / self.smoothing_frames
                known = np.isfinite(variance) & np.isfinite(self._smoothed)
                self._smoothed = np.where(known, (1 - rate) * self._smoothed + rate * variance, variance)
            variance = self._smoothed
        # A glint is this frame's, not to be smoothed into the next ones.
        variance = self._with_excess(variance, x)
        seen = x.visible & np.isfinite(variance).all(axis=2)
        rows = x.jacobian_rows[seen]                                  # (m, 2, 6)
        variance = np.maximum(variance[seen], 1e-10)                  # (m, 2)
        residuals = np.nan_to_num(x.residual_vectors_px[seen])          # (m, 2)
        nuisance = x.rig_rows is not None and x.rig_cov is not None
        if nuisance:
            nuisance_rows, nuisance_cov = x.rig_rows[seen], x.rig_cov
            info0 = np.einsum("mij,mik,mi->jk", rows, rows, 1.0 / variance)
            r = x.rig_parameters
            if r and not x.rig_known:
                # The rig known only by its error model (no data yet): this
                # frame's residuals say how far off it is (rig_scale_from_frame).
                try:
                    scale = rig_scale_from_frame(info0, rows, nuisance_rows[..., :r], 1.0 / variance,
                                                 nuisance_cov[:r, :r], residuals,
                                                 None if x.rig_mean is None else x.rig_mean[:r])
                    nuisance_cov = nuisance_cov.copy()
                    nuisance_cov[:r, :r] *= scale
                except np.linalg.LinAlgError:
                    pass
            # What the nuisances' error, as these residuals show it, explains
            # of them (the rig's share is not the centre's fault).
            X, _, e = nuisance_posterior(info0, rows, nuisance_rows, 1.0 / variance, nuisance_cov, residuals,
                                         x.rig_mean)
            unexplained = residuals + nuisance_rows @ e - rows @ (X @ e)
        else:
            unexplained = residuals
        # A centre whose residual neither the noise model nor the nuisances
        # explain (a glint fused with the marker, a partial occlusion) is
        # worse than the model says: its variance grows by its squared
        # residual beyond what chance gives 1% of centres (χ² with 2 dof: 9.21).
        excess = (unexplained ** 2 / variance).sum(axis=1) / _CHI2_2DOF_99
        weights = 1.0 / (variance * np.maximum(excess, 1.0)[:, None])
        info = np.einsum("mij,mik,mi->jk", rows, rows, weights)
        cov = geo.view_angle_covariance(x.R_world_G, info, 1.0, self.axes_G)
        if not nuisance:
            return cov
        # The pose is the fit with the nuisances as they are: what its
        # residuals show of their error is a bias of this pose, not only an
        # uncertainty (pose_error_covariance).
        full = np.linalg.inv(pose_error_covariance(info, rows, nuisance_rows, weights, nuisance_cov, residuals,
                                                   x.rig_mean, x.pose_corrected))
        share = geo.view_angle_covariance(x.R_world_G, full, 1.0, self.axes_G) - cov
        if self.smoothing_frames:
            # The nuisances' share is noisy from frame to frame where the
            # noise is not: what one frame's residuals show of the rig's
            # error, and the head's velocity (the last poses' noise, for a
            # still head) that the exposure offset's and the readout's
            # uncertainty multiply. Averaged like the centres' noise, in V's
            # own (φ, θ) (the head frame's), it is as steady; started afresh
            # whenever what is known of the rig changes (a refinement's
            # update, a new rig in use: a real change, not to be dragged).
            r = x.rig_parameters
            key = (x.rig_version, x.rig_known,
                   None if not r or x.rig_mean is None else np.asarray(x.rig_mean)[:r].tobytes(),
                   x.rig_cov[:r, :r].tobytes() if r else None)
            if self._smoothed_share is None or key != self._share_key:
                self._smoothed_share = share
            else:
                rate = 1.0 / self.smoothing_frames
                self._smoothed_share = (1 - rate) * self._smoothed_share + rate * share
            self._share_key = key
            share = self._smoothed_share
        return cov + share

    def _update(self, x: CovarianceInput) -> None:
        v_bg, v_shot = self._terms(x)
        vectors = x.residual_vectors_px
        if x.excess_px is not None:
            # A suspect centre's change is its glint's, not noise.
            vectors = np.where((np.nan_to_num(x.excess_px) > 0)[..., None], np.nan, vectors)
        current = (vectors, v_bg, v_shot, x.t, x.rig_version)
        previous, self._previous = self._previous, current
        if previous is None:
            return
        prev_vec, prev_bg, prev_shot, prev_t, prev_rig = previous
        if prev_rig != x.rig_version:
            return          # the rig changed between the frames: their residuals differ by that, not by noise
        if x.t is not None and prev_t is not None and not 0 < x.t - prev_t < 0.25:
            return
        diff = vectors - prev_vec
        seen = np.isfinite(diff).all(axis=2)
        count = int(seen.sum())
        if count < 4:
            return
        survive = max(1 - 6 / (2 * count), 0.2)
        # Per centre and axis, E Δr² / survive = σ_k² + σ_{k−1}².
        energy = diff ** 2 / survive                                             # (2, 5, 2)
        design = np.stack([np.broadcast_to(v_bg + prev_bg, energy.shape), v_shot + prev_shot], axis=3)  # (2,5,2,2)
        self.frames += 1
        rate = max(1.0 / self.frames, 1.0 / self.calibration_frames)
        for cam in (0, 1):
            e = energy[cam][seen[cam]].reshape(-1)
            d = design[cam][seen[cam]].reshape(-1, 2)
            expected = d @ np.maximum(self.coefficients[cam], tol.floor)
            if len(e) == 0:
                continue
            if self.frames > 10:
                # A glint that comes and goes is not noise, and must not teach
                # the model that it is: a change beyond what χ² with 1 dof
                # reaches once in 100 (×6.6) is left out. "Expected" is
                # rescaled to what the frame's quieter centres show (its 30th
                # percentile against χ²₁'s, 0.148), so a model already
                # inflated by glints cannot keep the glints in.
                ratio = e / np.maximum(expected, tol.zero)
                level = max(float(np.percentile(ratio, 30)) / 0.148, 1e-3)
                keep = ratio <= 6.6 * level
                e, d, expected = e[keep], d[keep], expected[keep]
                if len(e) == 0:
                    continue
            # Relative errors, each frame weighing the same in the average.
            scale2 = 1.0 / np.maximum(expected, 1e-8) ** 2
            scale2 /= scale2.mean()
            self.normal[cam] = (1 - rate) * self.normal[cam] + rate * (d.T * scale2) @ d
            self.rhs[cam] = (1 - rate) * self.rhs[cam] + rate * (d.T * scale2) @ e
            self.coefficients[cam] = _nonnegative_solve(self.normal[cam], self.rhs[cam], self.coefficients[cam])


# Centroid noise below this (px) is not believed: quantization of the 8-bit
# levels alone leaves about this much on a bright blob.
_SIGMA_FLOOR_PX = 0.002

# 99th percentile of χ² with 2 degrees of freedom (scipy.stats.chi2.ppf(0.99, 2) = −2 ln 0.01).
_CHI2_2DOF_99 = -2 * math.log(0.01)


def _nonnegative_solve(normal: np.ndarray, rhs: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """argmin of the quadratic with both coefficients ≥ 0 (2x2: try the full solve, then each alone)."""
    candidates = []
    if abs(np.linalg.det(normal)) > tol.zero * max(np.abs(normal).max(), 1e-30) ** 2:
        full = np.linalg.solve(normal, rhs)
        if (full >= 0).all():
            return full
    for k in (0, 1):
        if normal[k, k] > 0:
            c = np.zeros(2)
            c[k] = max(rhs[k] / normal[k, k], 0.0)
            candidates.append(c)
    if not candidates:
        return fallback
    cost = [c @ normal @ c - 2 * c @ rhs for c in candidates]
    return candidates[int(np.argmin(cost))]


class PaperPixelClouds:
    """Martinez et al.'s pixel-cloud sampling estimator (see the module docstring).

    Parameters
    ----------
    rig : headplod.io.Rig
    model_mm : (5, 3)
    ratio : float
        Fraction of each marker's 3D cloud kept (the paper: 0.3).
    deterministic : bool
        Strided sub-samples and a fixed draw of combinations instead of fresh
        random draws every frame.
    gap_mm : float
        Largest distance between the two viewing rays of a kept pixel pair
        (the paper: 2.0 mm, the first peak of its Fig. 10 histogram).
    structure : float
        Largest difference of the two pixels' distances to their blob
        centres, each divided by its blob's RMS radius. The paper compared raw
        pixel distances with a threshold set to "the mean difference over
        frames"; normalizing by the blob's size makes the rule hold when the
        two cameras see the marker at different distances and angles.
    max_combinations : int
        Combinations of one point per marker evaluated per frame: the full
        product (often 10⁶ and more) is replaced by this many combinations
        drawn uniformly, which bounds time and memory; the sample covariance
        of 4096 draws is within ±3% (1σ) of the full product's.
    window_px : int
        Side of the window searched for each marker's pixels.
    """

    name = "paper"

    def __init__(self, rig, model_mm, ratio: float = 0.3, deterministic: bool = False, gap_mm: float = 2.0,
                 structure: float = 0.5, max_combinations: int = 4096, window_px: int = 31, seed: int = 0):
        self.rig, self.model_mm = rig, np.asarray(model_mm, np.float64)
        self.ratio, self.deterministic = ratio, deterministic
        self.gap_mm, self.structure = gap_mm, structure
        self.max_combinations, self.window_px = max_combinations, window_px
        self.signs = geo.normal_signs(self.model_mm)
        self.seed = seed
        self.name = "paper_deterministic" if deterministic else "paper"
        self.reset()

    def reset(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.last_gaps_mm = np.zeros(0)

    def clouds(self, x: CovarianceInput):
        """Per marker, the 3D points of its kept pixel pairs (list of (k, 3) mm), and every pair's ray gap."""
        pixels = [marker_pixels(x.images[cam], x.centers_px[cam], x.thresholds_dn[cam], self.window_px)
                  for cam in (0, 1)]
        clouds, gaps_all = [], []
        for k in range(5):
            (pl, dl), (pr, dr) = pixels[0][k], pixels[1][k]
            if len(pl) == 0 or len(pr) == 0 or not x.visible[:, k].all():
                clouds.append(np.zeros((0, 3)))
                continue
            xl = geo.undistort(pl, self.rig.K1, self.rig.D1)
            xr = geo.undistort(pr, self.rig.K2, self.rig.D2)
            il, ir = np.meshgrid(np.arange(len(pl)), np.arange(len(pr)), indexing="ij")
            il, ir = il.ravel(), ir.ravel()
            points, gaps = geo.triangulate_midpoint(xl[il], xr[ir], self.rig.R, self.rig.T)
            gaps_all.append(gaps)
            keep = (gaps < self.gap_mm) & (np.abs(dl[il] - dr[ir]) < self.structure)
            clouds.append(points[keep])
        self.last_gaps_mm = np.concatenate(gaps_all) if gaps_all else np.zeros(0)
        return clouds

    def __call__(self, x: CovarianceInput) -> np.ndarray:
        clouds = self.clouds(x)
        if any(len(c) == 0 for c in clouds):
            return np.full((2, 2), np.nan)            # a marker without pairs: no estimate
        rng = np.random.default_rng(self.seed) if self.deterministic else self.rng
        subsets = []
        for cloud in clouds:
            keep = max(int(round(self.ratio * len(cloud))), 1)
            if self.deterministic:
                index = np.linspace(0, len(cloud) - 1, keep).round().astype(np.int64)
            else:
                index = rng.choice(len(cloud), keep, replace=False)
            subsets.append(cloud[index])
        sizes = [len(s) for s in subsets]
        total = math.prod(sizes)
        if total <= self.max_combinations:
            grids = np.meshgrid(*[np.arange(n) for n in sizes], indexing="ij")
            choice = np.stack([g.ravel() for g in grids], axis=1)
        else:
            choice = np.stack([rng.integers(0, n, self.max_combinations) for n in sizes], axis=1)
        points = np.stack([subsets[k][choice[:, k]] for k in range(5)], axis=1)     # (M, 5, 3)
        directions = geo.view_directions(points, self.signs)
        angles = view_angles_deg(directions, x.axes)
        if len(angles) < 3:
            return np.full((2, 2), np.nan)
        return np.cov(angles.T)


def marker_pixels(image: np.ndarray, centers_px: np.ndarray, threshold_dn: float, window_px: int):
    """Each marker's thresholded pixels: list of 5 (pixels (k, 2) px, distance to the centre / RMS radius (k,))."""
    height, width = image.shape
    half = window_px // 2
    out = []
    for c in centers_px:
        if not np.isfinite(c).all():
            out.append((np.zeros((0, 2)), np.zeros(0)))
            continue
        x0, y0 = max(int(round(c[0])) - half, 0), max(int(round(c[1])) - half, 0)
        win = image[y0:min(y0 + window_px, height), x0:min(x0 + window_px, width)]
        ys, xs = np.nonzero(win >= threshold_dn)
        pts = np.column_stack([xs + x0, ys + y0]).astype(np.float64)
        dist = np.linalg.norm(pts - c, axis=1)
        rms = math.sqrt(float(np.mean(dist ** 2))) if len(dist) else 1.0
        out.append((pts, dist / max(rms, tol.floor)))
    return out


class Smoothed:
    """Exponential moving average of another estimator's covariance (time constant ``frames``)."""

    def __init__(self, inner, frames: int = 15):
        self.inner, self.frames = inner, frames
        self.name = inner.name + "_smoothed"
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        self.value, self.count = None, 0

    def __call__(self, x: CovarianceInput) -> np.ndarray:
        cov = self.inner(x)
        if not np.isfinite(cov).all():
            return self.value if self.value is not None else cov
        self.count += 1
        rate = max(1.0 / self.count, 1.0 / self.frames)
        self.value = cov if self.value is None else (1 - rate) * self.value + rate * cov
        return self.value


class Fixed:
    """The largest covariance (by trace) measured so far: the paper's 'fixed' scenario."""

    def __init__(self, inner):
        self.inner = inner
        self.name = inner.name + "_fixed"
        self.reset()

    def reset(self) -> None:
        self.inner.reset()
        self.value = None

    def __call__(self, x: CovarianceInput) -> np.ndarray:
        cov = self.inner(x)
        if np.isfinite(cov).all() and (self.value is None or np.trace(cov) > np.trace(self.value)):
            self.value = cov
        return self.value if self.value is not None else cov


def make_covariance_estimator(name: str, rig, model_mm, axes_G):
    """An estimator by name (one of :data:`COVARIANCE_ESTIMATORS`)."""
    if name not in COVARIANCE_ESTIMATORS:
        raise ValueError(f"covariance estimator must be one of {COVARIANCE_ESTIMATORS}, got {name!r}")
    base, _, variant = name.partition("_")
    if name.startswith("first_order"):
        variant = name[len("first_order"):].lstrip("_")
        if variant == "smoothed":
            return FirstOrder(axes_G, smoothing_frames=5)
        inner = FirstOrder(axes_G)
    else:
        inner = PaperPixelClouds(rig, model_mm, deterministic=(variant == "deterministic"))
    if variant == "smoothed":
        return Smoothed(inner)
    if variant == "fixed":
        return Fixed(inner)
    return inner
