"""synthetic/gaze.py: a viewer whose eyes move, checked against the laws it claims.

Every check measures the simulated traces (speeds from finite differences,
onsets from speed thresholds, fixations from the phase labels) and compares
them with the laws computed here from the settings, not with the module's
own helpers where the helper is the thing under test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from synthetic.gaze import (
    PEAK_TO_MEAN_MIN,
    PHASE_FIXATION,
    PHASE_SACCADE,
    EyeHeadSettings,
    eye_lead_fit,
    eye_offset_distribution,
    flat_screen_half_extent_deg,
    offset_sigma_deg,
    simulate_gaze_shift,
    simulate_viewer,
)

SETTINGS = EyeHeadSettings()
DESK_HALF_DEG = (24.0, 14.0)      # 24-inch 16:9 at 60 cm
WIDE_HALF_DEG = (42.0, 13.0)      # 49-inch 32:9 at 65 cm

# ---- tolerances, each with why it is what it is ----------------------------
#: Sampling rate for single-shift checks, Hz: fine enough that a 45 ms saccade has 90 samples.
SHIFT_RATE_HZ = 2000.0
#: A sample is "moving" above this speed, deg/s: far below any saccade's or head movement's
#: speed, far above rounding noise (the model has no fixational noise).
MOVING_DEG_S = 1.0
#: Measured saccade duration against the law, s: the threshold cuts the profile's slow first
#: and last samples, at most about three samples at 2 kHz.
DURATION_TOL_S = 0.0015
#: Measured peak speed against the law, relative: the profile has a plateau at the peak, so
#: finite differences meet it to rounding.
PEAK_REL_TOL = 0.005
#: Gaze held "still" during a fixation: the brief's VOR criterion, deg.
GAZE_STILL_DEG = 0.5
#: Head displacement against the law, deg: the law is applied exactly; this is float rounding
#: plus the orbit margin the plan leaves.
HEAD_LAW_TOL_DEG = 1e-5
#: Measured head lead against the setting's lag, s: a minimum-jerk start passes MOVING_DEG_S a few
#: milliseconds after its onset; a lag of zero would miss this by more than the tolerance.
HEAD_LEAD_TOL_S = 0.01
#: Mean fixation duration against the setting, relative: about four standard errors of the mean
#: of ~700 gamma draws with shape 4 (coefficient of variation 0.5), plus one sample's rounding.
FIXATION_MEAN_REL_TOL = 0.08


def _speed(xy: np.ndarray, rate_hz: float) -> np.ndarray:
    """Speed per sample interval, deg/s (len T-1)."""
    return np.linalg.norm(np.diff(xy, axis=0), axis=1) * rate_hz


def _duration_law_s(a):
    return SETTINGS.saccade_duration_intercept_s + SETTINGS.saccade_duration_slope_s_per_deg * a


def _peak_law_deg_s(a):
    return SETTINGS.saccade_peak_speed_max_deg_s * (1 - math.exp(-a / SETTINGS.saccade_peak_speed_scale_deg))


# ---- the main sequence -------------------------------------------------------

@pytest.mark.parametrize("target", [(11, 0), (15, 0), (-19, 0), (12, 9), (30, 0)])
def test_saccades_follow_the_main_sequence(target):
    """Duration and peak speed of the gaze trace match both laws (30 deg: with the head moving, eye unclipped)."""
    tr = simulate_gaze_shift(SETTINGS, target, rate_hz=SHIFT_RATE_HZ)
    amp = float(np.hypot(*target))
    speed = _speed(tr.gaze_deg, tr.rate_hz)
    moving = np.flatnonzero(speed > MOVING_DEG_S)
    duration = (moving[-1] - moving[0] + 1) / tr.rate_hz
    assert duration == pytest.approx(_duration_law_s(amp), abs=DURATION_TOL_S)
    assert speed.max() == pytest.approx(_peak_law_deg_s(amp), rel=PEAK_REL_TOL)
    np.testing.assert_allclose(tr.gaze_deg[-1], target, atol=1e-9)


def test_small_saccades_keep_the_duration_law_and_a_feasible_peak():
    """Below ~10 deg the two laws ask for a peak under the mean speed; the duration law is kept."""
    amp = 4.0
    tr = simulate_gaze_shift(SETTINGS, (amp, 0), rate_hz=SHIFT_RATE_HZ)
    speed = _speed(tr.gaze_deg, tr.rate_hz)
    moving = np.flatnonzero(speed > MOVING_DEG_S)
    duration = (moving[-1] - moving[0] + 1) / tr.rate_hz
    mean_speed = amp / _duration_law_s(amp)
    assert _peak_law_deg_s(amp) < mean_speed                    # the conflict this test is about
    assert duration == pytest.approx(_duration_law_s(amp), abs=DURATION_TOL_S)
    assert speed.max() == pytest.approx(PEAK_TO_MEAN_MIN * mean_speed, rel=PEAK_REL_TOL)


# ---- the head's share ----------------------------------------------------------

@pytest.mark.parametrize("target", [(5, 0), (-12, 0), (19.5, 0), (0, 14), (-10, -10)])
def test_shifts_inside_the_eye_only_range_leave_the_head_still(target):
    tr = simulate_gaze_shift(SETTINGS, target, rate_hz=1000.0)
    assert np.ptp(tr.head_deg, axis=0).max() == 0.0
    np.testing.assert_allclose(tr.gaze_deg[-1], target, atol=1e-9)
    np.testing.assert_allclose(tr.eye_in_head_deg[-1], target, atol=1e-9)


@pytest.mark.parametrize("amplitude", [25.0, 30.0, 45.0, 80.0])
def test_beyond_the_range_the_head_takes_the_laws_share(amplitude):
    tr = simulate_gaze_shift(SETTINGS, (amplitude, 0), rate_hz=1000.0)
    expected = SETTINGS.head_gain_beyond_range * (amplitude - SETTINGS.eye_only_range_deg)
    moved = tr.head_deg[-1] - tr.head_deg[0]
    assert moved[0] == pytest.approx(expected, abs=HEAD_LAW_TOL_DEG)
    assert moved[1] == 0.0
    np.testing.assert_allclose(tr.gaze_deg[-1], (amplitude, 0), atol=1e-9)


def test_vertical_shifts_use_the_head_less():
    horizontal = simulate_gaze_shift(SETTINGS, (30, 0), rate_hz=500.0)
    vertical = simulate_gaze_shift(SETTINGS, (0, 30), rate_hz=500.0)
    h_moved = abs(horizontal.head_deg[-1, 0])
    v_moved = abs(vertical.head_deg[-1, 1])
    assert 0 < v_moved < h_moved
    assert v_moved == pytest.approx(SETTINGS.vertical_head_scale * h_moved, abs=HEAD_LAW_TOL_DEG)


def test_past_the_orbit_limit_the_head_brings_the_eye_back_to_it():
    """A 100 deg shift: the law's share would leave the eye beyond its limit; the head turns further."""
    tr = simulate_gaze_shift(SETTINGS, (100, 0), rate_hz=1000.0)
    law = SETTINGS.head_gain_beyond_range * (100 - SETTINGS.eye_only_range_deg)
    assert 100 - law > SETTINGS.eye_orbit_limit_deg                     # the case this test is about
    assert tr.eye_in_head_deg[-1, 0] == pytest.approx(SETTINGS.eye_orbit_limit_deg, abs=HEAD_LAW_TOL_DEG)
    np.testing.assert_allclose(tr.gaze_deg[-1], (100, 0), atol=1e-9)


def test_the_eye_never_exceeds_its_orbit_limit():
    corners = np.array([(x, y) for x in (-42, 42) for y in (-13, 13)], dtype=float)
    tr = simulate_viewer(SETTINGS, corners, screen_half_deg=WIDE_HALF_DEG, duration_s=20, rate_hz=500, seed=3)
    assert np.linalg.norm(tr.eye_in_head_deg, axis=1).max() <= SETTINGS.eye_orbit_limit_deg + 1e-9
    # and the clip was needed: the eye does reach its limit during the 84-deg shifts
    assert np.linalg.norm(tr.eye_in_head_deg, axis=1).max() > SETTINGS.eye_orbit_limit_deg - 0.01
    big = simulate_gaze_shift(SETTINGS, (-84, 0), gaze_start_deg=(42, 0), head_start_deg=(30, 0), rate_hz=1000.0)
    assert np.abs(big.eye_in_head_deg).max() <= SETTINGS.eye_orbit_limit_deg + 1e-9


# ---- timing: the eyes lead, the VOR holds gaze -------------------------------------

def test_vor_holds_gaze_while_the_head_finishes_turning():
    tr = simulate_gaze_shift(SETTINGS, (40, 0), rate_hz=1000.0)
    after = tr.t_s >= tr.land_s[1]
    head_turn_after = np.ptp(tr.head_deg[after, 0])
    assert head_turn_after > 5.0                         # the head is still turning after the landing ...
    assert np.ptp(tr.gaze_deg[after], axis=0).max() < GAZE_STILL_DEG      # ... and gaze stays put
    # the eye counter-rotates: its speed equals the head's
    eye_v = np.diff(tr.eye_in_head_deg[after, 0])
    head_v = np.diff(tr.head_deg[after, 0])
    np.testing.assert_allclose(eye_v, -SETTINGS.vor_gain * head_v, atol=1e-9)


def test_in_free_viewing_gaze_is_still_in_every_fixation_while_the_head_moves_in_some():
    tr = simulate_viewer(SETTINGS, screen_half_deg=WIDE_HALF_DEG, duration_s=60, rate_hz=500, seed=5)
    last = tr.fixation_index.max()
    head_moving_fixations = 0
    for i in range(1, last):
        in_fix = tr.fixation_index == i
        assert np.ptp(tr.gaze_deg[in_fix], axis=0).max() < GAZE_STILL_DEG, f"fixation {i}"
        head_moving_fixations += np.ptp(tr.head_deg[in_fix, 0]) > 1.0
    assert head_moving_fixations >= 10


def test_the_eyes_lead_the_head():
    tr = simulate_viewer(SETTINGS, screen_half_deg=WIDE_HALF_DEG, duration_s=60, rate_hz=1000, seed=7)
    gaze_speed = _speed(tr.gaze_deg, tr.rate_hz)
    head_speed = _speed(tr.head_deg, tr.rate_hz)
    leads = []
    for i in np.flatnonzero(np.isfinite(tr.head_onset_s)):
        k0 = int(round(tr.shift_onset_s[i] * tr.rate_hz))
        k1 = len(gaze_speed) if i + 1 >= len(tr.shift_onset_s) else int(round(tr.shift_onset_s[i + 1] * tr.rate_hz))
        gaze_on = np.flatnonzero(gaze_speed[k0:k1] > MOVING_DEG_S)
        head_on = np.flatnonzero(head_speed[k0:k1] > MOVING_DEG_S)
        if len(gaze_on) and len(head_on):            # (a tiny head movement may never pass the threshold)
            leads.append((head_on[0] - gaze_on[0]) / tr.rate_hz)
    assert len(leads) >= 20
    assert min(leads) > 0
    # the measured lead: the setting's lag plus the time the minimum-jerk start takes to pass the threshold
    assert np.median(leads) == pytest.approx(SETTINGS.head_lag_s, abs=HEAD_LEAD_TOL_S)


def test_the_head_is_slower_and_longer_than_the_saccade():
    tr = simulate_gaze_shift(SETTINGS, (45, 0), rate_hz=1000.0)
    head_speed = _speed(tr.head_deg, tr.rate_hz)
    moving_head = np.flatnonzero(head_speed > MOVING_DEG_S)
    head_duration = (moving_head[-1] - moving_head[0] + 1) / tr.rate_hz
    assert head_speed.max() < 0.6 * _peak_law_deg_s(45)
    assert head_duration > 2 * _duration_law_s(45)


# ---- fixations and targets ----------------------------------------------------------

def test_fixation_durations_have_the_settings_mean():
    tr = simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=300, rate_hz=200, seed=11)
    fix = tr.phase == PHASE_FIXATION
    ids = tr.fixation_index[fix]
    counts = np.bincount(ids)
    whole = counts[1:ids.max()]                  # not the start's, not the one cut by the end
    durations = whole / tr.rate_hz
    assert len(durations) > 600
    assert durations.mean() == pytest.approx(SETTINGS.fixation_mean_s, rel=FIXATION_MEAN_REL_TOL)
    cv = durations.std() / durations.mean()
    assert cv == pytest.approx(1 / math.sqrt(SETTINGS.fixation_gamma_shape), rel=0.15)
    # phases: every sample is a fixation or a gaze shift, and shifts carry no fixation index
    assert set(np.unique(tr.phase)) <= {PHASE_FIXATION, PHASE_SACCADE}
    assert np.all(tr.fixation_index[tr.phase == PHASE_SACCADE] == -1)


def test_the_same_seed_gives_the_same_viewer():
    a = simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=10, rate_hz=250, seed=42)
    b = simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=10, rate_hz=250, seed=42)
    c = simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=10, rate_hz=250, seed=43)
    for name in ("head_deg", "eye_in_head_deg", "gaze_deg", "phase", "fixation_index"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.gaze_deg, c.gaze_deg)
    np.testing.assert_array_equal(a.gaze_deg, a.head_deg + a.eye_in_head_deg)
    assert a.gaze_deg.shape == (2500, 2) and a.t_s.shape == (2500,)
    assert not a.gaze_deg.flags.writeable


def test_targets_are_centrally_biased():
    tr = simulate_viewer(SETTINGS, screen_half_deg=WIDE_HALF_DEG, duration_s=120, rate_hz=100, seed=2)
    xs = np.arange(-42, 43)
    ys = np.arange(-13, 14)
    grid = np.array([(x, y) for x in xs for y in ys], dtype=float)
    uniform_mean = np.linalg.norm(grid, axis=1).mean()
    chosen = tr.target_deg[1:]
    assert len(chosen) > 200
    assert np.linalg.norm(chosen, axis=1).mean() < 0.8 * uniform_mean
    assert np.abs(chosen[:, 0]).max() <= 42 and np.abs(chosen[:, 1]).max() <= 13


def test_weights_and_the_screen_choose_the_targets():
    targets = np.array([(-10, 0), (10, 0), (0, 5), (60, 0)], dtype=float)   # the last is off the desk screen
    tr = simulate_viewer(SETTINGS, targets, [1.0, 1.0, 0.0, 1.0], screen_half_deg=DESK_HALF_DEG,
                         duration_s=20, rate_hz=200, seed=1)
    chosen = {tuple(t) for t in tr.target_deg[1:]}
    assert chosen == {(-10.0, 0.0), (10.0, 0.0)}
    with pytest.raises(ValueError, match="no target"):
        simulate_viewer(SETTINGS, [(60, 0)], screen_half_deg=DESK_HALF_DEG, duration_s=1, rate_hz=100)
    with pytest.raises(ValueError, match="shape"):
        simulate_viewer(SETTINGS, [1, 2, 3], screen_half_deg=DESK_HALF_DEG, duration_s=1, rate_hz=100)


# ---- screens ---------------------------------------------------------------------------

def test_a_wide_screen_moves_the_head_more_than_a_desk_screen():
    desk = simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=120, rate_hz=100, seed=9)
    wide = simulate_viewer(SETTINGS, screen_half_deg=WIDE_HALF_DEG, duration_s=120, rate_hz=100, seed=9)
    assert wide.head_deg[:, 0].std() > 2 * desk.head_deg[:, 0].std()
    assert np.isfinite(wide.head_onset_s).mean() > np.isfinite(desk.head_onset_s).mean()


@pytest.mark.slow
def test_eye_offsets_are_larger_on_the_wide_screen_and_inside_the_orbit():
    desk = eye_offset_distribution(SETTINGS, DESK_HALF_DEG, 1500, seed=1)
    wide = eye_offset_distribution(SETTINGS, WIDE_HALF_DEG, 1500, seed=1)
    assert desk.shape == wide.shape == (1500, 2)
    assert np.linalg.norm(wide, axis=1).max() <= SETTINGS.eye_orbit_limit_deg + 1e-9
    assert np.sqrt((wide[:, 0] ** 2).mean()) > np.sqrt((desk[:, 0] ** 2).mean())
    sigma = offset_sigma_deg(SETTINGS, DESK_HALF_DEG, n=1500, seed=1)
    assert sigma == pytest.approx(tuple(np.sqrt((desk ** 2).mean(axis=0))))
    # the horizontal offsets stay inside the desk screen's half width (the head hardly moves there)
    assert np.abs(desk[:, 0]).max() <= DESK_HALF_DEG[0] + 1e-9


def test_flat_screen_half_extents():
    diag_in, cm = 24.0, 2.54
    w = diag_in * 16 / math.hypot(16, 9) * cm
    h = diag_in * 9 / math.hypot(16, 9) * cm
    got = flat_screen_half_extent_deg(w, h, 60.0)
    assert got == pytest.approx((math.degrees(math.atan(w / 120)), math.degrees(math.atan(h / 120))))
    assert got[0] == pytest.approx(24.0, abs=0.5)


# ---- settings ---------------------------------------------------------------------------

@pytest.mark.parametrize("field, value", [
    ("eye_only_range_deg", -1.0),
    ("head_gain_beyond_range", 0.0),
    ("head_gain_beyond_range", 1.5),
    ("vertical_head_scale", 2.0),
    ("eye_orbit_limit_deg", 0.0),
    ("saccade_duration_slope_s_per_deg", -0.001),
    ("saccade_peak_speed_max_deg_s", float("nan")),
    ("fixation_mean_s", 0.0),
    ("fixation_gamma_shape", 0.1),
    ("head_lag_s", -0.01),
    ("vor_gain", 3.0),
    ("central_bias_sigma_frac_h", 0.0),
    ("saccade_peak_speed_scale_deg", "fast"),
])
def test_bad_settings_raise_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        EyeHeadSettings(**{field: value})


def test_an_eye_only_range_beyond_the_orbit_is_refused():
    with pytest.raises(ValueError, match="eye_only_range_deg"):
        EyeHeadSettings(eye_only_range_deg=40.0, eye_orbit_limit_deg=35.0)


def test_bad_simulation_arguments_raise():
    with pytest.raises(ValueError, match="screen_half_deg"):
        simulate_viewer(SETTINGS, screen_half_deg=(0, 10), duration_s=1, rate_hz=100)
    with pytest.raises(ValueError, match="rate_hz"):
        simulate_viewer(SETTINGS, screen_half_deg=DESK_HALF_DEG, duration_s=1, rate_hz=0)
    with pytest.raises(ValueError, match="orbit"):
        simulate_gaze_shift(SETTINGS, (0, 0), gaze_start_deg=(40, 0))


# ---- eye lead: does the head's velocity tell where the eyes are? ----------------------

def test_eye_lead_fit_recovers_a_known_tau():
    from types import SimpleNamespace
    rate = 200.0
    t = np.arange(int(20 * rate)) / rate
    head = np.stack([30 * np.sin(2 * np.pi * 0.3 * t), 10 * np.sin(2 * np.pi * 0.5 * t + 1.0)], axis=1)
    omega = np.zeros_like(head)
    omega[1:] = np.diff(head, axis=0) * rate          # the function's own estimate, unsmoothed
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.5, head.shape)
    eye = np.array([0.1, 0.05]) * omega + noise
    fit = eye_lead_fit(SimpleNamespace(rate_hz=rate, head_deg=head, eye_in_head_deg=eye), smoothing_s=0.0)
    assert fit["tau_s"] == pytest.approx((0.1, 0.05), abs=0.003)
    assert fit["rms_about_fit_deg"] == pytest.approx((0.5, 0.5), rel=0.05)
    # R² = signal / (signal + noise), RMS of τω 4.0 and 1.1 deg: 4.0²/(4.0²+0.5²) ≈ 0.985 and 1.1²/(1.1²+0.5²) ≈ 0.83
    assert fit["r2"][0] > 0.97 and 0.78 < fit["r2"][1] < 0.88
    assert fit["moving_fraction"] > 0.8
    # a short smoothing window barely changes a slow movement's velocity
    smooth = eye_lead_fit(SimpleNamespace(rate_hz=rate, head_deg=head, eye_in_head_deg=eye), smoothing_s=0.05)
    assert smooth["smoothing_samples"] == 10
    assert smooth["tau_s"] == pytest.approx((0.1, 0.05), rel=0.05)


def test_eyes_lead_the_head_on_the_wide_screen():
    trace = simulate_viewer(SETTINGS, screen_half_deg=(42.7, 14.5), duration_s=120, rate_hz=100, seed=4)
    fit = eye_lead_fit(trace)
    assert fit["tau_s"][0] > 0.1                      # the offset points along the head's motion
    assert math.isnan(fit["tau_s"][1])                # the head never turns vertically here
    assert fit["r2_moving"][0] > 0.5
    assert fit["rms_about_fit_moving_deg"][0] < fit["rms_about_zero_moving_deg"][0]
    assert fit["rms_about_fit_deg"][0] < fit["rms_about_zero_deg"][0]
    assert 0.02 < fit["moving_fraction"] < 0.5
