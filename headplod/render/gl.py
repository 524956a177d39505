"""Offscreen terrain rendering with head-coupled perspective (moderngl, GLSL 330).

Frames and units
----------------
- world: the left camera frame (OpenCV: x right, y down, z forward), mm —
  the frame of ``screen.yaml`` and of the head position (conventions.md).
- screen-eye frame ("eye"): origin at the eye, x along
  ``top_left → top_right`` (right), y up (``bottom_left → top_left``, made
  orthogonal to x), z = x × y toward the viewer, mm. The screen plane is
  ``z = −d`` with d the eye's distance to the plane. This is the view space.
- scene: the virtual terrain, any unit (e.g. m), x east, y north, z up.
- clip / NDC: OpenGL's, NDC x right, y up, z ∈ [−1, 1] from near to far.
  Screen pixel (x, y) (``Screen.pixel_to_world`` convention: (0, 0) at the
  top-left corner of the visible area, (W, H) at the bottom-right one) is
  NDC ``(2x/W − 1, 1 − 2y/H)``.

Matrix convention
-----------------
Column vectors, ``p_clip = proj @ view @ model @ [p_scene, 1]``, so that
``model`` is ``T_world_scene`` (scene units → world mm), ``view`` is
``T_eye_world`` and ``proj`` is ``T_clip_eye``. All 4x4 matrices are numpy
arrays in row-major *memory* with the usual maths indexing ``M[row, col]``.
OpenGL (and moderngl's uniform ``write``) expects column-major bytes, so a
matrix is uploaded as ``prog['u_mvp'].write(M.T.astype('f4').tobytes())``.
:class:`TerrainRenderer` does this itself: it multiplies
``proj @ view @ model`` in float64 on the CPU and uploads one float32 MVP.

Images
------
:meth:`TerrainRenderer.render` returns ``(H, W, 3)`` uint8 RGB, row 0 at the
top (the GL read-back is flipped), covering exactly the screen's visible area:
image pixel column ``floor(x * W_img / W_screen)`` holds screen pixel x.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

try:  # the pure-numpy parts (projection, scene transform, overlay) work without it
    import moderngl
except ImportError as _exc:  # pragma: no cover - moderngl is a hard dependency
    moderngl = None
    _MODERNGL_IMPORT_ERROR: ImportError | None = _exc
else:
    _MODERNGL_IMPORT_ERROR = None

from ..io import Screen

__all__ = [
    "create_context",
    "screen_frame",
    "off_axis_projection",
    "SceneTransform",
    "scene_to_world",
    "TerrainRenderer",
    "overlay_poi",
    "PALETTE",
    "VIEW_MODES",
]

#: Debian/Ubuntu packages that provide headless EGL with Mesa's llvmpipe.
EGL_PACKAGES = "libegl1 libgl1-mesa-dri"

#: Colours of the "levels" view, RGB uint8, (8, 3); level k uses
#: ``PALETTE[k % 8]`` (modulated by the same Lambert shading as "shaded").
PALETTE = np.array([
    [230, 25, 75],    # red
    [60, 180, 75],    # green
    [0, 130, 200],    # blue
    [255, 225, 25],   # yellow
    [145, 30, 180],   # purple
    [70, 240, 240],   # cyan
    [245, 130, 48],   # orange
    [240, 50, 230],   # magenta
], dtype=np.uint8)

#: Accepted values of ``view_mode`` (each has its own shader program).
VIEW_MODES = {"shaded": 0, "wire": 1, "levels": 2}


# --------------------------------------------------------------------------
# context
# --------------------------------------------------------------------------


def create_context(require: int = 330) -> "moderngl.Context":
    """A standalone, headless OpenGL context through EGL (Mesa llvmpipe or a GPU).

    Parameters
    ----------
    require : int
        Minimum OpenGL version code (330 = OpenGL 3.3 core, enough for the
        shaders here).

    Returns
    -------
    moderngl.Context
        Current on the calling thread; release it with ``ctx.release()``.

    Raises
    ------
    RuntimeError
        When moderngl is not installed, or EGL / a Mesa driver is missing or
        too old; the message names the Debian packages to install.
    """
    if moderngl is None:
        raise RuntimeError(
            f"moderngl is not importable ({_MODERNGL_IMPORT_ERROR}); "
            "install it with 'pip install moderngl'"
        )
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=require)
    except Exception as exc:  # glcontext raises plain Exception subclasses
        raise RuntimeError(
            f"cannot create a headless OpenGL {require // 100}.{require % 100 // 10} "
            f"context through EGL: {type(exc).__name__}: {exc}. "
            f"Hint: install EGL and Mesa's software driver (Debian/Ubuntu: "
            f"'apt-get install {EGL_PACKAGES}'); on a GPU machine check that the "
            "vendor's libEGL is installed and that /dev/dri is accessible"
        ) from exc
    return ctx


# --------------------------------------------------------------------------
# head-coupled (off-axis) projection
# --------------------------------------------------------------------------


def screen_frame(screen: Screen) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal frame of the screen, world frame.

    Parameters
    ----------
    screen : Screen
        Corners in the world frame, mm.

    Returns
    -------
    right, up, toward_viewer : ndarray, shape (3,)
        Unit vectors (world frame): ``right`` along ``top_right − top_left``;
        ``up`` along ``top_left − bottom_left`` made orthogonal to ``right``
        (they are equal for a rectangular screen); ``toward_viewer`` =
        ``right × up`` = ``−screen.normal``, pointing from the screen to the
        side it is seen from.
    center_mm : ndarray, shape (3,)
        Centre of the visible area, world frame, mm.
    """
    a = screen.top_right - screen.top_left
    b = screen.bottom_left - screen.top_left
    right = a / np.linalg.norm(a)
    up = -b - np.dot(-b, right) * right
    up /= np.linalg.norm(up)
    toward = np.cross(right, up)
    center = screen.top_left + 0.5 * a + 0.5 * b
    return right, up, toward, center


def off_axis_projection(eye_mm: Any, screen: Screen, near_mm: float,
                        far_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """View and projection matrices of a head-coupled perspective.

    Kooima's generalized perspective projection: the screen's visible area is
    the image plane and the frustum's apex is the eye, so that a point on the
    screen is drawn where it is, whatever the eye position, and points behind
    (or in front of) the screen show the parallax of a real window.

    Parameters
    ----------
    eye_mm : array_like, shape (3,)
        Eye position (the centre of projection), world frame, mm. Must be on
        the viewer's side of the screen plane (``right × up`` side, i.e.
        opposite to ``screen.normal``).
    screen : Screen
        The display; its corners (world frame, mm) span the image.
    near_mm, far_mm : float
        Near and far clip planes, mm, as distances from the eye along the
        screen's normal (the planes are parallel to the screen);
        ``0 < near_mm < far_mm``. To see geometry popping out of the screen,
        take ``near_mm`` below the eye–screen distance.

    Returns
    -------
    view : ndarray, shape (4, 4), float32
        ``T_eye_world``: world (mm) → screen-eye frame (origin at the eye, x
        right along the screen's top edge, y up, z toward the viewer, mm).
        A rotation and a translation.
    proj : ndarray, shape (4, 4), float32
        ``T_clip_eye``: the asymmetric frustum through the screen's edges,
        OpenGL clip space (NDC z = −1 at ``near_mm``, +1 at ``far_mm``).
        A world point on the screen at pixel (x, y) lands on NDC
        ``(2x/W − 1, 1 − 2y/H)``. For a parallelogram (non-rectangular)
        screen the x row carries the shear that keeps this exact.

    Raises
    ------
    ValueError
        On a non-finite or wrongly shaped eye, bad clip distances, or an eye
        on or behind the screen plane.

    Notes
    -----
    Column vectors: ``p_clip = proj @ view @ [p_world, 1]``. Upload to GLSL
    as column-major bytes, ``M.T.tobytes()`` (see the module docstring).
    Matrices are computed in float64 and rounded to float32 on return.
    """
    eye = np.asarray(eye_mm, dtype=np.float64).reshape(-1)
    if eye.shape != (3,) or not np.isfinite(eye).all():
        raise ValueError(f"off_axis_projection: eye_mm must be 3 finite numbers (mm), got {eye_mm!r}")
    n, f = float(near_mm), float(far_mm)
    if not (math.isfinite(n) and math.isfinite(f) and 0.0 < n < f):
        raise ValueError(f"off_axis_projection: need 0 < near_mm < far_mm, got near={near_mm}, far={far_mm}")
    right, up, toward, _ = screen_frame(screen)
    R_eye_world = np.stack([right, up, toward])  # rows: the eye frame's axes in world
    tl = R_eye_world @ (screen.top_left - eye)          # (x0, y0, -d)
    a = R_eye_world @ (screen.top_right - screen.top_left)  # (ax, 0, 0)
    b = R_eye_world @ (screen.bottom_left - screen.top_left)  # (bx, by, 0)
    d = -tl[2]
    size = max(np.linalg.norm(a), np.linalg.norm(b))
    if not d > 1e-9 * size:
        raise ValueError(
            f"off_axis_projection: the eye {eye.tolist()} mm is {'on' if abs(d) <= 1e-9 * size else 'behind'} "
            f"the screen plane (signed distance {d:.6g} mm toward the viewer); it must be on the "
            "side the screen is seen from (opposite to screen.normal)"
        )
    x0, y0 = tl[0], tl[1]
    ax, bx, by = a[0], b[0], b[1]
    # On the screen plane z = -d, a view-space point q projects to p = d q / (-q_z);
    # x_ndc = 2u/W - 1 and y_ndc = 1 - 2v/H are affine in p (solve p = tl + u/W a + v/H b).
    cx = -2.0 * x0 / ax + 2.0 * bx * y0 / (ax * by) - 1.0
    cy = 2.0 * y0 / by + 1.0
    proj = np.array([
        [2.0 * d / ax, -2.0 * d * bx / (ax * by), -cx, 0.0],
        [0.0, -2.0 * d / by, -cy, 0.0],
        [0.0, 0.0, -(f + n) / (f - n), -2.0 * f * n / (f - n)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    view = np.eye(4)
    view[:3, :3] = R_eye_world
    view[:3, 3] = -R_eye_world @ eye
    return view.astype(np.float32), proj.astype(np.float32)


# --------------------------------------------------------------------------
# scene placement
# --------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SceneTransform:
    """Placement of the virtual scene in the world: ``T_world_scene``.

    Parameters
    ----------
    matrix : array_like, shape (4, 4)
        Homogeneous affine map, column vectors: ``[p_world_mm, 1] = matrix @
        [p_scene, 1]``; last row ``[0, 0, 0, 1]``. Stored as float64.

    Notes
    -----
    ``np.asarray(transform)`` gives the matrix, so a SceneTransform can be
    passed wherever a (4, 4) ``model`` matrix is expected.
    """

    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"SceneTransform: matrix has shape {m.shape}, expected (4, 4)")
        if not np.isfinite(m).all():
            raise ValueError("SceneTransform: matrix has NaN or inf")
        if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-12):
            raise ValueError(f"SceneTransform: last row is {m[3].tolist()}, expected [0, 0, 0, 1] (affine)")
        if abs(np.linalg.det(m[:3, :3])) < 1e-300:
            raise ValueError("SceneTransform: the linear part is singular")
        m.setflags(write=False)
        object.__setattr__(self, "matrix", m)

    @classmethod
    def identity(cls) -> "SceneTransform":
        """Scene = world (scene units are mm in the world frame)."""
        return cls(np.eye(4))

    def apply(self, points_scene: Any) -> np.ndarray:
        """World positions (mm) of scene points.

        Parameters
        ----------
        points_scene : array_like, shape (..., 3)
            Scene frame, scene units.

        Returns
        -------
        ndarray, shape (..., 3)
            World frame, mm.
        """
        p = np.asarray(points_scene, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ValueError(f"SceneTransform.apply needs shape (..., 3), got {p.shape}")
        return p @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def inverse(self) -> "SceneTransform":
        """``T_scene_world``."""
        return SceneTransform(np.linalg.inv(self.matrix))

    def __matmul__(self, other: "SceneTransform") -> "SceneTransform":
        return SceneTransform(self.matrix @ np.asarray(other, dtype=np.float64))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.matrix.astype(dtype) if dtype is not None else self.matrix.copy()


def scene_to_world(scale_mm_per_unit: float, center_scene: Any, screen: Screen,
                   depth_mm: float = 0.0, pitch_deg: float = 0.0) -> SceneTransform:
    """Place the terrain behind (or through) the screen.

    Parameters
    ----------
    scale_mm_per_unit : float
        World mm per scene unit (> 0), e.g. 0.1 shows 1 m of terrain as
        0.1 mm.
    center_scene : array_like, shape (3,)
        Scene point (scene units) that lands at the screen centre.
    screen : Screen
        The display (world frame, mm).
    depth_mm : float
        How far behind the screen plane ``center_scene`` lands, mm (away
        from the viewer; negative = in front of the screen). 0 puts it on the
        screen plane, the zero-parallax point that stays still as the head
        moves.
    pitch_deg : float
        Tilt about the screen's right axis, degrees. 0: the terrain's up (z)
        is the screen's up and north (y) points into the screen (a window
        onto the landscape). 90: up points at the viewer and north along
        the screen's up (a map on the screen). In between, the viewer looks
        down onto the terrain.

    Returns
    -------
    SceneTransform
        ``T_world_scene``: a rotation times ``scale_mm_per_unit`` plus a
        translation. Scene x (east) maps to the screen's right.
    """
    s = float(scale_mm_per_unit)
    if not (math.isfinite(s) and s > 0):
        raise ValueError(f"scene_to_world: scale_mm_per_unit must be > 0, got {scale_mm_per_unit!r}")
    c = np.asarray(center_scene, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.isfinite(c).all():
        raise ValueError(f"scene_to_world: center_scene must be 3 finite numbers, got {center_scene!r}")
    if not (math.isfinite(depth_mm) and math.isfinite(pitch_deg)):
        raise ValueError("scene_to_world: depth_mm and pitch_deg must be finite")
    right, up, toward, center = screen_frame(screen)
    p = math.radians(pitch_deg)
    up_s = math.cos(p) * up + math.sin(p) * toward        # scene z
    north_s = -math.cos(p) * toward + math.sin(p) * up    # scene y
    R_world_scene = np.column_stack([right, north_s, up_s])
    origin = center - float(depth_mm) * toward
    m = np.eye(4)
    m[:3, :3] = s * R_world_scene
    m[:3, 3] = origin - s * R_world_scene @ c
    return SceneTransform(m)


# --------------------------------------------------------------------------
# shaders
# --------------------------------------------------------------------------

# Shading is per vertex (Gouraud): Lambert + ambient times the height colour,
# one interpolated colour per fragment. On llvmpipe the cost of a triangle
# grows with the number of interpolated values; per-pixel lighting (normal,
# height and the wireframe's barycentric coordinates: 7 values) made a PLOD
# frame 1.6x as slow as one colour (3) for the same image within a few grey
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

const vec3 LOW = vec3(0.30, 0.42, 0.26);   // grey-green valleys
const vec3 MID = vec3(0.52, 0.56, 0.40);
const vec3 HIGH = vec3(0.80, 0.80, 0.76);  // pale grey peaks

void main() {
    gl_Position = u_mvp * vec4(in_position, 1.0);
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

_GEOMETRY_SHADER = """
#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 v_color[];
out vec3 g_color;
out vec3 g_bary;              // barycentric coordinates, for the wireframe
void main() {
    for (int i = 0; i < 3; ++i) {
        gl_Position = gl_in[i].gl_Position;
        g_color = v_color[i];
        g_bary = vec3(i == 0, i == 1, i == 2);
        gl_PrimitiveID = gl_PrimitiveIDIn;
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
#endif
out vec4 f_color;

void main() {
    vec3 color = COLOR;
#ifdef LEVELS
    int width = textureSize(u_levels, 0).x;
    uint level = texelFetch(u_levels, ivec2(gl_PrimitiveID % width, gl_PrimitiveID / width), 0).r;
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
    per triangle (measured 1.3-1.5x faster draws than the soup of the same
    triangles).
    """

    def __init__(self, ctx: "moderngl.Context", size: tuple[int, int] = (1280, 720), *,
                 samples: int = 0, background: tuple[float, float, float] = (0.62, 0.72, 0.82)):
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

        self.programs = {}
        for mode, defines in _VARIANTS.items():
            self.programs[mode] = ctx.program(
                vertex_shader=_shader_variant(_VERTEX_SHADER, defines),
                geometry_shader=_shader_variant(_GEOMETRY_SHADER, defines) if "WIRE" in defines else None,
                fragment_shader=_shader_variant(_FRAGMENT_SHADER, defines))
        self.programs["levels"]["u_palette"].write((PALETTE.astype("f4") / 255.0).tobytes())
        self.programs["levels"]["u_levels"].value = 0          # texture unit 0
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
               tag: Any = None) -> None:
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
        if n:
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

    def render(self, view: Any, proj: Any, model: Any = None, view_mode: str = "shaded",
               light_dir: Any = (0.4, -0.3, 0.85), *, ambient: float = 0.25,
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

        wire = view_mode == "wire"
        prog = self.programs[view_mode]
        prog["u_mvp"].write(np.ascontiguousarray(mvp.T, dtype="f4").tobytes())  # column-major
        prog["u_light"].value = tuple(light)
        prog["u_ambient"].value = float(ambient)
        if view_mode != "levels":      # the levels view does not use heights (the uniform is compiled out)
            prog["u_height_range"].value = tuple(float(v) for v in self.height_range)
        if wire:
            prog["u_wire_px"].value = float(wire_px)
            prog["u_wire_color"].value = tuple(float(c) for c in wire_color)

        ctx = self.ctx
        ctx.finish()  # uploads and earlier work are not part of the timing
        t0 = time.perf_counter()
        self._fbo.use()
        self._fbo.viewport = (0, 0, *self.size)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self._fbo.clear(*self.background, 1.0, depth=1.0)
        if self.n_triangles:
            if view_mode == "levels":
                self._level_texture.use(0)
            self._vaos[view_mode, self.indexed].render(moderngl.TRIANGLES, vertices=3 * self.n_triangles)
        if self.samples:
            ctx.copy_framebuffer(self._resolve, self._fbo)
        ctx.finish()
        t1 = time.perf_counter()
        w, h = self.size
        # RGBA is GL's native layout here: reading it is ~10x faster on llvmpipe than RGB;
        # one cvtColor drops alpha and (reading the rows bottom-up) flips.
        if self._rgba is None:
            self._rgba = np.empty((h, w, 4), np.uint8)
        self._resolve.read_into(self._rgba, components=4)
        image = cv2.cvtColor(self._rgba[::-1], cv2.COLOR_RGBA2RGB)
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


# --------------------------------------------------------------------------
# overlay
# --------------------------------------------------------------------------

_SHIFT = 4  # cv2 sub-pixel bits: coordinates in 1/16 px


def overlay_poi(image: np.ndarray, poi_px: Any, cov_deg2: Any, px_per_deg: float,
                color: tuple[int, int, int] = (255, 40, 40), *, n_sigma: float = 2.0,
                cross_px: int = 12, thickness: int = 1, inplace: bool = False) -> np.ndarray:
    """Draw the point of interest and its uncertainty ellipse.

    Parameters
    ----------
    image : ndarray, shape (H, W, 3), uint8
        Image to draw on (e.g. from :meth:`TerrainRenderer.render`), pixel
        (x, y) = column x, row y.
    poi_px : array_like, shape (2,), or None
        POI in image pixels (x right, y down). ``None`` or non-finite: the
        image is returned unchanged (a frame without a pose).
    cov_deg2 : array_like, shape (2, 2), or None
        Covariance of (φ, θ), deg² (conventions.md: φ vertical, positive up;
        θ horizontal, positive right). ``None``: crosshair only.
    px_per_deg : float
        Image pixels per degree of viewing direction at the POI (about
        ``distance_mm * pi / 180 / pixel_pitch_mm``); treats the mapping as
        locally isotropic and the head axes as aligned with the screen's.
    color : tuple of int
        Colour in the image's channel order (RGB for rendered images).
    n_sigma : float
        Ellipse at ``n_sigma`` standard deviations (2: ~86 % of a 2-D
        Gaussian).
    cross_px : int
        Half-length of the crosshair arms, px.
    thickness : int
        Line thickness, px.
    inplace : bool
        Draw into ``image`` itself instead of a copy.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
        The image with the overlay.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] not in (3, 4):
        raise ValueError(f"overlay_poi: image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
    out = img if inplace else img.copy()
    if poi_px is None:
        return out
    p = np.asarray(poi_px, dtype=np.float64).reshape(-1)
    if p.shape != (2,):
        raise ValueError(f"overlay_poi: poi_px has shape {np.shape(poi_px)}, expected (2,)")
    h, w = out.shape[:2]
    limit = 4.0 * max(h, w)
    if not np.isfinite(p).all() or np.abs(p).max() > limit:
        return out
    col = tuple(int(c) for c in color)
    scale = 1 << _SHIFT
    cx, cy = (int(round(v * scale)) for v in p)
    arm = int(cross_px) * scale
    cv2.line(out, (cx - arm, cy), (cx + arm, cy), col, thickness, cv2.LINE_AA, _SHIFT)
    cv2.line(out, (cx, cy - arm), (cx, cy + arm), col, thickness, cv2.LINE_AA, _SHIFT)
    if cov_deg2 is not None:
        c = np.asarray(cov_deg2, dtype=np.float64)
        if c.shape != (2, 2):
            raise ValueError(f"overlay_poi: cov_deg2 has shape {c.shape}, expected (2, 2) in (φ, θ) order")
        ppd = float(px_per_deg)
        if not (math.isfinite(ppd) and ppd > 0):
            raise ValueError(f"overlay_poi: px_per_deg must be > 0, got {px_per_deg!r}")
        if np.isfinite(c).all():
            # image axes (x, y) = (θ, −φ) * px_per_deg
            c_img = ppd ** 2 * np.array([[c[1, 1], -c[0, 1]], [-c[1, 0], c[0, 0]]])
            c_img = 0.5 * (c_img + c_img.T)
            evals, evecs = np.linalg.eigh(c_img)
            if evals[0] >= 0 and evals[1] > 0:
                half = np.minimum(n_sigma * np.sqrt(evals), limit)
                angle = math.degrees(math.atan2(evecs[1, 0], evecs[0, 0]))  # of the evals[0] axis
                axes = (int(round(half[0] * scale)), int(round(half[1] * scale)))
                cv2.ellipse(out, (cx, cy), axes, angle, 0.0, 360.0, col, thickness, cv2.LINE_AA, _SHIFT)
    return out
