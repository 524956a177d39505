"""The tracker's rig: the one in use, its refinement fed with the tracked frames, and its bootstrap from a
``rig.yaml`` far off.

:class:`_RigInUse` is a part of :class:`~.tracker.Tracker` (a mixin): the
rig in use and what derives from it (:meth:`_RigInUse._apply_rig`: the
epipolar geometry, the cameras; :meth:`_RigInUse._rig_gate`: the checks'
tolerances widened by the rig's uncertainty), the refinement
(:class:`~.rig_refine.RigRefiner`: started at the first frame, fed every
accepted frame by :meth:`_RigInUse._refine`, widened after a bump,
restarted after an exception inside it), and the bootstrap
(:meth:`_RigInUse._bootstrap_rig`: two consecutive frames that fail
against a rig.yaml no frame has confirmed may replace it by the rig they
show).
"""
from __future__ import annotations

import traceback

import numpy as np

from . import geometry as geo
from . import rig_frames, rig_priors, rig_refine, rig_refine_config, rig_solve, rig_state
from .rig_refine import RigRefiner

# Refusals that a rig far from rig.yaml explains (see Tracker._bootstrap_rig).
_RIG_FAILURES = ("reprojection error", "the images disagree with the rig", "the rig's error moves this pose")
_BOOTSTRAP_FRAMES = 2
# The module files of the rig's refinement: an exception that passed through
# them may have damaged its state (Tracker._internal_error restarts it).
_REFINER_FILES = tuple(module.__name__.rsplit(".", 1)[-1] + ".py" for module in (
    rig_refine, rig_state, rig_priors, rig_frames, rig_solve, rig_refine_config))


def _raised_in(exc: BaseException, filenames: str | tuple[str, ...]) -> bool:
    """Whether ``exc`` passed through code of a module file named ``filenames`` (e.g. ``rig_refine.py``, or a
    tuple of such names)."""
    return any(frame.f_code.co_filename.endswith(filenames) for frame, _ in traceback.walk_tb(exc.__traceback__))


class _RigInUse:
    """The rig of :class:`~.tracker.Tracker` and its refinement (module docstring)."""

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
