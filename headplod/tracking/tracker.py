"""The stereo IR head tracker: two images in, a verified head pose out.

Stages (each timed per frame in ``TrackResult.timings_s``):

1. ``detect``: blobs in both images (:mod:`headplod.tracking.detect`). While tracking,
   only a region around the previous frame's markers is searched and the
   previous labels are carried over by nearest neighbour; the whole image and
   a fresh identification are used when that fails.
2. ``identify``: stereo points (left/right blob pairs on each other's
   epipolar lines, triangulated), labelled P0..P4 by the marker model's
   pairwise distances and fitted to the model at its true size, the best
   ``max_hypotheses`` labelings only (:mod:`headplod.tracking.identify`); when
   no five-marker labeling fits, four with the fifth marker seen in one view.
3. ``triangulate`` and ``pose``: one of the estimators of :mod:`headplod.tracking.geometry`.
4. ``verify``: reprojection residuals in both images and the rigid-fit error;
   a pose that fails them is not reported (``ok`` False with a reason). A
   pose that passes them only with the rig's uncertainty is corrected for
   the rig error its residuals show, or withheld (tracked from and refining
   the rig, not reported) when that correction, the motion over the right
   image's exposure offset, or the covariance of V is beyond what the
   evidence supports.

The frames' times are checked against each other and against the motion
(:meth:`.frame_checks.FrameChecks.check_time`, :class:`~.motion.HeadMotion`):
a jump back or far ahead resets the motion state, a repeated or glitching
time gives no velocity, and the result's ``notes`` say so. An exception
while processing a frame is isolated to it (:meth:`Tracker.process`).

Parts. :class:`Tracker` is composed of parts (:class:`TrackerParts`, made by
:func:`make_parts`, as opentrack's point tracker is made of a camera, a
point extractor and a pose model). Each owns its state, takes and returns
values, and can be built, run and timed alone:

- frame checks (:class:`~.frame_checks.FrameChecks`): images and times in,
  verdicts out (a repeated buffer, a :class:`~.frame_checks.TimeVerdict`, a
  right camera's implausible offset); :class:`~.frame_checks.RightPairing`:
  the right image paired with each left one, and its exposure time;
- detection (:class:`~.detection.Detector`): images in, blobs out (*acquire*),
  or the locked markers re-measured (*track*, a :class:`~.detection.Remeasured`);
- identification (:class:`~.acquire.Identifier`): blobs and the rig's
  geometry in, labelled markers (a :class:`~.lock.Match`) or a reason out;
- pose fit (:class:`~.pose_fit.PoseFitter`): markers in, a
  :class:`~.pose_fit.Fit` (pose, residuals, verdicts) out; its checks
  (:class:`~.rig_check.RigChecks`) and the rolling shutter's compensation
  (:class:`~.rolling_shutter.RollingShutter`) are parts of their own;
- covariance (:class:`~.covariance.Covariance`): a fit in, the covariance of V out;
- the rig in use, its refinement and bootstrap (:class:`~.tracker_rig.RigInUse`,
  a :class:`~.tracker_rig.RigGeometry` value for the stages that use it);
- the head's motion (:class:`~.motion.HeadMotion`).

States. :class:`Tracker` holds the one state machine. The markers (a
:class:`MarkerState`: a :class:`MarkerPhase` and the lock):

- *acquire* (no lock): detect every blob and identify the five markers;
- *track* (a :class:`~.lock.Lock` on the last accepted frame's markers):
  re-measure them in small windows, and acquire when that fails;
- *withheld*: the last pass's pose was kept (tracked from, with a lock when
  every marker was seen) but not reported; a failed re-measure is then not
  repeated acquiring.

Only an accepted pose with every marker seen makes a lock; every refusal
drops it. The rig (a :class:`~.tracker_rig.RigPhase`, the rig part's):
*as rig.yaml says* (no update yet; two consecutive frames that fail against
it may replace it by the rig they show, :meth:`~.tracker_rig.RigInUse.bootstrap`),
*refining* (the online refinement's updates, every 8 tracked frames, solved
over the following frames), *refined* (its turn and shift known to a tenth
of their prior; a bump widens them again). :meth:`Tracker.state` names both.

A frame is one pass (:meth:`Tracker._attempt`): measure
(:meth:`Tracker._measure`), fit and check (:meth:`~.pose_fit.PoseFitter.fit`),
remember (:meth:`Tracker._remember`), the covariance of V, the rig's
refinement; a pass that fails while tracking is repeated acquiring. The
settings are :mod:`.tracker_config`'s.
"""
from __future__ import annotations

import enum
import math
import time
import traceback
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from . import geometry as geo
from .acquire import Identifier
from .covariance import Covariance
from .detection import Detector
from .frame_checks import FrameChecks, RightPairing, TimeLimits, TimeVerdict, describe_offset_s
from .geometry import ESTIMATORS
from .lock import _ALL_VISIBLE, _NAN5, _NAN53, _NO_BLOB, MARKER_NAMES, Lock, Match
from .motion import HeadMotion
from .pose_fit import Fit, PoseFitter
from .rig_check import RigChecks
from .rolling_shutter import RollingShutter
from .tracker_config import TrackerConfig
from .tracker_rig import _REFINER_FILES, _RIG_FAILURES, RigFailure, RigInUse, _raised_in
from .uncertainty import CovarianceInput
from ..tol import tol

__all__ = ["Tracker", "TrackResult", "TrackerParts", "make_parts", "MarkerPhase", "MarkerState",
           "internal_error_reason",
           # re-exported from the modules of the tracker's parts (and geometry's estimators)
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
    hypotheses : int
        Marker labelings the identification fitted in this pass (0 when the
        markers were re-measured): its cost, counted.
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
    hypotheses: int = 0

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


class MarkerPhase(enum.Enum):
    """The markers' state, and what moves it (module docstring).

    *acquire* (no lock: the whole image is searched and identified) goes to
    *track* on a reported pose and to *withheld* on a pose kept but not
    reported; *track* and *withheld* (a lock: only windows at the predicted
    markers are measured) go between each other the same way, and back to
    *acquire* when the markers are lost, a pose fails verification or the
    frame times are discontinuous.
    """

    ACQUIRE = "acquire"
    TRACK = "track"
    WITHHELD = "withheld"


@dataclass(frozen=True)
class MarkerState:
    """The markers' state: the phase and the lock on the last accepted frame's markers (None: acquire)."""

    phase: MarkerPhase = MarkerPhase.ACQUIRE
    lock: Lock | None = None

    @staticmethod
    def kept(lock: Lock | None, withheld: bool = False) -> MarkerState:
        """After a pose kept (tracked from): *withheld* if it is not reported, else *track* with a lock,
        *acquire* without one."""
        if withheld:
            return MarkerState(MarkerPhase.WITHHELD, lock)
        return MarkerState(MarkerPhase.TRACK if lock is not None else MarkerPhase.ACQUIRE, lock)


_ACQUIRE = MarkerState()


class TrackerParts(NamedTuple):
    """The parts a :class:`Tracker` is composed of (module docstring)."""

    frames: FrameChecks
    pairing: RightPairing
    detector: Detector
    identifier: Identifier
    motion: HeadMotion
    rig: RigInUse
    shutter: RollingShutter
    checks: RigChecks
    fitter: PoseFitter
    covariance: Covariance


def make_parts(rig, model_mm: np.ndarray, axes_G: np.ndarray, config: TrackerConfig,
               calibration_std: dict | None = None) -> TrackerParts:
    """The parts of a tracker for a rig (:class:`headplod.io.Rig`), a marker model ``model_mm`` (5, 3) mm
    with its axes ``axes_G`` (3, 3) (rows Ξ, Ψ, V, glasses frame) and the settings."""
    checks = RigChecks(config, model_mm)
    covariance = Covariance(config, model_mm, axes_G, rig, checks)
    rig_in_use = RigInUse(rig, model_mm, config, calibration_std, on_change=covariance.use_rig)
    motion = HeadMotion(config)
    shutter = RollingShutter(config, model_mm, rig_in_use, motion)
    fitter = PoseFitter(config, model_mm, axes_G, rig_in_use, motion, shutter, checks)
    return TrackerParts(FrameChecks(TimeLimits.of(config)), RightPairing(), Detector(config), Identifier(config, model_mm, axes_G),
                        motion, rig_in_use, shutter, checks, fitter, covariance)


@dataclass(frozen=True)
class _Frame:
    """One frame's inputs to its passes: the images to use, their times (s), the time's verdict, and the
    stages' timings (s, filled in) from ``start`` (``time.perf_counter``)."""

    images: tuple
    t: float | None
    t_right: float | None
    verdict: TimeVerdict
    timings: dict
    start: float


class _Pass(NamedTuple):
    """A pass's outcome: the result; the fit, if it got that far; the fit that failed for a reason a
    rig far from rig.yaml explains, if it did; what the motion made of the pose's time, if anything."""

    result: TrackResult
    fit: Fit | None = None
    failure: RigFailure | None = None
    motion_note: str | None = None


class Tracker:
    """Head tracker for one stereo rig and marker model.

    Parameters
    ----------
    rig : headplod.io.Rig
    model : headplod.io.MarkerModel
    config : TrackerConfig
    calibration_std : dict, optional
        The calibration's uncertainties, for the rig refinement's prior.
    parts : TrackerParts, optional
        The parts (default :func:`make_parts`), e.g. with one replaced.
    """

    def __init__(self, rig, model, config: TrackerConfig = TrackerConfig(), calibration_std: dict | None = None,
                 parts: TrackerParts | None = None):
        self.model = model
        self.config = config
        self.model_mm = np.asarray(model.points_mm, dtype=np.float64)
        self.axes_G = geo.model_axes(self.model_mm)
        self.parts = parts or make_parts(rig, self.model_mm, self.axes_G, config, calibration_std)
        self._markers = _ACQUIRE
        # Exceptions isolated by process(): counted, never silent (see process).
        self.internal_errors = 0
        self.first_internal_error: str | None = None
        self.first_internal_traceback: str | None = None
        self.reset()

    # ------------------------------------------------------------ the parts' state, read
    @property
    def rig(self):
        """The rig in use (:class:`headplod.io.Rig`): rig.yaml's, or the refined one."""
        return self.parts.rig.rig

    @property
    def refiner(self):
        """The rig's online refinement (:class:`~.rig_refine.RigRefiner`), None before the first frame."""
        return self.parts.rig.refiner

    @property
    def time_jumps(self) -> int:
        """Discontinuities of the frame time (back, or far ahead) so far: each reset the motion."""
        return self.parts.frames.time_jumps

    @property
    def first_time_jump(self) -> str | None:
        """The first discontinuity's note."""
        return self.parts.frames.first_time_jump

    def readout_s(self) -> float:
        """The rolling shutter's readout the centres are compensated for, s
        (:meth:`~.rolling_shutter.RollingShutter.readout_s`)."""
        return self.parts.shutter.readout_s()

    def reset(self) -> None:
        """Forget the previous frames (e.g. after a seek)."""
        p = self.parts
        p.covariance.reset()
        p.detector.reset()
        p.rig.reset()
        self._reset_motion()

    def _reset_motion(self) -> None:
        """Forget the head's motion: the poses, the last markers and the right images they came with.

        What a time discontinuity invalidates; the image statistics (noise,
        background) and the rig's refinement stand.
        """
        self._markers = _ACQUIRE
        self.parts.motion.reset()
        self.parts.pairing.reset()

    # ------------------------------------------------------------------ public
    def state(self) -> tuple[str, str]:
        """(markers, rig): 'track' or 'acquire'; 'rig.yaml', 'refining' or 'refined' (module docstring)."""
        markers = "track" if self._markers.lock is not None and self.config.track else "acquire"
        return markers, self.parts.rig.phase().value

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
        p = self.parts
        problem = p.frames.check_images(left, right, p.rig.rig.image_size)
        if problem:
            return TrackResult(False, problem, timings_s={"total": time.perf_counter() - start})
        repeated = p.frames.repeated_images(left, right)
        if repeated:
            return TrackResult(False, repeated, timings_s={"total": time.perf_counter() - start})
        verdict = p.frames.check_time(t)
        if verdict.discontinuity:
            self._reset_motion()
        notes = verdict.notes
        skew = p.frames.implausible_offset(t, t_right)
        if skew:
            self._markers = _ACQUIRE
            return TrackResult(False, skew, timings_s={"total": time.perf_counter() - start}, notes=notes)
        if p.rig.refiner is None:
            p.rig.start_refiner(t_right)
        p.shutter.set_readout_prior(p.frames.frame_periods)
        images, t_right = p.pairing.pair(left, right, t, t_right, p.rig.refiner)
        frame = _Frame(images, t, t_right, verdict, {}, start)
        tracking = self.config.track and self._markers.lock is not None
        passes = [self._attempt(frame, tracking)]
        result = passes[-1].result
        if (tracking and not result.ok and result.mode == "track"
                and self._markers.phase is not MarkerPhase.WITHHELD):
            # The re-measured markers did not verify: detect and identify afresh.
            passes.append(self._attempt(frame, False))
        bootstrap_note = self._bootstrap_rig(frame, passes)
        if bootstrap_note:
            # rig.yaml is far from the rig: the frame fitted jointly with the
            # rig gave one that explains it. Tracked afresh with that rig,
            # whose uncertainty the pose's covariance carries.
            passes.append(self._attempt(frame, False))
            passes[-1].result.notes = passes[-1].result.notes + [bootstrap_note]
        result = passes[-1].result
        motion_note = next((q.motion_note for q in reversed(passes) if q.motion_note), None)
        if motion_note:
            notes = notes + [motion_note]
        if notes:
            result.notes = notes + result.notes
        return result

    def _bootstrap_rig(self, frame: _Frame, passes: list) -> str | None:
        """The rig part's bootstrap (:meth:`~.tracker_rig.RigInUse.bootstrap`) on this frame's last fit
        that failed for a rig reason, with the last fit's compensation of the right view; its note."""
        failure = next((q.failure for q in reversed(passes) if q.failure is not None), None)
        fit = next((q.fit for q in reversed(passes) if q.fit is not None), None)
        return self.parts.rig.bootstrap(frame.t, failure, fit is not None and fit.uncompensated,
                                        fit is not None and fit.compensated, self.parts.pairing.declared_right)

    def _internal_error(self, exc: Exception, start: float) -> TrackResult:
        """The result of a frame whose processing raised ``exc``; the state it may have damaged is reset."""
        reason = internal_error_reason(exc)
        self.internal_errors += 1
        if self.first_internal_error is None:
            self.first_internal_error = reason
            self.first_internal_traceback = "".join(traceback.format_exception(exc))
        rig = self.parts.rig
        try:
            self.reset()
            if rig.refiner is not None and _raised_in(exc, _REFINER_FILES):
                rig.restart_refiner()
        except Exception as again:      # noqa: BLE001 -- a reset that fails too: start over entirely
            reason += f" (and resetting failed: {type(again).__name__}: {again})"
            rig.start_over()
            self.reset()
        return TrackResult(False, reason, timings_s={"total": time.perf_counter() - start})

    def _attempt(self, frame: _Frame, tracking: bool) -> _Pass:
        """One pass: measure (track or acquire), fit and check, the covariance of V, the rig's refinement."""
        p, images, t, t_right = self.parts, frame.images, frame.t, frame.t_right
        timings, start = frame.timings, frame.start
        match, mode, reason, blobs, hypotheses = self._measure(images, tracking, timings)
        if match is None:
            self._markers = _ACQUIRE
            timings["total"] = time.perf_counter() - start
            return _Pass(TrackResult(False, reason, mode=mode, timings_s=timings, blobs=blobs, hypotheses=hypotheses))
        fit = p.fitter.fit(match, t, t_right, timings)
        failure = None
        if (fit.reason or fit.withheld or "").startswith(_RIG_FAILURES):
            failure = RigFailure(match, *fit.fitted)          # for the rig's bootstrap
        if fit.reason is not None:
            self._markers = _ACQUIRE
            timings["total"] = time.perf_counter() - start
            return _Pass(TrackResult(False, fit.reason, centers_px=match.centers, residuals_px=fit.residuals,
                                     mode=mode, timings_s=timings, blobs=blobs, hypotheses=hypotheses,
                                     marker_blob=match.blob_index,
                                     rig=p.rig.status(), rig_message=p.rig.message()), fit, failure)
        motion_gain, motion_cov = p.fitter.motion_terms(t, t_right, fit.fitted)
        motion_note = self._remember(match, frame, fit, blobs, mode)
        timings["mean_pose"] = time.perf_counter() - start

        # The uncertainty of V is its own stage (the mean pose is done).
        t_cov = time.perf_counter()
        cov_input = p.covariance.input(images, match, fit, t, t_right, motion_gain, motion_cov,
                                       p.detector.backgrounds, p.detector.thresholds, p.rig)
        timings["covariance_input"] = time.perf_counter() - t_cov
        cov = p.covariance.estimate(cov_input)
        timings["covariance"] = time.perf_counter() - t_cov
        if not np.isfinite(cov).all() or np.linalg.det(cov) <= 0:
            timings["total"] = time.perf_counter() - start
            return _Pass(TrackResult(False, f"no covariance of V from the {p.covariance.name} estimator "
                                            "(too few marker pixels?)", mode=mode, timings_s=timings, blobs=blobs,
                                 hypotheses=hypotheses),
                         fit, failure, motion_note)
        withheld = fit.withheld
        sd_deg = math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0))
        if withheld is None and sd_deg > self.config.max_v_sd_deg:
            # Still tracked from and refining the rig: that is what narrows it.
            withheld = (f"V uncertain to ±{sd_deg:.1f}° (1σ), more than {self.config.max_v_sd_deg:g}°: "
                        "the rig or the motion leaves too much unknown; pose not reported")

        # The rig's refinement is its own stage, fed every accepted frame.
        t_ref = time.perf_counter()
        self._refine(match, frame, fit, cov_input)
        timings["refine_rig"] = time.perf_counter() - t_ref
        timings["total"] = time.perf_counter() - start
        if withheld is not None:
            self._markers = MarkerState.kept(self._markers.lock, withheld=True)
            return _Pass(TrackResult(False, withheld, centers_px=match.centers, residuals_px=fit.residuals,
                                     mode=mode, timings_s=timings, blobs=blobs, hypotheses=hypotheses,
                                     marker_blob=match.blob_index,
                                     rig=p.rig.status(), rig_message=p.rig.message(fit.disagrees)),
                         fit, failure, motion_note)
        axes = self.axes_G @ fit.R.T
        return _Pass(TrackResult(True, None, fit.p1, axes, fit.R, match.centers, fit.residuals, match.epipolar,
                                 match.fit_rms, mode, timings, blobs, match.blob_index, cov_deg2=cov, hypotheses=hypotheses,
                                 cov_input=cov_input, rig=p.rig.status(), rig_message=p.rig.message(fit.disagrees)),
                     fit, failure, motion_note)

    def _measure(self, images, tracking: bool, timings: dict):
        """The markers of this frame: (match or None, mode, reason for none, blobs, hypotheses scored).

        *Track* (``tracking``: a lock on the last frame's markers): re-measure
        them in small windows; *acquire* (no lock, or the re-measure failed):
        detect every blob and identify the five markers.
        """
        p = self.parts
        match, mode, reason, blobs, hypotheses = None, "acquire", None, (None, None), 0
        if tracking:
            t_det = time.perf_counter()
            match = self._remeasure(images)
            timings["detect"] = time.perf_counter() - t_det
            mode = "track"
        if match is None:
            t_det = time.perf_counter()
            blobs = p.detector.detect(images)
            timings["detect"] = timings.get("detect", 0.0) + time.perf_counter() - t_det
            t_id = time.perf_counter()
            match, reason, hypotheses = p.identifier.identify(blobs, p.rig.geometry)
            timings["identify"] = timings.get("identify", 0.0) + time.perf_counter() - t_id
            mode = "acquire"
        return match, mode, reason, blobs, hypotheses

    def _remeasure(self, images) -> Match | None:
        """The locked markers re-measured in small windows, labelled as before; None to re-acquire."""
        p = self.parts
        lock = self._markers.lock
        hidden_px = None
        if lock.visible is not None:
            # Where the predicted pose puts the hidden marker: if it is seen
            # there again, the frame re-acquires all five.
            hidden_px = p.rig.geometry.cameras.project_model(self.model_mm, *p.motion.predicted())
        found = p.detector.remeasure(images, lock, hidden_px)
        if found is None:
            return None
        centers, flux, sigma, size, shot_var = found
        visible, index = (_ALL_VISIBLE if lock.visible is None else lock.visible), _NO_BLOB
        if self.config.estimator == "reproj":
            # The labels are carried over, and the reprojection fit started
            # from the last pose verifies them: no triangulation needed.
            R, t = p.motion.predicted()
            return Match(centers, visible, index, _NAN5, _NAN53, R, t, float("nan"), sigma, flux, size, shot_var)
        match = p.identifier.match_from_centers(centers, visible, index, p.rig.geometry)
        if match is not None:
            match.sigma_px, match.flux, match.size, match.shot_var = sigma, flux, size, shot_var
        return match

    def _remember(self, match: Match, frame: _Frame, fit: Fit, blobs, mode: str) -> str | None:
        """Keep a fitted pose: the lock on its markers (when all were seen, or all but one in one view), the
        detection's thresholds, and the pose in the head's motion; the motion's note on its time, if any."""
        p = self.parts
        R, p1 = fit.fitted
        p.motion.set_pose(R, p1)
        lock = self._markers.lock
        previous = lock.centers if lock is not None else None
        visible = None if match.visible.all() else match.visible.copy()
        if visible is not None and not (self.config.track_hidden_marker and self.config.estimator == "reproj"
                                        and (~visible).sum() == 1):
            lock = None                            # re-identify while markers are hidden
        elif mode == "track":
            lock = Lock(match.centers, previous, match.size, match.flux, visible)
        else:
            # Fluxes of a full detection are measured differently: the first
            # tracked frame skips the flux comparison.
            size = np.full((2, 5), np.nan)
            for cam in range(2):
                seen = match.blob_index[cam] >= 0
                index = match.blob_index[cam][seen]
                size[cam, seen] = np.sqrt(np.maximum(blobs[cam].flux_dn[index]
                                                     / np.maximum(blobs[cam].peak_dn[index], tol.floor),
                                                     1.0) / (2 * np.pi))
            lock = Lock(match.centers, previous, size, None, visible)
        self._markers = MarkerState.kept(lock)
        p.detector.keep_thresholds(blobs)
        note = p.motion.remember(frame.t, R, p1, p.rig.version(), fit.JtJ, fit.checked_rates, frame.verdict.time_glitch)
        if note is not None:
            p.rig.forget_motion()          # its frames so far keep the geometry, lose their velocities
        return note

    def _refine(self, match: Match, frame: _Frame, fit: Fit, cov_input: CovarianceInput) -> None:
        """Feed an accepted frame to the rig's refinement; when the rig in use changed, the recent poses
        refitted with it go on in the head's motion (the velocity and prediction without a jump)."""
        p = self.parts
        if p.rig.refine(match, frame.t, lambda: p.covariance.centre_sd(cov_input, match), fit.fitted[0],
                        fit.fitted[1], fit.disagrees, frame.verdict.glitch, p.pairing.declared_right,
                        motion_known=not p.motion.motion_unknown):
            p.motion.refit(p.rig.refiner.estimator.refit_poses, p.rig.version())
