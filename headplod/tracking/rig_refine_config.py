"""Settings of the rig's online refinement (:class:`RigRefineConfig`, read by
:class:`~.rig_refine.RigRefiner`), each with its unit."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RigRefineConfig:
    """Settings of the online rig refinement, each with its unit.

    Attributes
    ----------
    enabled : bool
        Refine the rig from the tracked frames (``track --refine-rig``).
    chunk_frames : int
        Tracked frames per update (an update costs one small solve).
    iterations : int
        Gauss-Newton steps per update.
    cauchy_scale : float
        Residual (in units of its σ) beyond which a centre's weight falls
        (Cauchy loss): a glint or a bad frame does not pull the rig.
    min_sigma_px : float
        Floor of a centre's σ, px.
    drift_turn_deg_per_sqrt_s, drift_shift_mm_per_sqrt_s, drift_focal_per_sqrt_s,
    drift_offset_s_per_sqrt_s, drift_readout_s_per_sqrt_s : float
        Random-walk drift of the rig allowed between updates: what lets the
        estimate follow a slowly changing rig (warming cameras, a webcam's
        clock drift).
    first_at_once : bool
        Solve the first update at once, in the call that completes its
        chunk: until then the rig is only rig.yaml, and frames that only a
        refined rig can tell from a glint are withheld (one frame a run
        pays a whole solve).
    refit_velocity_change : float
        After a chunk's solve, its frames' velocities are taken again from
        the poses it refitted; when one changed by more than this (rad/s of
        the turn rate, or 100 times it in mm/s: 6°/s, 10 mm/s; above what
        a refitted pose's own noise makes), the chunk is solved again with
        them.
    observable_fraction : float
        A parameter is refined only when the chunk's information on it is at
        least this fraction of the prior's.
    inconsistency : float
        A chunk whose noise scale (the median centre's standardized χ²,
        per degree of freedom: robust to the few glints) exceeds this is
        tested for a change of the rig (a bump).
    publish_sigma : float
        The rig in use follows the refinement's estimate when they differ by
        more than this many σ of the estimate along some direction.
    bump_evidence : float
        Fall of the chunk's cost (χ², 9 dof) that re-solving with the
        widened prior must bring to accept a change of the rig.
    max_gap_frames : float
        Velocities (for the time offset) come from neighbours at most this
        many frame periods apart.
    recalibrate_turn_deg, recalibrate_scale, recalibrate_offset_s : float
        Beyond these, the status recommends recalibrating.
    synchronous : bool
        Solve a chunk in the ``add_frame`` call that completes it (offline
        use, tests) instead of over the next calls (:mod:`.rig_schedule`).
    passes_per_frame : int
        Gauss-Newton passes (each over all of a chunk's frames) of the update
        under way run per ``add_frame`` call: a chunk's update takes
        ``iterations + 1`` passes (twice that to test for a bump).
    """

    enabled: bool = True
    chunk_frames: int = 8
    iterations: int = 4
    cauchy_scale: float = 3.0
    min_sigma_px: float = 0.02
    drift_turn_deg_per_sqrt_s: float = 0.005
    drift_shift_mm_per_sqrt_s: float = 0.02
    drift_focal_per_sqrt_s: float = 1e-4
    drift_offset_s_per_sqrt_s: float = 2e-4
    drift_readout_s_per_sqrt_s: float = 1e-5
    refit_velocity_change: float = 0.1
    first_at_once: bool = True
    observable_fraction: float = 0.05
    inconsistency: float = 4.0
    publish_sigma: float = 3.0
    bump_evidence: float = 60.0
    max_gap_frames: float = 2.5
    recalibrate_turn_deg: float = 1.0
    recalibrate_scale: float = 0.03
    recalibrate_offset_s: float = 0.02
    synchronous: bool = False
    passes_per_frame: int = 2
