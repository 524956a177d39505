"""The rig's refinement as three parts, each built and run alone: the estimator
(:class:`RigEstimator`), the scheduler that spreads its updates over frames
(:class:`SolveScheduler`) and the report (:mod:`headplod.tracking.rig_report`).

Frames are synthetic and exact, as in ``tests/test_refine_properties.py``:
the default marker model posed by a general motion and projected by a true
rig whose right camera is turned from the sample ``rig.yaml``, no images.
"""
import math
import pickle

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.tracking import rig_report
from headplod.tracking.rig_estimator import RigEstimator, RigSummary, solve_at_once
from headplod.tracking.rig_frames import _INDEPENDENT
from headplod.tracking.rig_refine import RigRefineConfig, RigRefiner, RigState
from headplod.tracking.rig_schedule import SolveScheduler

from test_refine_properties import ALL_VISIBLE, MODEL, RIG, _centres, _pose  # noqa: E402

TURN_DEG = 0.4
TURN = cv2.Rodrigues(np.radians(TURN_DEG) * np.array([0.24, 0.96, 0.14]))[0]
TRUE_RIG = io.Rig(RIG.image_size, RIG.K1, RIG.D1, RIG.K2, RIG.D2, TURN @ RIG.R, TURN @ np.asarray(RIG.T).ravel())
SIGMA = np.full((2, 5), 0.05)
CHUNK = 8
AMP = 2.0                   # the head turns up to ±1 rad: every rig parameter observable


def _turn_deg(R_a, R_b) -> float:
    return float(np.degrees(np.linalg.norm(cv2.Rodrigues(np.asarray(R_a) @ np.asarray(R_b).T)[0])))


def _frames(estimator: RigEstimator, n: int, start: int = 0, seed: int = 0):
    """``n`` frames at 30 fps seen by the true rig (centres to 0.05 px), their poses exact (independent of
    the rig), as the estimator keeps them."""
    rng = np.random.default_rng(seed + start)
    out = []
    for i in range(start, start + n):
        t = i / 30
        centres = _centres(t, "general", AMP, rig=TRUE_RIG) + rng.normal(0.0, 0.05, (2, 5, 2))
        out.append(estimator.frame(t, 0.0, centres, ALL_VISIBLE, SIGMA, *_pose(t, "general", AMP), True, _INDEPENDENT))
    return out


# --------------------------------------------------------------------------- the estimator


def test_the_estimator_recovers_a_turned_camera_chunk_by_chunk():
    est = RigEstimator(RIG, MODEL)
    assert _turn_deg(est.estimate.R, TRUE_RIG.R) == pytest.approx(TURN_DEG, abs=1e-3)   # (rig.yaml's R to 6 digits)
    turn_sd_deg = []
    for k in range(12):
        chunk = _frames(est, CHUNK, start=k * CHUNK)
        R_before, P_before = est.estimate.R.copy(), est.P.copy()
        update = solve_at_once(est, chunk)
        # The update is a value: nothing of the estimator changed until it is applied.
        assert update.skip is None and update.solution is not None
        assert np.array_equal(est.estimate.R, R_before) and np.array_equal(est.P, P_before)
        est.apply(update, [])
        assert est.updates == k + 1
        turn_sd_deg.append(float(np.degrees(np.sqrt(np.linalg.eigvalsh(est.P[:3, :3]).max()))))
    # Every chunk narrows the turn; what is left of it is within 3σ and a small part of the turn.
    assert all(b < a for a, b in zip(turn_sd_deg, turn_sd_deg[1:])) and turn_sd_deg[-1] < 0.25 * TURN_DEG
    error = _turn_deg(est.estimate.R, TRUE_RIG.R)
    assert error < 3 * turn_sd_deg[-1] and error < 0.15 * TURN_DEG
    assert abs(np.linalg.norm(est.estimate.T) / np.linalg.norm(TRUE_RIG.T) - 1) < 0.002
    # The rig in use followed the estimate (it departed by far more than its noise).
    assert est.versions >= 1 and _turn_deg(est.state.R, TRUE_RIG.R) < 0.15 * TURN_DEG


def test_an_update_takes_its_passes_one_step_each():
    """The update's generator stops once before each Gauss-Newton pass: iterations + 1 stops for a chunk
    that the first solve explains (its frames carry no velocities to take again from the refitted poses)."""
    est = RigEstimator(RIG, MODEL, RigRefineConfig(iterations=3))
    steps = est.update_steps(_frames(est, CHUNK))
    stops = 0
    while True:
        try:
            next(steps)
        except StopIteration as end:
            update = end.value
            break
        stops += 1
    assert update.skip is None and not update.bumped and stops == 4


def test_a_chunk_without_a_usable_centre_is_a_skip_and_changes_nothing():
    est = RigEstimator(RIG, MODEL)
    chunk = _frames(est, CHUNK)
    for f in chunk:
        f.centers[:] = np.nan
    update = solve_at_once(est, chunk)
    P = est.P.copy()
    assert update.skip is not None and not est.apply(update, [])
    assert est.skipped_chunks == {update.skip: 1} and est.last_skip == (chunk[-1].t, update.skip)
    assert est.updates == 0 and np.array_equal(est.P, P)


# --------------------------------------------------------------------------- the scheduler


def _scheduled(passes_per_step: int, synchronous: bool = False):
    est = RigEstimator(RIG, MODEL)
    return SolveScheduler(est, CHUNK, passes_per_step, max_gap_frames=2.5, synchronous=synchronous), est


def _fill(scheduler: SolveScheduler, est: RigEstimator):
    """Give the scheduler one chunk of frames; the last call's Step."""
    for frame in _frames(est, CHUNK):
        step = scheduler.add(frame)
    return step


@pytest.mark.parametrize("budget", [1, 2, 3])
def test_the_scheduler_spreads_an_update_over_exactly_the_steps_its_passes_need(budget):
    sync, sync_est = _scheduled(budget, synchronous=True)
    done = _fill(sync, sync_est)
    passes = done.passes
    assert passes >= sync_est.config.iterations + 1 and sync_est.updates == 1 and not done.under_way

    scheduler, est = _scheduled(budget)
    taken = _fill(scheduler, est)
    assert taken.under_way and taken.passes == 0 and est.updates == 0     # the chunk taken, not solved
    steps = []
    while True:
        step = scheduler.add(None)
        steps.append(step.passes)
        if not step.under_way:
            break
    assert len(steps) == math.ceil(passes / budget)
    assert steps[:-1] == [budget] * (len(steps) - 1) and steps[-1] == passes - budget * (len(steps) - 1)
    assert scheduler.passes == passes and scheduler.frame_terms == passes * CHUNK
    # The same update as solved at once, bit for bit.
    assert est.updates == 1 and est.versions == sync_est.versions
    for a, b in ((est.estimate.R, sync_est.estimate.R), (est.estimate.T, sync_est.estimate.T), (est.P, sync_est.P)):
        assert np.array_equal(a, b)


def test_a_copy_of_the_scheduler_restarts_its_update_from_the_chunk():
    scheduler, est = _scheduled(2)
    _fill(scheduler, est)
    first = scheduler.add(None)
    assert first.passes == 2 and first.under_way
    copy = pickle.loads(pickle.dumps(scheduler))
    assert copy.solver is not est and copy.solver.updates == 0
    count = 0
    while scheduler.add(None).under_way:
        count += 1
    copy_count = 0
    while copy.add(None).under_way:
        copy_count += 1
    assert copy_count == count + 1                # the copy runs the first step's two passes again
    assert np.array_equal(copy.solver.estimate.R, est.estimate.R) and np.array_equal(copy.solver.P, est.P)


def test_dropping_the_frames_drops_the_update_under_way():
    scheduler, est = _scheduled(2)
    assert _fill(scheduler, est).under_way
    scheduler.drop()
    step = scheduler.add(None)
    assert step == type(step)(False, 0, False) and est.updates == 0
    assert scheduler.flush().passes == 0


# --------------------------------------------------------------------------- the report


SUMMARY = RigSummary(
    differences={"turn_deg": 1.234, "turn_axis": [0.0, 1.0, 0.0], "baseline_scale": 1.0456, "centre_shift_mm": 3.0,
                 "focal_scale": 1.0, "offset_ms": 25.0, "readout_ms": 0.0},
    sigma=np.array([1e-4, 2e-4, 3e-4, 0.1, 0.1, 0.1, 1e-4, 4e-4, 5e-4]),
    refined=np.array([True] * 6 + [False, True, False]), converged=False, updates=7, bumps=(2.5,))


def test_the_report_names_the_numbers_of_the_estimate():
    config = RigRefineConfig()
    line = rig_report.describe(SUMMARY, config)
    assert line.startswith("rig.yaml: right camera turned ~1.23°, baseline x1.046, time offset 25.0 ms ±0.4; ")
    assert "focal" not in line and "rolling shutter" not in line       # neither refined nor off
    assert "refining, rig changed at t=2.5 s" in line
    advice = rig_report.advice(SUMMARY, config)
    assert advice.startswith("recalibrate: the right camera is turned 1.2°; the baseline is 1.046x rig.yaml's")
    assert "the cameras expose 25 ms apart" in advice and line.endswith(advice)
    status = rig_report.status(SUMMARY)
    assert status == {"turn_deg": 1.234, "baseline_scale": 1.0456, "focal_scale": 1.0, "offset_ms": 25.0,
                      "turn_sd_deg": round(math.degrees(3e-4), 4), "offset_sd_ms": 0.4, "readout_ms": 0.0,
                      "readout_sd_ms": 0.5, "state": "refining", "updates": 7, "bumps": 1}


def test_the_report_of_a_close_rig_gives_no_advice():
    near = RigSummary({**SUMMARY.differences, "turn_deg": 0.2, "baseline_scale": 1.001, "offset_ms": 1.0},
                      SUMMARY.sigma, SUMMARY.refined, True, 3, ())
    assert rig_report.advice(near, RigRefineConfig()) is None
    line = rig_report.describe(near, RigRefineConfig())
    assert line.endswith("; refined") and "turned ~0.20°" in line


def test_the_report_of_an_estimator_states_its_rig_in_use():
    est = RigEstimator(RIG, MODEL)
    for k in range(3):
        est.apply(solve_at_once(est, _frames(est, CHUNK, start=k * CHUNK)), [])
    d = est.state.differences()
    line = rig_report.describe(est.summary(), est.config)
    assert f"turned ~{d['turn_deg']:.2f}°" in line and f"baseline x{d['baseline_scale']:.3f}" in line
    assert rig_report.status(est.summary())["updates"] == 3


# --------------------------------------------------------------------------- the composition


def test_the_refiner_composes_the_parts_and_owns_no_state():
    ref = RigRefiner(RIG, MODEL)
    assert set(vars(ref)) == {"estimator", "scheduler"} and ref.scheduler.solver is ref.estimator
    assert ref.describe() == rig_report.describe(ref.estimator.summary(), ref.estimator.config)
    assert RigState(RIG).error_from(ref.estimator.estimate) == pytest.approx(np.zeros(9))
