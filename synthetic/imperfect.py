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

What ordinary USB webcams add (any of them makes the dataset carry
``webcam_truth.json``, :func:`webcam_truth_fields`):

- ``readout_s`` (``right_readout_s``): rolling shutter, s from the first
  row's exposure to the last's (:class:`synthetic.render.RenderOptions`;
  webcams 0.015-0.033 s); the middle row is at the frame's time;
- ``jpeg_quality``: MJPEG compression of both images (webcams ≈ 60-85);
- ``clock_drift_ppm``: the right camera's clock runs this much slower
  (negative: faster) than the left one: right frame i is exposed at
  ``t0 + offset_s + i * period * (1 + ppm 1e-6)`` and each left frame is
  paired with the nearest right one, so the offset drifts (100 ppm: 0.1 ms
  a second) and wraps by a period when it passes half a period;
- ``timestamp_jitter_s``: the listed times (``t``, and ``t_right`` when
  declared) are the exposure times plus a uniform ±jitter (USB host
  timestamps, 0.5-2 ms); truth.csv refers to the listed t, the true
  exposure times are in ``webcam_truth.json``;
- ``auto_exposure``: the exposure time and gain change during the run, in
  steps ``(camera_frame, exposure_s, gain[, room])`` reached in
  ``ae_converge_frames`` frames (log-linear): a step's room factor (the room's
  IR level, what the auto exposure reacts to; default: the inverse of the
  step's change of exposure x gain, so the ambient level comes back) applies
  at once; markers (lit by the cameras' ring lights) scale with
  exposure x gain, the ambient with that times the room factor, shot noise
  with the gain (fewer electrons per DN), read noise in DN with the gain;
  motion blur follows the exposure (8 sub-exposures, one per ms beyond 8 ms);
  while the exposure is longer than the frame period, the camera delivers
  every other frame (its frame rate halved). True: a step up to 1.5x the
  exposure with gain 1.2 (markers x1.8) at 40 % of the run, and one down to
  0.625x (markers x0.625) at 75 %;
- ``drop_frames``: a fraction of the frames (``round(fraction * n)``, at
  least one from 10 frames on) or a list of camera frame numbers never
  delivered: ``times.csv`` jumps by two periods or more (frames stay
  numbered 000000.. in the folder);
- ``duplicate_frames``: a count or a list of dataset frames k ≥ 1 whose image
  pair is frame k - 1's again (the driver delivered the same buffer twice)
  under a new time; truth.csv still refers to the listed t.

Frame numbers: ``bump_frame`` and ``duplicate_frames`` count the dataset's
frames; ``drop_frames`` and auto-exposure steps count the camera's frames
(at ``t0 + k * period``, the dropped ones included).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence, Union

import cv2
import numpy as np

from .setups import Setup

__all__ = ["imperfect_rig", "ordinary_webcams", "faulty_setup", "DEFAULT_FAULT_AXIS", "ORDINARY_WEBCAMS",
           "WEBCAM_FAULTS"]

#: The faults of :func:`ordinary_webcams`: two ordinary USB webcams at realistic magnitudes.
ORDINARY_WEBCAMS = dict(
    rotation_deg=0.3, baseline_scale=1.02,              # a slightly stale rig.yaml
    offset_s=0.012, declare_offset=False, clock_drift_ppm=100.0, timestamp_jitter_s=0.001,
    readout_s=0.030, exposure_s=0.008, jpeg_quality=75, fused_glints=1,
    auto_exposure=True, drop_frames=0.01, duplicate_frames=2,
)

#: imperfect_rig's parameters that are ordinary webcams' faults (any of them: webcam_truth.json).
WEBCAM_FAULTS = ("readout_s", "right_readout_s", "jpeg_quality", "clock_drift_ppm", "timestamp_jitter_s",
                 "auto_exposure", "drop_frames", "duplicate_frames")

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
                  fused_glints: int = 0, bump_frame: Optional[int] = None, bump_deg: float = 0.0,
                  readout_s: float = 0.0, right_readout_s: Optional[float] = None,
                  jpeg_quality: Optional[int] = None, clock_drift_ppm: float = 0.0,
                  timestamp_jitter_s: float = 0.0, auto_exposure: Union[bool, Sequence] = False,
                  ae_converge_frames: int = 4, drop_frames: Union[float, Sequence[int]] = 0.0,
                  duplicate_frames: Union[int, Sequence[int]] = 0, name: Optional[str] = None):
    """A preset's head motion seen by a rig that ``rig.yaml`` describes wrongly.

    Parameters
    ----------
    n_frames, seed : as for the base preset; ``n_frames`` is the number of
        frames in the dataset (dropped frames come on top).
    base : the preset whose head motion and render options are used.
    rotation_deg, baseline_scale, focal_scale, offset_s, declare_offset,
    bump_frame, bump_deg : the faults (module docstring).
    exposure_s : exposure time for motion blur, s (8 sub-exposures); None
        keeps the base preset's.
    fused_glints : 0 or the most glints per image fused with a marker's blob
        (1..``fused_glints`` per image).
    readout_s, right_readout_s, jpeg_quality, clock_drift_ppm,
    timestamp_jitter_s, auto_exposure, ae_converge_frames, drop_frames,
    duplicate_frames : ordinary webcams' faults (module docstring; s, ppm,
        frames). Off by default; any of them on writes ``webcam_truth.json``.
    name : the scene's name (default ``imperfect_rig:BASE``).
    """
    from .scenes import PRESETS       # scenes imports this module's preset lazily

    kwargs = {"seed": seed}
    if n_frames is not None:
        kwargs["n_frames"] = int(n_frames)
    scene = PRESETS[base](**kwargs)
    webcam = dict(readout_s=readout_s, right_readout_s=right_readout_s, jpeg_quality=jpeg_quality,
                  clock_drift_ppm=clock_drift_ppm, timestamp_jitter_s=timestamp_jitter_s,
                  auto_exposure=auto_exposure, drop_frames=drop_frames, duplicate_frames=duplicate_frames)
    if any(_on(v) for v in webcam.values()):
        return _webcam_scene(PRESETS[base], kwargs, scene, base, name, seed, rotation_deg, baseline_scale,
                             focal_scale, offset_s, declare_offset, exposure_s, fused_glints, bump_frame, bump_deg,
                             ae_converge_frames, **webcam)
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
        bumped = _bumped(true, nominal, bump_deg)
        frame_setups = [true if k < bump_frame else bumped for k in range(len(scene.times))]
        changes["bump"] = f"bumped {bump_deg}° at frame {bump_frame}"
    parts = _rig_parts(rotation_deg, baseline_scale, focal_scale, offset_s, declare_offset, fused_glints)
    parts.extend(changes.values())
    return dataclasses.replace(
        scene, name=name or f"imperfect_rig:{base}", setup=true, calibrated_setup=nominal, options=options,
        declare_time_offset=bool(declare_offset), frame_setups=frame_setups,
        frame_options=None if scene.frame_options is None else [
            o.replace(right_time_offset_s=float(offset_s)) for o in scene.frame_options],
        description=f"{scene.description}; " + (", ".join(parts) or "perfect rig"))


def ordinary_webcams(n_frames: Optional[int] = None, seed: int = 0, base: str = "looking_around", **changes):
    """A preset's head motion (default ``looking_around``) seen by two ordinary USB webcams, everything at
    once at realistic magnitudes (:data:`ORDINARY_WEBCAMS`, ``changes`` override them): rolling shutter
    30 ms on both cameras, the right frames 12 ms late, undeclared, drifting 100 ppm, timestamps ±1 ms,
    8 ms exposure (motion blur), MJPEG quality 75, up to one glint fused with a marker, a slightly stale
    rig.yaml (right camera turned 0.3°, baseline 2 % long), auto exposure stepping 8 -> 12 ms (gain 1.2)
    and -> 5 ms, ≈ 1 % of the frames dropped and two delivered twice."""
    return imperfect_rig(n_frames=n_frames, seed=seed, base=base, name="ordinary_webcams",
                         **{**ORDINARY_WEBCAMS, **changes})


def _bumped(true: Setup, nominal: Setup, bump_deg: float) -> Setup:
    turn = _turn((0.1, 1.0, -0.2), bump_deg)
    return dataclasses.replace(true, R=turn @ true.R, T=turn @ np.asarray(true.T).reshape(3),
                               name=f"{nominal.name} (bumped)")


def _rig_parts(rotation_deg, baseline_scale, focal_scale, offset_s, declare_offset, fused_glints) -> list:
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
    return parts


def _on(value) -> bool:
    """Whether a webcam fault's value asks for it (a number other than 0, True, a non-empty list)."""
    if value is None or value is False:
        return False
    if isinstance(value, (list, tuple, np.ndarray)):
        return len(value) > 0
    return value != 0


def _ae_steps(auto_exposure, n: int, e0: float) -> list:
    """Auto-exposure steps [(camera_frame, exposure_s, gain, room or None)], in frame order."""
    if auto_exposure is True:
        return [(int(round(0.4 * n)), 1.5 * e0, 1.2, None), (int(round(0.75 * n)), 0.625 * e0, 1.0, None)]
    steps = []
    for step in auto_exposure or ():
        room = float(step[3]) if len(step) > 3 and step[3] is not None else None
        steps.append((int(step[0]), float(step[1]), float(step[2]), room))
        if steps[-1][1] <= 0 or steps[-1][2] <= 0:
            raise ValueError(f"auto-exposure step {tuple(step)}: the exposure and the gain must be positive")
    return sorted(steps)


def _ae_schedule(steps: list, e0: float, converge: int, m: int):
    """Per camera frame 0..m-1: exposure (s), gain and room factor; and the steps with their room factors."""
    exposure, gain, room = np.full(m, float(e0)), np.ones(m), np.ones(m)
    e_prev, g_prev, r_cum = float(e0), 1.0, 1.0
    resolved = []
    converge = max(int(converge), 1)
    for f, e, g, r in steps:
        r = (e_prev * g_prev) / (e * g) if r is None else r
        resolved.append({"camera_frame": f, "exposure_s": e, "gain": g, "room": r, "converge_frames": converge})
        for j in range(max(f, 0), m):
            a = min((j - f + 1) / converge, 1.0)
            exposure[j] = e_prev * (e / e_prev) ** a
            gain[j] = g_prev * (g / g_prev) ** a
            room[j] = r_cum * r
        e_prev, g_prev, r_cum = e, g, r_cum * r
    return exposure, gain, room, resolved


def _drop_list(drop_frames, n: int, rng: np.random.Generator) -> list:
    """Camera frames never delivered: a list as given, or round(fraction * n) (≥ 1 from 10 frames on) drawn
    among camera frames 1..n + count - 2."""
    if isinstance(drop_frames, (list, tuple, np.ndarray)):
        return sorted(int(j) for j in drop_frames)
    fraction = float(drop_frames or 0.0)
    if not 0.0 <= fraction < 0.5:
        raise ValueError(f"drop_frames: a fraction in [0, 0.5) or a list of camera frames, not {drop_frames!r}")
    count = int(round(fraction * n))
    if fraction > 0 and n >= 10:
        count = max(count, 1)
    candidates = np.arange(1, n + count - 1)
    count = min(count, candidates.size)
    return sorted(int(j) for j in rng.choice(candidates, size=count, replace=False)) if count else []


def _duplicate_list(duplicate_frames, n: int, rng: np.random.Generator) -> list:
    """Dataset frames k ≥ 1 that repeat frame k - 1's images: a list as given, or a count drawn, none adjacent."""
    if isinstance(duplicate_frames, (list, tuple, np.ndarray)):
        frames = sorted(int(k) for k in duplicate_frames)
        if any(not 1 <= k < n for k in frames):
            raise ValueError(f"duplicate_frames: frames 1..{n - 1} (frame k repeats k - 1), not {frames}")
        return frames
    count = min(int(duplicate_frames or 0), max(0, (n - 1) // 2))
    frames: list = []
    candidates = list(range(1, n))
    while len(frames) < count and candidates:
        k = int(rng.choice(candidates))
        frames.append(k)
        candidates = [c for c in candidates if abs(c - k) > 1]
    return sorted(frames)


def _webcam_scene(preset, kwargs, scene, base, name, seed, rotation_deg, baseline_scale, focal_scale, offset_s,
                  declare_offset, exposure_s, fused_glints, bump_frame, bump_deg, ae_converge_frames, *,
                  readout_s, right_readout_s, jpeg_quality, clock_drift_ppm, timestamp_jitter_s, auto_exposure,
                  drop_frames, duplicate_frames):
    """:func:`imperfect_rig` with ordinary webcams' faults (module docstring)."""
    n = scene.n_frames
    period = float(scene.times[1] - scene.times[0]) if n > 1 else 1.0 / 30.0
    t0 = float(scene.times[0])
    e0 = float(exposure_s) if exposure_s is not None else float(scene.options.exposure_s)
    if _on(auto_exposure) and e0 <= 0.0:
        e0 = 0.004                     # auto exposure needs an exposure time to change
    steps = _ae_steps(auto_exposure, n, e0) if _on(auto_exposure) else []
    jitter = float(timestamp_jitter_s)
    if not 0.0 <= jitter < 0.5 * period:
        raise ValueError(f"timestamp_jitter_s must be in [0, {0.5 * period:g}) s, not {timestamp_jitter_s!r}")
    if jpeg_quality is not None and not 1 <= int(jpeg_quality) <= 100:
        raise ValueError(f"jpeg_quality must be 1..100, not {jpeg_quality!r}")

    # which camera frames are delivered
    drops = set(_drop_list(drop_frames, n, np.random.default_rng([int(seed), 90210, 1])))
    m_max = 2 * n + len(drops) + 2
    exposure, gain, room, resolved = _ae_schedule(steps, e0, ae_converge_frames, m_max)
    cam_frames, dropped = [], []
    j = 0
    while len(cam_frames) < n:
        if j >= m_max:
            raise ValueError("too many frames dropped or slowed for the frames asked for")
        if j in drops:
            dropped.append({"camera_frame": j, "cause": "dropped"})
        elif exposure[j] > period and j % 2 == 1:
            dropped.append({"camera_frame": j, "cause": "exposure longer than the frame period: frame rate halved"})
        else:
            cam_frames.append(j)
        j += 1
    m = cam_frames[-1] + 1
    if m != n:                          # the recording runs longer than its delivered frames
        scene = preset(**{**kwargs, "n_frames": m})
    times = np.asarray(scene.times, float)
    for d in dropped:
        d["t_s"] = float(times[d["camera_frame"]])
        d["before_frame"] = sum(1 for c in cam_frames if c < d["camera_frame"])

    # the right camera's free-running clock: right frame i at offset_s + i * period * (1 + drift) after the
    # left one's first; each left frame paired with the nearest right frame
    drift = float(clock_drift_ppm) * 1e-6
    right_frame = [int(round((jj * period - offset_s) / (period * (1.0 + drift)))) for jj in range(m)]
    offsets = [float(offset_s) + (i - jj) * period + i * period * drift for jj, i in enumerate(right_frame)]

    nominal = scene.setup
    true = faulty_setup(nominal, rotation_deg, DEFAULT_FAULT_AXIS, baseline_scale, focal_scale)
    ae = bool(steps)

    def frame_options(jj: int):
        o = scene.options_for(jj).replace(right_time_offset_s=offsets[jj], readout_s=float(readout_s),
                                          right_readout_s=None if right_readout_s is None else float(right_readout_s),
                                          jpeg_quality=None if jpeg_quality is None else int(jpeg_quality))
        if fused_glints:
            o = o.replace(fused_glints=(1, int(fused_glints)), glint_peak_dn=(150.0, 450.0))
        e = float(exposure[jj]) if ae else exposure_s
        if e is not None:
            o = o.replace(exposure_s=float(e), motion_samples=max(8, math.ceil(e * 1e3 - 1e-9)) if e > 0 else 1)
        if ae:
            b, g = float(exposure[jj] * gain[jj] / e0), float(gain[jj])
            o = o.replace(brightness_scale=o.brightness_scale * b, ambient_dn=o.ambient_dn * b * float(room[jj]),
                          ambient_variation_dn=o.ambient_variation_dn * b * float(room[jj]),
                          gain_e_per_dn=None if o.gain_e_per_dn is None else o.gain_e_per_dn / g,
                          read_noise_dn=o.read_noise_dn * g)
        return o

    dups = _duplicate_list(duplicate_frames, n, np.random.default_rng([int(seed), 90210, 2]))
    repeats = {k: k - 1 for k in dups}
    content = []                        # the dataset frame whose exposure each frame's images show
    for k in range(n):
        content.append(content[k - 1] if k in repeats else k)
    per_frame = [frame_options(j) for j in cam_frames]
    t_exp = times[cam_frames]
    rng = np.random.default_rng([int(seed), 90210, 3])
    stamps = stamps_right = None
    if jitter > 0:
        stamps = t_exp + rng.uniform(-jitter, jitter, n)
        stamps_right = t_exp + np.array([offsets[j] for j in cam_frames]) + rng.uniform(-jitter, jitter, n)
    frame_setups = None
    changes = []
    if bump_frame is not None and bump_deg:
        bumped = _bumped(true, nominal, bump_deg)
        frame_setups = [true if k < bump_frame else bumped for k in range(n)]
        changes.append(f"bumped {bump_deg}° at frame {bump_frame}")

    parts = _rig_parts(rotation_deg, baseline_scale, focal_scale, offset_s, declare_offset, fused_glints)
    parts.extend(changes)
    if exposure_s is not None and not ae:
        parts.append(f"exposure {exposure_s * 1e3:g} ms")
    if readout_s or right_readout_s:
        rr = readout_s if right_readout_s is None else right_readout_s
        parts.append(f"rolling shutter {readout_s * 1e3:g} ms" + ("" if rr == readout_s else f" / right {rr * 1e3:g} ms"))
    if clock_drift_ppm:
        parts.append(f"right clock {clock_drift_ppm:+g} ppm")
    if jitter:
        parts.append(f"timestamps ±{jitter * 1e3:g} ms")
    if jpeg_quality is not None:
        parts.append(f"MJPEG quality {int(jpeg_quality)}")
    if ae:
        parts.append(f"auto exposure {e0 * 1e3:g} ms -> " + " -> ".join(
            f"{st['exposure_s'] * 1e3:g} ms x{st['gain']:g} gain at frame {st['camera_frame']}" for st in resolved))
    if dropped:
        parts.append(f"{len(dropped)} frames dropped")
    if dups:
        parts.append(f"{len(dups)} frames delivered twice")

    h = int(nominal.image_size[1])
    r_left = float(readout_s)
    r_right = r_left if right_readout_s is None else float(right_readout_s)
    src = [cam_frames[content[k]] for k in range(n)]
    truth = {
        "frame_period_s": period,
        "right_frame_period_s": period * (1.0 + drift),
        "t0_s": t0,
        "readout_s": r_left,
        "right_readout_s": r_right,
        "row_time_s": [r_left / (h - 1), r_right / (h - 1)],
        "jpeg_quality": None if jpeg_quality is None else int(jpeg_quality),
        "clock_drift_ppm": float(clock_drift_ppm),
        "time_offset_s_at_start": float(offset_s),
        "timestamp_jitter_s": jitter,
        "reference_exposure_s": e0,
        "auto_exposure_steps": resolved,
        "dropped": dropped,
        "duplicates": [{"frame": k, "repeats": k - 1} for k in dups],
        "frames": {
            "camera_frame": src,
            "right_camera_frame": [right_frame[j] for j in src],
            "t_exposure_s": [float(times[j]) for j in src],
            "right_time_offset_s": [offsets[j] for j in src],
            "t_right_exposure_s": [float(times[j]) + offsets[j] for j in src],
            "t_listed_s": [float(v) for v in (stamps if stamps is not None else t_exp)],
            "duplicate_of": [repeats.get(k) for k in range(n)],
            "exposure_s": [float(per_frame[content[k]].exposure_s) for k in range(n)],
            "gain": [float(gain[j]) if ae else 1.0 for j in src],
            "brightness": [float(exposure[j] * gain[j] / e0) if ae else 1.0 for j in src],
            "ambient": [float(exposure[j] * gain[j] / e0 * room[j]) if ae else 1.0 for j in src],
        },
    }
    if declare_offset and stamps_right is not None:
        truth["frames"]["t_right_listed_s"] = [float(v) for v in stamps_right]
    return dataclasses.replace(
        scene, name=name or f"imperfect_rig:{base}", setup=true, calibrated_setup=nominal, times=t_exp,
        options=per_frame[0], frame_options=per_frame, declare_time_offset=bool(declare_offset),
        frame_setups=frame_setups, stamps=stamps, stamps_right=stamps_right if declare_offset else None,
        repeats=repeats or None, webcam_truth=truth,
        description=f"{scene.description}; " + ", ".join(parts))
