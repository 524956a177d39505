"""The demo's windowless core: head pose → POI → PLOD levels → mesh → head-coupled render → HUD.

One :class:`DemoLoop` runs behind both the window (:mod:`headplod.demo.window`)
and the headless run (:mod:`headplod.demo.cli`), so what the benchmark
measures is what the window shows.

Frames and units
----------------
World frame: the left camera's, mm (conventions.md). The eye of the
head-coupled projection is the tracked head position P1, the bridge of the
glasses, about 10-20 mm in front of the eyes' midpoint; no eye offset is
applied (one could be added to :class:`TrackerPoses` when a per-user offset
is measured). The point of interest (POI) is where the ray from the head
along V meets the screen, in screen pixels; its covariance is the tracker's
covariance of (φ, θ) of V, deg².

Per frame
---------
1. A pose from a :class:`PoseSource`: the live tracker, a recording or the
   built-in synthetic sequence through the real tracker
   (:class:`TrackerPoses`), or the mouse / a scripted path
   (:class:`MousePoses`).
2. Tracking failure: a frame without a pose keeps the last good pose and
   grows its covariance by ``growth_deg2_per_s`` per second on the diagonal
   (:class:`PoseHold`); the HUD says "tracking lost: <reason>".
3. Ohshima et al.'s saccade rule: while the POI moves faster than 180°/s
   (seen from the eye) the previous levels are kept — no re-selection, the
   frame is still rendered with the current head-coupled projection (they
   skipped rendering; keeping the image head-coupled costs nothing extra
   here). Head tremor is handled by the view conditioning, whose One Euro
   filters on the eye and POI, and the selector's hysteresis on the levels,
   keep small motions from switching levels (:mod:`headplod.plod.view`).
4. The frame itself is the one frame step, :class:`headplod.render.frame.FrameStep`,
   the same that ``headplod render`` and the benchmarks run: levels →
   :meth:`AdaptiveMesh.update_indices` (only base triangles whose
   case changed are rebuilt, as indices into the mesh's vertex table, which
   is uploaded once) → upload of the indices, skipped when the mesh did not
   change → off-axis indexed render → HUD.

   With a :class:`headplod.plod.lazy_mesh.LazyAdaptiveMesh` (``--max-level``
   above 5, or ``--lazy``) there is no whole table: a frame whose cases
   changed gets a new compact table (the pieces it draws, from the shared
   piece cache) and indices into it, both uploaded; a frame whose cases did
   not change uploads nothing. The ``raymask`` back end (rays against the
   whole ``full`` mesh) is not offered with it, nor ``full`` above
   :data:`headplod.render.still.FULL_MAX_LEVEL`.
"""
from __future__ import annotations

import abc
import dataclasses
import math
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..capture import open_source
from ..plod.select import MODES, UNCERTAINTY_MODES, SelectorConfig
from ..plod.view import View, poi_direction
from ..render import TerrainRenderer, create_context, off_axis_projection
from ..plod.raymask import RayMaskConfig
from ..render.foveate import FoveatedRenderer, FoveationConfig, LayerAnchor
from ..render.frame import FAR_MM, NEAR_MM, VIEW_MODES, FrameStep, MeshBackend, RayMaskBackend, px_per_deg_at
from ..render.still import full_fits, default_head, uses_table
from . import viewpoints as vps
from .hud import HudInfo, draw_hud, draw_picture_overlay

#: Uncertainty scenarios: the paper's three (none, fixed, adaptive) and smoothed.
SCENARIOS = tuple(UNCERTAINTY_MODES)
#: Ohshima et al.: above this POI speed the eye is in a saccade and sees no detail (the view
#: conditioning's ``SelectorConfig.saccade_hold_deg_s``).
SACCADE_DEG_S = SelectorConfig.saccade_hold_deg_s
#: The demo's back ends (:data:`headplod.render.frame.CAPABILITIES`).
DEMO_BACKENDS = ("mesh", "raymask")
#: Growth of the covariance's diagonal while tracking is lost, deg²/s (σ reaches 2° after 1 s).
GROWTH_DEG2_PER_S = 4.0
#: Cap of each diagonal term of a grown covariance, deg² (σ 20°).
MAX_HELD_VAR_DEG2 = 400.0
#: Stage names of a frame, in order.
STAGES = ("pose", "select", "build", "upload", "render", "readback", "hud")


# --------------------------------------------------------------------------
# poses
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# the loop
# --------------------------------------------------------------------------


@dataclass
class FrameResult:
    """What one :meth:`DemoLoop.step` produced.

    Attributes
    ----------
    index : int
    t : float
        Pose time, s.
    image : (H, W, 3) uint8
        RGB, row 0 at the top; with the HUD when it is on.
    levels : (F,) int64 or None
        Level per base triangle (None for the raymask back end).
    triangles : int
    stage_ms : dict
        Wall time per stage (``STAGES``), ms.
    frame_ms : float
        Wall time of the whole step, ms.
    pose : Pose
        The pose the frame was drawn with (held while tracking is lost).
    saccade_skipped : bool
        The saccade rule kept the previous levels.
    poi_speed_deg_s : float
        Angular speed of the POI seen from the eye, deg/s.
    cache_bytes : int or None
        A lazy mesh's piece cache after the frame's build, bytes (shared by the loops of one scene); None
        for the whole-table mesh.
    lazy_stats : dict or None
        A lazy mesh's build of the frame: ``rebuilt_faces``, ``generated_pieces``, ``vertices`` (None for
        the whole-table mesh).
    view : headplod.plod.view.ConditionedView
        The conditioned view the frame was made for.
    """

    index: int
    t: float
    image: np.ndarray
    levels: np.ndarray
    triangles: int
    stage_ms: dict
    frame_ms: float
    pose: Pose
    saccade_skipped: bool
    poi_speed_deg_s: float
    cache_bytes: int | None = None
    lazy_stats: dict | None = None
    view: object = None

    @property
    def tracking_lost(self) -> str | None:
        return self.pose.reason if self.pose.held else None


@dataclass
class RunStats:
    """Per-frame records of a run, and their summary."""

    frame_ms: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    stage_ms: dict = field(default_factory=lambda: {s: [] for s in STAGES})
    saccade_skipped: int = 0
    tracking_failures: int = 0
    cache_bytes: list = field(default_factory=list)
    lazy: dict = field(default_factory=dict)

    def add(self, r: FrameResult) -> None:
        self.frame_ms.append(r.frame_ms)
        if r.cache_bytes is not None:
            self.cache_bytes.append(r.cache_bytes)
        for key, value in (r.lazy_stats or {}).items():
            self.lazy.setdefault(key, []).append(value)
        self.triangles.append(r.triangles)
        for s in STAGES:
            self.stage_ms[s].append(r.stage_ms.get(s, 0.0))
        self.saccade_skipped += int(r.saccade_skipped)
        self.tracking_failures += int(r.pose.held)

    def summary(self, skip_first: int = 1) -> dict:
        """Medians over the frames after the first ``skip_first`` (the first builds the whole mesh)."""
        k = skip_first if len(self.frame_ms) > skip_first else 0
        frame = float(np.median(self.frame_ms[k:])) if self.frame_ms else float("nan")
        return {"frames": len(self.frame_ms),
                "fps": 1e3 / frame if frame > 0 else float("nan"),
                "frame_ms_median": frame,
                "stage_ms_median": {s: float(np.median(v[k:])) if v else float("nan")
                                    for s, v in self.stage_ms.items()},
                "triangles_median": float(np.median(self.triangles[k:])) if self.triangles else float("nan"),
                "saccade_skipped": self.saccade_skipped,
                "tracking_failures": self.tracking_failures}


class DemoLoop:
    """The viewer without a window: one :meth:`step` per frame.

    Each frame is the one frame step (:class:`headplod.render.frame.FrameStep`)
    of the current (viewpoint, back end, mode, scenario), around a pose
    source, the held pose of a lost tracker, and the HUD.

    Parameters
    ----------
    scene : headplod.render.still.TerrainScene
        Built once; viewpoints only change its model matrix. The loop builds
        its meshes in its own :meth:`AdaptiveMesh.share` of ``scene.mesh``.
    poses : PoseSource
        Its screen must be the scene's.
    renderer : TerrainRenderer, optional
        Default: a new one on a headless EGL context at ``size``. Loops
        stepped in turn need a renderer each (a loop re-sends its mesh only
        when its selection changed).
    size : (2,) int
        Image size (width, height), px, when the renderer is made here.
    mode, uncertainty, viewpoint, view_mode, backend : str
        Initial settings (:data:`headplod.plod.select.MODES`, ``SCENARIOS``,
        ``viewpoints.VIEWPOINTS``, ``VIEW_MODES``, :data:`DEMO_BACKENDS`).
    hud : bool
        Draw the heads-up display.
    saccade_deg_s : float
        POI speed above which the previous levels are kept, deg/s.
    growth_deg2_per_s : float
        Covariance growth while tracking is lost (:class:`PoseHold`).
    selector_options : dict, optional
        Other :class:`SelectorConfig` fields for every frame step.
    foveate : bool
        Draw the frame as foveated resolution layers (:mod:`headplod.render.foveate`)
        centred on the conditioned POI, widened by the scenario's covariance,
        both held by a :class:`LayerAnchor` (a still head: a still frame). The
        renderer must have ``samples=0``.
    foveation : FoveationConfig, optional
        The layers' settings (default ``FoveationConfig()``).
    """

    def __init__(self, scene, poses: PoseSource, renderer=None, *, size=(1280, 720), mode="csf",
                 uncertainty="adaptive", viewpoint="overview", view_mode="shaded", hud=True,
                 saccade_deg_s=SACCADE_DEG_S, growth_deg2_per_s=GROWTH_DEG2_PER_S, selector_options=None,
                 foveate=False, foveation: FoveationConfig | None = None, backend: str = "mesh"):
        # Its own build state over the scene's shared tables: loops run side by side (the
        # headless demo interleaves them) each rebuild only what their own selection changes.
        self.base_scene = dataclasses.replace(scene, mesh=scene.mesh.share())
        self.screen = scene.screen
        if poses.screen is not None and not _same_screen(poses.screen, self.screen):
            raise ValueError(f"DemoLoop: the pose source's screen ({poses.screen.size_px} px, top-left "
                             f"{np.round(poses.screen.top_left, 1).tolist()} mm) is not the scene's "
                             f"({self.screen.size_px} px, top-left {np.round(self.screen.top_left, 1).tolist()} mm)"
                             "; build the scene for the source's screen")
        self.poses = poses
        if renderer is None:
            renderer = TerrainRenderer(create_context(), size=tuple(int(v) for v in size))
        self.renderer = renderer
        self.foveation = foveation or FoveationConfig()
        self.foveated = FoveatedRenderer(renderer, self.foveation) if foveate else None
        self.anchor = LayerAnchor()
        # The lazy mesh keeps no whole full mesh for raymask's rays, and full above FULL_MAX_LEVEL does not fit.
        mesh = scene.mesh
        self._modes = tuple(m for m in MODES if not (m == "full" and not full_fits(mesh)))
        self._backends = tuple(b for b in DEMO_BACKENDS if not (b == "raymask" and not uses_table(mesh)))
        self.raymask = RayMaskConfig()      # the settings of the raymask back end
        self._raymask_renderer = None
        self.settings = {}
        self.set("backend", backend)
        self.set("mode", mode)
        self.set("uncertainty", uncertainty)
        self.set("viewpoint", viewpoint)
        self.set("view_mode", view_mode)
        self.hud = bool(hud)
        centre = np.array(self.screen.size_px, dtype=np.float64) / 2
        self.hold = PoseHold(default_head(self.screen), centre, growth_deg2_per_s)
        self.selector_options = {"saccade_hold_deg_s": float(saccade_deg_s), **dict(selector_options or {})}
        self.stats = RunStats()
        self.index = 0
        self.last: FrameResult | None = None
        self._steps: dict = {}
        self._scenes: dict = {}
        self._active = None
        self._frame_times = deque(maxlen=30)

    @property
    def saccade_deg_s(self) -> float:
        return self.selector_options["saccade_hold_deg_s"]

    # -- settings ---------------------------------------------------------------

    def set(self, key: str, value) -> None:
        """Change a setting: ``backend``, ``mode``, ``uncertainty``, ``viewpoint``, ``view_mode`` or ``hud``."""
        allowed = {"backend": self._backends, "mode": self._modes, "uncertainty": SCENARIOS,
                   "viewpoint": tuple(vps.VIEWPOINTS), "view_mode": VIEW_MODES}
        if key == "hud":
            self.hud = bool(value)
            return
        if key not in allowed:
            raise ValueError(f"unknown setting {key!r}; expected one of {sorted(allowed) + ['hud']}")
        if value not in allowed[key]:
            if key == "mode" and value == "raymask":
                raise ValueError("raymask is a back end, not a mode: set backend to 'raymask'")
            raise ValueError(f"{key} must be one of {allowed[key]}, got {value!r}")
        self.settings[key] = value

    def apply(self, action) -> bool:
        """Apply a key action from :func:`headplod.demo.window.action_for_key`; False for ``quit``."""
        if action is None:
            return True
        key, value = action
        if key == "quit":
            return False
        if key == "hud":
            self.hud = not self.hud
        elif key == "mode" and value not in self._modes:
            pass                             # a mode this mesh cannot draw (see __init__): the key does nothing
        elif key == "viewpoint" and value == "next":
            names = list(vps.VIEWPOINTS)
            self.set("viewpoint", names[(names.index(self.settings["viewpoint"]) + 1) % len(names)])
        else:
            self.set(key, value)
        return True

    @property
    def scene(self):
        """The scene placed at the current viewpoint."""
        name = self.settings["viewpoint"]
        if name not in self._scenes:
            self._scenes[name] = vps.place(self.base_scene, name)
        return self._scenes[name]

    def frame_step(self) -> FrameStep:
        """The frame step of the current (viewpoint, back end, mode, scenario), made once and cached."""
        s = self.settings
        key = (s["viewpoint"], s["backend"], s["mode"], s["uncertainty"])
        step = self._steps.get(key)
        if step is None:
            scene = self.scene
            config = SelectorConfig(mode=s["mode"], uncertainty=s["uncertainty"], **self.selector_options)
            if s["backend"] == "raymask":
                backend = RayMaskBackend(self._raymask(), self.screen, self.raymask)
            else:
                backend = MeshBackend(scene.mesh, scene.selector(s["mode"], s["uncertainty"], config), self.renderer,
                                      self.screen, foveated=self.foveated, anchor=self.anchor,
                                      foveation=self.foveation)
            step = self._steps[key] = FrameStep(backend, self.screen, config)
        if key != self._active:
            step.reset()                     # stale smoothing, hysteresis, layers and levels from its last use
            self._active = key
        return step

    def selector(self):
        """The level selector of the current settings (None for the raymask back end)."""
        return getattr(self.frame_step().backend, "selector", None)

    def _raymask(self):
        """The loop's ray-mask renderer, made when first asked for (its shaders compile then)."""
        if self._raymask_renderer is None:
            from ..render.raymask import RayMaskRenderer

            self._raymask_renderer = RayMaskRenderer(self.renderer.ctx, self.base_scene.mesh,
                                                     size=tuple(self.renderer.size))
        return self._raymask_renderer

    # -- one frame ----------------------------------------------------------------

    def step(self) -> FrameResult | None:
        """Run one frame; None when the pose source has ended."""
        t0 = time.perf_counter()
        raw = self.poses.read()
        if raw is None:
            return None
        pose = self.hold(raw)
        t1 = time.perf_counter()
        out = self.frame_step()(View(pose.eye_mm, pose.poi_px, pose.cov_deg2, pose.t), self.scene.model,
                                self.settings["view_mode"])
        lazy = out.details.get("lazy")
        result = FrameResult(self.index, pose.t, out.image, out.levels, out.triangles,
                             {"pose": (t1 - t0) * 1e3, **out.stage_ms, "hud": 0.0},
                             (time.perf_counter() - t0) * 1e3, pose, out.held, out.view.poi_speed_deg_s,
                             out.details.get("cache_bytes"), lazy, view=out.view)
        return self._finish(result, t0)

    def _finish(self, result: FrameResult, t0: float) -> FrameResult:
        """The HUD drawn on the frame (when on), and the frame counted."""
        if self.hud:
            t5 = time.perf_counter()
            result.image = draw_hud(result.image, self.hud_info(result), inplace=True,
                                    max_level=self.base_scene.mesh.max_level)
            t6 = time.perf_counter()
            result.stage_ms["hud"] = (t6 - t5) * 1e3
            result.frame_ms = (t6 - t0) * 1e3
        self._frame_times.append(result.frame_ms)
        self.stats.add(result)
        self.index += 1
        self.last = result
        return result

    def hud_info(self, result: FrameResult):
        """The HUD's content for a frame."""
        w, h = self.renderer.size
        pose = result.pose
        scale = np.array([w, h], dtype=np.float64) / np.array(self.screen.size_px, dtype=np.float64)
        fps = 1e3 / float(np.mean(self._frame_times)) if self._frame_times else 1e3 / result.frame_ms
        return HudInfo(fps=fps, stage_ms=dict(result.stage_ms), frame_ms=result.frame_ms,
                       triangles=result.triangles,
                       mode=("raymask" if self.settings["backend"] == "raymask" else self.settings["mode"])
                       + (" +foveate" if self.foveated is not None else ""),
                       uncertainty=self.settings["uncertainty"], viewpoint=self.settings["viewpoint"],
                       view_mode=self.settings["view_mode"], source=self.poses.name,
                       poi_image_px=pose.poi_px * scale, cov_deg2=pose.cov_deg2,
                       px_per_deg=px_per_deg_at(self.screen, pose.eye_mm, (w, h)),
                       tracking_lost=result.tracking_lost, lost_s=pose.lost_s,
                       saccade=result.saccade_skipped, poi_speed_deg_s=result.poi_speed_deg_s,
                       images=pose.images, markers_px=pose.markers_px,
                       failures=self.stats.tracking_failures + int(pose.held), frame=result.index)

    def picture(self, view_mode: str = "levels", caption: str | None = None) -> np.ndarray:
        """The last frame re-rendered in ``view_mode`` with the POI, its 2σ ellipse and a level legend.

        Returns
        -------
        (H, W, 3) uint8 RGB
        """
        if self.last is None:
            raise RuntimeError("DemoLoop.picture: no frame has been run yet")
        pose = self.last.pose
        view, proj = off_axis_projection(pose.eye_mm, self.screen, NEAR_MM, FAR_MM)
        image = self.renderer.render(view, proj, self.scene.model, view_mode=view_mode)
        info = self.hud_info(self.last)
        if self.foveated is not None and self.anchor.poi_px is not None:
            from ..render.overlay import overlay_layers
            ppd = px_per_deg_at(self.screen, pose.eye_mm, self.renderer.size)
            image = overlay_layers(image, self.anchor.poi_px, self.anchor.layers, ppd)
        return draw_picture_overlay(image, info, caption=caption, legend=view_mode == "levels",
                                    max_level=self.base_scene.mesh.max_level)


def _same_screen(a, b) -> bool:
    return (tuple(a.size_px) == tuple(b.size_px) and np.allclose(a.top_left, b.top_left, atol=1e-6)
            and np.allclose(a.top_right, b.top_right, atol=1e-6)
            and np.allclose(a.bottom_left, b.bottom_left, atol=1e-6))
