"""One PLOD frame, the same for ``headplod render``, the demo and every benchmark.

A frame is one step (:class:`FrameStep`):

1. **condition** the tracker's view once (:class:`headplod.plod.view.ViewConditioner`:
   filters, uncertainty scenario, head axes, hysteresis and saccade state);
2. **select** levels from the conditioned view (a selector; the last levels
   are kept during a saccade);
3. **draw** through a back end, which builds and uploads what the levels ask
   for and renders it from the raw eye (the camera is where the eye is; only
   the levels are smoothed).

The back ends sit behind one small interface (:class:`Backend`) and say what
they support in one table (:data:`CAPABILITIES`), which ``--help``, the docs
and the command lines' checks all read:

- ``mesh``: a level per base triangle (:class:`headplod.plod.select.LevelSelector`)
  over an adaptive mesh (whole table or lazy pieces), drawn indexed by
  :class:`headplod.render.gl.TerrainRenderer`, optionally as foveated layers;
- ``tessellation``: the same criterion per patch on the GPU
  (:class:`headplod.render.tessellate.TessellationRenderer`);
- ``raymask``: Murphy & Duchowski's rays through a CSF ray mask
  (:class:`headplod.render.raymask.RayMaskRenderer`), no levels.

Frames and units: world = left camera frame, mm; screen px; images (H, W, 3)
uint8 RGB, row 0 at the top; times in the stats in ms.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..plod.csf import CSF_MODELS
from ..plod.raymask import RAYMASK_CSF_MODELS, RayMaskConfig
from ..plod.select import DEFAULT_CSF_MODEL, MODES, SelectorConfig
from ..plod.view import UNCERTAINTY_MODES, ConditionedView, View, ViewConditioner, still_view
from .gl import VIEW_MODES as _GL_VIEW_MODES
from .projection import off_axis_projection, screen_to_image_px

__all__ = ["NEAR_MM", "FAR_MM", "VIEW_MODES", "BACKENDS", "DEMO_BACKENDS", "BackendCapabilities", "CAPABILITIES", "options_problem",
           "capability_table", "FrameOutput", "Backend", "MeshBackend", "TessellationBackend", "RayMaskBackend",
           "FrameStep", "FrameSettings", "SelectionOnlyBackend", "make_backend", "make_frame_step", "one_frame",
           "px_per_deg_at", "budget_outcome"]

#: Near and far planes of every frame's off-axis projection, mm from the eye.
NEAR_MM, FAR_MM = 50.0, 5000.0
#: How the mesh back end colours the image, in order (the names of :data:`headplod.render.gl.VIEW_MODES`).
VIEW_MODES = tuple(_GL_VIEW_MODES)


@dataclass(frozen=True)
class BackendCapabilities:
    """What one back end supports; :func:`options_problem` checks options against it.

    Attributes
    ----------
    name : str
    summary : str
        One line for ``--help`` and the docs.
    modes : tuple of str
        Level-selection modes (:data:`headplod.plod.select.MODES`) it draws.
    scenarios : tuple of str
        Uncertainty scenarios (:data:`headplod.plod.view.UNCERTAINTY_MODES`).
    view_modes : tuple of str
        Image colourings (:data:`VIEW_MODES`).
    foveate : bool
        Draws foveated resolution layers (``--foveate``).
    own_terrain : bool
        Takes a person's terrain file (``--terrain``).
    hysteresis : bool
        Keeps a piece's level within a dead band (a still head: no change).
    contrast_sources : tuple of str
        Where the contrast of the CSF comes from (``shading``; ``readback``: the paper's read-back window).
    export : bool
        Writes the frame's mesh (``--export``).
    level_bias : bool
        Takes a bias on every continuous level (``--level-bias``).
    budget : bool
        Meets a triangle budget per frame (``--budget``).
    finest_level : str
        What sets its finest detail.
    default_mode : str
        The mode it draws when none is asked for: the project's default criterion
        (:class:`headplod.plod.select.SelectorConfig`) where it takes it, else ``csf``.
    csf_forms : tuple of str
        The CSF forms ``--csf`` may choose (:data:`headplod.plod.csf.CSF_MODELS`; ``gp``: Geisler–Perry).
    default_csf : str
        The form it uses when none is asked for (the mesh: each CSF-based mode's own,
        :data:`headplod.plod.select.DEFAULT_CSF_MODEL`).
    csf_modes : tuple of str or None
        The modes whose CSF ``--csf`` sets; None: every mode it draws.
    compare : bool
        Its frame can be compared with ``full`` from the same view (``render --compare full``).
    mesh_options : bool
        Draws the scene's PLOD mesh, so takes its options (``--max-level``, ``--lazy``, ``--cache-mb``).
    lazy_mesh : bool
        Works over the lazy mesh (the ray mask casts rays against the whole ``full`` mesh, which the lazy mesh
        never holds).
    demo : bool
        The demo draws it live (the tessellation needs an OpenGL 4.3 context of its own).
    """

    name: str
    summary: str
    modes: tuple
    scenarios: tuple
    view_modes: tuple
    foveate: bool
    own_terrain: bool
    hysteresis: bool
    contrast_sources: tuple
    export: bool
    level_bias: bool
    budget: bool
    finest_level: str
    default_mode: str = "csf"
    csf_forms: tuple = ("kelly_scaled",)
    default_csf: str = "kelly_scaled"
    csf_modes: tuple | None = None
    compare: bool = True
    mesh_options: bool = True
    lazy_mesh: bool = True
    demo: bool = True


CAPABILITIES = {
    "mesh": BackendCapabilities(
        "mesh", "a level per base triangle over an adaptive mesh, drawn indexed", MODES, UNCERTAINTY_MODES,
        VIEW_MODES, foveate=True, own_terrain=True, hysteresis=True, contrast_sources=("shading", "readback"),
        export=True, level_bias=True, budget=True,
        finest_level="--max-level 1..8 (above 5: lazy pieces; full up to 7)", default_mode=SelectorConfig().mode,
        csf_forms=CSF_MODELS, default_csf=", ".join(f"{m}: {f}" for m, f in DEFAULT_CSF_MODEL.items()),
        csf_modes=tuple(DEFAULT_CSF_MODEL)),
    "tessellation": BackendCapabilities(
        "tessellation", "the CSF per patch on the GPU, tessellated from a height texture", ("csf", "full"),
        UNCERTAINTY_MODES, ("shaded",), foveate=False, own_terrain=True, hysteresis=False,
        contrast_sources=("shading",), export=False, level_bias=True, budget=False,
        finest_level="one vertex per height sample (--grid-samples)", compare=False, mesh_options=False,
        lazy_mesh=False, demo=False),
    "raymask": BackendCapabilities(
        "raymask", "Murphy & Duchowski: rays through a CSF ray mask, no levels", ("csf",), UNCERTAINTY_MODES,
        ("shaded",), foveate=False, own_terrain=True, hysteresis=False, contrast_sources=("shading",),
        export=False, level_bias=False, budget=False,
        finest_level="the whole-table mesh's finest level (--max-level up to 5)",
        csf_forms=RAYMASK_CSF_MODELS, default_csf=RayMaskConfig.csf_model, lazy_mesh=False),
}
#: The back ends, in the order the tools list them.
BACKENDS = tuple(CAPABILITIES)
#: The back ends the demo draws live (:attr:`BackendCapabilities.demo`).
DEMO_BACKENDS = tuple(name for name, cap in CAPABILITIES.items() if cap.demo)


def default_mode(backend: str) -> str:
    """The mode ``backend`` draws when no ``--mode`` is given (:attr:`BackendCapabilities.default_mode`;
    the mesh back end's for an unknown name, which :func:`options_problem` then refuses)."""
    return CAPABILITIES.get(backend, CAPABILITIES["mesh"]).default_mode


def options_problem(backend: str, *, mode: str = "csf", uncertainty: str = "adaptive", view_mode: str = "shaded",
                    foveate: bool = False, contrast: str = "shading", export: bool = False,
                    terrain: bool = False, level_bias: bool = False, budget: bool = False,
                    csf: str | None = None, compare: bool = False, mesh_options: tuple = ()) -> str | None:
    """One line saying which option ``backend`` does not support, or None when it supports them all.

    ``csf``: the CSF form asked for (``--csf``), or None for the back end's own; ``compare``: ``--compare full``
    asked for; ``mesh_options``: the mesh options given (their names, e.g. ``("--max-level",)``)."""
    if backend not in CAPABILITIES:
        return f"unknown back end {backend!r}; choose one of {', '.join(BACKENDS)}"
    cap = CAPABILITIES[backend]
    if csf is not None and cap.csf_modes is not None and mode not in cap.csf_modes:
        return (f"--csf sets the CSF of the CSF-based modes ({', '.join(cap.csf_modes)}); --mode {mode} has "
                "none")
    bad = [text for text, ok in (
        (f"--mode {mode} (modes: {', '.join(cap.modes)})", mode in cap.modes),
        (f"--uncertainty {uncertainty}", uncertainty in cap.scenarios),
        (f"--view {view_mode} (views: {', '.join(cap.view_modes)})", view_mode in cap.view_modes),
        ("--foveate", cap.foveate or not foveate),
        (f"--contrast {contrast}", contrast in cap.contrast_sources),
        ("--export", cap.export or not export),
        ("--terrain", cap.own_terrain or not terrain),
        ("--level-bias", cap.level_bias or not level_bias),
        ("--budget", cap.budget or not budget),
        (f"--csf {csf} (forms: {', '.join(cap.csf_forms)}"
         + ("; Geisler-Perry is --mode gp)" if csf == "gp" and "gp" in cap.modes else ")"),
         csf is None or csf in cap.csf_forms)) if not ok]
    if bad:
        return f"--backend {backend} does not take {', '.join(bad)}"
    if compare and not cap.compare:
        return (f"--backend {backend} does not take --compare (use "
                f"{' or '.join(n for n, c in CAPABILITIES.items() if c.compare)})")
    if mesh_options and not cap.mesh_options:
        return f"--backend {backend} does not take {', '.join(mesh_options)} (its detail is --grid-samples)"
    return None


def capability_table(markdown: bool = False) -> str:
    """The capability table as text (``--help``; ``markdown``: for the docs)."""
    yes = {True: "yes", False: "no"}
    rows = [("back end", "modes", "default mode", "scenarios", "views", "foveate", "own terrain", "hysteresis",
             "level bias", "budget", "CSF forms (default)", "finest level")]
    for cap in CAPABILITIES.values():
        rows.append((cap.name, ", ".join(cap.modes) if cap.modes != MODES else "all", cap.default_mode,
                     "all" if cap.scenarios == UNCERTAINTY_MODES else ", ".join(cap.scenarios),
                     ", ".join(cap.view_modes), yes[cap.foveate], yes[cap.own_terrain], yes[cap.hysteresis],
                     yes[cap.level_bias], yes[cap.budget],
                     f"{', '.join(cap.csf_forms)} ({cap.default_csf})",
                     cap.finest_level))
    if markdown:
        lines = ["| " + " | ".join(r) + " |" for r in rows]
        lines.insert(1, "|" + "---|" * len(rows[0]))
        return "\n".join(lines)
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]) - 1)]
    return "\n".join("  ".join(v.ljust(w) for v, w in zip(r[:-1], widths)) + "  " + r[-1] for r in rows)


def px_per_deg_at(screen, eye_mm, size) -> float:
    """Image pixels per degree of visual angle at the screen centre, seen from ``eye_mm`` (3,) world mm.

    ``size`` (width, height) image px.
    """
    centre = screen.pixel_to_world(np.array(screen.size_px, dtype=np.float64) / 2.0)
    width_mm = float(np.linalg.norm(np.asarray(screen.top_right) - screen.top_left))
    distance = float(np.linalg.norm(centre - np.asarray(eye_mm, dtype=np.float64)))
    return distance * np.tan(np.radians(1.0)) * size[0] / width_mm


@dataclass
class FrameOutput:
    """One frame's image and what made it.

    Attributes
    ----------
    image : (H, W, 3) uint8
        RGB, row 0 at the top.
    view : ConditionedView
        The conditioned view the frame was made for.
    levels : (F,) int64 or None
        Level per base triangle (``mesh``); None where the back end keeps its levels on the GPU or has none.
    triangle_levels : (T,) uint8 or None
        Level per drawn triangle (``mesh``).
    triangles : int
        Triangles drawn (rasterised, for ``raymask``; generated, for ``tessellation``).
    held : bool
        The last levels were kept (a saccade).
    stage_ms : dict
        ``select``, ``build``, ``upload``, ``render``, ``readback``: ms.
    details : dict
        The back end's own figures (layers, draw calls, ray counts, lazy cache: JSON-ready).
    """

    image: np.ndarray
    view: ConditionedView
    levels: np.ndarray | None
    triangle_levels: np.ndarray | None
    triangles: int
    held: bool
    stage_ms: dict
    details: dict = field(default_factory=dict)


class Backend:
    """What a back end does in a frame: select (or not) and draw. Subclasses set ``name``.

    ``select(cv)`` returns levels (or None when the back end selects on the GPU or not at all);
    ``draw(cv, levels, camera, model, view_mode)`` returns (image, triangles drawn, stage ms, details).
    ``camera`` is (view (4, 4), proj (4, 4)) from the raw eye; ``model`` (4, 4) scene → world mm.
    """

    name = ""

    def select(self, cv: ConditionedView):
        return None

    def draw(self, cv: ConditionedView, levels, camera, model, view_mode: str):
        raise NotImplementedError

    def reset(self) -> None:
        """Forget per-run state (a new setting or a new run)."""


class MeshBackend(Backend):
    """Levels per base triangle over an adaptive mesh, drawn indexed (optionally as foveated layers).

    Parameters
    ----------
    mesh : headplod.plod.mesh.AdaptiveMesh or LazyAdaptiveMesh
        This back end's own build state (:meth:`share` of a scene's mesh when several run side by side).
    selector : headplod.plod.select.LevelSelector
    renderer : headplod.render.gl.TerrainRenderer
    foveated : headplod.render.foveate.FoveatedRenderer or None
        Draw foveated layers about the conditioned POI, held by ``anchor``.
    anchor : headplod.render.foveate.LayerAnchor or None
    foveation : headplod.render.foveate.FoveationConfig or None
    screen : headplod.io.Screen
    """

    name = "mesh"

    def __init__(self, mesh, selector, renderer, screen, *, foveated=None, anchor=None, foveation=None):
        self.mesh, self.selector, self.renderer, self.screen = mesh, selector, renderer, screen
        self.foveated, self.anchor, self.foveation = foveated, anchor, foveation
        self._uploaded = None          # the index array the renderer (or the layers) last received
        self.last_info = None          # the last selection's per-triangle features (LevelSelector.select's dict)

    def select(self, cv):
        levels, self.last_info = self.selector.select(cv)
        return levels

    def reset(self) -> None:
        self.selector.reset()
        if self.anchor is not None:
            self.anchor.reset()

    def draw(self, cv, levels, camera, model, view_mode):
        t0 = time.perf_counter()
        mesh = self.mesh
        indices, tri_levels = mesh.update_indices(levels)
        t1 = time.perf_counter()
        self._upload(indices, tri_levels)
        t2 = time.perf_counter()
        details = {}
        if self.foveated is not None:
            image = self._draw_foveated(cv, camera, model, view_mode)
            renderer = self.foveated
            details["foveate_layers"] = [{"scale": l.scale, "inner_deg": round(l.inner_deg, 3),
                                          "outer_deg": None if np.isinf(l.outer_deg) else round(l.outer_deg, 3)}
                                         for l in self.anchor.layers]
        else:
            image = self.renderer.render(*camera, model, view_mode=view_mode)
            renderer = self.renderer
        stage = {"build": (t1 - t0) * 1e3, "upload": (t2 - t1) * 1e3, "render": renderer.last_render_ms,
                 "readback": renderer.last_readback_ms}
        if self.foveated is not None:            # the layers' face spans and index re-sort
            stage["upload"] += self.foveated.last_sort_ms
        config = self.selector.config
        if config.budget_triangles is not None and self.last_info is not None:
            details["budget_bias"] = float(self.last_info["budget_bias"])
            details["budget"] = budget_outcome(config.budget_triangles, len(tri_levels),
                                               self.last_info.get("budget_reach"), config.budget_tolerance,
                                               details["budget_bias"])
        if mesh.kind == "lazy":
            details["cache_bytes"] = int(mesh.cache_bytes)
            details["lazy"] = {k: int(mesh.stats.get(k, 0)) for k in ("rebuilt_faces", "generated_pieces",
                                                                       "vertices")}
        return image, tri_levels, stage, details

    def _upload(self, indices, tri_levels) -> None:
        """The vertex table once per renderer; then only a new selection's indices and levels."""
        mesh, renderer = self.mesh, self.renderer
        new_table = renderer.tag is not mesh.vertex_positions
        if new_table:
            # The colours span the whole terrain's heights, not the uploaded vertices': a height keeps
            # its colour whichever pieces a frame draws (and on either kind of mesh).
            z_range = (float(mesh.z_range[:, 0].min()), float(mesh.z_range[:, 1].max()))
            renderer.upload(mesh.vertex_positions, mesh.vertex_normals, tri_levels, indices, tag=mesh.vertex_positions,
                            height_range=z_range)
        if self.foveated is not None and (new_table or self._uploaded is not indices):
            self.foveated.set_mesh(indices, tri_levels, mesh.face_per_triangle(), (mesh.corners, mesh.z_range))
        elif not new_table and self._uploaded is not indices:
            renderer.set_indices(indices, tri_levels)
        self._uploaded = indices

    def _draw_foveated(self, cv, camera, model, view_mode):
        """The layers about the conditioned POI (held by the anchor), widened by the scenario's covariance."""
        from .foveate import layer_plan

        w, h = self.renderer.size
        ppd = px_per_deg_at(self.screen, cv.raw_eye_mm, (w, h))
        poi, layers = self.anchor.update(screen_to_image_px(cv.poi_px, self.screen.size_px, (w, h)),
                                         layer_plan(ppd, cv.cov_deg2, self.foveation), ppd)
        return self.foveated.render(*camera, model, poi, ppd, cv.cov_deg2, view_mode=view_mode, layers=layers)


class TessellationBackend(Backend):
    """The CSF per patch on the GPU; ``mode`` ``csf`` or ``full`` (the reference).

    ``renderer``: a :class:`headplod.render.tessellate.TessellationRenderer`.
    """

    name = "tessellation"

    def __init__(self, renderer, mode: str = "csf", *, region_ndc=None, supersample: int = 1):
        self.renderer, self.mode = renderer, mode
        self.region_ndc, self.supersample = region_ndc, supersample

    def draw(self, cv, levels, camera, model, view_mode):
        r = self.renderer
        image = r.render(*camera, model, cv, mode=self.mode, region_ndc=self.region_ndc,
                         supersample=self.supersample)
        stage = {"select": r.last_setup_ms, "render": r.last_render_ms}
        return image, None, stage, {"draw_calls": r.last_draw_calls, "patches": r.last_nodes,
                                    "triangles": int(r.last_triangles)}


class RayMaskBackend(Backend):
    """Murphy & Duchowski's hybrid frame about the conditioned POI, widened by the scenario's covariance.

    ``renderer``: a :class:`headplod.render.raymask.RayMaskRenderer`; ``config``: its
    :class:`headplod.plod.raymask.RayMaskConfig`; ``screen``: the screen.
    """

    name = "raymask"

    def __init__(self, renderer, screen, config=None):
        from ..plod.raymask import RayMaskConfig

        self.renderer, self.screen = renderer, screen
        self.config = config or RayMaskConfig()

    def draw(self, cv, levels, camera, model, view_mode):
        rr = self.renderer
        mask = rr.mask(self.screen, cv.raw_eye_mm, cv.poi_px, px_per_deg_at(self.screen, cv.raw_eye_mm, rr.size),
                       cv.cov_deg2, self.config)
        image = rr.render(mask, *camera, model, self.config)
        st = rr.last_stats
        details = {"raymask": {**{k: v for k, v in st.items() if k != "render_ms"},
                               "inset_deg": self.config.inset_deg, "csf_model": self.config.csf_model,
                               "mask_contrast": self.config.contrast, "silhouettes": bool(self.config.silhouettes),
                               "fill_radius_deg": round(mask.r_fill_deg, 3), "rings": int(len(mask.rings_deg)),
                               "angles": int(mask.n_angles)},
                   "triangles": 2 * int(st["drawn_quads"])}
        return image, None, {"select": rr.last_mask_ms, "render": st["render_ms"]}, details


class FrameStep:
    """One PLOD frame from a raw view (module notes): condition, select, draw.

    Parameters
    ----------
    backend : Backend
    screen : headplod.io.Screen
    config : SelectorConfig
        The view conditioning's settings (its filters, scenario, saccade hold, gaze prior).

    Made by :func:`make_frame_step` (the one place a step is assembled) from :class:`FrameSettings`.
    """

    def __init__(self, backend: Backend, screen, config: SelectorConfig):
        self.backend, self.screen, self.config = backend, screen, config
        self.conditioner = ViewConditioner(screen, config)
        self.levels = None             # the last levels (kept during a saccade)

    def reset(self) -> None:
        """Forget the filters, the scenario's memory, the hysteresis and the last levels."""
        self.conditioner.reset()
        self.backend.reset()
        self.levels = None

    def __call__(self, view: View, model, view_mode: str = "shaded") -> FrameOutput:
        """The frame of ``view`` (raw :class:`View`) with the scene placed by ``model`` (4, 4) scene → world mm."""
        t0 = time.perf_counter()
        cv = self.conditioner(view)
        held = cv.saccade and self.levels is not None
        if not held:
            self.levels = self.backend.select(cv)
        t1 = time.perf_counter()
        camera = off_axis_projection(cv.raw_eye_mm, self.screen, near_mm=NEAR_MM, far_mm=FAR_MM)
        image, tri_levels, stage, details = self.backend.draw(cv, self.levels, camera, model, view_mode)
        stage = {"select": 0.0, "build": 0.0, "upload": 0.0, "readback": 0.0, **stage}
        stage["select"] += (t1 - t0) * 1e3
        triangles = details.pop("triangles", None)
        if triangles is None:
            triangles = 0 if tri_levels is None else int(len(tri_levels))
        return FrameOutput(image, cv, self.levels, tri_levels, int(triangles), bool(held), stage, details)


@dataclass(frozen=True)
class FrameSettings:
    """Every setting of a frame step (:func:`make_frame_step`): what draws, what it selects for, and how.

    Attributes
    ----------
    backend : str
        One of :data:`BACKENDS` (default ``mesh``).
    selection : SelectorConfig or None
        Mode, uncertainty scenario, level bias, budget, CSF form, gaze prior, hysteresis, ... and the view
        conditioning's settings (its filters, saccade hold). None: the defaults for the back end's own mode
        (:attr:`BackendCapabilities.default_mode`; its gaze prior is that mode's own). The ``tessellation``
        back end draws ``selection.mode`` (``csf``, or ``full``: the reference).
    foveate : bool
        ``mesh``: draw foveated resolution layers about the conditioned POI (:mod:`headplod.render.foveate`).
    foveation : FoveationConfig or None
        The layers' settings (None: ``FoveationConfig()``).
    raymask : RayMaskConfig or None
        ``raymask``: the ray mask's settings (None: ``RayMaskConfig()``).
    region_ndc : (4,) float or None
        ``tessellation``: draw only this rectangle (x0, y0, x1, y1) of normalised device coordinates.
    supersample : int
        ``tessellation``: samples per pixel side (1: none).
    draw : bool
        False: select only, nothing drawn (``mesh``; selection benchmarks over grids that have no mesh): a
        frame's image is None and its triangles 0.
    """

    backend: str = "mesh"
    selection: SelectorConfig | None = None
    foveate: bool = False
    foveation: object = None
    raymask: RayMaskConfig | None = None
    region_ndc: tuple | None = None
    supersample: int = 1
    draw: bool = True

    def __post_init__(self):
        if self.backend not in CAPABILITIES:
            raise ValueError(f"FrameSettings: unknown back end {self.backend!r}; choose one of {', '.join(BACKENDS)}")
        cap = CAPABILITIES[self.backend]
        if self.selection is None:
            object.__setattr__(self, "selection", SelectorConfig(mode=cap.default_mode))
        problem = options_problem(self.backend, mode=self.selection.mode, uncertainty=self.selection.uncertainty,
                                  foveate=self.foveate)
        if problem:
            raise ValueError(f"FrameSettings: {problem}")
        if not self.draw and self.backend != "mesh":
            raise ValueError(f"FrameSettings: draw=False is the mesh back end's (selection only), not {self.backend}'s")
        if not (isinstance(self.supersample, (int, np.integer)) and self.supersample >= 1):
            raise ValueError(f"FrameSettings: supersample must be a whole number >= 1, got {self.supersample!r}")


def budget_outcome(budget: int, drawn: int, reach, tolerance: float, bias: float) -> dict:
    """Whether a frame met its triangle budget, and if not the nearest count it could reach (a frame's stats).

    Parameters
    ----------
    budget : int
        The budget, triangles (:attr:`SelectorConfig.budget_triangles`).
    drawn : int
        The frame's triangles.
    reach : (2,) int or None
        (coarsest, finest): the triangles of the frame with every seen base triangle at level 0 and at the finest
        level (the selector's ``budget_reach``); None: not known.
    tolerance : float
        The fraction of the budget it is met within (:attr:`SelectorConfig.budget_tolerance`).
    bias : float
        The level bias the budget chose, levels.

    Returns
    -------
    dict
        ``triangles`` (the budget), ``met`` (``drawn`` within ``tolerance`` of it), ``nearest`` (``drawn`` when
        not met, else None), ``limit`` (``coarsest`` or ``finest`` when the budget lies beyond what this view's
        terrain allows, else None: met, or missed between two counts a whole base triangle apart),
        ``reachable`` ([coarsest, finest] or None) and ``bias``.
    """
    met = abs(drawn - budget) <= tolerance * budget
    limit = None
    if not met and reach is not None:
        limit = "coarsest" if budget < reach[0] else "finest" if budget > reach[1] else None
    return {"triangles": int(budget), "met": bool(met), "nearest": None if met else int(drawn), "limit": limit,
            "reachable": None if reach is None else [int(reach[0]), int(reach[1])], "bias": float(bias)}


class SelectionOnlyBackend(MeshBackend):
    """The mesh back end's selection (:meth:`MeshBackend.select`) with nothing drawn (``FrameSettings.draw``
    false): a frame's image is None and its triangles 0."""

    def __init__(self, selector, screen):
        super().__init__(None, selector, None, screen)

    def draw(self, cv, levels, camera, model, view_mode):
        return None, None, {}, {}


def make_backend(settings: FrameSettings, screen, *, renderer=None, scene=None, mesh=None, selector=None,
                 foveated=None, anchor=None) -> Backend:
    """The back end of ``settings`` over the parts a caller owns (:func:`make_frame_step`'s parameters)."""
    config = settings.selection
    if settings.backend == "tessellation":
        return TessellationBackend(renderer, config.mode, region_ndc=settings.region_ndc,
                                   supersample=settings.supersample)
    if settings.backend == "raymask":
        return RayMaskBackend(renderer, screen, settings.raymask)
    selector = scene.selector(config.mode, config.uncertainty, config) if selector is None else selector
    if not settings.draw:                # (no mesh: grids of a selection bench have none)
        return SelectionOnlyBackend(selector, screen)
    mesh = scene.mesh if mesh is None else mesh
    if settings.foveate:
        from .foveate import FoveatedRenderer, FoveationConfig, LayerAnchor

        foveated = foveated or FoveatedRenderer(renderer, settings.foveation or FoveationConfig())
        anchor = anchor or LayerAnchor()
    return MeshBackend(mesh, selector, renderer, screen, foveated=foveated if settings.foveate else None,
                       anchor=anchor, foveation=foveated.config if foveated is not None else settings.foveation)


def make_frame_step(settings: FrameSettings, screen, *, renderer=None, scene=None, mesh=None, selector=None,
                    foveated=None, anchor=None) -> FrameStep:
    """The one place a :class:`FrameStep` is assembled: ``settings``' back end over the parts a caller owns.

    Parameters
    ----------
    settings : FrameSettings
    screen : headplod.io.Screen
    renderer
        The back end's renderer: a :class:`headplod.render.gl.TerrainRenderer` (``mesh``), a
        :class:`headplod.render.tessellate.TessellationRenderer` or a
        :class:`headplod.render.raymask.RayMaskRenderer`; None for ``draw=False``.
    scene : headplod.render.still.TerrainScene or None
        ``mesh``: the scene whose mesh and selector (:meth:`TerrainScene.selector` of ``settings.selection``)
        are used, unless ``mesh`` or ``selector`` are given.
    mesh, selector
        ``mesh``: this step's own build state (e.g. ``scene.mesh.share()`` when steps run side by side) and
        level selector (any with :class:`headplod.plod.select.LevelSelector`'s ``select(cv)``).
    foveated, anchor
        ``mesh`` with ``settings.foveate``: layers and their anchor shared between steps (the demo's); made
        here when None.
    """
    return FrameStep(make_backend(settings, screen, renderer=renderer, scene=scene, mesh=mesh, selector=selector,
                                  foveated=foveated, anchor=anchor), screen, settings.selection)


def one_frame(settings: FrameSettings, screen, model, head_mm=None, poi_px=None, cov_deg2=None, *,
              t: float | None = 0.0, view_mode: str = "shaded", **parts) -> FrameOutput:
    """One frame of a fresh frame step (:func:`make_frame_step` of ``settings`` and ``parts``): a still view,
    no history.

    ``head_mm`` (3,) world mm (default 600 mm in front of the screen centre), ``poi_px`` (2,) screen px
    (default the centre), ``cov_deg2`` (2, 2) deg² or None, ``t`` s (the back end keeps its own last
    frame, e.g. for the tessellation's angular speeds).
    """
    step = make_frame_step(settings, screen, **parts)
    return step(still_view(screen, head_mm, poi_px, cov_deg2, t), model, view_mode)
