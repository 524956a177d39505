"""The stereo IR head tracker: two images in, a verified head pose out.

Stages (each timed per frame in ``TrackResult.timings_s``):

1. ``detect``: blobs in both images (:mod:`headplod.tracking.detect`). While tracking,
   only a region around the previous frame's markers is searched and the
   previous labels are carried over by nearest neighbour; the whole image and
   a fresh identification are used when that fails.
2. ``identify``: labelings P0..P4 per image (:mod:`headplod.tracking.identify`), then
   the left/right pair that best satisfies the epipolar constraint and the
   marker model's geometry (rigid fit with the model's true size). When no
   pair of full labelings works, a marker hidden in one view is tried: the
   other view's blobs are matched to the labeled view through the same checks.
3. ``triangulate`` and ``pose``: one of the estimators of :mod:`headplod.tracking.geometry`.
4. ``verify``: reprojection residuals in both images and the rigid-fit error;
   a pose that fails them is not reported (``ok`` False with a reason). A
   pose that passes them only with the rig's uncertainty is corrected for
   the rig error its residuals show, or withheld (tracked from and refining
   the rig, not reported) when that correction, the motion over the right
   image's exposure offset, or the covariance of V is beyond what the
   evidence supports.

The frames' times are checked against each other and against the motion
(:meth:`Tracker._check_time`, :class:`~headplod.tracking.motion.PoseHistory`):
a jump back or far ahead resets the motion state, a repeated or glitching
time gives no velocity, and the result's ``notes`` say so. An exception
while processing a frame is isolated to it (:meth:`Tracker.process`).

States. The tracker is in one of two states for the markers, and one of
three for the rig:

- *acquire* (no lock): detect every blob and identify the five markers;
  *track* (a :class:`_Lock` on the last accepted frame's markers):
  re-measure them in small windows, and acquire when that fails. Only an
  accepted pose with every marker seen makes a lock; every refusal drops it.
- the rig: *as rig.yaml says* (no update yet; two consecutive frames that
  fail against it may replace it by the rig they show,
  :meth:`Tracker._bootstrap_rig`), *refining* (the online refinement's
  updates, every 8 tracked frames, solved over the following frames),
  *refined* (its turn and shift known to a tenth of their prior; a bump
  widens them again). :meth:`Tracker.state` names both.

A frame is one pass (:meth:`Tracker._attempt`): measure
(:meth:`Tracker._measure`), fit and check (:meth:`Tracker._fit`, a
:class:`_Fit`), the covariance of V (:meth:`Tracker._covariance_input`), the
rig's refinement (:meth:`Tracker._refine`); a pass that fails while
tracking is repeated acquiring.

Why this module is long (about 1,950 lines): :class:`Tracker` is one state
machine over a stereo stream, and its stages share that state (the lock,
the rig in use and its refinement, the noise tolerances the rig widens,
the suspects of a frame, the rolling shutter's compensation). What has no
state of its own lives elsewhere: detection, identification, geometry, the
head's recent motion (:mod:`.motion`), the covariance (:mod:`.uncertainty`)
and the rig's refinement (:mod:`.rig_refine`).
"""
from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field

import cv2
import numpy as np
import scipy.linalg
from scipy.stats import chi2

from . import geometry as geo
from . import rig_frames, rig_priors, rig_refine, rig_refine_config, rig_solve, rig_state
from .geometry import ESTIMATORS
from .detect import Blobs, DetectionParams, centroids_near, detect_blobs, estimate_background, shot_variance
from .identify import ModelRule, find_hypotheses
from .motion import PoseHistory
from .rig_refine import RigErrorModel, RigRefineConfig, RigRefiner, readout_prior, rig_jacobian_rows
from .uncertainty import DEFAULT_COVARIANCE, CovarianceInput, make_covariance_estimator, rig_residual_rows

# Read-only constants of the tracking path (copied before any change).
_ALL_VISIBLE = np.ones((2, 5), bool)
_NO_BLOB = np.full((2, 5), -1)
_NAN5 = np.full(5, np.nan)
_NAN53 = np.full((5, 3), np.nan)
for _constant in (_ALL_VISIBLE, _NO_BLOB, _NAN5, _NAN53):
    _constant.flags.writeable = False
MARKER_NAMES = ("P0", "P1", "P2", "P3", "P4")


def _scale_hint(points_mm: np.ndarray, model_mm: np.ndarray) -> str:
    """A hint on units when triangulated markers (5, 3) and the model (5, 3) differ in size, else "".

    Size: the RMS distance of the five points from their centroid. The
    markers seen 10, 25.4 or 1000 times the model's size mean a model in cm,
    inches or metres; any factor beyond 2 is worth saying.
    """
    def size(P):
        P = np.asarray(P, dtype=np.float64)
        return float(np.sqrt(np.mean(np.sum((P - P.mean(axis=0)) ** 2, axis=1))))

    seen, model = size(points_mm), size(model_mm)
    if not (model > 0 and np.isfinite(seen)) or 0.5 <= seen / model <= 2.0:
        return ""
    return (f"; the markers seen are {seen / model:.3g} times the size of the marker model: "
            "is markers.yaml in mm (conventions.md), and is it these glasses?")


# The module files of the rig's refinement: an exception that passed through
# them may have damaged its state (Tracker._internal_error restarts it).
_REFINER_FILES = tuple(module.__name__.rsplit(".", 1)[-1] + ".py" for module in (
    rig_refine, rig_state, rig_priors, rig_frames, rig_solve, rig_refine_config))
# A rig correction beyond these (mm, deg: ten times a clean pose's noise at
# 65 cm, ~0.5 mm and 0.05°) is refused when the frame cannot tell it from noise
# or a stray blob: with suspect centres, or P1 known to worse than 1.5 mm (1σ)
# after it; with five markers in both views a frame knows it to 0.2-1 mm
# (Tracker._rig_consistent).
_AMBIGUOUS_CORRECTION_MM = 5.0
_AMBIGUOUS_CORRECTION_DEG = 0.5
# Refusals that a rig far from rig.yaml explains (see Tracker._bootstrap_rig).
_RIG_FAILURES = ("reprojection error", "the images disagree with the rig", "the rig's error moves this pose")
_BOOTSTRAP_FRAMES = 2
_CORRECTED_P1_SD_MM = 1.5


def _names(mask: np.ndarray) -> str:
    """'P1 left, P3 right' for a (2, 5) bool mask of centres."""
    return ", ".join(f"{MARKER_NAMES[m]} {('left', 'right')[c]}" for c, m in np.argwhere(mask))


def _raised_in(exc: BaseException, filenames: str | tuple[str, ...]) -> bool:
    """Whether ``exc`` passed through code of a module file named ``filenames`` (e.g. ``rig_refine.py``, or a
    tuple of such names)."""
    return any(frame.f_code.co_filename.endswith(filenames) for frame, _ in traceback.walk_tb(exc.__traceback__))


def describe_offset_s(offset_s: float) -> str:
    """``t_right - t`` in words: ``"5.0 s after"``, ``"120 ms before"``."""
    side = "after" if offset_s >= 0 else "before"
    size = abs(offset_s)
    if size >= 1e4:                                    # a clock's wild value, not a skew: no 300 digits
        return f"{size:.3g} s {side}"
    return f"{size:.1f} s {side}" if size >= 1.0 else f"{size * 1e3:.0f} ms {side}"


def internal_error_reason(exc: BaseException) -> str:
    """A frame's reason for an exception caught while processing it: ``internal error: TYPE: message``
    (the message on one line, at most 300 characters)."""
    message = " ".join(str(exc).split()) or "(no message)"
    return f"internal error: {type(exc).__name__}: {message[:300]}"


@dataclass(frozen=True)
class TrackerConfig:
    """Tracker settings, each with its unit.

    Attributes
    ----------
    estimator : {'reproj', 'rigid', 'paper'}
        Pose estimator (see :mod:`headplod.tracking.geometry`); 'reproj' is the default
        because it was the most accurate in ``headplod bench track`` at a cost
        well inside the speed goal.
    detection : DetectionParams
    max_candidates : int
        Blobs per image considered for identification (best ranked first).
    epipolar_tol_px : float
        Largest epipolar error of an accepted marker correspondence, px.
    fit_tol_mm : float
        Largest RMS distance of the triangulated markers from the rigidly
        fitted model, mm.
    reproj_tol_px : float
        Largest reprojection residual of any marker after the pose fit, px.
    ambiguity_deg : float
        Two accepted identifications whose V differ by more than this make the
        frame ambiguous: no pose is reported.
    track : bool
        Reuse the previous frame's marker positions (search a region around
        them, carry the labels over).
    track_margin_px : float
        Margin of the tracking region around the previous markers, px.
    hidden_marker : bool
        Accept a pose with one marker hidden in one view.
    compensate_offset : bool
        When the right image is exposed at another time than the left one
        (times.csv's t_right), move the model by the head's velocity over that
        offset before the right camera sees it (reproj estimator).
    uncertainty : str
        Estimator of the covariance of V (:mod:`headplod.tracking.uncertainty`);
        the default was chosen by ``headplod bench uncertainty``.
    min_centroid_sigma_px : float
        Floor of the expected centroid noise, px.
    track_flux_change : float
        While tracking, a marker whose flux changes from the previous frame
        by more than this factor relative to the other markers of its view (a
        glint or a neighbour in its window) makes the frame re-detect and
        re-identify.
    weighted_fit : bool
        Weight each centre in the reprojection fit by its expected noise
        (from its flux, size and the image noise).
    outlier_sigma, outlier_floor_px : float
        A centre whose residual exceeds both ``outlier_sigma`` times its
        expected error (with a suspect's excess, see ``robust_suspect_sigma``)
        and ``outlier_floor_px`` is an outlier: the frame gets no pose.
    outlier_min_sigma_px : float
        Floor of the expected centroid noise in that test, px: the noise
        model leaves out shot noise, so a bright blob's σ is not trusted
        below this.
    robust_suspect_sigma : float
        A centre whose residual exceeds this many σ of its expected error
        (noise floored at ``outlier_min_sigma_px``) is suspect: the
        residuals are fitted by a pose and a rig change with a robust loss,
        and the centres still beyond it after that fit are down-weighted
        (their variance gets the excess), if the others agree.
    robust_cauchy_sigma : float
        Scale of that fit's Cauchy loss, in σ of each centre's expected noise.
    robust_iterations : int
        Most reweighting passes of that fit.
    robust_max_suspects : int
        Most down-weighted centres in a frame; six centres of four markers
        must remain.
    rig_refine : RigRefineConfig
        Online refinement of the rig from the tracked frames
        (:mod:`headplod.tracking.rig_refine`).
    rig_errors : RigErrorModel
        How far the real rig may be from ``rig.yaml`` before any refinement
        (1σ): with the calibration's own σ, the prior of the refinement.
    rig_far : RigErrorModel
        How far off a ``rig.yaml`` may be and still be corrected from the
        first frames (1σ): two consecutive frames that fail against a rig
        no frame has yet confirmed are fitted with the rig under this prior
        (:meth:`RigRefiner.bootstrap`); when that explains them down to the
        noise, the refinement starts from the rig they gave.
    extrapolate_velocity : bool
        The head's velocity for the right image's exposure offset is
        extrapolated at constant acceleration from three poses (else the
        last two poses' difference, half a frame old).
    rig_gate_sigma : float
        The consistency checks (epipolar, model fit, reprojection, outlier)
        allow this many σ of the image displacement the rig's remaining
        uncertainty can cause, on top of their image-noise tolerances.
    max_right_offset_periods : float
        A right image exposed more than this many frame periods (1/30 s
        until the frame rate is known), and more than 0.1 s, before or after
        the left one is not a stereo pair the head's motion can bridge: the
        frame gets no pose, and its reason names the skew (``t_right``
        seconds off is a clock problem, not a tracking one).
    max_uncompensated_offset_s : float
        A right image known to be exposed more than this, s, before or
        after the left one (``t_right``, or the refinement's estimate of the
        offset) gives no pose while the head's motion over the offset is
        not known (the frames just after an acquisition): the head may
        have turned by its speed times the offset (0.2° at 100°/s and 2 ms).
        The pose is kept for the next frames' velocity.
    max_v_sd_deg : float
        A pose whose V is uncertain by more than this (1σ, the largest axis
        of ``cov_deg2``), deg, is not reported: a stale rig before its
        refinement, or a motion that is poorly known, make it a guess.
        2°: a 5% board-scale rig before its first refinement update gives
        σ 1.6° (errors 0.4-0.7°), reported; the fuzz's stale-rig, offset
        and 'everything' classes (seeds 1-11) have no ok pose 5° off with
        2°, nor (seeds 1-6) with 2.5°.
    max_rig_correction_mm, max_rig_correction_deg : float
        Largest move of P1 (mm) and turn of the head (deg) by which a pose
        is corrected for the rig change its residuals show (the joint fit
        of the pose and the rig, linearized at the pose fitted with the rig
        as is); a larger one is not trusted to a linear step: no pose.
        2°: that 5% board-scale rig's first frames need 1.6-1.9° (V then
        0.7° off at most).
    max_time_gap_s, max_time_gap_periods : float
        A frame more than ``max_time_gap_s`` seconds, or more than
        ``max_time_gap_periods`` frame periods (once the frame rate is
        known), after the previous one, or before it, is a discontinuity (a
        seek, a stall, a clock reset): the head's motion is not extrapolated
        across it; the tracker forgets its motion state and acquires afresh,
        and the result's ``notes`` say so.
    min_velocity_base_s : float
        Shortest time between the two poses of a velocity, s, beside half
        the usual frame spacing (:class:`~headplod.tracking.motion.PoseHistory`):
        poses closer than that (repeated or jittered times) make a velocity
        of their noise, which the exposure offset's compensation multiplies.
    max_head_rate_dps, max_head_speed_mm_s : float
        Fastest turn (deg/s) and P1 speed (mm/s) of a head. Two poses whose
        times make them faster are not one motion (the times are a clock's
        glitch, the frames out of order): no velocity is taken across them,
        the motion state starts afresh, and the rig's refinement does not
        learn from that frame; the result's ``notes`` say so.
    readout_s : float or None
        The cameras' rolling-shutter readout, s: the time from the exposure
        of an image's first row to its last (0: a global shutter). None:
        the one a rig saved by ``--save-rig`` learnt, else not known: the
        refinement starts from 0 with σ as long as a webcam's readout can
        be (the frame period × 0.92, a webcam's active rows over its total
        rows; :func:`~headplod.tracking.rig_refine.readout_prior`) and
        estimates it from the head's image motion. A value given here is
        trusted to 5% or 0.5 ms (0.2 ms for a global shutter).
    compensate_rolling_shutter : bool
        Take each marker centre back to the image's time t through the
        head's velocity (reproj estimator): row r of an image H rows high
        is exposed at t + (r − (H − 1)/2) × readout / (H − 1) (t is the
        middle row's time, the dataset contract's mid-exposure).
    min_readout_s : float
        A refined readout below this, s, is not compensated (:meth:`Tracker.readout_s`).
    prior_head_rate_dps, prior_head_speed_mm_s : float
        A head's motion (1σ per axis: deg/s, mm/s of P1) when no recent
        poses tell it: what the first frame after an acquisition's pose may
        be off by, over a rolling shutter's row delays.
    offset_passes : int
        Most Gauss-Newton steps of a frame whose right image's motion is
        taken from its own pose (an exposure offset), each with the motion
        of the pose the step before found: the fit of the motion consistent
        with the pose it moves.
    """

    estimator: str = "reproj"
    detection: DetectionParams = field(default_factory=DetectionParams)
    max_candidates: int = 8
    epipolar_tol_px: float = 2.5
    fit_tol_mm: float = 2.0
    reproj_tol_px: float = 2.0
    ambiguity_deg: float = 3.0
    track: bool = True
    track_margin_px: float = 10.0
    hidden_marker: bool = True
    compensate_offset: bool = True
    uncertainty: str = DEFAULT_COVARIANCE
    min_centroid_sigma_px: float = 0.01
    track_flux_change: float = 1.25
    weighted_fit: bool = True
    outlier_sigma: float = 10.0
    outlier_floor_px: float = 0.3
    outlier_min_sigma_px: float = 0.03
    robust_suspect_sigma: float = 3.5
    robust_cauchy_sigma: float = 3.0
    robust_iterations: int = 10
    robust_max_suspects: int = 4
    rig_refine: RigRefineConfig = field(default_factory=RigRefineConfig)
    rig_errors: RigErrorModel = field(default_factory=RigErrorModel)
    rig_far: RigErrorModel = field(default_factory=lambda: RigErrorModel(turn_deg=5.0, shift_fraction=0.15,
                                                                         focal_fraction=0.05))
    rig_gate_sigma: float = 3.0
    max_right_offset_periods: float = 3.0
    extrapolate_velocity: bool = True
    max_uncompensated_offset_s: float = 0.002
    max_v_sd_deg: float = 2.0
    max_rig_correction_mm: float = 40.0
    max_rig_correction_deg: float = 2.0
    max_time_gap_s: float = 1.0
    max_time_gap_periods: float = 10.0
    min_velocity_base_s: float = 0.004
    max_head_rate_dps: float = 1000.0
    max_head_speed_mm_s: float = 4000.0
    offset_passes: int = 6
    readout_s: float | None = None
    compensate_rolling_shutter: bool = True
    min_readout_s: float = 0.0005
    prior_head_rate_dps: float = 50.0
    prior_head_speed_mm_s: float = 150.0

    def __post_init__(self):
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator must be one of {ESTIMATORS}, got {self.estimator!r}")
        if self.readout_s is not None and not (math.isfinite(self.readout_s) and 0.0 <= self.readout_s < 1.0):
            raise ValueError(f"readout_s must be a time in [0, 1) s, got {self.readout_s!r}")


@dataclass
class TrackResult:
    """The outcome of one stereo frame.

    Attributes
    ----------
    ok : bool
        A verified pose is present.
    reason : str or None
        Why there is no pose, for a person to act on.
    position_mm : (3,) or None
        P1 in the world (left camera) frame, mm.
    axes : (3, 3) or None
        Rows Ξ, Ψ, V in the world frame (conventions.md).
    R_world_G : (3, 3) or None
        Rotation from the glasses frame to the world frame.
    centers_px : (2, 5, 2)
        Marker centres per image (0 left, 1 right) and marker; NaN if hidden.
    residuals_px : (2, 5)
        Reprojection residual per image and marker after the fit; NaN if hidden.
    epipolar_px : (5,)
        Epipolar error of each marker correspondence, px.
    fit_rms_mm : float
        RMS distance of the triangulated markers from the fitted model, mm.
    mode : {'track', 'acquire'}
        Whether the previous frame's markers were reused.
    timings_s : dict[str, float]
        Seconds per stage.
    cov_deg2 : (2, 2) or None
        Covariance of (φ, θ) of V, deg² (conventions.md).
    notes : list of str
        What happened to the tracker's state at this frame, for a person
        (e.g. a time discontinuity that reset the motion); in the record's
        ``notes``.
    """

    ok: bool
    reason: str | None = None
    position_mm: np.ndarray | None = None
    axes: np.ndarray | None = None
    R_world_G: np.ndarray | None = None
    centers_px: np.ndarray = field(default_factory=lambda: np.full((2, 5, 2), np.nan))
    residuals_px: np.ndarray = field(default_factory=lambda: np.full((2, 5), np.nan))
    epipolar_px: np.ndarray = field(default_factory=lambda: np.full(5, np.nan))
    fit_rms_mm: float = float("nan")
    mode: str = "acquire"
    timings_s: dict = field(default_factory=dict)
    blobs: tuple = (None, None)
    marker_blob: np.ndarray | None = None
    cov_deg2: np.ndarray | None = None
    cov_input: CovarianceInput | None = None
    rig: dict | None = None
    rig_message: str | None = None
    notes: list = field(default_factory=list)

    def record_extras(self) -> dict:
        """JSON-ready diagnostics for a pose record (the contract allows more keys)."""
        out = {"mode": self.mode, "timings_ms": {k: round(v * 1e3, 4) for k, v in self.timings_s.items()}}
        if self.rig is not None:
            out["rig"] = self.rig
        if self.rig_message:
            out["rig_message"] = self.rig_message
        if self.notes:
            out["notes"] = list(self.notes)
        if self.ok:
            out["residuals_px"] = [[None if np.isnan(r) else round(float(r), 4) for r in row]
                                   for row in self.residuals_px]
        return out


@dataclass
class _Match:
    """Marker centres of one identification: (2, 5, 2) px and visibility (2, 5)."""

    centers: np.ndarray
    visible: np.ndarray
    blob_index: np.ndarray      # (2, 5) blob index per image, -1 if hidden
    epipolar: np.ndarray        # (5,)
    points: np.ndarray          # (5, 3) triangulated, NaN if hidden in a view
    R: np.ndarray
    t: np.ndarray
    fit_rms: float
    sigma_px: np.ndarray = None     # (2, 5) expected centroid noise, px
    flux: np.ndarray = None         # (2, 5) blob flux, DN·px
    size: np.ndarray = None         # (2, 5) Gaussian σ of each blob as re-measured while tracking, px
    shot_var: np.ndarray = None     # (2, 5, 2) centroid variance of x, y per unit shot-noise factor, px²/DN
    excess_px: np.ndarray = None    # (2, 5) error of a suspect centre beyond its noise (a fused glint), px
    # A rolling shutter exposes each row at its own time: each centre's
    # displacement by the head's motion from the image's time t to its row's
    # time (2, 5, 2) px, which the fit takes off the measured centre, and
    # that displacement's 1σ from the velocity's uncertainty (2, 5) px, per
    # coordinate. None: not compensated (a global shutter, no motion known).
    shutter_shift_px: np.ndarray = None
    shutter_sd_px: np.ndarray = None
    shutter_delay_s: np.ndarray = None   # (2, 5) each centre's row time after t, s
    shutter_cov: np.ndarray = None       # (6, 6) covariance of the head's velocity over those delays


@dataclass
class _Lock:
    """What tracking re-measures: the markers of the last accepted frame (the tracker is in its *track*
    state while it has one, and *acquires* — detects and identifies from scratch — while it has none)."""

    centers: np.ndarray                 # (2, 5, 2) last accepted centres, px
    previous: np.ndarray | None         # (2, 5, 2) the ones before, for a constant-velocity prediction
    size: np.ndarray                    # (2, 5) Gaussian σ of each marker's blob, px
    flux: np.ndarray | None             # (2, 5) fluxes, DN·px; None after a full detection (measured otherwise)

    def predicted(self) -> np.ndarray:
        """Where the markers should be in this frame (2, 5, 2) px: at constant image velocity."""
        return self.centers if self.previous is None else 2 * self.centers - self.previous


@dataclass
class _Fit:
    """A frame's pose as fitted and checked: what the fit stage (:meth:`Tracker._fit`) hands on.

    ``R``, ``p1``: the pose to report (corrected for the rig error its
    residuals show, when that applies); ``fitted``: (R, p1) as fitted with
    the rig in use, which the motion history and the refinement keep;
    ``residuals`` (2, 5) px, ``vectors`` (2, 5, 2) px, ``JtJ`` (6, 6) of the
    fit; ``velocity`` the head's (ω, v) for the rig's terms, or None;
    ``rig_rows`` (2, 5, 2, k), ``rig_sd`` (2, 5) px, ``pose_rows`` (2, 5, 2,
    6), ``rig_cov`` (k, k): the rig's share, when computed; ``reason``: why
    no pose at all; ``withheld``: why a pose that is tracked from and refines
    the rig is not reported; ``disagrees``: it fits only the rig's wider,
    unrefined uncertainty (a bump?).
    """

    R: np.ndarray
    p1: np.ndarray
    fitted: tuple
    residuals: np.ndarray
    vectors: np.ndarray
    JtJ: np.ndarray
    velocity: tuple | None
    rig_rows: np.ndarray | None
    rig_sd: np.ndarray | None
    pose_rows: np.ndarray | None
    rig_cov: np.ndarray | None
    reason: str | None = None
    withheld: str | None = None
    disagrees: bool = False


class Tracker:
    """Head tracker for one stereo rig and marker model.

    Parameters
    ----------
    rig : headplod.io.Rig
    model : headplod.io.MarkerModel
    config : TrackerConfig
    """

    def __init__(self, rig, model, config: TrackerConfig = TrackerConfig(), calibration_std: dict | None = None):
        self.calibrated_rig = rig
        self.model = model
        self.config = config
        self.model_mm = np.asarray(model.points_mm, dtype=np.float64)
        self.rule = ModelRule.from_model(self.model_mm)
        self.normal_signs = geo.normal_signs(self.model_mm)
        self.axes_G = geo.model_axes(self.model_mm)
        self._calibration_std = calibration_std
        self.refiner = None           # made at the first frame, when it is known whether t_right is given
        self._frame_periods = []      # recent frame periods, s, for the right time's plausibility (kept by reset)
        self._last_t = None
        self.time_jumps = 0           # discontinuities of the frame time (back, or far ahead): motion reset
        self.first_time_jump: str | None = None
        # This frame's time is no clock's (a repeat, a glitch, jitter): not for
        # the refinement; a repeat or a step of a fraction of a period: not for
        # the motion history either.
        self._glitch = self._time_glitch = False
        self._motion_unknown = False   # this frame's time does not fit the motion (set by _remember)
        self._motion_note = None      # what the motion model made of this frame's time, for the result's notes
        self._times_suspect = False   # the last velocity checked was not a head's, none since was
        self._withheld = False
        self._last_fit = None         # (match, R, p1) of the last frame fitted but not reported, for _bootstrap_rig
        self._previous_images = None  # (left, right) of the last frame, to recognize a repeated buffer
        self._rates = None            # (t, R, p1, rig version, rates_to) of the last pose _fit checked
        self._bootstrap_note = None
        self._bootstrap_fits = []      # consecutive frames that failed against the rig, for _bootstrap_rig
        self._readout_prior_set = False
        self._declared_offsets = []   # recent t_right - t of the frames fed to the rig's refinement, s
        # Exceptions isolated by process(): counted, never silent (see process).
        self.internal_errors = 0
        self.first_internal_error: str | None = None
        self.first_internal_traceback: str | None = None
        self._apply_rig(rig)
        self.uncertainty = make_covariance_estimator(config.uncertainty, rig, self.model_mm, self.axes_G)
        self.reset()

    def _apply_rig(self, rig) -> None:
        """Use a (refined) rig from now on: epipolar geometry, cameras, the paper estimator's rig."""
        self.rig = rig
        self.E = geo.essential_matrix(rig.R, rig.T)
        self.focal = (float(np.sqrt(rig.K1[0, 0] * rig.K1[1, 1])), float(np.sqrt(rig.K2[0, 0] * rig.K2[1, 1])))
        self.cameras_mid_mm = 0.5 * (-rig.R.T @ np.reshape(rig.T, 3))
        self._cameras = geo.StereoCameras(rig)
        if hasattr(self, "uncertainty") and hasattr(self.uncertainty, "rig"):
            self.uncertainty.rig = rig
        self._rig_gate()

    def _start_refiner(self, t, t_right) -> None:
        declared = t_right is not None
        self.refiner = RigRefiner(self.calibrated_rig, self.model_mm, self.config.rig_refine,
                                  self.config.rig_errors, offset_declared=declared,
                                  calibration_std=self._calibration_std)
        self._rig_gate()

    def _rig_gate(self) -> None:
        """Tolerances of the consistency checks: image noise plus what the rig's uncertainty can displace.

        σ_rig (px): the image shift a 1σ error of the rig's turn, shift and
        focal scale causes at a typical distance (60 cm) and image radius
        (300 px). The exposure offset's share needs the head's image speed,
        unknown when acquiring; it is left to the reprojection checks.
        """
        c = self.config
        P = self._rig_cov()
        if P is None:
            sigma_px = 0.0
        else:
            f = self.focal[1]
            turn = float(np.sqrt(np.linalg.eigvalsh(P[:3, :3]).max()))
            shift = float(np.sqrt(np.linalg.eigvalsh(P[3:6, 3:6]).max()))
            sigma_px = float(np.sqrt((f * turn) ** 2 + (f * shift / 600.0) ** 2 + (300.0 * np.sqrt(P[6, 6])) ** 2))
        self.rig_sigma_px = sigma_px
        k = c.rig_gate_sigma * sigma_px
        self.epipolar_tol_px = float(np.hypot(c.epipolar_tol_px, k))
        # A rig error changes the triangulated shape by about a third of a
        # millimetre per pixel of disparity error at 60 cm.
        self.fit_tol_mm = float(np.hypot(c.fit_tol_mm, 0.35 * k))

    def _rig_cov(self, wide: bool = False):
        """Covariance (9, 9) of the rig's error state now (None before the first frame)."""
        if self.refiner is None:
            return None
        P = self.refiner.cov()
        return P + self.refiner.prior if wide else P

    def reset(self) -> None:
        """Forget the previous frames (e.g. after a seek)."""
        if hasattr(self, "uncertainty"):
            self.uncertainty.reset()
        self._prev_background = [None, None]
        self._prev_threshold = [None, None]
        self._disagreements = 0
        self._reset_motion()

    def _reset_motion(self) -> None:
        """Forget the head's motion: the poses, the last markers and the right images they came with.

        What a time discontinuity invalidates; the image statistics (noise,
        background) and the rig's refinement stand.
        """
        self._lock: _Lock | None = None   # the markers to re-measure (track), or None (acquire)
        c = self.config
        self._motion = PoseHistory(c.extrapolate_velocity, c.min_velocity_base_s,
                                   max_rate_dps=c.max_head_rate_dps, max_speed_mm_s=c.max_head_speed_mm_s)
        self._prev_pose = None
        self._uncompensated = False
        self._compensated = False      # the last fit moved the right view's model by the head's motion
        self._last_right = None        # (image, t, t_right) of the previous frame's right camera
        self._declared_right = None    # the right image's time as given (times.csv, the driver), s
        self._periods = []             # recent frame periods, s

    # ------------------------------------------------------------------ public
    def state(self) -> tuple[str, str]:
        """(markers, rig): 'track' or 'acquire'; 'rig.yaml', 'refining' or 'refined' (module docstring)."""
        markers = "track" if self._lock is not None and self.config.track else "acquire"
        refiner = self.refiner
        if refiner is None or not self.config.rig_refine.enabled or (not refiner.updates
                                                                       and refiner.bootstrapped_at is None):
            return markers, "rig.yaml"
        return markers, "refined" if refiner.converged() else "refining"

    def process(self, left: np.ndarray, right: np.ndarray, t: float | None = None,
                t_right: float | None = None) -> TrackResult:
        """Track one stereo pair.

        Parameters
        ----------
        left, right : (H, W) uint8
            IR images of the left and right camera, the rig's size.
        t, t_right : float, optional
            Image times in seconds (t_right only if it differs): mid-exposure for
            synthetic data, a camera's capture time live (not mid-exposure).

        Returns
        -------
        TrackResult
            Always, with ``timings_s["total"]``. An exception while
            processing the frame (a singular system, an OpenCV assertion,
            memory) is isolated to it: the frame gets ``ok`` False with the
            reason ``"internal error: <type>: <message>"``, the tracker's
            state is reset (:meth:`reset`; the rig's refinement loses its
            pending frames, or restarts if its estimate is damaged), the
            error is counted (:attr:`internal_errors`, the first one's
            reason and traceback in :attr:`first_internal_error` and
            :attr:`first_internal_traceback`) and the next frame is
            processed as usual. ``KeyboardInterrupt`` and ``SystemExit``
            are not caught.
        """
        start = time.perf_counter()
        try:
            result = self._process(left, right, t, t_right, start)
        except Exception as exc:        # noqa: BLE001 -- isolated to this frame, counted, reported
            return self._internal_error(exc, start)
        result.timings_s.setdefault("total", time.perf_counter() - start)
        return result

    def _process(self, left, right, t, t_right, start) -> TrackResult:
        """:meth:`process` without the isolation of exceptions."""
        timings = {}
        self._motion_note = None
        problem = self._check_images(left, right)
        if problem:
            return TrackResult(False, problem, timings_s={"total": time.perf_counter() - start})
        repeated = self._repeated_images(left, right)
        if repeated:
            return TrackResult(False, repeated, timings_s={"total": time.perf_counter() - start})
        notes = self._check_time(t)
        skew = self._implausible_offset(t, t_right)
        if skew:
            self._lock = None
            return TrackResult(False, skew, timings_s={"total": time.perf_counter() - start}, notes=notes)
        if self.refiner is None:
            self._start_refiner(t, t_right)
        self._set_readout_prior()
        images, t_right = self._pair(left, right, t, t_right)
        tracking = self.config.track and self._lock is not None
        result = self._attempt(images, t, t_right, timings, start, tracking)
        if tracking and not result.ok and result.mode == "track" and not self._withheld:
            # The re-measured markers did not verify: detect and identify afresh.
            result = self._attempt(images, t, t_right, timings, start, False)
        if self._bootstrap_rig(t):
            # rig.yaml is far from the rig: the frame fitted jointly with the
            # rig gave one that explains it. Tracked afresh with that rig,
            # whose uncertainty the pose's covariance carries.
            result = self._attempt(images, t, t_right, timings, start, False)
            result.notes = result.notes + [self._bootstrap_note]
        if self._motion_note:
            notes = notes + [self._motion_note]
        if notes:
            result.notes = notes + result.notes
        return result

    def _repeated_images(self, left: np.ndarray, right: np.ndarray) -> str | None:
        """Why a frame is refused when a camera delivered the very image it delivered last (a driver or
        a capture loop handing the same buffer out twice): that image was exposed a frame earlier than
        its time says, so no pose may be made from it. None for new images. (Two exposures are never
        identical to the bit: sensor noise, and MJPEG's coding of it, differ.)"""
        previous, self._previous_images = self._previous_images, (left, right)
        if previous is None:
            return None
        # One row first: two exposures differ in noise nearly everywhere, so it
        # tells new images at once (the whole images are compared only when it matches).
        # An image without any variation (a covered lens, black or clipped) repeats
        # without being a repeated buffer: it tells nothing either way.
        def repeats(a, b):
            if a.shape != b.shape:
                return False
            row = a[a.shape[0] // 2]          # one contiguous row first: cheaper than a scattered grid
            return (np.array_equal(row, b[b.shape[0] // 2]) and int(row.max()) != int(row.min())
                    and np.array_equal(a, b))

        same = [repeats(a, b) for a, b in zip(previous, (left, right))]
        if not any(same):
            return None
        which = "both cameras" if all(same) else ("the left camera" if same[0] else "the right camera")
        return (f"{which} delivered the same image as in the last frame (a repeated buffer, not a new exposure): "
                "no pose from it")

    def _given_readout_s(self) -> float | None:
        """The readout known before any frame, s: ``readout_s`` (``--readout-ms``), else the one a rig saved
        by ``--save-rig`` learnt (``refined_readout_ms``: the same cameras read out as they did); None."""
        if self.config.readout_s is not None:
            return float(self.config.readout_s)
        saved = self.calibrated_rig.extra.get("refined_readout_ms")
        try:
            value = float(np.ravel(saved)[0]) * 1e-3
        except (TypeError, ValueError, IndexError):
            return None
        return max(value, 0.0) if math.isfinite(value) and value < 1.0 else None

    def _set_readout_prior(self) -> None:
        """Give the rig's refinement the rolling shutter's prior once it can be had: the user's readout
        (``readout_s``) at once, else from the frame period once two periods are known."""
        refiner = self.refiner
        if refiner is None or self._readout_prior_set:
            return
        period = float(np.median(self._frame_periods)) if len(self._frame_periods) >= 2 else None
        given = self._given_readout_s()
        if given is None and period is None:
            return
        if refiner.updates:
            self._readout_prior_set = True     # learnt already: the prior is the refinement's business
            return
        mean, sd = readout_prior(period, given)
        if given is None:
            # Not given: compensate nothing until the motion shows a readout,
            # σ the longest a webcam's can be (wrongly compensating a global
            # shutter by 30 ms costs as much as not compensating a rolling one).
            mean, sd = 0.0, math.hypot(mean, sd)
        refiner.set_readout_prior(mean, sd)
        self._readout_prior_set = True

    def _bootstrap_rig(self, t) -> bool:
        """When consecutive frames fail against a rig.yaml no frame has yet confirmed (before the
        refinement's first update), fit their poses and the rig together under the far-off prior
        ``rig_far`` (:meth:`RigRefiner.bootstrap`): a rig.yaml far off (the right camera turned 3°, a
        board 10% off) then gives poses from the second frame on instead of none, or wrong ones. Two
        frames, not one: a stray blob taken for a marker in one frame does not agree with the next
        one's rig. True when the refinement now starts from the rig they gave; the note says what it
        found."""
        refiner, last = self.refiner, self._last_fit
        self._last_fit = None
        if (last is None or refiner is None or refiner.updates or refiner.bootstrapped_at is not None
                or not self.config.rig_refine.enabled or self.config.estimator != "reproj" or t is None):
            self._bootstrap_fits = []
            return False
        match, R, p1 = last
        if not match.visible.all() or self._uncompensated or (
                self._declared_right is not None and abs(self._declared_right - t) > self.config.max_uncompensated_offset_s
                and not self._compensated):
            # A hidden marker leaves too little to tell the rig from the pose;
            # a right view that saw the head at another time, by a motion not
            # known yet, would be taken for the rig.
            self._bootstrap_fits = []
            return False
        self._bootstrap_fits = (self._bootstrap_fits + [(t, match.centers, match.visible, self._sigma(match), R, p1)])
        self._bootstrap_fits = self._bootstrap_fits[-_BOOTSTRAP_FRAMES:]
        if len(self._bootstrap_fits) < _BOOTSTRAP_FRAMES:
            return False
        if not refiner.bootstrap(self._bootstrap_fits, self.config.rig_far):
            return False
        self._bootstrap_fits = []
        self._apply_rig(refiner.state.rig())
        self._bootstrap_note = ("rig.yaml is far from the rig these images show: the rig was estimated from the "
                                f"markers of this frame and the last ({refiner.describe()}); the pose carries its "
                                "uncertainty")
        return True

    def _internal_error(self, exc: Exception, start: float) -> TrackResult:
        """The result of a frame whose processing raised ``exc``; the state it may have damaged is reset."""
        reason = internal_error_reason(exc)
        self.internal_errors += 1
        if self.first_internal_error is None:
            self.first_internal_error = reason
            self.first_internal_traceback = "".join(traceback.format_exception(exc))
        try:
            self.reset()
            if self.refiner is not None and _raised_in(exc, _REFINER_FILES):
                self._restart_refiner()
        except Exception as again:      # noqa: BLE001 -- a reset that fails too: start over entirely
            reason += f" (and resetting failed: {type(again).__name__}: {again})"
            self.refiner = None
            self._apply_rig(self.calibrated_rig)
            self.reset()
        return TrackResult(False, reason, timings_s={"total": time.perf_counter() - start})

    def _restart_refiner(self) -> None:
        """After an exception inside the rig's refinement: drop the frames it was collecting, and keep
        its estimate only if it is intact (finite, a positive definite covariance); else start it over
        from rig.yaml."""
        refiner = self.refiner
        refiner.drop_pending()
        intact = False
        try:
            P = refiner.cov()
            state = (refiner.state.R, refiner.state.T, refiner.estimate.R, refiner.estimate.T)
            intact = (all(np.isfinite(a).all() for a in state) and np.isfinite(P).all()
                      and np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0)
        except Exception:              # noqa: BLE001 -- a state that cannot even be read is not intact
            intact = False
        if not intact:
            refiner.reset()
            self._apply_rig(refiner.state.rig())
        self._rig_gate()

    def _frame_period(self) -> float | None:
        """The usual time between frames, s (None until a step is known): the 75th percentile of the
        last 16 steps, which neither timestamp glitches (steps of a ms) nor a few dropped frames (steps of
        two periods) move far, while up to half of either would move a median."""
        if not self._frame_periods:
            return None
        steps = sorted(self._frame_periods)
        return steps[(3 * (len(steps) - 1)) // 4]

    def _check_time(self, t) -> list:
        """Notes on this frame's time against the previous frame's; a discontinuity resets the motion.

        Back in time, or forward by more than ``max_time_gap_s`` or
        ``max_time_gap_periods`` frame periods: the poses before it are not
        this motion's past, and no velocity bridges the gap, so the motion
        state is forgotten (:meth:`_reset_motion`) and the markers are
        acquired afresh. A time equal to the previous one is noted (the
        motion model gets no velocity from it). Keeps the recent frame
        periods (s) for this and the right time's plausibility.
        """
        self._glitch = self._time_glitch = False
        if t is None:
            return []
        last, self._last_t = self._last_t, t
        if last is None:
            return []
        step = float(t) - float(last)
        period = self._frame_period()
        c = self.config
        known = len(self._frame_periods) >= 4        # a period from fewer steps may be a glitch's
        gap = min(c.max_time_gap_s, c.max_time_gap_periods * period) if known else c.max_time_gap_s
        if 0 < step <= c.max_time_gap_s:
            # Every step within the absolute bound counts towards the period,
            # so that a period first learnt from glitches recovers.
            self._frame_periods = (self._frame_periods + [step])[-16:]
        if 0 < step <= gap:
            # A step under a third of the usual period is a repeat or a late
            # timestamp more likely than a faster camera (until the period is
            # known, a third of the longest step so far). One a tenth of a
            # period off the frame clock (jitter) is a time the rig's
            # refinement must not learn velocities and offsets from.
            usual = period if known else max(self._frame_periods, default=step)
            self._time_glitch = step < 0.3 * usual
            self._glitch = self._time_glitch or (known and abs(step - period * round(step / period)) > 0.1 * period)
            return []
        if step == 0:
            self._glitch = self._time_glitch = True
            return [f"time {t:.6f} s repeats the previous frame's: no motion measured over it"]
        self._reset_motion()
        if step < 0:
            note = (f"time went back {describe_offset_s(-step).replace(' after', '')} (t={t:.6g} s after "
                    f"{last:.6g} s): motion state reset, markers acquired afresh")
        else:
            note = (f"time jumped {describe_offset_s(step).replace(' after', '')} ahead (t={t:.6g} s after "
                    f"{last:.6g} s, more than {gap * 1e3:.0f} ms): motion state reset, markers acquired afresh")
        self.time_jumps += 1
        self.first_time_jump = self.first_time_jump or note
        return [note]

    def _attempt(self, images, t, t_right, timings, start, tracking) -> TrackResult:
        """One pass: measure (track or acquire), fit and check, the covariance of V, the rig's refinement."""
        self._withheld = False         # a pose verified, kept and tracked from, but not reported
        match, mode, reason, blobs = self._measure(images, tracking, timings)
        if match is None:
            self._lock = None
            timings["total"] = time.perf_counter() - start
            return TrackResult(False, reason, mode=mode, timings_s=timings, blobs=blobs)
        fit = self._fit(match, t, t_right, timings)
        if (fit.reason or fit.withheld or "").startswith(_RIG_FAILURES):
            self._last_fit = (match, *fit.fitted)          # for _bootstrap_rig
        if fit.reason is not None:
            self._lock = None
            timings["total"] = time.perf_counter() - start
            return TrackResult(False, fit.reason, centers_px=match.centers, residuals_px=fit.residuals, mode=mode,
                               timings_s=timings, blobs=blobs, marker_blob=match.blob_index,
                               rig=self._rig_status(), rig_message=self._rig_message())
        motion_gain, motion_cov = self._motion_terms(t, t_right, fit.fitted)
        self._remember(match, t, *fit.fitted, blobs, mode, fit.JtJ)
        timings["mean_pose"] = time.perf_counter() - start

        # The uncertainty of V is its own stage (the mean pose is done).
        t_cov = time.perf_counter()
        cov_input = self._covariance_input(images, match, fit, t, t_right, motion_gain, motion_cov)
        timings["covariance_input"] = time.perf_counter() - t_cov
        cov = self.uncertainty(cov_input)
        timings["covariance"] = time.perf_counter() - t_cov
        if not np.isfinite(cov).all() or np.linalg.det(cov) <= 0:
            timings["total"] = time.perf_counter() - start
            return TrackResult(False, f"no covariance of V from the {self.uncertainty.name} estimator "
                                      "(too few marker pixels?)", mode=mode, timings_s=timings, blobs=blobs)
        withheld = fit.withheld
        sd_deg = math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
        if withheld is None and sd_deg > self.config.max_v_sd_deg:
            # Still tracked from and refining the rig: that is what narrows it.
            withheld = (f"V uncertain to ±{sd_deg:.1f}° (1σ), more than {self.config.max_v_sd_deg:g}°: "
                        "the rig or the motion leaves too much unknown; pose not reported")

        # The rig's refinement is its own stage, fed every accepted frame.
        t_ref = time.perf_counter()
        self._refine(match, t, cov_input=cov_input, R=fit.fitted[0], p1=fit.fitted[1], disagrees=fit.disagrees)
        timings["refine_rig"] = time.perf_counter() - t_ref
        timings["total"] = time.perf_counter() - start
        if withheld is not None:
            self._withheld = True
            return TrackResult(False, withheld, centers_px=match.centers, residuals_px=fit.residuals, mode=mode,
                               timings_s=timings, blobs=blobs, marker_blob=match.blob_index,
                               rig=self._rig_status(), rig_message=self._rig_message(fit.disagrees))
        axes = self.axes_G @ fit.R.T
        return TrackResult(True, None, fit.p1, axes, fit.R, match.centers, fit.residuals, match.epipolar,
                           match.fit_rms, mode, timings, blobs, match.blob_index, cov_deg2=cov, cov_input=cov_input,
                           rig=self._rig_status(), rig_message=self._rig_message(fit.disagrees))

    def _measure(self, images, tracking: bool, timings: dict):
        """The markers of this frame: (match or None, mode, reason for none, blobs).

        *Track* (``tracking``: a lock on the last frame's markers): re-measure
        them in small windows; *acquire* (no lock, or the re-measure failed):
        detect every blob and identify the five markers.
        """
        match, mode, reason, blobs = None, "acquire", None, (None, None)
        if tracking:
            t_det = time.perf_counter()
            match = self._track_fast(images)
            timings["detect"] = time.perf_counter() - t_det
            mode = "track"
        if match is None:
            t_det = time.perf_counter()
            blobs = tuple(self._detect_full(img, i) for i, img in enumerate(images))
            timings["detect"] = timings.get("detect", 0.0) + time.perf_counter() - t_det
            t_id = time.perf_counter()
            match, reason = self._identify(blobs)
            timings["identify"] = timings.get("identify", 0.0) + time.perf_counter() - t_id
            mode = "acquire"
        return match, mode, reason, blobs

    def _fit(self, match: _Match, t, t_right, timings: dict) -> _Fit:
        """Fit the pose to the markers and check it against the images and the rig (:class:`_Fit`)."""
        t_pose = time.perf_counter()
        self._uncompensated = (t_right is not None and t is not None and t_right != t
                               and self._right_motion(t, t_right) is None
                               and (not self._motion or t - self._motion.last_time() > 0.2))
        R, p1, residuals, JtJ, vectors = self._estimate(match, t, t_right)
        velocity = self._motion.velocity()
        if velocity is not None and t is not None:
            # The velocity of the last poses is this frame's motion only if
            # this pose continues it: one a head cannot reach from them (the
            # check _remember makes afterwards) says the motion here is not
            # known. The rig's exposure offset, not yet learnt, times that
            # velocity would otherwise widen the checks by pixels (25 ms at
            # 1000°/s) and let a glint or an occlusion through.
            rates = self._motion.rates_to(t, R, p1, self._rig_version())
            self._rates = (t, R, p1, self._rig_version(), rates)       # _remember's check, if the pose stays
            if rates is not None and not rates[2]:
                velocity = None
        rig_rows = rig_sd = pose_rows = None
        # The rig's share only widens the checks: a frame that passes them on
        # image noise alone (the usual case) needs no rig terms before its covariance.
        outlier = self._outlier(residuals, match)
        suspect = self._suspect(residuals, match)
        plain = self._verify(R, p1, residuals, None, match)          # the image noise alone
        if suspect or outlier is not None or plain is not None:
            rig_rows, rig_sd, pose_rows = self._rig_terms(R, p1, t, t_right, velocity, self._rig_cov(), match)
            outlier = self._outlier(residuals, match, rig_sd)
        if suspect and self.config.estimator == "reproj":
            # Centres that disagree with the others beyond what the rig's
            # uncertainty explains (glints fused with markers, partial
            # occlusions) are down-weighted rather than the frame refused,
            # if the others agree.
            suspects, excess = self._suspects(vectors, match, pose_rows, rig_rows, self._rig_cov())
            if suspects is not None:
                match.excess_px = excess        # their variance gets the excess
                R, p1, residuals, JtJ, vectors = self._estimate(match, t, t_right)
                rig_rows, rig_sd, pose_rows = self._rig_terms(R, p1, t, t_right, velocity, self._rig_cov(), match)
                outlier = self._outlier(residuals, match, rig_sd)
        timings["pose"] = time.perf_counter() - t_pose

        t_ver = time.perf_counter()
        # (With no rig terms and no outlier the checks are the plain ones, done above.)
        reason = plain if (rig_sd is None and outlier is None) else self._verify(R, p1, residuals, outlier, match, rig_sd)
        rig_cov = self._rig_cov()
        disagrees = False
        if reason is not None and self.refiner is not None:
            # Not consistent with the rig as refined: is it with the rig as
            # uncertain as before any refinement (the rig changed: a bump)?
            wide = self._rig_cov(wide=True)
            wide_rows, wide_sd, _ = self._rig_terms(R, p1, t, t_right, velocity, wide, match)
            if (self._verify(R, p1, residuals, self._outlier(residuals, match, wide_sd), match, wide_sd) is None
                    and self._rig_explains(pose_rows, vectors, wide_rows, wide, match)):
                reason, rig_cov, disagrees = None, wide, True
        withheld = None
        fitted = (R, p1)               # the pose fitted with the rig in use, before any correction
        if (reason is None and rig_rows is not None and rig_cov is not None and self.config.estimator == "reproj"
                and self._verify(R, p1, residuals, self._outlier(residuals, match), match) is not None):
            # The checks passed only with the rig's uncertainty: report the
            # pose that uncertainty implies, not the one fitted with the rig
            # as is, or none. A withheld pose is still the markers' and the
            # rig's evidence: it is tracked from and refines the rig (which
            # is what brings the next poses back), it is only not reported.
            # The motion history and the refinement keep the pose fitted with
            # the rig in use, as for every other frame: a correction that
            # comes and goes would be motion to the one and, to the other,
            # a pose of another rig than the one it linearizes at.
            # (The rigid and paper estimators' poses are not reprojection
            # fits, which the correction starts from: they stay as they are.)
            R, p1, reason, withheld = self._rig_consistent(R, p1, vectors, pose_rows, rig_rows, rig_cov, match)
        if reason is None and withheld is None:
            withheld = self._offset_unbridged(t, t_right)
        timings["verify"] = time.perf_counter() - t_ver
        return _Fit(R, p1, fitted, residuals, vectors, JtJ, velocity, rig_rows, rig_sd, pose_rows, rig_cov,
                    reason, withheld, disagrees)

    def _covariance_input(self, images, match: _Match, fit: _Fit, t, t_right, motion_gain,
                          motion_cov) -> CovarianceInput:
        """What the estimator of V's covariance needs: the centres and their noise, the fit, and the nuisances
        the pose is uncertain by beside the image noise (the rig's error, the motion that moved the right
        view, the rolling shutter's velocity), each as rows (2, 5, 2, k) with a covariance (k, k)."""
        R, p1, rig_rows, pose_rows, rig_cov = fit.R, fit.p1, fit.rig_rows, fit.pose_rows, fit.rig_cov
        if pose_rows is None:
            rig_rows, _, pose_rows = self._rig_terms(R, p1, t, t_right, fit.velocity, self._rig_cov(), match,
                                                     spread=False)
        rig_mean, rig_parameters = None, 0
        if rig_rows is not None and rig_cov is not None and self.refiner is not None and not fit.disagrees:
            # V's uncertainty takes the rig's error as the data know it, the
            # error model's scale learnt too (a right rig.yaml's share shrinks);
            # the checks keep the error model as it is.
            rig_mean, rig_cov = self.refiner.error_distribution()
            rig_parameters = len(rig_mean)
        plain_rows = pose_rows                 # ∂x/∂pose, before the motion's gain below
        right_rows = np.zeros_like(pose_rows)
        right_rows[1] = pose_rows[1]
        if motion_gain:
            # The right view's model follows this pose (1 + gain) times (the
            # velocity that moved it was taken from this pose).
            pose_rows = pose_rows + motion_gain * right_rows
        if motion_cov is not None:
            # ... and the earlier poses' errors move it too: as a pose error of
            # the right view alone, another nuisance beside the rig's.
            if rig_rows is None or rig_cov is None:
                rig_rows, rig_cov = right_rows, motion_cov
            else:
                rig_rows = np.concatenate([rig_rows, right_rows], axis=-1)
                rig_cov = scipy.linalg.block_diag(rig_cov, motion_cov)
        if match.shutter_cov is not None:
            # ... and so does what is unknown of the velocity that took each
            # row back to t (the rolling shutter): rows δ_r ∂x/∂pose.
            shutter_rows = np.nan_to_num(plain_rows) * match.shutter_delay_s[..., None, None]
            if rig_rows is None or rig_cov is None:
                rig_rows, rig_cov = shutter_rows, match.shutter_cov
            else:
                rig_rows = np.concatenate([rig_rows, shutter_rows], axis=-1)
                rig_cov = scipy.linalg.block_diag(rig_cov, match.shutter_cov)
        if rig_mean is not None:
            rig_mean = np.concatenate([rig_mean, np.zeros(rig_cov.shape[0] - len(rig_mean))])   # the motion's: 0
        axes = self.axes_G @ R.T
        if match.shot_var is None:      # the tracking path leaves the shot-noise term to this stage
            match.shot_var = shot_variance(images, match.centers, match.size, self._prev_background)
        return CovarianceInput(images, match.centers, match.visible, match.sigma_px, fit.residuals, fit.JtJ,
                               R, p1, axes, tuple(self._prev_threshold), tuple(self._prev_background),
                               fit.vectors, t, match.shot_var,
                               pose_rows, rig_rows, rig_cov, self._rig_version(), match.excess_px,
                               rig_mean, not (R is fit.fitted[0] and p1 is fit.fitted[1]), rig_parameters,
                               self.refiner is None or self.refiner.has_data())

    # ------------------------------------------------------------------ the rig
    def _implausible_offset(self, t, t_right) -> str | None:
        """The reason for refusing a pair whose right time is far from the left one (None if plausible).

        Far: more than ``max_right_offset_periods`` frame periods and 0.1 s.
        No motion model bridges that; compensating it would move the model
        by seconds of head motion, so the frame gets no pose, and the
        reason names the skew rather than the reprojection error it causes.
        """
        if t is None or t_right is None:
            return None
        offset_s = float(t_right) - float(t)
        period_s = self._frame_period() or 1.0 / 30.0
        k = self.config.max_right_offset_periods
        bound_s = max(k * period_s, 0.1)
        if not abs(offset_s) > bound_s:
            return None
        periods = f", {k:g} frame periods" if self._frame_periods and bound_s > 0.1 else ""
        return (f"right image's time is {describe_offset_s(offset_s)} the left's (t_right - t), more than "
                f"{bound_s * 1e3:.0f} ms{periods}: not a stereo pair; check times.csv / the cameras' clocks")

    def _pair(self, left, right, t, t_right):
        """The images to use and the right one's exposure time, with the estimated offset.

        The right time is the given one (or t) plus the offset the
        refinement estimated, once it is known. When the right camera
        exposes more than half a frame period after the left one, the
        previous right image is the one nearest to this left image in
        time: it is used instead (no added latency), and the motion over
        what remains of the offset is compensated as usual.
        """
        previous, self._last_right = self._last_right, (right, t, t_right)
        self._declared_right = t_right
        if t is None or self.refiner is None:
            return (left, right), t_right
        if previous is not None and previous[1] is not None and 0 < t - previous[1] < 1.0:
            self._periods = (self._periods + [t - previous[1]])[-8:]
        offset = self.refiner.state.offset_s
        if not abs(offset) > max(2.0 * self.refiner.sigma()[7], 3e-4):
            return (left, right), t_right
        period = float(np.median(self._periods)) if self._periods else None
        if (period and offset > 0.5 * period and previous is not None and previous[1] is not None
                and 0 < t - previous[1] < 1.5 * period):
            right, t_prev, t_right_prev = previous
            self._declared_right = t_right_prev if t_right_prev is not None else t_prev
            return (left, right), self._declared_right + offset
        return (left, right), (t_right if t_right is not None else t) + offset

    def _rig_terms(self, R, p1, t, t_right, velocity, P, match, spread: bool = True):
        """Rig Jacobian rows (2, 5, 2, 9) at the pose, each centre's 1σ residual from the rig (2, 5), px
        (None unless ``spread``), and the pose's own Jacobian rows (2, 5, 2, 6)
        (:func:`geometry.reprojection_rows`).

        A rig error e moves the centres by J_r e; the pose fit absorbs part
        of that and leaves r = (I − H) J_r e in the residuals (H the fit's
        hat matrix, with the fit's weights), in both images: that is what
        the checks must allow.
        """
        pose_rows = geo.reprojection_rows(R, p1, self.model_mm, match.visible, self._cameras)
        if P is None or self.refiner is None:
            return None, None, pose_rows
        dt = (t_right - t) if (t is not None and t_right is not None) else 0.0
        omega, v = velocity if velocity is not None else (None, None)
        rows = rig_jacobian_rows(R, p1, self.model_mm, self.refiner.state, self._cameras.D[1], dt, omega, v,
                                 rows_px=match.centers[..., 1], image_height=int(self.rig.image_size[1]))
        if not spread:
            return rows, None, pose_rows
        M, _ = self._rig_after_fit(pose_rows, rows, match.visible, self._sigma(match))
        var = np.einsum("ij,jk,ik->i", M, P, M).reshape(-1, 2).sum(axis=1)
        sd = np.full(match.visible.shape, np.nan)
        # A spread that cannot be computed (a degenerate fit) widens nothing:
        # NaN would make the checks skip the centre.
        sd[match.visible] = np.sqrt(np.where(np.isfinite(var), np.maximum(var, 0.0), 0.0))
        return rows, sd, pose_rows

    @staticmethod
    def _rig_after_fit(pose_rows, rig_rows, visible, sigma_px):
        """(I − H) J_r (2m, 8), what a rig change leaves in the residuals after the pose fit (px per unit),
        and the fit's weights 1/σ² (2m,), over the visible centres."""
        w = np.repeat(1.0 / np.square(sigma_px[visible]), 2)
        return rig_residual_rows(pose_rows[visible].reshape(-1, 6),
                                 rig_rows[visible].reshape(-1, rig_rows.shape[-1]), w), w

    def _rig_explains(self, pose_rows, vectors, rig_rows, P, match) -> bool:
        """Whether one change of the rig (within P) explains the residuals down to the image noise.

        A bumped camera displaces every centre of its image coherently; a
        glint or a wrong centre displaces one. The residuals are fitted by a
        rig change e (prior P) after the pose fit's share is removed; what
        is left must pass χ² at 99.9% for the degrees of freedom left, or be
        a tenth of the χ² before.
        """
        vis = match.visible
        sigma = np.maximum(self._sigma(match), self.config.outlier_min_sigma_px)
        M, w = self._rig_after_fit(pose_rows, rig_rows, vis, sigma)
        M = M * np.sqrt(w)[:, None]
        r = vectors[vis].reshape(-1) * np.sqrt(w)
        e = np.linalg.solve(M.T @ M + np.linalg.inv(P), M.T @ r)
        before = float(r @ r)
        left = float(np.square(r - M @ e).sum())
        dof = max(len(r) - 6 - P.shape[0], 1)
        # The linear model leaves a little (the fit under the old rig, the σ
        # floor): what is left must be small against what the rig removed.
        return left <= max(float(chi2.ppf(0.999, dof)), 0.1 * before)

    def _offset_unbridged(self, t, t_right) -> str | None:
        """Why the pose is withheld when the right image is known to be exposed at another time than the
        left one and the head's motion over that offset is not known (no recent poses, or none whose
        velocity a head can have): the right view saw the head elsewhere, by an unknown amount. None
        otherwise.

        Only the reproj estimator compensates the offset. The pose is still
        remembered, so the next frame has the velocity.
        """
        c = self.config
        if (c.estimator != "reproj" or not c.compensate_offset or t is None or t_right is None
                or self._compensated or not abs(t_right - t) > c.max_uncompensated_offset_s):
            return None
        return (f"the right image is exposed {describe_offset_s(t_right - t)} the left one and the head's "
                "motion over that is not known (no recent poses give a head's velocity): pose not reported")

    def _rig_consistent(self, R, p1, vectors, pose_rows, rig_rows, P, match):
        """The pose of the joint fit of the pose and a rig change e (prior P), from the pose fitted with
        the rig as is: (R, p1, reason, withheld), the last two None for a pose to report.

        The checks let a frame through when the rig's uncertainty can explain
        its residuals; the pose fitted with the rig as is then carries that
        rig error: a camera turned 1° since rig.yaml, or a baseline 5% off,
        moves P1 by tens of mm at 65 cm (the fit trades the two views'
        disagreement off between them), and a motion compensation that
        drifted does the same. Linearized at the fit (residual vectors r
        (2, 5, 2) px, pose rows J (2, 5, 2, 6), rig rows J_r (2, 5, 2, k)):
        the MAP rig change is ê = −P Mᵀ (M P Mᵀ + W⁻¹)⁻¹ r with M = (I − H) J_r
        what the fit leaves of a rig change, and the pose moves by
        −(JᵀWJ)⁻¹ JᵀW J_r ê (what the fit had absorbed of it).

        Applied only where the images show a rig change (the χ² it removes
        beyond ``chi2.ppf(0.999, k)``); noise is left to the plain fit.
        Refused (``reason``: the frame is not trusted at all): a change
        beyond the rig's uncertainty (Mahalanobis² in P beyond the same
        quantile: not a rig error the model allows; e.g. the left and right
        images exchanged), or a correction beyond 5 mm or 0.5° that the
        frame cannot tell from noise or a stray blob: one centre left out
        explains as much, P1 is known to worse than 1.5 mm (1σ) after it (a
        hidden marker, a weak view), or the robust fit found centres suspect. Withheld (``withheld``: tracked from and
        refining the rig, not reported): a correction too large for the
        linearization (``max_rig_correction_mm``, ``max_rig_correction_deg``).
        """
        cfg = self.config
        vis = match.visible
        sigma = np.maximum(self._sigma(match), cfg.outlier_min_sigma_px)[vis]
        sw = np.repeat(1.0 / sigma, 2)                                   # √W, px⁻¹
        J = pose_rows[vis].reshape(-1, 6) * sw[:, None]
        Jr = rig_rows[vis].reshape(-1, rig_rows.shape[-1]) * sw[:, None]
        r = vectors[vis].reshape(-1) * sw
        if not (np.isfinite(J).all() and np.isfinite(Jr).all() and np.isfinite(r).all() and np.isfinite(P).all()):
            return R, p1, "the rig's share of the residuals cannot be computed at this pose (degenerate fit)", None
        # G = (JᵀWJ)⁺ JᵀW J_r by least squares (defined when few markers make J rank-deficient).
        G = np.linalg.lstsq(J, Jr, rcond=1e-10)[0]
        M = Jr - J @ G
        S = M @ P @ M.T + np.eye(len(r))                                  # whitened: W⁻¹ = I
        u = np.linalg.solve(S, r)
        removed = float(r @ r - r @ u)                                    # χ² the MAP rig change explains
        k = rig_rows.shape[-1]
        quantile = float(chi2.ppf(0.999, k))
        if not removed > quantile:
            return R, p1, None, None
        MPu = P @ (M.T @ u)
        e = -MPu
        mahalanobis2 = float((M.T @ u) @ MPu)
        delta = -G @ e                                                    # (δ rad, ε mm)
        turn = math.degrees(float(np.linalg.norm(delta[:3])))
        shift = float(np.linalg.norm(delta[3:]))
        if mahalanobis2 > quantile:
            return R, p1, (f"the images disagree with the rig beyond its uncertainty "
                           f"({math.sqrt(mahalanobis2):.1f}σ; the pose would move {shift:.0f} mm, {turn:.1f}°): "
                           "rig.yaml stale or the camera moved?"), None
        if shift > _AMBIGUOUS_CORRECTION_MM or turn > _AMBIGUOUS_CORRECTION_DEG:
            Q = np.linalg.pinv(J.T @ J)                                   # the pose's covariance, (rad, mm)²
            # One wrong centre (a stray blob taken for a marker) against one
            # rig change: the χ² that leaving out each centre would remove
            # (block deletion, r_cᵀ (I − H_cc)⁻¹ r_c, at the fit) beside the
            # χ² the rig change removes. A stale rig moves every centre a
            # little and no single one explains it (a third of it, at most
            # three quarters, on stale rigs up to 3° and 10%).
            Jc = J.reshape(-1, 2, 6)
            rc = r.reshape(-1, 2)
            lever = np.eye(2) - np.einsum("cij,jk,clk->cil", Jc, Q, Jc)
            single = float(np.einsum("ci,ci->c", rc, np.linalg.solve(lever, rc[..., None])[..., 0]).max())
            if single >= removed:
                return R, p1, (f"one centre explains these residuals as well as a rig error, and the two move "
                               f"the pose {shift:.0f} mm, {turn:.1f}° apart: a stray blob taken for a marker? "
                               "Not trusted"), None
            # How well this frame alone knows the corrected P1: the pose's own
            # covariance plus what the rig's posterior leaves (mm²).
            rig_post = P - P @ M.T @ np.linalg.solve(S, M @ P)
            p1_var = Q[3:, 3:] + (G @ rig_post @ G.T)[3:, 3:]
            p1_sd = math.sqrt(max(float(np.trace(p1_var)), 0.0))
            if p1_sd > _CORRECTED_P1_SD_MM:
                # Few markers (one hidden) or a weak view: the rig's error and
                # the pose's trade off, and the correction follows noise or a
                # stray blob as readily as the rig.
                return R, p1, (f"the markers seen do not tell the rig's error from the pose (a correction of "
                               f"{shift:.0f} mm, {turn:.1f}°, known to ±{p1_sd:.1f} mm): not trusted"), None
            if match.excess_px is not None:
                # Some centres disagreed with the others (a glint, an
                # occlusion, a stray blob taken for a marker): what they leave
                # is as well a rig change as not.
                # Withheld, not refused: the markers are identified either way,
                # and the refinement, robust to the few centres that disagree,
                # is what tells the two apart (refused, a stale rig with a
                # glint in every frame was never refined: no pose at all).
                return R, p1, None, (f"a rig error and the centres that disagree ({_names(match.excess_px > 0)}) "
                                     f"both explain these residuals, and they move the pose {shift:.0f} mm, "
                                     f"{turn:.1f}° apart: pose not reported until the rig is refined")
        if shift > cfg.max_rig_correction_mm or turn > cfg.max_rig_correction_deg:
            return R, p1, None, (f"the rig's error moves this pose by {shift:.0f} mm, {turn:.1f}°, more than a "
                                 f"linear correction is trusted for: pose not reported until the rig is refined")
        return cv2.Rodrigues(delta[:3])[0] @ R, p1 + delta[3:], None, None

    def _refine(self, match, t, cov_input, R, p1, disagrees) -> None:
        """Feed an accepted frame to the rig's refinement; use the refined rig when it changes."""
        refiner = self.refiner
        if refiner is None:
            return
        if disagrees:
            self._disagreements += 1
            if self._disagreements >= 3:
                # Three frames in a row agree only with the unrefined rig: it changed.
                refiner.widen(t)
                self._disagreements = 0
                self._rig_gate()
            return
        self._disagreements = 0
        if not self.config.rig_refine.enabled or self._glitch:
            # A frame whose time is a repeat or a glitch would teach the
            # refinement a velocity, and an exposure offset, that are not the
            # head's. (One whose time does not fit the motion still tells the
            # rig's geometry: it goes in without a velocity, below.)
            return
        inner = getattr(self.uncertainty, "inner", self.uncertainty)
        if hasattr(inner, "variances"):
            sigma = np.sqrt(inner.variances(cov_input))
        else:
            sigma = np.repeat(self._sigma(match)[..., None], 2, axis=2)
        declared = self._declared_right
        offset = (declared - t) if (declared is not None and t is not None) else 0.0
        recent, self._declared_offsets = self._declared_offsets, (self._declared_offsets + [offset])[-16:]
        usual = sorted(recent)[len(recent) // 2] if recent else offset
        if len(recent) >= 4 and abs(offset - usual) > self.config.rig_errors.offset_declared_s:
            # A declared offset off the usual one by more than its own σ: the
            # times jitter, and the refinement would take that for the rig.
            return
        if refiner.add_frame(t, offset, match.centers, match.visible, sigma, R, p1,
                             motion_known=not self._motion_unknown):
            self._apply_rig(refiner.state.rig())
            # The recent poses, refitted with the new rig by the update itself:
            # the velocity and prediction go on without a jump.
            version = self._rig_version()
            self._motion.refit(refiner.refit_poses, version)
            last = self._motion.last_pose(version)
            if last is not None:
                self._prev_pose = last

    def _rig_version(self) -> int:
        return 0 if self.refiner is None else self.refiner.versions

    def _rig_status(self):
        return None if self.refiner is None else self.refiner.status()

    def _rig_message(self, disagrees: bool = False):
        if self.refiner is None:
            return None
        if disagrees:
            return "the images disagree with the refined rig (bumped?); tracking with the calibration's uncertainty"
        if self.refiner.updates == 0 and not self.refiner.bumps:
            return None
        return self.refiner.describe()

    def _verify(self, R, p1, residuals, outlier, match, rig_sd=None) -> str | None:
        """Why a fitted pose is not to be trusted, or None.

        ``rig_sd`` (2, 5), px: each centre's 1σ displacement from the rig's
        uncertainty, which widens the reprojection tolerance.
        """
        if not np.isfinite(R.sum() + p1.sum()):
            return "pose fit diverged (non-finite result)"
        tol = self.config.reproj_tol_px
        if rig_sd is not None:
            tol = np.hypot(tol, self.config.rig_gate_sigma * rig_sd)
        excess = residuals / tol
        worst = np.fmax.reduce(excess, axis=None)          # ignores hidden markers' NaN
        if np.isnan(worst):
            worst = np.inf
        if worst > 1.0:
            cam, marker = np.unravel_index(np.nanargmax(excess), residuals.shape)
            limit = float(np.broadcast_to(tol, residuals.shape)[cam, marker])
            return (f"reprojection error {residuals[cam, marker]:.2f} px of {MARKER_NAMES[marker]} in the "
                    f"{('left', 'right')[cam]} image exceeds {limit:.2f} px: "
                    "the identification is not trusted")
        if outlier is not None:
            cam, marker = outlier
            return (f"{MARKER_NAMES[marker]} in the {('left', 'right')[cam]} image is "
                    f"{residuals[cam, marker]:.2f} px from where the other markers put it "
                    f"({residuals[cam, marker] / match.sigma_px[cam, marker]:.0f}x its expected "
                    "noise): a glint or partial occlusion; pose not trusted")
        return None

    # --------------------------------------------------------------- detection
    def _check_images(self, left, right) -> str | None:
        width, height = self.rig.image_size
        for name, img in (("left", left), ("right", right)):
            if img is None:
                return f"{name} image missing"
            if img.dtype != np.uint8 or img.ndim != 2:
                return f"{name} image is {img.dtype} with shape {img.shape}; expected 8-bit grayscale"
            if img.shape != (height, width):
                return (f"{name} image is {img.shape[1]}x{img.shape[0]} px but the rig is calibrated "
                        f"for {width}x{height}: wrong camera mode or wrong rig.yaml")
        return None

    def _detect_full(self, image, cam) -> Blobs:
        background = estimate_background(image)
        self._prev_background[cam] = background
        return detect_blobs(image, self.config.detection, background=background)

    # ----------------------------------------------------------- identification
    def _track_fast(self, images) -> _Match | None:
        """Re-measure the previous frame's markers in small windows; None to re-acquire."""
        lock = self._lock
        predicted, size = lock.predicted(), lock.size
        # Window: the blob (±3 σ) plus the prediction's error.
        side = 2 * int(np.ceil(3 * size.max() + self.config.track_margin_px / 2)) + 1
        centers, found, flux, sigma, size, _, shot_var = centroids_near(images, predicted, side, self._prev_background,
                                                                        self._prev_threshold, size)
        if not found.all():
            return None
        # (Two windows locked onto one blob leave a residual of a marker
        # spacing, tens of pixels: verification rejects that frame.)
        # A glint or a neighbour entering a window adds flux to one marker:
        # re-identify rather than let it pull the centroid. Head motion
        # changes all markers of a view alike, so compare with the median.
        if lock.flux is not None:
            # Allowed: the configured change plus 3σ of the relative flux
            # noise of the dimmest marker (Gaussian-weighted flux: σ_n √π s,
            # s the blob's σ), around the median change of the five.
            changes = np.sort(flux / lock.flux, axis=1).tolist()
            dimmest = (flux.min(axis=1) / size.max(axis=1)).tolist()
            for cam in (0, 1):
                low, _, median, _, high = changes[cam]
                if not dimmest[cam] > 0:
                    return None                       # a window with no flux: re-detect
                rel = self._prev_background[cam][1] * 1.7725 / dimmest[cam]
                # 3√2 σ of a ratio; beyond a factor e⁵ the check says nothing anyway.
                limit = self.config.track_flux_change * math.exp(min(4.24 * rel, 5.0))
                if not (median / limit <= low and high <= median * limit):
                    return None
        visible, index = _ALL_VISIBLE, _NO_BLOB
        if self.config.estimator == "reproj":
            # The labels are carried over, and the reprojection fit started
            # from the last pose verifies them: no triangulation needed.
            R, t = self._predicted_pose()
            return _Match(centers, visible, index, _NAN5, _NAN53, R, t, float("nan"), sigma, flux, size, shot_var)
        match = self._match_from_centers(centers, visible, index)
        if match is not None:
            match.sigma_px, match.flux, match.size, match.shot_var = sigma, flux, size, shot_var
        return match

    def _predicted_pose(self):
        """This frame's pose by constant velocity from the last two (the last one if unknown)."""
        return self._motion.predicted(*self._prev_pose)

    def _match_from_centers(self, centers, visible, index) -> _Match | None:
        """Triangulate labeled centres and fit the model; None if they break the checks."""
        xn = [geo.undistort(centers[0], self.rig.K1, self.rig.D1), geo.undistort(centers[1], self.rig.K2, self.rig.D2)]
        epi = geo.epipolar_error_px(xn[0], xn[1], self.E, *self.focal)
        points, _ = geo.triangulate_midpoint(xn[0], xn[1], self.rig.R, self.rig.T)
        R, t, rms = geo.kabsch(self.model_mm, points)
        if epi.max() > self.epipolar_tol_px or rms > self.fit_tol_mm:
            return None
        return _Match(centers, visible, index, epi, points, R, t, float(rms))

    def _candidates(self, b: Blobs) -> np.ndarray:
        """Indices of the blobs most likely to be markers, best first."""
        n = len(b)
        if n == 0:
            return np.zeros(0, np.int64)
        clean = np.flatnonzero(~b.glint)
        pool = clean if len(clean) else np.arange(n)
        # Typical marker size: the median of the five brightest clean blobs
        # (noise specks must not make the markers look oversized).
        brightest = pool[np.argsort(-b.flux_dn[pool])[:5]]
        typical = np.sort(b.area_px[brightest])[len(brightest) // 2]
        oversized = b.area_px > 6 * max(typical, 1)
        penalty = 2 * b.glint + 1 * oversized
        order = np.lexsort((-b.flux_dn, penalty))
        return order[: self.config.max_candidates]

    def _identify(self, blobs) -> tuple[_Match | None, str | None]:
        cand = [self._candidates(b) for b in blobs]
        counts = [len(c) for c in cand]
        names = ("left", "right")
        if min(counts) < 4 or (max(counts) < 5):
            cam = int(np.argmin(counts))
            return None, f"{names[cam]} image: {counts[cam]} marker blobs, 5 needed"
        hyps = [find_hypotheses(blobs[i].centers_px[cand[i]], self.rule) if counts[i] >= 5 else None
                for i in range(2)]
        xn = [geo.undistort(blobs[0].centers_px[cand[0]], self.rig.K1, self.rig.D1),
              geo.undistort(blobs[1].centers_px[cand[1]], self.rig.K2, self.rig.D2)]
        match, reason = None, None
        if hyps[0] is not None and hyps[1] is not None and len(hyps[0]) and len(hyps[1]):
            match, reason = self._best_pair(hyps, xn, cand, blobs)
        if match is None and self.config.hidden_marker:
            alt, alt_reason = self._hidden_marker(hyps, xn, cand, blobs)
            if alt is not None:
                return alt, None
            reason = reason or alt_reason
        if match is None and reason is None:
            missing = [names[i] for i in range(2) if hyps[i] is None or not len(hyps[i])]
            reason = (f"{' and '.join(missing)} image: no five blobs in the markers' layout (three in a line "
                      "and two beside)" if missing else "no consistent stereo identification")
        return match, reason

    def _epipolar_matrix(self, xn) -> np.ndarray:
        """Epipolar error (px) of every left candidate against every right one: (m_left, m_right)."""
        return geo.epipolar_error_px(xn[0][:, None, :], xn[1][None, :, :], self.E, *self.focal)

    def _best_pair(self, hyps, xn, cand, blobs) -> tuple[_Match | None, str | None]:
        """The left/right pair of labelings that best fits the epipolar geometry and the model.

        Pairs are screened by a lookup in the candidates' epipolar-error
        matrix before anything is triangulated; the paper's labelings are
        tried first and the alternatives only when none of those fits.
        """
        hl, hr = hyps
        epi_matrix = self._epipolar_matrix(xn)
        tol = self.epipolar_tol_px
        best_reason = None
        for ranks in ((0,), (0, 1)):
            il_all = np.flatnonzero(hl.rank <= max(ranks))
            ir_all = np.flatnonzero(hr.rank <= max(ranks))
            il = np.repeat(il_all, len(ir_all))
            ir = np.tile(ir_all, len(il_all))
            epi = epi_matrix[hl.index[il], hr.index[ir]]           # (P, 5) by lookup
            keep = epi.max(axis=1) <= tol
            if not keep.any():
                best_reason = (f"no consistent stereo identification: no labeling of the left blobs matches "
                               f"one of the right blobs within the epipolar tolerance ({tol:.1f} px)")
                continue
            il, ir, epi = il[keep], ir[keep], epi[keep]
            xl = xn[0][hl.index[il]]            # (P, 5, 2)
            xr = xn[1][hr.index[ir]]
            points, _ = geo.triangulate_midpoint(xl, xr, self.rig.R, self.rig.T)
            R, t, rms = geo.kabsch(self.model_mm, points)
            valid = (rms <= self.fit_tol_mm) & self._facing_cameras(R, t)
            if not valid.any():
                k = int(np.argmin(rms))
                best_reason = (f"no consistent stereo identification: the best labeling is {rms[k]:.1f} mm "
                               f"(RMS) from the marker model, tolerance {self.fit_tol_mm:.1f} mm"
                               + _scale_hint(points[k], self.model_mm))
                continue
            # Ranked in units of the image-noise tolerances, not of the rig-widened
            # ones: widening must not make a clearly worse assignment a rival.
            cost = (rms / self.config.fit_tol_mm + epi.max(axis=1) / self.config.epipolar_tol_px
                    + 0.05 * (hl.rank[il] + hr.rank[ir]))
            cost = np.where(valid, cost, np.inf)
            best = int(np.argmin(cost))
            if self._ambiguous(R, cost, best):
                return None, "ambiguous identification: two marker assignments fit equally well"
            index = np.stack([cand[0][hl.index[il[best]]], cand[1][hr.index[ir[best]]]])
            return self._make_match(blobs, index, epi[best], points[best], R[best], t[best], rms[best]), None
        return None, best_reason

    def _hidden_marker(self, hyps, xn, cand, blobs) -> tuple[_Match | None, str | None]:
        """One marker hidden in one view: label the full view, match the other's blobs to it.

        For each labeled marker, the other view's blobs within the epipolar
        tolerance are its only possible partners; the assignments are the
        products of those short lists with exactly one marker hidden.
        """
        epi_matrix = self._epipolar_matrix(xn)
        tol = self.epipolar_tol_px
        best = None
        for full in (0, 1):
            other = 1 - full
            h = hyps[full]
            if h is None or not len(h) or len(cand[other]) < 4:
                continue
            rows, hyp_of_row = [], []
            for k, labels in enumerate(h.index[h.rank == 0] if (h.rank == 0).any() else h.index):
                errors = epi_matrix[labels, :] if full == 0 else epi_matrix[:, labels].T     # (5, m_other)
                options = [np.flatnonzero(errors[j] <= tol) for j in range(5)]
                for hidden in range(5):
                    lists = [options[j] if j != hidden else np.array([-1]) for j in range(5)]
                    if any(len(o) == 0 for o in lists):
                        continue
                    combos = np.array(np.meshgrid(*lists, indexing="ij")).reshape(5, -1).T
                    shown = combos[:, [j for j in range(5) if j != hidden]]
                    distinct = np.array([len(set(r)) == 4 for r in shown.tolist()])
                    rows.append(combos[distinct])
                    hyp_of_row.append(np.full(int(distinct.sum()), k))
            if not rows:
                continue
            assignments = np.concatenate(rows)
            labels_full = (h.index[h.rank == 0] if (h.rank == 0).any() else h.index)[np.concatenate(hyp_of_row)]
            if len(assignments) == 0:
                continue
            xf = xn[full][labels_full]                                   # (P, 5, 2)
            xo = xn[other][np.maximum(assignments, 0)]
            weights = (assignments >= 0).astype(np.float64)
            xl, xr = (xf, xo) if full == 0 else (xo, xf)
            epi = np.where(weights > 0, geo.epipolar_error_px(xl, xr, self.E, *self.focal), 0.0)
            points, _ = geo.triangulate_midpoint(xl, xr, self.rig.R, self.rig.T)
            R, t, rms = geo.kabsch(self.model_mm, points, weights)
            valid = (rms <= self.fit_tol_mm) & self._facing_cameras(R, t)
            if not valid.any():
                continue
            cost = np.where(valid, rms / self.config.fit_tol_mm + epi.max(axis=1) / self.config.epipolar_tol_px, np.inf)
            k = int(np.argmin(cost))
            if self._ambiguous(R, cost, k):
                return None, "ambiguous identification with a marker hidden in one view"
            if best is None or cost[k] < best[0]:
                index = np.full((2, 5), -1)
                index[full] = cand[full][labels_full[k]]
                shown = assignments[k] >= 0
                index[other, shown] = cand[other][assignments[k][shown]]
                pts = np.where(weights[k][:, None] > 0, points[k], np.nan)
                best = (cost[k], index, epi[k], pts, R[k], t[k], rms[k])
        if best is None:
            return None, "no consistent identification with a marker hidden in one view"
        return self._make_match(blobs, *best[1:]), None

    def _make_match(self, blobs, index, epi, points, R, t, rms) -> _Match:
        visible = index >= 0
        centers = np.full((2, 5, 2), np.nan)
        for cam in range(2):
            centers[cam, visible[cam]] = blobs[cam].centers_px[index[cam, visible[cam]]]
        epi = np.where(visible.all(axis=0), epi, np.nan)
        sigma, flux, shot = np.full((2, 5), np.nan), np.full((2, 5), np.nan), np.full((2, 5, 2), np.nan)
        for cam in range(2):
            sigma[cam, visible[cam]] = blobs[cam].sigma_px[index[cam, visible[cam]]]
            flux[cam, visible[cam]] = blobs[cam].flux_dn[index[cam, visible[cam]]]
            if blobs[cam].shot_var is not None:
                shot[cam, visible[cam]] = blobs[cam].shot_var[index[cam, visible[cam]]]
        return _Match(centers, visible, index, epi, points, R, t, float(rms), sigma, flux, shot_var=shot)

    def _facing_cameras(self, R, t) -> np.ndarray:
        """The glasses' front (V) must face the cameras: retro-reflectors are seen only from the front."""
        v = np.einsum("...ij,j->...i", R, self.axes_G[2])
        to_cams = self.cameras_mid_mm - t
        return np.einsum("...i,...i->...", v, to_cams) > 0

    def _ambiguous(self, R, cost, best) -> bool:
        """Another acceptable identification nearly as good as the best, with a different V.

        "Nearly as good": cost below twice the best's plus 0.2 (costs are
        errors in units of their tolerances). A hypothesis that merely passes
        the tolerances while the best fits at the noise level is not a rival.
        """
        v = np.einsum("...ij,j->...i", R, self.axes_G[2])
        rivals = np.isfinite(cost) & (cost <= 2 * cost[best] + 0.2)
        cos = np.clip(v[rivals] @ v[best], -1, 1)
        return bool(np.any(np.degrees(np.arccos(cos)) > self.config.ambiguity_deg))

    # -------------------------------------------------------------------- pose
    def _estimate(self, match: _Match, t, t_right):
        """Pose (R_world_G, p1), reprojection residuals (2, 5) and JᵀJ (6, 6) with the configured estimator."""
        est = self.config.estimator
        if est in ("rigid", "paper"):
            R, p1 = match.R, match.t
            if est == "paper" and np.isfinite(match.points).all():
                axes = geo.axes_from_points(match.points, self.normal_signs)
                R = axes.T @ self.axes_G     # rotation taking the model's axes onto the measured ones
                p1 = match.points[1]
            vectors = self._residuals(R, p1, match)
            residuals = np.hypot(vectors[..., 0], vectors[..., 1])
            JtJ = geo.reprojection_jacobian(R, p1, self.model_mm, match.visible[0], match.visible[1], self.rig,
                                            cameras=self._cameras, sigma_px=self._sigma(match))
            return R, p1, residuals, JtJ, vectors
        sigma = self._sigma(match) if self.config.weighted_fit else None
        motion = self._right_motion(t, t_right) if self.config.compensate_offset else None
        self._compensated = motion is not None
        rolling = self._rolling_shutter(match, t)
        fit = geo.refine_reprojection(match.R, match.t, self.model_mm, *self._fit_centers(match),
                                      match.visible[0], match.visible[1], self.rig, right_motion=motion,
                                      sigma_px=sigma, cameras=self._cameras)
        offset = self.config.compensate_offset and t_right is not None and t_right != t
        if offset or rolling:
            # Second pass: the velocity from the last pose to this one lags by
            # half a frame instead of one and a half.
            # The velocity is taken from this pose too: the fit's right rows
            # carry that gain, which makes it the maximum-likelihood fit.
            # refine_reprojection holds the motion fixed while it steps the
            # pose, so a fit of several steps ends where the motion of its
            # starting pose, not of its own, fits best: a first pose
            # displaced by a lagging velocity (a turning head, a late right
            # image) was carried on by the gain instead of corrected. One
            # Gauss-Newton step per pass, the motion taken afresh from the
            # pose before each, is Gauss-Newton on the consistent model.
            # The rolling shutter's displacements are taken afresh likewise
            # (their gain, the rows' time over the velocity's base, is below
            # a half and left out of the rows).
            for _ in range(max(self.config.offset_passes, 1)):
                motion, gain = None, 0.0
                if offset:
                    motion = self._right_motion(t, t_right, current=fit[:2])
                    if motion is not None:
                        self._compensated = True
                        gain, _ = self._motion_terms(t, t_right, fit[:2], covariance=False)
                if rolling:
                    rolling = self._rolling_shutter(match, t, current=fit[:2])
                if motion is None and not rolling:
                    break
                before_R, before_p = fit[0], fit[1]
                fit = geo.refine_reprojection(fit[0], fit[1], self.model_mm, *self._fit_centers(match),
                                              match.visible[0], match.visible[1], self.rig, right_motion=motion,
                                              sigma_px=sigma, cameras=self._cameras, right_gain=gain,
                                              iterations=0)
                # Settled: a step of 0.01 mm and 1e-5 rad, far below the noise.
                if np.abs(fit[1] - before_p).max() < 0.01 and np.abs(fit[0] - before_R).max() < 1e-5:
                    break
        return fit

    # ---------------------------------------------------------- rolling shutter
    def readout_s(self) -> float:
        """The rolling shutter's readout the centres are compensated for, s (first row to last; 0: a
        global shutter, or none known yet).

        The refinement's estimate once it is known to be a readout: beyond
        twice its σ and ``min_readout_s``. Below that the compensation would
        move the centres by less than their noise (0.5 ms at 300 px/s and
        the image's edge: 0.07 px) or by the estimate's own noise, and costs
        a frame's work; what is unknown of it is the rig's uncertainty,
        through its column, all the same. Without the refinement: the
        configured readout."""
        refiner = self.refiner
        if refiner is not None and self.config.rig_refine.enabled:
            readout = float(refiner.state.readout_s)
            sd = float(refiner.sigma()[8])
            return readout if readout > max(2.0 * sd, self.config.min_readout_s) else 0.0
        return self._given_readout_s() or 0.0

    def _row_times(self, centers: np.ndarray, readout_s: float) -> np.ndarray:
        """Each centre's exposure time relative to its image's time (2, 5), s, for a readout (s).

        Row r of an image H rows high is exposed at (r − (H − 1)/2) ×
        readout / (H − 1) after the image's time (the middle row's)."""
        height = int(self.rig.image_size[1])
        return (centers[..., 1] - 0.5 * (height - 1)) * (readout_s / max(height - 1, 1))

    def _rolling_shutter(self, match: _Match, t, current=None) -> bool:
        """Set ``match``'s rolling-shutter terms from the head's velocity at ``t``
        (:meth:`PoseHistory.velocity_at`, with ``current`` = (R, p1) this frame's pose when known);
        True when the centres are compensated.

        A centre at row r was exposed δ_r after t (:meth:`_row_times`): the
        head's image there is displaced by u̇ δ_r, u̇ = ∂x/∂pose · (ω, v) its
        image velocity, which the fit takes off (``shutter_shift_px``). What
        is not known of the velocity (its covariance Σ_v, or, when no recent
        poses give one, a head's typical motion ``prior_head_rate_dps``,
        ``prior_head_speed_mm_s``) is a nuisance of the pose: the rows
        δ_r ∂x/∂pose with covariance Σ_v (``shutter_delay_s``,
        ``shutter_cov``), marginalized in the covariance of V like the rig's
        error; each centre's share, ``shutter_sd_px``, widens the checks.
        (The readout's own uncertainty is the rig's, through its column.)
        """
        match.shutter_shift_px = match.shutter_sd_px = match.shutter_cov = match.shutter_delay_s = None
        if not self.config.compensate_rolling_shutter or self.config.estimator != "reproj" or t is None:
            return False
        readout = self.readout_s()
        if not readout:
            return False
        motion = self._motion.velocity_at(t, self._rig_version(), current)
        R, p1 = current if current is not None else (match.R, match.t)
        rows = np.nan_to_num(geo.reprojection_rows(R, p1, self.model_mm, match.visible, self._cameras))  # (2,5,2,6)
        delay = self._row_times(match.centers, readout)                                                    # (2, 5) s
        if motion is None:
            cov = self._prior_motion_cov
        else:
            omega, velocity, cov = motion
            match.shutter_shift_px = (rows @ np.concatenate([omega, velocity])) * delay[..., None]
            if cov is None:
                cov = self._prior_motion_cov
        match.shutter_delay_s, match.shutter_cov = delay, cov
        var = np.einsum("cmij,jk,cmik->cm", rows, cov, rows) * 0.5 * delay ** 2                           # per coordinate
        match.shutter_sd_px = np.sqrt(np.maximum(var, 0.0))
        return match.shutter_shift_px is not None

    @property
    def _prior_motion_cov(self) -> np.ndarray:
        """A head's motion when no recent poses tell it (6, 6): (rad/s)² ×3, (mm/s)² ×3."""
        c = self.config
        return np.diag([math.radians(c.prior_head_rate_dps) ** 2] * 3 + [c.prior_head_speed_mm_s ** 2] * 3)

    def _fit_centers(self, match: _Match):
        """The centres the pose is fitted to (left (5, 2), right (5, 2)) px: measured, less the rolling
        shutter's displacement when compensated."""
        centers = match.centers if match.shutter_shift_px is None else match.centers - match.shutter_shift_px
        return centers[0], centers[1]

    def _outlier(self, residuals, match: _Match, rig_sd=None):
        """(camera, marker) of the worst centre if it is an outlier, else None.

        ``rig_sd`` (2, 5), px: the rig's share of each centre's expected
        error (a stale rig displaces the right image's centres together).

        Not tested while the right image's exposure offset cannot be
        compensated (no recent pose to take the velocity from): the motion
        then displaces every right centre, and only the absolute tolerance
        applies.
        """
        if match.sigma_px is None or self._uncompensated:
            return None
        if not np.fmax.reduce(residuals, axis=None) > self.config.outlier_floor_px:
            return None                                   # the usual case: nothing near the floor
        sigma = np.where(np.isfinite(match.sigma_px), np.maximum(self._sigma(match), self.config.outlier_min_sigma_px),
                         np.inf)
        if rig_sd is not None:
            sigma = np.hypot(sigma, rig_sd)
        score = np.where(np.isfinite(residuals) & (residuals > self.config.outlier_floor_px),
                         residuals / sigma, 0.0)
        if score.max() <= self.config.outlier_sigma:
            return None
        return np.unravel_index(int(np.argmax(score)), score.shape)

    def _suspect(self, residuals, match: _Match) -> bool:
        """Whether a centre's residual (2, 5) px exceeds ``robust_suspect_sigma`` times its expected
        noise (floored at ``outlier_min_sigma_px``)."""
        if match.sigma_px is None or self._uncompensated:
            return False
        if not np.fmax.reduce(residuals, axis=None) > self.config.robust_suspect_sigma * self.config.outlier_min_sigma_px:
            return False                      # the usual case: every residual within the floor's 3.5σ
        expected = np.maximum(self._sigma(match), self.config.outlier_min_sigma_px)
        return bool(np.nanmax(residuals / expected) > self.config.robust_suspect_sigma)

    def _suspects(self, vectors, match: _Match, pose_rows, rig_rows, rig_cov):
        """The centres (2, 5) bool that disagree with the others, and each one's excess error (2, 5) px;
        (None, None) if none do, or too many for the others to be trusted.

        A robust (Cauchy, scale ``robust_cauchy_sigma`` σ) fit of the
        residual vectors (2, 5, 2) px by a pose change and a rig change
        within its prior ``rig_cov``, linearized at the fitted pose
        (``pose_rows`` (2, 5, 2, 6), ``rig_rows`` (2, 5, 2, 9) or None): a
        rig error displaces the centres of a view coherently and is
        explained by the rig's columns; a glint fused with a marker, or a
        partial occlusion, displaces one centre and is not. The centres
        still beyond ``robust_suspect_sigma`` σ of their noise after that
        fit are suspect; their excess, per coordinate, is their residual
        against it over √2.
        """
        cfg = self.config
        vis = match.visible
        sigma = np.maximum(self._sigma(match), cfg.outlier_min_sigma_px)[vis]          # (m,)
        r = vectors[vis].reshape(-1)
        J = pose_rows[vis].reshape(-1, 6)
        prior = np.zeros((6, 6))
        if rig_rows is not None and rig_cov is not None:
            J = np.hstack([J, rig_rows[vis].reshape(-1, rig_rows.shape[-1])])
            prior = np.zeros((J.shape[1], J.shape[1]))
            prior[6:, 6:] = np.linalg.inv(rig_cov)
        # Columns in their natural units (rad, mm, ...) differ by orders of
        # magnitude: solve in scaled columns.
        col = np.sqrt((J ** 2).sum(axis=0)) + 1e-12
        Js, prior = J / col, prior / np.outer(col, col)
        weight = np.ones(len(sigma))
        for _ in range(cfg.robust_iterations):
            w = np.repeat(weight / sigma ** 2, 2)
            A = Js.T @ (Js * w[:, None]) + prior + 1e-9 * np.eye(Js.shape[1])
            left = (r - Js @ np.linalg.solve(A, Js.T @ (w * r))).reshape(-1, 2)
            z = np.hypot(left[:, 0], left[:, 1]) / sigma
            new = 1.0 / (1.0 + (z / cfg.robust_cauchy_sigma) ** 2)
            if np.abs(new - weight).max() < 0.01:
                break
            weight = new
        bad = z > cfg.robust_suspect_sigma
        if not bad.any():
            return None, None
        suspects = np.zeros(vis.shape, bool)
        suspects[vis] = bad
        # The others agree: at most a few suspects, and six centres of four
        # markers among the rest (a pose and its check).
        agree = vis & ~suspects
        if bad.sum() > cfg.robust_max_suspects or agree.sum() < 6 or agree.any(axis=0).sum() < 4:
            return None, None
        excess = np.zeros(vis.shape)
        excess[vis] = np.where(bad, np.hypot(left[:, 0], left[:, 1]) / math.sqrt(2.0), 0.0)   # per coordinate
        return suspects, excess

    def _sigma(self, match: _Match) -> np.ndarray:
        """Expected centroid error (2, 5), px: the noise, floored (a perfect image is never perfect),
        with a suspect centre's excess."""
        sigma = np.maximum(match.sigma_px, self.config.min_centroid_sigma_px)
        if match.excess_px is not None:
            sigma = np.hypot(sigma, match.excess_px)
        if match.shutter_sd_px is not None:
            sigma = np.hypot(sigma, match.shutter_sd_px)
        return sigma

    def _residuals(self, R, p1, match: _Match) -> np.ndarray:
        """Residual vectors (2, 5, 2), projected minus measured centre, px (NaN if hidden)."""
        pts = (R @ self.model_mm.T).T + p1
        res = np.full((2, 5, 2), np.nan)
        pl = geo.project(pts, np.eye(3), np.zeros(3), self.rig.K1, self.rig.D1)
        pr = geo.project(pts, self.rig.R, self.rig.T, self.rig.K2, self.rig.D2)
        centers = self._fit_centers(match)
        for cam, proj in ((0, pl), (1, pr)):
            vis = match.visible[cam]
            res[cam, vis] = proj[vis] - centers[cam][vis]
        return res

    def _right_motion(self, t, t_right, current=None):
        """The head's motion over the right image's exposure offset (:meth:`PoseHistory.right_motion`)."""
        return self._motion.right_motion(t, t_right, self._rig_version(), current)

    def _motion_terms(self, t, t_right, current, covariance: bool = True):
        """(gain, cov) of the motion compensation (:meth:`PoseHistory.motion_terms`); (0, None) if off."""
        if not self.config.compensate_offset:
            return 0.0, None
        return self._motion.motion_terms(t, t_right, self._rig_version(), current, covariance)

    def _remember(self, match: _Match, t, R, p1, blobs, mode, info=None) -> None:
        self._prev_pose = (R, p1)
        previous = self._lock.centers if self._lock is not None else None
        if not match.visible.all():
            self._lock = None                      # re-identify while a marker is hidden
        elif mode == "track":
            self._lock = _Lock(match.centers, previous, match.size, match.flux)
        else:
            # Fluxes of a full detection are measured differently: the first
            # tracked frame skips the flux comparison.
            size = np.stack([np.sqrt(np.maximum(blobs[cam].flux_dn[match.blob_index[cam]]
                                                / np.maximum(blobs[cam].peak_dn[match.blob_index[cam]], 1e-6),
                                                1.0) / (2 * np.pi)) for cam in range(2)])
            self._lock = _Lock(match.centers, previous, size, None)
        for cam in range(2):
            if blobs[cam] is not None and len(blobs[cam]):
                self._prev_threshold[cam] = blobs[cam].threshold_dn
        if t is not None and not self._time_glitch:
            # (A frame whose time repeats the last one's, or follows it by a
            # fraction of a period, was exposed at an unknown time: its pose
            # would put the motion at the wrong instant.)
            cached = self._rates
            if cached is not None and cached[0] == t and cached[1] is R and cached[2] is p1 and cached[3] == self._rig_version():
                rates = cached[4]                            # _fit made this check on this very pose
            else:
                rates = self._motion.rates_to(t, R, p1, self._rig_version())
            if rates is not None and not rates[2]:
                # The times do not describe the motion the images show (a
                # glitching clock, frames out of order): the poses before
                # this one are no past to take a velocity from, and the rig's
                # refinement, which learns the exposure offset from velocities
                # over the frames' times, must not learn from them, nor from
                # the next frames until a velocity is plausible again.
                self._motion.clear()
                self._times_suspect = True
                if self.refiner is not None:     # its frames so far keep the geometry, lose their velocities
                    self.refiner.forget_motion()
                self._motion_note = (f"the head would have turned {rates[0]:.0f}°/s and moved {rates[1]:.0f} mm/s "
                                     "since the last poses by these times: not a motion a head makes; "
                                     "motion state reset")
            elif rates is not None:
                self._times_suspect = False
            self._motion_unknown = self._times_suspect and (rates is None or not rates[2])
            self._motion.add(t, R, p1, self._rig_version(), info)

