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

A scene's ``stamps`` (timestamps with jitter) are what ``times.csv`` lists
and what truth.csv refers to; its ``repeats`` are frames whose image pair is
an earlier frame's again (the same bytes).
"""
from __future__ import annotations

import json
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Optional, Union

import cv2
import numpy as np

from .conventions import write_markers, write_rig, write_screen
from .render import render_pair
from .scenes import Scene

__all__ = ["write_dataset", "TRUTH_HEADER", "frame_rng"]

TRUTH_HEADER = "frame,x,y,z,xi_x,xi_y,xi_z,psi_x,psi_y,psi_z,v_x,v_y,v_z"


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

    def _write(path: Path, img: np.ndarray) -> None:
        if not cv2.imwrite(str(path), img):
            raise OSError(f"could not write {path}")

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
            pending.append(pool.submit(_write, folder / "left" / f"{k:06d}.png", left))
            pending.append(pool.submit(_write, folder / "right" / f"{k:06d}.png", right))
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
