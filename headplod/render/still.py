"""The terrain scene (:class:`TerrainScene`) and ``headplod render``'s one frame (:func:`render_still`).

The frame itself is made by the one frame step, :mod:`headplod.render.frame`,
as the demo and the benchmarks make theirs; here are the scene it draws (the
terrain, its meshes and where it sits behind the screen), the mesh options of
the command lines and the one-frame outputs.
"""
from __future__ import annotations

import dataclasses
import errno
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..plod.contrast import project_to_screen_px, readback_contrast
from ..io import encode_image, write_atomically
from ..plod.export import export_mesh
from ..plod.lazy_mesh import DEFAULT_CACHE_BYTES, LazyAdaptiveMesh
from ..plod.mesh import AdaptiveMesh, BaseMesh
from ..plod.mesh_base import FULL_MAX_LEVEL
from ..plod.select import LevelSelector, SelectorConfig
from ..plod.terrain import Terrain
from ..plod.view import default_head, still_view  # noqa: F401 (default_head: the scene's default eye, re-exported)
from .context import create_context
from .frame import CAPABILITIES, FrameSettings, make_frame_step, options_problem, px_per_deg_at
from .gl import TerrainRenderer
from .overlay import overlay_poi
from .projection import scene_to_world, screen_fit, screen_to_image_px

# Where the terrain sits: its centre 250 mm behind the screen, 30 km shown as
# about 600 mm, seen from above at 35° (pitch 55° from the "window" pose).
SCALE_MM_PER_M = 0.02
DEPTH_MM = 250.0
PITCH_DEG = 55.0
#: The span the scale and the demo's viewpoints were chosen for: the built-in terrain's longer side, m.
#: Another terrain is scaled by ``fit = FRAME_SPAN_M / its span`` (:func:`fit_scale`) to be framed alike.
FRAME_SPAN_M = 31_700.0

#: Finest level of the meshes (``--max-level``): 1..8 (8: 134 M triangles at full detail on the 32 x 32 base).
MAX_LEVELS = range(1, 9)
#: Default finest level: the whole-table :class:`AdaptiveMesh`, 1025 x 1025 samples, 2.1 M triangles.
DEFAULT_MAX_LEVEL = 5
#: Finest level the whole-table :class:`AdaptiveMesh` is used for; above it the scene's mesh is a
#: :class:`LazyAdaptiveMesh` (its table would be about 190 MB at level 6, 750 MB at 7, 3 GB at 8: 4x a level).
TABLE_MAX_LEVEL = 5
#: Shortest synthetic detail wave of the built-in terrain at the default level, m (``Terrain``'s default).
BUILTIN_DETAIL_M = 60.0

#: Where a triangle's contrast comes from (``render_still(contrast=...)``, ``headplod render --contrast``):
#: the shading, or the paper's window read back from a first frame.
CONTRAST_SOURCES = ("shading", "readback")


@dataclass
class TerrainScene:
    """The terrain, its base mesh and adaptive mesh, placed behind a screen."""

    terrain: Terrain
    mesh: AdaptiveMesh | LazyAdaptiveMesh
    model: np.ndarray           # (4, 4) scene (m) → world (mm)
    screen: object
    fit: float = 1.0            # scale factor of SCALE_MM_PER_M and the viewpoints' scales (1: the built-in)

    @classmethod
    def build(cls, screen, max_level: int = DEFAULT_MAX_LEVEL, terrain: Terrain | None = None, *,
              lazy: bool | None = None, cache_bytes: int = DEFAULT_CACHE_BYTES) -> "TerrainScene":
        """The scene of ``terrain`` (default: the built-in Jacksboro terrain), framed by :func:`fit_scale`.

        Any terrain gets the same base: a 32 x 32 grid over its extent,
        refined to ``max_level``: ``32 * 2**max_level + 1`` samples per side
        at full detail (1025 at level 5, 4097 at 7), sampled from the
        terrain's own interpolant, so a DEM finer than 1025 samples shows
        its detail where the selection asks for those levels.

        ``lazy``: the mesh is a :class:`LazyAdaptiveMesh` (pieces made for
        what a frame draws, in a cache of ``cache_bytes``) instead of the
        whole-table :class:`AdaptiveMesh`; default: above
        :data:`TABLE_MAX_LEVEL`. At level 5 both draw the same triangles.

        The built-in terrain's synthetic detail reaches down to twice the
        finest level's vertex spacing: 60 m at level 5 (as before), halved
        per level above it (30 m at 6, 15 m at 7), so finer levels have
        detail to show (and no aliasing); ``--terrain`` files get no
        synthetic detail at any level.
        """
        if not isinstance(max_level, (int, np.integer)) or not 0 <= max_level <= MAX_LEVELS.stop - 1:
            raise ValueError(f"max_level must be an integer in 0..{MAX_LEVELS.stop - 1}, got {max_level!r}")
        lazy = max_level > TABLE_MAX_LEVEL if lazy is None else bool(lazy)
        fit = 1.0 if terrain is None else fit_scale(terrain)
        terrain = Terrain.jacksboro(**builtin_terrain_options(max_level)) if terrain is None else terrain
        base = BaseMesh.grid(terrain)
        if lazy:
            mesh = LazyAdaptiveMesh(base, terrain, max_level=max_level, cache_bytes=cache_bytes)
        else:
            mesh = AdaptiveMesh(base, terrain, max_level=max_level)
        model = scene_model(terrain.extent, float(np.median(terrain.dem_z_m)), screen, fit)
        return cls(terrain, mesh, model, screen, fit)

    def selector(self, mode: str, uncertainty: str, config: SelectorConfig | None = None,
                 **settings) -> LevelSelector:
        """A level selector for this scene's mesh.

        ``mode``, ``uncertainty`` and the keyword ``settings`` (any other
        :class:`SelectorConfig` field, e.g. ``hysteresis=False``) replace
        those of ``config`` (default ``SelectorConfig()``).
        """
        config = SelectorConfig() if config is None else config
        config = dataclasses.replace(config, mode=mode, uncertainty=uncertainty, **settings)
        m = self.mesh
        return LevelSelector(m.centroids, m.edge_length, m.geometric_error, m.contrast, self.model, self.screen,
                             config, corners_scene=m.corners, triangle_count=m.triangle_count,
                             change=(m.change_contrast, m.normal_axis, m.normal_cone_deg))


def scene_model(extent, centre_z_m: float, screen, fit: float = 1.0) -> np.ndarray:
    """(4, 4) scene (m) → world (mm) placing a terrain behind the screen, as every back end places it.

    ``extent`` (x0, x1, y0, y1) scene m; the terrain's centre at height
    ``centre_z_m`` sits :data:`DEPTH_MM` behind the screen centre, at
    ``SCALE_MM_PER_M * fit`` mm per m times :func:`screen_fit` (a wider screen is filled too), seen from above
    at :data:`PITCH_DEG`.
    """
    x0, x1, y0, y1 = extent
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, float(centre_z_m)])
    return np.asarray(scene_to_world(SCALE_MM_PER_M * fit * screen_fit(screen), centre, screen, depth_mm=DEPTH_MM,
                                     pitch_deg=PITCH_DEG).matrix, dtype=np.float64)


def builtin_terrain_options(max_level: int) -> dict:
    """``Terrain.jacksboro`` options for a mesh of ``max_level``: {} up to level 5 (the built-in scene as it
    is), else the detail's shortest wave halved per level above 5 (``BUILTIN_DETAIL_M / 2**(max_level - 5)``)."""
    if max_level <= DEFAULT_MAX_LEVEL:
        return {}
    return {"detail_min_wavelength_m": BUILTIN_DETAIL_M / 2 ** (max_level - DEFAULT_MAX_LEVEL)}


@dataclass(frozen=True)
class MeshOptions:
    """The scene's mesh: ``--max-level``, ``--lazy``, ``--cache-mb``.

    Attributes
    ----------
    max_level : int
        Finest level, 0..8 (the commands take 1..8); default 5: the 32 x 32 base to 1025 x 1025 samples.
    lazy : bool
        A :class:`LazyAdaptiveMesh`; always true above :data:`TABLE_MAX_LEVEL` (set so when made), false:
        the whole-table :class:`AdaptiveMesh`.
    cache_mb : float
        Budget of the lazy mesh's piece cache, MB (2**20 bytes), 1..65536; default 256.
    """

    max_level: int = DEFAULT_MAX_LEVEL
    lazy: bool = False
    cache_mb: float = DEFAULT_CACHE_BYTES / 2 ** 20

    def __post_init__(self):
        if not isinstance(self.max_level, (int, np.integer)) or not 0 <= self.max_level <= MAX_LEVELS.stop - 1:
            raise ValueError(f"max_level must be an integer in 0..{MAX_LEVELS.stop - 1}, got {self.max_level!r}")
        if not (math.isfinite(self.cache_mb) and 1 <= self.cache_mb <= 65536):
            raise ValueError(f"cache_mb must lie in 1..65536 MB, got {self.cache_mb!r}")
        object.__setattr__(self, "max_level", int(self.max_level))
        object.__setattr__(self, "lazy", bool(self.lazy) or self.max_level > TABLE_MAX_LEVEL)

    @property
    def cache_bytes(self) -> int:
        return int(self.cache_mb * 2 ** 20)

    def build(self, screen, terrain: Terrain | None = None) -> "TerrainScene":
        """``TerrainScene.build`` with these options."""
        return TerrainScene.build(screen, self.max_level, terrain=terrain, lazy=self.lazy,
                                  cache_bytes=self.cache_bytes)


def mesh_stats(mesh) -> dict:
    """What a frame's stats say of the mesh: ``kind`` (``table`` or ``lazy``), ``max_level``,
    ``full_triangles``; for a lazy mesh also the last frame's ``vertices`` (compact table rows) and its
    cache's ``cache_bytes`` and ``cache_budget_bytes``."""
    out = {"kind": mesh.kind, "max_level": int(mesh.max_level),
           "full_triangles": int(mesh.triangle_count(np.full(mesh.n_faces, mesh.max_level)))}
    if mesh.kind == "lazy":
        out.update(vertices=int(len(mesh.vertex_positions)), cache_bytes=int(mesh.cache_bytes),
                   cache_budget_bytes=int(mesh.budget_bytes))
    return out


def fit_scale(terrain) -> float:
    """Factor on the scene scale that frames ``terrain`` as the built-in one is framed.

    ``FRAME_SPAN_M`` over the larger of the terrain's width, depth and twice
    its relief (so a small, steep height map does not reach through the
    screen or past the far plane). The built-in scene uses 1 (not this
    function), so its framing stays as it was.
    """
    x0, x1, y0, y1 = terrain.extent
    relief = float(np.ptp(terrain.dem_z_m))
    return FRAME_SPAN_M / max(x1 - x0, y1 - y0, 2.0 * relief)




@dataclass(frozen=True)
class StillSettings:
    """One still frame (:func:`render_still`): what draws it and from which view, at what size, how coloured.

    Attributes
    ----------
    frame : FrameSettings
        The frame step's settings: back end, selection (mode, scenario, level bias, ...), foveation, ray mask.
    head_mm : (3,) float or None
        The eye, world mm; None: :func:`default_head`.
    poi_px : (2,) float or None
        The point of interest, screen px; None: the screen's centre.
    cov_deg2 : (2, 2) float or None
        Covariance of the viewing direction (φ, θ), deg²; None: none given.
    size : (2,) int
        Image (width, height), px.
    view_mode : str
        ``shaded``, ``wire`` or ``levels`` (:data:`headplod.render.frame.VIEW_MODES`; what the back end takes).
    contrast : str
        :data:`CONTRAST_SOURCES`: the shading's, or ``readback`` (the paper's eq. 2: each base triangle's
        contrast read from a 10x10 window of a first frame's luminance).
    export : Path or None
        Also write the frame's mesh here (:mod:`headplod.plod.export`; the command checks its ending and folder).
    overlay : bool
        Draw the POI cross and the covariance's ellipse (with ``cov_deg2`` or the levels view); False for a frame
        judged against a reference, which has no marker.

    The combination is checked against the back end's capabilities when made (ValueError, one line).
    """

    frame: FrameSettings = FrameSettings()
    head_mm: tuple | None = None
    poi_px: tuple | None = None
    cov_deg2: np.ndarray | None = None
    size: tuple = (1280, 720)
    view_mode: str = "shaded"
    contrast: str = "shading"
    export: Path | None = None
    overlay: bool = True

    def __post_init__(self):
        object.__setattr__(self, "size", tuple(int(v) for v in self.size))
        f = self.frame
        problem = options_problem(f.backend, mode=f.selection.mode, uncertainty=f.selection.uncertainty,
                                  view_mode=self.view_mode, foveate=f.foveate, contrast=self.contrast,
                                  export=self.export is not None)
        if problem:
            raise ValueError(f"StillSettings: {problem}")


def render_still(settings: StillSettings, screen, *, scene=None, renderer=None, raymask_renderer=None, model=None,
                 out=None, stats_path=None, details=None):
    """Render one frame of ``settings`` through the frame step (:func:`headplod.render.frame.make_frame_step`);
    (image (H, W, 3) uint8 RGB, stats dict).

    Per back end (``settings.frame.backend``):

    - ``mesh``: ``scene`` (default: the built-in :class:`TerrainScene`) and
      ``renderer`` (a :class:`TerrainRenderer` of ``settings.size``; made here when None);
    - ``tessellation``: ``renderer`` is a
      :class:`headplod.render.tessellate.TessellationRenderer` and ``model``
      (4, 4) its grid's scene → world mm (:func:`scene_model`);
    - ``raymask``: ``raymask_renderer`` is reused when given (its height field and last masks are kept).

    ``out``, ``stats_path``: the image and the stats (JSON) are written there; ``details``: more entries for
    the stats.
    """
    fs = settings.frame
    view = still_view(screen, settings.head_mm, settings.poi_px, settings.cov_deg2)
    if fs.backend == "tessellation":
        if renderer is None or model is None:
            raise ValueError("render_still: backend 'tessellation' needs its TessellationRenderer and model")
        step = make_frame_step(fs, screen, renderer=renderer)
        scene = None
    else:
        scene = scene or TerrainScene.build(screen)
        model = scene.model
        _check_scene(fs, scene)
        step = make_frame_step(fs, screen, scene=scene,
                               renderer=_renderer_for_scene(fs, scene, settings.size, renderer, raymask_renderer))
    readback_ms = None
    try:
        if settings.contrast == "readback":
            readback_ms = _read_back_contrast(step, view, scene)
        result = step(view, model, settings.view_mode)
    finally:
        if fs.foveate:
            step.backend.foveated.release()
    image = result.image
    if settings.overlay and (settings.cov_deg2 is not None or settings.view_mode == "levels"):
        image = overlay_poi(image, screen_to_image_px(view.poi_px, screen.size_px, settings.size),
                            settings.cov_deg2, px_per_deg_at(screen, view.eye_mm, settings.size))
    stats = _frame_stats(result, settings, view.eye_mm, view.poi_px, scene)
    stats["gaze_prior_deg"] = list(fs.selection.gaze_prior)       # the eye-in-head σ in use (given, or the mode's own)
    if readback_ms is not None:
        stats["readback_ms"] = readback_ms
    stats.update(details or {})
    write_outputs(image, stats, out, stats_path)
    if settings.export is not None:
        export_mesh(scene.mesh, result.levels, settings.export)
    return image, stats


def _check_scene(fs: FrameSettings, scene) -> None:
    """ValueError when ``scene``'s mesh cannot serve ``fs`` (a lazy mesh for a back end that needs the whole
    table, :attr:`BackendCapabilities.lazy_mesh`; ``full`` above :data:`FULL_MAX_LEVEL`)."""
    if not CAPABILITIES[fs.backend].lazy_mesh and not scene.mesh.has_full_table:
        raise ValueError(f"render_still: the {fs.backend} back end needs the whole-table mesh "
                         "(max_level <= 5, not lazy)")
    if fs.selection.mode == "full" and not scene.mesh.full_fits:
        raise ValueError(f"render_still: mode 'full' at max_level {scene.mesh.max_level} does not fit "
                         f"(at most {FULL_MAX_LEVEL})")


def _renderer_for_scene(fs: FrameSettings, scene, size, renderer, raymask_renderer):
    """The renderer of a one-frame render's mesh or raymask back end: the one given, else made here."""
    if fs.backend == "raymask":
        from .raymask import RayMaskRenderer

        rr = raymask_renderer
        if rr is None:
            ctx = renderer.ctx if renderer is not None else create_context()
            rr = RayMaskRenderer(ctx, scene.mesh, size=tuple(size))
        elif tuple(rr.size) != tuple(int(v) for v in size):
            raise ValueError(f"render_still: raymask_renderer is {rr.size}, the image {tuple(size)}")
        return rr
    return TerrainRenderer(create_context(), size=tuple(size)) if renderer is None else renderer


def _read_back_contrast(step, view, scene) -> float:
    """The paper's eq. 2: a first frame drawn, each base triangle's contrast read back; its ms."""
    selector = step.backend.selector
    shaded = step(view, scene.model, "shaded").image
    t0 = time.perf_counter()
    centroids_px = project_to_screen_px(selector.centroids_mm, np.asarray(view.eye_mm, float), scene.screen)
    selector.contrast = readback_contrast(shaded, centroids_px, scene.screen.size_px, fallback=scene.mesh.contrast)
    ms = step.backend.renderer.last_readback_ms + (time.perf_counter() - t0) * 1e3
    step.reset()
    return ms


def _frame_stats(result, settings: StillSettings, head, poi, scene) -> dict:
    """The stats of one rendered frame (``render_still``'s; ms, triangles, levels); ``head`` (3,) world mm,
    ``poi`` (2,) screen px: the view's."""
    fs = settings.frame
    backend, contrast = fs.backend, settings.contrast
    stats = {"backend": backend, "mode": fs.selection.mode, "uncertainty": fs.selection.uncertainty,
             "view": settings.view_mode, "size": list(settings.size),
             "head_mm": head.round(2).tolist(), "poi_px": poi.round(2).tolist(), "triangles": result.triangles,
             "select_ms": result.stage_ms["select"], "build_ms": result.stage_ms["build"],
             "render_ms": result.stage_ms["render"], "contrast": contrast, **result.details}
    if result.triangle_levels is not None:
        stats["triangles_per_level"] = np.bincount(result.triangle_levels,
                                                   minlength=scene.mesh.max_level + 1).tolist()
    if scene is not None and backend == "mesh":
        stats["mesh"] = mesh_stats(scene.mesh)
    source = getattr(scene.terrain, "source", None) if scene is not None else None    # a --terrain file
    if source is not None:
        stats["terrain"] = {"path": source.path, "kind": source.kind, "shape": list(scene.terrain.shape),
                            "spacing_m": [source.dx_m, source.dy_m], "filled_samples": source.filled,
                            "fit": scene.fit}
    return stats


def write_outputs(image: np.ndarray, stats: dict, out=None, stats_path=None) -> None:
    """Write the image (RGB (H, W, 3) uint8; format from the ending) and the stats (JSON), each whole or not at all.

    Raises ValueError when OpenCV cannot encode the image (an ending it does
    not know) and OSError when a file cannot be written; the OSError names
    ``out`` or ``stats_path`` as given, never the temporary name written first.
    """
    if out:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)

        def write_image(name: str) -> None:
            try:                                # encoded in memory: OpenCV never sees the path (io/images.py)
                data = encode_image(cv2.cvtColor(image, cv2.COLOR_RGB2BGR), out.suffix)
            except ValueError:
                raise ValueError(f"{out}: OpenCV could not write an image there (use .png or .jpg)") from None
            try:
                Path(name).write_bytes(data)
            except OSError as exc:
                raise OSError(exc.errno or errno.EIO, exc.strerror or "the image could not be written",
                              str(out)) from exc
        write_atomically(out, write_image, suffix=out.suffix)
    if stats_path:
        Path(stats_path).parent.mkdir(parents=True, exist_ok=True)
        write_atomically(stats_path, lambda name: Path(name).write_text(json.dumps(stats, indent=2)))

