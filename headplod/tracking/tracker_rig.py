"""The tracker's rig: the one in use, its refinement fed with the tracked frames, and its bootstrap from a
``rig.yaml`` far off.

:class:`RigInUse` is a part of :class:`~.tracker.Tracker`: it owns the rig
in use and what derives from it, as one value (:class:`RigGeometry`: the
epipolar geometry, the cameras, and the checks' tolerances widened by the
rig's uncertainty, :meth:`RigInUse.apply`), the refinement
(:class:`~.rig_refine.RigRefiner`: started at the first frame, fed every
accepted frame by :meth:`RigInUse.refine`, widened after a bump, restarted
after an exception inside it), and the bootstrap
(:meth:`RigInUse.bootstrap`: two consecutive frames that fail against a
rig.yaml no frame has confirmed may replace it by the rig they show). Its
phase (:class:`RigPhase`: as rig.yaml says, refining, refined) is the rig's
half of the tracker's state (:meth:`~.tracker.Tracker.state`).
"""
from __future__ import annotations

import enum
import traceback
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np

from . import geometry as geo
from . import (rig_estimator, rig_frames, rig_priors, rig_refine, rig_refine_config, rig_report, rig_schedule,
               rig_solve, rig_state)
from .lock import Match, centroid_sigma
from .rig_refine import RigRefiner

# Refusals that a rig far from rig.yaml explains (see RigInUse.bootstrap).
_RIG_FAILURES = ("reprojection error", "the images disagree with the rig", "the rig's error moves this pose")
_BOOTSTRAP_FRAMES = 2
# The module files of the rig's refinement: an exception that passed through
# them may have damaged its state (Tracker._internal_error restarts it).
_REFINER_FILES = tuple(module.__name__.rsplit(".", 1)[-1] + ".py" for module in (
    rig_refine, rig_estimator, rig_schedule, rig_report, rig_state, rig_priors, rig_frames, rig_solve,
    rig_refine_config))


def _raised_in(exc: BaseException, filenames: str | tuple[str, ...]) -> bool:
    """Whether ``exc`` passed through code of a module file named ``filenames`` (e.g. ``rig_refine.py``, or a
    tuple of such names)."""
    return any(frame.f_code.co_filename.endswith(filenames) for frame, _ in traceback.walk_tb(exc.__traceback__))


class RigPhase(enum.Enum):
    """The rig's state: as rig.yaml says (no update yet), refining (updates, not converged), refined.

    The first accepted update (or a bootstrap, when rig.yaml fails on
    consecutive frames) starts *refining*; the estimator's convergence makes
    it *refined*; a bump (the rig moved: the frames agree only with the
    unrefined uncertainty) widens the estimate and returns it to *refining*.
    """

    YAML = "rig.yaml"
    REFINING = "refining"
    REFINED = "refined"


@dataclass(frozen=True)
class RigGeometry:
    """The rig in use and what the tracking stages derive from it.

    ``rig`` (:class:`headplod.io.Rig`); ``E`` (3, 3) its essential matrix;
    ``focal`` (left, right) geometric-mean focal lengths, px;
    ``cameras_mid_mm`` (3,) the point between the cameras, world (left
    camera) frame, mm; ``cameras`` (:class:`~.geometry.StereoCameras`);
    ``rig_sigma_px`` the image shift a 1σ rig error causes, px, and the
    identification's tolerances it widens: ``epipolar_tol_px`` px,
    ``fit_tol_mm`` mm (:meth:`RigInUse.apply`).
    """

    rig: object
    E: np.ndarray
    focal: tuple
    cameras_mid_mm: np.ndarray
    cameras: geo.StereoCameras
    rig_sigma_px: float = 0.0
    epipolar_tol_px: float = 0.0
    fit_tol_mm: float = 0.0


class RigFailure(NamedTuple):
    """A frame fitted but refused or withheld for a reason a rig far from rig.yaml explains: its markers and
    the pose fitted with the rig in use (R_world_G (3, 3), P1 (3,) mm), what :meth:`RigInUse.bootstrap`
    takes."""

    match: Match
    R: np.ndarray
    p1: np.ndarray


class RigInUse:
    """The rig of :class:`~.tracker.Tracker` and its refinement (module docstring).

    Parameters
    ----------
    rig : headplod.io.Rig
        rig.yaml's rig (:attr:`calibrated_rig`), in use until refined.
    model_mm : (5, 3) float
        The marker model, glasses frame, mm.
    config : TrackerConfig
    calibration_std : dict, optional
        The calibration's uncertainties, for the refinement's prior.
    on_change : callable, optional
        Called with each rig put in use (e.g. to give it to the covariance's estimator).
    """

    def __init__(self, rig, model_mm: np.ndarray, config, calibration_std: dict | None = None,
                 on_change: Callable | None = None):
        self.calibrated_rig = rig
        self.rig_model_mm = model_mm
        self.rig_config = config
        self._calibration_std = calibration_std
        self._on_change = on_change
        self.refiner = None           # made at the first frame, when it is known whether t_right is given
        self._bootstrap_fits = []     # consecutive frames that failed against the rig, for bootstrap
        self._disagreements = 0       # consecutive frames that agree only with the unrefined rig
        self._declared_offsets = []   # recent t_right - t of the frames fed to the rig's refinement, s
        self.geometry: RigGeometry | None = None
        self.apply(rig)

    @property
    def rig(self):
        """The rig in use (:class:`headplod.io.Rig`)."""
        return self.geometry.rig

    def apply(self, rig) -> None:
        """Use a (refined) rig from now on: epipolar geometry, cameras, the checks' tolerances."""
        self.geometry = RigGeometry(
            rig, geo.essential_matrix(rig.R, rig.T),
            (float(np.sqrt(rig.K1[0, 0] * rig.K1[1, 1])), float(np.sqrt(rig.K2[0, 0] * rig.K2[1, 1]))),
            0.5 * (-rig.R.T @ np.reshape(rig.T, 3)), geo.StereoCameras(rig))
        if self._on_change is not None:
            self._on_change(rig)
        self._gate()

    def start_refiner(self, t_right) -> None:
        """Start the rig's refinement (at the first frame: whether ``t_right`` is given is then known)."""
        c = self.rig_config
        self.refiner = RigRefiner(self.calibrated_rig, self.rig_model_mm, c.rig_refine, c.rig_errors,
                                  offset_declared=t_right is not None, calibration_std=self._calibration_std)
        self._gate()

    def start_over(self) -> None:
        """Forget the refinement and use rig.yaml's rig again (after a reset that failed)."""
        self.refiner = None
        self.apply(self.calibrated_rig)

    def reset(self) -> None:
        """Forget the frames that disagreed with the refined rig (the tracker's reset)."""
        self._disagreements = 0

    def _gate(self) -> None:
        """Tolerances of the consistency checks: image noise plus what the rig's uncertainty can displace.

        σ_rig (px): the image shift a 1σ error of the rig's turn, shift and
        focal scale causes at a typical distance (60 cm) and image radius
        (300 px). The exposure offset's share needs the head's image speed,
        unknown when acquiring; it is left to the reprojection checks.
        """
        c = self.rig_config
        P = self.cov()
        if P is None:
            sigma_px = 0.0
        else:
            f = self.geometry.focal[1]
            turn = float(np.sqrt(np.linalg.eigvalsh(P[:3, :3]).max()))
            shift = float(np.sqrt(np.linalg.eigvalsh(P[3:6, 3:6]).max()))
            sigma_px = float(np.sqrt((f * turn) ** 2 + (f * shift / 600.0) ** 2 + (300.0 * np.sqrt(P[6, 6])) ** 2))
        k = c.rig_gate_sigma * sigma_px
        # A rig error changes the triangulated shape by about a third of a
        # millimetre per pixel of disparity error at 60 cm.
        self.geometry = replace(self.geometry, rig_sigma_px=sigma_px,
                                epipolar_tol_px=float(np.hypot(c.epipolar_tol_px, k)),
                                fit_tol_mm=float(np.hypot(c.fit_tol_mm, 0.35 * k)))

    def cov(self, wide: bool = False):
        """Covariance (9, 9) of the rig's error state now (None before the first frame); ``wide``: plus its
        prior (the rig as uncertain as before any refinement)."""
        if self.refiner is None:
            return None
        estimator = self.refiner.estimator
        P = estimator.cov()
        return P + estimator.prior if wide else P

    def phase(self) -> RigPhase:
        """As rig.yaml says, refining or refined (module docstring)."""
        estimator = None if self.refiner is None else self.refiner.estimator
        if estimator is None or not self.rig_config.rig_refine.enabled or (not estimator.updates
                                                                             and estimator.bootstrapped_at is None):
            return RigPhase.YAML
        return RigPhase.REFINED if estimator.converged() else RigPhase.REFINING

    def bootstrap(self, t, failure: RigFailure | None, uncompensated: bool, compensated: bool,
                  declared_right) -> str | None:
        """When consecutive frames fail against a rig.yaml no frame has yet confirmed (before the
        refinement's first update), fit their poses and the rig together under the far-off prior
        ``rig_far`` (:meth:`RigRefiner.bootstrap`): a rig.yaml far off (the right camera turned 3°, a
        board 10% off) then gives poses from the second frame on instead of none, or wrong ones. Two
        frames, not one: a stray blob taken for a marker in one frame does not agree with the next
        one's rig.

        ``failure``: this frame's fit that failed for a rig reason, or None; ``uncompensated``,
        ``compensated``: whether the frame's last fit could not, or did, compensate the right view's
        motion; ``declared_right``: the right image's time as given, s. Returns the note saying what it
        found when the refinement now starts from the rig they gave, else None."""
        refiner, c = self.refiner, self.rig_config
        if (failure is None or refiner is None or refiner.estimator.updates
                or refiner.estimator.bootstrapped_at is not None
                or not c.rig_refine.enabled or c.estimator != "reproj" or t is None):
            self._bootstrap_fits = []
            return None
        match, R, p1 = failure
        if not match.visible.all() or uncompensated or (
                declared_right is not None and abs(declared_right - t) > c.max_uncompensated_offset_s
                and not compensated):
            # A hidden marker leaves too little to tell the rig from the pose;
            # a right view that saw the head at another time, by a motion not
            # known yet, would be taken for the rig.
            self._bootstrap_fits = []
            return None
        sigma = centroid_sigma(match, c.min_centroid_sigma_px)
        self._bootstrap_fits = (self._bootstrap_fits + [(t, match.centers, match.visible, sigma, R, p1)])
        self._bootstrap_fits = self._bootstrap_fits[-_BOOTSTRAP_FRAMES:]
        if len(self._bootstrap_fits) < _BOOTSTRAP_FRAMES:
            return None
        if not refiner.bootstrap(self._bootstrap_fits, c.rig_far):
            return None
        self._bootstrap_fits = []
        self.apply(refiner.estimator.state.rig())
        return ("rig.yaml is far from the rig these images show: the rig was estimated from the "
                f"markers of this frame and the last ({refiner.describe()}); the pose carries its "
                "uncertainty")

    def restart_refiner(self) -> None:
        """After an exception inside the rig's refinement: drop the frames it was collecting, and keep
        its estimate only if it is intact (finite, a positive definite covariance); else start it over
        from rig.yaml."""
        refiner = self.refiner
        refiner.drop_pending()
        intact = False
        try:
            estimator = refiner.estimator
            P = estimator.cov()
            state = (estimator.state.R, estimator.state.T, estimator.estimate.R, estimator.estimate.T)
            intact = (all(np.isfinite(a).all() for a in state) and np.isfinite(P).all()
                      and np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0)
        except Exception:              # noqa: BLE001 -- a state that cannot even be read is not intact
            intact = False
        if not intact:
            refiner.reset()
            self.apply(refiner.estimator.state.rig())
        self._gate()

    def refine(self, match: Match, t, centre_sd: Callable, R, p1, disagrees: bool, glitch: bool,
               declared_right, motion_known: bool) -> bool:
        """Feed an accepted frame to the rig's refinement; True when the rig in use changed (then
        :attr:`refiner`'s estimator's ``refit_poses`` holds the recent poses refitted with it).

        ``centre_sd()``: each centre's 1σ per coordinate (2, 5, 2) px, asked for only when the frame is
        fed; ``glitch``: the frame's time is a repeat or a glitch; ``declared_right``: the right image's
        time as given, s; ``motion_known``: the frame's time fits the head's motion.
        """
        refiner = self.refiner
        if refiner is None:
            return False
        if disagrees:
            self._disagreements += 1
            if self._disagreements >= 3:
                # Three frames in a row agree only with the unrefined rig: it changed.
                refiner.widen(t)
                self._disagreements = 0
                self._gate()
            return False
        self._disagreements = 0
        if not self.rig_config.rig_refine.enabled or glitch:
            # A frame whose time is a repeat or a glitch would teach the
            # refinement a velocity, and an exposure offset, that are not the
            # head's. (One whose time does not fit the motion still tells the
            # rig's geometry: it goes in without a velocity, below.)
            return False
        sigma = centre_sd()
        offset = (declared_right - t) if (declared_right is not None and t is not None) else 0.0
        recent, self._declared_offsets = self._declared_offsets, (self._declared_offsets + [offset])[-16:]
        usual = sorted(recent)[len(recent) // 2] if recent else offset
        if len(recent) >= 4 and abs(offset - usual) > self.rig_config.rig_errors.offset_declared_s:
            # A declared offset off the usual one by more than its own σ: the
            # times jitter, and the refinement would take that for the rig.
            return False
        if refiner.add_frame(t, offset, match.centers, match.visible, sigma, R, p1, motion_known=motion_known):
            self.apply(refiner.estimator.state.rig())
            return True
        return False

    def forget_motion(self) -> None:
        """The frames' times did not describe the head's motion: the refinement keeps its frames'
        geometry and forgets their velocities."""
        if self.refiner is not None:
            self.refiner.forget_motion()

    def version(self) -> int:
        """The rig's version: how often the rig in use changed (0 before the refinement)."""
        return 0 if self.refiner is None else self.refiner.estimator.versions

    def status(self):
        """The refinement's status for a result (None before it starts)."""
        return None if self.refiner is None else self.refiner.status()

    def message(self, disagrees: bool = False):
        """What a person should know of the rig at this frame, or None."""
        if self.refiner is None:
            return None
        if disagrees:
            return "the images disagree with the refined rig (bumped?); tracking with the calibration's uncertainty"
        estimator = self.refiner.estimator
        if estimator.updates == 0 and not estimator.bumps:
            return None
        return self.refiner.describe()
