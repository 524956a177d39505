"""PLOD on the GPU: a terrain of patches tessellated from a height texture, per-patch CSF levels as factors.

The second PLOD back end (issue 14), beside the CPU one (``LevelSelector`` +
``AdaptiveMesh`` + :class:`headplod.render.gl.TerrainRenderer`):

- The terrain is a :class:`headplod.plod.patches.PatchGrid`: an ``N x N``
  height grid (an R32F texture, mipmapped for the normals of coarse levels)
  cut into patches of ``patch_samples`` sample spacings, drawn as
  ``GL_PATCHES`` of one control point per patch (no vertex buffer: a
  patch is known by its ``gl_VertexID``).
- The view: every frame reads a
  :class:`headplod.plod.view.ConditionedView` (the filtered eye, the head
  axes, the covariance the uncertainty scenario gives, the time): the same
  conditioning as every other back end, so ``uncertainty="none"`` ignores
  the covariance here too. The settings the mesh back end takes from
  :class:`headplod.plod.select.SelectorConfig` (``shift``,
  ``ellipse_sigma``, ``level_bias``) come from the renderer's ``selection``.
- The CSF levels: a levels pass evaluates the ``csf`` rule of
  :mod:`headplod.plod.criteria` in closed form per patch, as
  :func:`headplod.plod.patches.patch_levels` does in numpy (tested equal,
  and the rule itself on a grid of inputs): the patch's inner level from
  its corners, each outer (edge) level from the edge alone (endpoints,
  midpoint, and the larger contrast of the two patches sharing it), so
  both patches sharing an edge compute the same factor: no cracks. Level L
  is the tessellation factor 2^L (``equal_spacing``); the finest level puts
  one vertex per height sample. The highest visible frequency (Lambert's
  W_{-1}) is solved by Newton's method in log form. Patches whose bounding
  box (corners' x, y; the patch's height range) is outside the view
  frustum are culled (:func:`headplod.plod.cull.box_outside_clip`'s test).
  The GLSL is :mod:`headplod.render.tess_shaders`, its constants generated
  from :mod:`headplod.plod.csf`'s. The same GLSL runs in the tessellation
  control shader (``csf_stage="control"``) or, by default, in a vertex
  shader of one vertex per patch (``"vertex"``): llvmpipe runs a control
  shader of one output vertex one patch at a time and a vertex shader
  several at a time (``headplod bench plod --scale``). Either writes the
  levels to a storage buffer; the draw's control shader turns them into
  tessellation factors.
- Or, with ``TessellationConfig.hierarchy``, a quadtree of variable-size
  patches (:class:`headplod.plod.patch_tree.PatchTree`): walked in numpy
  per frame, refined only where the CSF needs it, 2:1 balanced, with
  crack-free factors on transition edges. Its drawn nodes are uploaded as
  records (origin sample, size, inner and outer factors: 32 bytes a node) to
  a storage buffer the control and evaluation shaders read by the patch's
  ``gl_VertexID``; no levels pass. The CPU's share is the walk and the upload.
  ``mode="full"`` (the reference) always draws the flat grid.
- Two llvmpipe limits shape the draw. It numbers a draw call's tessellated
  vertices with 16 bits (past 65536, triangles join vertices of other
  patches), so the levels are read back (24 bytes per patch) and the
  patches split into draw calls of fewer than 65536 vertices. And its
  ``gl_PrimitiveID`` restarts within large draws, so a patch is known by
  its vertex's ``gl_VertexID``. Both are tested (watertightness over
  16384 patches, and at full detail across several draw calls).
- The evaluation shader places every vertex on a height sample (the tess
  coordinate rounded to the sample grid, so shared edge vertices are
  bit-identical).
- Shading (``TessellationConfig.shading``), with the one light of
  :mod:`headplod.plod.shading`. By default (``texture``) every sample's
  colour (``gl.py``'s terrain shading: Lambert + ambient times the height
  colour, with the sample's own normal from central differences, as
  :func:`headplod.plod.patches.grid_normals`) is baked once, on the GPU,
  into a mipmapped RGBA8 texture, and each fragment samples it trilinearly
  at the pixel's footprint. A pixel then shows the average colour of the
  samples it covers whichever level drew it: the geometry is PLOD's, the
  shading is prefiltered as terrain renderers do with colour or normal
  maps. Why: once a sample is smaller than a pixel, the full-detail
  render's per-vertex shading aliases and a coarser level's smoothed
  normals cannot match it (``tests/test_tessellate.py`` compares the two
  in the 5° disc). ``vertex`` keeps the per-vertex colour, with a coarse
  level's normal from the matching mip level of the heights (the surface
  that level can show). Anisotropic filtering (``anisotropy``) gained
  little for a much slower frame on llvmpipe, so it is off.

The CPU's share per frame is the uniforms, the read-back of the levels and
the split into draw calls (``headplod bench plod --scale``). Not here (yet):
hysteresis (per-patch state), the read-back contrast, the levels and wire
views.

Frames and units: scene metres → world mm by ``model``; matrices as in
:mod:`headplod.render.projection`; images as :mod:`headplod.render.gl`'s.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from ..plod import criteria
from ..plod import perception as pc
from ..plod.patch_tree import PatchTree
from ..plod.patches import FACTOR_RULES, PatchGrid, max_level_for, tess_factors
from ..plod.select import SelectorConfig
from ..plod.shading import AMBIENT, light_unit
from ..plod.view import ConditionedView
from . import tess_shaders as ts
from .context import moderngl
from .gl import _FRAGMENT_SHADER, BACKGROUND_RGB, FULLSCREEN_VERTEX_SHADER, read_rgb

__all__ = ["TessellationConfig", "TessellationRenderer", "TESS_MODES", "REQUIRED_GL", "grid_model"]

#: What the control shader computes: the CSF's levels, or every patch at the finest level (the reference).
TESS_MODES = ("csf", "full")

#: OpenGL version the back end needs: 4.0 for tessellation shaders; 4.3 for the storage buffers of the tests.
REQUIRED_GL = 400

#: Most vertices one draw call may tessellate: llvmpipe indexes them with 16 bits (``_draw_ranges``).
VERTICES_PER_DRAW = 65536


@dataclass(frozen=True)
class TessellationConfig:
    """Settings of the tessellation back end, each with its unit.

    Attributes
    ----------
    patch_samples : int
        Patch side, height-sample spacings (64): at the finest level a patch
        has ``patch_samples`` segments per side, one per sample. A power of
        two, 1..max_tess_level.
    max_tess_level : int
        Largest tessellation factor used, segments per patch side (64, GL's
        minimum ``GL_MAX_TESS_GEN_LEVEL``). A power of two.
    cull : bool
        Drop patches outside the view frustum in the control shader (True).
    smooth_normals : bool
        With ``shading="vertex"``: normals of a coarse level from the matching
        mip level of the heights (True); False: every vertex's normal from its
        neighbouring samples.
    shading : {"texture", "vertex"}
        ``texture`` (default): every height sample's colour (Lambert +
        ambient times the height colour, from the sample's own normal) is
        baked once into a mipmapped RGBA8 texture, sampled per fragment with
        trilinear (and ``anisotropy``) filtering at the pixel's footprint:
        what a pixel shows is the average of the samples it covers, whatever
        the level that drew it. ``vertex``: colour per vertex from the
        level's normal (``smooth_normals``), interpolated (``gl.py``'s way).
    anisotropy : float
        Texture anisotropy of ``texture`` shading, 1..16 (1: isotropic).
    csf_stage : {"vertex", "control"}
        Where the levels pass evaluates the CSF: a vertex shader, one vertex
        per patch (default: llvmpipe runs it 8 patches at a time), or the
        tessellation control shader (one patch at a time on llvmpipe, and
        again in the draw). Both write the same storage buffer; the draw's
        control shader turns its levels into factors.
    hierarchy : bool
        Select with :class:`headplod.plod.patch_tree.PatchTree` (a quadtree
        of patches of ``patch_samples * 2^k`` samples, walked in numpy, its
        nodes' factors uploaded as records; no levels pass) instead of the
        flat grid of patches evaluated on the GPU. Needs a power-of-two
        number of patches per side. ``mode="full"`` always draws the flat grid.
        Off by default: its selection grows far more slowly with the
        terrain than the flat path's, but its merged nodes draw more
        triangles (a node shows all its patches at its worst patch's
        bounded level), and llvmpipe's draw follows the triangles, so the
        frame is slower (``headplod bench plod --scale``).
    split_factor : int
        With ``hierarchy``: the largest tessellation factor (segments per
        side) of a node larger than a patch; a node that needs more is split
        (a power of two <= ``max_tess_level``; 16).
    factors : {"whole", "power_of_two"}
        How a patch's continuous level becomes its factor
        (:func:`headplod.plod.patches.tess_factors`): ``whole`` (default),
        the fewest segments that keep every gap within the level's vertex
        spacing; ``power_of_two``, 2^ceil(level) as the CPU mesh's integer
        levels (up to 2x the segments per side).
    """

    patch_samples: int = 64
    max_tess_level: int = 64
    cull: bool = True
    smooth_normals: bool = True
    shading: str = "texture"
    anisotropy: float = 1.0
    csf_stage: str = "vertex"
    hierarchy: bool = False
    split_factor: int = 16
    factors: str = "whole"

    def __post_init__(self):
        for name in ("patch_samples", "max_tess_level", "split_factor"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1 or v & (v - 1):
                raise ValueError(f"TessellationConfig.{name} must be a power of two >= 1, got {v!r}")
        if not isinstance(self.hierarchy, (bool, np.bool_)):
            raise ValueError(f"TessellationConfig.hierarchy must be a bool, got {self.hierarchy!r}")
        if self.split_factor > self.max_tess_level:
            raise ValueError(f"TessellationConfig.split_factor ({self.split_factor}) must be <= max_tess_level "
                             f"({self.max_tess_level})")
        if self.factors not in FACTOR_RULES:
            raise ValueError(f"TessellationConfig.factors must be one of {FACTOR_RULES}, got {self.factors!r}")
        if self.csf_stage not in ("vertex", "control"):
            raise ValueError(f"TessellationConfig.csf_stage must be 'vertex' or 'control', got {self.csf_stage!r}")
        if self.shading not in ("texture", "vertex"):
            raise ValueError(f"TessellationConfig.shading must be 'texture' or 'vertex', got {self.shading!r}")
        if not (isinstance(self.anisotropy, (int, float)) and 1.0 <= self.anisotropy <= 16.0):
            raise ValueError(f"TessellationConfig.anisotropy must be within 1..16, got {self.anisotropy!r}")

    @property
    def max_level(self) -> int:
        """Finest level: 2^max_level segments per patch side."""
        return max_level_for(self.patch_samples, self.max_tess_level)


def _split_draws(counts: np.ndarray, most: int) -> list:
    """Draw calls ``(first, count)`` over patches with these vertex bounds (0: not drawn), each < 65536 vertices.

    ``most``: the largest bound one patch can have; a call's patches are consecutive.
    """
    counts = np.asarray(counts, np.int64)
    group = (np.cumsum(counts) - counts) // (VERTICES_PER_DRAW - most)   # each group < VERTICES_PER_DRAW
    nz = np.flatnonzero(counts)
    if not len(nz):
        return []
    g = group[nz]
    cut = np.flatnonzero(np.diff(g)) + 1
    firsts = nz[np.concatenate(([0], cut))]
    lasts = nz[np.concatenate((cut - 1, [len(nz) - 1]))]
    return [(int(a), int(b - a + 1)) for a, b in zip(firsts, lasts)]


class TessellationRenderer:
    """Draw a :class:`PatchGrid` with per-patch CSF tessellation, offscreen.

    Parameters
    ----------
    ctx : moderngl.Context
        OpenGL >= 4.0 (``create_context(require=400)``; 4.3 for :meth:`levels`
        and the tests' ``triangle_samples``, tests/render_hooks.py).
    grid : PatchGrid
        The terrain; its ``patch_samples`` must equal ``config.patch_samples``.
    size : (width, height)
        Image size, px.
    config : TessellationConfig
    background : RGB in [0, 1]
        Clear colour (``TerrainRenderer``'s).
    selection : SelectorConfig
        The level rule's settings, as the mesh back end takes them: ``shift``,
        ``ellipse_sigma``, ``level_bias``. The rule is ``csf`` with the
        ``kelly_scaled`` CSF (``mode`` ``csf`` or ``full``; :meth:`render`'s
        ``mode`` picks which to draw).

    Every frame's view is a :class:`ConditionedView`: the eye, head axes,
    covariance and time the levels are chosen for; the angular speed is the
    motion of the eye since the view of the renderer's last call
    (:meth:`render`, :meth:`levels` or the tests' ``triangle_samples``).

    Attributes
    ----------
    last_render_ms : float
        Clear + draw + ``ctx.finish()`` of the last :meth:`render`, ms (no read-back).
    last_setup_ms : float
        Time from the frame's start to its draw (the selection's CPU share: the flat path's levels pass,
        read-back and split, or the hierarchy's walk and upload; the uniforms), ms.
    last_nodes : int
        Patches (flat) or nodes (hierarchy) the last frame drew.
    last_selection : NodeSelection or None
        The hierarchy's last selection.
    last_triangles : int
        Triangles the last :meth:`render` generated (``GL_PRIMITIVES_GENERATED``).
    height_range : (2,) float
        Scene z of the low and high terrain colours: the grid's range.
    """

    def __init__(self, ctx, grid: PatchGrid, size=(1280, 720), config: TessellationConfig = TessellationConfig(),
                 background=BACKGROUND_RGB, *, selection: SelectorConfig = SelectorConfig(mode="csf")):
        w, h = self._check(ctx, grid, size, config, selection)
        self.ctx, self.grid, self.config, self.size, self.selection = ctx, grid, config, (w, h), selection
        self.background = tuple(float(c) for c in background)
        self.last_render_ms = self.last_setup_ms = float("nan")
        self.last_triangles = 0
        z = grid.heights_m
        self.height_range = (float(z.min()), float(z.max()))
        n = z.shape[0]
        self._height = ctx.texture((n, n), 1, np.ascontiguousarray(z, np.float32).tobytes(), dtype="f4")
        if config.smooth_normals and config.shading == "vertex":     # only per-vertex shading reads the mips
            self._height.build_mipmaps()
            self._height.filter = (moderngl.LINEAR_MIPMAP_NEAREST, moderngl.LINEAR)
        else:
            self._height.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._height.repeat_x = self._height.repeat_y = False
        self._color = self._bake_colors() if config.shading == "texture" else None
        # The foveal f_max at the speed floor of each patch's contrast (the levels pass's still-head shortcut).
        fmax_still = criteria.foveal_fmax_cpd(grid.contrast.astype(np.float64), pc.MIN_SPEED_DEG_S)
        info = np.stack([grid.z_min_m, grid.z_max_m, grid.contrast, fmax_still], axis=-1)
        self._patch = ctx.texture((grid.n_patches, grid.n_patches), 4, info.astype(np.float32).tobytes(), dtype="f4")
        self._patch.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._programs = {}
        self._vaos = {}
        self._fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)],
                                    depth_attachment=ctx.depth_renderbuffer((w, h)))
        self._rgba = np.empty((h, w, 4), np.uint8)
        self._query = ctx.query(primitives=True)
        self._previous = None        # (eye_mm, t) of the last call's view, for the angular speed
        self._levels_buffer = None
        self.last_draw_calls = 0
        # The hierarchy: the tree's bounds (built once), the node records' buffer, the last selection.
        self._tree = (PatchTree(grid, config.split_factor, config.max_tess_level, factors=config.factors,
                                selection=selection, cull=config.cull) if config.hierarchy else None)
        self._node_buffer = None
        self._tree_frame = False
        self.last_selection = None
        self.last_nodes = 0

    @staticmethod
    def _check(ctx, grid, size, config, selection):
        """The arguments' errors, raised; the image's (width, height)."""
        if not isinstance(config, TessellationConfig):
            raise TypeError(f"TessellationRenderer: config must be a TessellationConfig, got {type(config).__name__}")
        if not isinstance(selection, SelectorConfig):
            raise TypeError(f"TessellationRenderer: selection must be a SelectorConfig, got {type(selection).__name__}")
        if selection.mode not in TESS_MODES or selection.csf != "kelly_scaled":
            raise ValueError(f"TessellationRenderer: the GPU evaluates csf with the kelly_scaled CSF (or full); "
                             f"got mode={selection.mode!r}, csf_model={selection.csf!r}")
        if ctx.version_code < REQUIRED_GL:
            raise RuntimeError(f"TessellationRenderer: needs OpenGL {REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10}, "
                               f"the context has {ctx.version_code}")
        if grid.patch_samples != config.patch_samples:
            raise ValueError(f"TessellationRenderer: grid has patches of {grid.patch_samples} samples, "
                             f"config.patch_samples is {config.patch_samples}")
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValueError(f"TessellationRenderer: size must be positive (width, height), got {size!r}")
        return w, h

    def _bake_colors(self):
        """The colour texture of ``texture`` shading: RGBA8 (n, n), every sample's colour, mipmapped.

        Drawn on the GPU (one fragment per sample) so no (n, n, 3) normal
        array is made on the CPU (at 8193² that array would not fit a small machine's memory).
        """
        ctx, cfg = self.ctx, self.config
        n = self.grid.heights_m.shape[0]
        texture = ctx.texture((n, n), 4, dtype="f1")
        fbo = ctx.framebuffer(color_attachments=[texture])
        prog = ctx.program(vertex_shader=FULLSCREEN_VERTEX_SHADER, fragment_shader=ts.BAKE_FRAGMENT)
        vao = ctx.vertex_array(prog, [])
        try:
            self._shade_uniforms(prog)
            prog["u_height"].value = 0
            prog["u_spacing_m"].value = (self.grid.dx_m, self.grid.dy_m)
            self._height.use(0)
            fbo.use()
            fbo.viewport = (0, 0, n, n)
            ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
            vao.render(moderngl.TRIANGLES, vertices=3)
            ctx.finish()
        finally:
            for obj in (vao, prog, fbo):
                obj.release()
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        texture.repeat_x = texture.repeat_y = False
        if cfg.anisotropy > 1:
            texture.anisotropy = float(cfg.anisotropy)
        return texture

    def _shade_uniforms(self, prog):
        """The light (:mod:`headplod.plod.shading`) and the colours' height range."""
        for name, value in (("u_light", tuple(light_unit())), ("u_ambient", float(AMBIENT)),
                            ("u_height_range", self.height_range)):
            if name in prog:
                prog[name].value = value

    # -- programs --------------------------------------------------------------

    def _program(self, kind: str):
        """``draw`` (image), ``levels`` (the levels pass: levels into the buffer), ``samples`` (triangles' samples);
        ``draw_tree``, ``samples_tree``: the same from the hierarchy's node records."""
        if kind not in self._programs:
            tree = kind.endswith("_tree")
            here = ("CSF_HERE",) if self.config.csf_stage == "control" else ()
            if tree:
                kind, here = kind[:-len("_tree")], ("TREE",)
            if kind == "levels" and self.config.csf_stage == "vertex":
                prog = self.ctx.program(vertex_shader=ts.LEVELS_VERTEX, fragment_shader=ts.NO_FRAGMENT)
            else:
                control = ts.variant(ts.CONTROL, "LEVELS_OUT") if kind == "levels" else ts.variant(ts.CONTROL, *here)
                textured = kind == "draw" and self.config.shading == "texture"
                evaluation = ts.variant(ts.EVALUATION, *(("SAMPLES_OUT",) if kind == "samples" else
                                                         ("TEXTURE_SHADING",) if textured else ()),
                                        *(("TREE",) if tree else ()))
                prog = self.ctx.program(vertex_shader=ts.VERTEX, tess_control_shader=control,
                                        tess_evaluation_shader=evaluation,
                                        geometry_shader=ts.GEOMETRY_SAMPLES if kind == "samples" else None,
                                        fragment_shader=ts.TEXTURE_FRAGMENT if textured else _FRAGMENT_SHADER)
            kind = kind + ("_tree" if tree else "")
            self._programs[kind] = prog
            self._vaos[kind] = self.ctx.vertex_array(prog, [])
        return self._programs[kind]

    def _last_eye(self, t):
        """(the last call's eye (3,) world mm, or None; the time since, s, or 0) for the angular speed at ``t``."""
        prev = self._previous
        if t is not None and prev is not None and prev[1] is not None and t > prev[1]:
            return prev[0], float(t - prev[1])
        return None, 0.0

    def _remember(self, cv: ConditionedView) -> None:
        self._previous = (np.asarray(cv.eye_mm, float).copy(), cv.t)

    def _set_uniforms(self, prog, view, proj, model, cv: ConditionedView, mode, region_ndc):
        """Every uniform of the frame (the CPU's whole share of the selection)."""
        g, cfg, sel = self.grid, self.config, self.selection
        model = np.asarray(model, np.float64)
        mvp = np.asarray(proj, np.float64) @ np.asarray(view, np.float64) @ model
        eye = tuple(np.asarray(cv.eye_mm, float))
        values = {
            "u_height": 0, "u_patch": 1, "u_patches": g.n_patches, "u_patch_samples": g.patch_samples,
            "u_origin_m": g.origin_m, "u_spacing_m": (g.dx_m, g.dy_m),
            "u_model": model.T.astype("f4").tobytes(), "u_mvp": mvp.T.astype("f4").tobytes(),
            "u_eye_mm": eye, "u_axes": np.asarray(cv.axes, "f4").tobytes(),
            "u_level_bias": float(sel.level_bias), "u_max_level": cfg.max_level, "u_full": int(mode == "full"),
            "u_whole_factors": int(cfg.factors == "whole"),
            "u_cull": int(cfg.cull), "u_ellipse_sigma": float(sel.ellipse_sigma),
            "u_region_ndc": tuple(region_ndc) if region_ndc is not None else (-2.0, -2.0, 2.0, 2.0),
            "u_smooth_normals": int(cfg.smooth_normals), "u_color": 2,
        }
        self._shade_uniforms(prog)
        # Σ⁻¹ for the shift (None or all-zero: no shift). u_axes: the rows Ξ, Ψ, V written row-major are the
        # columns of the GLSL mat3, so transpose(u_axes) * d = (Ξ·d, Ψ·d, V·d).
        form, cov_inv = ts.SHIFT_FORMS[None], np.eye(2)
        if cv.cov_deg2 is not None and np.any(np.asarray(cv.cov_deg2) != 0):
            form, cov_inv = ts.SHIFT_FORMS[sel.shift], np.linalg.inv(np.asarray(cv.cov_deg2, np.float64))
        values["u_shift_form"], values["u_cov_inv"] = form, cov_inv.astype("f4").tobytes()
        prev, dt = self._last_eye(cv.t)
        values["u_eye_prev_mm"] = eye if prev is None else tuple(prev)
        values["u_dt_s"] = dt
        for name, value in values.items():
            if name in prog:
                if isinstance(value, bytes):
                    prog[name].write(value)
                else:
                    prog[name].value = value

    def _bind(self):
        if self._levels_buffer is not None:
            self._levels_buffer.bind_to_storage_buffer(0)
        if self._node_buffer is not None:
            self._node_buffer.bind_to_storage_buffer(3)
        self._height.use(0)
        self._patch.use(1)
        if self._color is not None:
            self._color.use(2)
        self.ctx.patch_vertices = 1

    # -- frames ----------------------------------------------------------------

    def render(self, view, proj, model, cv: ConditionedView, *, mode: str = "csf", region_ndc=None,
               supersample: int = 1) -> np.ndarray:
        """Draw one frame and read it back: (H, W, 3) uint8 RGB, row 0 at the top.

        Parameters
        ----------
        view, proj : (4, 4)
            ``T_eye_world`` and ``T_clip_eye`` (:func:`off_axis_projection`; the camera at the raw eye).
        model : (4, 4)
            ``T_world_scene``.
        cv : ConditionedView
            The frame's view: eye, head axes (V toward the POI), covariance (None: no uncertainty shift)
            and time (with the last call's, the patches' angular speed; None: the speed floor).
        mode : {"csf", "full"}
            ``full``: every patch at the finest level (the reference).
        region_ndc : (4,) or None
            (x0, y0, x1, y1) in NDC: only patches whose box reaches it are drawn (a reference of a region).
        supersample : int
            Draw at this many times the size per axis and average down (``cv2.INTER_AREA``): a reference
            whose triangles are smaller than a pixel, without aliasing. 1: the image's own size.
        """
        if mode not in TESS_MODES:
            raise ValueError(f"TessellationRenderer.render: mode must be one of {TESS_MODES}, got {mode!r}")
        k = int(supersample)
        if k < 1:
            raise ValueError(f"TessellationRenderer.render: supersample must be >= 1, got {supersample!r}")
        ctx = self.ctx
        t0 = time.perf_counter()
        ranges = self._draw_ranges(view, proj, model, cv, mode, region_ndc)
        kind = "draw_tree" if self._tree_frame else "draw"
        prog = self._program(kind)
        self._set_uniforms(prog, view, proj, model, cv, mode, region_ndc)
        self._remember(cv)
        self.last_setup_ms = (time.perf_counter() - t0) * 1e3
        self._bind()     # with the levels pass's levels (flat) or the node records (hierarchy)
        ctx.finish()
        t1 = time.perf_counter()
        fbo, rgba = self._fbo, self._rgba
        if k > 1:
            w, h = self.size[0] * k, self.size[1] * k
            fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)],
                                  depth_attachment=ctx.depth_renderbuffer((w, h)))
            rgba = np.empty((h, w, 4), np.uint8)
        fbo.use()
        fbo.viewport = (0, 0, fbo.width, fbo.height)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        fbo.clear(*self.background, 1.0, depth=1.0)
        with self._query:
            for first, count in ranges:
                self._vaos[kind].render(moderngl.PATCHES, vertices=count, first=first)
        ctx.finish()
        self.last_render_ms = (time.perf_counter() - t1) * 1e3
        self.last_triangles = int(self._query.primitives)
        self.last_draw_calls = len(ranges)
        image = read_rgb(fbo, rgba)
        if k > 1:
            for attachment in (*fbo.color_attachments, fbo.depth_attachment):
                attachment.release()
            fbo.release()
            image = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA)
        return image

    def _levels_pass(self, view, proj, model, cv, mode, region_ndc) -> np.ndarray:
        """(n, n, 6) float32: the control shader's inner, outer W S E N levels and culled flag of every patch."""
        n = self.grid.n_patches
        prog = self._program("levels")
        self._set_uniforms(prog, view, proj, model, cv, mode, region_ndc)
        if self._levels_buffer is None:
            self._levels_buffer = self.ctx.buffer(reserve=6 * 4 * n * n)
        self._levels_buffer.bind_to_storage_buffer(0)
        self._bind()
        # Not under RASTERIZER_DISCARD: llvmpipe then skips the tessellation stages (the buffer stays 0).
        self._fbo.use()
        if self.config.csf_stage == "vertex":
            self._vaos["levels"].render(moderngl.POINTS, vertices=n * n)
        else:
            self._vaos["levels"].render(moderngl.PATCHES, vertices=n * n)
        self.ctx.memory_barrier()
        return np.frombuffer(self._levels_buffer.read(), np.float32).reshape(n, n, 6)

    def _draw_ranges(self, view, proj, model, cv, mode, region_ndc) -> list:
        """Draw calls ``(first patch, patches)`` that each generate fewer than 65536 vertices.

        llvmpipe numbers a draw call's tessellated vertices with 16 bits: past
        65536 its triangles join vertices of different patches. So the
        levels are computed first (one levels pass, read back: 24 bytes per
        patch), and the patches split into calls of at most
        :data:`VERTICES_PER_DRAW` vertices; culled patches cost nothing.
        """
        top = self.config.max_level
        most = (2 ** top + 1) ** 2 + 4 * (2 ** top + 1)
        self._tree_frame = self._tree is not None and mode == "csf"
        if self._tree_frame:
            sel = self._select_nodes(view, proj, model, cv, region_ndc)
            lim = self.config.max_tess_level
            return _split_draws(sel.vertex_bound(), (lim + 1) ** 2 + 4 * (lim + 1))
        lv = self._levels_pass(view, proj, model, cv, mode, region_ndc).reshape(-1, 6)
        self.last_nodes = int(np.count_nonzero(lv[:, 5] < 0.5))
        if mode == "full":
            inner = np.full(len(lv), 2 ** top)
            outer = np.full((len(lv), 4), 2 ** top)
        else:
            rule, p = self.config.factors, self.grid.patch_samples
            inner, outer = tess_factors(lv[:, 0], top, p, rule), tess_factors(lv[:, 1:5], top, p, rule)
        counts = np.where(lv[:, 5] > 0.5, 0, (inner + 1) ** 2 + (outer + 1).sum(axis=1))   # bound on vertices
        return _split_draws(counts, most)

    def _select_nodes(self, view, proj, model, cv, region_ndc):
        """The hierarchy's selection of this frame (:meth:`PatchTree.select`), its records uploaded."""
        model = np.asarray(model, np.float64)
        mvp = np.asarray(proj, np.float64) @ np.asarray(view, np.float64) @ model
        sel = self._tree.select(cv, model, mvp=mvp, region_ndc=region_ndc)
        data = sel.records().tobytes() or bytes(32)
        if self._node_buffer is None or self._node_buffer.size < len(data):
            if self._node_buffer is not None:
                self._node_buffer.release()
            self._node_buffer = self.ctx.buffer(reserve=max(len(data), 32 * 1024))
        self._node_buffer.write(data)
        self.last_selection, self.last_nodes = sel, len(sel)
        return sel

    def levels(self, view, proj, model, cv: ConditionedView):
        """The levels pass's continuous levels for ``cv`` (nothing is drawn; :meth:`render`'s arguments).

        Returns
        -------
        inner : (n, n) float32
            Each patch's level (row pi, column pj; where nothing is visible, f_max at its floor:
            :func:`headplod.plod.criteria.frequency_level`).
        outer : (n, n, 4) float32
            Its edges' levels, W, S, E, N.
        culled : (n, n) bool
            Patches dropped by the frustum test.
        """
        out = self._levels_pass(view, proj, model, cv, "csf", None).copy()
        self._remember(cv)
        return out[..., 0], out[..., 1:5], out[..., 5] > 0.5

    def release(self) -> None:
        """Free the GL objects (the context stays)."""
        for obj in [*self._vaos.values(), *self._programs.values(), self._height, self._patch, self._fbo,
                    self._levels_buffer, self._color, self._node_buffer]:
            if obj is not None:
                obj.release()
        self._vaos, self._programs = {}, {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


# --------------------------------------------------------------------------
# one frame
# --------------------------------------------------------------------------


def grid_model(grid: PatchGrid, screen, centre_z_m: float | None = None) -> np.ndarray:
    """(4, 4) scene (m) → world (mm) of a grid placed as the built-in scene: :func:`headplod.render.still.scene_model`
    with the grid's extent and ``centre_z_m`` (default the median height of every 8th sample)."""
    from .still import scene_model

    cz = float(np.median(grid.heights_m[::8, ::8])) if centre_z_m is None else float(centre_z_m)
    return scene_model(grid.extent, cz, screen)
