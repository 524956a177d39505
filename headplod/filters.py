"""The One Euro filter: speed-adaptive low-pass smoothing of a noisy signal (numpy only).

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

Pure numpy and imports nothing from ``headplod``: the tracker's pose smoothing
(:class:`headplod.tracking.filters.PoseFilter`) and the PLOD level selector's
eye and POI smoothing (:mod:`headplod.plod.select`) both use it.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["OneEuroFilter", "smoothing_factor"]


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
