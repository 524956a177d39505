"""The rolling shutter's readout time as the rig's 9th parameter.

Frames are synthetic and exact, as in ``tests/test_refine_properties.py``:
the default marker model posed by a chosen motion and projected by the
sample rig (640 x 480 px) into both cameras, no images. The cameras have a
rolling shutter by the dataset's contract: a frame's time is the exposure
of the image's MIDDLE row, and row r of an image H rows high is exposed at
t + (r − (H−1)/2) · readout / (H−1). Each centre is where its marker was
when the centre's own row was exposed (solved for by fixed-point
iteration), the right image ``offset`` later than the left one.
"""
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.tracking import rig_refine
from headplod.tracking.rig_estimator import RigEstimator
from headplod.tracking.rig_refine import (N_RIG, PARAMETERS, READOUT_ACTIVE_FRACTION, RigErrorModel, RigRefiner,
                                          RigState, readout_prior, rig_jacobian_rows)

# The sample rig, the default model and the head's motions of the property tests (one definition).
from test_refine_properties import ALL_VISIBLE, CENTRE, FACING, MODEL, RIG, _pose, _project  # noqa: E402,F401
HEIGHT = RIG.image_size[1]
READOUT = PARAMETERS.index("readout_s")
OFFSET = PARAMETERS.index("time_offset_s")
VIEWS = ((np.eye(3), np.zeros(3), RIG.K1, RIG.D1), (RIG.R, RIG.T, RIG.K2, RIG.D2))


def _row_time(row, readout_s):
    return (row - 0.5 * (HEIGHT - 1)) * readout_s / (HEIGHT - 1)


def _centres(t, motion, amp, offset_s, readout_s, views=VIEWS):
    """Exact centres (2, 5, 2) px of a rolling-shutter rig: each marker where it was when its own row
    was exposed (the row is the centre's: solved by fixed-point iteration to 1e-9 px)."""
    out = np.empty((2, 5, 2))
    for cam, (Rc, Tc, K, D) in enumerate(views):
        t_cam = t + (offset_s if cam else 0.0)
        for k in range(5):
            row = 0.5 * (HEIGHT - 1)
            for _ in range(50):
                R, p1 = _pose(t_cam + _row_time(row, readout_s), motion, amp)
                px = _project(MODEL[k:k + 1] @ R.T + p1, Rc, Tc, K, D)[0]
                done = abs(px[1] - row) < 1e-9
                row = px[1]
                if done:
                    break
            else:
                raise AssertionError("the row did not converge")
            out[cam, k] = px
    return out


def _run(readout_s, offset_s, motion="general", amp=2.0, seconds=5.0, noise_px=0.02, seed=0, **kwargs):
    """The refiner fed ``seconds`` of frames at 30 fps (exact poses, noisy centres); the right time
    undeclared. The readout's prior from the frame period (or the user's), as the tracker sets it."""
    rng = np.random.default_rng(seed)
    user = kwargs.get("error_model", RigErrorModel()).readout_s
    ref = RigRefiner(RIG, MODEL, readout_prior=readout_prior(1 / 30, user), **kwargs)
    sigma = np.full((2, 5), max(noise_px, 0.02))
    for i in range(int(round(seconds * 30))):
        t = i / 30
        centres = _centres(t, motion, amp, offset_s, readout_s) + rng.normal(0.0, noise_px, (2, 5, 2))
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, *_pose(t, motion, amp))
    ref.flush()
    return ref


# --------------------------------------------------------------------------- the prior


def test_readout_prior_rule():
    mean, sd = readout_prior(1 / 30, None)
    assert mean == pytest.approx(READOUT_ACTIVE_FRACTION / 30) and sd == pytest.approx(0.5 * mean)
    assert readout_prior(1 / 30, 0.021) == pytest.approx((0.021, 1.05e-3))        # the user's: 5%
    assert readout_prior(None, 0.004) == pytest.approx((0.004, 5e-4))             # ... or 0.5 ms
    assert readout_prior(1 / 30, 0.0) == pytest.approx((0.0, 2e-4))               # a global shutter
    assert readout_prior(None, None) == rig_refine.READOUT_PRIOR_UNKNOWN
    assert readout_prior(float("nan"), None) == rig_refine.READOUT_PRIOR_UNKNOWN
    assert RigErrorModel(readout_s=0.02).readout_prior(1 / 60) == pytest.approx((0.02, 1e-3))


def test_refiner_takes_the_readout_prior():
    ref = RigRefiner(RIG, MODEL, JOB)
    assert ref.estimator.prior.shape == (N_RIG, N_RIG) == (9, 9) and ref.estimator.estimate.readout_s == 0.0
    assert math.sqrt(ref.estimator.prior[READOUT, READOUT]) == rig_refine.READOUT_PRIOR_UNKNOWN[1]
    user = RigRefiner(RIG, MODEL, error_model=RigErrorModel(readout_s=0.025))
    assert user.estimator.state.readout_s == user.estimator.estimate.readout_s == 0.025
    assert math.sqrt(user.estimator.prior[READOUT, READOUT]) == pytest.approx(1.25e-3)
    given = RigRefiner(RIG, MODEL, readout_prior=(0.03, 0.004))
    assert given.estimator.estimate.readout_s == 0.03
    assert math.sqrt(given.estimator.prior[READOUT, READOUT]) == pytest.approx(0.004)
    with pytest.raises(ValueError):
        RigRefiner(RIG, MODEL, readout_prior=(0.03, 0.0))


def test_set_readout_prior_until_the_first_update():
    ref = RigRefiner(RIG, MODEL, JOB)
    ref.widen(0.0)                                       # P twice the prior: stays twice
    before = ref.estimator.P.copy()
    assert ref.set_readout_prior(0.0307, 0.015)
    assert ref.estimator.state.readout_s == ref.estimator.estimate.readout_s == 0.0307
    assert ref.estimator.prior[READOUT, READOUT] == pytest.approx(0.015 ** 2)
    assert ref.estimator.P[READOUT, READOUT] == pytest.approx(2 * 0.015 ** 2)
    np.testing.assert_array_equal(ref.estimator.P[:READOUT, :READOUT], before[:READOUT, :READOUT])
    assert ref.estimator._scale[READOUT] == pytest.approx(0.015)
    L_inv = ref.estimator._prior_L_inv
    np.testing.assert_allclose(L_inv @ ref.estimator.prior @ L_inv.T, np.eye(N_RIG), atol=1e-12)
    assert ref.estimator.cov()[READOUT, READOUT] == pytest.approx(2 * 0.015 ** 2)
    ref.reset()                                          # back to rig.yaml, with the readout's prior set last
    assert ref.estimator.estimate.readout_s == 0.0307 and ref.estimator.P[READOUT, READOUT] == pytest.approx(0.015 ** 2)
    # Once an update has used the prior, it stays.
    ref = _run(0.0, 0.0, seconds=0.6)
    assert ref.estimator.updates >= 1
    P = ref.estimator.P.copy()
    assert not ref.set_readout_prior(0.01, 0.001)
    np.testing.assert_array_equal(ref.estimator.P, P)


# --------------------------------------------------------------------------- the model's derivatives


def _linear_model(R, p1, omega, velocity, rows, right_dt, state):
    """Both cameras' centres by the refiner's model: each point moved linearly over its row's time."""
    lever = MODEL @ R.T
    motion = np.cross(omega, lever) + velocity
    out = np.empty((2, 5, 2))
    for cam, (_, _, K, D) in enumerate(VIEWS):
        dt = (right_dt if cam else 0.0) + _row_time(rows[cam], state.readout_s)
        world = lever + p1 + dt[:, None] * motion
        Rc, Tc = (np.eye(3), np.zeros(3)) if cam == 0 else (state.R, state.T)
        out[cam] = _project(world, Rc, Tc, state.K2() if cam else K, D)
    return out


@pytest.mark.parametrize("readout_s", [0.0, 0.03])
def test_rig_jacobian_rows_readout_column_in_both_cameras(readout_s):
    R, p1 = _pose(1.3, "general", 2.0)
    omega, velocity = np.array([0.4, -1.1, 0.3]), np.array([120.0, -60.0, 40.0])
    rows = _centres(1.3, "general", 2.0, 0.01, readout_s)[..., 1]
    state = RigState(RIG, readout_s=readout_s)
    J = rig_jacobian_rows(R, p1, MODEL, state, np.asarray(RIG.D2), 0.01, omega, velocity, rows_px=rows,
                          image_height=HEIGHT)
    assert J.shape == (2, 5, 2, 9)
    # The left camera's rows: the readout's column only, and not zero with a moving head.
    assert np.all(J[0, :, :, :READOUT] == 0) and np.abs(J[0, :, :, READOUT]).max() > 1.0
    h = 1e-6
    plus, minus = RigState(RIG, readout_s=readout_s + h), RigState(RIG, readout_s=readout_s - h)
    numeric = (_linear_model(R, p1, omega, velocity, rows, 0.01, plus)
               - _linear_model(R, p1, omega, velocity, rows, 0.01, minus)) / (2 * h)
    np.testing.assert_allclose(J[..., READOUT], numeric, rtol=1e-5, atol=1e-3)
    # The offset's column: the right camera's image speed; the readout's is it times the row's fraction.
    frac = (rows[1] - 0.5 * (HEIGHT - 1)) / (HEIGHT - 1)
    np.testing.assert_allclose(J[1, :, :, READOUT], J[1, :, :, OFFSET] * frac[:, None], rtol=1e-12)
    # Without the rows (or without motion): as before the readout, left rows zero.
    old = rig_jacobian_rows(R, p1, MODEL, RigState(RIG), np.asarray(RIG.D2), 0.01, omega, velocity)
    assert np.all(old[0] == 0) and np.all(old[..., READOUT] == 0)
    still = rig_jacobian_rows(R, p1, MODEL, state, np.asarray(RIG.D2), 0.01, rows_px=rows)
    assert np.all(still[..., OFFSET] == 0) and np.all(still[..., READOUT] == 0)


# --------------------------------------------------------------------------- recovery


@pytest.mark.slow
@pytest.mark.parametrize("readout_s, offset_s", [(0.0, 0.0), (0.0, 0.012), (0.015, 0.0), (0.015, 0.008),
                                                 (0.03, 0.0), (0.03, 0.010)])
def test_refiner_recovers_readout_and_offset(readout_s, offset_s):
    """5 s of a varied head motion (turns up to ±1 rad, moves of ±120 mm), centres to 0.02 px: the
    readout within 5% or 1 ms and the undeclared offset within 1 ms, each within 3σ of its own."""
    ref = _run(readout_s, offset_s)
    est = ref.estimator.estimate
    sd = np.sqrt(np.diag(ref.estimator.P))
    assert ref.estimator.refined[READOUT] and ref.estimator.refined[OFFSET] and not ref.estimator.skipped_chunks
    err_readout, err_offset = est.readout_s - readout_s, est.offset_s - offset_s
    assert abs(err_readout) <= max(0.05 * readout_s, 1e-3), (err_readout, sd[READOUT])
    assert abs(err_readout) <= 3 * sd[READOUT] and sd[READOUT] < 1e-3
    assert abs(err_offset) <= 1e-3 and abs(err_offset) <= 3 * sd[OFFSET]
    status = ref.status()
    assert status["readout_sd_ms"] == pytest.approx(ref.estimator.sigma()[READOUT] * 1e3, abs=1e-3)
    assert "rolling shutter" in ref.describe()
    assert ref.estimator.state.rig().extra["refined_readout_ms"] == round(ref.estimator.state.readout_s * 1e3, 4)


@pytest.mark.slow
def test_still_head_leaves_the_readout_at_its_prior():
    """A still head shows no row's time: the readout is not refined, the estimate stays at the prior's mean
    (the turn and shift are still learnt)."""
    for motion, amp in (("still", 1.0), ("general", 0.0)):
        ref = _run(0.03, 0.01, motion=motion, amp=amp, seconds=2.0)
        mean = READOUT_ACTIVE_FRACTION / 30
        assert not ref.estimator.refined[READOUT] and not ref.estimator.refined[OFFSET]
        assert ref.estimator.estimate.readout_s == mean and ref.estimator.state.readout_s == mean
        assert ref.estimator.P[READOUT, READOUT] == pytest.approx(ref.estimator.prior[READOUT, READOUT], rel=1e-6)
        assert ref.status()["readout_ms"] == round(mean * 1e3, 3)


@pytest.mark.slow
def test_a_global_shutter_rig_stays_global():
    """Global-shutter cameras (readout 0, as the user says): nothing to learn, and the moving head's
    offset is recovered as well as with a free readout."""
    ref = _run(0.0, 0.01, error_model=RigErrorModel(readout_s=0.0))
    assert abs(ref.estimator.estimate.readout_s) < 3e-4 and abs(ref.estimator.estimate.offset_s - 0.01) < 1e-3


# --------------------------------------------------------------------------- the solve spread over frames
#
# A chunk's update runs as a job over the add_frame calls after the one completing it, a fixed number of
# Gauss-Newton passes per call (RigRefineConfig.passes_per_frame): the work per call is counted, never
# timed, and the results are those of solving at once (RigRefineConfig.synchronous).


def _stream(seconds=6.0, seed=5):
    """Frames of a stale rig (right camera turned 0.3°, baseline 2% long, the right image 10 ms late,
    a 20 ms rolling shutter), a glint now and then, a frame without a pose, and the bar bumped by 0.6°
    at 3 s: [(t, centres, R, p1)]."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(int(round(seconds * 30))):
        t = i / 30
        turn = cv2.Rodrigues(np.radians(0.3) * np.array([0.24, 0.96, 0.14]))[0]
        if t >= 3.0:
            turn = cv2.Rodrigues(np.radians(0.6) * np.array([0.0, 0.0, 1.0]))[0] @ turn
        centres = _centres_on(t, 0.010, 0.020, turn, 1.02) + rng.normal(0.0, 0.03, (2, 5, 2))
        if i % 23 == 5:
            centres[1, 2] += 25.0                       # a glint
        R, p1 = _pose(t, "general", 2.0)
        if i == 40:
            R = np.full((3, 3), np.nan)                 # no pose: counted, not used
        out.append((t, centres, R, p1))
    return out


def _centres_on(t, offset_s, readout_s, turn, scale):
    """_centres with the right camera turned by ``turn`` and the baseline scaled (the true rig)."""
    right = (turn @ RIG.R, scale * turn @ np.asarray(RIG.T).ravel(), RIG.K2, RIG.D2)
    return _centres(t, "general", 2.0, offset_s, readout_s, views=(VIEWS[0], right))


STREAM = None


#: The job's mechanics are tested on every update, the first too (which the default solves at once).
JOB = rig_refine.RigRefineConfig(first_at_once=False)


def _feed(config, frames=None, hook=None):
    """A refiner fed the stream (poses independent of its rig), flushed at the end. Returns it, the
    passes run in each add_frame call, and what each update (or skip) left: [(calls so far, record)]."""
    global STREAM
    if STREAM is None:
        STREAM = _stream()
    ref = RigRefiner(RIG, MODEL, config, readout_prior=readout_prior(1 / 30, None))
    sigma = np.full((2, 5), 0.03)
    passes, results = [], []
    done = 0
    for k, (t, centres, R, p1) in enumerate(STREAM if frames is None else frames):
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1, independent_pose=True)
        passes.append(ref.scheduler.last_step.passes)
        if hook is not None:
            ref = hook(k, ref) or ref
        if ref.estimator.updates + sum(ref.estimator.skipped_chunks.values()) > done:
            done = ref.estimator.updates + sum(ref.estimator.skipped_chunks.values())
            results.append(_record(ref))
    # The update under way, run by calls without a frame, then the frames short of a chunk.
    for finish in (_finish_job, RigRefiner.flush):
        finish(ref)
        if ref.estimator.updates + sum(ref.estimator.skipped_chunks.values()) > done:
            done = ref.estimator.updates + sum(ref.estimator.skipped_chunks.values())
            results.append(_record(ref))
    return ref, passes, results


def _finish_job(ref):
    """Calls without a frame (t None) until the update under way, if any, is done."""
    while ref.scheduler.last_step.under_way:
        ref.add_frame(None, 0.0, None, None, None, None, None)


def _record(ref):
    estimator = ref.estimator
    est, use = estimator.estimate, estimator.state
    return dict(estimate=np.concatenate([est.R.ravel(), est.T, [est.log_focal, est.offset_s, est.readout_s]]),
                state=np.concatenate([use.R.ravel(), use.T, [use.log_focal, use.offset_s, use.readout_s]]),
                P=estimator.P.copy(), cov=estimator.cov().copy(), updates=estimator.updates,
                versions=estimator.versions, skipped=dict(estimator.skipped_chunks), bumps=list(estimator.bumps),
                refined=estimator.refined.copy(),
                refit={t: np.concatenate([R.ravel(), p]) for t, (R, p) in estimator.refit_poses.items()})


def _assert_same_results(a, b, atol=1e-9):
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.keys() == y.keys()
        for key in x:
            if key == "refit":
                assert x[key].keys() == y[key].keys()
                for t in x[key]:
                    np.testing.assert_allclose(x[key][t], y[key][t], rtol=0, atol=atol)
            elif isinstance(x[key], np.ndarray):
                np.testing.assert_allclose(x[key], y[key], rtol=1e-9, atol=atol * np.abs(y[key]).max())
            else:
                assert x[key] == y[key], key


@pytest.fixture(scope="module")
def synchronous():
    return _feed(rig_refine.RigRefineConfig(synchronous=True))


@pytest.mark.slow
def test_incremental_solve_is_bounded_and_equals_the_synchronous_one(synchronous):
    sync_ref, sync_passes, sync_results = synchronous
    ref, passes, results = _feed(JOB)
    # The stream taught something, through both paths of an update: a bump's retry and skips.
    assert sync_ref.estimator.updates >= 15 and sync_ref.estimator.bumps and sync_ref.estimator.versions >= 2
    assert sync_ref.estimator.ignored_frames == 1
    assert max(sync_passes) >= 2 * (sync_ref.estimator.config.iterations + 1)   # the retry, at once
    # No call ran more than passes_per_frame passes; the one completing a chunk none.
    budget = ref.estimator.config.passes_per_frame
    assert max(passes) == budget
    assert passes[7] == passes[15] == passes[23] == 0      # the calls completing the first chunks
    work, sync_work = ref.scheduler, sync_ref.scheduler
    assert work.frame_terms <= work.passes * ref.estimator.config.chunk_frames
    # The same work, spread, and the same results, update by update.
    assert work.passes == sync_work.passes and work.frame_terms == sync_work.frame_terms
    _assert_same_results(results, sync_results)
    assert not ref.scheduler.last_step.under_way


@pytest.mark.slow
def test_a_job_still_running_is_finished_first(synchronous):
    """One pass a frame: a bump's retry (10 passes) outlasts its chunk's 7 following frames; the next
    chunk's completion finishes it first, and the results stay those of the synchronous solve."""
    _, _, sync_results = synchronous
    ref, passes, results = _feed(rig_refine.RigRefineConfig(passes_per_frame=1, first_at_once=False))
    assert max(passes) > 1                             # the finish-first call
    assert sorted(set(passes))[:2] == [0, 1]
    _assert_same_results(results, sync_results)


@pytest.mark.slow
def test_a_copy_or_a_readout_prior_restarts_the_job_with_the_same_result(synchronous):
    import copy
    import pickle
    _, _, sync_results = synchronous
    seen = {}

    def hook(k, ref):
        if ref.scheduler.last_step.under_way and "copy" not in seen:
            seen["copy"] = k
            return copy.deepcopy(pickle.loads(pickle.dumps(ref)))     # mid-job: restarted from its chunk
        return None

    _, _, results = _feed(JOB, hook=hook)
    assert "copy" in seen
    _assert_same_results(results, sync_results)
    # The readout's prior set while the first update runs: it starts over, as if the prior were given.
    frames = STREAM[:24]
    given, _, expected = _feed(rig_refine.RigRefineConfig(synchronous=True), frames=frames)

    def set_prior(k, ref):
        if ref.scheduler.last_step.under_way and ref.estimator.updates == 0 and "prior" not in seen:
            seen["prior"] = k
            ref.set_readout_prior(*readout_prior(1 / 30, None))
        return None

    # (The refiners of _feed start with the frame period's prior: set again, to the same value.)
    _, _, results = _feed(JOB, frames=frames, hook=set_prior)
    assert "prior" in seen
    _assert_same_results(results, expected)


@pytest.mark.parametrize("how", ["widen", "reset", "drop_pending", "forget_motion"])
def test_widen_reset_drop_pending_with_a_job_running(how):
    ref = RigRefiner(RIG, MODEL, JOB)
    sigma = np.full((2, 5), 0.03)
    for k, (t, centres, R, p1) in enumerate(_stream(seconds=0.5)[:9]):
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1)
    assert ref.scheduler.last_step.under_way and ref.estimator.updates == 0 and len(ref.scheduler.pending) == 1
    before = (ref.estimator.estimate.R.copy(), ref.estimator.P.copy())
    if how == "widen":
        ref.widen(0.3)
    elif how == "forget_motion":
        ref.forget_motion()
    else:
        getattr(ref, how)()
    if how == "forget_motion":
        # The job's chunk keeps its velocities and runs on; only the pending frame lost its motion.
        assert not ref.scheduler.pending[0].motion_known
        ref.flush()
        assert ref.estimator.updates == 1
        return
    # Dropped: nothing of it applied, nothing left to run (a flush runs no pass).
    assert ref.estimator.updates == 0 and not ref.scheduler.pending
    np.testing.assert_array_equal(ref.estimator.estimate.R, before[0])
    assert not ref.flush() and ref.scheduler.last_step.passes == 0 and ref.estimator.updates == 0


def test_an_exception_inside_the_job_ends_it(monkeypatch):
    ref = RigRefiner(RIG, MODEL, JOB)
    sigma = np.full((2, 5), 0.03)
    frames = _stream(seconds=1.0)

    def singular(self, chunk, prior):
        raise np.linalg.LinAlgError("Singular matrix")

    for t, centres, R, p1 in frames[:8]:
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1)
    assert ref.scheduler.last_step.under_way
    monkeypatch.setattr(RigEstimator, "solve", singular)
    t, centres, R, p1 = frames[8]
    with pytest.raises(np.linalg.LinAlgError):
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1)
    # The job ended with the exception: a flush finds nothing to run (one frame is short of a chunk).
    assert not ref.flush() and ref.scheduler.last_step.passes == 0 and ref.estimator.updates == 0
    ref.drop_pending()
    monkeypatch.undo()
    for t, centres, R, p1 in frames[9:17]:
        ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1)
    ref.flush()
    assert ref.estimator.updates == 1


def test_frames_given_during_a_job_are_moved_onto_the_new_rig():
    """Poses tracked with the rig in use (the default): when a job's result changes it, the frames given
    since (tracked with the old rig; this call's included) are moved onto the new one, and refit_poses
    gives them to the tracker with the chunk's."""
    ref = RigRefiner(RIG, MODEL, JOB, readout_prior=readout_prior(1 / 30, None))
    sigma = np.full((2, 5), 0.03)
    frames = _stream(seconds=1.0)
    for k, (t, centres, R, p1) in enumerate(frames):
        if ref.add_frame(t, 0.0, centres, ALL_VISIBLE, sigma, R, p1):
            break
    else:
        raise AssertionError("the rig in use never changed")
    assert ref.estimator.versions == 1 and k > 8
    chunk_times = [f[0] for f in frames[:8]]
    since = [f[0] for f in frames[8:k + 1]]
    assert sorted(ref.estimator.refit_poses) == chunk_times + since
    for f in ref.scheduler.pending:
        assert f.rig_version == 0 and f.refit[0] == 1
        np.testing.assert_array_equal(f.newest()[1], ref.estimator.refit_poses[f.t][1])
    # The move is the change of the chunk's last pose: a rigid motion, the same for every frame.
    last_t = chunk_times[-1]
    R_old, p_old = frames[7][2], frames[7][3]
    R_new, p_new = ref.estimator.refit_poses[last_t]
    turn = R_new @ R_old.T
    for t, _, R, p1 in frames[8:k + 1]:
        np.testing.assert_allclose(ref.estimator.refit_poses[t][0], turn @ R, atol=1e-12)
        np.testing.assert_allclose(ref.estimator.refit_poses[t][1], turn @ p1 + p_new - turn @ p_old, atol=1e-9)


@pytest.mark.slow
def test_the_first_update_is_solved_at_once_and_the_next_ones_over_the_frames_after():
    """first_at_once (the default): the call that completes the first chunk solves it (until then the rig is
    only rig.yaml); every later update is a job over the following calls, at most passes_per_frame each."""
    config = rig_refine.RigRefineConfig()
    ref, passes, results = _feed(config)
    first = next(k for k, p in enumerate(passes) if p)
    assert first == config.chunk_frames - 1 and passes[first] > config.passes_per_frame
    assert max(passes[first + 1:]) <= config.passes_per_frame
    assert ref.estimator.updates >= 5
