"""The rig's refinement in words and numbers: pure functions of the estimator's values
(:class:`~.rig_estimator.RigSummary`).

- :func:`describe`: one line for a person;
- :func:`advice`: a recommendation to recalibrate, or None;
- :func:`status`: the JSON-ready dict of the pose records.
"""
from __future__ import annotations

import numpy as np

from .rig_estimator import RigSummary
from .rig_refine_config import RigRefineConfig
from .rig_state import _FOCAL, _OFFSET, _READOUT, _TURN

__all__ = ["advice", "describe", "status"]


def _phase(summary: RigSummary) -> str:
    return "refined" if summary.converged else "refining"


def describe(summary: RigSummary, config: RigRefineConfig) -> str:
    """One line for a person: how the rig in use differs from rig.yaml and what the refinement is doing
    (turn °, baseline and focal scales, time offset and rolling shutter ms with their σ)."""
    d = summary.differences
    sd = summary.sigma
    parts = [f"rig.yaml: right camera turned ~{d['turn_deg']:.2f}°",
             f"baseline x{d['baseline_scale']:.3f}"]
    if summary.refined[_FOCAL] or abs(d["focal_scale"] - 1) > 1e-4:
        parts.append(f"right focal x{d['focal_scale']:.3f}")
    if summary.refined[_OFFSET] or abs(d["offset_ms"]) > 0.05:
        parts.append(f"time offset {d['offset_ms']:.1f} ms ±{sd[_OFFSET] * 1e3:.1f}")
    if summary.refined[_READOUT] or abs(d["readout_ms"]) > 0.05:
        # (A readout is never negative; an estimate below 0 is a global shutter seen through noise.)
        parts.append(f"rolling shutter {max(d['readout_ms'], 0.0):.1f} ms ±{sd[_READOUT] * 1e3:.1f}")
    state = _phase(summary)
    if summary.bumps:
        state += f", rig changed at t={summary.bumps[-1]:.1f} s"
    recommendation = advice(summary, config)
    return ", ".join(parts) + f"; {state}" + (f"; {recommendation}" if recommendation else "")


def advice(summary: RigSummary, config: RigRefineConfig) -> str | None:
    """A recommendation to recalibrate (beyond config ``recalibrate_*``), and what the refinement cannot
    fix, or None."""
    d = summary.differences
    reasons = []
    if d["turn_deg"] > config.recalibrate_turn_deg:
        reasons.append(f"the right camera is turned {d['turn_deg']:.1f}°")
    if abs(d["baseline_scale"] - 1) > config.recalibrate_scale:
        reasons.append(f"the baseline is {d['baseline_scale']:.3f}x rig.yaml's (check the board's square size)")
    if abs(d["offset_ms"]) * 1e-3 > config.recalibrate_offset_s:
        reasons.append(f"the cameras expose {d['offset_ms']:.0f} ms apart (fast motion will blur depth)")
    if not reasons:
        return None
    return ("recalibrate: " + "; ".join(reasons)
            + " (refined online, but distortion and the left camera are taken from rig.yaml as they are)")


def status(summary: RigSummary) -> dict:
    """JSON-ready state for the pose records: differences from rig.yaml (°, scales, ms) with their σ,
    ``state`` (refined / refining), the counts of updates and bumps."""
    d = summary.differences
    sd = summary.sigma
    return {"turn_deg": round(d["turn_deg"], 4), "baseline_scale": round(d["baseline_scale"], 5),
            "focal_scale": round(d["focal_scale"], 5), "offset_ms": round(d["offset_ms"], 3),
            "turn_sd_deg": round(float(np.degrees(sd[_TURN].max())), 4),
            "offset_sd_ms": round(float(sd[_OFFSET] * 1e3), 3),
            "readout_ms": round(d["readout_ms"], 3), "readout_sd_ms": round(float(sd[_READOUT] * 1e3), 3),
            "state": _phase(summary), "updates": summary.updates,
            "bumps": len(summary.bumps)}
