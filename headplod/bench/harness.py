"""The one harness of the PLOD benchmarks: scene and view, frames through the frame step, quality, charts.

Every frame a PLOD benchmark makes is a frame of :class:`headplod.render.frame.FrameStep`, the step
``headplod render`` and the demo run, with the back end that draws it (:func:`mesh_step`,
:func:`raymask_step`): the view conditioned once, the levels selected, the mesh's indices built and uploaded
(the vertex table once per renderer), rendered and read back. So a benchmark measures what the demo does.

- :class:`BenchScene`: the benches' scene and default view (the embedded screen, the built-in terrain, a
  renderer of :data:`SIZE`, the head 60 cm in front of the screen centre, the POI at the centre, the
  tracker's covariance :data:`TRACKER_COV_DEG2`, the camera, px per degree, the :data:`DISC_DEG` disc).
- :func:`run_views`: a list of views through a step, in order: its :class:`FrameOutput` per view.
- :func:`steady_frame` (and :meth:`BenchScene.steady`): N frames of one view; the median of each stage
  after the first frame (:func:`steady_stats`).
- :func:`alternate`: several steps run in turn, round by round, so a busy machine slows them alike.
- :func:`quality`: PSNR, PSNR in the disc, FLIP (:mod:`headplod.render.image_metrics`).
- :func:`pyplot`, :func:`save_figure`, :func:`write_png` (:mod:`.outputs`), :func:`label_axes`: charts.

Units: world mm, screen px, images (H, W, 3) uint8 RGB, times ms, angles deg.
"""
from __future__ import annotations

import numpy as np

from calib import DEFAULT_SCREEN

from .. import io
from ..plod.select import SelectorConfig
from ..plod.view import View
from ..progress import note
from ..render.frame import FAR_MM, NEAR_MM, FrameSettings, FrameStep, make_frame_step, px_per_deg_at
from ..render.projection import off_axis_projection, screen_to_image_px
from ..render.still import TerrainScene, default_head
from ..render.image_metrics import poi_disc, quality
from .outputs import pyplot, save_figure, write_png

__all__ = ["SIZE", "TRACKER_SIGMA_DEG", "TRACKER_COV_DEG2", "DISC_DEG", "FRAME_DT_S", "FRAME_STAGES",
           "BenchScene", "mesh_step", "raymask_step", "release_step", "run_views", "steady_frame", "steady_stats",
           "alternate", "quality", "poi_disc", "progress", "label_axes", "pyplot", "save_figure", "write_png",
           "DEFAULT_SCREEN"]

#: Image size of the benchmarks (and the demo's default), px (width, height).
SIZE = (1280, 720)
#: The tracker's σ of each angle of V for a head at 60 cm, deg (``headplod bench uncertainty`` measures it).
TRACKER_SIGMA_DEG = 0.05
#: The tracker-like covariance of (φ, θ) the benchmarks' views carry, deg² (read-only).
TRACKER_COV_DEG2 = np.diag([TRACKER_SIGMA_DEG ** 2] * 2)
TRACKER_COV_DEG2.setflags(write=False)
#: Radius of the disc about the POI where PSNR is also measured, deg.
DISC_DEG = 5.0
#: Time between the benchmarks' frames, s (60 Hz).
FRAME_DT_S = 1 / 60
#: The stages whose medians make a frame's ``frame_ms`` (the read-back of the image is reported apart).
FRAME_STAGES = ("select", "build", "upload", "render")


def progress(name: str):
    """A progress callable for a benchmark: ``progress("bench plod")("csf")`` prints ``bench plod: csf`` to stderr
    (nothing with the command's ``-q``)."""
    return lambda text: note(f"{name}: {text}")


def label_axes(ax, xlabel, ylabel=None, title=None, xscale=None, yscale=None, which="major", legend=7) -> None:
    """Labels, scales, grid and legend (``legend``: its font size; None: no legend) of a chart's panel."""
    for setter, value in ((ax.set_xlabel, xlabel), (ax.set_ylabel, ylabel), (ax.set_title, title),
                          (ax.set_xscale, xscale), (ax.set_yscale, yscale)):
        if value:
            setter(value)
    ax.grid(True, which=which, alpha=0.3)
    if legend:
        ax.legend(fontsize=legend)


def mesh_step(scene, renderer, mode: str, uncertainty: str = "adaptive", *, foveate: bool = False,
              foveation=None, **settings) -> FrameStep:
    """A frame step of the mesh back end, as the demo makes it, over its own build state of ``scene``'s mesh.

    ``scene`` a :class:`TerrainScene` (placed at a viewpoint or not); ``renderer`` a
    :class:`headplod.render.gl.TerrainRenderer` (steps run in turn need one each: a step re-sends its
    indices only when its selection changes); ``settings`` other :class:`SelectorConfig` fields;
    ``foveate``: drawn as foveated layers (:func:`release_step` frees them). ``step.backend.last_info``:
    the last selection's features (``speed_deg_s``, ``distance_mm``, ...).
    """
    config = SelectorConfig(mode=mode, uncertainty=uncertainty, **settings)
    return make_frame_step(FrameSettings("mesh", config, foveate=foveate, foveation=foveation), scene.screen,
                           renderer=renderer, scene=scene, mesh=scene.mesh.share())


def raymask_step(screen, raymask_renderer, config=None, uncertainty: str = "adaptive") -> FrameStep:
    """A frame step of the ray-mask back end (``config``: a :class:`headplod.plod.raymask.RayMaskConfig`)."""
    return make_frame_step(FrameSettings("raymask", SelectorConfig(mode="csf", uncertainty=uncertainty),
                                         raymask=config), screen, renderer=raymask_renderer)


def release_step(step: FrameStep) -> None:
    """Free what a step made for itself (the foveated layers' buffers); its renderer stays."""
    foveated = getattr(step.backend, "foveated", None)
    if foveated is not None:
        foveated.release()


def run_views(step: FrameStep, views, model, view_mode: str = "shaded", images: bool = True) -> list:
    """Each of ``views`` (:class:`View`, in order) through ``step`` with the scene placed by ``model`` (4, 4);
    the :class:`FrameOutput` of each (``images`` false: their images dropped, for long runs)."""
    out = []
    for view in views:
        frame = step(view, model, view_mode)
        if not images:
            frame.image = None
        out.append(frame)
    return out


def steady_stats(outputs, levels: int = 0) -> dict:
    """Medians of each stage over the frames after the first (ms): ``select_ms`` … ``readback_ms``,
    ``frame_ms`` (the sum over :data:`FRAME_STAGES`), ``triangles`` (the last frame's) and, for a mesh,
    ``triangles_per_level`` (at least ``levels`` entries)."""
    steady = outputs[1:] or outputs
    stats = {f"{s}_ms": float(np.median([o.stage_ms[s] for o in steady])) for s in outputs[-1].stage_ms}
    stats["frame_ms"] = sum(stats[f"{s}_ms"] for s in FRAME_STAGES)
    last = outputs[-1]
    stats["triangles"] = int(last.triangles)
    if last.triangle_levels is not None:
        stats["triangles_per_level"] = np.bincount(last.triangle_levels, minlength=levels).tolist()
    return stats


def steady_frame(step: FrameStep, view_at, model, frames: int = 3, view_mode: str = "shaded", before=None):
    """A steady-state frame: ``frames`` frames of one view through a fresh ``step`` (its state reset first).

    ``view_at(k)`` gives frame k's :class:`View` (the same pose, its time advancing); ``before(k, last)``,
    when given, runs before frame k with the last :class:`FrameOutput` (None before the first), e.g. to
    set ``step.backend.selector.contrast`` from the last image. The first frame builds the mesh; later
    ones rebuild only what changed. Returns (the last :class:`FrameOutput`, :func:`steady_stats`).
    """
    step.reset()
    outputs = []
    for k in range(int(frames)):
        if before is not None:
            before(k, outputs[-1] if outputs else None)
        if k >= 2:
            outputs[-2].image = None              # only the last two images are kept (``before`` reads one)
        outputs.append(step(view_at(k), model, view_mode))
    mesh = getattr(step.backend, "mesh", None)
    return outputs[-1], steady_stats(outputs, 0 if mesh is None else mesh.max_level + 1)


def alternate(steps: dict, view_at, model, rounds: int, repeats: int = 1) -> tuple[dict, dict]:
    """Run ``steps`` ({name: FrameStep}) in turn, round by round (each ``repeats`` times a round), one view.

    Returns ({name: [per round: [FrameOutput of each repeat]]}, {name: its last FrameOutput}); round 0
    is the warm-up (the builds and masks) and is left out of the rounds. Only the last frame of each
    step keeps its image.
    """
    timed, last = {name: [] for name in steps}, {}
    for k in range(int(rounds) + 1):
        for name, step in steps.items():
            frames = []
            for j in range(repeats):
                if name in last:
                    last[name].image = None
                last[name] = step(view_at(k * repeats + j), model)
                frames.append(last[name])
            if k:
                timed[name].append(frames)
    return timed, last


class BenchScene:
    """The benches' scene and default view (module notes).

    ``size`` (w, h) px; ``scene`` (default: the built-in terrain behind ``screen``); ``screen`` (default: the
    scene's, else ``calib/screen.yaml``); ``ctx`` (default: a new headless context); ``frames`` of a steady
    frame (:meth:`steady`: the first builds, the rest are timed).

    Attributes: ``renderer`` (of ``size``); ``head`` (3,) world mm and ``poi`` (2,) screen px, the default
    view (:meth:`view`); ``camera`` (view, projection) (4, 4) each; ``px_per_deg`` at the screen centre;
    ``poi_image`` (2,) image px; ``disc`` (H, W) bool, the :data:`DISC_DEG` disc about the POI.
    """

    def __init__(self, size=SIZE, scene: TerrainScene | None = None, screen=None, ctx=None, frames: int = 3):
        from ..render import TerrainRenderer, create_context

        self.screen = screen or (scene.screen if scene is not None else io.read_screen(DEFAULT_SCREEN))
        self.scene = scene or TerrainScene.build(self.screen)
        self.size = tuple(int(v) for v in size)
        self.ctx = ctx or create_context()
        self.renderer = TerrainRenderer(self.ctx, size=self.size)
        self.frames = int(frames)
        self.head = default_head(self.screen)
        self.poi = np.array(self.screen.size_px, dtype=np.float64) / 2
        self.camera = off_axis_projection(self.head, self.screen, near_mm=NEAR_MM, far_mm=FAR_MM)
        self.px_per_deg = px_per_deg_at(self.screen, self.head, self.size)
        self.poi_image = screen_to_image_px(self.poi, self.screen.size_px, self.size)
        self.disc = poi_disc((self.size[1], self.size[0]), self.poi_image, DISC_DEG * self.px_per_deg)
        self._raymask_renderer = self._small = None

    @property
    def small_renderer(self):
        """A renderer of a quarter of :data:`SIZE` per side, for the parts whose figures are levels and
        triangles (the image's size changes neither); made when first asked for."""
        if self._small is None:
            from ..render import TerrainRenderer

            self._small = TerrainRenderer(self.ctx, size=(SIZE[0] // 4, SIZE[1] // 4))
        return self._small

    def view(self, t: float = 0.0, cov_deg2=TRACKER_COV_DEG2, eye_mm=None) -> View:
        """The default view at time ``t`` s (``cov_deg2``: another covariance, deg², or None; ``eye_mm``: another eye)."""
        return View(self.head if eye_mm is None else eye_mm, self.poi, cov_deg2, t)

    def view_at(self, cov_deg2=TRACKER_COV_DEG2):
        """``k`` → the default view at frame k's time (60 Hz)."""
        return lambda k: self.view(k * FRAME_DT_S, cov_deg2)

    def mesh_step(self, mode: str, uncertainty: str = "adaptive", *, scene=None, renderer=None, **settings):
        """:func:`mesh_step` on this scene (or ``scene``, e.g. placed at a viewpoint) and renderer."""
        return mesh_step(scene or self.scene, renderer or self.renderer, mode, uncertainty, **settings)

    @property
    def raymask_renderer(self):
        """The ray-mask renderer over this scene's mesh (made when first asked for)."""
        if self._raymask_renderer is None:
            from ..render.raymask import RayMaskRenderer

            self._raymask_renderer = RayMaskRenderer(self.ctx, self.scene.mesh, size=self.size,
                                                     background=self.renderer.background)
        return self._raymask_renderer

    def raymask_step(self, config=None) -> FrameStep:
        """:func:`raymask_step` with this scene's ray-mask renderer."""
        return raymask_step(self.screen, self.raymask_renderer, config)

    def steady(self, step: FrameStep, model=None, cov_deg2=TRACKER_COV_DEG2, view_mode: str = "shaded", before=None):
        """:func:`steady_frame` of the default view (``model``: default the scene's); (FrameOutput, stats)."""
        model = self.scene.model if model is None else model
        return steady_frame(step, self.view_at(cov_deg2), model, self.frames, view_mode, before)

    def quality(self, image, reference, flip: bool = True) -> dict:
        """:func:`quality` at this view's disc and px per degree."""
        return quality(image, reference, self.disc, self.px_per_deg, flip)

    def release(self) -> None:
        """Free the renderers (the context stays)."""
        for r in (self._raymask_renderer, self._small, self.renderer):
            if r is not None:
                r.release()
        self._raymask_renderer = self._small = None
