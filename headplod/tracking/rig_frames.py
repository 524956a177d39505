"""The frames the rig's refinement keeps (:class:`_Frame`), the head's velocities it takes from their poses
(:func:`take_velocities`, :func:`refit_velocities`), and a chunk of them stacked for its solve
(:class:`_ChunkData`).

Poses are R_world_G (3, 3) and P1 (3,) mm in the world (left camera) frame;
velocities are the head's in that frame, rad/s and mm/s; times in s.
Velocities difference poses of one rig only (a rig's change is not motion).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .motion import pose_rates
from .rig_state import row_fractions


@dataclass
class _Frame:
    """One tracked frame as the refinement keeps it (``RigRefiner.add_frame``)."""

    t: float
    declared_offset_s: float      # t_right − t from times.csv / the driver (0 when not given)
    centers: np.ndarray           # (2, 5, 2) px
    visible: np.ndarray           # (2, 5) bool
    sigma: np.ndarray             # (2, 5, 2) px per coordinate
    R: np.ndarray                 # (3, 3) tracked R_world_G
    p1: np.ndarray                # (3,) tracked P1, mm
    omega: np.ndarray | None = None   # (3,) head angular velocity, world, rad/s
    velocity: np.ndarray | None = None  # (3,) P1 velocity, mm/s
    motion_known: bool = True     # False: its time does not fit the motion; no velocity from or across it
    rig_version: int = 0          # RigEstimator.versions of the rig its pose was fitted with (_INDEPENDENT: none)
    refit: tuple | None = None    # (version, R, p1): its pose refitted with a newer rig, by an update

    def newest(self):
        """(R, p1): the pose fitted with the newest rig known for this frame."""
        if self.refit is not None and self.refit[0] > self.rig_version:
            return self.refit[1], self.refit[2]
        return self.R, self.p1


# _Frame.rig_version of a pose that does not depend on the rig (add_frame(independent_pose=True)).
_INDEPENDENT = -1


def take_velocities(recent, chunk: list[_Frame], max_gap_frames: float) -> None:
    """Set the chunk's head velocities (:attr:`_Frame.omega`, rad/s; :attr:`_Frame.velocity`, mm/s) by
    central differences of the tracked poses (one-sided at the ends), ``recent`` the frames before it;
    neighbours more than ``max_gap_frames`` frame periods apart are not differenced.

    The poses differenced are of one rig (a change of the rig is not
    motion): a neighbour's as tracked, or as refitted by the update that
    changed the rig (:attr:`_Frame.refit`), whichever was fitted with the
    rig of the frame's own pose. A frame with no such neighbour (a lone
    frame tracked with the old rig while the update that changed it ran)
    takes its neighbours' poses as tracked all the same: a rig's step is
    a smaller error than no velocity at all, which would tell the solve
    the head stood still while the right image was exposed later.
    """
    frames = list(recent) + chunk
    times = np.array([f.t for f in frames])
    gaps = np.diff(times)
    period = float(np.median(gaps)) if len(gaps) else 0.0
    limit = max_gap_frames * period
    known = [f.motion_known for f in frames]

    def pose(f: _Frame, version: int | None):
        if version is None or f.rig_version in (version, _INDEPENDENT):
            return f.R, f.p1
        if f.refit is not None and f.refit[0] == version:
            return f.refit[1], f.refit[2]
        return None

    for i in range(len(frames) - len(chunk), len(frames)):
        if not known[i]:
            continue
        near_lo = i > 0 and known[i - 1] and 0 < times[i] - times[i - 1] <= limit
        near_hi = i + 1 < len(frames) and known[i + 1] and 0 < times[i + 1] - times[i] <= limit
        if not (near_lo or near_hi):
            continue
        f = frames[i]
        version = f.refit[0] if f.refit is not None and f.refit[0] > f.rig_version else f.rig_version
        lo = pose(frames[i - 1], version) if near_lo else None
        hi = pose(frames[i + 1], version) if near_hi else None
        if lo is None and hi is None:
            version = None                  # no neighbour of this rig: the poses as tracked
            lo = pose(frames[i - 1], None) if near_lo else None
            hi = pose(frames[i + 1], None) if near_hi else None
        a = (times[i - 1], *lo) if lo is not None else (times[i], *pose(f, version))
        b = (times[i + 1], *hi) if hi is not None else (times[i], *pose(f, version))
        f.omega, f.velocity = pose_rates(a[1], a[2], b[1], b[2], b[0] - a[0])

def refit_velocities(chunk: list[_Frame], refit: dict, max_gap_frames: float, max_change: float) -> bool:
    """The chunk's velocities as central differences of its refitted poses ({t: (R, p1)}, one rig), where a
    frame has a refitted neighbour (else its velocity stays); True when one changed by more than
    ``max_change`` (rad/s of the turn rate, or 100x that in mm/s); neighbours more than
    ``max_gap_frames`` frame periods apart are not differenced."""
    times = np.array([f.t for f in chunk])
    gaps = np.diff(times)
    if not len(gaps):
        return False
    limit = max_gap_frames * float(np.median(gaps))
    new = {}
    changed = False
    for i, f in enumerate(chunk):
        if not f.motion_known or f.omega is None or f.t not in refit:
            continue
        lo = i - 1 if (i > 0 and chunk[i - 1].motion_known and chunk[i - 1].t in refit
                       and 0 < times[i] - times[i - 1] <= limit) else i
        hi = i + 1 if (i + 1 < len(chunk) and chunk[i + 1].motion_known and chunk[i + 1].t in refit
                       and 0 < times[i + 1] - times[i] <= limit) else i
        if lo == hi:
            continue
        omega, velocity = pose_rates(*refit[chunk[lo].t], *refit[chunk[hi].t], times[hi] - times[lo])
        change = max(float(np.abs(omega - f.omega).max()), float(np.abs(velocity - f.velocity).max()) / 100.0)
        changed |= change > max_change
        new[i] = (omega, velocity)
    if changed:                  # else the velocities stay: those the solve used
        for i, (omega, velocity) in new.items():
            chunk[i].omega, chunk[i].velocity = omega, velocity
    return changed


@dataclass
class _ChunkData:
    """A chunk's frames stacked for :func:`~.rig_solve.chunk_terms` (n frames)."""

    R: np.ndarray            # (n, 3, 3) tracked R_world_G
    p1: np.ndarray           # (n, 3) mm
    centers: np.ndarray      # (n, 2, 5, 2) px
    visible: np.ndarray      # (n, 2, 5)
    sigma: np.ndarray        # (n, 2, 5, 2) px
    declared: np.ndarray     # (n,) s
    omega: np.ndarray        # (n, 3) rad/s, zero where the motion is unknown
    velocity: np.ndarray     # (n, 3) mm/s, likewise
    frac: np.ndarray         # (n, 2, 5) each centre's row time in readouts (row_fractions)

    @classmethod
    def of(cls, chunk: list[_Frame], image_height: int | None) -> "_ChunkData":
        moving = [f.omega is not None and f.velocity is not None for f in chunk]
        zero = np.zeros(3)
        centers = np.stack([f.centers for f in chunk])
        start = [f.newest() for f in chunk]              # each pose from the newest rig it is known with
        return cls(np.stack([R for R, _ in start]), np.stack([p1 for _, p1 in start]),
                   centers, np.stack([f.visible for f in chunk]),
                   np.stack([f.sigma for f in chunk]), np.array([f.declared_offset_s for f in chunk]),
                   np.stack([f.omega if k else zero for f, k in zip(chunk, moving)]),
                   np.stack([f.velocity if k else zero for f, k in zip(chunk, moving)]),
                   row_fractions(centers[..., 1], image_height))
