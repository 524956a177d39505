"""Smoothing of the head pose: the One Euro filter.

The One Euro filter (Casiez, Roussel & Vogel, "1€ Filter: A Simple
Speed-based Low-pass Filter for Noisy Input in Interactive Systems", CHI
2012) is a first-order low-pass filter whose cutoff frequency rises with the
speed of the signal: at rest a low cutoff removes jitter, in fast motion a
high cutoff removes lag. For a sample x_i at time t_i, with T_e = t_i - t_(i-1):

- alpha(f_c) = 1 / (1 + tau / T_e), tau = 1 / (2 pi f_c)
- dx_i = (x_i - x̂_(i-1)) / T_e, smoothed with alpha(d_cutoff) into dx̂_i
- f_c = min_cutoff + beta |dx̂_i|
- x̂_i = alpha(f_c) x_i + (1 - alpha(f_c)) x̂_(i-1)

Tuning for head tracking at 30-60 Hz
------------------------------------
Two parameters matter (``d_cutoff_hz`` = 1 Hz rarely needs changing):

``min_cutoff_hz`` (Hz): the cutoff at rest; it sets the jitter of a still
head and the lag of slow motion. Set ``beta`` = 0, hold still and lower it
until the jitter is acceptable: 0.5-1.5 Hz suits heads (with beta = 0,
1 Hz cuts the standard deviation of white noise sampled at 60 Hz about
4.5-fold, at 30 Hz about 3-fold). Below ~0.3 Hz slow drifts of the gaze visibly trail.

``beta`` (Hz per unit of speed of the filtered value): how fast the cutoff
rises with speed. For the position, speed is in mm/s, so beta is in
Hz / (mm/s); heads move at 50-500 mm/s, and beta = 0.01-0.05 raises the
cutoff to 3-25 Hz at 200-500 mm/s. For a unit direction vector, speed is in
1/s, which is the angular speed in rad/s, so beta is in Hz / (rad/s); heads
turn at 0.5-5 rad/s, and beta = 1-5 suits them. Raise beta, moving the head
quickly, until the lag is acceptable.

:class:`PoseFilter` uses ``beta`` for the position and ``beta * lever_mm``
(``lever_mm`` = 100 mm: the speed of a point 10 cm along the direction) for
the direction unless ``beta_direction`` is given.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np


def smoothing_factor(cutoff_hz: float, dt_s: float) -> float:
    """The exponential smoothing factor of a first-order low-pass filter.

    Parameters
    ----------
    cutoff_hz : float
        Cutoff frequency f_c, Hz (> 0).
    dt_s : float
        Time since the previous sample T_e, s (> 0).

    Returns
    -------
    float
        alpha = 1 / (1 + tau / T_e), tau = 1 / (2 pi f_c) (Casiez et al. 2012,
        eq. in section "1€ filter"); in (0, 1).
    """
    tau = 1.0 / (2.0 * math.pi * cutoff_hz)
    return 1.0 / (1.0 + tau / dt_s)


class OneEuroFilter:
    """The One Euro filter, for a scalar or an array of any fixed shape.

    Parameters
    ----------
    min_cutoff_hz : float
        Cutoff frequency at rest, Hz (> 0). Lower: less jitter, more lag.
    beta : float
        Cutoff increase per unit of speed, Hz per (unit of the value)/s (>= 0).
        Higher: less lag in fast motion.
    d_cutoff_hz : float
        Cutoff frequency of the speed estimate, Hz (> 0).

    Notes
    -----
    - The speed is the Euclidean norm of the whole array's derivative, so a
      vector gets one cutoff for all its components and the filter does not
      depend on the direction of motion (for a scalar this is |dx/dt|).
    - The first sample (and the first after :meth:`reset`) passes through
      unchanged, with a speed of zero.
    - Time steps may be irregular: alpha is computed from each step's T_e.
    - A sample holding a NaN or an infinity is rejected as a whole: the last
      output is returned and the state is left as it was. Before any good
      sample there is no output to return, and the input comes back as is.
    - A sample whose time is not after the previous one's (a duplicate or
      out of order) is ignored likewise: the last output is returned.
    """

    def __init__(self, min_cutoff_hz: float = 1.0, beta: float = 0.0, d_cutoff_hz: float = 1.0):
        if not min_cutoff_hz > 0:
            raise ValueError(f"min_cutoff_hz must be > 0, got {min_cutoff_hz}")
        if not beta >= 0:
            raise ValueError(f"beta must be >= 0, got {beta}")
        if not d_cutoff_hz > 0:
            raise ValueError(f"d_cutoff_hz must be > 0, got {d_cutoff_hz}")
        self.min_cutoff_hz = float(min_cutoff_hz)
        self.beta = float(beta)
        self.d_cutoff_hz = float(d_cutoff_hz)
        self.reset()

    def reset(self) -> None:
        """Forget the past: the next sample passes through."""
        self._x: np.ndarray | None = None  # last output x̂
        self._dx: np.ndarray | None = None  # last smoothed derivative dx̂
        self._t: float | None = None
        self.cutoff_hz: float | None = None  # cutoff used for the last sample

    def __call__(self, value, t_s: float) -> np.ndarray:
        """Filter one sample.

        Parameters
        ----------
        value : array_like of float
            The sample; any shape, the same for every call until :meth:`reset`.
        t_s : float
            Its time, s.

        Returns
        -------
        ndarray of float
            The filtered value, shape of ``value`` (a new array).

        Raises
        ------
        ValueError
            When the shape differs from the previous samples'.
        """
        x = np.array(value, dtype=float)
        t = float(t_s)
        if self._x is not None and x.shape != self._x.shape:
            raise ValueError(f"OneEuroFilter: expected a value of shape {self._x.shape}, got {x.shape}")
        if not (np.all(np.isfinite(x)) and math.isfinite(t)):
            return x if self._x is None else self._x.copy()
        if self._x is None:
            self._x, self._dx, self._t = x, np.zeros_like(x), t
            self.cutoff_hz = self.min_cutoff_hz
            return x.copy()
        dt = t - self._t
        if not dt > 0:
            return self._x.copy()
        dx = (x - self._x) / dt
        a_d = smoothing_factor(self.d_cutoff_hz, dt)
        dx_hat = self._dx + a_d * (dx - self._dx)
        cutoff = self.min_cutoff_hz + self.beta * float(np.linalg.norm(dx_hat))
        a = smoothing_factor(cutoff, dt)
        self._x = self._x + a * (x - self._x)  # = a x + (1 - a) x̂, exact for a constant
        self._dx, self._t, self.cutoff_hz = dx_hat, t, cutoff
        return self._x.copy()


class PoseFilter:
    """One Euro smoothing of pose records (position and head axes).

    The position (mm, world frame) goes through one :class:`OneEuroFilter`;
    V and Ξ (unit vectors, world frame) each through another, after which the
    axes are rebuilt as a proper rotation: V normalized, Ξ with its component
    along V removed and normalized, Ψ = V × Ξ (the contract's construction).

    Parameters
    ----------
    min_cutoff_hz : float
        Cutoff at rest, Hz, for position and direction.
    beta : float
        Speed coefficient for the position, Hz per (mm/s).
    d_cutoff_hz : float
        Cutoff of the speed estimates, Hz.
    beta_direction : float, optional
        Speed coefficient for the direction vectors, Hz per (rad/s). Default
        ``beta * lever_mm``.
    lever_mm : float
        Converts ``beta`` to ``beta_direction`` when that is not given: the
        distance from the head of the point whose linear speed stands for the
        angular speed (100 mm).
    reset_after_s : float
        A gap longer than this between two good poses (tracking lost)
        restarts the filters, so the first pose after it passes through
        instead of being pulled toward a stale one. Shorter gaps (a single
        failed frame) keep the state.

    Notes
    -----
    - A record with ``ok`` false is returned as is (the same object).
    - The returned record is a shallow copy with ``position`` and ``axes``
      replaced by the filtered ones (lists); ``cov`` and every other key are
      untouched, so keys derived from the raw pose (``poi_px``,
      ``residuals_px``) still refer to the raw pose.
    - A time that does not increase (a replay starting again) also restarts
      the filters.
    """

    def __init__(self, min_cutoff_hz: float = 1.0, beta: float = 0.02, d_cutoff_hz: float = 1.0, *,
                 beta_direction: float | None = None, lever_mm: float = 100.0, reset_after_s: float = 0.5):
        if not reset_after_s > 0:
            raise ValueError(f"reset_after_s must be > 0, got {reset_after_s}")
        beta_dir = beta * lever_mm if beta_direction is None else beta_direction
        self.position = OneEuroFilter(min_cutoff_hz, beta, d_cutoff_hz)
        self.view = OneEuroFilter(min_cutoff_hz, beta_dir, d_cutoff_hz)
        self.lateral = OneEuroFilter(min_cutoff_hz, beta_dir, d_cutoff_hz)
        self.reset_after_s = float(reset_after_s)
        self._last_ok_t: float | None = None

    def reset(self) -> None:
        """Restart all filters."""
        for f in (self.position, self.view, self.lateral):
            f.reset()
        self._last_ok_t = None

    def __call__(self, record: Mapping, t_s: float | None = None) -> Mapping:
        """Filter one pose record.

        Parameters
        ----------
        record : mapping
            A pose record (``ok``, ``t``, ``position`` (3,) mm, ``axes``
            (3, 3) rows Ξ, Ψ, V, world frame).
        t_s : float, optional
            Its time, s; default ``record["t"]``.

        Returns
        -------
        mapping
            The filtered record (see the class notes).

        Raises
        ------
        ValueError
            When an ok record has no time, or a position or axes of the wrong shape.
        """
        if not record.get("ok"):
            return record
        t = record.get("t") if t_s is None else t_s
        if t is None:
            raise ValueError("PoseFilter: the record has no 't' and no t_s was given")
        t = float(t)
        p = np.asarray(record["position"], dtype=float)
        axes = np.asarray(record["axes"], dtype=float)
        if p.shape != (3,) or axes.shape != (3, 3):
            raise ValueError(f"PoseFilter: expected position (3,) and axes (3, 3), got {p.shape} and {axes.shape}")
        if self._last_ok_t is not None and not (0 < t - self._last_ok_t <= self.reset_after_s):
            self.reset()
        xi_f = self.lateral(axes[0], t)
        v_f = self.view(axes[2], t)
        p_f = self.position(p, t)
        v = v_f / np.linalg.norm(v_f)
        xi = xi_f - (xi_f @ v) * v
        n = np.linalg.norm(xi)
        if not (np.all(np.isfinite(v)) and n > 1e-9):
            return record  # degenerate (cannot happen with sane input); keep the raw pose
        xi /= n
        out = dict(record)
        out["position"] = p_f.tolist()
        out["axes"] = [xi.tolist(), np.cross(v, xi).tolist(), v.tolist()]
        self._last_ok_t = t
        return out
