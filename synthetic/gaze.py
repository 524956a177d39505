"""A viewer whose eyes move: gaze = head direction + eye-in-head rotation.

headplod's POI follows the head's viewing direction V; a real viewer also
turns the eyes. This module simulates where the head and the eyes point
while a viewer looks around a screen, from published laws of eye-head
coordination, so that benchmarks can ask how far gaze sits from V.

Frame and units
---------------
All directions are ``(horizontal, vertical)`` angles in degrees, shape
``(..., 2)``, of a direction seen from the eye: horizontal positive to the
viewer's right, vertical positive up, ``(0, 0)`` the screen normal through
the screen's centre. ``head_deg`` is the head's direction in that frame,
``eye_in_head_deg`` the eye's rotation relative to the head (0 = eye
centred in the orbit) and ``gaze_deg = head_deg + eye_in_head_deg``. Adding
angles per axis is the small-angle composition of the two rotations: exact
for purely horizontal or purely vertical movements, and off by a few tenths
of a degree to a few degrees for oblique directions tens of degrees out.
Times are seconds, speeds degrees per second.

The model (see docs/viewer-model.md for the sources)
----------------------------------------------------
- The viewer fixates a target, then shifts gaze to the next one, drawn from
  the candidate targets (weights times a Gaussian central bias).
- Gaze moves along a straight line with the saccadic main sequence:
  duration ``D = intercept + slope * A``, peak speed
  ``V = V_max (1 - exp(-A / A_scale))``.
- The head's displacement follows the target relative to the head (its
  planned end): nothing inside the eye-only range, beyond it a fixed share
  of the excess, less vertically; more if the eye would end past its orbit
  limit. The head starts ``head_lag_s`` after the eyes and moves with a
  minimum-jerk profile, slower and longer than the saccade.
- The eye in the head is gaze minus head, clipped to the orbit limit (the
  head then carries gaze the rest of the way). Once gaze lands, the
  vestibulo-ocular reflex counter-rotates the eye against the head's
  remaining turn, so gaze stays on the target (gain 1).
- Fixations last a gamma-distributed time, counted from the gaze landing.

``synthetic/`` never imports ``headplod``; this module is pure numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Callable, Sequence, Tuple

import numpy as np

__all__ = [
    "EyeHeadSettings",
    "ViewerTrace",
    "PHASE_FIXATION",
    "PHASE_SACCADE",
    "saccade_duration_s",
    "saccade_peak_speed_deg_s",
    "head_displacement_deg",
    "head_duration_s",
    "target_probabilities",
    "flat_screen_half_extent_deg",
    "simulate_viewer",
    "simulate_gaze_shift",
    "eye_offset_distribution",
    "offset_sigma_deg",
    "eye_lead_fit",
]

#: Phase codes of :attr:`ViewerTrace.phase`.
PHASE_FIXATION = 0
PHASE_SACCADE = 1

#: The smallest ratio of a saccade's peak speed to its mean speed the velocity
#: profile may take. Below about 10 deg the duration law and the peak-speed law
#: together ask for a peak below the mean, which no movement can have; there
#: the duration law is kept and the peak is this ratio times the mean speed.
PEAK_TO_MEAN_MIN = 1.1
#: The largest ratio: a raised cosine with no plateau.
PEAK_TO_MEAN_MAX = 2.0

#: Candidate grid spacing, deg, used when no targets are given (a featureless
#: screen: every direction on it is a candidate). Finer than any gaze shift
#: the model cares about, coarse enough to stay a few thousand points.
DEFAULT_GRID_STEP_DEG = 1.0

#: Margin under the orbit limit the head's plan leaves the eye, deg, so that
#: rounding never leaves the final eye position a hair outside it.
ORBIT_MARGIN_DEG = 1e-6


@dataclass(frozen=True)
class EyeHeadSettings:
    """The viewer model's parameters; every default with its source.

    Full citations are in docs/viewer-model.md. "Choice" marks a value no
    source gives; the model needs one, and the page says so.

    Attributes
    ----------
    eye_only_range_deg : float, deg, default 20.0
        Head motor error (target relative to the head) below which the head
        does not move. Freedman & Sparks 1997 (monkeys, eyes centred): no head
        contribution to horizontal gaze shifts under 20 deg. The human
        eye-only range of Stahl 1999 varies between people; its figures could
        not be read here, so the reading list's value stands.
    head_gain_beyond_range : float, deg of head per deg of excess, default 55/70
        Share of the head motor error beyond the eye-only range the head
        turns. Freedman & Sparks 1997: the head's contribution grows linearly
        from 25 to 90 deg while the eye's amplitude saturates near 35 deg;
        55/70 is the slope that takes the eye from 20 deg at the range's edge
        to 35 deg at 90 deg (derived from those figures, not a fitted slope
        read from the paper).
    vertical_head_scale : float, dimensionless, default 0.5
        Factor on ``head_gain_beyond_range`` for the vertical component.
        Freedman & Sparks 1997: the head contributes less to vertical gaze
        shifts (qualitative); the value 0.5 is a choice.
    eye_orbit_limit_deg : float, deg, default 35.0
        Largest eye-in-head eccentricity (norm of both axes). Freedman &
        Sparks 1997: eye amplitude saturates near 35 deg.
    saccade_duration_intercept_s : float, s, default 0.021
    saccade_duration_slope_s_per_deg : float, s/deg, default 0.0022
        Main-sequence duration ``D = intercept + slope * A`` (Carpenter 1988,
        the linear fit of Bahill et al. 1975's data range).
    saccade_peak_speed_max_deg_s : float, deg/s, default 500.0
    saccade_peak_speed_scale_deg : float, deg, default 14.0
        Main-sequence peak speed ``V = max (1 - exp(-A / scale))``, the
        exponential form of Baloh et al. 1975; these two values are the
        ones commonly quoted with it (not checked against the paper's table).
    fixation_mean_s : float, s, default 0.33
        Mean fixation duration in scene viewing: Rayner 1998 (scene
        perception); Henderson & Hollingworth 1999 give the same range.
    fixation_gamma_shape : float, dimensionless, default 4.0
        Shape of the gamma distribution of fixation durations (coefficient
        of variation ``1 / sqrt(shape)`` = 0.5). Choice: the sources give the
        mean and a right-skewed distribution, not this shape.
    head_lag_s : float, s, default 0.030
        Head onset after gaze (saccade) onset. Goossens & Van Opstal 1997 and
        Freedman & Sparks 1997: for visual targets the eyes start first; the
        reading list's 20-50 ms range, its middle taken.
    head_duration_intercept_s : float, s, default 0.15
    head_duration_slope_s_per_deg : float, s/deg, default 0.006
        Head movement duration ``intercept + slope * |dH|`` (minimum-jerk
        profile, peak speed ``1.875 |dH| / duration``). Choice: they make the
        head's movement longer and its peak speed lower than the saccade's,
        as Freedman 2008 describes, with no table read for the numbers.
    vor_gain : float, dimensionless, default 1.0
        Eye counter-rotation per unit head rotation once gaze has landed.
        Freedman 2008: the vestibulo-ocular reflex holds gaze on the target
        while the head finishes turning (gain about 1).
    central_bias_sigma_frac_h : float, fraction of the screen's half-width, default 0.5
    central_bias_sigma_frac_v : float, fraction of the screen's half-height, default 0.5
        Standard deviations of the Gaussian central bias multiplying the
        targets' weights. Tatler 2007 (central fixation bias on screens),
        Sitzmann et al. 2018 (equator bias in VR); the widths are a choice.
    """

    eye_only_range_deg: float = 20.0
    head_gain_beyond_range: float = 55.0 / 70.0
    vertical_head_scale: float = 0.5
    eye_orbit_limit_deg: float = 35.0
    saccade_duration_intercept_s: float = 0.021
    saccade_duration_slope_s_per_deg: float = 0.0022
    saccade_peak_speed_max_deg_s: float = 500.0
    saccade_peak_speed_scale_deg: float = 14.0
    fixation_mean_s: float = 0.33
    fixation_gamma_shape: float = 4.0
    head_lag_s: float = 0.030
    head_duration_intercept_s: float = 0.15
    head_duration_slope_s_per_deg: float = 0.006
    vor_gain: float = 1.0
    central_bias_sigma_frac_h: float = 0.5
    central_bias_sigma_frac_v: float = 0.5

    #: (low, high, low inclusive, high inclusive) per field.
    _RANGES = {
        "eye_only_range_deg": (0.0, 90.0, True, False),
        "head_gain_beyond_range": (0.0, 1.0, False, True),
        "vertical_head_scale": (0.0, 1.0, True, True),
        "eye_orbit_limit_deg": (0.0, 60.0, False, True),
        "saccade_duration_intercept_s": (0.0, 0.2, False, True),
        "saccade_duration_slope_s_per_deg": (0.0, 0.02, False, True),
        "saccade_peak_speed_max_deg_s": (0.0, 2000.0, False, True),
        "saccade_peak_speed_scale_deg": (0.0, 100.0, False, True),
        "fixation_mean_s": (0.02, 5.0, True, True),
        "fixation_gamma_shape": (0.5, 1000.0, True, True),
        "head_lag_s": (0.0, 0.5, True, True),
        "head_duration_intercept_s": (0.0, 2.0, False, True),
        "head_duration_slope_s_per_deg": (0.0, 0.1, True, True),
        "vor_gain": (0.0, 1.5, True, True),
        "central_bias_sigma_frac_h": (0.0, 100.0, False, True),
        "central_bias_sigma_frac_v": (0.0, 100.0, False, True),
    }

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            lo, hi, lo_in, hi_in = self._RANGES[f.name]
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise ValueError(f"EyeHeadSettings.{f.name} must be a number (got {value!r})") from None
            above = x >= lo if lo_in else x > lo
            below = x <= hi if hi_in else x < hi
            if not (math.isfinite(x) and above and below):
                span = f"{'[' if lo_in else '('}{lo:g}, {hi:g}{']' if hi_in else ')'}"
                raise ValueError(f"EyeHeadSettings.{f.name} must be in {span} (got {value!r})")
        if self.eye_only_range_deg > self.eye_orbit_limit_deg:
            raise ValueError(
                "EyeHeadSettings.eye_only_range_deg must not exceed eye_orbit_limit_deg "
                f"(got {self.eye_only_range_deg!r} > {self.eye_orbit_limit_deg!r}): "
                "the eye could not make the shifts the head leaves to it")


@dataclass(frozen=True)
class ViewerTrace:
    """A simulated viewer, sampled at a fixed rate (arrays read-only).

    Per sample (T samples at ``rate_hz``):

    t_s : (T,) float, s from the start.
    head_deg : (T, 2) float, deg, the head's direction (horizontal, vertical).
    eye_in_head_deg : (T, 2) float, deg, the eye's rotation in the head.
    gaze_deg : (T, 2) float, deg, ``head_deg + eye_in_head_deg``.
    phase : (T,) int8, :data:`PHASE_FIXATION` or :data:`PHASE_SACCADE`
        (from a gaze shift's onset to its landing; the head may still turn
        during a fixation).
    fixation_index : (T,) int, the fixation a sample belongs to, -1 during
        gaze shifts. Fixation 0 is the start, at the screen's centre.

    Per fixation (F fixations; fixation i > 0 is reached by gaze shift i):

    target_deg : (F, 2) float, deg, the fixated target.
    shift_onset_s : (F,) float, s, the gaze shift's onset (NaN for 0).
    land_s : (F,) float, s, when gaze reached the target (0 for 0).
    head_onset_s : (F,) float, s, the head movement's onset (NaN if the head
        did not move for this shift).
    head_displacement_deg : (F, 2) float, deg, the head movement's planned
        displacement (zeros inside the eye-only range).
    fixation_duration_s : (F,) float, s, the drawn fixation duration (the
        last one is cut by the end of the trace).
    """

    rate_hz: float
    t_s: np.ndarray
    head_deg: np.ndarray
    eye_in_head_deg: np.ndarray
    gaze_deg: np.ndarray
    phase: np.ndarray
    fixation_index: np.ndarray
    target_deg: np.ndarray
    shift_onset_s: np.ndarray
    land_s: np.ndarray
    head_onset_s: np.ndarray
    head_displacement_deg: np.ndarray
    fixation_duration_s: np.ndarray

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value.setflags(write=False)


# ----------------------------------------------------------------------------
# the laws
# ----------------------------------------------------------------------------

def saccade_duration_s(settings: EyeHeadSettings, amplitude_deg) -> np.ndarray:
    """Main-sequence duration, s, of saccades of ``amplitude_deg`` (any shape, deg)."""
    a = np.abs(np.asarray(amplitude_deg, dtype=float))
    return settings.saccade_duration_intercept_s + settings.saccade_duration_slope_s_per_deg * a


def saccade_peak_speed_deg_s(settings: EyeHeadSettings, amplitude_deg) -> np.ndarray:
    """Main-sequence peak speed, deg/s, of saccades of ``amplitude_deg`` (any shape, deg).

    This is the law; the simulated peak equals it wherever the law and the
    duration law allow a movement (peak at least :data:`PEAK_TO_MEAN_MIN`
    times the mean speed, amplitudes above about 10 deg with the defaults),
    and is that minimum ratio times the mean speed below.
    """
    a = np.abs(np.asarray(amplitude_deg, dtype=float))
    return settings.saccade_peak_speed_max_deg_s * -np.expm1(-a / settings.saccade_peak_speed_scale_deg)


def _peak_to_mean(settings: EyeHeadSettings, amplitude_deg: float) -> float:
    """The profile's peak / mean speed ratio for one amplitude (both laws, within the feasible range)."""
    if amplitude_deg <= 0:
        return PEAK_TO_MEAN_MIN
    mean = amplitude_deg / float(saccade_duration_s(settings, amplitude_deg))
    ratio = float(saccade_peak_speed_deg_s(settings, amplitude_deg)) / mean
    return min(max(ratio, PEAK_TO_MEAN_MIN), PEAK_TO_MEAN_MAX)


def _saccade_position(tau: np.ndarray, peak_to_mean: float) -> np.ndarray:
    """Fraction of the amplitude covered at normalized time ``tau`` in [0, 1].

    The speed profile rises as a half cosine over a fraction ``p`` of the
    duration, stays flat, and falls symmetrically; its peak / mean ratio is
    ``1 / (1 - p)``, which lets one profile meet both main-sequence laws.
    """
    p = 1.0 - 1.0 / peak_to_mean
    tau = np.clip(tau, 0.0, 1.0)

    def rise(x):                      # integral of the rising ramp from 0 to x (x <= p)
        return 0.5 * (x - (p / math.pi) * np.sin(math.pi * x / p))

    total = 1.0 - p
    out = np.where(tau < p, rise(np.minimum(tau, p)), 0.5 * p + (tau - p))
    tail = tau > 1.0 - p
    out = np.where(tail, total - rise(np.minimum(1.0 - tau, p)), out)
    return out / total


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk position fraction at normalized time ``tau`` (clipped to [0, 1])."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau ** 3 * (10.0 - 15.0 * tau + 6.0 * tau ** 2)


def head_displacement_deg(settings: EyeHeadSettings, head_motor_error_deg) -> np.ndarray:
    """The head's displacement, deg, for a target at ``head_motor_error_deg`` from the head.

    head_motor_error_deg : (..., 2) deg, target minus the head's (planned)
        direction, horizontal and vertical.

    Returns (..., 2) deg: per axis, ``sign(M) * gain * max(|M| - range, 0)``
    with the gain scaled by ``vertical_head_scale`` vertically; then, if the
    eye would end beyond its orbit limit, the head turns further so that the
    eye ends on the limit.
    """
    m = np.asarray(head_motor_error_deg, dtype=float)
    if m.shape[-1:] != (2,):
        raise ValueError(f"head_motor_error_deg must have shape (..., 2), got {m.shape}")
    gain = np.array([1.0, settings.vertical_head_scale]) * settings.head_gain_beyond_range
    dh = np.sign(m) * gain * np.maximum(np.abs(m) - settings.eye_only_range_deg, 0.0)
    eye_end = m - dh
    norm = np.linalg.norm(eye_end, axis=-1, keepdims=True)
    limit = settings.eye_orbit_limit_deg - ORBIT_MARGIN_DEG
    scale = np.where(norm > limit, limit / np.maximum(norm, 1e-300), 1.0)
    return m - eye_end * scale


def head_duration_s(settings: EyeHeadSettings, displacement_deg) -> np.ndarray:
    """Head movement duration, s, for displacement magnitudes ``displacement_deg`` (deg)."""
    a = np.abs(np.asarray(displacement_deg, dtype=float))
    return settings.head_duration_intercept_s + settings.head_duration_slope_s_per_deg * a


# ----------------------------------------------------------------------------
# targets and screens
# ----------------------------------------------------------------------------

def _check_screen(screen_half_deg) -> Tuple[float, float]:
    try:
        h, v = (float(x) for x in screen_half_deg)
    except (TypeError, ValueError):
        raise ValueError(f"screen_half_deg must be (horizontal, vertical) deg, got {screen_half_deg!r}") from None
    if not (0 < h < 90 and 0 < v < 90):
        raise ValueError(f"screen_half_deg must be in (0, 90) deg on both axes, got {screen_half_deg!r}")
    return h, v


def flat_screen_half_extent_deg(width_cm: float, height_cm: float, distance_cm: float) -> Tuple[float, float]:
    """Angular half-extents (horizontal, vertical), deg, of a flat screen seen square-on from its centre's normal."""
    for name, x in (("width_cm", width_cm), ("height_cm", height_cm), ("distance_cm", distance_cm)):
        if not (math.isfinite(x) and x > 0):
            raise ValueError(f"{name} must be a positive length, got {x!r}")
    return (math.degrees(math.atan(0.5 * width_cm / distance_cm)),
            math.degrees(math.atan(0.5 * height_cm / distance_cm)))


def _candidates(targets, weights, screen_half_deg) -> Tuple[np.ndarray, np.ndarray]:
    """Candidate directions (N, 2) deg on the screen and their weights (N,)."""
    h, v = _check_screen(screen_half_deg)
    if targets is None:
        if weights is not None:
            raise ValueError("weights given without targets")
        xs = np.arange(-math.floor(h), math.floor(h) + 1, DEFAULT_GRID_STEP_DEG)
        ys = np.arange(-math.floor(v), math.floor(v) + 1, DEFAULT_GRID_STEP_DEG)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        return pts, np.ones(len(pts))
    pts = np.asarray(targets, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise ValueError(f"targets must have shape (N, 2) deg, got {pts.shape}")
    if weights is None:
        w = np.ones(len(pts))
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (len(pts),):
            raise ValueError(f"weights must have shape ({len(pts)},), got {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError("weights must be finite and non-negative")
    if not np.all(np.isfinite(pts)):
        raise ValueError("targets must be finite")
    inside = (np.abs(pts[:, 0]) <= h) & (np.abs(pts[:, 1]) <= v)
    pts, w = pts[inside], w[inside]
    if len(pts) == 0 or not np.any(w > 0):
        raise ValueError(f"no target with positive weight lies on the screen (half extents {h:g}, {v:g} deg)")
    return pts, w


def target_probabilities(settings: EyeHeadSettings, targets_deg, weights, screen_half_deg) -> np.ndarray:
    """Probability (N,) of each candidate being the next target: weight times the central bias.

    targets_deg : (N, 2) deg on the screen; weights : (N,) non-negative;
    screen_half_deg : (horizontal, vertical) half extents, deg.
    """
    h, v = _check_screen(screen_half_deg)
    pts = np.asarray(targets_deg, dtype=float)
    sx, sy = settings.central_bias_sigma_frac_h * h, settings.central_bias_sigma_frac_v * v
    bias = np.exp(-0.5 * ((pts[:, 0] / sx) ** 2 + (pts[:, 1] / sy) ** 2))
    p = np.asarray(weights, dtype=float) * bias
    total = p.sum()
    if not total > 0:
        raise ValueError("the targets' weights times the central bias sum to zero")
    return p / total


# ----------------------------------------------------------------------------
# the simulator
# ----------------------------------------------------------------------------

@dataclass
class _HeadMove:
    onset_s: float
    duration_s: float
    displacement_deg: np.ndarray      # (2,)

    @property
    def end_s(self) -> float:
        return self.onset_s + self.duration_s


class _Head:
    """The head as a sum of minimum-jerk movements (overlapping ones add)."""

    def __init__(self, start_deg: np.ndarray):
        self.base = np.array(start_deg, dtype=float)     # start plus every finished movement
        self.active: list[_HeadMove] = []

    def planned_end(self) -> np.ndarray:
        return self.base + sum((m.displacement_deg for m in self.active), np.zeros(2))

    def retire(self, t_s: float) -> None:
        """Fold movements finished by ``t_s`` into the base."""
        keep = []
        for m in self.active:
            if m.end_s <= t_s:
                self.base = self.base + m.displacement_deg
            else:
                keep.append(m)
        self.active = keep

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """Head direction (len(t), 2) deg at times ``t_s`` (none before the last retire time)."""
        out = np.broadcast_to(self.base, (len(t_s), 2)).copy()
        for m in self.active:
            out += _min_jerk((t_s - m.onset_s) / m.duration_s)[:, None] * m.displacement_deg
        return out

    def last_end_s(self) -> float:
        return max((m.end_s for m in self.active), default=0.0)


def _clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return v * np.where(norm > limit, limit / np.maximum(norm, 1e-300), 1.0)


def _run(settings: EyeHeadSettings, next_target: Callable[[int, np.ndarray], np.ndarray],
         fixation_s: Callable[[int], float], n_samples: int, rate_hz: float,
         start_deg: Tuple[np.ndarray, np.ndarray]) -> ViewerTrace:
    """The simulation loop: one iteration per gaze shift and the fixation after it.

    next_target(i, current_target) -> (2,) deg; fixation_s(i) -> s. Samples
    are filled window by window (a window is a gaze shift and its fixation).
    """
    dt = 1.0 / rate_hz
    t_all = np.arange(n_samples) * dt
    head_out = np.zeros((n_samples, 2))
    eye_out = np.zeros((n_samples, 2))
    phase = np.full(n_samples, PHASE_FIXATION, dtype=np.int8)
    fix_idx = np.full(n_samples, -1, dtype=np.int64)
    limit = settings.eye_orbit_limit_deg

    head0, eye0 = (np.asarray(x, dtype=float) for x in start_deg)
    head = _Head(head0)
    gaze_now = head0 + eye0
    target = gaze_now.copy()
    rows = {k: [] for k in ("target", "onset", "land", "head_onset", "dh", "fix")}

    # Fixation 0: the start, eyes on `target`, nothing moving.
    k_next = min(n_samples, max(1, int(round(fixation_s(0) * rate_hz))))
    head_out[:k_next] = head0
    eye_out[:k_next] = eye0
    fix_idx[:k_next] = 0
    for key, val in (("target", target), ("onset", math.nan), ("land", 0.0), ("head_onset", math.nan),
                     ("dh", np.zeros(2)), ("fix", k_next * dt)):
        rows[key].append(val)

    i = 0
    while k_next < n_samples:
        i += 1
        k_on = k_next
        t_on = k_on * dt
        head.retire(t_on)
        new_target = np.asarray(next_target(i, target), dtype=float)

        # The head: planned from the target relative to where the head is heading.
        dh = head_displacement_deg(settings, new_target - head.planned_end())
        dh_norm = float(np.linalg.norm(dh))
        head_onset = math.nan
        if dh_norm > 0:
            head_onset = t_on + settings.head_lag_s
            head.active.append(_HeadMove(head_onset, float(head_duration_s(settings, dh_norm)), dh))

        # Gaze: a main-sequence saccade from where gaze is to the target.
        amp = float(np.linalg.norm(new_target - gaze_now))
        dur = float(saccade_duration_s(settings, amp))
        ratio = _peak_to_mean(settings, amp)
        n_sac = max(1, math.ceil(dur * rate_hz - 1e-9))

        # Landing: the plan's end, or later if the head must first bring the
        # target within the eye's reach.
        k_plan_end = k_on + n_sac
        k_land = k_plan_end
        head_left_s = max(0.0, head.last_end_s() - k_plan_end * dt)
        k_search_end = k_plan_end + math.ceil(head_left_s * rate_hz) + 1
        t_search = np.arange(k_plan_end, k_search_end) * dt
        reach = np.linalg.norm(new_target - head.at(t_search), axis=1) <= limit
        if reach.any():
            k_land = k_plan_end + int(np.argmax(reach))
        else:                                        # cannot happen: the plan ends with the eye inside the limit
            k_land = k_search_end

        f_s = fixation_s(i)
        k_end = k_land + max(1, int(round(f_s * rate_hz)))
        k_stop = min(k_end, n_samples)

        ks = np.arange(k_on, k_stop)
        t = ks * dt
        h = head.at(t)
        tau = (ks - k_on) / (dur * rate_hz)
        plan = gaze_now + _saccade_position(tau, ratio)[:, None] * (new_target - gaze_now)
        eye_des = plan - h
        fixating = ks >= k_land
        if fixating.any():
            h_land = head.at(np.array([k_land * dt]))[0]
            eye_des[fixating] = (new_target - h_land) - settings.vor_gain * (h[fixating] - h_land)
        eye = _clip_norm(eye_des, limit)

        head_out[k_on:k_stop] = h
        eye_out[k_on:k_stop] = eye
        phase[k_on:k_stop] = np.where(fixating, PHASE_FIXATION, PHASE_SACCADE)
        fix_idx[k_on:k_stop] = np.where(fixating, i, -1)
        for key, val in (("target", new_target), ("onset", t_on), ("land", k_land * dt),
                         ("head_onset", head_onset), ("dh", dh), ("fix", (k_end - k_land) * dt)):
            rows[key].append(val)

        gaze_now = h[-1] + eye[-1] if len(h) else gaze_now
        target = new_target
        k_next = k_end

    return ViewerTrace(
        rate_hz=float(rate_hz), t_s=t_all, head_deg=head_out, eye_in_head_deg=eye_out,
        gaze_deg=head_out + eye_out, phase=phase, fixation_index=fix_idx,
        target_deg=np.array(rows["target"], dtype=float).reshape(-1, 2),
        shift_onset_s=np.array(rows["onset"], dtype=float),
        land_s=np.array(rows["land"], dtype=float),
        head_onset_s=np.array(rows["head_onset"], dtype=float),
        head_displacement_deg=np.array(rows["dh"], dtype=float).reshape(-1, 2),
        fixation_duration_s=np.array(rows["fix"], dtype=float),
    )


def _check_timing(duration_s: float, rate_hz: float) -> int:
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f"rate_hz must be positive, got {rate_hz!r}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be positive, got {duration_s!r}")
    return max(1, int(round(duration_s * rate_hz)))


def simulate_viewer(settings: EyeHeadSettings, targets=None, weights=None, *,
                    screen_half_deg: Sequence[float], duration_s: float, rate_hz: float = 1000.0,
                    seed: int = 0) -> ViewerTrace:
    """Simulate a viewer looking around a screen; deterministic for a seed.

    Parameters
    ----------
    settings : EyeHeadSettings
    targets : (N, 2) array, deg, optional
        Candidate gaze targets (horizontal, vertical angles from the screen's
        centre normal); those off the screen are dropped. None: every point of
        a 1-deg grid over the screen (a featureless scene).
    weights : (N,) array, optional
        Non-negative interest of each target (e.g. local contrast); None: equal.
    screen_half_deg : (h, v), deg
        The screen's angular half extents: they bound the targets.
    duration_s : float, s;  rate_hz : float, Hz
    seed : int, for ``np.random.default_rng``.

    The viewer starts at the screen's centre, head and eyes centred. Each
    next target is drawn from the candidates by weight times the central
    bias, never the current target again (when there is another).

    Returns
    -------
    ViewerTrace
    """
    n = _check_timing(duration_s, rate_hz)
    pts, w = _candidates(targets, weights, screen_half_deg)
    p = target_probabilities(settings, pts, w, screen_half_deg)
    rng = np.random.default_rng(seed)
    scale = settings.fixation_mean_s / settings.fixation_gamma_shape
    current = {"index": -1}

    def next_target(i, _current):
        q = p
        if current["index"] >= 0 and np.count_nonzero(p) > 1:
            q = p.copy()
            q[current["index"]] = 0.0
            q /= q.sum()
        k = int(rng.choice(len(pts), p=q))
        current["index"] = k
        return pts[k]

    def fixation_s(i):
        return float(rng.gamma(settings.fixation_gamma_shape, scale))

    zero = np.zeros(2)
    return _run(settings, next_target, fixation_s, n, rate_hz, (zero, zero))


def simulate_gaze_shift(settings: EyeHeadSettings, target_deg, *, gaze_start_deg=(0.0, 0.0),
                        head_start_deg=(0.0, 0.0), rate_hz: float = 1000.0, hold_s: float = 1.0,
                        lead_s: float = 0.1) -> ViewerTrace:
    """One gaze shift from a still start to ``target_deg``, then a long fixation.

    target_deg, gaze_start_deg, head_start_deg : (2,) deg. The eye starts at
    ``gaze_start_deg - head_start_deg`` (it must be within the orbit limit).
    The shift begins after ``lead_s`` s of fixation; the trace runs
    ``hold_s`` s past the landing, long enough for the head to finish.
    For tests of single shifts (main sequence, head share, VOR).
    """
    g0 = np.asarray(gaze_start_deg, dtype=float)
    h0 = np.asarray(head_start_deg, dtype=float)
    goal = np.asarray(target_deg, dtype=float)
    for name, v in (("target_deg", goal), ("gaze_start_deg", g0), ("head_start_deg", h0)):
        if v.shape != (2,) or not np.all(np.isfinite(v)):
            raise ValueError(f"{name} must be 2 finite deg, got {v!r}")
    if np.linalg.norm(g0 - h0) > settings.eye_orbit_limit_deg:
        raise ValueError("the start puts the eye beyond its orbit limit: "
                         f"|gaze - head| = {np.linalg.norm(g0 - h0):.3g} deg > {settings.eye_orbit_limit_deg:g}")
    amp = float(np.linalg.norm(goal - g0))
    head_s = float(head_duration_s(settings, np.linalg.norm(goal - h0)))
    total = lead_s + float(saccade_duration_s(settings, amp)) + settings.head_lag_s + head_s + hold_s
    n = _check_timing(total, rate_hz)
    return _run(settings, lambda i, cur: goal, lambda i: lead_s if i == 0 else total,
                n, rate_hz, (h0, g0 - h0))


# ----------------------------------------------------------------------------
# eye-in-head offsets: the "gaze prior"
# ----------------------------------------------------------------------------

#: Sampling rate of the simulations behind the offset statistics, Hz: a
#: display's rate is all a renderer sees; finer only costs time.
OFFSET_RATE_HZ = 100.0


def eye_offset_distribution(settings: EyeHeadSettings, screen_half_deg: Sequence[float], n: int,
                            seed: int = 0, targets=None, weights=None) -> np.ndarray:
    """Eye-in-head offsets, (n, 2) deg, one per fixation at a random moment of it.

    The viewer of :func:`simulate_viewer` (same targets, weights and central
    bias) is run long enough for ``n`` fixations after the start's; each
    contributes the eye's rotation in the head at one uniformly drawn sample
    of its (possibly VOR-counter-rotating) fixation, the offset a renderer
    following the head would see at a random frame. Deterministic for a seed.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n must be a positive integer, got {n!r}")
    n = int(n)
    per_fixation_s = settings.fixation_mean_s + float(saccade_duration_s(settings, 30.0)) + settings.head_lag_s
    duration = 1.2 * (n + 2) * per_fixation_s + 1.0
    pick_rng = np.random.default_rng([seed, 1])     # a stream apart from the simulation's
    while True:
        trace = simulate_viewer(settings, targets, weights, screen_half_deg=screen_half_deg,
                                duration_s=duration, rate_hz=OFFSET_RATE_HZ, seed=seed)
        fi = trace.fixation_index
        # Whole fixations only: not the start's (0), not the last (cut by the end).
        last = int(fi.max())
        usable = (fi > 0) & (fi < last)
        order = np.flatnonzero(usable)
        ids = fi[order]
        starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
        if len(starts) >= n:
            break
        duration *= 2.0
    counts = np.diff(np.r_[starts, len(ids)])
    pick = starts[:n] + (pick_rng.random(n) * counts[:n]).astype(np.int64)
    return np.array(trace.eye_in_head_deg[order[pick]])


def offset_sigma_deg(settings: EyeHeadSettings, screen_half_deg: Sequence[float], n: int = 20000,
                     seed: int = 0, targets=None, weights=None) -> Tuple[float, float]:
    """(σ_h, σ_v), deg: RMS of the eye-in-head offsets during fixation, about zero.

    About zero (not the mean) because the prior it feeds is centred on the
    head's direction. From :func:`eye_offset_distribution` with the same
    arguments.
    """
    off = eye_offset_distribution(settings, screen_half_deg, n, seed, targets, weights)
    rms = np.sqrt(np.mean(off ** 2, axis=0))
    return float(rms[0]), float(rms[1])


# ----------------------------------------------------------------------------
# does the head's motion tell where the eyes are?
# ----------------------------------------------------------------------------

#: Default window, s, of the causal moving average on the head's angular
#: velocity in :func:`eye_lead_fit`: about what a tracker's pose filter
#: (e.g. a One Euro filter at 60-100 Hz) averages over, and short against a
#: head movement (0.15 s or more in the model).
EYE_LEAD_SMOOTHING_S = 0.05

#: Default head speed, deg/s, above which :func:`eye_lead_fit` counts the head
#: as moving: well above a tracker's jitter, well below a head turn's peak.
EYE_LEAD_MOVING_DEG_S = 10.0


def _causal_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Trailing mean over ``n`` samples (fewer at the start) along axis 0."""
    if n <= 1:
        return x.copy()
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x]), axis=0)
    k = np.arange(1, len(x) + 1)
    lo = np.maximum(k - n, 0)
    counts = (k - lo).reshape((-1,) + (1,) * (x.ndim - 1))
    return (c[k] - c[lo]) / counts


def eye_lead_fit(trace, smoothing_s: float = EYE_LEAD_SMOOTHING_S, max_speed_deg_s: float | None = None,
                 moving_threshold_deg_s: float = EYE_LEAD_MOVING_DEG_S) -> dict:
    """Fit eye-in-head ≈ τ·ω, ω the head's angular velocity, per axis.

    The question: could a renderer that knows only the head's pose and its
    velocity centre its gaze prior at ``τ·ω`` (eyes leading the head) rather
    than at the head's direction, and how much would that explain?

    Parameters
    ----------
    trace : ViewerTrace, or any object with ``rate_hz`` (Hz),
        ``head_deg`` (T, 2) deg and ``eye_in_head_deg`` (T, 2) deg.
    smoothing_s : float, s, default 0.05
        Window of a causal (trailing) moving average on the velocity, as a
        tracker's filtered pose would give it; a renderer cannot see the
        future, so the window only looks back (its lag is about half the
        window). 0 (or under 1.5 samples): the raw backward
        difference.
    max_speed_deg_s : float, deg/s, optional
        If given, ω's norm is clipped to it (a renderer saturating
        implausible speeds); None: no clip.
    moving_threshold_deg_s : float, deg/s, default 10
        |ω| (norm of both axes) above which the head counts as moving.

    ω is the backward difference of ``head_deg`` times ``rate_hz`` (0 at the
    first sample), then smoothed. τ per axis is the least-squares slope
    through the origin ``Σ e ω / Σ ω²`` over all samples; NaN on an axis where
    ω is identically zero (the prediction there is 0).

    Returns
    -------
    dict with
        tau_s : (τ_h, τ_v), s.
        r2 : (h, v), ``1 - Σ (e - τω)² / Σ e²``: the share of the offset's
            mean square about zero (the head-centred prior's) that the
            velocity-centred prior removes; on moving samples ``r2_moving``.
        rms_about_zero_deg, rms_about_fit_deg : (h, v), deg, over all samples.
        rms_about_zero_moving_deg, rms_about_fit_moving_deg : (h, v), deg,
            over samples where the head moves (NaN if none).
        moving_fraction : share of samples where |ω| > the threshold.
        omega_rms_deg_s : (h, v), deg/s, RMS of ω over all samples.
        smoothing_s, smoothing_samples, moving_threshold_deg_s, n_samples.
    """
    rate = float(trace.rate_hz)
    head = np.asarray(trace.head_deg, dtype=float)
    eye = np.asarray(trace.eye_in_head_deg, dtype=float)
    if head.ndim != 2 or head.shape[1] != 2 or eye.shape != head.shape or len(head) < 2:
        raise ValueError(f"head_deg and eye_in_head_deg must both be (T, 2), T >= 2; got {head.shape}, {eye.shape}")
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"rate_hz must be positive, got {rate!r}")
    if not (math.isfinite(smoothing_s) and smoothing_s >= 0):
        raise ValueError(f"smoothing_s must be >= 0, got {smoothing_s!r}")
    if max_speed_deg_s is not None and not max_speed_deg_s > 0:
        raise ValueError(f"max_speed_deg_s must be positive or None, got {max_speed_deg_s!r}")

    omega = np.zeros_like(head)
    omega[1:] = np.diff(head, axis=0) * rate
    n_smooth = max(1, int(round(smoothing_s * rate)))
    omega = _causal_mean(omega, n_smooth)
    speed = np.linalg.norm(omega, axis=1)
    if max_speed_deg_s is not None:
        omega = omega * np.minimum(1.0, max_speed_deg_s / np.maximum(speed, 1e-300))[:, None]
        speed = np.minimum(speed, max_speed_deg_s)

    ww = np.sum(omega ** 2, axis=0)
    ew = np.sum(eye * omega, axis=0)
    tau = np.where(ww > 0, ew / np.where(ww > 0, ww, 1.0), np.nan)
    pred = np.nan_to_num(tau) * omega
    resid = eye - pred
    moving = speed > moving_threshold_deg_s

    def rms(x):
        return tuple(float(v) for v in np.sqrt(np.mean(x ** 2, axis=0))) if len(x) else (math.nan, math.nan)

    def r2(e, r):
        if not len(e):
            return (math.nan, math.nan)
        ee = np.sum(e ** 2, axis=0)
        return tuple(float(1.0 - a / b) if b > 0 else math.nan for a, b in zip(np.sum(r ** 2, axis=0), ee))

    return {
        "tau_s": tuple(float(v) for v in tau),
        "r2": r2(eye, resid),
        "r2_moving": r2(eye[moving], resid[moving]),
        "rms_about_zero_deg": rms(eye),
        "rms_about_fit_deg": rms(resid),
        "rms_about_zero_moving_deg": rms(eye[moving]),
        "rms_about_fit_moving_deg": rms(resid[moving]),
        "moving_fraction": float(moving.mean()),
        "omega_rms_deg_s": rms(omega),
        "smoothing_s": n_smooth / rate,
        "smoothing_samples": n_smooth,
        "moving_threshold_deg_s": float(moving_threshold_deg_s),
        "n_samples": int(len(head)),
    }
