"""The demo's pose sources: where each frame's head pose comes from, and the pose held while tracking is lost.

- :class:`TrackerPoses`: the real tracker on a frame source (live cameras, a
  recording, or the built-in synthetic sequence);
- :class:`MousePoses`: no tracker, the POI follows the mouse or a scripted path;
- :class:`ReplayPoses`, :class:`TeePoses` (one source read by several loops),
  :class:`PrefetchPoses` (tracking on a thread), :class:`DropoutPoses`
  (a simulated tracking failure);
- :class:`PoseHold`: a frame without a pose keeps the last good one and grows
  its covariance.

Frames and units: the world frame is the left camera's, mm; the POI is in
screen px; covariances of (φ, θ) of V in deg²; times in s.
"""
from __future__ import annotations

import abc
import dataclasses
import queue
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..capture import open_source
from ..render.still import default_head

#: Growth of the covariance's diagonal while tracking is lost, deg²/s (σ reaches 2° after 1 s).
GROWTH_DEG2_PER_S = 4.0
#: Cap of each diagonal term of a grown covariance, deg² (σ 20°).
MAX_HELD_VAR_DEG2 = 400.0




@dataclass
class Pose:
    """One frame's head pose, as the viewer uses it.

    Attributes
    ----------
    t : float
        Time, s.
    ok : bool
        A pose was measured in this frame.
    eye_mm : (3,) float64 or None
        Head position P1, world frame, mm (the eye of the projection).
    poi_px : (2,) float64 or None
        Point of interest, screen pixels.
    cov_deg2 : (2, 2) float64 or None
        Covariance of (φ, θ) of V, deg².
    reason : str or None
        Why there is no pose (``ok`` false).
    images : tuple of two (H, W) uint8, or None
        The left and right camera images (tracker sources).
    markers_px : (2, 5, 2) float64 or None
        Identified marker centres in the left and right images, NaN where not found.
    timings_ms : dict
        Time spent getting the pose, ms, by stage (``capture``, ``track``).
    held : bool
        Set by :class:`PoseHold`: eye, POI and covariance are the last good
        pose's, the covariance grown.
    lost_s : float
        How long tracking has been lost, s (``held`` poses).
    """

    t: float
    ok: bool
    eye_mm: np.ndarray | None = None
    poi_px: np.ndarray | None = None
    cov_deg2: np.ndarray | None = None
    reason: str | None = None
    images: tuple | None = None
    markers_px: np.ndarray | None = None
    timings_ms: dict = field(default_factory=dict)
    held: bool = False
    lost_s: float = 0.0


class PoseSource(abc.ABC):
    """Where the viewer's poses come from: one small interface for tracker, recording and mouse.

    Attributes
    ----------
    name : str
    screen : headplod.io.Screen
        The display the POI is measured on (and the terrain is rendered to).
    """

    name = "poses"
    screen = None

    @abc.abstractmethod
    def read(self) -> Pose | None:
        """The next pose (``ok`` false with a reason when none was measured), or None at the end."""

    def close(self) -> None:
        """Release cameras or files; idempotent."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def default_screen():
    """The embedded 24-inch screen (``calib/screen.yaml``)."""
    return io.read_screen(DEFAULT_SCREEN)


class TrackerPoses(PoseSource):
    """Poses from the real tracker on a frame source (live cameras, a recording, the synthetic sequence).

    The frames are read and tracked by :func:`headplod.live.loop.track_frames`,
    the loop ``headplod track`` and the benchmarks use, with its error policy:
    a frame with an ``error`` (a stalled camera, an unreadable image) gives a
    pose with ``ok`` false and that error as the reason, and resets the
    tracker.

    Parameters
    ----------
    source : FrameSource or str
        A frame source, or a spec for :func:`headplod.capture.open_source`
        (``"synthetic"``, a dataset folder, ``"v4l2:/dev/video0,/dev/video2"``).
    screen : headplod.io.Screen, optional
        Default: the source's ``screen.yaml``, else the embedded screen.
    config : TrackerConfig, optional
    loop : bool
        Replay: start again at the end (a spec string only), with times
        continuing, so a window can run forever on a recording.
    max_frames : int, optional
        End after this many frames.
    **open_options
        Passed to ``open_source`` (e.g. ``realtime=True``).
    """

    def __init__(self, source, screen=None, config=None, loop: bool = False, max_frames: int | None = None,
                 **open_options):
        # Imported on use: they pull in scipy.stats (~0.5 s), and headplod/cli.py imports this module at every start.
        from ..live.loop import FrameTimes, make_tracker, track_frames
        from ..tracking.tracker import TrackerConfig

        self._spec = source if isinstance(source, str) else None
        self._open_options = open_options
        self.source = open_source(source, **open_options) if isinstance(source, str) else source
        if self.source.rig is None:
            raise ValueError(f"{self.source.name}: the source has no rig calibration (rig.yaml); "
                             "the tracker needs one")
        self.name = f"tracker on {self.source.name}"
        self.screen = screen or self.source.screen or default_screen()
        self.tracker = make_tracker(self.source, config or TrackerConfig())
        self.loop = loop and self._spec is not None
        self.count = 0
        self._t_offset = 0.0
        self._last_t = None
        self._period = 1 / 30
        self._times = FrameTimes()
        self._tracked = track_frames(self._frames(), self.tracker, max_frames=max_frames, times=self._times)

    def _frames(self):
        """The source's frames on the pose clock: replayed again at the end when looping, times continuing.

        A frame is yielded with ``t`` (and ``t_right``) moved by the time
        offset of the current replay; a frame without a time gets one from
        the measured frame period.
        """
        while True:
            frame = self.source.read()
            if frame is None and self.loop:
                self.source.close()
                self.source = open_source(self._spec, **self._open_options)
                self.tracker.reset()
                self._t_offset = (self._last_t or 0.0) + self._period
                frame = self.source.read()
            if frame is None:
                return
            self.count += 1
            t_frame = frame.t if frame.t is not None else (self.count - 1) * self._period
            t = self._t_offset + t_frame
            if self._last_t is not None and t > self._last_t:
                self._period = 0.9 * self._period + 0.1 * min(t - self._last_t, 1.0)
            self._last_t = t
            t_right = None if frame.t_right is None else self._t_offset + frame.t_right
            yield dataclasses.replace(frame, t=t, t_right=t_right)

    def read(self) -> Pose | None:
        item = next(self._tracked, None)
        if item is None:
            return None
        frame, result = item
        t, times = frame.t, self._times
        timings = {"capture": times.read_s * 1e3}
        if result is None:
            return Pose(t, False, reason=frame.error, timings_ms=timings)
        timings["track"] = times.track_s * 1e3
        images = (frame.left, frame.right)
        markers = np.asarray(result.centers_px, dtype=np.float64)
        if not result.ok:
            return Pose(t, False, reason=result.reason, images=images, markers_px=markers, timings_ms=timings)
        poi = self.screen.intersect_ray(result.position_mm, result.axes[2])
        if poi is None:
            return Pose(t, False, reason="the viewing direction misses the screen plane", images=images,
                        markers_px=markers, timings_ms=timings)
        cov = None if result.cov_deg2 is None else np.asarray(result.cov_deg2, dtype=np.float64)
        return Pose(t, True, np.asarray(result.position_mm, dtype=np.float64), np.asarray(poi, dtype=np.float64),
                    cov, images=images, markers_px=markers, timings_ms=timings)

    def close(self) -> None:
        self.source.close()


class MousePoses(PoseSource):
    """The POI from the mouse (window) or a scripted path (headless); the eye is fixed.

    Parameters
    ----------
    screen : headplod.io.Screen, optional
        Default: the embedded screen.
    path : callable(k, t) -> (2,) screen px, or (N, 2) array, optional
        Scripted POI per frame k (an array ends after N frames). None: the
        POI is what :meth:`set_poi` last set (the screen centre at first).
    eye_mm : (3,), optional
        Eye position, world mm (default: 600 mm in front of the screen centre).
    cov_deg2 : (2, 2) or None
        Covariance reported with every pose, deg². The default, σ = 0.5°, is
        a nominal gaze uncertainty so the scenarios differ on screen (the
        tracker's own σ of V at 60 cm is ~0.05°).
    fps : float
        Frame rate of the scripted times (t = k / fps).
    clock : callable() -> float, optional
        Real time for interactive use (the saccade rule needs true speeds).
    """

    name = "mouse"

    def __init__(self, screen=None, path=None, eye_mm=None, cov_deg2=np.diag([0.25, 0.25]), fps: float = 30.0,
                 clock: Callable[[], float] | None = None):
        self.screen = screen or default_screen()
        self.eye_mm = default_head(self.screen) if eye_mm is None else np.asarray(eye_mm, dtype=np.float64)
        self.path = path if (path is None or callable(path)) else np.asarray(path, dtype=np.float64)
        if isinstance(self.path, np.ndarray) and (self.path.ndim != 2 or self.path.shape[1] != 2):
            raise ValueError(f"MousePoses: path must be (N, 2) screen px, got shape {self.path.shape}")
        self.cov_deg2 = None if cov_deg2 is None else np.asarray(cov_deg2, dtype=np.float64)
        self.fps = float(fps)
        self.clock = clock
        self.poi_px = np.array(self.screen.size_px, dtype=np.float64) / 2
        self.count = 0
        self.name = "mouse" if path is None else "scripted POI"

    def set_poi(self, poi_px) -> None:
        """Move the POI (screen px), e.g. from the mouse."""
        self.poi_px = np.asarray(poi_px, dtype=np.float64).reshape(2)

    def read(self) -> Pose | None:
        k = self.count
        if isinstance(self.path, np.ndarray):
            if k >= len(self.path):
                return None
            self.poi_px = self.path[k]
        t = self.clock() if self.clock is not None else k / self.fps
        if callable(self.path):
            self.poi_px = np.asarray(self.path(k, t), dtype=np.float64).reshape(2)
        self.count += 1
        return Pose(t, True, self.eye_mm.copy(), self.poi_px.copy(),
                    None if self.cov_deg2 is None else self.cov_deg2.copy())


class TeePoses:
    """One pose source read once for several consumers, each of which gets every pose in order.

    The headless demo runs its scenarios and ``full`` interleaved, one frame
    of each in turn, from one tracked sequence: every run sees the same
    poses, the tracking is done once, and a drift of the machine's speed
    during the run affects all of them alike (their frame-rate ratios are
    measured back to back).

    Parameters
    ----------
    inner : PoseSource
    consumers : int
        Number of consumers (``consumer(k)``, k < consumers). Poses a
        consumer has not read yet wait for it (at most the lead of the
        fastest consumer).
    """

    def __init__(self, inner: PoseSource, consumers: int):
        if consumers < 1:
            raise ValueError(f"TeePoses: need at least one consumer, got {consumers}")
        self.inner = inner
        self._queues = [deque() for _ in range(consumers)]
        self._open = set(range(consumers))
        self._ended = False

    def consumer(self, k: int) -> PoseSource:
        """The PoseSource of consumer ``k``."""
        if k not in range(len(self._queues)):
            raise ValueError(f"TeePoses: consumer {k} of {len(self._queues)}")
        return _TeeConsumer(self, k)

    def _read(self, k: int) -> Pose | None:
        queue = self._queues[k]
        if not queue:
            if self._ended:
                return None
            pose = self.inner.read()
            if pose is None:
                self._ended = True
                return None
            for j in self._open:
                self._queues[j].append(pose)
        return queue.popleft()

    def _close(self, k: int) -> None:
        self._open.discard(k)
        self._queues[k].clear()
        if not self._open:
            self.inner.close()

    def close(self) -> None:
        """Close every consumer and the inner source."""
        for k in list(self._open):
            self._close(k)


class _TeeConsumer(PoseSource):
    def __init__(self, tee: TeePoses, k: int):
        self._tee, self._k = tee, k
        self.screen, self.name = tee.inner.screen, tee.inner.name

    def read(self) -> Pose | None:
        return self._tee._read(self._k)

    def close(self) -> None:
        if self._k in self._tee._open:
            self._tee._close(self._k)


class ReplayPoses(PoseSource):
    """Poses recorded earlier (a list of :class:`Pose`, e.g. from :func:`read_all_poses`) read again in order.

    Each read gives a copy: a loop may change the pose it is given, and the
    same list is replayed to several loops (benchmarks compare them on the
    same poses, the tracking done once).
    """

    def __init__(self, poses, screen, name: str = "replay"):
        self._poses, self._k = list(poses), 0
        self.screen, self.name = screen, name

    def read(self) -> Pose | None:
        if self._k >= len(self._poses):
            return None
        self._k += 1
        return dataclasses.replace(self._poses[self._k - 1])

    def close(self) -> None:
        self._k = len(self._poses)


def read_all_poses(source: PoseSource) -> list:
    """Every pose of ``source`` until it ends, its camera images dropped; the source is closed."""
    try:
        poses = []
        while (pose := source.read()) is not None:
            poses.append(dataclasses.replace(pose, images=None))
        return poses
    finally:
        source.close()


class PrefetchPoses(PoseSource):
    """Another source read ahead on its own thread: tracking runs while the viewer renders.

    This is how a live tracker feeds a viewer: the cameras' frames are
    tracked as they arrive, concurrently with rendering, and the render loop
    takes the next pose when it starts a frame. Poses keep their order (at
    most ``depth`` are read ahead; the reader waits for the loop), so a
    headless run draws exactly the frames it would without prefetching.

    Parameters
    ----------
    inner : PoseSource
    depth : int
        Poses read ahead (≥ 1).
    """

    def __init__(self, inner: PoseSource, depth: int = 2):
        if depth < 1:
            raise ValueError(f"PrefetchPoses: depth must be ≥ 1, got {depth}")
        self.inner, self.screen, self.name = inner, inner.screen, inner.name
        self._queue: "queue.Queue" = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, name="pose-prefetch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self.inner.read()
            except Exception as exc:           # handed to the loop, which reports it
                item = exc
            while not self._stop.is_set():
                try:
                    self._queue.put(item, timeout=0.1)
                    break
                except queue.Full:
                    continue
            if item is None or isinstance(item, Exception):
                return

    def read(self) -> Pose | None:
        if self._done:
            return None
        item = self._queue.get()
        if item is None:
            self._done = True
        elif isinstance(item, Exception):
            self._done = True
            raise item
        return item

    def __getattr__(self, name):               # e.g. set_poi of a mouse source
        return getattr(self.inner, name)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.inner.close()


class DropoutPoses(PoseSource):
    """Another source with tracking failures injected at given frames (tests, ``--dropout``).

    Parameters
    ----------
    inner : PoseSource
    frames : iterable of int
        Frame numbers (0-based, counted here) that lose their pose.
    reason : str
    """

    def __init__(self, inner: PoseSource, frames, reason: str = "simulated dropout: markers hidden"):
        self.inner, self.frames, self.reason = inner, set(int(f) for f in frames), reason
        self.screen, self.name = inner.screen, f"{inner.name} with dropouts"
        self.count = 0

    def read(self) -> Pose | None:
        pose = self.inner.read()
        if pose is None:
            return None
        k, self.count = self.count, self.count + 1
        if k in self.frames:
            return Pose(pose.t, False, reason=self.reason, images=pose.images, timings_ms=pose.timings_ms)
        return pose

    def close(self) -> None:
        self.inner.close()


class PoseHold:
    """Keeps the viewer running through tracking failures: the last good pose, its covariance growing.

    Parameters
    ----------
    fallback_eye_mm : (3,)
        Eye used before the first good pose (world mm).
    fallback_poi_px : (2,)
        POI used before the first good pose (screen px).
    growth_deg2_per_s : float
        Added to each diagonal term of the covariance per second since the
        last good pose (before the first: since the first frame).
    max_var_deg2 : float
        Cap of each grown diagonal term.
    """

    def __init__(self, fallback_eye_mm, fallback_poi_px, growth_deg2_per_s: float = GROWTH_DEG2_PER_S,
                 max_var_deg2: float = MAX_HELD_VAR_DEG2):
        if not (growth_deg2_per_s >= 0 and max_var_deg2 > 0):
            raise ValueError(f"PoseHold: need growth_deg2_per_s >= 0 and max_var_deg2 > 0, got "
                             f"{growth_deg2_per_s}, {max_var_deg2}")
        self.fallback = Pose(0.0, True, np.asarray(fallback_eye_mm, dtype=np.float64),
                             np.asarray(fallback_poi_px, dtype=np.float64), None)
        self.growth, self.max_var = float(growth_deg2_per_s), float(max_var_deg2)
        self.last_good: Pose | None = None
        self._t_first = None

    def __call__(self, pose: Pose) -> Pose:
        """The pose to view with: ``pose`` itself when ok, else the held one (``held`` true)."""
        if self._t_first is None:
            self._t_first = pose.t
        if pose.ok:
            self.last_good = pose
            return pose
        base = self.last_good or self.fallback
        t_since = pose.t - (self.last_good.t if self.last_good is not None else self._t_first)
        lost_s = max(float(t_since), 0.0)
        cov = np.zeros((2, 2)) if base.cov_deg2 is None else np.array(base.cov_deg2, dtype=np.float64)
        grow = np.minimum(np.diag(cov) + self.growth * lost_s, self.max_var) - np.diag(cov)
        cov = cov + np.diag(np.maximum(grow, 0.0))
        return Pose(pose.t, False, base.eye_mm.copy(), base.poi_px.copy(), cov, reason=pose.reason,
                    images=pose.images, markers_px=pose.markers_px, timings_ms=pose.timings_ms, held=True,
                    lost_s=lost_s)
