"""The pose source that ``headplod demo``'s options ask for, shared by the window and the headless run.

:func:`make_poses` turns the parsed options (``--source``, ``--calib``,
``--mouse``, ``--dropout``, ``--headless``, ``--frames``) into one of the pose
sources of :mod:`headplod.demo.loop`; :func:`scripted_path` is the headless
run's mouse path.
"""
from __future__ import annotations

import time

import numpy as np

from . import loop as lp

__all__ = ["make_poses", "scripted_path"]


def scripted_path(screen, frames: int, fps: float = 30.0):
    """A POI path (callable(k, t) -> screen px): a slow Lissajous (≤ ~35°/s) with one saccade halfway.

    At frame ``frames // 2`` the POI jumps by 40% of the screen width over
    two frames (several hundred deg/s): the saccade rule keeps the levels.
    """
    w, h = screen.size_px
    jump = frames // 2

    def path(k, t):
        x = 0.5 * w + 0.3 * w * np.sin(2 * np.pi * t / 5.0)
        y = 0.5 * h + 0.3 * h * np.sin(4 * np.pi * t / 5.0 + 0.7)
        x += 0.4 * w * np.clip((k - jump + 2) / 2.0, 0.0, 1.0) - 0.2 * w
        return np.array([x, y])
    return path


def make_poses(args, screen=None, frames: int | None = None) -> lp.PoseSource:
    """The pose source the options ask for (a fresh one per run)."""
    if args.mouse:
        screen = screen or lp.default_screen()
        n = frames or args.frames
        poses = lp.MousePoses(screen, path=scripted_path(screen, n) if args.headless else None,
                              clock=None if args.headless else time.monotonic)
        if args.headless:
            poses = _Limit(poses, n)
    else:
        live = args.source.lower().startswith("v4l2")
        options = {} if args.headless or live else {"realtime": True}
        if getattr(args, "calib", None):
            options["rig"] = args.calib
        elif live:
            raise ValueError("--source v4l2:... needs --calib rig.yaml (the calibration of these cameras)")
        poses = lp.TrackerPoses(args.source, screen=screen, loop=not args.headless, max_frames=frames,
                                **options)
    if args.dropout is not None:
        poses = lp.DropoutPoses(poses, args.dropout)
    if not args.mouse:
        poses = lp.PrefetchPoses(poses)       # tracking on its own thread, as a live tracker runs
    return poses


class _Limit(lp.PoseSource):
    """At most ``n`` poses of another source."""

    def __init__(self, inner, n):
        self.inner, self.n, self.count = inner, n, 0
        self.screen, self.name = inner.screen, inner.name

    def read(self):
        if self.count >= self.n:
            return None
        self.count += 1
        return self.inner.read()

    def close(self):
        self.inner.close()
