"""Murphy & Duchowski's hybrid image/model rendering of the terrain: rays through a CSF ray mask (``raymask``).

Per frame (:meth:`RayMaskRenderer.render`), all on the GL context:

1. **Cast the ring samples** (:class:`headplod.plod.raymask.RayMask`): one
   fragment per sample in a float texture (samples laid out row by row,
   1024 wide); each fragment casts its ray against the terrain's height
   field and writes the hit's colour and clip-space w (eye depth), or a
   miss (w = -1). The texture is read back (16 bytes per sample).
2. **Classify the quads** (numpy): all four corners hit and their depths
   within ``1 + depth_ratio`` of each other: drawn by rasterisation;
   mixed hit/miss corners (the terrain meets the sky) or a depth jump (a
   nearer ridge in front of a farther slope): a *silhouette quad*; all
   miss: background.
3. **Rasterise the intermediate mesh**: the drawn quads as two triangles
   each, vertices at the samples' pixel positions with the hits' colours
   (interpolated perspective-correctly with the hits' w).
4. **Cast every pixel** of the filled inset (points, one per pixel) and of
   the silhouette quads (the quads rasterised with the ray-casting shader),
   overwriting what step 3 drew. With ``silhouettes=False`` the silhouette
   quads are drawn by rasterisation instead where their corners hit (a
   triangle whose three corners all hit), so the silhouette is as coarse as
   the mask there.

The ray caster
--------------
The triangles are those ``full`` draws (:func:`headplod.plod.raymask.height_grid`:
two per grid cell, diagonal (i, j)–(i+1, j+1)), so a pixel cast here and
a pixel of ``full`` see the same surface. The rays walk a maximum mipmap
of the height field (:meth:`HeightGrid.max_mip`; Tevs et al. 2008): a
node is skipped when the ray stays above its highest vertex over the
node's extent; otherwise the walk descends, and at a cell the ray is
intersected with its two triangles exactly. The hit's colour is the
barycentric blend of the three vertices' colours, each computed as
:mod:`headplod.render.gl`'s vertex shader does (Lambert + ambient times the
height colour; GL interpolates perspective-correctly, i.e. barycentrically
on the triangle), so the cast pixel matches ``full``'s to float rounding.

The ray caster runs as a GLSL fragment shader. A vectorized numpy caster
was timed only as its inner step (one traversal step for every ray of a
frame) and already took longer than the shader's whole cast, so it was not
built. Rays start 4 levels below the top (the coarse levels hold a peak
almost everywhere) and go up one level only when they leave their parent
node. Rasterising the level-3/4/6 blocks as boxes to start each pixel's
ray at its first box was tried: identical images, no measurable gain (the
steps that cost are the divergent grazing rays near the horizon, not the
descent), so it was dropped. Ring samples are cast in 4x4 tiles (rings x
angles) of the sample texture so that a SIMD block of fragments casts
neighbouring rays.

Where the time goes (llvmpipe): a SIMD block of fragments waits for its
slowest ray; the filled inset (the Geisler–Perry cutoff at C = 1 needs
every pixel out to about 12°) and the rings are most of the frame, the
intermediate mesh of small triangles most of the rest. ``full``
rasterises its triangles in about the time of those rays, so on a CPU
rasteriser the hybrid is not faster than ``full`` at the paper's contrast;
at the terrain's median shading contrast it casts fewer rays (``headplod
bench plod``'s ray-mask part, :mod:`headplod.bench.plod_raymask`).

Frames and units: image px (x right, y down, (0, 0) the centre of the
top-left pixel); the grid frame of the caster is (column, row, height in
scene units): scene x = origin_x + column * dx, y likewise.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..plod.raymask import HeightGrid, RayMask, RayMaskConfig, build_ray_mask, height_grid
from ..plod.shading import AMBIENT, LIGHT_DIR, height_colour, shade
from .context import moderngl
from .gl import BACKGROUND_RGB, read_rgb

__all__ = ["RayMaskRenderer", "vertex_colors", "classify_quads"]

_SAMPLE_TEXTURE_WIDTH = 1024
_TILE = 4                  # ring samples sit in the sample texture in tiles of 4 rings x 4 angles

_CAST_LIB = """
uniform sampler2D u_grid;      // (N+1)^2 RGBA32F: vertex colour rgb, height (scene units)
uniform sampler2D u_cells;     // N^2 RGBA32F: each cell's corner heights (0,0), (1,0), (0,1), (1,1)
uniform sampler2D u_maxmip;    // R32F atlas 2N x N: level k at x offset 2N - (2N >> k)
uniform int u_n;               // cells per side
uniform int u_top;             // log2(u_n)
uniform vec3 u_eye;            // the eye in grid coordinates (column, row, height)
uniform mat3 u_dir;            // NDC (x, y, 1) -> ray direction, grid coordinates
uniform vec4 u_wrow;           // grid (column, row, height, 1) -> clip w
uniform vec2 u_size;           // image width, height, px
uniform vec2 u_zrange;         // lowest and highest vertex
uniform vec3 u_background;
uniform int u_max_steps;

const float EPS = 1e-3;        // step past a node's exit, cells
const float TOL = 5e-4;        // tolerance of the triangle test, cells (float32 error of the hit ~1e-4)
const int START_DROP = 4;      // rays start this many levels below the top (they ascend when they need to)

int level_offset(int k) { return k == 0 ? 0 : 2 * u_n - ((2 * u_n) >> k); }

// Cast the ray through image pixel `pix`; (colour, clip w), w = -1 on a miss.
vec4 cast_ray(vec2 pix) {
    vec2 ndc = vec2((pix.x + 0.5) / u_size.x * 2.0 - 1.0, 1.0 - (pix.y + 0.5) / u_size.y * 2.0);
    vec3 d = u_dir * vec3(ndc, 1.0);
    d /= max(length(d.xy), 1e-6);                 // t counts cells along the ground
    vec3 o = u_eye;
    vec3 dd = vec3(abs(d.x) < 1e-9 ? 1e-9 : d.x, abs(d.y) < 1e-9 ? 1e-9 : d.y, abs(d.z) < 1e-9 ? 1e-9 : d.z);
    vec3 inv = 1.0 / dd;
    vec3 t0 = (vec3(0.0, 0.0, u_zrange.x) - o) * inv;
    vec3 t1 = (vec3(float(u_n), float(u_n), u_zrange.y) - o) * inv;
    vec3 tlo = min(t0, t1), thi = max(t0, t1);
    float tin = max(max(tlo.x, tlo.y), max(tlo.z, 0.0));
    float tout = min(min(thi.x, thi.y), thi.z);
    if (tin > tout) return vec4(u_background, -1.0);
    // Restart the ray where it enters the grid's box: coordinates there are <= N, so the cell tests
    // below lose less to float32 than from an eye thousands of cells away.
    o += d * tin;
    tout -= tin;
    float t = 0.0;
    int level = max(u_top - START_DROP, 0);
    vec2 dirstep = step(0.0, d.xy);
    for (int it = 0; it < u_max_steps; ++it) {
        if (t > tout + EPS) break;
        vec3 p = o + d * t;
        int size = 1 << level;
        ivec2 node = clamp(ivec2(floor(p.xy / float(size))), ivec2(0), ivec2((u_n >> level) - 1));
        vec2 lo = vec2(node * size);
        vec2 txy = (lo + float(size) * dirstep - o.xy) * inv.xy;
        float texit = max(min(txy.x, txy.y), t);
        if (level > 0) {
            float zmax = texelFetch(u_maxmip, ivec2(level_offset(level) + node.x, node.y), 0).r;
            if (min(p.z, o.z + d.z * texit) <= zmax) { level -= 1; continue; }
        } else {
            // A cell: its two triangles, (0,0)-(1,0)-(1,1) and (0,0)-(1,1)-(0,1).
            vec4 h = texelFetch(u_cells, node, 0);        // h00, h10, h01, h11
            vec3 q = o - vec3(vec2(node), 0.0);
            float best = 1e30;
            vec2 fbest = vec2(0.0);
            bool upper = false;
            float bA = h.y - h.x, cA = h.w - h.y;
            float den = d.z - bA * d.x - cA * d.y;
            if (den != 0.0) {
                float tA = (h.x + bA * q.x + cA * q.y - q.z) / den;
                vec2 f = q.xy + d.xy * tA;
                if (tA >= 0.0 && f.y >= -TOL && f.x <= 1.0 + TOL && f.y <= f.x + TOL) { best = tA; fbest = f; }
            }
            float bB = h.w - h.z, cB = h.z - h.x;
            den = d.z - bB * d.x - cB * d.y;
            if (den != 0.0) {
                float tB = (h.x + bB * q.x + cB * q.y - q.z) / den;
                vec2 f = q.xy + d.xy * tB;
                if (tB >= 0.0 && tB < best && f.x >= -TOL && f.y <= 1.0 + TOL && f.x <= f.y + TOL) {
                    best = tB; fbest = f; upper = true;
                }
            }
            if (best < 1e30) {
                vec2 f = fbest;
                vec3 c00 = texelFetch(u_grid, node, 0).rgb;
                vec3 c11 = texelFetch(u_grid, node + ivec2(1, 1), 0).rgb;
                vec3 colour = upper
                    ? (1.0 - f.y) * c00 + f.x * c11 + (f.y - f.x) * texelFetch(u_grid, node + ivec2(0, 1), 0).rgb
                    : (1.0 - f.x) * c00 + (f.x - f.y) * texelFetch(u_grid, node + ivec2(1, 0), 0).rgb + f.y * c11;
                vec3 hit = o + d * best;
                return vec4(clamp(colour, 0.0, 1.0), dot(u_wrow, vec4(hit, 1.0)));
            }
        }
        // Past this node; one level up when the next node lies in another parent.
        t = texit + EPS;
        vec2 pn = o.xy + d.xy * t;
        ivec2 next = ivec2(floor(pn / float(size)));
        if (level < u_top && (next >> 1) != (node >> 1)) level += 1;
    }
    return vec4(u_background, -1.0);
}
"""

_FULLSCREEN_VS = """
#version 330
const vec2 P[3] = vec2[3](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
void main() { gl_Position = vec4(P[gl_VertexID], 0.0, 1.0); }
"""

# Pass 1: one fragment per sample (texel x, y = sample y * width + x).
_SAMPLES_FS = "#version 330\n" + _CAST_LIB + """
uniform sampler2D u_samples;   // RG32F: the samples' image px
out vec4 f_hit;
void main() {
    f_hit = cast_ray(texelFetch(u_samples, ivec2(gl_FragCoord.xy), 0).xy);
}
"""

# Pixels cast in place: the fill as points, the silhouette quads as triangles.
_PIXEL_VS = """
#version 330
uniform vec2 u_size;
in vec2 in_px;                 // image px
void main() {
    gl_Position = vec4((in_px.x + 0.5) / u_size.x * 2.0 - 1.0, 1.0 - (in_px.y + 0.5) / u_size.y * 2.0, 0.0, 1.0);
    gl_PointSize = 1.0;
}
"""
_PIXEL_FS = "#version 330\n" + _CAST_LIB + """
#ifdef FILL
uniform sampler2D u_fill;      // R8, image rows top to bottom: 1 where the pixel is in the filled inset
#endif
out vec4 f_color;
void main() {
    vec2 pix = vec2(gl_FragCoord.x - 0.5, u_size.y - gl_FragCoord.y - 0.5);
#ifdef FILL
    if (texelFetch(u_fill, ivec2(pix), 0).r < 0.5) discard;
#endif
    f_color = vec4(cast_ray(pix).rgb, 1.0);
}
"""

# The intermediate mesh: samples at their pixels, the hits' colours, perspective-correct with their w.
_MESH_VS = """
#version 330
uniform vec2 u_size;
in vec2 in_px;
in vec4 in_hit;                // colour rgb, clip w (> 0: only hits are drawn)
out vec3 v_color;
void main() {
    vec2 ndc = vec2((in_px.x + 0.5) / u_size.x * 2.0 - 1.0, 1.0 - (in_px.y + 0.5) / u_size.y * 2.0);
    float w = max(in_hit.w, 1e-6);
    gl_Position = vec4(ndc * w, 0.0, w);
    v_color = in_hit.rgb;
}
"""
_MESH_FS = """
#version 330
in vec3 v_color;
out vec4 f_color;
void main() { f_color = vec4(v_color, 1.0); }
"""


def vertex_colors(grid: HeightGrid, height_range, light_dir=LIGHT_DIR, ambient: float = AMBIENT) -> np.ndarray:
    """Each grid vertex's colour as :mod:`headplod.render.gl`'s "shaded" vertex shader computes it, (ny+1, nx+1, 3) float32.

    :func:`headplod.plod.shading.shade` times the height colour (low → mid →
    high over ``height_range``, scene units), in float32; the light by
    default :mod:`headplod.plod.shading`'s, the one every back end draws with.
    """
    f = np.float32
    n = grid.normals.astype(f)
    shaded = shade(n / np.linalg.norm(n, axis=-1, keepdims=True), light_dir, ambient)      # float32
    lo, hi = (f(v) for v in height_range)
    span = max(hi - lo, f(1e-20))
    t = np.clip((grid.heights.astype(f) - lo) / span, f(0), f(1))
    return (height_colour(t) * shaded[..., None]).astype(f)


def classify_quads(quads: np.ndarray, hits: np.ndarray, depth_ratio: float):
    """Split the mask's quads by their corners' hits.

    Parameters
    ----------
    quads : (Q, 4) int
        Rows of the samples.
    hits : (N, 4) float32
        Per sample: colour rgb, clip w (eye depth; < 0: the ray missed).
    depth_ratio : float
        A quad whose hits' w span more than ``1 + depth_ratio`` (farthest
        over nearest) straddles an occluding ridge.

    Returns
    -------
    drawn : (D,) int64
        Quads whose four corners hit on one surface (rasterised).
    silhouette : (S,) int64
        Quads with mixed hit/miss corners or a depth jump.
    """
    wcol = np.ascontiguousarray(hits[:, 3])
    q = np.asarray(quads)
    w = [wcol[q[:, i]] for i in range(4)]                   # four (Q,) columns: faster than (Q, 4) reductions
    w_near = np.minimum(np.minimum(w[0], w[1]), np.minimum(w[2], w[3]))
    w_far = np.maximum(np.maximum(w[0], w[1]), np.maximum(w[2], w[3]))
    all_hit = w_near > 0                                    # misses have w = -1
    mixed = (w_far > 0) & ~all_hit
    jump = all_hit & (w_far > (1.0 + depth_ratio) * w_near)
    return np.flatnonzero(all_hit & ~jump), np.flatnonzero(mixed | jump)


class RayMaskRenderer:
    """The hybrid renderer on a GL context, for one terrain mesh.

    Parameters
    ----------
    ctx : moderngl.Context
    mesh : headplod.plod.mesh.AdaptiveMesh
        Its ``full`` mesh is the surface the rays hit.
    size : (2,) int
        Image (width, height), px.
    background : tuple of float
        RGB in [0, 1] where rays miss (the terrain renderer's sky).
    max_steps : int
        Traversal steps per ray before it is taken as a miss (4096).

    Attributes
    ----------
    last_stats : dict
        After :meth:`render`: ``rays`` (cast in all passes), ``ring_rays``,
        ``fill_rays``, ``silhouette_rays`` (fragments cast in the
        silhouette quads), ``silhouette_quads``, ``drawn_quads``,
        ``cast_ms`` (ring samples cast + read back), ``classify_ms``
        (numpy), ``raster_ms`` (mesh + fill + silhouettes, GL finished),
        ``render_ms`` (all of them; excludes the final read-back),
        ``readback_ms``.
    last_silhouette_quads : (S,) int64
        After :meth:`render`: the silhouette quads, as rows of the mask's ``quads``.
    last_hits : (N_ring, 4) float32
        After :meth:`render`: each ring sample's colour (rgb) and clip w
        (< 0: a miss), in the mask's sample order (the samples after the fill).
    """

    def __init__(self, ctx, mesh, size=(1280, 720), *, background=BACKGROUND_RGB, max_steps: int = 4096):
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValueError(f"RayMaskRenderer: size must be positive (width, height), got {size!r}")
        self.ctx, self.size = ctx, (w, h)
        self.background = tuple(float(c) for c in background)
        self.grid = grid = height_grid(mesh)
        nx, ny = grid.shape_cells
        lo, hi = float(grid.heights.min()), float(grid.heights.max())
        colors = vertex_colors(grid, (lo, hi if hi > lo else lo + 1.0))     # the light of plod.shading
        texels = np.concatenate([colors, grid.heights[..., None]], axis=-1).astype("f4")
        self._grid_tex = ctx.texture((nx + 1, ny + 1), 4, texels.tobytes(), dtype="f4")
        mips = grid.max_mip()
        atlas = np.zeros((nx, 2 * nx), np.float32)
        for k, m in enumerate(mips):                                    # loop over levels
            off = 0 if k == 0 else 2 * nx - ((2 * nx) >> k)
            atlas[:m.shape[0], off:off + m.shape[1]] = m
        self._mip_tex = ctx.texture((2 * nx, nx), 1, atlas.tobytes(), dtype="f4")
        hh = grid.heights
        cells = np.stack([hh[:-1, :-1], hh[:-1, 1:], hh[1:, :-1], hh[1:, 1:]], axis=-1).astype("f4")
        self._cell_tex = ctx.texture((nx, ny), 4, np.ascontiguousarray(cells).tobytes(), dtype="f4")
        for tex in (self._grid_tex, self._mip_tex, self._cell_tex):
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._zrange = (lo, hi)
        self._top = int(np.log2(nx))
        self.max_steps = int(max_steps)
        self._progs = {
            "samples": ctx.program(vertex_shader=_FULLSCREEN_VS, fragment_shader=_SAMPLES_FS),
            "pixels": ctx.program(vertex_shader=_PIXEL_VS, fragment_shader=_PIXEL_FS),
            "fill": ctx.program(vertex_shader=_PIXEL_VS, fragment_shader=_PIXEL_FS.replace(
                "#version 330\n", "#version 330\n#define FILL 1\n", 1)),
            "mesh": ctx.program(vertex_shader=_MESH_VS, fragment_shader=_MESH_FS),
        }
        self._fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)])
        self._rgba = np.empty((h, w, 4), np.uint8)
        self._empty_vao = ctx.vertex_array(self._progs["samples"], [])
        self._mask = None          # the RayMask the buffers below hold
        self._mask_cache = {}      # the masks mask() built, by their inputs, oldest first
        self._last_mask = None
        self.last_mask_ms = float("nan")
        self._buffers = {}
        self.last_stats: dict = {}

    # -- per mask --------------------------------------------------------------
    def _set_mask(self, mask: RayMask) -> None:
        """Upload a mask's samples: the ring samples' texture and target, the pixel positions."""
        if mask is self._mask:
            return
        ctx = self.ctx
        for obj in self._buffers.values():
            obj.release()
        self._buffers = {}
        n_ring = len(mask.samples_px) - mask.n_fill
        ring_px = mask.samples_px[mask.n_fill:].astype(np.float32)
        # Texels in tiles of 4 rings x 4 angles, so that the rays a SIMD block of fragments casts
        # together are neighbours on the image (row-major sample order put rays a ring apart side by
        # side, and each block waited for its slowest, diverging ray).
        k, m = mask.ring_of[mask.n_fill:], mask.angle_of[mask.n_fill:]
        tile = (k // _TILE) * (mask.n_angles // _TILE + 1) + m // _TILE
        tiles, tile_index = np.unique(tile, return_inverse=True)
        per_row = _SAMPLE_TEXTURE_WIDTH // _TILE
        width = _SAMPLE_TEXTURE_WIDTH
        rows = max(1, -(-len(tiles) // per_row)) * _TILE
        tx = (tile_index % per_row) * _TILE + m % _TILE
        ty = (tile_index // per_row) * _TILE + k % _TILE
        texels = np.zeros((rows, width, 2), np.float32)
        # Texels no sample uses take their tile's first sample (a coherent ray, not one from pixel 0).
        first = np.zeros(len(tiles), np.int64)
        first[tile_index[::-1]] = np.arange(n_ring)[::-1]
        tile_of_texel = (np.arange(rows)[:, None] // _TILE) * per_row + np.arange(width)[None, :] // _TILE
        valid = tile_of_texel < len(tiles)
        if n_ring:
            texels[valid] = ring_px[first[tile_of_texel[valid]]]
            texels[ty, tx] = ring_px
        self._texel_of = (ty, tx)
        b = self._buffers
        b["sample_tex"] = ctx.texture((width, rows), 2, texels.tobytes(), dtype="f4")
        b["sample_tex"].filter = (moderngl.NEAREST, moderngl.NEAREST)
        b["hit_tex"] = ctx.texture((width, rows), 4, dtype="f4")
        b["hit_fbo"] = ctx.framebuffer(color_attachments=[b["hit_tex"]])
        b["ring_px"] = ctx.buffer(ring_px.tobytes() if n_ring else bytes(8))      # GL buffers cannot be empty
        b["ring_hit"] = ctx.buffer(reserve=max(n_ring, 1) * 16)
        # The fill: a mask texture and the rectangle around it (two triangles, image px).
        fill = mask.fill_px
        w, h = self.size
        fill_mask = np.zeros((h, w), np.uint8)
        fill_mask[fill[:, 1], fill[:, 0]] = 255
        b["fill_tex"] = ctx.texture((w, h), 1, fill_mask.tobytes(), dtype="f1")
        b["fill_tex"].filter = (moderngl.NEAREST, moderngl.NEAREST)
        if len(fill):
            (x0, y0), (x1, y1) = fill.min(axis=0) - 0.5, fill.max(axis=0) + 0.5
        else:
            x0 = y0 = x1 = y1 = -10.0
        rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y0], [x1, y1], [x0, y1]], "f4")   # pixel edges
        b["fill_px"] = ctx.buffer(rect.tobytes())
        b["mesh_index"] = ctx.buffer(reserve=4)
        b["sil_index"] = ctx.buffer(reserve=4)
        self._hits = np.empty((rows, width, 4), np.float32)
        self._hits_items = self._hits.view("V16").reshape(-1)      # one 16-byte item per texel
        self._texel_flat = self._texel_of[0] * width + self._texel_of[1]
        self._n_ring, self._rows = n_ring, rows
        self._quads = mask.quads - mask.n_fill
        self._quad_triangles = np.ascontiguousarray(self._quads[:, [0, 1, 2, 0, 2, 3]], dtype=np.uint32
                                                    ).view("V24").reshape(-1)     # one 24-byte item per quad
        self._quads = np.ascontiguousarray(self._quads)
        self._mask = mask
        # Vertex arrays over the buffers (made again for each mask: they are cheap).
        self._vao_fill = ctx.vertex_array(self._progs["fill"], [(b["fill_px"], "2f", "in_px")])
        self._make_indexed_vaos()

    def _make_indexed_vaos(self):
        b, ctx = self._buffers, self.ctx
        self._vao_mesh = ctx.vertex_array(self._progs["mesh"], [(b["ring_px"], "2f", "in_px"),
                                                                (b["ring_hit"], "4f", "in_hit")],
                                          index_buffer=b["mesh_index"], index_element_size=4)
        self._vao_sil = ctx.vertex_array(self._progs["pixels"], [(b["ring_px"], "2f", "in_px")],
                                         index_buffer=b["sil_index"], index_element_size=4)

    def _write_index(self, name, data: np.ndarray) -> None:
        """Write (T, 3) indices; the buffer is orphaned to grow (same GL name: the vertex arrays stay valid)."""
        raw = np.ascontiguousarray(data, dtype=np.uint32).tobytes()
        buf = self._buffers[name]
        need = max(len(raw), 4)
        if need > buf.size or need < buf.size // 4:
            buf.orphan(need)
        if raw:
            buf.write(raw)

    # -- per frame ---------------------------------------------------------------
    def _uniforms(self, view, proj, model):
        """Set the cast uniforms of every program from the matrices (float64 on the CPU)."""
        g = self.grid
        nx, _ = g.shape_cells
        # grid (column, row, height) -> scene
        T_scene_grid = np.eye(4)
        T_scene_grid[0, 0], T_scene_grid[1, 1] = g.cell
        T_scene_grid[:2, 3] = g.origin
        T_clip_grid = np.asarray(proj, float) @ np.asarray(view, float) @ np.asarray(model, float) @ T_scene_grid
        inv = np.linalg.inv(T_clip_grid)
        # The eye is the point mapped to clip (0, 0, *, 0): the null vector of rows x, y, w of T_clip_grid.
        A = T_clip_grid[[0, 1, 3], :]
        _, _, vt = np.linalg.svd(A)
        e = vt[-1]
        eye = e[:3] / e[3]
        # Directions: far-plane points (NDC z = 1) minus the eye, affine in NDC (x, y).
        cols = []
        for x, y in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)):
            p = inv @ np.array([x, y, 1.0, 1.0])
            cols.append(p[:3] / p[3] - eye)
        c0, cx, cy = cols
        D = np.column_stack([cx - c0, cy - c0, c0])       # d = D @ (x, y, 1)
        D /= np.abs(D).max()
        wrow = T_clip_grid[3]
        values = {"u_grid": 0, "u_maxmip": 1, "u_cells": 4, "u_n": nx, "u_top": self._top,
                  "u_eye": tuple(float(v) for v in eye), "u_wrow": tuple(float(v) for v in wrow),
                  "u_size": tuple(float(v) for v in self.size),
                  "u_zrange": tuple(float(v) for v in self._zrange), "u_background": self.background,
                  "u_max_steps": self.max_steps}
        for name in ("samples", "pixels", "fill"):
            prog = self._progs[name]
            prog["u_dir"].write(D.T.astype("f4").tobytes())          # column-major
            for key, value in values.items():
                if key in prog:                                        # unused uniforms are compiled out
                    prog[key].value = value
        self._progs["samples"]["u_samples"].value = 2
        self._progs["fill"]["u_fill"].value = 3
        self._progs["mesh"]["u_size"].value = tuple(float(v) for v in self.size)

    def render(self, mask: RayMask, view, proj, model, config: RayMaskConfig = RayMaskConfig()) -> np.ndarray:
        """One frame: (H, W, 3) uint8 RGB, row 0 at the top (see the module notes for the passes).

        ``view``, ``proj``, ``model``: ``T_eye_world``, ``T_clip_eye``,
        ``T_world_scene`` (4, 4), as :meth:`TerrainRenderer.render` takes them.
        """
        ctx = self.ctx
        self._set_mask(mask)
        self._uniforms(view, proj, model)
        ctx.finish()
        t0 = time.perf_counter()
        ctx.disable(moderngl.DEPTH_TEST | moderngl.CULL_FACE | moderngl.BLEND)
        ctx.enable(moderngl.PROGRAM_POINT_SIZE)
        self._grid_tex.use(0)
        self._mip_tex.use(1)
        self._cell_tex.use(4)
        b = self._buffers
        b["sample_tex"].use(2)
        b["fill_tex"].use(3)
        # 1. the ring samples
        if self._n_ring:
            b["hit_fbo"].use()
            b["hit_fbo"].viewport = (0, 0, _SAMPLE_TEXTURE_WIDTH, self._rows)
            self._empty_vao.render(moderngl.TRIANGLES, vertices=3)
            b["hit_tex"].read_into(self._hits)
        hits = self._hits_items[self._texel_flat].view(np.float32).reshape(-1, 4)   # (n_ring, 4), sample order
        self.last_hits = hits
        t1 = time.perf_counter()
        # 2. classify
        drawn, sil = classify_quads(self._quads, hits, config.depth_ratio)
        self.last_silhouette_quads = sil
        tri6 = self._quad_triangles                               # (Q,) 24-byte rows: two triangles per quad
        tri_drawn = tri6[drawn].view(np.uint32).reshape(-1, 3)
        if config.silhouettes:
            tri_sil = tri6[sil].view(np.uint32).reshape(-1, 3)
        else:
            # Without refinement a silhouette quad is rasterised where its triangles' corners all hit.
            tri = tri6[sil].view(np.uint32).reshape(-1, 3)
            tri_drawn = np.concatenate([tri_drawn, tri[(hits[tri, 3] > 0).all(axis=1)]])
            tri_sil = np.zeros((0, 3), np.uint32)
        b["ring_hit"].write(hits.tobytes())
        self._write_index("mesh_index", tri_drawn)
        self._write_index("sil_index", tri_sil)
        t2 = time.perf_counter()
        # 3. the intermediate mesh, 4. the pixels cast in place
        self._fbo.use()
        self._fbo.viewport = (0, 0, *self.size)
        self._fbo.clear(*self.background, 1.0)
        if len(tri_drawn):
            self._vao_mesh.render(moderngl.TRIANGLES, vertices=3 * len(tri_drawn))
        query = ctx.query(samples=True)
        with query:
            if len(tri_sil):
                self._vao_sil.render(moderngl.TRIANGLES, vertices=3 * len(tri_sil))
        if mask.n_fill:
            self._vao_fill.render(moderngl.TRIANGLES, vertices=6)
        ctx.finish()
        t3 = time.perf_counter()
        image = read_rgb(self._fbo, self._rgba)
        t4 = time.perf_counter()
        sil_rays = int(query.samples) if len(tri_sil) else 0

        self.last_stats = {
            "rays": int(self._n_ring + mask.n_fill + sil_rays), "ring_rays": int(self._n_ring),
            "fill_rays": int(mask.n_fill), "silhouette_rays": sil_rays, "silhouette_quads": int(len(sil)),
            "drawn_quads": int(len(drawn)), "cast_ms": (t1 - t0) * 1e3, "classify_ms": (t2 - t1) * 1e3,
            "raster_ms": (t3 - t2) * 1e3, "render_ms": (t3 - t0) * 1e3, "readback_ms": (t4 - t3) * 1e3}
        return image

    def mask(self, screen, eye_mm, poi_px, px_per_deg: float, cov_deg2=None,
             config: RayMaskConfig = RayMaskConfig()) -> RayMask:
        """The ray mask of a view, built by :func:`build_ray_mask` or reused when the view is unchanged.

        The last few masks (8) are kept with their inputs (eye, POI,
        covariance, px/deg, and the config's mask settings; compared
        exactly): a still head and POI reuse theirs, so their frames are
        identical. ``last_mask_ms``: the build time, 0 when reused.
        """
        mask_settings = dataclasses.replace(config, silhouettes=True, depth_ratio=RayMaskConfig.depth_ratio)
        key = (tuple(np.asarray(eye_mm, float).ravel()), tuple(np.asarray(poi_px, float).ravel()),
               None if cov_deg2 is None else tuple(np.asarray(cov_deg2, float).ravel()), float(px_per_deg),
               mask_settings, id(screen))
        mask = self._mask_cache.pop(key, None)
        if mask is None:
            t0 = time.perf_counter()
            mask = build_ray_mask(screen, eye_mm, poi_px, self.size, px_per_deg, cov_deg2, config)
            self.last_mask_ms = (time.perf_counter() - t0) * 1e3
        else:
            self.last_mask_ms = 0.0
        self._mask_cache[key] = mask                   # most recent last
        while len(self._mask_cache) > 8:
            self._mask_cache.pop(next(iter(self._mask_cache)))
        self._last_mask = mask
        return mask

    def release(self) -> None:
        """Free the GL objects (the context stays)."""
        for obj in [*self._buffers.values(), *self._progs.values(), self._grid_tex, self._mip_tex, self._cell_tex, self._fbo]:
            obj.release()
        self._buffers = {}
        self._mask = None
