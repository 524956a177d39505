"""Accuracy of tracked poses against a dataset's truth.

Errors are measured as the contract defines the pose: the angle between the
reported and true viewing directions V (degrees) and the distance between the
reported and true positions of P1 (mm). A *wrong identification* is a pose
reported with V more than 5° off: worse than no pose at all.
"""
from __future__ import annotations

import numpy as np

WRONG_IDENTIFICATION_DEG = 5.0


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between unit vectors (..., 3), degrees; robust near 0 (atan2 form)."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    dot = np.einsum("...i,...i->...", a, b)
    return np.degrees(np.arctan2(cross, dot))


def pose_errors(records: list[dict], truth: dict) -> dict:
    """Per-frame errors of ok records that have truth.

    Parameters
    ----------
    records : list of pose records (dicts, docs/contract.md)
    truth : {frame: (position_mm (3,), axes (3, 3))}

    Returns
    -------
    dict with arrays ``frame``, ``v_err_deg``, ``pos_err_mm`` and the counts
    ``frames``, ``ok``.
    """
    frames, v_err, p_err = [], [], []
    for rec in records:
        if not rec.get("ok") or rec["frame"] not in truth:
            continue
        pos_true, axes_true = truth[rec["frame"]]
        frames.append(rec["frame"])
        v_err.append(float(angle_deg(np.asarray(rec["axes"][2]), np.asarray(axes_true[2]))))
        p_err.append(float(np.linalg.norm(np.asarray(rec["position"]) - pos_true)))
    return {"frame": np.array(frames, dtype=np.int64), "v_err_deg": np.array(v_err),
            "pos_err_mm": np.array(p_err), "frames": len(records),
            "ok": sum(1 for r in records if r.get("ok"))}


def summarize(records: list[dict], truth: dict | None) -> dict:
    """Accuracy summary: medians, 95th percentiles, tracked fraction, wrong identifications."""
    out = {"frames": len(records), "ok": sum(1 for r in records if r.get("ok"))}
    out["tracked_fraction"] = out["ok"] / out["frames"] if out["frames"] else 0.0
    if not truth:
        return out
    err = pose_errors(records, truth)
    v, p = err["v_err_deg"], err["pos_err_mm"]
    out["wrong_identifications"] = int(np.sum(v > WRONG_IDENTIFICATION_DEG))
    if len(v):
        out.update({
            "v_err_deg_median": float(np.median(v)),
            "v_err_deg_p95": float(np.percentile(v, 95)),
            "v_err_deg_max": float(v.max()),
            "pos_err_mm_median": float(np.median(p)),
            "pos_err_mm_p95": float(np.percentile(p, 95)),
        })
    return out


def format_summary(name: str, s: dict) -> str:
    """One human-readable line of :func:`summarize`'s output."""
    line = f"{name}: {s['ok']}/{s['frames']} frames tracked"
    if "v_err_deg_median" in s:
        line += (f"; V error median {s['v_err_deg_median']:.3f}° p95 {s['v_err_deg_p95']:.3f}°"
                 f"; position error median {s['pos_err_mm_median']:.3f} mm p95 {s['pos_err_mm_p95']:.3f} mm"
                 f"; wrong identifications {s['wrong_identifications']}")
    return line
