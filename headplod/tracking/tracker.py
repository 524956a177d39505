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
  *track* (a :class:`~.lock._Lock` on the last accepted frame's markers):
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
:class:`~.pose_fit._Fit`), the covariance of V (:meth:`Tracker._covariance_input`), the
rig's refinement (:meth:`Tracker._refine`); a pass that fails while
tracking is repeated acquiring.

Where the parts live: :class:`Tracker` is one state machine over a stereo
stream, and its stages share that state (the lock, the rig in use and its
refinement, the noise tolerances the rig widens, the suspects of a frame,
the rolling shutter's compensation). This module holds the machine: its
state, the public API, a frame's pass and what it remembers. Its stages are
parts of the class (mixins), each in its module: the frame's images and
times (:mod:`.frame_checks`), the *track* state's lock and the markers of a
frame (:mod:`.lock`), the *acquire* state's detection and identification
(:mod:`.acquire`), the pose's fit (:mod:`.pose_fit`) and checks
(:mod:`.rig_check`), the rolling shutter's compensation
(:mod:`.rolling_shutter`), the rig in use, its refinement and bootstrap
(:mod:`.tracker_rig`); the settings are :mod:`.tracker_config`'s. What has no
state of its own lives elsewhere: detection, identification, geometry, the
head's recent motion (:mod:`.motion`), the covariance (:mod:`.uncertainty`)
and the rig's refinement (:mod:`.rig_refine`).
"""
from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from . import geometry as geo
from .acquire import _Acquisition
from .frame_checks import _FrameChecks, describe_offset_s
from .geometry import ESTIMATORS
from .identify import ModelRule
from .lock import MARKER_NAMES, _Lock, _Match, _Tracking
from .motion import PoseHistory
from .pose_fit import _PoseFit
from .rig_check import _RigChecks
from .rolling_shutter import _RollingShutter
from .tracker_config import TrackerConfig
from .tracker_rig import _REFINER_FILES, _RIG_FAILURES, _raised_in, _RigInUse
from .uncertainty import CovarianceInput, make_covariance_estimator

__all__ = ["Tracker", "TrackResult", "internal_error_reason",
           # re-exported from the modules the tracker was split into (and geometry's estimators)
           "TrackerConfig", "MARKER_NAMES", "describe_offset_s", "ESTIMATORS"]


def internal_error_reason(exc: BaseException) -> str:
    """A frame's reason for an exception caught while processing it: ``internal error: TYPE: message``
    (the message on one line, at most 300 characters)."""
    message = " ".join(str(exc).split()) or "(no message)"
    return f"internal error: {type(exc).__name__}: {message[:300]}"


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
        Rows Ξ, Ψ, V in the world frame (docs/contract.md).
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
        Covariance of (φ, θ) of V, deg² (docs/contract.md).
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


class Tracker(_FrameChecks, _Tracking, _Acquisition, _PoseFit, _RigChecks, _RollingShutter, _RigInUse):
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
