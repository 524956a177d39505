"""The checks of the rig file in ``headplod doctor``: ``rig``, ``rig age``, ``rig RMS``, ``rig cameras``.

:func:`check_rig` takes the run's :class:`~.checks.Survey` and returns those four lines (a list of
:class:`~.machine.Result`); :func:`calibration_time` reads a rig's ``calibration_date``.
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

from ..capture import usb
from .checks import Survey
from .machine import FAIL, OK, SKIP, WARN, Result, guard

__all__ = ["check_rig", "calibration_time"]


def check_rig(sv: Survey) -> list[Result]:
    names = ("rig", "rig age", "rig RMS", "rig cameras")
    path, origin = sv.rig_location()
    if path is None:
        if sv.auto:
            return [Result(FAIL, "rig", "v4l2:auto finds the cameras the rig names, and no rig is given",
                           f"headplod doctor --source {sv.source} --calib rig.yaml")] + \
                [Result(SKIP, n, "no rig") for n in names[1:]]
        why = "no --calib, no calib in a config file and no rig.yaml in the current folder"
        return [Result(SKIP, n, why) for n in names]
    rig = sv.rig()
    if rig is None:
        missing = not Path(path).exists()
        found = f"{path} (from {origin}): " + ("no such file" if missing else sv.rig_error)
        fix = sv.calibrate_fix() if missing else f"fix the file, or recalibrate: {sv.calibrate_fix()}"
        return [Result(FAIL, "rig", found, fix)] + [Result(SKIP, n, "the rig cannot be read") for n in names[1:]]
    w, h = rig.image_size
    out = [Result(OK, "rig", f"{path} (from {origin}): {w}x{h} px, baseline {rig.baseline_mm:.0f} mm")]
    for check in (_rig_age, _rig_rms, _rig_cameras):
        out.append(guard(names[len(out)], check, sv, rig, path)[0])
    return out


def calibration_time(rig) -> float | None:
    """``calibration_date`` of the rig (ISO 8601; UTC when no zone is given), s since the epoch, or None."""
    value = rig.extra.get("calibration_date")
    if not isinstance(value, str) or not value.strip():
        return None
    when = _dt.datetime.fromisoformat(value.strip().replace("Z", "+00:00"))
    if when.tzinfo is None:
        when = when.replace(tzinfo=_dt.timezone.utc)
    return when.timestamp()


def _rig_age(sv: Survey, rig, path) -> list[Result]:
    stamp = calibration_time(rig)
    origin = "its calibration_date"
    if stamp is None:
        stamp, origin = sv.m.file_mtime(path), "the file's modification time"
    days = (sv.m.clock() - stamp) / 86400.0
    when = _dt.datetime.fromtimestamp(stamp, _dt.timezone.utc).strftime("%Y-%m-%d")
    found = f"dated {when}, {days:.0f} days ago (from {origin})"
    if days < -1:
        return [Result(WARN, "rig age", f"dated {when}, in the future (from {origin}): is the clock right?",
                       "date; timedatectl status")]
    if days > sv.s.rig_max_age_days:
        return [Result(WARN, "rig age", f"{found}, older than {sv.s.rig_max_age_days:g} days: cameras get bumped",
                       f"if 'rig cameras' or tracking looks off, recalibrate: {sv.calibrate_fix()}")]
    return [Result(OK, "rig age", found)]


def _rig_rms(sv: Survey, rig, path) -> list[Result]:
    values = {k: rig.extra.get(f"calibration_rms_{k}_px") for k in ("stereo", "left", "right")}
    values = {k: float(v) for k, v in values.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
    if "stereo" not in values:
        return [Result(WARN, "rig RMS", "rig.yaml records no calibration_rms_stereo_px (not written by "
                                        "'headplod calibrate'): its accuracy is unknown",
                       sv.calibrate_fix())]
    rms = values["stereo"]
    sides = ", ".join(f"{k} {values[k]:.2f}" for k in ("left", "right") if k in values)
    found = f"stereo reprojection RMS {rms:.2f} px" + (f" ({sides})" if sides else "")
    if rms > sv.s.rms_fail_px:
        return [Result(FAIL, "rig RMS", f"{found}, above {sv.s.rms_fail_px:g} px",
                       f"recalibrate with more, sharper pairs: {sv.calibrate_fix()}")]
    if rms > sv.s.rms_warn_px:
        return [Result(WARN, "rig RMS", f"{found}, above {sv.s.rms_warn_px:g} px",
                       f"recalibrate with more, sharper pairs: {sv.calibrate_fix()}")]
    return [Result(OK, "rig RMS", f"{found}, at most {sv.s.rms_warn_px:g} px")]


def _rig_cameras(sv: Survey, rig, path) -> list[Result]:
    name = "rig cameras"
    store = f"headplod cameras --store --source v4l2:LEFT,RIGHT --rig {path}"
    if not sv.capture:
        return [Result(FAIL if sv.auto else SKIP, name, "no camera connected to compare with the rig's")]
    if usb.LEFT_KEY not in rig.extra or usb.RIGHT_KEY not in rig.extra:
        return [Result(FAIL if sv.auto else WARN, name,
                       f"the rig names no cameras ({usb.LEFT_KEY}, {usb.RIGHT_KEY}): v4l2:auto cannot find them",
                       store)]
    try:
        left, right = usb.resolve_rig_cameras(rig, sv.usb_cameras())
    except LookupError as exc:
        return [Result(FAIL if sv.auto else WARN, name, f"not the connected cameras: {exc}",
                       "plug the calibrated cameras into the sockets they had; if these are other cameras, "
                       f"recalibrate: {sv.calibrate_fix()}, then {store}")]
    except ValueError as exc:
        return [Result(FAIL, name, f"the rig's camera identities are malformed: {exc}", store)]
    found = f"left {left}, right {right} (by USB identity{sv.cams_note})"
    if sv.named is not None and [left, right] != sv.named:
        return [Result(WARN, name, f"{found}, but --source names {sv.named[0]}, {sv.named[1]}",
                       f"headplod track --source v4l2:auto --calib {path} (or --source v4l2:{left},{right})")]
    return [Result(OK, name, found)]
