"""Write a scene as a contract dataset folder (see conventions.md).

::

    OUT/
      rig.yaml  markers.yaml  screen.yaml
      left/000000.png  right/000000.png  ...
      times.csv   frame,t[,t_right]      (6 decimals, s)
      truth.csv   frame,x,y,z,xi_x,...,v_z (6 decimals; P1 in mm and the
                  axes rows Ξ, Ψ, V at the left image's time t)
"""
from __future__ import annotations

import time
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
    write_rig(folder / "rig.yaml", s.image_size, s.K1, s.D1, s.K2, s.D2, s.R, s.T)
    write_markers(folder / "markers.yaml", scene.model_points_mm, scene.diameter_mm)
    write_screen(folder / "screen.yaml", s.screen_size_px, s.top_left, s.top_right, s.bottom_left)

    offset = float(scene.options.right_time_offset_s)
    n = scene.n_frames
    times_lines = ["frame,t,t_right" if offset != 0.0 else "frame,t"]
    truth_lines = [TRUTH_HEADER]

    def _write(path: Path, img: np.ndarray) -> None:
        if not cv2.imwrite(str(path), img):
            raise OSError(f"could not write {path}")

    # PNG encoding (≈ 8 ms per 640x480 image) runs in threads, overlapping the rendering
    pending: deque = deque()
    with ThreadPoolExecutor(max_workers=2) as pool:
        for k, t in enumerate(scene.times):
            t = float(t)
            options = scene.options_for(k) if hasattr(scene, "options_for") else scene.options
            left, right = render_pair(s, scene.model_points_mm, scene.diameter_mm, scene.pose_fn, t,
                                      options, frame_rng(seed, k))
            pending.append(pool.submit(_write, folder / "left" / f"{k:06d}.png", left))
            pending.append(pool.submit(_write, folder / "right" / f"{k:06d}.png", right))
            while len(pending) > 8:
                pending.popleft().result()
            if offset != 0.0:
                times_lines.append(f"{k},{t:.6f},{t + offset:.6f}")
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
    return folder


def _print_progress(prefix: str = "") -> Callable[[int, int], None]:
    t0 = time.perf_counter()

    def cb(done: int, total: int) -> None:
        if done == total or done % 10 == 0 or done == 1:
            dt = time.perf_counter() - t0
            print(f"\r{prefix}{done}/{total} frames  {dt:6.1f} s  ({1000 * dt / done:5.1f} ms/frame)",
                  end="\n" if done == total else "", flush=True)

    return cb
