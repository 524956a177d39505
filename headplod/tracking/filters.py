"""Smoothing of the head pose: :class:`PoseFilter`, the One Euro filter on pose records.

The filter itself, and how to tune ``min_cutoff_hz`` and ``beta`` for head
tracking, is :mod:`headplod.filters` (pure numpy, shared with the PLOD level
selector).

:class:`PoseFilter` uses ``beta`` for the position and ``beta * lever_mm``
(``lever_mm`` = 100 mm: the speed of a point 10 cm along the direction) for
the direction unless ``beta_direction`` is given.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from ..filters import OneEuroFilter
from ..tol import tol

__all__ = ["PoseFilter"]


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
        if not (np.all(np.isfinite(v)) and n > tol.small):
            return record  # degenerate (cannot happen with sane input); keep the raw pose
        xi /= n
        out = dict(record)
        out["position"] = p_f.tolist()
        out["axes"] = [xi.tolist(), np.cross(v, xi).tolist(), v.tolist()]
        self._last_ok_t = t
        return out
