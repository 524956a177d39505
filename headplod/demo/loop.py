"""The demo's windowless core: head pose → POI → PLOD levels → mesh → head-coupled render → HUD.

One :class:`DemoLoop` runs behind both the window (:mod:`headplod.demo.window`)
and the headless run (:mod:`headplod.demo.cli`), so what the benchmark
measures is what the window shows.

Frames and units
----------------
World frame: the left camera's, mm (docs/contract.md). The eye of the
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

import dataclasses
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..plod.select import MODES, UNCERTAINTY_MODES, SelectorConfig
from ..plod.view import View
from ..render import TerrainRenderer, create_context, off_axis_projection
from ..plod.raymask import RayMaskConfig
from ..render.foveate import FoveatedRenderer, FoveationConfig, LayerAnchor
from ..render.frame import (CAPABILITIES, DEMO_BACKENDS, FAR_MM, NEAR_MM, VIEW_MODES, FrameSettings, FrameStep,
                            make_frame_step, px_per_deg_at)
from ..render.projection import screen_to_image_px
from ..render.still import default_head
from . import viewpoints as vps
from .pose_sources import (GROWTH_DEG2_PER_S, MAX_HELD_VAR_DEG2, DropoutPoses, MousePoses, Pose,  # noqa: F401
                           PoseHold, PoseSource, PrefetchPoses, ReplayPoses, TeePoses, TrackerPoses, default_screen,
                           read_all_poses)
from .hud import HudInfo, draw_hud, draw_picture_overlay
from ..tol import tol

#: Uncertainty scenarios: the paper's three (none, fixed, adaptive) and smoothed.
SCENARIOS = tuple(UNCERTAINTY_MODES)
#: Ohshima et al.: above this POI speed the eye is in a saccade and sees no detail (the view
#: conditioning's ``SelectorConfig.saccade_hold_deg_s``).
SACCADE_DEG_S = SelectorConfig.saccade_hold_deg_s
#: Stage names of a frame, in order.
STAGES = ("pose", "select", "build", "upload", "render", "readback", "hud")


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
    budget : dict or None
        With a triangle budget: whether the frame met it and the nearest count it could reach
        (:func:`headplod.render.frame.budget_outcome`); None without one.
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
    budget: dict | None = None

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
    budget: list = field(default_factory=list)      # each frame's budget outcome, with a budget

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
        if r.budget is not None:
            self.budget.append(r.budget)

    def summary(self, skip_first: int = 1) -> dict:
        """Medians over the frames after the first ``skip_first`` (the first builds the whole mesh); with a
        budget, ``budget``: its triangles, the frames that met it, the range of the counts of those that did not
        (a view beyond reach, or levels the hysteresis or a saccade kept), and ``missed_limit``: ``coarsest``
        or ``finest`` when every one of them was at that end of what its view allows, else None."""
        k = skip_first if len(self.frame_ms) > skip_first else 0
        frame = float(np.median(self.frame_ms[k:])) if self.frame_ms else float("nan")
        budget = {}
        if self.budget:
            missed = [b for b in self.budget if not b["met"]]
            counts = [b["nearest"] for b in missed]
            limits = {b["limit"] for b in missed}
            budget = {"budget": {"triangles": self.budget[0]["triangles"],
                                 "met_frames": len(self.budget) - len(missed),
                                 "missed_range": [min(counts), max(counts)] if missed else None,
                                 "missed_limit": limits.pop() if len(limits) == 1 else None}}
        return {**budget, "frames": len(self.frame_ms),
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
    raymask : RayMaskConfig, optional
        The raymask back end's settings (default ``RayMaskConfig()``).
    """

    def __init__(self, scene, poses: PoseSource, renderer=None, *, size=(1280, 720), mode="csf",
                 uncertainty="adaptive", viewpoint="overview", view_mode="shaded", hud=True,
                 saccade_deg_s=SACCADE_DEG_S, growth_deg2_per_s=GROWTH_DEG2_PER_S, selector_options=None,
                 foveate=False, foveation: FoveationConfig | None = None, backend: str = "mesh",
                 raymask: RayMaskConfig | None = None):
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
        self._modes = tuple(m for m in MODES if not (m == "full" and not mesh.full_fits))
        self._backends = tuple(b for b in DEMO_BACKENDS if CAPABILITIES[b].lazy_mesh or mesh.has_full_table)
        self.raymask = raymask or RayMaskConfig()      # the settings of the raymask back end
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
            raymask = s["backend"] == "raymask"
            settings = FrameSettings(s["backend"], config, foveate=self.foveated is not None and not raymask,
                                     foveation=self.foveation, raymask=self.raymask)
            step = self._steps[key] = make_frame_step(
                settings, self.screen, renderer=self._raymask() if raymask else self.renderer, scene=scene,
                foveated=self.foveated, anchor=self.anchor)
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
                             out.details.get("cache_bytes"), lazy, view=out.view, budget=out.details.get("budget"))
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
        fps = 1e3 / float(np.mean(self._frame_times)) if self._frame_times else 1e3 / result.frame_ms
        return HudInfo(fps=fps, stage_ms=dict(result.stage_ms), frame_ms=result.frame_ms,
                       triangles=result.triangles,
                       mode=("raymask" if self.settings["backend"] == "raymask" else self.settings["mode"])
                       + (" +foveate" if self.foveated is not None else ""),
                       uncertainty=self.settings["uncertainty"], viewpoint=self.settings["viewpoint"],
                       view_mode=self.settings["view_mode"], source=self.poses.name,
                       poi_image_px=screen_to_image_px(pose.poi_px, self.screen.size_px, (w, h)), cov_deg2=pose.cov_deg2,
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
        levels = self.last.levels
        return draw_picture_overlay(image, info, caption=caption, legend=view_mode == "levels",
                                    max_level=self.base_scene.mesh.max_level,
                                    present=None if levels is None else {int(v) for v in np.unique(levels)})


def _same_screen(a, b) -> bool:
    return (tuple(a.size_px) == tuple(b.size_px) and np.allclose(a.top_left, b.top_left, atol=tol.text)
            and np.allclose(a.top_right, b.top_right, atol=tol.text)
            and np.allclose(a.bottom_left, b.bottom_left, atol=tol.text))
