"""Write a scene as a contract dataset folder (see docs/contract.md).

::

    OUT/
      rig.yaml  markers.yaml  screen.yaml
      left/000000.png  right/000000.png  ...
      times.csv   frame,t[,t_right]      (6 decimals, s)
      truth.csv   frame,x,y,z,xi_x,...,v_z (6 decimals; P1 in mm and the
                  axes rows Ξ, Ψ, V at the left image's time t)
      rig_truth.json  only when rig.yaml is not the rig the images were
                  rendered with (a stale calibration, unsynchronized
                  cameras): the true rig per frame range and the true
                  exposure offset, kept aside like truth.csv
      webcam_truth.json  only for scenes with ordinary webcams' faults
                  (Scene.webcam_truth, synthetic.imperfect): rolling
                  shutter, per-frame exposure offset and auto exposure,
                  dropped and repeated frames, true exposure times
      gaze_truth.csv  frame,eye_h_deg,eye_v_deg,gaze_x,gaze_y,gaze_z,
                  gaze_px_x,gaze_px_y (6 decimals): where the viewer really
                  looks at truth.csv's time, the head's V turned by the eyes
                  of the viewer model (synthetic.gaze; :func:`true_gaze`);
                  for benches only, kept aside like truth.csv

A scene's ``stamps`` (timestamps with jitter) are what ``times.csv`` lists
and what truth.csv refers to; its ``repeats`` are frames whose image pair is
an earlier frame's again (the same bytes).
"""
from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Optional, Union

import numpy as np

from .conventions import write_image, write_markers, write_rig, write_screen
from .gaze import EyeHeadSettings, flat_screen_half_extent_deg, simulate_viewer
from .render import render_pair
from .scenes import Scene

__all__ = ["write_dataset", "TRUTH_HEADER", "GAZE_TRUTH_HEADER", "frame_rng", "gaze_seed", "true_gaze",
           "TrueGaze"]

TRUTH_HEADER = "frame,x,y,z,xi_x,xi_y,xi_z,psi_x,psi_y,psi_z,v_x,v_y,v_z"
GAZE_TRUTH_HEADER = "frame,eye_h_deg,eye_v_deg,gaze_x,gaze_y,gaze_z,gaze_px_x,gaze_px_y"

#: Sampling rate of the viewer simulation behind gaze_truth.csv, Hz. A frame takes the eye's offset
#: interpolated linearly between the two samples about its time: at 1 kHz a saccade's peak (500 deg/s)
#: moves the eye 0.5 deg between samples, which the interpolation follows to well under that.
GAZE_RATE_HZ = 1000.0
#: Mixed with the dataset's seed to seed the viewer model: the eyes' stream is apart from the images' noise
#: (``frame_rng``), and the same seed gives the same eyes.
GAZE_SEED_TAG = 0x6A2E
#: A ray whose direction has less than this cosine with the screen's normal is taken as parallel to the
#: screen plane (it meets it nowhere near), dimensionless.
PARALLEL_COS = 1e-9


def frame_rng(seed: int, frame: int) -> np.random.Generator:
    """The generator used for frame ``frame`` (independent of render order)."""
    return np.random.default_rng([int(seed), int(frame)])


def write_dataset(
    folder: Union[str, Path],
    scene: Scene,
    seed: int = 0,
    progress: Optional[Callable[[int, int], None]] = None,
) -> Path:
    """Render ``scene`` into a contract dataset folder.

    Parameters
    ----------
    folder : output folder (created; existing files are overwritten).
    scene : what to render (:func:`synthetic.scenes.make_scene`).
    seed : seeds the per-frame noise and glints (frame k uses
        ``np.random.default_rng([seed, k])``).
    progress : optional ``progress(done, total)`` called after each frame.

    Returns
    -------
    Path of the folder.
    """
    folder = Path(folder)
    (folder / "left").mkdir(parents=True, exist_ok=True)
    (folder / "right").mkdir(parents=True, exist_ok=True)
    s = scene.setup
    cal = getattr(scene, "calibrated_setup", None) or s
    write_rig(folder / "rig.yaml", cal.image_size, cal.K1, cal.D1, cal.K2, cal.D2, cal.R, cal.T)
    write_markers(folder / "markers.yaml", scene.model_points_mm, scene.diameter_mm)
    write_screen(folder / "screen.yaml", s.screen_size_px, s.top_left, s.top_right, s.bottom_left)

    offset = float(scene.options.right_time_offset_s)
    n_opts = scene.n_frames if getattr(scene, "frame_options", None) is not None else 0
    offsets = {offset} | {float(scene.options_for(k).right_time_offset_s) for k in range(n_opts)}
    declared = offsets != {0.0} and getattr(scene, "declare_time_offset", True)
    n = scene.n_frames
    times_lines = ["frame,t,t_right" if declared else "frame,t"]
    setup_for = getattr(scene, "setup_for", lambda k: s)
    truth_lines = [TRUTH_HEADER]
    repeats = getattr(scene, "repeats", None) or {}
    sources = set(repeats.values())
    kept: dict = {}                 # frames whose images a later frame repeats
    stamps = getattr(scene, "stamps", None)
    stamps_right = getattr(scene, "stamps_right", None)

    # PNG encoding (≈ 8 ms per 640x480 image) runs in threads, overlapping the rendering
    pending: deque = deque()
    with ThreadPoolExecutor(max_workers=2) as pool:
        for k, t in enumerate(scene.times):
            t = float(t)
            options = scene.options_for(k) if hasattr(scene, "options_for") else scene.options
            if k in repeats:
                left, right = kept[repeats[k]]
            else:
                left, right = render_pair(setup_for(k), scene.model_points_mm, scene.diameter_mm, scene.pose_fn, t,
                                          options, frame_rng(seed, k))
            if k in sources:
                kept[k] = (left, right)
            pending.append(pool.submit(write_image, folder / "left" / f"{k:06d}.png", left))
            pending.append(pool.submit(write_image, folder / "right" / f"{k:06d}.png", right))
            while len(pending) > 8:
                pending.popleft().result()
            if stamps is not None:
                t = float(stamps[k])
            if declared:
                t_right = (float(stamps_right[k]) if stamps_right is not None
                           else t + float(options.right_time_offset_s))
                times_lines.append(f"{k},{t:.6f},{t_right:.6f}")
            else:
                times_lines.append(f"{k},{t:.6f}")
            p1, axes = scene.truth(t)
            truth_lines.append(f"{k}," + ",".join(f"{v:.6f}" for v in (*p1, *axes.ravel())))
            if progress is not None:
                progress(k + 1, n)
        while pending:
            pending.popleft().result()
    (folder / "times.csv").write_text("\n".join(times_lines) + "\n")
    (folder / "truth.csv").write_text("\n".join(truth_lines) + "\n")
    (folder / "gaze_truth.csv").write_text(_gaze_truth_text(true_gaze(scene, seed)))
    truth_rig = _rig_truth(scene, n, offset)
    if truth_rig is not None:
        (folder / "rig_truth.json").write_text(json.dumps(truth_rig, indent=1) + "\n")
    webcam = getattr(scene, "webcam_truth", None)
    if webcam is not None:
        (folder / "webcam_truth.json").write_text(json.dumps(webcam, indent=1) + "\n")
    return folder


def _rig_truth(scene: Scene, n: int, offset: float):
    """The true rig and exposure offset when rig.yaml or times.csv do not tell them, else None.

    ``segments``: [{first_frame, R (3x3), T (3,) mm, K1, K2 (3x3)}] in frame
    order (more than one when a camera was bumped during the recording);
    ``time_offset_s``: the right exposure minus the left one, s; when it
    changes from frame to frame (free-running clocks) their mean, and
    ``time_offset_s_per_frame`` each frame's.
    """
    stale = getattr(scene, "calibrated_setup", None) is not None or getattr(scene, "frame_setups", None) is not None
    undeclared = offset != 0.0 and not getattr(scene, "declare_time_offset", True)
    if not (stale or undeclared):
        return None
    segments, last = [], None
    for k in range(n):
        rig = scene.setup_for(k)
        if rig is not last:
            segments.append({"first_frame": k, "R": np.asarray(rig.R, float).tolist(),
                             "T": np.asarray(rig.T, float).reshape(3).tolist(),
                             "K1": np.asarray(rig.K1, float).tolist(), "K2": np.asarray(rig.K2, float).tolist()})
            last = rig
    out = {"segments": segments, "time_offset_s": offset}
    if getattr(scene, "frame_options", None) is not None:
        per_frame = [float(scene.options_for(k).right_time_offset_s) for k in range(n)]
        if any(v != offset for v in per_frame):
            out["time_offset_s"] = float(np.mean(per_frame))
            out["time_offset_s_per_frame"] = per_frame
    return out


# ----------------------------------------------------------------------------
# the viewer's true gaze
# ----------------------------------------------------------------------------

def gaze_seed(seed: int) -> int:
    """The viewer model's seed for a dataset rendered with ``seed`` (its own stream, deterministic)."""
    return int(np.random.SeedSequence([int(seed), GAZE_SEED_TAG]).generate_state(1)[0])


@dataclass(frozen=True)
class TrueGaze:
    """Where the viewer of a scene looks, per frame (N frames, at the times truth.csv refers to).

    t_s : (N,) s, the frame times (``Scene.stamp``).
    eye_in_head_deg : (N, 2) deg, the eyes' rotation in the head (horizontal positive to the wearer's
        right, -Ξ; vertical positive up, Ψ), from :func:`synthetic.gaze.simulate_viewer`.
    direction : (N, 3) unit vectors, world frame: the head's V turned by those angles (see :func:`true_gaze`).
    screen_px : (N, 2) screen px where the ray from P1 along ``direction`` meets the screen plane
        (possibly outside the screen); NaN where it meets the plane nowhere in front of the head.
    screen_half_deg : (2,) deg, the screen's half extents the viewer model was run with.
    """

    t_s: np.ndarray
    eye_in_head_deg: np.ndarray
    direction: np.ndarray
    screen_px: np.ndarray
    screen_half_deg: tuple


def true_gaze(scene: Scene, seed: int = 0, settings: Optional[EyeHeadSettings] = None) -> TrueGaze:
    """The viewer's true gaze at each frame of ``scene``: its head (``scene.truth``) and the model's eyes.

    The eye-in-head offsets come from :func:`synthetic.gaze.simulate_viewer` (``settings``, default
    :class:`EyeHeadSettings`; seed :func:`gaze_seed` of ``seed``) run over the frames' times at
    :data:`GAZE_RATE_HZ` from the first frame's, on a featureless screen whose half extents are the
    screen's seen from the head's median distance to its plane
    (:func:`synthetic.gaze.flat_screen_half_extent_deg`). Only the eyes of the model are used: the head is
    the scene's. The offset (h, v) turns the head's V in the head frame (rows Ξ, Ψ, V of the truth) as the
    contract's angles of a direction: ``d ∝ -tan(h) Ξ + tan(v) Ψ + V``, so that θ = -h and φ = v
    (docs/contract.md: horizontal angles are measured toward Ξ, the wearer's left).
    """
    settings = settings or EyeHeadSettings()
    s = scene.setup
    n = scene.n_frames
    stamps = getattr(scene, "stamps", None)          # what times.csv lists and truth.csv refers to
    times = np.asarray(scene.times if stamps is None else stamps, dtype=np.float64)[:n].copy()
    positions = np.empty((n, 3))
    axes = np.empty((n, 3, 3))
    for k, t in enumerate(times):
        positions[k], axes[k] = scene.truth(float(t))
    tl, tr, bl = (np.asarray(v, dtype=np.float64) for v in (s.top_left, s.top_right, s.bottom_left))
    across, down = tr - tl, bl - tl
    normal = np.cross(across, down)
    normal /= np.linalg.norm(normal)
    distance_mm = float(np.median(np.abs((positions - tl) @ normal))) if n else 600.0
    half = flat_screen_half_extent_deg(np.linalg.norm(across) / 10.0, np.linalg.norm(down) / 10.0,
                                       max(distance_mm, 1.0) / 10.0)
    half = (float(half[0]), float(half[1]))
    if n == 0:
        empty = np.empty((0, 2))
        return TrueGaze(times, empty, np.empty((0, 3)), empty, half)
    start = float(times.min())
    duration = float(times.max() - start) + 2.0 / GAZE_RATE_HZ
    trace = simulate_viewer(settings, screen_half_deg=half, duration_s=duration, rate_hz=GAZE_RATE_HZ,
                            seed=gaze_seed(seed))
    rel = times - start
    eye = np.stack([np.interp(rel, trace.t_s, trace.eye_in_head_deg[:, i]) for i in range(2)], axis=1)
    h, v = np.radians(eye[:, 0]), np.radians(eye[:, 1])
    d = -np.tan(h)[:, None] * axes[:, 0] + np.tan(v)[:, None] * axes[:, 1] + axes[:, 2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # Where each ray meets the screen plane, in screen px (docs/contract.md's pixel formula, inverted).
    px = np.full((n, 2), np.nan)
    facing = d @ normal
    reach = ((tl - positions) @ normal) / np.where(np.abs(facing) > PARALLEL_COS, facing, np.nan)
    hit = np.isfinite(reach) & (reach > 0)
    if hit.any():
        q = positions[hit] + reach[hit, None] * d[hit] - tl
        basis = np.stack([across, down], axis=1)                        # (3, 2): px fractions -> mm
        frac = np.linalg.lstsq(basis, q.T, rcond=None)[0].T           # (M, 2)
        px[hit] = frac * np.array(s.screen_size_px, dtype=np.float64)
    return TrueGaze(times, eye, d, px, half)


def _gaze_truth_text(gaze: TrueGaze) -> str:
    """gaze_truth.csv's text: :data:`GAZE_TRUTH_HEADER`, 6 decimals, empty pixel cells where the ray misses."""
    lines = [GAZE_TRUTH_HEADER]
    for k in range(len(gaze.t_s)):
        cells = [f"{x:.6f}" for x in (*gaze.eye_in_head_deg[k], *gaze.direction[k])]
        px = gaze.screen_px[k]
        cells += [f"{x:.6f}" for x in px] if np.isfinite(px).all() else ["", ""]
        lines.append(f"{k}," + ",".join(cells))
    return "\n".join(lines) + "\n"
