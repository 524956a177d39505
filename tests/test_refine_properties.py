"""The rig refiner and the rig's residual rows cannot lose definiteness or raise (issue 21).

Frames are synthetic and exact: the default marker model, posed by a
chosen motion, projected by the sample rig (``tests/data/sweep12/rig.yaml``,
baseline 350 mm) into both cameras (no images), with optional centroid
noise, a rolling shutter (each marker seen at the time its row is
exposed), an exposure offset of the right camera and outliers. They drive
:class:`RigRefiner` and :func:`rig_residual_rows` directly.

After every frame the refiner's covariances must be finite, exactly
symmetric and positive definite; every chunk must either update the rig or
be counted in ``skipped_chunks``, and a skipped chunk must leave the
estimate, its covariance and the rig in use exactly as they were.
"""
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from headplod import io
from headplod.tracking import geometry as geo
from headplod.tracking import rig_refine, rig_solve
from headplod.tracking.rig_estimator import RigEstimator
from headplod.tracking.rig_refine import N_RIG, RigRefiner, RigState, rig_jacobian_rows
from headplod.tracking.uncertainty import rig_residual_rows

RIG = io.read_rig(Path(__file__).parent / "data" / "sweep12" / "rig.yaml")
MODEL = io.default_marker_model().points_mm
CAMERAS = geo.StereoCameras(RIG)
FACING = cv2.Rodrigues(np.array([np.pi, 0.0, 0.0]))[0]     # G's z towards the cameras
CENTRE = np.array([-170.0, 0.0, 650.0])                     # between the cameras, 65 cm away
ALL_VISIBLE = np.ones((2, 5), bool)
MOTIONS = ("still", "translation", "rotation", "general")


def _pose(t: float, motion: str, amp: float = 1.0):
    """R_world_G (3, 3), P1 (3,) mm of the head at t (s): still, pure translation,
    pure rotation about the world's y axis, or a general motion of ±0.3-0.5·amp rad."""
    if motion == "still":
        return FACING, CENTRE.copy()
    if motion == "translation":
        return FACING, CENTRE + amp * np.array([80 * np.sin(2.1 * t), 30 * np.sin(1.3 * t), 50 * np.sin(0.7 * t)])
    if motion == "rotation":
        return cv2.Rodrigues(np.array([0.0, 0.4 * amp * np.sin(1.7 * t), 0.0]))[0] @ FACING, CENTRE.copy()
    turn = amp * np.array([0.3 * np.sin(1.3 * t), 0.5 * np.sin(1.7 * t), 0.1 * np.sin(0.9 * t)])
    shift = amp * np.array([60 * np.sin(1.1 * t), 20 * np.sin(0.8 * t), 40 * np.sin(0.6 * t)])
    return cv2.Rodrigues(turn)[0] @ FACING, CENTRE + shift


def _project(points, R, T, K, D):
    return cv2.projectPoints(points.reshape(-1, 1, 3), cv2.Rodrigues(np.asarray(R, float))[0],
                             np.asarray(T, float).reshape(3), np.asarray(K, float), np.asarray(D, float))[0].reshape(-1, 2)


def _centres(t, motion, amp=1.0, right_dt=0.0, rolling_s=0.0, rig=RIG):
    """Exact centres (2, 5, 2) px: the left image exposed at t, the right at t + right_dt (s); with a
    rolling shutter (rows read out over ``rolling_s``, the middle row at the frame's time: row r of H at
    (r − (H−1)/2) rolling_s/(H−1)) each marker is where the head was when its row was exposed (the row
    it has at the frame's time: tests/test_rig_refine_readout.py solves for the exact row)."""
    centres = np.empty((2, 5, 2))
    height = rig.image_size[1]
    views = ((np.eye(3), np.zeros(3), rig.K1, rig.D1), (rig.R, rig.T, rig.K2, rig.D2))
    for cam, (Rc, Tc, K, D) in enumerate(views):
        tc = t + (right_dt if cam else 0.0)
        R, p = _pose(tc, motion, amp)
        px = _project(MODEL @ R.T + p, Rc, Tc, K, D)
        if rolling_s:
            for k, row_dt in enumerate(rolling_s * (px[:, 1] - 0.5 * (height - 1)) / (height - 1)):
                Rk, pk = _pose(tc + row_dt, motion, amp)
                px[k] = _project(MODEL[k:k + 1] @ Rk.T + pk, Rc, Tc, K, D)[0]
        centres[cam] = px
    return centres


def _assert_spd(M):
    assert M.shape == (N_RIG, N_RIG)
    assert np.isfinite(M).all()
    np.testing.assert_array_equal(M, M.T)
    assert np.linalg.eigvalsh(M).min() > 0
    np.linalg.cholesky(M)


def _snapshot(ref: RigRefiner):
    est, use = ref.estimator.estimate, ref.estimator.state
    return (est.R.copy(), est.T.copy(), est.log_focal, est.offset_s, ref.estimator.P.copy(), ref.estimator.cov().copy(),
            use.R.copy(), use.T.copy(), use.log_focal, use.offset_s, ref.estimator.updates, ref.estimator.versions,
            ref.estimator.refined.copy(), len(ref.estimator.bumps))


def _assert_same(a, b):
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def _checked(ref: RigRefiner, call):
    """A call of the refiner, then the invariants: SPD covariances; a skipped chunk changed nothing.
    (A chunk's update runs over the add_frame calls after the one completing it: any call may end one.)"""
    before = _snapshot(ref)
    skipped, updates = sum(ref.estimator.skipped_chunks.values()), ref.estimator.updates
    call()
    _assert_spd(ref.estimator.cov())
    _assert_spd(ref.estimator.P)
    # (One call may end a skipped chunk's job and then solve the next chunk at once — the first update
    # is (RigRefineConfig.first_at_once) — which does change the state: the skip alone must not.)
    if sum(ref.estimator.skipped_chunks.values()) > skipped and ref.estimator.updates == updates:
        _assert_same(_snapshot(ref), before)


def _add(ref: RigRefiner, t, declared, centres, visible, sigma, R, p1):
    _checked(ref, lambda: ref.add_frame(t, declared, centres, visible, sigma, R, p1))


def _flush(ref: RigRefiner):
    _checked(ref, ref.flush)


# --------------------------------------------------------------------------- the refiner


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(motion=st.sampled_from(MOTIONS), amp=st.floats(0.0, 3.0),
       step=st.sampled_from([1 / 30, 1e-3, 0.0]),
       right_dt=st.sampled_from([0.0, 1e-3, -1e-3, 0.008, -0.03, 0.5, -0.5]),
       declared=st.booleans(), rolling=st.sampled_from([0.0, 0.03]), outlier=st.booleans(),
       seed=st.integers(0, 2 ** 16))
def test_refiner_stays_definite_whatever_the_motion(motion, amp, step, right_dt, declared, rolling, outlier, seed):
    """A still head, pure translation, pure rotation about one axis or a general motion; frames 33 ms,
    1 ms or 0 s apart; the right image up to ±0.5 s off, declared or not; a 50 px outlier."""
    rng = np.random.default_rng(seed)
    ref = RigRefiner(RIG, MODEL, offset_declared=declared)
    sigma = np.full((2, 5), 0.05)
    for i in range(24):
        t = 10.0 + i * step
        centres = _centres(t, motion, amp, right_dt, rolling) + rng.normal(0.0, 0.05, (2, 5, 2))
        if outlier and i % 5 == 2:
            centres[rng.integers(2), rng.integers(5)] += 50.0 * np.array([0.6, 0.8])
        R, p1 = _pose(t, motion, amp)
        _add(ref, t, right_dt if declared else 0.0, centres, ALL_VISIBLE, sigma, R, p1)
    _flush(ref)                     # the last chunk's update
    # Every chunk either updated the rig or was counted with its reason.
    assert ref.estimator.updates + sum(ref.estimator.skipped_chunks.values()) == 3
    assert set(ref.estimator.skipped_chunks) <= {rig_refine.SKIP_UNOBSERVABLE, rig_refine.SKIP_NO_DATA,
                                       rig_refine.SKIP_NON_FINITE, rig_refine.SKIP_SINGULAR,
                                       rig_refine.SKIP_INCONSISTENT}


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(depth=st.floats(120.0, 1e5), lateral=st.floats(-1e4, 1e4), sigma_exp=st.floats(-6.0, 3.0),
       off_px=st.floats(-1e4, 1e4), visible=st.lists(st.booleans(), min_size=10, max_size=10),
       step=st.sampled_from([1 / 30, 1e-3, 0.0]), right_dt=st.sampled_from([0.0, 0.5, -0.5]),
       seed=st.integers(0, 2 ** 16))
def test_refiner_stays_definite_on_extreme_values(depth, lateral, sigma_exp, off_px, visible, step, right_dt, seed):
    """NaN-free but extreme: the head 12 cm to 100 m away and 10 m aside, centre noise 1e-6 to 1000 px,
    a centre thousands of px off, any subset of the centres seen (possibly too few for a pose)."""
    rng = np.random.default_rng(seed)
    ref = RigRefiner(RIG, MODEL)
    vis = np.array(visible).reshape(2, 5)
    sigma = np.full((2, 5), 10.0 ** sigma_exp)
    for i in range(16):
        t = i * step
        R, _ = _pose(t, "general")
        p1 = np.array([lateral, 0.0, depth]) + (_pose(t, "translation")[1] - CENTRE)
        world = MODEL @ R.T + p1
        centres = np.stack([_project(world, np.eye(3), np.zeros(3), RIG.K1, RIG.D1),
                            _project(world, RIG.R, RIG.T, RIG.K2, RIG.D2)])
        centres = centres + rng.normal(0.0, min(10.0 ** sigma_exp, 1.0), centres.shape)
        centres[i % 2, i % 5] += off_px
        _add(ref, t, right_dt, centres, vis, sigma, R, p1)
    _flush(ref)
    assert ref.estimator.updates + sum(ref.estimator.skipped_chunks.values()) == 2


def test_singular_chunk_leaves_the_state_unchanged():
    # A rig whose right camera is turned 0.3° from rig.yaml: the updates move the estimate.
    turn = cv2.Rodrigues(np.radians(0.3) * np.array([0.24, 0.96, 0.14]))[0]
    true_rig = io.Rig(RIG.image_size, RIG.K1, RIG.D1, RIG.K2, RIG.D2, turn @ RIG.R, turn @ np.asarray(RIG.T).ravel())
    rng = np.random.default_rng(0)
    ref = RigRefiner(RIG, MODEL)
    sigma = np.full((2, 5), 0.05)

    def feed(frames, visible=ALL_VISIBLE, blank=False, start=0):
        for i in range(start, start + frames):
            t = i / 30
            centres = _centres(t, "general", rig=true_rig) + rng.normal(0.0, 0.05, (2, 5, 2))
            if blank:
                centres[:] = np.nan
            _add(ref, t, 0.0, centres, visible, sigma, *_pose(t, "general"))
        _flush(ref)                 # the last chunk's update (the frames make whole chunks)

    feed(16)
    assert ref.estimator.updates == 2 and not ref.estimator.skipped_chunks
    assert np.abs(ref.estimator.estimate.error_from(RigState(RIG))[:3]).max() > 1e-4     # it learnt part of the turn
    before = _snapshot(ref)
    # Two centres of the left image and none of the right: 4 rows for 6 pose parameters per frame.
    two = np.array([[True, True, False, False, False], [False] * 5])
    feed(8, visible=two, start=16)
    assert ref.estimator.skipped_chunks == {rig_refine.SKIP_SINGULAR: 1}
    assert ref.estimator.last_skip == (23 / 30, rig_refine.SKIP_SINGULAR)
    _assert_same(_snapshot(ref), before)
    # Seen but every centre NaN: no usable row at all.
    feed(8, blank=True, start=24)
    assert ref.estimator.skipped_chunks[rig_refine.SKIP_NO_DATA] == 1
    _assert_same(_snapshot(ref), before)
    # Frames without a finite time or pose are not used at all (the chunk does not even fill).
    ref.add_frame(float("nan"), 0.0, _centres(1.0, "general"), ALL_VISIBLE, sigma, *_pose(1.0, "general"))
    ref.add_frame(1.0, 0.0, _centres(1.0, "general"), ALL_VISIBLE, sigma, np.full((3, 3), np.nan), CENTRE)
    assert ref.estimator.ignored_frames == 2 and not ref.scheduler.pending
    # And the refiner goes on learning afterwards.
    feed(8, start=32)
    assert ref.estimator.updates == 3


@pytest.mark.slow
def test_rolling_shutter_sequence_keeps_the_prior_definite():
    """Bug 1: rows exposed over 30 ms, a head moving fast; `np.linalg.cholesky(prior)` in `_solve` raised
    'Matrix is not positive definite' at frame 63 (the noise-inflated posterior's variances passed the
    prior's, and capping the diagonal alone left the correlations too large)."""
    rng = np.random.default_rng(3)
    ref = RigRefiner(RIG, MODEL)
    sigma = np.full((2, 5), 0.05)
    for i in range(80):
        t = i / 30
        centres = _centres(t, "general", amp=4.0, rolling_s=0.03) + rng.normal(0.0, 0.05, (2, 5, 2))
        _add(ref, t, 0.0, centres, ALL_VISIBLE, sigma, *_pose(t, "general", 4.0))
    _flush(ref)
    assert ref.estimator.updates >= 8            # of 10 chunks: the refinement still runs
    assert ref.estimator.updates + sum(ref.estimator.skipped_chunks.values()) == 10


def test_predicted_prior_caps_variances_without_losing_definiteness():
    """The mechanism of bug 1: a posterior whose shift-z and focal variances exceed the prior's, the
    two 98% correlated. Capping the diagonal alone gives an indefinite matrix; the prior of the next
    chunk must be SPD, with the variances capped and the correlation kept."""
    est = RigEstimator(RIG, MODEL)
    sd = np.sqrt(np.diag(est.prior))
    corr = np.eye(N_RIG)
    corr[5, 6] = corr[6, 5] = 0.98
    ratio = np.ones(N_RIG)
    ratio[5], ratio[6] = 1.2, 1.1
    est.P = corr * np.outer(sd * ratio, sd * ratio)
    _assert_spd(est.P)
    capped_diagonal = est.P.copy()
    np.fill_diagonal(capped_diagonal, np.minimum(np.diag(est.P), np.diag(est.prior)))
    assert np.linalg.eigvalsh(capped_diagonal).min() < 0          # what the old cap did
    prior = est.predicted_prior(0.0)
    _assert_spd(prior)
    np.testing.assert_allclose(np.diag(prior), np.minimum(np.diag(est.P), np.diag(est.prior)), rtol=1e-12)
    np.testing.assert_allclose(prior[5, 6] / np.sqrt(prior[5, 5] * prior[6, 6]), 0.98, rtol=1e-12)


def test_cov_stays_definite_in_raw_units_for_an_absurd_departure():
    """A posterior singular along one direction (but for the floor), and the rig in use 1e5 prior σ
    from the estimate: P + d dᵀ spans 17 orders of magnitude in rad, mm and s, where rounding alone
    gives eigvalsh a negative eigenvalue (-1e-4 here); cov() must stay positive definite."""
    est = RigEstimator(RIG, MODEL)
    sd = np.sqrt(np.diag(est.prior))
    rng = np.random.default_rng(0)
    u = rng.normal(size=N_RIG)
    u /= np.linalg.norm(u)
    est.P = rig_solve._positive_definite(est.prior - np.outer(sd * u, sd * u), sd)
    _assert_spd(est.P)
    departure = np.zeros(N_RIG)
    departure[3:6] = 1e5 * sd[3:6] * rng.normal(size=3)
    est._estimate = est.state.moved(departure)
    est._cov = None
    _assert_spd(est.cov())
    # The floor acts only at the rounding level: the departure's variance is kept.
    d = est._estimate.error_from(est.state)
    assert d @ est.cov() @ d == pytest.approx((d @ d) ** 2, rel=1e-6)


def test_positive_definite_floor():
    """Indefinite or singular input becomes SPD with the eigenvalues floored in units of the prior;
    an input already above the floor comes back unchanged (only symmetrized)."""
    ref = RigRefiner(RIG, MODEL)
    sd = np.sqrt(np.diag(ref.estimator.prior))
    rng = np.random.default_rng(1)
    U = np.linalg.qr(rng.normal(size=(N_RIG, N_RIG)))[0]
    lam = np.array([-1e-3, 0.0, 1e-12, 1e-6, 0.1, 0.5, 1.0, 1.5, 2.0])
    M = (U * lam) @ U.T * np.outer(sd, sd)
    out = rig_solve._positive_definite(M, sd)
    _assert_spd(out)
    floored = np.linalg.eigvalsh(out / np.outer(sd, sd))
    assert floored.min() >= rig_solve._VARIANCE_FLOOR * (1 - 1e-6)
    np.testing.assert_allclose(floored[3:], lam[3:], rtol=1e-6)          # the rest untouched
    good = ref.estimator.prior + 0.1 * np.outer(sd, sd)
    np.testing.assert_array_equal(rig_solve._positive_definite(good, sd), good)
    with pytest.raises(rig_solve._SkipChunk):
        rig_solve._positive_definite(np.full((N_RIG, N_RIG), np.nan), sd)


# --------------------------------------------------------------------------- the rig's residual rows


def _assert_projection(J, Jr, w, M, rtol=1e-6):
    """M = (I − H) J_r: W-orthogonal to J's columns, and J_r − M in J's span (checked on the weighted rows)."""
    assert M.shape == Jr.shape and np.isfinite(M).all()
    s = np.sqrt(w)[:, None]
    Js, Jrs, Ms = J * s, Jr * s, M * s
    scale = np.outer(np.linalg.norm(Js, axis=0), np.linalg.norm(Jrs, axis=0)) + 1e-300
    assert np.all(np.abs(Js.T @ Ms) <= rtol * scale)
    fit = np.linalg.lstsq(Js, Jrs - Ms, rcond=None)[0]
    assert np.all(np.linalg.norm(Js @ fit - (Jrs - Ms), axis=0) <= rtol * (np.linalg.norm(Jrs, axis=0) + 1e-300))


def _rows(R, p1, visible, dt, omega, velocity, sigma):
    """The pose's and the rig's rows over the visible coordinates, and their weights, as the tracker
    builds them (``RigChecks.rig_after_fit``)."""
    pose = geo.reprojection_rows(R, p1, MODEL, visible, CAMERAS)
    world = MODEL @ R.T + p1
    rows = np.stack([_project(world, np.eye(3), np.zeros(3), RIG.K1, RIG.D1)[:, 1],
                     _project(world, RIG.R, RIG.T, RIG.K2, RIG.D2)[:, 1]])
    state = RigState(RIG, readout_s=0.03)
    rig = rig_jacobian_rows(R, p1, MODEL, state, np.asarray(RIG.D2), dt, omega, velocity, rows_px=rows,
                            image_height=RIG.image_size[1])
    return (pose[visible].reshape(-1, 6), rig[visible].reshape(-1, N_RIG),
            np.repeat(1.0 / np.square(sigma[visible]), 2))


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(motion=st.sampled_from(MOTIONS), t=st.floats(0.0, 10.0), depth=st.floats(150.0, 5000.0),
       dt=st.sampled_from([0.0, 1e-3, -1e-3, -0.021, -0.042, 0.5, -0.5]),
       visible=st.lists(st.booleans(), min_size=10, max_size=10).filter(any),   # (the pose rows need one)
       sigma_exp=st.floats(-4.0, 2.0), zero_weights=st.integers(0, 20),
       degenerate=st.sampled_from(["none", "duplicate column", "zero column"]))
def test_rig_residual_rows_is_a_projection_whatever_the_frame(motion, t, depth, dt, visible, sigma_exp,
                                                               zero_weights, degenerate):
    """Few or no visible markers, any distance, a still head (no offset column), offsets of ±0.5 s,
    weights of zero, and pose columns made exactly dependent: never an exception, always finite,
    and always the weighted projection."""
    R, p1 = _pose(t, motion)
    p1 = p1 * depth / CENTRE[2]
    previous = _pose(t - 1 / 30, motion)
    omega = cv2.Rodrigues(R @ previous[0].T)[0].ravel() * 30.0
    velocity = (p1 - previous[1] * depth / CENTRE[2]) * 30.0
    vis = np.array(visible).reshape(2, 5)
    J, Jr, w = _rows(R, p1, vis, dt, omega, velocity, np.full((2, 5), 10.0 ** sigma_exp))
    w[:zero_weights] = 0.0
    if degenerate == "duplicate column":
        J[:, 5] = J[:, 4]
    elif degenerate == "zero column":
        J[:, 0] = 0.0
    M = rig_residual_rows(J, Jr, w)
    _assert_projection(J, Jr, w, M)


def test_rig_residual_rows_with_the_right_time_before_the_left():
    """Bug 2: t_right 30 ms before t, the pose fit ended with the head on the right camera's focal
    plane (its projections and their derivatives ~1e21 px), and `np.linalg.solve` in
    `rig_residual_rows` raised 'Singular matrix'."""
    R = FACING
    # P1 300 mm aside, 0.1 mm in front of the right camera's focal plane (z_right = 0.1 mm).
    normal, T = np.asarray(RIG.R)[2], np.asarray(RIG.T).ravel()
    p1 = np.array([300.0, 0.0, 0.0])
    p1[2] = (0.1 - T[2] - normal[0] * p1[0]) / normal[2]
    assert p1[2] > 0                                                 # in front of the left camera
    J, Jr, w = _rows(R, p1, ALL_VISIBLE, -0.03, np.array([0.0, 0.5, 0.0]), np.array([50.0, 0.0, 0.0]),
                     np.full((2, 5), 0.05))
    assert np.abs(J).max() > 1e18                                    # the blown-up rows of the bug
    # The normal equations the old code solved are singular to working precision.
    assert np.linalg.cond(J.T @ (J * w[:, None])) > 1e20
    M = rig_residual_rows(J, Jr, w)
    _assert_projection(J, Jr, w, M)


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")     # inf × 0, on purpose
def test_rig_residual_rows_with_non_finite_inputs():
    """A row with a NaN or inf entry, or a NaN, infinite or negative weight, stays out of the fit:
    its own output row is NaN where its inputs are, every other row is the projection over the rest."""
    R, p1 = _pose(0.3, "general")
    J, Jr, w = _rows(R, p1, ALL_VISIBLE, 0.01, np.array([0.1, 0.4, 0.0]), np.array([30.0, 0.0, 0.0]),
                     np.full((2, 5), 0.05))
    good = np.ones(len(w), bool)
    J[2, 3] = np.nan
    Jr[7, 1] = np.inf
    w[11] = np.nan
    w[12] = np.inf
    w[13] = -1.0
    good[[2, 7, 11, 12, 13]] = False
    M = rig_residual_rows(J, Jr, w)
    assert np.isnan(M[2]).all() and not np.isfinite(M[7]).all()
    assert np.isfinite(M[[11, 12, 13]]).all()                        # finite rows, only left out of the fit
    _assert_projection(J[good], Jr[good], w[good], M[good])
    expected = rig_residual_rows(J[good], Jr[good], w[good])
    np.testing.assert_allclose(M[good], expected, rtol=1e-6, atol=1e-9 * np.abs(Jr[good]).max())
    # No row at all: an empty answer, not an error.
    assert rig_residual_rows(J[:0], Jr[:0], w[:0]).shape == (0, N_RIG)
