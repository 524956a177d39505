"""The head's recent poses: its velocity, and its motion over the right image's exposure offset.

Frames and units (conventions.md): world = the left camera's frame, mm; a
pose is (R_world_G, p1), p1 the bridge marker in mm; velocities are ω in
rad/s (world frame, a rotation about P1) and v in mm/s (of P1).

Two webcams without a shared trigger expose the right image δ after the
left one. The tracker fits one pose at the left image's time t and lets the
right camera see the model moved by the head's motion over δ, taken from
the recent poses (:meth:`PoseHistory.right_motion`). Each pose is kept with
the version of the rig it was fitted with: poses fitted with different rigs
differ by the rig's change as well as the motion, and a refinement step of
the rig must not look like a head jump (:meth:`PoseHistory.refit` brings
them onto the new rig when it can).
"""
from __future__ import annotations

import cv2
import numpy as np


class PoseHistory:
    """The last three accepted poses, each with its rig version and first-order information.

    Parameters
    ----------
    extrapolate : bool
        Extrapolate the velocity at constant acceleration from three poses
        to the middle of [t, t_right] (else the last two poses' difference,
        half a frame old).
    """

    def __init__(self, extrapolate: bool = True):
        self.extrapolate = extrapolate
        self.clear()

    def clear(self) -> None:
        self.poses = []        # [(t s, R_world_G (3, 3), p1 (3,) mm)], oldest first
        self.rigs = []         # the rig version each pose was fitted with
        self.infos = []        # their information JᵀΣ⁻¹J (6, 6) per (rad, mm), or None

    def __len__(self) -> int:
        return len(self.poses)

    def last_time(self):
        """Time (s) of the last accepted pose, or None."""
        return self.poses[-1][0] if self.poses else None

    def add(self, t: float, R: np.ndarray, p1: np.ndarray, rig_version: int, info=None) -> None:
        """Keep an accepted pose (the oldest of four is dropped)."""
        self.poses = (self.poses + [(t, R, p1)])[-3:]
        self.rigs = (self.rigs + [rig_version])[-3:]
        self.infos = (self.infos + [info])[-3:]

    def refit(self, poses: dict, rig_version: int) -> None:
        """Replace the poses refitted with a new rig ({t: (R, p1)}) and mark them with its version."""
        for i, (t, _, _) in enumerate(self.poses):
            if t in poses:
                self.poses[i] = (t, *poses[t])
                self.rigs[i] = rig_version

    def last_pose(self, rig_version: int):
        """(R, p1) of the last pose if it was fitted with ``rig_version``, else None."""
        if self.poses and self.rigs[-1] == rig_version:
            return self.poses[-1][1:]
        return None

    def predicted(self, R: np.ndarray, p1: np.ndarray):
        """This frame's pose by constant velocity from the last two, when the last is (R, p1); else (R, p1)."""
        if len(self.poses) >= 2 and self.poses[-1][1] is R and self.rigs[-1] == self.rigs[-2]:
            (_, Ra, pa), (_, Rb, pb) = self.poses[-2:]
            return (Rb @ Ra.T) @ Rb, 2 * pb - pa
        return R, p1

    def velocity(self):
        """(ω rad/s, v mm/s) of the head from the last two poses fitted with one rig, or None."""
        pair = self._pair()
        if pair is None:
            return None
        (ta, Ra, pa), (tb, Rb, pb) = pair
        dt = tb - ta
        if not dt > 0:
            return None
        return cv2.Rodrigues(Rb @ Ra.T)[0].ravel() / dt, (pb - pa) / dt

    def right_motion(self, t, t_right, rig_version: int, current=None):
        """World-frame motion (rvec, tvec) of the head from t to t_right.

        The velocity comes from the last accepted pose and ``current`` (this
        frame's pose, R and p1) when given and both were fitted with the
        same rig, else from the last two poses fitted with one rig. With a
        third pose before them (same rig), it is extrapolated at constant
        acceleration to the middle of [t, t_right]: a difference's velocity
        is half a frame old, which at a head's turning point is most of the
        motion over a few ms.
        None when the cameras are synchronous or there is no recent history.
        """
        plan = self._plan(t, t_right, rig_version, current)
        if plan is None:
            return None
        seq, k, dz = plan
        (ta, Ra, pa), (tb, Rb, pb) = seq[-2:]
        dt = tb - ta
        w = cv2.Rodrigues(Rb @ Ra.T)[0].ravel() / dt             # rad/s, at (ta + tb) / 2
        v = (pb - pa) / dt                                         # mm/s
        if k is not None:
            _, Rz, pz = seq[0]
            w = w + (w - cv2.Rodrigues(Ra @ Rz.T)[0].ravel() / dz) * k
            v = v + (v - (pa - pz) / dz) * k
        step = t_right - t
        omega = w * step
        dR = cv2.Rodrigues(omega)[0]
        # Rotation about P1 plus P1's displacement: X → dR (X − p1) + p1 + v·δt.
        p_now = pb + (pb - pa) * ((t - tb) / dt)
        tvec = p_now - dR @ p_now + v * step
        return omega, tvec

    def motion_terms(self, t, t_right, rig_version: int, current, covariance: bool = True):
        """How the motion compensation (:meth:`right_motion` with ``current``) ties the right view to
        the poses: (gain, cov).

        The right view's model is this pose moved by the velocity, itself
        Σ α_i pose_i over the poses used (this one last), times the offset
        δ: a change of this pose moves it (1 + α δ) times as much (``gain``
        = α δ), and the earlier poses' errors move it by their α_i δ (``cov``
        (6, 6), rad and mm, from their first-order covariances), plus the
        extrapolation's own error, taken to be as large as its correction.
        (0, None) when no motion is applied; ``cov`` None without
        ``covariance`` (the fit needs only the gain).
        """
        plan = self._plan(t, t_right, rig_version, current)
        if plan is None or plan[0][-1][0] != t:
            return 0.0, None
        seq, k, dz = plan
        (ta, Ra, pa), (tb, Rb, pb) = seq[-2:]
        dt = tb - ta
        alpha = [0.0] * (len(seq) - 2) + [-1.0 / dt, 1.0 / dt]
        if k is not None:
            alpha = [k / dz, -(1 + k) / dt - k / dz, (1 + k) / dt]
        step = t_right - t
        gain = alpha[-1] * step
        if not covariance:
            return gain, None
        covs = [None if i is None else _inverse(i) for i in self.infos[len(self.poses) - (len(seq) - 1):]]
        if any(c is None for c in covs):
            return 0.0, None
        model = np.zeros((6, 6))
        if k is not None:
            _, Rz, pz = seq[0]
            correction = k * step * np.concatenate([
                cv2.Rodrigues(Rb @ Ra.T)[0].ravel() / dt - cv2.Rodrigues(Ra @ Rz.T)[0].ravel() / dz,
                (pb - pa) / dt - (pa - pz) / dz])
            model = np.outer(correction, correction)
        return gain, step ** 2 * sum(a * a * c for a, c in zip(alpha[:-1], covs)) + model

    def _plan(self, t, t_right, rig_version: int, current):
        """The poses a velocity over [t, t_right] comes from, and its extrapolation: (poses oldest first,
        k, dz) with k, dz None when it is not extrapolated; None when no motion applies (synchronous
        cameras, no two poses of one rig, or poses too old)."""
        if t is None or t_right is None or t_right == t or not self.poses:
            return None
        seq = self._sequence(t, current, rig_version)
        if seq is None:
            return None
        (ta, _, _), (tb, _, _) = seq[-2:]
        dt = tb - ta
        if dt <= 0 or t - ta > 4 * dt or (current is None and t - tb > 3 * dt):
            return None
        if len(seq) == 3 and self.extrapolate:
            dz = ta - seq[0][0]
            if 0 < dz <= 2 * dt:
                # To the middle of [t, t_right], from the two velocities' times.
                return seq, (t + 0.5 * (t_right - t) - 0.5 * (ta + tb)) / (0.5 * (tb - seq[0][0])), dz
        return seq, None, None

    def _pair(self):
        """The last two poses fitted with one rig, ((t, R, p1), (t, R, p1)), or None."""
        for i in range(len(self.poses) - 1, 0, -1):
            if self.rigs[i] == self.rigs[i - 1]:
                return self.poses[i - 1], self.poses[i]
        return None

    def _sequence(self, t, current, rig_version: int):
        """The last two or three poses (t, R, p1), oldest first, fitted with one rig, for a velocity:
        the history and ``current`` when the last pose was fitted with ``rig_version``, else the
        history alone; None if no two poses share a rig."""
        if current is not None and self.rigs[-1] == rig_version:
            poses, rigs = self.poses + [(t, *current)], self.rigs + [rig_version]
        else:
            poses, rigs = list(self.poses), list(self.rigs)
        end = next((i for i in range(len(poses) - 1, 0, -1) if rigs[i] == rigs[i - 1]), None)
        if end is None:
            return None
        start = end - 1
        if start > 0 and rigs[start - 1] == rigs[end]:
            start -= 1
        return poses[start:end + 1]


def _inverse(info: np.ndarray):
    """The inverse of an information matrix, or None if it is singular."""
    try:
        return np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
