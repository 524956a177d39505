"""The rig's error state: its nine parameters, the rig as estimated (:class:`RigState`), and the stereo
projections' derivatives with respect to that state (:func:`rig_jacobian_rows`).

The state is the one the rig's refinement estimates (:mod:`.rig_refine`);
every covariance of the rig in this package is over it, in its units.

Error state (9 parameters, relative to the current estimate)
--------------------------------------------------------------
``ω`` (3, rad)
    Turn of the right camera about its own centre, in its frame:
    ``R ← exp([ω]×) R``, ``T ← exp([ω]×) T``.
``τ`` (3, mm)
    Shift of the right camera's translation: ``T ← T + τ`` (a baseline
    scale is ``τ`` along ``T``).
``s`` (1)
    Log scale of the right camera's focal lengths: ``fx, fy ← e^s fx, e^s fy``.
    The left camera's focal length is the reference: together with the
    markers' size it fixes the depth scale, and a common focal scale of both
    cameras is observable only through perspective, which five markers 14 cm
    apart at 65 cm barely show.
``δt`` (1, s)
    Exposure of the right image minus that of the left one, added to what
    ``times.csv`` or the driver says (``t_right``).
``ρ`` (1, s)
    Readout time of the cameras' rolling shutter: the time from the
    exposure of an image's first row to that of its last (0: a global
    shutter; USB webcams 15-33 ms). Both cameras are taken to be the same
    model with the same readout. A frame's time (``t``, and ``t_right``)
    is the exposure of the image's MIDDLE row: row ``r`` of an image ``H``
    rows high (``rig.image_size`` is (width, height)) is exposed at
    ``t + (r − (H−1)/2) ρ/(H−1)``. Each marker centre is the model point
    moved by the head's motion over that time (the centre's measured row
    gives its time: known, and no circular dependency), so ρ is seen only
    when the head moves, through how the markers' rows spread in time
    (a time common to all of a frame's markers is a pose). Its prior
    (:func:`~.rig_priors.readout_prior`) comes from the frame period (most webcams read
    out for ~92% of it) or from the user.
"""
from __future__ import annotations

import copy
import math

import cv2
import numpy as np

from .. import io
from ..tol import tol

PARAMETERS = ("turn_x_rad", "turn_y_rad", "turn_z_rad", "shift_x_mm", "shift_y_mm", "shift_z_mm",
              "log_focal_right", "time_offset_s", "readout_s")
N_RIG = len(PARAMETERS)
_TURN, _SHIFT, _FOCAL, _OFFSET, _READOUT = slice(0, 3), slice(3, 6), 6, 7, 8
# The parameters a calibration gets more or less right (RigEstimator.error_distribution learns their error
# model's scale): the right camera's turn, shift and focal length.
_GEOMETRY = np.arange(N_RIG) < 7


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]× for v (..., 3) → (..., 3, 3)."""
    v = np.asarray(v)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


class RigState:
    """The rig as currently estimated: the right camera's R, T, focal scale, the exposure offset and readout.

    Attributes
    ----------
    R : (3, 3), T : (3,) mm
        World (left camera) → right camera.
    log_focal : float
        Log scale of the right camera's focal lengths relative to ``rig.yaml``.
    offset_s : float
        Right exposure minus left, beyond what the timestamps say, s.
    readout_s : float
        Rolling-shutter readout time of both cameras (first row to last), s.
    """

    def __init__(self, rig, readout_s: float = 0.0):
        self.calibrated = rig
        self.R = np.asarray(rig.R, np.float64).copy()
        self.T = np.asarray(rig.T, np.float64).reshape(3).copy()
        self.log_focal = 0.0
        self.offset_s = 0.0
        self.readout_s = float(readout_s)

    def apply(self, increment: np.ndarray) -> None:
        """Add an error-state increment (9,) to the estimate."""
        turn = cv2.Rodrigues(np.asarray(increment[_TURN], np.float64))[0]
        self.R = turn @ self.R
        self.R = cv2.Rodrigues(cv2.Rodrigues(self.R)[0])[0]
        self.T = turn @ self.T + increment[_SHIFT]
        self.log_focal += float(increment[_FOCAL])
        self.offset_s += float(increment[_OFFSET])
        self.readout_s += float(increment[_READOUT])

    def K2(self) -> np.ndarray:
        K = np.asarray(self.calibrated.K2, np.float64).copy()
        K[0, 0] *= math.exp(self.log_focal)
        K[1, 1] *= math.exp(self.log_focal)
        return K

    def error_from(self, other: "RigState") -> np.ndarray:
        """The error-state increment (9,) that moves ``other`` onto this estimate."""
        turn = cv2.Rodrigues(self.R @ other.R.T)[0].ravel()
        out = np.zeros(N_RIG)
        out[_TURN] = turn
        out[_SHIFT] = self.T - cv2.Rodrigues(turn)[0] @ other.T
        out[_FOCAL] = self.log_focal - other.log_focal
        out[_OFFSET] = self.offset_s - other.offset_s
        out[_READOUT] = self.readout_s - other.readout_s
        return out

    def moved(self, increment: np.ndarray) -> "RigState":
        """A copy moved by an error-state increment (9,); this estimate is left as it is."""
        out = copy.copy(self)
        out.apply(increment)
        return out

    def rig(self):
        """This estimate as a :class:`headplod.io.Rig` (intrinsics of the left camera and distortions unchanged)."""
        cal = self.calibrated
        extra = dict(cal.extra)
        extra["refined_time_offset_ms"] = round(self.offset_s * 1e3, 4)
        extra["refined_readout_ms"] = round(self.readout_s * 1e3, 4)
        if cal.path:
            extra["refined_from"] = str(cal.path)
        return io.Rig(cal.image_size, cal.K1, cal.D1, self.K2(), cal.D2, self.R, self.T, extra=extra)

    def differences(self) -> dict:
        """How the estimate differs from ``rig.yaml``: turn (deg), baseline scale, focal scale, offset (ms),
        and the rolling shutter's readout (ms)."""
        cal = self.calibrated
        turn = cv2.Rodrigues(self.R @ np.asarray(cal.R, np.float64).T)[0].ravel()
        centre = -self.R.T @ self.T
        centre_cal = -np.asarray(cal.R).T @ np.asarray(cal.T).reshape(3)
        return {"turn_deg": float(np.degrees(np.linalg.norm(turn))),
                "turn_axis": (turn / max(np.linalg.norm(turn), tol.zero)).tolist(),
                "baseline_scale": float(np.linalg.norm(self.T) / np.linalg.norm(cal.T)),
                "centre_shift_mm": float(np.linalg.norm(centre - centre_cal)),
                "focal_scale": float(math.exp(self.log_focal)),
                "offset_ms": self.offset_s * 1e3,
                "readout_ms": self.readout_s * 1e3}


def project_right(points_world: np.ndarray, R: np.ndarray, T: np.ndarray, K: np.ndarray, D: np.ndarray):
    """Right-camera projections (n, 2) px and their derivatives.

    Returns
    -------
    px : (n, 2)
    d_cam : (n, 2, 3)
        ∂px/∂X_cam (the right camera's frame, mm).
    d_logf : (n, 2)
        ∂px/∂s for a common log scale s of fx and fy.
    cam : (n, 3)
        The points in the right camera's frame, mm.
    """
    cam = points_world @ R.T + T
    px, jac = cv2.projectPoints(cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    jac = jac.reshape(-1, 2, jac.shape[1])
    d_cam = jac[:, :, 3:6]
    d_logf = jac[:, :, 6] * K[0, 0] + jac[:, :, 7] * K[1, 1]
    return px.reshape(-1, 2), d_cam, d_logf, cam


def row_fractions(rows_px: np.ndarray, image_height: int | None) -> np.ndarray:
    """Each centre's exposure relative to its frame's time, in readouts: (r − (H−1)/2) / (H−1).

    ``rows_px`` (any shape): the centres' measured rows (y), px. A
    non-finite row (a centre not seen), or no height (H ≤ 1), gives 0: the
    frame's time; a row beyond the image (no measured centre is) its edge's,
    ±0.5.
    """
    rows = np.asarray(rows_px, np.float64)
    if image_height is None or not image_height > 1:
        return np.zeros(rows.shape)
    frac = (rows - 0.5 * (image_height - 1)) / (image_height - 1)
    return np.where(np.isfinite(frac), np.clip(frac, -0.5, 0.5), 0.0)


def _stereo_terms(world: np.ndarray, motion: np.ndarray, frac: np.ndarray, right_dt, state: RigState,
                  K1: np.ndarray, D1: np.ndarray, D2: np.ndarray, left: bool = True):
    """Both cameras' projections of points seen through rolling shutters, and their derivatives.

    ``world`` (k, 3) mm: the points at the frame's time (its images' middle
    rows); ``motion`` (k, 3) mm/s: their world velocity (zeros: unknown);
    ``frac`` (2, k): each centre's row time in readouts (:func:`row_fractions`);
    ``right_dt`` (k,) or scalar, s: the right image's time minus the left's
    (declared + offset). Left camera: the points at ``frac[0] ρ``; right:
    at ``right_dt + frac[1] ρ`` (ρ = ``state.readout_s``), moved linearly.

    Returns px (2, k, 2), ∂px/∂(world point) (2, k, 2, 3), and
    ∂px/∂(rig error state) (2, k, 2, 9): the left rows' only non-zero column
    is the readout's. ``left`` False: the left camera's px and derivatives
    are left NaN, its rig rows zero (for callers that need the right's only).
    """
    k = len(world)
    readout = state.readout_s
    px = np.full((2, k, 2), np.nan)
    d_world = np.full((2, k, 2, 3), np.nan)
    J_rig = np.zeros((2, k, 2, N_RIG))
    if left:
        world_l = world + (frac[0] * readout)[:, None] * motion
        pl, jac = cv2.projectPoints(world_l.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K1, D1)
        d_left = jac.reshape(k, 2, -1)[..., 3:6]                        # the left camera's frame is the world's
        px[0], d_world[0] = pl.reshape(k, 2), d_left
        J_rig[0, :, :, _READOUT] = np.einsum("kij,kj->ki", d_left, motion) * frac[0][:, None]
    world_r = world + (right_dt + frac[1] * readout)[:, None] * motion
    pr, d_cam, d_logf, cam = project_right(world_r, state.R, state.T, state.K2(), D2)
    px[1], d_world[1] = pr, d_cam @ state.R
    J_rig[1] = _right_rig_columns(d_cam, d_logf, cam, state.R, motion, frac[1])
    return px, d_world, J_rig


def rig_jacobian_rows(R_world_G: np.ndarray, p1_mm: np.ndarray, model_mm: np.ndarray, state: RigState,
                      D2: np.ndarray, right_dt_s: float = 0.0, omega: np.ndarray | None = None,
                      velocity: np.ndarray | None = None, rows_px: np.ndarray | None = None,
                      image_height: int | None = None) -> np.ndarray:
    """∂(projected centre)/∂(rig error state) at a pose: (2, 5, 2, 9).

    ``omega`` (rad/s) and ``velocity`` (mm/s) are the head's motion in the
    world frame; without them the time offset's and the readout's columns
    are zero. ``right_dt_s``: the right image's time minus the left's (the
    declared offset plus the estimated one). ``rows_px`` (2, 5): the
    centres' measured rows (y, px; NaN for a centre not seen), with
    ``image_height`` (px; default ``state.calibrated.image_size[1]``):
    each point is moved by the head's motion over its row's time in each
    camera (:func:`_stereo_terms`, with ``state.readout_s``), and the
    readout's column is filled in both cameras. Without ``rows_px`` the
    left rows are zero and the readout's column too (no rolling shutter
    modelled), as before the readout was a parameter.
    """
    lever = model_mm @ R_world_G.T
    world = lever + p1_mm
    m = len(model_mm)
    moving = omega is not None and velocity is not None
    motion = np.cross(omega, lever) + velocity if moving else np.zeros((m, 3))
    if rows_px is not None and moving:
        if image_height is None:
            image_height = state.calibrated.image_size[1]
        frac = row_fractions(np.asarray(rows_px, np.float64).reshape(2, m), image_height)
    else:
        frac = np.zeros((2, m))
    cal = state.calibrated
    _, _, J_rig = _stereo_terms(world, motion, frac, right_dt_s, state, np.asarray(cal.K1, np.float64),
                                np.asarray(cal.D1, np.float64), D2, left=rows_px is not None and moving)
    return J_rig


def _right_rig_columns(d_cam, d_logf, cam, R_right, motion, frac=None):
    """∂(right projections)/∂(rig error state) (n, 2, 9) from :func:`project_right`'s derivatives.

    ``motion`` (n, 3), mm/s: each point's world velocity (None: the time
    offset's and readout's columns are zero); ``frac`` (n,): its row's
    time in readouts (:func:`row_fractions`; None: the readout's column is
    zero).
    """
    cols = np.zeros(d_cam.shape[:2] + (N_RIG,))
    cols[:, :, _TURN] = np.einsum("nij,njk->nik", d_cam, -_skew(cam))
    cols[:, :, _SHIFT] = d_cam
    cols[:, :, _FOCAL] = d_logf
    if motion is not None:
        speed = np.einsum("nij,jk,nk->ni", d_cam, R_right, motion)        # ∂px/∂t
        cols[:, :, _OFFSET] = speed
        if frac is not None:
            cols[:, :, _READOUT] = speed * np.asarray(frac)[:, None]
    return cols
