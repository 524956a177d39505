"""Is the covariance of V honest? NEES against the truth, and the pieces of the rig's share (issue 22).

Mean NEES of V (2 dof) should be near 2: within 1.5-2.6 on perfect rigs and
1.5-3 on imperfect ones (headplod.bench.rig.RIG_GOALS). Before the rig's
share learnt how far off rig.yaml is, a perfect rig's mean was 1.2-1.6
(the share stayed the error model's), which the sequences below show.
The parts are checked against their own definitions: the covariance of the
pose fitted with the rig as it is against a Monte Carlo of that fit, the
learnt error model against what the data put in it.
"""
import numpy as np
import pytest

from headplod import io
from headplod.bench.rig import run_rig_set
from headplod.bench.uncertainty import nees
from headplod.capture.synthetic import ensure_dataset
from headplod.live.loop import track_frames
from headplod.tracking.rig_refine import RigRefiner, scaled_error_distribution
from headplod.tracking.tracker import Tracker, TrackerConfig
from headplod.tracking.uncertainty import pose_error_covariance, rig_scale_from_frame, with_rig_uncertainty


# ------------------------------------------------------------------ sequences
def _mean_nees(preset, frames, **options):
    ds = io.Dataset(ensure_dataset(preset, frames=frames, quiet=True, **options))
    tracker = Tracker(ds.rig, ds.markers, TrackerConfig())
    values = [nees(r.cov_deg2, ds.truth[f.index][1][2], r.axes)
              for f, r in track_frames(ds, tracker) if r is not None and r.ok and f.index in ds.truth]
    assert len(values) >= 0.95 * frames
    return float(np.mean(values))


@pytest.mark.slow
def test_perfect_rig_nees_within_the_perfect_band():
    """imperfect_rig with no fault: rig.yaml is right; 5 s of looking around (was 1.55)."""
    folder = ensure_dataset("imperfect_rig", frames=150, quiet=True)
    assert 1.5 <= run_rig_set(folder)["nees_mean"] <= 2.6


@pytest.mark.slow
def test_still_head_nees_within_the_perfect_band():
    """A still head at 55 cm, 3 s, rig.yaml right: what a still head cannot teach of the rig stays
    unknown, and the share of it stayed the error model's (was 1.22)."""
    assert 1.5 <= _mean_nees("static", 90, distance_mm=550.0) <= 2.6


@pytest.mark.slow
def test_short_extreme_pose_nees_within_the_perfect_band():
    """40 frames at yaw 60° and roll 35°: most of them before the refinement knows much, when the share was
    the error model's whole (was 0.86)."""
    assert 1.5 <= _mean_nees("extreme", 40) <= 2.6


@pytest.mark.slow
def test_stale_rig_nees_within_the_band():
    """The right camera turned 0.5° since rig.yaml: the rig's share must stay as large as its error."""
    folder = ensure_dataset("imperfect_rig", frames=150, quiet=True, rotation_deg=0.5)
    assert 1.5 <= run_rig_set(folder)["nees_mean"] <= 3.0


# ------------------------------------------------------------------ the pose fitted with the rig as it is
def _linear_frame(rng, m=10, k=5):
    """A random linearized frame: pose rows J (m, 2, 6), nuisance rows J_r (m, 2, k), weights (m, 2)."""
    J = rng.normal(size=(m, 2, 6))
    Jr = rng.normal(size=(m, 2, k)) * 0.7
    w = rng.uniform(0.5, 2.0, size=(m, 2))
    return J, Jr, w


@pytest.mark.slow
def test_pose_error_covariance_is_the_fits_second_moment():
    """δp = G (J_r e + n), r = −(I − H)(J_r e + n): averaged over r, the conditional second moment given r
    is the fit's second moment (law of total expectation), signs included."""
    rng = np.random.default_rng(1)
    J, Jr, w = _linear_frame(rng)
    m, k = Jr.shape[0], Jr.shape[2]
    A = rng.normal(size=(k, k))
    C = A @ A.T / k + 0.1 * np.eye(k)
    mu = rng.normal(size=k) * 0.5
    info = np.einsum("mij,mik,mi->jk", J, J, w)
    Jf, Jrf, wf = J.reshape(-1, 6), Jr.reshape(-1, k), w.reshape(-1)
    G = np.linalg.solve(info, Jf.T * wf)
    second = np.zeros((6, 6))
    predicted = np.zeros((6, 6))
    n_draws = 4000
    for _ in range(n_draws):
        e = mu + np.linalg.cholesky(C) @ rng.normal(size=k)
        shift = Jrf @ e + rng.normal(size=2 * m) / np.sqrt(wf)        # the centres' displacement, px
        dp = G @ shift
        r = (Jf @ dp - shift).reshape(m, 2)                             # projected minus measured
        second += np.outer(dp, dp) / n_draws
        predicted += pose_error_covariance(info, J, Jr, w, C, r, mu) / n_draws
    np.testing.assert_allclose(predicted, second, atol=0.06 * np.abs(second).max())


def test_a_corrected_pose_has_the_joint_fits_covariance():
    """Corrected by what its residuals show of e, the pose is the joint fit's: the Schur complement."""
    rng = np.random.default_rng(2)
    J, Jr, w = _linear_frame(rng)
    C = np.diag(rng.uniform(0.2, 2.0, Jr.shape[2]))
    info = np.einsum("mij,mik,mi->jk", J, J, w)
    r = rng.normal(size=w.shape)
    np.testing.assert_allclose(pose_error_covariance(info, J, Jr, w, C, r, corrected=True),
                               np.linalg.inv(with_rig_uncertainty(info, J, Jr, w, C)), rtol=1e-8, atol=1e-12)


def test_a_frames_residuals_tell_the_error_models_scale():
    """Residuals with no rig error in them: the error model's scale is far below 1; with an error drawn from
    the error model itself: of order 1."""
    rng = np.random.default_rng(3)
    J, Jr, w = _linear_frame(rng, m=10, k=4)
    Jr *= 30.0                                  # the error model's rig moves centres by tens of σ
    info = np.einsum("mij,mik,mi->jk", J, J, w)
    C = np.eye(4)
    Jf, Jrf, wf = J.reshape(-1, 6), Jr.reshape(-1, 4), w.reshape(-1)
    G = np.linalg.solve(info, Jf.T * wf)

    def residuals(e):
        shift = Jrf @ e + rng.normal(size=len(wf)) / np.sqrt(wf)
        return (Jf @ (G @ shift) - shift).reshape(w.shape)

    assert rig_scale_from_frame(info, J, Jr, w, C, residuals(np.zeros(4))) < 0.01
    scales = [rig_scale_from_frame(info, J, Jr, w, C, residuals(rng.normal(size=4))) for _ in range(40)]
    assert 0.3 < np.median(scales) < 3.0


# ------------------------------------------------------------------ the rig's error model learnt
def _posterior(info_diag, delta):
    """The refinement's (P, estimate − reference) for a prior I and data with information info_diag (k,)
    saying the rig is off by delta (k,)."""
    P = np.diag(1.0 / (1.0 + info_diag))
    return P, P @ (info_diag * delta)


def test_a_rig_found_off_keeps_the_refinements_posterior():
    P, est = _posterior(np.full(4, 100.0), np.array([3.0, -2.0, 0.0, 1.0]))    # off by 2-3 prior σ
    mean, cov = scaled_error_distribution(P, np.eye(4), est, np.zeros(4), np.ones(4, bool))
    np.testing.assert_allclose(mean, est, rtol=0.02, atol=0.02)
    np.testing.assert_allclose(np.diag(cov), np.diag(P), rtol=0.1)


def test_a_rig_found_right_shrinks_its_share():
    """Data that put the rig within their own noise (σ 0.1 of the error model's) of rig.yaml: the rig in use
    (rig.yaml) is off by far less than P says."""
    rng = np.random.default_rng(4)
    P, est = _posterior(np.full(6, 100.0), rng.normal(size=6) * 0.1)
    mean, cov = scaled_error_distribution(P, np.eye(6), est, np.zeros(6), np.ones(6, bool))
    assert np.trace(cov) + mean @ mean < 0.3 * (np.trace(P) + est @ est)
    # ... and nothing is shrunk that the error model does not scale (the exposure offset's prior).
    scaled = np.array([True] * 5 + [False])
    _, cov = scaled_error_distribution(P, np.eye(6), est, np.zeros(6), scaled)
    assert cov[5, 5] == pytest.approx(P[5, 5], rel=0.05)


def test_without_data_the_error_model_stands(sweep12_dir):
    ds = io.Dataset(sweep12_dir)
    refiner = RigRefiner(ds.rig, ds.markers.points_mm)
    mean, cov = refiner.estimator.error_distribution()
    np.testing.assert_allclose(mean, 0.0, atol=1e-12)
    np.testing.assert_allclose(cov, refiner.estimator.prior, rtol=1e-9)
    assert not refiner.estimator.has_data() and refiner.estimator.data_scale() == 1.0
