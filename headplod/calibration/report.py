"""The calibration report a person reads: RMS, baseline, convergence, the calibration's own σ, rejections."""

from __future__ import annotations

import numpy as np

from ..angles import angle_between_deg


def _size_str(size) -> str:
    return f"{size[0]}x{size[1]}"


def _convergence_deg(R: np.ndarray) -> float:
    """Angle between the two optical axes, degrees."""
    z_right_in_left = R.T @ np.array([0.0, 0.0, 1.0])
    return float(angle_between_deg(z_right_in_left, (0.0, 0.0, 1.0)))


def _std_line(result) -> str:
    """One line with the 1-sigma values written to rig.yaml as the tracker's prior."""
    def vec(v) -> str:
        return "n/a" if v is None else " ".join(f"{float(x):.3g}" for x in np.ravel(v))

    parts = []
    for side in ("left", "right"):
        sd = result.std_px.get(side)
        parts.append(f"{side} fx fy cx cy {vec(None if not sd else [sd[k] for k in ('fx', 'fy', 'cx', 'cy')])} px")
    parts.append(f"rotation vector {vec(result.std_rotation_deg)} deg")
    parts.append(f"T {vec(result.std_translation_mm)} mm")
    return "calibration 1-sigma (written to rig.yaml): " + "; ".join(parts)


def format_report(result) -> str:
    """A human-readable summary of a :class:`~headplod.calibration.calibrate.CalibrationResult`, for the command line."""
    rig = result.rig
    lines = [f"board: {result.spec.describe()}",
             f"pairs: {len(result.used)} used, {len(result.rejected)} rejected"]
    for name, reason in result.rejected:
        lines.append(f"  rejected {name}: {reason}")
    lines.append(f"image size: {_size_str(rig.image_size)} px")
    for side, K, D in (("left", rig.K1, rig.D1), ("right", rig.K2, rig.D2)):
        sd = result.std_px.get(side, {})
        lines.append(
            f"{side:5s} camera: fx {K[0, 0]:.1f} ± {sd.get('fx', float('nan')):.1f}, "
            f"fy {K[1, 1]:.1f} ± {sd.get('fy', float('nan')):.1f}, "
            f"cx {K[0, 2]:.1f} ± {sd.get('cx', float('nan')):.1f}, "
            f"cy {K[1, 2]:.1f} ± {sd.get('cy', float('nan')):.1f} px; "
            f"distortion {' '.join(f'{v:+.4f}' for v in D)}")
    c = rig.right_center_mm
    lines.append(f"baseline: {rig.baseline_mm:.1f} mm; right camera at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) mm "
                 f"in the left camera's frame; optical axes converge by {_convergence_deg(rig.R):.1f} deg")
    lines.append(f"reprojection RMS: left {result.rms_left_px:.3f} px, right {result.rms_right_px:.3f} px, "
                 f"stereo {result.rms_stereo_px:.3f} px (single-camera calibrations: "
                 f"{result.rms_zhang_px[0]:.3f}, {result.rms_zhang_px[1]:.3f} px)")
    lines.append(_std_line(result))
    worst = sorted(result.pair_errors_px.items(), key=lambda kv: -max(kv[1]))[:3]
    if worst:
        lines.append("worst pairs: " + ", ".join(f"{n} ({max(e):.2f} px)" for n, e in worst))
    if result.rms_stereo_px > 1.0:
        lines.append("WARNING: stereo RMS over 1 px: check the board's square size, that it is flat, and "
                     "that the two images of a pair were taken at the same moment")
    elif result.rms_stereo_px > 0.5:
        lines.append("note: stereo RMS over 0.5 px; a sharp, flat board usually gives 0.1-0.4 px")
    if result.coverage:
        lines.append("coverage: the poses could be better:")
        lines += [f"  {m}" for m in result.coverage]
    return "\n".join(lines)
