"""One view-conditioning step per frame: the tracker's pose made into the view every back end reads.

A PLOD frame starts from a raw :class:`View`: the eye (world frame = left
camera frame, mm), the point of interest (POI, screen px), the covariance of
the viewing direction (deg², docs/contract.md) and the time (s). Before any
level is chosen, that view is *conditioned* once:

- the eye and the POI go through One Euro filters (the tracker's noise out,
  real motion through), restarted by a jump (:meth:`ViewConditioner._filter`);
- the uncertainty scenario picks the covariance the selection uses
  (:class:`UncertaintyPolicy`: ``none``, ``fixed``, ``adaptive``, ``smoothed``);
- the head axes Ξ, Ψ, V look from the filtered eye at the filtered POI
  (:func:`head_axes`);
- the hysteresis state for the frame: whether the filters restarted (the
  levels' dead band restarts with them), whether the POI moves (the band then
  lets triangles near it refine at once), and whether the raw POI moves as
  fast as a saccade (the last levels are then kept: a saccade's blur hides
  them).

The result is a :class:`ConditionedView`, a small frozen value. Every back end
(the flat and tree selectors over a mesh, the GPU patches, the ray mask, the
foveated layers) reads it and never the raw view, so a setting means the same
on every back end: ``none`` ignores the covariance everywhere.

Every setting is a field of :class:`headplod.plod.select.SelectorConfig`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..filters import OneEuroFilter
from ..angles import angle_between_deg

__all__ = ["UNCERTAINTY_MODES", "View", "ConditionedView", "UncertaintyPolicy", "ViewConditioner", "head_axes",
           "poi_direction", "default_head", "still_view", "gaze_covariance", "require_conditioned"]

UNCERTAINTY_MODES = ("none", "fixed", "adaptive", "smoothed")
"""Which covariance the selection uses (:attr:`SelectorConfig.uncertainty`, :class:`UncertaintyPolicy`)."""


@dataclass
class View:
    """One frame's raw view of the screen, as the tracker gives it.

    Attributes
    ----------
    eye_mm : (3,)
        Eye (head) position, world frame, mm.
    poi_px : (2,)
        Point of interest on the screen, screen pixels.
    cov_deg2 : (2, 2) or None
        Covariance of (φ, θ) of the viewing direction, deg².
    t : float or None
        Time, s; None: no time (the filters are bypassed).
    """

    eye_mm: np.ndarray
    poi_px: np.ndarray
    cov_deg2: np.ndarray | None = None
    t: float | None = 0.0


@dataclass(frozen=True)
class ConditionedView:
    """One frame's view after conditioning: what every back end reads.

    Attributes
    ----------
    t : float or None
        Time, s.
    eye_mm : (3,) float64
        Filtered eye, world frame, mm: the levels are chosen from here.
    poi_px : (2,) float64
        Filtered POI, screen px.
    axes : (3, 3) float64
        Rows Ξ, Ψ, V of the head frame looking from ``eye_mm`` at ``poi_px``
        (Ξ along the screen's rows; :func:`head_axes`).
    cov_deg2 : (2, 2) float64 or None
        The covariance of where the viewer looks about V, (φ, θ) deg², that
        the selection uses: the covariance of V the scenario gives (none for
        ``none``, and before any covariance was seen) plus the eye-in-head
        prior (:attr:`SelectorConfig.gaze_prior`; :func:`gaze_covariance`).
        None when there is neither.
    raw_eye_mm : (3,) float64
        The tracker's eye, world mm: the camera is placed here (the image is
        drawn from where the eye is; only the levels are smoothed).
    raw_poi_px : (2,) float64
        The tracker's POI, screen px.
    raw_cov_deg2 : (2, 2) float64 or None
        The tracker's covariance, deg².
    restart : bool
        The filters restarted on a jump this frame: a selector's hysteresis
        restarts too, so the levels follow within the frame.
    gaze_speed_deg_s : float
        Angular speed of the direction from the filtered eye to the filtered
        POI since the last frame, deg/s (0 on the first).
    moving : bool
        ``gaze_speed_deg_s`` above ``SelectorConfig.hysteresis_eager_deg_s``:
        near the POI the hysteresis lets triangles refine at once.
    saccade : bool
        The raw POI's direction moved faster than
        ``SelectorConfig.saccade_hold_deg_s`` since the last frame: the frame
        step keeps the last levels.
    poi_speed_deg_s : float
        That raw speed, deg/s (0 on the first frame).
    """

    t: float | None
    eye_mm: np.ndarray
    poi_px: np.ndarray
    axes: np.ndarray
    cov_deg2: np.ndarray | None
    raw_eye_mm: np.ndarray
    raw_poi_px: np.ndarray
    raw_cov_deg2: np.ndarray | None
    restart: bool = False
    gaze_speed_deg_s: float = 0.0
    moving: bool = False
    saccade: bool = False
    poi_speed_deg_s: float = 0.0

    @property
    def gaze(self) -> np.ndarray:
        """(3,) unit vector V from the filtered eye to the filtered POI, world frame."""
        return self.axes[2]


def require_conditioned(view, where: str) -> None:
    """Raise TypeError unless ``view`` is a :class:`ConditionedView`: a back end (``where``, e.g.
    ``"LevelSelector.select"``) reads only conditioned views and conditions nothing itself."""
    if not isinstance(view, ConditionedView):
        raise TypeError(f"{where} takes a ConditionedView (condition the raw view first with a ViewConditioner, "
                        f"as the frame step does), got {type(view).__name__}")


def head_axes(screen, eye_mm, poi_px) -> np.ndarray:
    """(3, 3) rows Ξ, Ψ, V of the head frame looking from the eye at the POI.

    ``eye_mm`` (3,) world mm; ``poi_px`` (2,) screen px. V points from the eye
    to the POI, Ξ along the screen's rows (orthogonalised to V), Ψ = V × Ξ.
    The one definition of the head frame for every criterion and back end.
    """
    eye = np.asarray(eye_mm, dtype=np.float64)
    v = screen.pixel_to_world(np.asarray(poi_px, dtype=np.float64)) - eye
    v = v / np.linalg.norm(v)
    right = np.asarray(screen.top_right, float) - np.asarray(screen.top_left, float)
    xi = right - v * (right @ v)
    xi /= np.linalg.norm(xi)
    return np.stack([xi, np.cross(v, xi), v])


def default_head(screen, distance_mm: float = 600.0) -> np.ndarray:
    """(3,) world mm: the eye ``distance_mm`` in front of the screen centre, on the viewer's side (away from
    the scene): the view a frame takes when no head is given."""
    centre = screen.pixel_to_world(np.array(screen.size_px, dtype=np.float64) / 2.0)
    normal = np.cross(np.asarray(screen.top_right) - screen.top_left, np.asarray(screen.bottom_left) - screen.top_left)
    normal /= np.linalg.norm(normal)
    # The cameras (world origin) are on the viewer's side of the screen.
    if normal @ (np.zeros(3) - centre) < 0:
        normal = -normal
    return centre + distance_mm * normal


def still_view(screen, eye_mm=None, poi_px=None, cov_deg2=None, t: float | None = 0.0) -> View:
    """A :class:`View` with the defaults of a one-frame render: the eye at :func:`default_head` (world mm),
    the POI at the screen centre (screen px); given values as float64 arrays."""
    eye = default_head(screen) if eye_mm is None else np.asarray(eye_mm, dtype=np.float64)
    poi = np.array(screen.size_px, dtype=np.float64) / 2 if poi_px is None else np.asarray(poi_px, dtype=np.float64)
    return View(eye, poi, cov_deg2, t)


def poi_direction(screen, eye_mm, poi_px) -> np.ndarray:
    """(3,) unit vector from the eye (world mm) to the POI (screen px), world frame."""
    d = screen.pixel_to_world(np.asarray(poi_px, dtype=np.float64)) - np.asarray(eye_mm, dtype=np.float64)
    return d / np.linalg.norm(d)


class UncertaintyPolicy:
    """Which covariance the selection uses: none, the largest seen (fixed), this frame's, or smoothed.

    ``smoothing_frames``: the time constant of ``smoothed``, frames (each
    frame's covariance enters with weight 1/smoothing_frames).
    """

    def __init__(self, mode: str = "adaptive", smoothing_frames: float = 15):
        if mode not in UNCERTAINTY_MODES:
            raise ValueError(f"uncertainty mode must be one of {UNCERTAINTY_MODES}, got {mode!r}")
        self.mode, self.smoothing_frames = mode, smoothing_frames
        self.fixed = None
        self.smoothed = None

    def __call__(self, cov):
        """The covariance (2, 2) deg² for this frame's ``cov`` (2, 2) deg² or None; None for ``none``."""
        if self.mode == "none" or cov is None:
            return None if self.mode == "none" else (self.fixed if self.mode == "fixed" else self.smoothed)
        cov = np.asarray(cov, dtype=np.float64)
        if self.fixed is None or np.trace(cov) > np.trace(self.fixed):
            self.fixed = cov
        rate = 1.0 / self.smoothing_frames
        self.smoothed = cov if self.smoothed is None else (1 - rate) * self.smoothed + rate * cov
        return {"fixed": self.fixed, "adaptive": cov, "smoothed": self.smoothed}[self.mode]

    def reset(self) -> None:
        self.fixed = None
        self.smoothed = None


def gaze_covariance(cov_deg2, prior_sigma_deg) -> np.ndarray | None:
    """(2, 2) deg² over (φ, θ): the covariance of where the viewer looks about V, or None.

    ``cov_deg2`` (2, 2) deg² or None: the tracker's covariance of V (after the
    scenario); ``prior_sigma_deg`` (horizontal, vertical) deg: the σ of the
    eyes' offset in the head (:attr:`SelectorConfig.gaze_prior`). The two are
    independent, so their covariances add; φ is vertical and θ horizontal
    (docs/contract.md), hence the prior's diagonal (vertical², horizontal²).
    None when ``cov_deg2`` is None and the prior is zero (the paper's head-only view with ``none``).
    """
    horizontal, vertical = (float(v) for v in prior_sigma_deg)
    if horizontal == 0 and vertical == 0:
        return cov_deg2
    prior = np.diag([vertical ** 2, horizontal ** 2])
    return prior if cov_deg2 is None else np.asarray(cov_deg2, dtype=np.float64) + prior


class ViewConditioner:
    """Makes each frame's :class:`ConditionedView` (module notes). Call once per frame.

    Parameters
    ----------
    screen : headplod.io.Screen
    config : headplod.plod.select.SelectorConfig
        The smoothing, jump, scenario, eager and saccade settings.
    """

    def __init__(self, screen, config):
        self.screen = screen
        self.config = config
        self.px_per_mm = screen.size_px[0] / float(np.linalg.norm(np.asarray(screen.top_right) - screen.top_left))
        self.policy = UncertaintyPolicy(config.uncertainty, config.uncertainty_smoothing_frames)
        self.reset()

    def reset(self) -> None:
        """Forget the filters, the scenario's memory and the last frame (a new run, or a new setting)."""
        self.policy.reset()
        self._filters = None          # the eye and POI One Euro filters
        self._raw = None              # (t, eye, poi) of the last raw view
        self._velocity = None         # (eye mm/s, poi px/s) of the last two raw views
        self._previous_gaze = None    # (t, filtered gaze (3,))
        self._previous_poi = None     # (t, raw direction to the POI (3,))

    def __call__(self, view: View) -> ConditionedView:
        raw_eye = np.asarray(view.eye_mm, dtype=np.float64)
        raw_poi = np.asarray(view.poi_px, dtype=np.float64)
        raw_cov = None if view.cov_deg2 is None else np.asarray(view.cov_deg2, dtype=np.float64)
        eye, poi, restart = self._filter(view.t, raw_eye, raw_poi, raw_cov)
        axes = head_axes(self.screen, eye, poi)
        gaze_speed = self._speed("_previous_gaze", view.t, axes[2])
        poi_speed = self._speed("_previous_poi", view.t, poi_direction(self.screen, raw_eye, raw_poi))
        cfg = self.config
        cov = gaze_covariance(self.policy(raw_cov), cfg.gaze_prior)
        return ConditionedView(view.t, eye, poi, axes, cov, raw_eye, raw_poi, raw_cov,
                               restart=restart, gaze_speed_deg_s=gaze_speed,
                               moving=gaze_speed > cfg.hysteresis_eager_deg_s,
                               saccade=poi_speed > cfg.saccade_hold_deg_s, poi_speed_deg_s=poi_speed)

    def _speed(self, slot: str, t, direction) -> float:
        """Angular speed (deg/s) of ``direction`` (3,) since the last frame's in ``slot``; 0 on the first."""
        previous = getattr(self, slot)
        setattr(self, slot, (t, direction))
        if previous is None or t is None or previous[0] is None or t <= previous[0]:
            return 0.0
        return float(angle_between_deg(direction, previous[1])) / (t - previous[0])

    def _filter(self, t, eye, poi, cov):
        """(filtered eye (3,) mm, filtered POI (2,) px, restarted: bool).

        Tracker noise moves the eye and the POI by a fraction of a degree per
        frame; unfiltered, that reads as tens of degrees per second of head
        motion and as eccentricity jitter, and triangles near a level boundary
        flicker (Ohshima et al. smooth the gaze for the same reason). A plain
        exponential average would lag a moving head by speed x time constant;
        the One Euro filter raises its cutoff with the speed, so a steady
        movement passes with little lag. A jump larger than the noise
        (``SelectorConfig.jump_*``; for the POI at least ``jump_poi_sigma`` of
        the tracker's σ of V on the screen) is a real movement: its filter
        restarts, and the levels follow within the frame. The jump is
        measured from where the last two raw samples were heading (constant
        velocity), not from the last sample, so a steady pursuit is not a jump.
        """
        if t is None:
            return eye, poi, False
        cfg = self.config
        if self._filters is None:
            cutoff = 1.0 / (2 * math.pi * cfg.smoothing_s)
            self._filters = {"eye": OneEuroFilter(cutoff, beta=cfg.eye_beta),
                             "poi": OneEuroFilter(cutoff, beta=cfg.poi_beta)}
        raw, velocity = self._raw, self._velocity
        self._raw = (t, eye, poi)
        jumped = False
        if raw is not None:
            dt = t - raw[0]
            predicted_eye, predicted_poi = raw[1], raw[2]
            if velocity is not None and 0 < dt < 0.5:
                predicted_eye = predicted_eye + velocity[0] * dt
                predicted_poi = predicted_poi + velocity[1] * dt
            self._velocity = ((eye - raw[1]) / dt, (poi - raw[2]) / dt) if dt > 0 else None
            # The prediction from two noisy samples has sqrt(1 + 4 + 1) times their noise.
            poi_noise_px = cfg.jump_poi_px
            if cov is not None:
                lam = float(np.linalg.eigvalsh(cov)[-1])
                reach_mm = float(np.linalg.norm(self.screen.pixel_to_world(poi) - eye))
                poi_noise_px = max(poi_noise_px, cfg.jump_poi_sigma * math.sqrt(6.0) * reach_mm
                                   * math.tan(math.radians(math.sqrt(max(lam, 0.0)))) * self.px_per_mm)
            # Each filter restarts on its own jump only: restarting the eye's on a saccade of the
            # POI would move the filtered eye by its lag at once, a speed spike that coarsened
            # the terrain for a frame.
            for name, value, predicted, limit in (("eye", eye, predicted_eye, cfg.jump_eye_mm),
                                                  ("poi", poi, predicted_poi, poi_noise_px)):
                if np.linalg.norm(value - predicted) > limit:
                    self._filters[name].reset()
                    jumped = True
            if jumped:
                self._velocity = None       # a jump's step is not a velocity to extrapolate
        return self._filters["eye"](eye, t), self._filters["poi"](poi, t), jumped
