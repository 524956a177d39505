"""The head's recent poses: its velocity, and its motion over the right image's exposure offset.

Frames and units (docs/contract.md): world = the left camera's frame, mm; a
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

Velocities are differences of poses, so they are only as good as their time
base: a pose error (or a timestamp error) δ over a base Δt makes a velocity
error δ/Δt, and the offset's compensation multiplies it by the offset.
Two frames 1 ms apart, or with the same time, give no velocity here: each
difference spans at least :attr:`PoseHistory.min_base` (half the usual
spacing of the poses, and ``min_base_s``), and, for the motion over an
exposure offset, at least the offset itself (so the compensation moves the
right view by at most about the pose's own error), older poses being used
when the newest are closer than that; its covariance grows as (offset/Δt)²
with the base it has (:meth:`PoseHistory.motion_terms`). A velocity no head
has (beyond ``max_rate_dps`` or ``max_speed_mm_s``) says the times are not
the images' (a 1 kHz clock on 30 fps images): it is not used.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np


def pose_rates(R_a: np.ndarray, p_a: np.ndarray, R_b: np.ndarray, p_b: np.ndarray, dt: float):
    """(ω rad/s (3,), v mm/s (3,)): the head's velocity from pose a to pose b, ``dt`` s later (world frame;
    ω a rotation about P1, v of P1; the difference's, so at the middle of the two times)."""
    return cv2.Rodrigues(R_b @ R_a.T)[0].ravel() / dt, (p_b - p_a) / dt


class PoseHistory:
    """The last accepted poses, each with its rig version and first-order information.

    Parameters
    ----------
    extrapolate : bool
        Extrapolate the velocity at constant acceleration from three poses
        to the middle of [t, t_right] (else the last two poses' difference,
        half a frame old).
    min_base_s : float
        Shortest time base of a velocity, s, whatever the frame rate (see
        :attr:`min_base`).
    keep : int
        Poses kept: enough to span a minimum base twice when a few of the
        newest are closer together than that (repeated or jittered times).
    max_rate_dps, max_speed_mm_s : float
        Fastest head turn (deg/s) and P1 speed (mm/s) a velocity may show;
        beyond either, the poses and their times disagree (:meth:`rates_to`).
    """

    def __init__(self, extrapolate: bool = True, min_base_s: float = 0.004, keep: int = 8,
                 max_rate_dps: float = 1000.0, max_speed_mm_s: float = 4000.0):
        self.extrapolate = extrapolate
        self.min_base_s = float(min_base_s)
        self.keep = int(keep)
        self.max_rate = np.radians(float(max_rate_dps))
        self.max_speed = float(max_speed_mm_s)
        self.clear()

    def clear(self) -> None:
        self.poses = []        # [(t s, R_world_G (3, 3), p1 (3,) mm)], oldest first, t strictly increasing
        self.rigs = []         # the rig version each pose was fitted with
        self.infos = []        # their information JᵀΣ⁻¹J (6, 6) per (rad, mm), or None
        self._spacing = None   # median time between the kept poses, s (None with fewer than two)

    def __len__(self) -> int:
        return len(self.poses)

    def last_time(self):
        """Time (s) of the last accepted pose, or None."""
        return self.poses[-1][0] if self.poses else None

    def add(self, t: float, R: np.ndarray, p1: np.ndarray, rig_version: int, info=None) -> None:
        """Keep an accepted pose (the oldest beyond ``keep`` is dropped).

        A pose at the time of the last one replaces it (a repeated time: two
        poses at one instant have no velocity between them); one before it
        starts the history afresh (time went back: the older poses are not
        this motion's past).
        """
        if self.poses and not t > self.poses[-1][0]:
            if t == self.poses[-1][0]:
                self.poses.pop(), self.rigs.pop(), self.infos.pop()
            else:
                self.clear()
        self.poses = (self.poses + [(t, R, p1)])[-self.keep:]
        self.rigs = (self.rigs + [rig_version])[-self.keep:]
        self.infos = (self.infos + [info])[-self.keep:]
        gaps = sorted(b[0] - a[0] for a, b in zip(self.poses, self.poses[1:]))
        n = len(gaps)
        self._spacing = None if not n else 0.5 * (gaps[(n - 1) // 2] + gaps[n // 2])

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

    @property
    def max_base(self) -> float:
        """Longest time base of a velocity, s: 0.1 s, or 2.5 times the median spacing of the kept poses
        at a low frame rate. A difference over longer (the poses before a run of frames without a
        pose) is an average of a motion that has changed since, not its velocity."""
        return 0.1 if self._spacing is None else max(0.1, 2.5 * self._spacing)

    @property
    def min_base(self) -> float:
        """Shortest time base of a velocity, s: half the median spacing of the kept poses (a frame
        closer to the last than that is a repeat or a timestamp glitch, not a measure of the motion),
        and at least ``min_base_s``."""
        return self.min_base_s if self._spacing is None else max(self.min_base_s, 0.5 * self._spacing)

    def predicted(self, R: np.ndarray, p1: np.ndarray):
        """This frame's pose by constant velocity from the last two, when the last is (R, p1); else (R, p1).

        A starting point for the fit (it assumes evenly spaced frames): the
        fit, not this, decides the pose."""
        if len(self.poses) >= 2 and self.poses[-1][1] is R and self.rigs[-1] == self.rigs[-2]:
            (_, Ra, pa), (_, Rb, pb) = self.poses[-2:]
            return (Rb @ Ra.T) @ Rb, 2 * pb - pa
        return R, p1

    def rates_to(self, t: float, R: np.ndarray, p1: np.ndarray, rig_version: int):
        """(deg/s, mm/s, plausible) of the head from the kept poses (a minimum base before) to this one
        (t, R, p1), or None when no kept pose is one to compare with. Not plausible: beyond what a head
        does; the times do not describe the motion the images show."""
        if not self.poses or not t > self.poses[-1][0]:
            return None
        seq = self._sequence(t, (R, p1), rig_version, self.min_base)
        if seq is None or seq[-1][0] != t:
            return None
        rate, speed = self._rates(seq[-2], seq[-1])
        return float(np.degrees(rate)), speed, rate <= self.max_rate and speed <= self.max_speed

    @staticmethod
    def _rates(a, b):
        """Turn rate (rad/s) and P1 speed (mm/s) between two poses (t, R, p1, ...)."""
        dt = b[0] - a[0]
        # The angle from the trace: cos θ = (tr(R_b R_aᵀ) − 1) / 2 = (Σ R_b ∘ R_a − 1) / 2.
        cos = 0.5 * (float(np.vdot(b[1], a[1])) - 1.0)
        d = b[2] - a[2]
        return math.acos(min(max(cos, -1.0), 1.0)) / dt, math.sqrt(float(d @ d)) / dt

    def _plausible(self, seq) -> bool:
        """Whether the velocity of a sequence's last two poses is one a head can have."""
        rate, speed = self._rates(seq[-2], seq[-1])
        return rate <= self.max_rate and speed <= self.max_speed

    def velocity(self):
        """(ω rad/s, v mm/s) of the head from the newest two poses fitted with one rig between
        :attr:`min_base` and :attr:`max_base` apart, or None."""
        seq = self._sequence(None, None, None, self.min_base)
        if seq is None:
            return None
        (ta, Ra, pa, _), (tb, Rb, pb, _) = seq[-2:]
        dt = tb - ta
        w, v = pose_rates(Ra, pa, Rb, pb, dt)
        if math.sqrt(w @ w) > self.max_rate or math.sqrt(v @ v) > self.max_speed:
            return None
        return w, v

    def velocity_at(self, t: float, rig_version: int, current=None):
        """(ω rad/s, v mm/s, cov (6, 6) or None) of the head at time ``t``, or None.

        For a rolling shutter's rows, each exposed at its own time around
        ``t``. The velocity of the newest two poses of one rig (``current``,
        this frame's pose at ``t``, last when given), extrapolated to ``t``
        at constant acceleration when a third pose is as far before them
        (a difference's velocity is half a frame old). ``cov``: the poses'
        first-order covariances through the difference (1/Δt² each; this
        frame's own taken as the last one's), plus the extrapolation's own
        error taken as large as its correction; None when a pose used has
        none.
        """
        if t is None:
            return None
        seq = self._sequence(t, current, rig_version, self.min_base)
        if seq is None or not self._plausible(seq):
            return None
        (ta, Ra, pa, ia), (tb, Rb, pb, ib) = seq[-2:]
        dt = tb - ta
        if t - tb > 3 * dt:
            return None                          # the motion since has changed
        w, v = pose_rates(Ra, pa, Rb, pb, dt)
        correction = np.zeros(6)
        if len(seq) == 3 and self.extrapolate:
            tz, Rz, pz, _ = seq[0]
            dz = ta - tz
            if dz <= 2 * dt:
                k = (t - 0.5 * (ta + tb)) / (0.5 * (tb - tz))
                correction = k * np.concatenate([w - cv2.Rodrigues(Ra @ Rz.T)[0].ravel() / dz, v - (pa - pz) / dz])
                w, v = w + correction[:3], v + correction[3:]
        infos = [ia, ib if ib is not None else ia]
        covs = [None if i is None else _inverse(i) for i in infos]
        cov = None
        if all(c is not None for c in covs):
            cov = (covs[0] + covs[1]) / dt ** 2 + np.outer(correction, correction)
        return w, v, cov

    def right_motion(self, t, t_right, rig_version: int, current=None):
        """World-frame motion (rvec, tvec) of the head from t to t_right.

        The velocity comes from ``current`` (this frame's pose, R and p1)
        when given and fitted with the same rig as the history, else from
        the newest pose, and an earlier one of the same rig at least
        :attr:`min_base` and |t_right - t| before it. With a third pose as far before those
        (same rig), it is extrapolated at constant acceleration to the
        middle of [t, t_right]: a difference's velocity is half a frame old,
        which at a head's turning point is most of the motion over a few ms.
        None when the cameras are synchronous or there is no recent history.
        """
        plan = self._plan(t, t_right, rig_version, current)
        if plan is None:
            return None
        seq, k, dz = plan
        (ta, Ra, pa, _), (tb, Rb, pb, _) = seq[-2:]
        dt = tb - ta
        w, v = pose_rates(Ra, pa, Rb, pb, dt)                      # rad/s, mm/s at (ta + tb) / 2
        if k is not None:
            _, Rz, pz, _ = seq[0]
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
        The α_i are 1/Δt of the differences' bases: the covariance grows as
        the square of the offset over the base, which the minimum base
        bounds. (0, None) when no motion is applied; ``cov`` None without
        ``covariance`` (the fit needs only the gain).
        """
        plan = self._plan(t, t_right, rig_version, current)
        if plan is None:
            return 0.0, None
        seq, k, dz = plan
        (ta, Ra, pa, _), (tb, Rb, pb, _) = seq[-2:]
        dt = tb - ta
        alpha = [0.0] * (len(seq) - 2) + [-1.0 / dt, 1.0 / dt]
        if k is not None:
            alpha = [k / dz, -(1 + k) / dt - k / dz, (1 + k) / dt]
        step = t_right - t
        mine = current is not None and seq[-1][0] == t        # the velocity is taken from this pose too
        gain = alpha[-1] * step if mine else 0.0
        if not covariance:
            return gain, None
        earlier = seq[:-1] if mine else seq
        covs = [None if entry[3] is None else _inverse(entry[3]) for entry in earlier]
        if any(c is None for c in covs):
            return 0.0, None
        model = np.zeros((6, 6))
        if k is not None:
            _, Rz, pz, _ = seq[0]
            correction = k * step * np.concatenate([
                cv2.Rodrigues(Rb @ Ra.T)[0].ravel() / dt - cv2.Rodrigues(Ra @ Rz.T)[0].ravel() / dz,
                (pb - pa) / dt - (pa - pz) / dz])
            model = np.outer(correction, correction)
        return gain, step ** 2 * sum(a * a * c for a, c in zip(alpha[:len(covs)], covs)) + model

    def _plan(self, t, t_right, rig_version: int, current):
        """The poses a velocity over [t, t_right] comes from, and its extrapolation: (poses oldest first,
        k, dz) with k, dz None when it is not extrapolated; None when no motion applies (synchronous
        cameras, no two poses of one rig a minimum base apart, or poses too old).

        Which poses: the fit of each frame feeds the next frames' motion, so
        an error of a pose comes back through the right view of the frames
        after it, multiplied by the weights the velocity gives the earlier
        poses over the weight it gives this one. Where the right view alone
        fixes a direction (the depth, with a wide baseline), those errors
        grow from frame to frame unless that feedback is below one. With
        ``current`` and x = (t_right - t) / Δt: a right image after the left
        one (x > 0) takes the velocity from this pose and two before it,
        extrapolated (feedback ≤ 0.6 for x ≤ 1); one before it by less than
        a third of the base interpolates between the last pose and this one
        (feedback |x| / (1 + x) ≤ 0.5); one earlier still sees mostly the
        last frame's head, and a velocity from this pose would amplify that
        frame's error (2x at x = -1/2): the velocity is the last two poses'
        (feedback √|x| < 1).
        """
        if t is None or t_right is None or t_right == t or not self.poses:
            return None
        step = t_right - t
        # The offset's compensation is velocity × offset: over a base shorter
        # than the offset it would move the right view by more than the
        # poses' own errors.
        base = max(self.min_base, abs(step))
        seq = self._sequence(t, current, rig_version, base)
        if seq is None:
            return None
        extrapolate = self.extrapolate
        if current is not None and seq[-1][0] == t and step < 0:
            extrapolate = False
            if -step / (seq[-1][0] - seq[-2][0]) > 1.0 / 3.0:
                seq = self._sequence(t, None, rig_version, base)
                if seq is None:
                    return None
                current = None
        (ta, _, _, _), (tb, _, _, _) = seq[-2:]
        dt = tb - ta
        if t - ta > 4 * dt or (current is None and t - tb > 3 * dt) or not self._plausible(seq):
            return None
        if len(seq) == 3 and extrapolate:
            dz = ta - seq[0][0]
            if dz <= 2 * dt:
                # To the middle of [t, t_right], from the two velocities' times.
                return seq, (t + 0.5 * (t_right - t) - 0.5 * (ta + tb)) / (0.5 * (tb - seq[0][0])), dz
        return seq, None, None

    def _sequence(self, t, current, rig_version, base: float):
        """The poses of a velocity, oldest first, as (t, R, p1, info): the newest pose b (``current``
        at ``t`` when given and the last pose was fitted with ``rig_version``), the newest earlier pose a
        of the same rig at least ``base`` (s) and at most :attr:`max_base` before b, and the newest one z
        as far before a, if any. When the newest pose has no such partner, the one before it is tried
        as b, and so on. None if no pair qualifies."""
        poses, rigs, n = self.poses, self.rigs, len(self.poses)
        # Index n is ``current`` (a pose after the kept ones), when it is one.
        extra = current is not None and rigs[-1] == rig_version and t > poses[-1][0]
        longest = max(self.max_base, base)

        def partner(j):
            """The newest pose of j's rig between the minimum and the maximum base before pose j, or None."""
            tj, rj = (t, rig_version) if j == n else (poses[j][0], rigs[j])
            for i in range(j - 1, -1, -1):
                gap = tj - poses[i][0]
                if rigs[i] != rj or gap > longest:
                    return None
                if gap >= base:
                    return i
            return None

        b = n if extra else n - 1
        if b >= 2:
            # The usual case, regular frames of one rig: b, b - 1 and b - 2.
            tb = t if extra else poses[b][0]
            ta, tz = poses[b - 1][0], poses[b - 2][0]
            if (rigs[b - 2] == rigs[b - 1] == (rig_version if extra else rigs[b])
                    and base <= tb - ta <= longest and base <= ta - tz <= longest):
                last = (t, current[0], current[1], None) if extra else (*poses[b], self.infos[b])
                return [(*poses[b - 2], self.infos[b - 2]), (*poses[b - 1], self.infos[b - 1]), last]
        for b in range(b, 0, -1):
            a = partner(b)
            if a is not None:
                z = partner(a)
                return [(t, current[0], current[1], None) if i == n else (*poses[i], self.infos[i])
                        for i in ((z, a, b) if z is not None else (a, b))]
        return None


def _inverse(info: np.ndarray):
    """The inverse of an information matrix, or None if it is singular."""
    try:
        return np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None


class HeadMotion:
    """The head's motion as the tracker knows it: its recent poses (:class:`PoseHistory`, :attr:`history`)
    and the last pose (:attr:`prev_pose`), and whether the frames' times are suspect.

    Parameters
    ----------
    config : TrackerConfig
        ``extrapolate_velocity``, ``min_velocity_base_s``, ``max_head_rate_dps``, ``max_head_speed_mm_s``.
    """

    def __init__(self, config):
        self.motion_config = config
        self.times_suspect = False     # the last velocity checked was not a head's, none since was
        self.motion_unknown = False    # the last frame's time did not fit the motion (while times are suspect)
        self.history: PoseHistory | None = None
        self.prev_pose = None          # (R_world_G, p1) of the last pose remembered
        self.reset()

    def reset(self) -> None:
        """Forget the poses (a time discontinuity, a seek); whether the times are suspect stands."""
        c = self.motion_config
        self.history = PoseHistory(c.extrapolate_velocity, c.min_velocity_base_s,
                                   max_rate_dps=c.max_head_rate_dps, max_speed_mm_s=c.max_head_speed_mm_s)
        self.prev_pose = None

    def predicted(self):
        """This frame's pose (R, p1) by constant velocity from the last two (the last one if unknown)."""
        return self.history.predicted(*self.prev_pose)

    def set_pose(self, R: np.ndarray, p1: np.ndarray) -> None:
        """The last pose, (R_world_G (3, 3), p1 (3,) mm), whether or not its time is kept."""
        self.prev_pose = (R, p1)

    def remember(self, t, R, p1, rig_version: int, info, checked, time_glitch: bool) -> str | None:
        """Keep a pose at time ``t`` (s) fitted with rig ``rig_version`` (``info``: its JᵀJ (6, 6)), unless
        its time is a glitch (``time_glitch``: a repeat, or a step of a fraction of a period, exposed at
        an unknown time) or unknown. ``checked``: (R, p1, rates) when the fit checked
        :meth:`PoseHistory.rates_to` on this very pose, else None.

        Returns a note when the head would have moved faster than a head does since the last poses: the
        history is then cleared, and the rig's refinement must forget its frames' velocities too. Sets
        :attr:`motion_unknown`: this time does not fit the motion (the refinement must not learn a
        velocity from it)."""
        if t is None or time_glitch:
            # (A frame whose time repeats the last one's, or follows it by a
            # fraction of a period, was exposed at an unknown time: its pose
            # would put the motion at the wrong instant.)
            return None
        if checked is not None and checked[0] is R and checked[1] is p1:
            rates = checked[2]                               # the fit made this check on this very pose
        else:
            rates = self.history.rates_to(t, R, p1, rig_version)
        note = None
        if rates is not None and not rates[2]:
            # The times do not describe the motion the images show (a
            # glitching clock, frames out of order): the poses before
            # this one are no past to take a velocity from, and the rig's
            # refinement, which learns the exposure offset from velocities
            # over the frames' times, must not learn from them, nor from
            # the next frames until a velocity is plausible again.
            self.history.clear()
            self.times_suspect = True
            note = (f"the head would have turned {rates[0]:.0f}°/s and moved {rates[1]:.0f} mm/s "
                    "since the last poses by these times: not a motion a head makes; "
                    "motion state reset")
        elif rates is not None:
            self.times_suspect = False
        self.motion_unknown = self.times_suspect and (rates is None or not rates[2])
        self.history.add(t, R, p1, rig_version, info)
        return note

    def refit(self, poses: dict, rig_version: int) -> None:
        """The recent poses refitted with a new rig (version ``rig_version``): the velocity and prediction
        go on without a jump."""
        self.history.refit(poses, rig_version)
        last = self.history.last_pose(rig_version)
        if last is not None:
            self.prev_pose = last
