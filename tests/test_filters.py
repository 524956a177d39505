"""One Euro filter and pose smoothing."""
import copy
import math

import numpy as np
import pytest

from headplod.filters import OneEuroFilter, smoothing_factor
from headplod.tracking.filters import PoseFilter
from headplod.live.opentrack import axes_from_opentrack


def run(f, values, times):
    return np.array([f(v, t) for v, t in zip(values, times)])


def test_smoothing_factor_matches_the_paper():
    # alpha = 1 / (1 + tau / Te), tau = 1 / (2 pi fc): fc = 1 Hz, Te = 1/60 s.
    tau = 1 / (2 * math.pi)
    assert smoothing_factor(1.0, 1 / 60) == pytest.approx(1 / (1 + tau * 60))
    assert smoothing_factor(1.0, 1 / 60) == pytest.approx(0.094793, abs=1e-6)


def test_first_sample_passes_and_constant_stays():
    f = OneEuroFilter(1.0, 0.5)
    x = np.array([[1.0, -2.0, 3.0], [4.0, 5.0, 6.0]])
    for i in range(50):
        assert np.array_equal(f(x, i / 60), x)


def test_single_step_uses_alpha():
    f = OneEuroFilter(min_cutoff_hz=2.0, beta=0.0)
    f(0.0, 0.0)
    a = smoothing_factor(2.0, 0.05)
    assert float(f(1.0, 0.05)) == pytest.approx(a)


def test_jitter_reduced_at_rest():
    rng = np.random.default_rng(1)
    n = 600  # 10 s at 60 Hz
    noisy = 500.0 + rng.normal(0.0, 1.0, size=(n, 3))
    out = run(OneEuroFilter(1.0, 0.0), noisy, np.arange(n) / 60)
    ratio = out[60:].std(axis=0) / noisy[60:].std(axis=0)
    # A first-order low-pass with alpha = 0.095 keeps sqrt(alpha / (2 - alpha)) = 0.22 of white noise.
    assert np.all(ratio < 0.3), ratio
    assert np.all(np.abs(out[60:].mean(axis=0) - 500.0) < 0.2)


def test_beta_reduces_lag_on_a_ramp():
    t = np.arange(120) / 60
    ramp = 300.0 * t  # 300 mm/s
    lags = []
    for beta in (0.0, 0.01, 0.1):
        out = run(OneEuroFilter(1.0, beta), ramp, t)
        lags.append(ramp[-1] - out[-1])
    assert lags[0] > lags[1] > lags[2] > 0
    assert lags[2] < 0.2 * lags[0]


def test_nan_is_rejected_without_poisoning():
    f = OneEuroFilter(1.0, 0.1)
    f([1.0, 2.0], 0.0)
    good = f([1.5, 2.5], 1 / 60)
    assert np.array_equal(f([math.nan, 3.0], 2 / 60), good)
    after = f([1.5, 2.5], 3 / 60)
    assert np.all(np.isfinite(after))
    # Same as if the NaN sample never came.
    g = OneEuroFilter(1.0, 0.1)
    g([1.0, 2.0], 0.0)
    g([1.5, 2.5], 1 / 60)
    assert np.allclose(after, g([1.5, 2.5], 3 / 60))
    # Before any good sample, the input comes back.
    assert np.isnan(OneEuroFilter()(math.nan, 0.0))


def test_irregular_time_steps():
    # With beta = 0 the filter is a first-order low-pass: the response to a step after an
    # irregular sequence of steps is the product of the per-step (1 - alpha).
    f = OneEuroFilter(1.0, 0.0)
    f(0.0, 0.0)
    times = [0.01, 0.05, 0.06, 0.16, 0.17]
    expected_left = 1.0
    prev = 0.0
    for t in times:
        y = float(f(1.0, t))
        expected_left *= 1 - smoothing_factor(1.0, t - prev)
        prev = t
        assert y == pytest.approx(1 - expected_left)
    # A repeated or earlier time is ignored.
    assert float(f(5.0, 0.17)) == pytest.approx(1 - expected_left)
    assert float(f(5.0, 0.10)) == pytest.approx(1 - expected_left)


def test_reset_and_shape_check():
    f = OneEuroFilter()
    f([0.0, 0.0], 0.0)
    with pytest.raises(ValueError, match="shape"):
        f([0.0, 0.0, 0.0], 0.1)
    f.reset()
    assert np.array_equal(f([7.0, 8.0, 9.0], 0.2), [7.0, 8.0, 9.0])
    with pytest.raises(ValueError, match="min_cutoff_hz"):
        OneEuroFilter(min_cutoff_hz=0)


def pose(t, yaw, pitch, roll, x=0.0, ok=True):
    return {"frame": int(round(t * 60)), "t": t, "ok": ok, "position": [x, 0.0, 600.0],
            "axes": axes_from_opentrack(yaw, pitch, roll).tolist(), "cov": [[0.5, 0.1], [0.1, 0.4]],
            "reason": None}


def test_pose_filter_axes_are_a_rotation():
    rng = np.random.default_rng(2)
    pf = PoseFilter(1.0, 0.02)
    for i in range(120):
        t = i / 60
        rec = pose(t, 20 * math.sin(t) + rng.normal(0, 1), 10 * math.cos(2 * t) + rng.normal(0, 1),
                   rng.normal(0, 2), x=rng.normal(0, 1))
        before = copy.deepcopy(rec)
        out = pf(rec)
        assert rec == before  # the input record is not modified
        A = np.array(out["axes"])
        assert A @ A.T == pytest.approx(np.eye(3), abs=1e-12)
        assert np.linalg.det(A) == pytest.approx(1.0, abs=1e-12)
        assert np.allclose(np.cross(A[2], A[0]), A[1])
        assert out["cov"] == rec["cov"]


def test_pose_filter_smooths_and_handles_failures():
    rng = np.random.default_rng(3)
    pf = PoseFilter(1.0, 0.0, reset_after_s=0.5)
    yaws = []
    for i in range(240):
        out = pf(pose(i / 60, 10 + rng.normal(0, 1.0), 0, 0))
        yaws.append(math.degrees(math.atan2(-out["axes"][2][0], -out["axes"][2][2])))
    assert np.std(yaws[60:]) < 0.35  # raw std 1 deg
    bad = {"frame": 240, "t": 4.0, "ok": False, "position": None, "axes": None, "cov": None, "reason": "x"}
    assert pf(bad) is bad
    # A single failure keeps the state: a jump is still smoothed.
    out = pf(pose(241 / 60, 0, 0, 0, x=100.0))
    assert out["position"][0] < 50
    # A long gap restarts: the first pose after it passes through.
    out = pf(pose(241 / 60 + 1.0, 0, 0, 0, x=100.0))
    assert out["position"][0] == pytest.approx(100.0)
    assert np.allclose(out["axes"], pose(0, 0, 0, 0)["axes"])
