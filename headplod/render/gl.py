"""The terrain renderer: offscreen, head-coupled, a shader program per view mode (moderngl, GLSL 330).

Frames, units and the matrix convention are :mod:`headplod.render.projection`'s;
the context is :mod:`headplod.render.context`'s.

Images
------
:meth:`TerrainRenderer.render` returns ``(H, W, 3)`` uint8 RGB, row 0 at the
top (the GL read-back is flipped), covering exactly the screen's visible area:
image pixel column ``floor(x * W_img / W_screen)`` holds screen pixel x.
"""
from __future__ import annotations

import time
from typing import Any

import cv2
import numpy as np

from ..plod.shading import AMBIENT, GLSL_HEIGHT_COLOURS, LIGHT_DIR
from ..plod.mesh import LEVEL_PALETTE
from .context import moderngl

__all__ = ["TerrainRenderer", "PALETTE", "VIEW_MODES", "read_rgb", "FULLSCREEN_VERTEX_SHADER"]

#: A vertex shader of one triangle covering the viewport, drawn with 3 vertices and no buffer:
#: (-1,-1), (3,-1), (-1,3) in NDC; ``v_uv`` is (0, 0) at the bottom left, (1, 1) at the top right.
FULLSCREEN_VERTEX_SHADER = """
#version 330
out vec2 v_uv;
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    v_uv = p;
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
"""

#: Colours of the "levels" view, RGB uint8, (8, 3); level k uses
#: ``PALETTE[k % 8]`` (modulated by the same Lambert shading as "shaded").
PALETTE = LEVEL_PALETTE

#: The sky behind the terrain, linear RGB in [0, 1]: every renderer's clear colour (mesh, tessellation, ray mask).
BACKGROUND_RGB = (0.62, 0.72, 0.82)

#: Accepted values of ``view_mode`` (each has its own shader program).
VIEW_MODES = {"shaded": 0, "wire": 1, "levels": 2}


# --------------------------------------------------------------------------
# shaders
# --------------------------------------------------------------------------

# Shading is per vertex (Gouraud): Lambert + ambient times the height colour,
# one interpolated colour per fragment. On llvmpipe the cost of a triangle
# grows with the number of interpolated values; per-pixel lighting (normal,
# height and the wireframe's barycentric coordinates: 7 values instead of 3)
# made a PLOD frame markedly slower for the same image within a few grey
# levels: the terrain's diffuse shading varies across a triangle only
# through its vertex normals.
#
# Variants (``#define``s, one program each): LEVELS colours a triangle by
# its level, read per fragment from a texture at ``gl_PrimitiveID`` (so an
# indexed mesh, whose vertices are shared by faces of different levels, is
# coloured per triangle); WIRE adds barycentric coordinates made by a
# geometry shader (which works for indexed meshes too, unlike
# ``gl_VertexID % 3``) and draws the edges dark.

_VERTEX_SHADER = """
#version 330
uniform mat4 u_mvp;           // T_clip_scene, column-major
uniform vec3 u_light;         // unit vector toward the light, scene frame
uniform float u_ambient;      // in [0, 1]
uniform vec2 u_height_range;  // scene z of the low and high colour
in vec3 in_position;          // scene units
in vec3 in_normal;            // scene frame
out vec3 v_color;
// CULL (the foveated layers' variant): planes 0-3 keep the NDC rectangle u_keep_rect (x0, y0, x1, y1); plane 4 drops what
// lies inside the disc u_drop_disc (centre x, y and radius, viewport px). Its distance is
// w (r - radius), r the vertex's distance from the centre on the screen: interpolated over a
// triangle it is at least (interpolated w) (r - radius) at every point (r is convex), so no
// point outside the disc is ever dropped.
#ifdef CULL
uniform vec4 u_keep_rect;
uniform vec3 u_drop_disc;
uniform vec2 u_viewport;
out gl_PerVertex { vec4 gl_Position; float gl_ClipDistance[5]; };
#endif

%HEIGHT_COLOURS%

void main() {
    gl_Position = u_mvp * vec4(in_position, 1.0);
#ifdef CULL
    vec4 c = gl_Position;
    gl_ClipDistance[0] = c.x - u_keep_rect.x * c.w;
    gl_ClipDistance[1] = u_keep_rect.z * c.w - c.x;
    gl_ClipDistance[2] = c.y - u_keep_rect.y * c.w;
    gl_ClipDistance[3] = u_keep_rect.w * c.w - c.y;
    if (c.w > 0.0) {
        vec2 s = (c.xy / c.w * 0.5 + 0.5) * u_viewport;
        gl_ClipDistance[4] = c.w * (distance(s, u_drop_disc.xy) - u_drop_disc.z);
    } else {
        gl_ClipDistance[4] = 1e30;      // behind the eye: never dropped here (the near plane clips it)
    }
#endif
    vec3 n = normalize(in_normal);
    float shade = u_ambient + (1.0 - u_ambient) * max(dot(n, u_light), 0.0);
#ifdef LEVELS
    v_color = vec3(shade);    // times the triangle's palette colour, per fragment
#else
    float span = max(u_height_range.y - u_height_range.x, 1e-20);
    float t = clamp((in_position.z - u_height_range.x) / span, 0.0, 1.0);
    vec3 base = t < 0.5 ? mix(LOW, MID, 2.0 * t) : mix(MID, HIGH, 2.0 * t - 1.0);
    v_color = base * shade;
#endif
}
"""
_VERTEX_SHADER = _VERTEX_SHADER.replace("%HEIGHT_COLOURS%", GLSL_HEIGHT_COLOURS)     # plod.shading's colours

_GEOMETRY_SHADER = """
#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
#ifdef CULL
in gl_PerVertex { vec4 gl_Position; float gl_ClipDistance[5]; } gl_in[];
out float gl_ClipDistance[5];
#endif
in vec3 v_color[];
out vec3 g_color;
out vec3 g_bary;              // barycentric coordinates, for the wireframe
void main() {
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_color = v_color[i];
        g_bary = vec3(i == 0, i == 1, i == 2);
        gl_PrimitiveID = gl_PrimitiveIDIn;
#ifdef CULL
        for (int j = 0; j < 5; ++j) gl_ClipDistance[j] = gl_in[i].gl_ClipDistance[j];
#endif
        EmitVertex();
    }
    EndPrimitive();
}
"""

_FRAGMENT_SHADER = """
#version 330
#ifdef WIRE
uniform float u_wire_px;      // wire half-width, px
uniform vec3 u_wire_color;
in vec3 g_color;
in vec3 g_bary;
#define COLOR g_color
#else
in vec3 v_color;
#define COLOR v_color
#endif
#ifdef LEVELS
uniform usampler2D u_levels;  // level of triangle p at texel (p % width, p / width)
uniform vec3 u_palette[8];
uniform int u_primitive_base; // first triangle of the draw call (gl_PrimitiveID restarts at 0 per call)
#endif
out vec4 f_color;

void main() {
    vec3 color = COLOR;
#ifdef LEVELS
    int width = textureSize(u_levels, 0).x;
    int p = gl_PrimitiveID + u_primitive_base;
    uint level = texelFetch(u_levels, ivec2(p % width, p / width), 0).r;
    color *= u_palette[level % 8u];
#endif
#ifdef WIRE
    vec3 w = fwidth(g_bary) * u_wire_px;
    vec3 e = smoothstep(0.5 * w, 1.5 * w, g_bary);
    float inside = min(min(e.x, e.y), e.z);
    color = mix(u_wire_color, color, inside);
#endif
    f_color = vec4(color, 1.0);
}
"""

#: ``#define``s of each view mode's program.
_VARIANTS = {"shaded": (), "wire": ("WIRE",), "levels": ("LEVELS",)}

#: GL_CLIP_DISTANCE0 (moderngl has no flag for it: enabled with ``enable_direct``).
_GL_CLIP_DISTANCE0 = 0x3000

#: Width of the per-triangle level texture, texels (its height grows with the triangle count).
_LEVEL_TEXTURE_WIDTH = 4096


def _shader_variant(source: str, defines) -> str:
    """The shader with ``defines`` added after the #version line."""
    if not defines:
        return source
    head, rest = source.lstrip().split("\n", 1)
    return head + "\n" + "".join(f"#define {d} 1\n" for d in defines) + rest


# --------------------------------------------------------------------------
# renderer
# --------------------------------------------------------------------------


def _as_array(name: str, value: Any, dtype, shape_tail: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        want = "(N, " + ", ".join(map(str, shape_tail)) + ")" if shape_tail else "(N,)"
        raise ValueError(f"TerrainRenderer.upload: {name} has shape {a.shape}, expected {want}")
    return np.ascontiguousarray(a, dtype=dtype)


def read_rgb(framebuffer, rgba: np.ndarray) -> np.ndarray:
    """A framebuffer's image as (H, W, 3) uint8 RGB, row 0 at the top, read through ``rgba`` (H, W, 4) uint8.

    RGBA is GL's native layout: llvmpipe reads it much faster than RGB; one
    cvtColor drops alpha and (reading the rows bottom-up) flips.
    """
    framebuffer.read_into(rgba, components=4)
    return cv2.cvtColor(rgba[::-1], cv2.COLOR_RGBA2RGB)


class TerrainRenderer:
    """Draw a triangle mesh offscreen, head-coupled, in one of three views.

    Parameters
    ----------
    ctx : moderngl.Context
        From :func:`create_context` (GL ≥ 3.3).
    size : tuple of int
        ``(width, height)`` of the image, px. Use the screen's ``size_px``
        for square pixels; any size covers the whole screen area.
    samples : int
        MSAA samples; 0 (default) for bit-reproducible images.
    background : tuple of float
        RGB clear colour in [0, 1].

    Attributes
    ----------
    last_render_ms : float
        Wall time of the last :meth:`render`'s clear + draw + ``ctx.finish()``
        (GPU work done), ms; excludes the read-back.
    last_readback_ms : float
        Wall time of the last read-back and flip, ms.
    n_triangles : int
        Triangles to draw.
    n_vertices : int
        Vertices uploaded.
    tag : object
        The ``tag`` of the last :meth:`upload` (None by default).
    indexed : bool
        Whether the mesh is drawn through an index buffer (``upload`` with
        ``indices``, or ``set_indices``) or as a triangle soup.
    height_range : tuple of float
        Scene z mapped to the low and high terrain colours; set by
        :meth:`upload` to the vertices' z range, may be overwritten.

    Notes
    -----
    Depth test on (24-bit depth), no face culling, no blending. Vertices are
    two buffers (position 3f, normal 3f: 24 bytes per vertex); an indexed
    mesh adds a uint32 index buffer (12 bytes per triangle). Each
    triangle's level lives in a uint8 texture read by the "levels" view at
    ``gl_PrimitiveID``. Buffers grow with ``orphan`` when an upload is
    larger and shrink when it is much smaller.

    Indexed drawing is the fast path for a PLOD mesh: upload the mesh's
    vertex table once (``AdaptiveMesh.vertex_positions``/``vertex_normals``)
    and give each new selection's indices to :meth:`set_indices`. On
    llvmpipe a shared vertex is also shaded once per batch rather than once
    per triangle, so the draw is faster than the soup of the same triangles
    (``headplod bench plod`` measures the frame).
    """

    def __init__(self, ctx: "moderngl.Context", size: tuple[int, int] = (1280, 720), *,
                 samples: int = 0, background: tuple[float, float, float] = BACKGROUND_RGB):
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValueError(f"TerrainRenderer: size must be positive (width, height), got {size!r}")
        samples = int(samples)
        if samples < 0 or samples > ctx.max_samples:
            raise ValueError(f"TerrainRenderer: samples={samples}, this context supports 0..{ctx.max_samples}")
        self.ctx = ctx
        self.size = (w, h)
        self.samples = samples
        self.background = tuple(float(c) for c in background)
        self.last_render_ms = float("nan")
        self.last_readback_ms = float("nan")
        self.n_triangles = 0
        self.n_vertices = 0
        self.indexed = False
        self.tag = None
        self.height_range = (0.0, 1.0)

        # A program per view mode, and per view mode with CULL (``draw(cull=...)``, the foveated
        # layers): keys "shaded", ("shaded", "cull"), ... The plain programs carry no clip
        # distances (llvmpipe tests every plane the shader writes, enabled or not).
        self.programs = {}
        for mode, defines in _VARIANTS.items():
            for key, extra in ((mode, ()), ((mode, "cull"), ("CULL",))):
                self.programs[key] = ctx.program(
                    vertex_shader=_shader_variant(_VERTEX_SHADER, defines + extra),
                    geometry_shader=(_shader_variant(_GEOMETRY_SHADER, defines + extra) if "WIRE" in defines
                                     else None),
                    fragment_shader=_shader_variant(_FRAGMENT_SHADER, defines + extra))
        for key in ("levels", ("levels", "cull")):
            self.programs[key]["u_palette"].write((PALETTE.astype("f4") / 255.0).tobytes())
            self.programs[key]["u_levels"].value = 0          # texture unit 0
        self._fbo = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer((w, h), components=4, samples=samples)],
            depth_attachment=ctx.depth_renderbuffer((w, h), samples=samples),
        )
        if samples:
            self._resolve = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)])
        else:
            self._resolve = self._fbo
        self._buffers: dict[str, Any] = {}
        self._vaos: dict[tuple[str, bool], Any] = {}     # (view mode, indexed) -> vertex array
        self._level_texture = None
        self._rgba = None                  # read-back buffer

    # -- data ----------------------------------------------------------------

    def _write(self, name: str, data: np.ndarray) -> None:
        raw = data.tobytes()
        need = max(len(raw), 4)
        buf = self._buffers.get(name)
        if buf is None:
            self._buffers[name] = buf = self.ctx.buffer(reserve=need)
        elif need > buf.size or need < buf.size // 4:
            buf.orphan(need)   # same GL name, so the vertex arrays stay valid
        if raw:
            buf.write(raw)

    def _write_levels(self, levels: np.ndarray) -> None:
        """Per-triangle levels (T,) uint8 into the level texture (row-major, ``_LEVEL_TEXTURE_WIDTH`` wide)."""
        width = _LEVEL_TEXTURE_WIDTH
        rows = max(1, -(-len(levels) // width))
        tex = self._level_texture
        if tex is None or tex.height < rows or tex.height > 4 * rows:
            if tex is not None:
                tex.release()
            tex = self._level_texture = self.ctx.texture((width, rows), 1, dtype="u1")
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        data = np.zeros(tex.width * tex.height, np.uint8)
        data[:len(levels)] = levels
        tex.write(data.tobytes())

    @staticmethod
    def _levels_per_triangle(levels: Any, n_triangles: int, last_vertex: np.ndarray, n_vertices: int
                             ) -> np.ndarray:
        """(T,) uint8 from levels per triangle (T,) or per vertex (N,) (a triangle takes its last vertex's)."""
        if levels is None:
            return np.zeros(n_triangles, np.uint8)
        lev = np.asarray(levels).reshape(-1)
        if lev.size and not np.issubdtype(lev.dtype, np.number):
            raise ValueError(f"TerrainRenderer: levels have dtype {lev.dtype}, expected integers")
        if lev.size and (lev.min() < 0 or lev.max() > 255):
            raise ValueError(f"TerrainRenderer.upload: levels in {lev.min()}..{lev.max()}, expected 0..255")
        if len(lev) == n_triangles:
            return lev.astype(np.uint8)
        if len(lev) == n_vertices:
            return lev[last_vertex].astype(np.uint8)
        raise ValueError(f"TerrainRenderer.upload: {len(lev)} levels, expected {n_triangles} (per triangle) "
                         f"or {n_vertices} (per vertex)")

    def upload(self, positions: Any, normals: Any, levels: Any = None, indices: Any = None, *,
               tag: Any = None, height_range: Any = None) -> None:
        """Replace the mesh.

        Parameters
        ----------
        positions : array_like, shape (N, 3), float32
            Vertices, scene frame, scene units.
        normals : array_like, shape (N, 3), float32
            Vertex normals, scene frame (need not be unit).
        levels : array_like of uint8, shape (T,) or (N,), optional
            Level of each triangle (T triangles), or of each vertex; in the
            latter case a triangle takes the level of its last vertex. When
            both readings fit (N == T), it is per triangle. ``None``: all 0.
        indices : array_like of int, shape (T, 3) or (3T,), optional
            Triangles as vertex indices (drawn indexed). ``None``:
            ``positions`` is a triangle soup, three vertices per triangle
            (N = 3T).
        tag : object, optional
            Kept as :attr:`tag`: lets callers sharing the renderer tell
            whether the vertices on the GPU are still theirs (e.g. a mesh's
            vertex table, uploaded once for :meth:`set_indices`).
        height_range : (2,) float, optional
            Scene z of the low and high terrain colours. Give the terrain's
            own range so a height keeps its colour whichever vertices a frame
            uploads; default: the range of ``positions``.

        Raises
        ------
        ValueError
            On wrong shapes, non-finite positions, out-of-range indices or
            levels outside 0..255.
        """
        pos = _as_array("positions", positions, np.float32, (3,))
        nrm = _as_array("normals", normals, np.float32, (3,))
        n = len(pos)
        if len(nrm) != n:
            raise ValueError(f"TerrainRenderer.upload: {len(nrm)} normals for {n} positions, expected equal")
        if not np.isfinite(pos).all():
            raise ValueError("TerrainRenderer.upload: positions have NaN or inf")
        if indices is None and n % 3:
            raise ValueError(f"TerrainRenderer.upload: a triangle soup needs 3 vertices per triangle, "
                             f"got {n} positions (not a multiple of 3); or pass indices")
        # Everything is checked before anything is written: a refused upload leaves the mesh as it was.
        if indices is None:
            idx, t, last = None, n // 3, np.arange(2, n, 3)
        else:
            idx = self._check_indices(indices, n)
            t, last = idx.size // 3, idx[2::3]
        tri_levels = self._levels_per_triangle(levels, t, last, n)
        self._write("position", pos)
        self._write("normal", nrm)
        self.n_vertices = n
        self.tag = tag
        if ("shaded", False) not in self._vaos:           # soup vertex arrays, made once
            b = self._buffers
            for mode, prog in self.programs.items():
                self._vaos[mode, False] = self.ctx.vertex_array(
                    prog, [(b["position"], "3f", "in_position"), (b["normal"], "3f", "in_normal")])
        if height_range is not None:
            lo, hi = (float(v) for v in height_range)
            self.height_range = (lo, hi if hi > lo else lo + 1.0)
        elif n:
            z = pos[:, 2]
            lo, hi = float(z.min()), float(z.max())
            self.height_range = (lo, hi if hi > lo else lo + 1.0)
        if idx is None:
            self._write_levels(tri_levels)
            self.indexed = False
            self.n_triangles = t
        else:
            self._set_checked_indices(idx, tri_levels)

    @staticmethod
    def _check_indices(indices: Any, n_vertices: int) -> np.ndarray:
        """(3T,) uint32 from (T, 3) or (3T,) integer indices, each in 0..n_vertices-1."""
        idx = np.asarray(indices)
        if not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"TerrainRenderer.upload: indices have dtype {idx.dtype}, expected integers")
        if not ((idx.ndim == 2 and idx.shape[1] == 3) or (idx.ndim == 1 and idx.size % 3 == 0)):
            raise ValueError(f"TerrainRenderer.upload: indices have shape {idx.shape}, expected (T, 3) or (3T,)")
        idx = idx.reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= n_vertices):
            raise ValueError(f"TerrainRenderer.upload: indices in {idx.min()}..{idx.max()}, "
                             f"expected 0..{n_vertices - 1}")
        return np.ascontiguousarray(idx, dtype=np.uint32)

    def set_indices(self, indices: Any, levels: Any = None) -> None:
        """Draw the uploaded vertices through new triangle indices (the vertices stay on the GPU).

        Parameters
        ----------
        indices : array_like of int, shape (T, 3) or (3T,)
            Triangles as rows of the last :meth:`upload`'s vertices,
            counter-clockwise seen from the front. uint32 is used as is.
        levels : array_like, shape (T,) or (N,), optional
            As in :meth:`upload`.

        Raises
        ------
        ValueError
            With no vertices uploaded, on a wrong shape or dtype, or indices
            outside ``0..n_vertices-1``.
        """
        if "position" not in self._buffers:
            raise ValueError("TerrainRenderer.set_indices: upload the vertices first (upload(positions, normals))")
        idx = self._check_indices(indices, self.n_vertices)
        self._set_checked_indices(idx, self._levels_per_triangle(levels, idx.size // 3, idx[2::3],
                                                                 self.n_vertices))

    def _set_checked_indices(self, idx: np.ndarray, levels: np.ndarray) -> None:
        """Write checked (3T,) uint32 indices and their (T,) uint8 levels."""
        t = idx.size // 3
        self._write("index", idx)
        if ("shaded", True) not in self._vaos:            # indexed vertex arrays, made once
            b = self._buffers
            for mode, prog in self.programs.items():
                self._vaos[mode, True] = self.ctx.vertex_array(
                    prog, [(b["position"], "3f", "in_position"), (b["normal"], "3f", "in_normal")],
                    index_buffer=b["index"], index_element_size=4)
        self._write_levels(levels)
        self.indexed = True
        self.n_triangles = t

    # -- drawing -------------------------------------------------------------

    def prepare(self, view: Any, proj: Any, model: Any = None, view_mode: str = "shaded",
                light_dir: Any = LIGHT_DIR, *, ambient: float = AMBIENT,
                wire_px: float = 1.0, wire_color: tuple[float, float, float] = (0.08, 0.08, 0.08)) -> None:
        """Check the matrices and set the program's uniforms for :meth:`draw` (arguments as :meth:`render`)."""
        if view_mode not in VIEW_MODES:
            raise ValueError(f"render: view_mode is {view_mode!r}, expected one of {sorted(VIEW_MODES)}")
        mats = []
        for name, m in (("view", view), ("proj", proj), ("model", np.eye(4) if model is None else model)):
            a = np.asarray(m, dtype=np.float64)
            if a.shape != (4, 4) or not np.isfinite(a).all():
                raise ValueError(f"render: {name} must be a finite (4, 4) matrix, got shape {a.shape}")
            mats.append(a)
        mvp = mats[1] @ mats[0] @ mats[2]
        light = np.asarray(light_dir, dtype=np.float64).reshape(-1)
        if light.shape != (3,) or not np.isfinite(light).all() or np.linalg.norm(light) == 0:
            raise ValueError(f"render: light_dir must be a non-zero 3-vector, got {light_dir!r}")
        light /= np.linalg.norm(light)
        for prog in (self.programs[view_mode], self.programs[view_mode, "cull"]):
            prog["u_mvp"].write(np.ascontiguousarray(mvp.T, dtype="f4").tobytes())  # column-major
            prog["u_light"].value = tuple(light)
            prog["u_ambient"].value = float(ambient)
            if view_mode != "levels":      # the levels view does not use heights (the uniform is compiled out)
                prog["u_height_range"].value = tuple(float(v) for v in self.height_range)
            if view_mode == "wire":
                prog["u_wire_px"].value = float(wire_px)
                prog["u_wire_color"].value = tuple(float(c) for c in wire_color)

    def draw(self, fbo, viewport: tuple[int, int, int, int], view_mode: str = "shaded", scissor=None,
             ranges=None, clear: bool = True, cull=None, indirect=None) -> None:
        """Clear ``fbo`` and draw the uploaded mesh into it with the uniforms of :meth:`prepare`.

        ``viewport`` (x, y, w, h) px of ``fbo``: where the screen's visible
        area is mapped (a smaller framebuffer draws the same view at a lower
        resolution); ``scissor`` (x, y, w, h) px, optional: only that
        rectangle is cleared and shaded. ``ranges``, optional: (first, count)
        pairs of triangles (rows of the index buffer, or of the soup) to
        draw, one draw call each, instead of the whole mesh. ``clear``:
        clear colour and depth (within the scissor) first. ``cull``,
        optional: ((x0, y0, x1, y1) viewport px, (cx, cy, radius) viewport
        px or None): the triangles wholly outside the rectangle or wholly
        inside the disc are dropped before set-up (clip distances); one
        crossing an edge is clipped there, so its pixels near that edge may
        differ in the last bit from an undropped draw. ``indirect``, optional:
        (buffer, n): draw the n commands of an indirect buffer (5 uint32
        each: index count, 1, first index, 0, 0) in one call instead
        (not for the "levels" view: gl_PrimitiveID restarts with each command).
        """
        ctx = self.ctx
        fbo.use()
        fbo.viewport = tuple(int(v) for v in viewport)
        fbo.scissor = None if scissor is None else tuple(int(v) for v in scissor)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        if clear:
            fbo.clear(*self.background, 1.0, depth=1.0)
        if self.n_triangles:
            key = view_mode if cull is None else (view_mode, "cull")
            vao = self._vaos[key, self.indexed]
            if view_mode == "levels":
                self._level_texture.use(0)
            if ranges is None:
                ranges = ((0, self.n_triangles),)
            levels_prog = self.programs[key] if view_mode == "levels" else None
            if cull is not None:
                prog = self.programs[key]
                vw, vh = float(viewport[2]), float(viewport[3])
                prog["u_viewport"].value = (vw, vh)
                (x0, y0, x1, y1), disc = cull
                prog["u_keep_rect"].value = (2 * (x0 - viewport[0]) / vw - 1, 2 * (y0 - viewport[1]) / vh - 1,
                                             2 * (x1 - viewport[0]) / vw - 1, 2 * (y1 - viewport[1]) / vh - 1)
                prog["u_drop_disc"].value = (0.0, 0.0, -1.0) if disc is None else tuple(float(v) for v in disc)
                for i in range(5):
                    ctx.enable_direct(_GL_CLIP_DISTANCE0 + i)
            if indirect is not None:
                if view_mode == "levels":
                    raise ValueError("draw: the levels view cannot be drawn indirect (its levels follow gl_PrimitiveID)")
                if indirect[1] > 0:
                    vao.render_indirect(indirect[0], moderngl.TRIANGLES, count=int(indirect[1]))
                ranges = ()
            for first, count in ranges:
                first, count = int(first), min(int(count), self.n_triangles - int(first))
                if count <= 0:
                    continue
                if levels_prog is not None:
                    levels_prog["u_primitive_base"].value = first
                vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)
            if cull is not None:
                for i in range(5):
                    ctx.disable_direct(_GL_CLIP_DISTANCE0 + i)
        fbo.scissor = None

    def render(self, view: Any, proj: Any, model: Any = None, view_mode: str = "shaded",
               light_dir: Any = LIGHT_DIR, *, ambient: float = AMBIENT,
               wire_px: float = 1.0, wire_color: tuple[float, float, float] = (0.08, 0.08, 0.08)
               ) -> np.ndarray:
        """Draw the uploaded mesh and read the image back.

        Parameters
        ----------
        view : array_like, shape (4, 4)
            ``T_eye_world``, e.g. from :func:`off_axis_projection`.
        proj : array_like, shape (4, 4)
            ``T_clip_eye``.
        model : SceneTransform or array_like, shape (4, 4), optional
            ``T_world_scene``; identity when ``None``.
        view_mode : {"shaded", "wire", "levels"}
            "shaded": Lambert + ambient, per vertex (Gouraud), grey-green colour by scene height;
            "wire": "shaded" with triangle edges drawn dark (one pass,
            barycentric); "levels": ``PALETTE[level % 8]`` with the same
            shading.
        light_dir : array_like, shape (3,)
            Direction toward the light, scene frame (normalized here).
        ambient : float
            Shade of faces turned away from the light, in [0, 1]; a face
            facing the light gets 1.
        wire_px : float
            Wire half-width, px (roughly).
        wire_color : tuple of float
            RGB of the wire, [0, 1].

        Returns
        -------
        ndarray, shape (H, W, 3), uint8
            RGB, row 0 at the top of the screen.
        """
        ctx = self.ctx
        self.prepare(view, proj, model, view_mode, light_dir, ambient=ambient, wire_px=wire_px,
                     wire_color=wire_color)
        ctx.finish()  # uploads and earlier work are not part of the timing
        t0 = time.perf_counter()
        self.draw(self._fbo, (0, 0, *self.size), view_mode)
        if self.samples:
            ctx.copy_framebuffer(self._resolve, self._fbo)
        ctx.finish()
        t1 = time.perf_counter()
        w, h = self.size
        if self._rgba is None:
            self._rgba = np.empty((h, w, 4), np.uint8)
        image = read_rgb(self._resolve, self._rgba)
        self.last_render_ms = (t1 - t0) * 1e3
        self.last_readback_ms = (time.perf_counter() - t1) * 1e3
        return image

    def release(self) -> None:
        """Free the GL objects (the context stays)."""
        for obj in [*self._vaos.values(), *self._buffers.values(), self._fbo, self._level_texture,
                    None if self._resolve is self._fbo else self._resolve, *self.programs.values()]:
            if obj is not None:
                obj.release()
        self._vaos = {}
        self._buffers = {}
        self._level_texture = None

    def __enter__(self) -> "TerrainRenderer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()
