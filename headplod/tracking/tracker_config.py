"""The tracker's settings (:class:`TrackerConfig`, frozen), each with its unit: what
:class:`~.tracker.Tracker` reads, and the rig's refinement settings and error models it passes on."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from .detect import DetectionParams
from .geometry import ESTIMATORS
from .rig_priors import RigErrorModel
from .rig_refine_config import RigRefineConfig
from .uncertainty import DEFAULT_COVARIANCE


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
        Blobs per image considered for identification (best ranked first):
        a bound on the epipolar matrix, not on the labelings.
    max_hypotheses : int
        The identification budget: marker labelings fitted to the model per
        frame, best first (:mod:`headplod.tracking.identify`). A frame whose
        labelings run past it and none of the best fits says so
        ("identification budget").
    working_range_mm : (float, float)
        Nearest and farthest depth of a marker in both cameras, mm: stereo
        points outside are not considered.
    hidden_search_px : float
        Largest distance of a marker seen in one view only from where the
        other four put it, px.
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
    track_hidden_marker : bool
        Keep tracking (re-measure the other nine centres, reproj
        estimator) while one marker is hidden in one view, instead of
        acquiring every frame until it is back.
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
        (:meth:`.RigRefiner.bootstrap`); when that explains them down to the
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
        rows; :func:`~headplod.tracking.rig_priors.readout_prior`) and
        estimates it from the head's image motion. A value given here is
        trusted to 5% or 0.5 ms (0.2 ms for a global shutter).
    compensate_rolling_shutter : bool
        Take each marker centre back to the image's time t through the
        head's velocity (reproj estimator): row r of an image H rows high
        is exposed at t + (r − (H − 1)/2) × readout / (H − 1) (t is the
        middle row's time, the dataset contract's mid-exposure).
    min_readout_s : float
        A refined readout below this, s, is not compensated (:meth:`.Tracker.readout_s`).
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
    max_candidates: int = 64
    max_hypotheses: int = 256
    working_range_mm: tuple = (150.0, 3000.0)
    hidden_search_px: float = 4.0
    epipolar_tol_px: float = 2.5
    fit_tol_mm: float = 2.0
    reproj_tol_px: float = 2.0
    ambiguity_deg: float = 3.0
    track: bool = True
    track_margin_px: float = 10.0
    hidden_marker: bool = True
    track_hidden_marker: bool = True
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
