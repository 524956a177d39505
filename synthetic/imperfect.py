"""Rigs that are not the one their ``rig.yaml`` describes.

A person's rig drifts from its calibration: the bar gets bumped (the right
camera turns by a fraction of a degree), the calibration board was printed
at the wrong scale (the baseline comes out a few percent off), a focal length
was poorly determined, and two ordinary webcams expose milliseconds apart
without saying so. :func:`imperfect_rig` takes any preset's head motion and
renders it with a *true* rig that differs from the written one in those ways;
the dataset keeps the truth aside in ``rig_truth.json``
(:mod:`synthetic.dataset`), as it keeps the head's in ``truth.csv``.

Conventions: ``rig.yaml`` is the nominal rig of the base preset; the true
rig is derived from it, so a fault's number says what ``rig.yaml`` gets wrong:

- ``rotation_deg`` about ``rotation_axis`` (right camera frame): the true
  right camera is turned by this since calibration,
  ``R_true = Rot(axis, deg) @ R_yaml``, ``T_true = Rot(axis, deg) @ T_yaml``
  (the camera turns about its own centre);
- ``baseline_scale``: ``T_yaml = baseline_scale * T_true`` (a board printed
  ``1/baseline_scale`` times its nominal size);
- ``focal_scale``: the right camera's ``fx, fy`` in ``rig.yaml`` are this
  times the true ones;
- ``offset_s``: the right image is exposed this long after the left one;
  ``declare_offset`` False leaves ``t_right`` out of ``times.csv``;
- ``bump_frame``, ``bump_deg``: from that frame on the right camera is turned
  by a further ``bump_deg`` (a bump during the recording).
"""
from __future__ import annotations

import dataclasses
from typing import Optional

import cv2
import numpy as np

from .setups import Setup

__all__ = ["imperfect_rig", "faulty_setup", "DEFAULT_FAULT_AXIS"]

#: Axis of the default camera turn, right camera frame: mostly a pan (the
#: bar twisted), with some tilt and roll.
DEFAULT_FAULT_AXIS = (0.25, 1.0, 0.15)


def _turn(axis, deg: float) -> np.ndarray:
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    return cv2.Rodrigues(a * np.radians(deg))[0]


def faulty_setup(nominal: Setup, rotation_deg: float = 0.0, rotation_axis=DEFAULT_FAULT_AXIS,
                 baseline_scale: float = 1.0, focal_scale: float = 1.0) -> Setup:
    """The true rig behind a ``rig.yaml`` equal to ``nominal`` (see the module's conventions)."""
    turn = _turn(rotation_axis, rotation_deg)
    K2 = np.array(nominal.K2, float)
    K2[0, 0] /= focal_scale
    K2[1, 1] /= focal_scale
    return dataclasses.replace(
        nominal,
        R=turn @ np.asarray(nominal.R, float),
        T=turn @ (np.asarray(nominal.T, float).reshape(3) / baseline_scale),
        K2=K2,
        name=f"{nominal.name} (true rig)",
    )


def imperfect_rig(n_frames: Optional[int] = None, seed: int = 0, base: str = "looking_around",
                  rotation_deg: float = 0.0, baseline_scale: float = 1.0, focal_scale: float = 1.0,
                  offset_s: float = 0.0, declare_offset: bool = False, exposure_s: Optional[float] = None,
                  fused_glints: int = 0, bump_frame: Optional[int] = None, bump_deg: float = 0.0):
    """A preset's head motion seen by a rig that ``rig.yaml`` describes wrongly.

    Parameters
    ----------
    n_frames, seed : as for the base preset.
    base : the preset whose head motion and render options are used.
    rotation_deg, baseline_scale, focal_scale, offset_s, declare_offset,
    bump_frame, bump_deg : the faults (module docstring).
    exposure_s : exposure time for motion blur, s (8 sub-exposures); None
        keeps the base preset's.
    fused_glints : 0 or the most glints per image fused with a marker's blob
        (1..``fused_glints`` per image).
    """
    from .scenes import PRESETS       # scenes imports this module's preset lazily

    kwargs = {"seed": seed}
    if n_frames is not None:
        kwargs["n_frames"] = int(n_frames)
    scene = PRESETS[base](**kwargs)
    nominal = scene.setup
    true = faulty_setup(nominal, rotation_deg, DEFAULT_FAULT_AXIS, baseline_scale, focal_scale)
    changes = {}
    options = scene.options.replace(right_time_offset_s=float(offset_s))
    if exposure_s is not None:
        options = options.replace(exposure_s=float(exposure_s), motion_samples=8 if exposure_s > 0 else 1)
    if fused_glints:
        options = options.replace(fused_glints=(1, int(fused_glints)), glint_peak_dn=(150.0, 450.0))
    frame_setups = None
    if bump_frame is not None and bump_deg:
        bumped = dataclasses.replace(true, R=_turn((0.1, 1.0, -0.2), bump_deg) @ true.R,
                                     T=_turn((0.1, 1.0, -0.2), bump_deg) @ np.asarray(true.T).reshape(3),
                                     name=f"{nominal.name} (bumped)")
        frame_setups = [true if k < bump_frame else bumped for k in range(len(scene.times))]
        changes["bump"] = f"bumped {bump_deg}° at frame {bump_frame}"
    parts = []
    if rotation_deg:
        parts.append(f"right camera turned {rotation_deg}°")
    if baseline_scale != 1.0:
        parts.append(f"baseline in rig.yaml x{baseline_scale}")
    if focal_scale != 1.0:
        parts.append(f"right focal in rig.yaml x{focal_scale}")
    if offset_s:
        parts.append(f"right exposure {offset_s * 1e3:.1f} ms late ({'declared' if declare_offset else 'undeclared'})")
    if fused_glints:
        parts.append(f"up to {fused_glints} glints fused with markers")
    parts.extend(changes.values())
    return dataclasses.replace(
        scene, name=f"imperfect_rig:{base}", setup=true, calibrated_setup=nominal, options=options,
        declare_time_offset=bool(declare_offset), frame_setups=frame_setups,
        frame_options=None if scene.frame_options is None else [
            o.replace(right_time_offset_s=float(offset_s)) for o in scene.frame_options],
        description=f"{scene.description}; " + (", ".join(parts) or "perfect rig"))
