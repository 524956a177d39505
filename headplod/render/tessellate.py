"""PLOD on the GPU: a terrain of patches tessellated from a height texture, per-patch CSF levels as factors.

The second PLOD back end (issue 14), beside the CPU one (``LevelSelector`` +
``AdaptiveMesh`` + :class:`headplod.render.gl.TerrainRenderer`):

- The terrain is a :class:`headplod.plod.patches.PatchGrid`: an ``N x N``
  height grid (an R32F texture, mipmapped for the normals of coarse levels)
  cut into patches of ``patch_samples`` sample spacings, drawn as
  ``GL_PATCHES`` of one control point per patch (no vertex buffer: a
  patch is known by its ``gl_VertexID``).
- The CSF levels: a levels pass evaluates the ``csf`` criterion of
  :mod:`headplod.plod.select` in closed form per patch, as
  :func:`headplod.plod.patches.patch_levels` does in numpy (tested equal):
  the patch's inner level from its corners, each outer (edge) level from
  the edge alone (endpoints, midpoint, and the larger contrast of the two
  patches sharing it), so both patches sharing an edge compute the same
  factor: no cracks. Level L is the tessellation factor 2^L
  (``equal_spacing``); the finest level puts one vertex per height sample.
  The highest visible frequency (Lambert's W_{-1}) is solved by Newton's
  method in log form. Patches whose bounding box (corners' x, y; the
  patch's height range) is outside the view frustum are culled. The same
  GLSL runs in the tessellation control shader (``csf_stage="control"``)
  or, by default, in a vertex shader of one vertex per patch
  (``"vertex"``): llvmpipe runs a control shader of one output vertex one
  patch at a time and a vertex shader 8 at a time (16384 patches: 19 ms
  against 66 ms). Either writes the levels to a storage buffer; the draw's
  control shader turns them into tessellation factors.
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
- Shading (``TessellationConfig.shading``). By default (``texture``) every
  sample's colour (``gl.py``'s terrain shading: Lambert + ambient times the
  height colour, with the sample's own normal from central differences, as
  :func:`headplod.plod.patches.grid_normals`) is baked once, on the GPU,
  into a mipmapped RGBA8 texture, and each fragment samples it trilinearly
  at the pixel's footprint. A pixel then shows the average colour of the
  samples it covers whichever level drew it: the geometry is PLOD's, the
  shading is prefiltered as terrain renderers do with colour or normal
  maps. Why: once a sample is smaller than a pixel (8M triangles and up on
  the scale bench's view), the full-detail render's per-vertex shading
  aliases and a coarser level's smoothed normals cannot match it (36.5 dB
  in the 5° disc at 134M; 56 dB with the texture). ``vertex`` keeps the
  per-vertex colour, with a coarse level's normal from the matching mip
  level of the heights (the surface that level can show). Anisotropic
  filtering (``anisotropy``) gained 0.8 dB for 2-3x the frame time on
  llvmpipe, so it is off.

The CPU's share per frame is the uniforms, the read-back of the levels and
the split into draw calls (``headplod bench plod --scale``). Not here (yet):
hysteresis (per-patch state), the read-back contrast, the levels and wire
views.

Frames and units: scene metres → world mm by ``model``; matrices as in
:mod:`headplod.render.projection`; images as :mod:`headplod.render.gl`'s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from ..plod.patch_tree import PatchTree
from ..plod import perception as pc
from ..plod.patches import FACTOR_RULES, PatchGrid, max_level_for, tess_factors
from .context import moderngl
from .gl import _FRAGMENT_SHADER, FULLSCREEN_VERTEX_SHADER, read_rgb

__all__ = ["TessellationConfig", "TessellationRenderer", "TESS_MODES", "REQUIRED_GL", "grid_model", "head_axes",
           "render_frame"]

#: What the control shader computes: the CSF's levels, or every patch at the finest level (the reference).
TESS_MODES = ("csf", "full")

#: OpenGL version the back end needs: 4.0 for tessellation shaders; 4.3 for the storage buffers of the tests.
REQUIRED_GL = 400

_SHIFT_FORMS = {None: 0, "ellipse": 1, "eq1": 2}

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
    level_bias : float
        Added to every continuous level, levels (0.0; ``SelectorConfig.level_bias``).
    shift : {"ellipse", "eq1"}
        The uncertainty shift's form (``SelectorConfig.shift``).
    ellipse_sigma : float
        Size of its ellipse, standard deviations (2.0).
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
    light_dir : (3,) float
        Toward the light, scene frame (normalised).
    ambient : float
        Ambient share of the shading, 0..1.
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
        Off by default: on the scale bench's view (busy 2-core machine,
        medians of 5 interleaved runs) its selection grows 1.5x from 2M to
        134M triangles (3.6 -> 5.4 ms; flat: 1.1 -> 8.0 ms, 7x), but at 134M
        its merged nodes draw 175k triangles against the flat path's 109k
        with whole-number factors (147k with powers of two): a node shows
        all its patches at its worst patch's bounded level, and llvmpipe's
        draw follows the triangles, so the frame is slower.
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
    level_bias: float = 0.0
    shift: str = "ellipse"
    ellipse_sigma: float = 2.0
    cull: bool = True
    smooth_normals: bool = True
    shading: str = "texture"
    anisotropy: float = 1.0
    light_dir: tuple = (0.4, -0.3, 0.85)
    ambient: float = 0.25
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
        if not (isinstance(self.ambient, (int, float)) and 0.0 <= self.ambient <= 1.0):
            raise ValueError(f"TessellationConfig.ambient must be within 0..1, got {self.ambient!r}")
        light = np.asarray(self.light_dir, dtype=float)
        if light.shape != (3,) or not np.all(np.isfinite(light)) or not np.linalg.norm(light) > 0:
            raise ValueError(f"TessellationConfig.light_dir must be a non-zero 3-vector, got {self.light_dir!r}")
        if self.shift not in ("ellipse", "eq1"):
            raise ValueError(f"TessellationConfig.shift must be 'ellipse' or 'eq1', got {self.shift!r}")
        for name in ("level_bias", "ellipse_sigma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)) or (name == "ellipse_sigma" and v < 0):
                raise ValueError(f"TessellationConfig.{name} must be a finite number"
                                 f"{' >= 0' if name == 'ellipse_sigma' else ''}, got {v!r}")

    @property
    def max_level(self) -> int:
        """Finest level: 2^max_level segments per patch side."""
        return max_level_for(self.patch_samples, self.max_tess_level)


# --------------------------------------------------------------------------
# shaders
# --------------------------------------------------------------------------

_VERTEX = """
#version 430
flat out int v_patch;
// A patch is known by its vertex's number (no attributes; gl_VertexID counts from the draw's first):
// llvmpipe's gl_PrimitiveID in the control shader restarts within large draws (measured on 16384 patches).
void main() { v_patch = gl_VertexID; }
"""

_COMMON = """
uniform sampler2D u_height;       // R32F, texel (j, i) = height of sample [i, j], metres
uniform sampler2D u_patch;        // RGBA32F (n, n): z_min, z_max (m), contrast, still f_max (cpd) of patch (pj, pi)
uniform int u_patches;            // patches per side, n
uniform int u_patch_samples;      // P
uniform vec2 u_origin_m;          // scene (x, y) of sample [0, 0]
uniform vec2 u_spacing_m;         // (dx, dy)
uniform mat4 u_mvp;               // T_clip_scene

ivec2 patch_of(int id) { return ivec2(id % u_patches, id / u_patches); }     // (column, row)

#ifdef TREE
// The hierarchy's nodes (patch_tree.NodeSelection.records): (column, row, size, inner), (outer W, S, E, N).
layout(std430, binding = 3) readonly buffer Nodes { ivec4 nodes[]; };
void patch_box(int id, out ivec2 origin, out int size) { ivec4 a = nodes[2 * id]; origin = a.xy; size = a.z; }
#else
void patch_box(int id, out ivec2 origin, out int size) { origin = patch_of(id) * u_patch_samples; size = u_patch_samples; }
#endif

vec3 sample_point(ivec2 s) {      // scene position of sample (column, row)
    return vec3(u_origin_m + vec2(s) * u_spacing_m, texelFetch(u_height, s, 0).r);
}
"""

_CSF = """

uniform mat4 u_model;             // T_world_scene (mm per m)
uniform vec3 u_eye_mm;            // eye, world frame
uniform vec3 u_eye_prev_mm;       // eye at the last frame (speed), world frame
uniform float u_dt_s;             // time since then, s; 0: speed at its floor
uniform mat3 u_axes;              // columns Ξ, Ψ, V (world frame)
uniform mat2 u_cov_inv;           // Σ⁻¹ of the viewing direction's (φ, θ), 1/deg²
uniform int u_shift_form;         // 0 none, 1 ellipse, 2 eq1
uniform float u_ellipse_sigma;
uniform float u_level_bias;
uniform int u_max_level;
uniform int u_full;               // 1: every patch at u_max_level
uniform int u_cull;
uniform vec4 u_region_ndc;        // patches whose box misses this NDC rectangle (x0, y0, x1, y1) are dropped

layout(std430, binding = 0) buffer Levels { float levels[]; };   // 6 per patch: inner, outer W S E N, culled

const float PI = 3.14159265358979;
const float MIN_SPEED = 0.1;      // deg/s
const float ECC_SLOPE = 0.29;     // 1/deg

vec3 world(vec3 p) { return (u_model * vec4(p, 1.0)).xyz; }

float angle_deg(vec3 u, vec3 v) { return degrees(2.0 * asin(min(length(u - v) * 0.5, 1.0))); }

// (φ, θ) of a world point about the viewing direction, deg (perception.view_offsets_deg).
vec2 offsets_deg(vec3 p) {
    vec3 loc = transpose(u_axes) * (p - u_eye_mm);
    return vec2(degrees(atan(loc.y, loc.z)), degrees(atan(loc.x, loc.z)));
}

// perception.uncertainty_shift
vec2 shift(vec2 P) {
    if (u_shift_form == 0) return P;
    float q = dot(P, u_cov_inv * P);
    float f = u_shift_form == 1 ? max(1.0 - u_ellipse_sigma / sqrt(q), 0.0) : 1.0 - exp(-0.5 * q);
    if (q == 0.0) f = 0.0;
    return f * P;
}

float eccentricity_deg(vec2 P) { vec2 t = tan(radians(P)); return degrees(atan(length(t))); }

// csf.max_visible_freq_cpd, kelly_scaled: f_max = 2 t / b / (1 + 0.29 e), t = -W_{-1}(-z),
// z = (b/2) / sqrt(A C); in log form t - ln t = L := 0.5 ln(A C) - ln(b / 2), visible iff L >= 1.
float fmax_cpd(float contrast, float speed, float ecc) {
    float v = max(abs(speed), MIN_SPEED);
    float lg = abs(log(v / 3.0) / log(10.0));
    float A = 4.0 * PI * PI * (6.1 + 7.3 * lg * lg * lg) * v;
    float b = 4.0 * PI * (v + 2.0) / 45.9;
    if (!(contrast > 0.0)) return 0.0;
    float L = 0.5 * log(A * contrast) - log(0.5 * b);
    if (L < 1.0) return 0.0;
    float d = L - 1.0;
    float t = max(1.0 + sqrt(2.0 * d) + 2.0 * d / 3.0, L + log(L));     // start at or right of the root
    for (int k = 0; k < 8; ++k) {
        float g = t - log(t) - L, dg = 1.0 - 1.0 / t;
        if (dg < 1e-6) break;
        t = max(t - g / dg, 1.0);
    }
    return 2.0 * t / b / (1.0 + ECC_SLOPE * ecc);
}

// Continuous level log2(f_max · diameter) of pieces centred at world point c, reaching reach_deg from it.
// fmax_still: the pieces' f_max at eccentricity 0 and the speed floor (precomputed per patch, cpd): the
// same number as fmax_cpd there, without its Newton steps (a still or slow head, the common case).
float level_at(vec3 c, float reach_deg, float diameter_deg, float contrast, float fmax_still) {
    float ecc = max(eccentricity_deg(shift(offsets_deg(c))) - reach_deg, 0.0);
    float speed = MIN_SPEED;
    if (u_dt_s > 0.0)
        speed = max(angle_deg(normalize(c - u_eye_prev_mm), normalize(c - u_eye_mm)) / u_dt_s, MIN_SPEED);
    float f = speed <= MIN_SPEED ? fmax_still / (1.0 + ECC_SLOPE * ecc) : fmax_cpd(contrast, speed, ecc);
    if (f <= 0.0) return -1e30;
    return log2(f * max(diameter_deg, 1e-9)) + u_level_bias;
}

uniform int u_whole_factors;       // 1: patches.tess_factors' "whole" rule; 0: "power_of_two"

float factor(float level) {       // patches.tess_factors
    if (u_full == 1) return exp2(float(u_max_level));
    if (u_whole_factors == 1) {
        float P = float(u_patch_samples);
        float gap = max(floor(P * exp2(-clamp(level, -1.0, float(u_max_level)))), 1.0);
        return min(ceil(P / gap), exp2(float(u_max_level)));
    }
    return exp2(clamp(ceil(clamp(level, -1.0, float(u_max_level) + 1.0)), 0.0, float(u_max_level)));
}

bool outside(vec3 lo, vec3 hi) {   // the box is wholly outside one frustum plane, or misses the region
    vec4 c[8];
    for (int k = 0; k < 8; ++k)
        c[k] = u_mvp * vec4((k & 1) == 0 ? lo.x : hi.x, (k & 2) == 0 ? lo.y : hi.y, (k & 4) == 0 ? lo.z : hi.z, 1.0);
    for (int axis = 0; axis < 3; ++axis) {
        bool below = true, above = true;
        for (int k = 0; k < 8; ++k) {
            below = below && c[k][axis] < -c[k].w;
            above = above && c[k][axis] > c[k].w;
        }
        if (below || above) return true;
    }
    bool in_front = true;
    vec2 mn = vec2(1e30), mx = vec2(-1e30);
    for (int k = 0; k < 8; ++k) {
        in_front = in_front && c[k].w > 0.0;
        vec2 ndc = c[k].xy / c[k].w;
        mn = min(mn, ndc); mx = max(mx, ndc);
    }
    return in_front && (mx.x < u_region_ndc.x || mn.x > u_region_ndc.z || mx.y < u_region_ndc.y || mn.y > u_region_ndc.w);
}

// The levels of patch id (row-major): continuous inner and outer (W, S, E, N) levels; culled by the frustum.
void patch_levels(int id, out float inner, out float outer[4], out bool culled) {
    ivec2 pq = patch_of(id);
    int P = u_patch_samples;
    ivec2 s0 = pq * P;
    vec4 info = texelFetch(u_patch, pq, 0);
    // Corners SW, SE, NE, NW (scene, then world).
    vec3 cs[4] = vec3[4](sample_point(s0), sample_point(s0 + ivec2(P, 0)), sample_point(s0 + ivec2(P, P)),
                         sample_point(s0 + ivec2(0, P)));
    culled = false;
    if (u_cull == 1) {
        vec2 lo = u_origin_m + vec2(s0) * u_spacing_m, hi = u_origin_m + vec2(s0 + P) * u_spacing_m;
        culled = outside(vec3(lo, info.x), vec3(hi, info.y));
    }
    vec3 c[4], d[4];
    for (int k = 0; k < 4; ++k) { c[k] = world(cs[k]); d[k] = normalize(c[k] - u_eye_mm); }
    // Inner: the patch's centre, diameter (largest angle between corners) and reach (to the farthest corner).
    vec3 centre = 0.25 * (c[0] + c[1] + c[2] + c[3]);
    vec3 cd = normalize(centre - u_eye_mm);
    float diameter = max(max(max(angle_deg(d[0], d[1]), angle_deg(d[1], d[2])), max(angle_deg(d[2], d[3]),
                         angle_deg(d[3], d[0]))), max(angle_deg(d[0], d[2]), angle_deg(d[1], d[3])));
    float reach = max(max(angle_deg(cd, d[0]), angle_deg(cd, d[1])), max(angle_deg(cd, d[2]), angle_deg(cd, d[3])));
    inner = level_at(centre, reach, diameter, info.z, info.w);
    // Edges W, S, E, N from their endpoints alone, ordered west to east and south to north.
    ivec2 ends[4] = ivec2[4](ivec2(0, 3), ivec2(0, 1), ivec2(1, 2), ivec2(3, 2));
    ivec2 step[4] = ivec2[4](ivec2(-1, 0), ivec2(0, -1), ivec2(1, 0), ivec2(0, 1));
    for (int e = 0; e < 4; ++e) {
        vec3 a = c[ends[e].x], b = c[ends[e].y];
        vec3 da = d[ends[e].x], db = d[ends[e].y];
        vec3 mid = 0.5 * (a + b);
        vec3 md = normalize(mid - u_eye_mm);
        ivec2 nb = clamp(pq + step[e], ivec2(0), ivec2(u_patches - 1));
        vec4 other = texelFetch(u_patch, nb, 0);      // f_max rises with the contrast: the larger one's
        outer[e] = level_at(mid, max(angle_deg(md, da), angle_deg(md, db)), angle_deg(da, db),
                            max(info.z, other.z), max(info.w, other.w));
    }
}

void write_levels(int id, float inner, float outer[4], bool culled) {
    levels[6 * id] = inner;
    for (int e = 0; e < 4; ++e) levels[6 * id + 1 + e] = outer[e];
    levels[6 * id + 5] = culled ? 1.0 : 0.0;
}
"""

# The levels pass in a vertex shader: one vertex per patch (gl_VertexID), levels into the storage buffer.
# llvmpipe runs vertex shaders 8 lanes wide; a control shader of one output vertex runs one patch at a time.
_LEVELS_VERTEX = """
#version 430
""" + _COMMON + _CSF + """
void main() {
    float inner, outer[4];
    bool culled;
    patch_levels(gl_VertexID, inner, outer, culled);
    write_levels(gl_VertexID, inner, outer, culled);
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);     // outside the clip volume: nothing is drawn
    gl_PointSize = 1.0;
}
"""

# The control shader: the levels computed here (CSF_HERE), or read from the levels pass's buffer;
# LEVELS_OUT: write them and generate nothing (the levels pass of ``csf_stage="control"``).
_CONTROL = """
#version 430
layout(vertices = 1) out;
flat in int v_patch[];
patch out int p_id;               // the patch (gl_PrimitiveID in the evaluation shader is not it on llvmpipe)
""" + _COMMON + _CSF + """
void main() {
    int id = v_patch[0];
    p_id = id;
#ifdef TREE
    ivec4 node = nodes[2 * id], node_outer = nodes[2 * id + 1];
    for (int e = 0; e < 4; ++e) gl_TessLevelOuter[e] = float(node_outer[e]);
    gl_TessLevelInner[0] = gl_TessLevelInner[1] = float(node.w);
    return;
#endif
    float inner, outer[4];
    bool culled;
#if defined(CSF_HERE) || defined(LEVELS_OUT)
    patch_levels(id, inner, outer, culled);
#else
    inner = levels[6 * id];
    for (int e = 0; e < 4; ++e) outer[e] = levels[6 * id + 1 + e];
    culled = levels[6 * id + 5] > 0.5;
#endif
#ifdef LEVELS_OUT
    write_levels(id, inner, outer, culled);
    for (int e = 0; e < 4; ++e) gl_TessLevelOuter[e] = 0.0;      // levels only: nothing is generated
    gl_TessLevelInner[0] = gl_TessLevelInner[1] = 0.0;
    return;
#endif
    for (int e = 0; e < 4; ++e) gl_TessLevelOuter[e] = culled ? 0.0 : factor(outer[e]);
    gl_TessLevelInner[0] = gl_TessLevelInner[1] = factor(inner);
}
"""

# Colour of a height and a normal (gl.py's terrain shader: Lambert + ambient times the height colour), and the
# normal of a sample from its neighbours (np.gradient: central differences, one-sided at the border).
_SHADE = """
uniform vec3 u_light;             // unit vector toward the light, scene frame
uniform float u_ambient;
uniform vec2 u_height_range;      // scene z of the low and high colour

const vec3 LOW = vec3(0.30, 0.42, 0.26);   // as gl.py's terrain shader
const vec3 MID = vec3(0.52, 0.56, 0.40);
const vec3 HIGH = vec3(0.80, 0.80, 0.76);

float h(ivec2 s) { return texelFetch(u_height, s, 0).r; }

vec3 terrain_color(float z, vec3 nrm) {
    float shade = u_ambient + (1.0 - u_ambient) * max(dot(nrm, u_light), 0.0);
    float span = max(u_height_range.y - u_height_range.x, 1e-20);
    float t = clamp((z - u_height_range.x) / span, 0.0, 1.0);
    vec3 base = t < 0.5 ? mix(LOW, MID, 2.0 * t) : mix(MID, HIGH, 2.0 * t - 1.0);
    return base * shade;
}

vec2 sample_gradient(ivec2 s) {
    int n = textureSize(u_height, 0).x;
    ivec2 lo = max(s - 1, ivec2(0)), hi = min(s + 1, ivec2(n - 1));
    return vec2((h(ivec2(hi.x, s.y)) - h(ivec2(lo.x, s.y))) / (float(hi.x - lo.x) * u_spacing_m.x),
                (h(ivec2(s.x, hi.y)) - h(ivec2(s.x, lo.y))) / (float(hi.y - lo.y) * u_spacing_m.y));
}
"""

_EVALUATION = """
#version 430
layout(quads, equal_spacing, ccw) in;
patch in int p_id;
""" + _COMMON + _SHADE + """
uniform int u_smooth_normals;
#ifdef TEXTURE_SHADING
out vec2 v_st;                    // the colour texture's coordinate of the surface point
#else
out vec3 v_color;
#endif
#ifdef SAMPLES_OUT
out vec2 t_sample;                // the vertex's sample (column, row), for the watertightness test
#endif

void main() {
    ivec2 s0;
    int P;                                              // the patch's (or node's) size, samples
    patch_box(p_id, s0, P);
    vec2 uv = gl_TessCoord.xy;
    ivec2 s = s0 + ivec2(round(uv * float(P)));         // on the sample grid: shared vertices are identical
    vec3 pos = sample_point(s);
    gl_Position = u_mvp * vec4(pos, 1.0);
#ifdef SAMPLES_OUT
    t_sample = vec2(s);
#endif
#ifdef TEXTURE_SHADING
    // Texel centres are the samples; linear along a triangle as the sample grid is linear in scene x, y.
    v_st = (vec2(s) + 0.5) / vec2(textureSize(u_height, 0));
    return;
#else
    // Vertex spacing of the level that made this vertex: an edge's factor on an edge (the same in both
    // patches), the inner factor inside; at a corner (shared by four patches' different edges) full detail.
    bool eu = uv.x == 0.0 || uv.x == 1.0, ev = uv.y == 0.0 || uv.y == 1.0;
    float tf = gl_TessLevelInner[0];
    if (eu && !ev) tf = uv.x == 0.0 ? gl_TessLevelOuter[0] : gl_TessLevelOuter[2];
    if (ev && !eu) tf = uv.y == 0.0 ? gl_TessLevelOuter[1] : gl_TessLevelOuter[3];
    if (eu && ev) tf = float(P);
    int n = textureSize(u_height, 0).x;
    vec2 grad;
    float spacing = float(P) / tf;       // samples between vertices, a power of two
    if (u_smooth_normals == 0 || spacing <= 1.0) {
        grad = sample_gradient(s);
    } else {
        float lod = log2(spacing);
        vec2 c = (vec2(s) + 0.5) / float(n), dx = vec2(spacing / float(n), 0.0), dy = vec2(0.0, spacing / float(n));
        grad = vec2(textureLod(u_height, c + dx, lod).r - textureLod(u_height, c - dx, lod).r,
                    textureLod(u_height, c + dy, lod).r - textureLod(u_height, c - dy, lod).r)
               / (2.0 * spacing * u_spacing_m);
    }
    v_color = terrain_color(pos.z, normalize(vec3(-grad, 1.0)));
#endif
}
"""

# Texture shading's bake (over gl.FULLSCREEN_VERTEX_SHADER): one fragment per height sample, its colour from its
# own normal (the finest level's).
_BAKE_FRAGMENT = """
#version 430
uniform sampler2D u_height;
uniform vec2 u_spacing_m;
""" + _SHADE + """
out vec4 f_color;
void main() {
    ivec2 s = ivec2(gl_FragCoord.xy);
    f_color = vec4(terrain_color(h(s), normalize(vec3(-sample_gradient(s), 1.0))), 1.0);
}
"""

_TEXTURE_FRAGMENT = """
#version 430
uniform sampler2D u_color;        // RGBA8 (n, n), mipmapped: the samples' colours
in vec2 v_st;
out vec4 f_color;
void main() { f_color = vec4(texture(u_color, v_st).rgb, 1.0); }
"""

# The watertightness test's pass: every generated triangle's three samples into a storage buffer.
_GEOMETRY_SAMPLES = """
#version 430
layout(triangles) in;
layout(points, max_vertices = 1) out;
in vec2 t_sample[];
out vec3 v_color;                 // (nothing is emitted)
layout(std430, binding = 1) buffer Triangles { uint count; uint capacity; uint pad0; uint pad1; vec2 corners[]; };
void main() {
    uint k = atomicAdd(count, 1u);
    if (k < capacity)
        for (int i = 0; i < 3; ++i) corners[3u * k + uint(i)] = t_sample[i];
}
"""


_NO_FRAGMENT = """
#version 430
out vec4 f_color;
void main() { f_color = vec4(0.0); }
"""


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


def _variant(source: str, *defines: str) -> str:
    head, rest = source.lstrip().split("\n", 1)
    return head + "\n" + "".join(f"#define {d} 1\n" for d in defines) + rest


class TessellationRenderer:
    """Draw a :class:`PatchGrid` with per-patch CSF tessellation, offscreen.

    Parameters
    ----------
    ctx : moderngl.Context
        OpenGL >= 4.0 (``create_context(require=400)``; 4.3 for :meth:`levels`
        and :meth:`triangle_samples`).
    grid : PatchGrid
        The terrain; its ``patch_samples`` must equal ``config.patch_samples``.
    size : (width, height)
        Image size, px.
    config : TessellationConfig
    background : RGB in [0, 1]
        Clear colour (``TerrainRenderer``'s).

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
                 background=(0.62, 0.72, 0.82)):
        if not isinstance(config, TessellationConfig):
            raise TypeError(f"TessellationRenderer: config must be a TessellationConfig, got {type(config).__name__}")
        if ctx.version_code < REQUIRED_GL:
            raise RuntimeError(f"TessellationRenderer: needs OpenGL {REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10}, "
                               f"the context has {ctx.version_code}")
        if grid.patch_samples != config.patch_samples:
            raise ValueError(f"TessellationRenderer: grid has patches of {grid.patch_samples} samples, "
                             f"config.patch_samples is {config.patch_samples}")
        w, h = (int(v) for v in size)
        if w <= 0 or h <= 0:
            raise ValueError(f"TessellationRenderer: size must be positive (width, height), got {size!r}")
        self.ctx, self.grid, self.config, self.size = ctx, grid, config, (w, h)
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
        fmax_still = pc.max_visible_freq_cpd(grid.contrast.astype(np.float64), pc.MIN_SPEED_DEG_S, 0.0,
                                             model="kelly_scaled")
        info = np.stack([grid.z_min_m, grid.z_max_m, grid.contrast, fmax_still], axis=-1)
        self._patch = ctx.texture((grid.n_patches, grid.n_patches), 4, info.astype(np.float32).tobytes(), dtype="f4")
        self._patch.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._programs = {}
        self._vaos = {}
        self._fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)],
                                    depth_attachment=ctx.depth_renderbuffer((w, h)))
        self._rgba = np.empty((h, w, 4), np.uint8)
        self._query = ctx.query(primitives=True)
        self._prev = None        # (eye_mm, t) of the last frame, for the angular speed
        self._levels_buffer = None
        self.last_draw_calls = 0
        # The hierarchy: the tree's bounds (built once), the node records' buffer, the last selection.
        self._tree = (PatchTree(grid, config.split_factor, config.max_tess_level, factors=config.factors) if config.hierarchy else None)
        self._node_buffer = None
        self._tree_frame = False
        self.last_selection = None
        self.last_nodes = 0

    def _bake_colors(self):
        """The colour texture of ``texture`` shading: RGBA8 (n, n), every sample's colour, mipmapped.

        Drawn on the GPU (one fragment per sample) so no (n, n, 3) normal
        array is made on the CPU (8193²: 0.8 GB of float32).
        """
        ctx, cfg = self.ctx, self.config
        n = self.grid.heights_m.shape[0]
        texture = ctx.texture((n, n), 4, dtype="f1")
        fbo = ctx.framebuffer(color_attachments=[texture])
        prog = ctx.program(vertex_shader=FULLSCREEN_VERTEX_SHADER, fragment_shader=_BAKE_FRAGMENT)
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
        cfg = self.config
        light = np.asarray(cfg.light_dir, np.float64)
        for name, value in (("u_light", tuple(light / np.linalg.norm(light))), ("u_ambient", float(cfg.ambient)),
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
                prog = self.ctx.program(vertex_shader=_LEVELS_VERTEX, fragment_shader=_NO_FRAGMENT)
            else:
                control = _variant(_CONTROL, "LEVELS_OUT") if kind == "levels" else _variant(_CONTROL, *here)
                textured = kind == "draw" and self.config.shading == "texture"
                evaluation = _variant(_EVALUATION, *(("SAMPLES_OUT",) if kind == "samples" else
                                                     ("TEXTURE_SHADING",) if textured else ()),
                                      *(("TREE",) if tree else ()))
                prog = self.ctx.program(vertex_shader=_VERTEX, tess_control_shader=control,
                                        tess_evaluation_shader=evaluation,
                                        geometry_shader=_GEOMETRY_SAMPLES if kind == "samples" else None,
                                        fragment_shader=_TEXTURE_FRAGMENT if textured else _FRAGMENT_SHADER)
            kind = kind + ("_tree" if tree else "")
            self._programs[kind] = prog
            self._vaos[kind] = self.ctx.vertex_array(prog, [])
        return self._programs[kind]

    def _last_eye(self, t):
        """(the last frame's eye (3,) world mm, or None; the time since, s, or 0) for the angular speed at ``t``."""
        if t is not None and self._prev is not None and self._prev[1] is not None and t > self._prev[1]:
            return self._prev[0], float(t - self._prev[1])
        return None, 0.0

    def _set_uniforms(self, prog, view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc):
        """Every uniform of the frame (the CPU's whole share of the selection)."""
        g, cfg = self.grid, self.config
        model = np.asarray(model, np.float64)
        mvp = np.asarray(proj, np.float64) @ np.asarray(view, np.float64) @ model
        values = {
            "u_height": 0, "u_patch": 1, "u_patches": g.n_patches, "u_patch_samples": g.patch_samples,
            "u_origin_m": g.origin_m, "u_spacing_m": (g.dx_m, g.dy_m),
            "u_model": model.T.astype("f4").tobytes(), "u_mvp": mvp.T.astype("f4").tobytes(),
            "u_eye_mm": tuple(np.asarray(eye_mm, float)), "u_axes": np.asarray(axes, "f4").tobytes(),
            "u_level_bias": float(cfg.level_bias), "u_max_level": cfg.max_level, "u_full": int(mode == "full"),
            "u_whole_factors": int(cfg.factors == "whole"),
            "u_cull": int(cfg.cull), "u_ellipse_sigma": float(cfg.ellipse_sigma),
            "u_region_ndc": tuple(region_ndc) if region_ndc is not None else (-2.0, -2.0, 2.0, 2.0),
            "u_smooth_normals": int(cfg.smooth_normals), "u_color": 2,
        }
        self._shade_uniforms(prog)
        # Σ⁻¹ for the shift (None or all-zero: no shift). u_axes: the rows Ξ, Ψ, V written row-major are the
        # columns of the GLSL mat3, so transpose(u_axes) * d = (Ξ·d, Ψ·d, V·d).
        form, cov_inv = 0, np.eye(2)
        if cov_deg2 is not None and np.any(np.asarray(cov_deg2) != 0):
            form, cov_inv = _SHIFT_FORMS[cfg.shift], np.linalg.inv(np.asarray(cov_deg2, np.float64))
        values["u_shift_form"], values["u_cov_inv"] = form, cov_inv.astype("f4").tobytes()
        prev, dt = self._last_eye(t)
        values["u_eye_prev_mm"] = tuple(np.asarray(eye_mm, float) if prev is None else prev)
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

    def render(self, view, proj, model, eye_mm, axes, cov_deg2=None, *, mode: str = "csf", t: float | None = None,
               region_ndc=None, supersample: int = 1) -> np.ndarray:
        """Draw one frame and read it back: (H, W, 3) uint8 RGB, row 0 at the top.

        Parameters
        ----------
        view, proj : (4, 4)
            ``T_eye_world`` and ``T_clip_eye`` (:func:`off_axis_projection`).
        model : (4, 4)
            ``T_world_scene``.
        eye_mm : (3,)
            Eye, world frame, mm.
        axes : (3, 3)
            Rows Ξ, Ψ, V of the head frame looking at the POI (:meth:`LevelSelector.head_axes`).
        cov_deg2 : (2, 2) or None
            Covariance of the viewing direction, deg² (the uncertainty shift).
        mode : {"csf", "full"}
            ``full``: every patch at the finest level (the reference).
        t : float or None
            Time, s: with the last frame's, the patches' angular speed; None: the speed floor.
        region_ndc : (4,) or None
            (x0, y0, x1, y1) in NDC: only patches whose box reaches it are drawn (a reference of a region).
        supersample : int
            Draw at this many times the size per axis and average down (``cv2.INTER_AREA``): a reference
            whose triangles are smaller than a pixel, without aliasing. 1: the image's own size.
        """
        if mode not in TESS_MODES:
            raise ValueError(f"TessellationRenderer.render: mode must be one of {TESS_MODES}, got {mode!r}")
        ctx = self.ctx
        t0 = time.perf_counter()
        ranges = self._draw_ranges(view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc)
        kind = "draw_tree" if self._tree_frame else "draw"
        prog = self._program(kind)
        self._set_uniforms(prog, view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc)
        self._prev = (np.asarray(eye_mm, float).copy(), t)
        self.last_setup_ms = (time.perf_counter() - t0) * 1e3
        self._bind()     # with the levels pass's levels (flat) or the node records (hierarchy)
        ctx.finish()
        t1 = time.perf_counter()
        k = int(supersample)
        if k < 1:
            raise ValueError(f"TessellationRenderer.render: supersample must be >= 1, got {supersample!r}")
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

    def _levels_pass(self, view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc) -> np.ndarray:
        """(n, n, 6) float32: the control shader's inner, outer W S E N levels and culled flag of every patch."""
        n = self.grid.n_patches
        prog = self._program("levels")
        self._set_uniforms(prog, view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc)
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

    def _draw_ranges(self, view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc) -> list:
        """Draw calls ``(first patch, patches)`` that each generate fewer than 65536 vertices.

        llvmpipe numbers a draw call's tessellated vertices with 16 bits: past
        65536 its triangles join vertices of different patches (measured:
        patches of 33² vertices, 61 per call). So the levels are computed
        first (one control-shader pass, read back: 24 bytes per patch), and
        the patches split into calls of at most :data:`VERTICES_PER_DRAW`
        vertices; culled patches cost nothing.
        """
        top = self.config.max_level
        most = (2 ** top + 1) ** 2 + 4 * (2 ** top + 1)
        self._tree_frame = self._tree is not None and mode == "csf"
        if self._tree_frame:
            sel = self._select_nodes(view, proj, model, eye_mm, axes, cov_deg2, t, region_ndc)
            lim = self.config.max_tess_level
            return _split_draws(sel.vertex_bound(), (lim + 1) ** 2 + 4 * (lim + 1))
        lv = self._levels_pass(view, proj, model, eye_mm, axes, cov_deg2, mode, t, region_ndc).reshape(-1, 6)
        self.last_nodes = int(np.count_nonzero(lv[:, 5] < 0.5))
        if mode == "full":
            inner = np.full(len(lv), 2 ** top)
            outer = np.full((len(lv), 4), 2 ** top)
        else:
            rule, p = self.config.factors, self.grid.patch_samples
            inner, outer = tess_factors(lv[:, 0], top, p, rule), tess_factors(lv[:, 1:5], top, p, rule)
        counts = np.where(lv[:, 5] > 0.5, 0, (inner + 1) ** 2 + (outer + 1).sum(axis=1))   # bound on vertices
        return _split_draws(counts, most)

    def _select_nodes(self, view, proj, model, eye_mm, axes, cov_deg2, t, region_ndc):
        """The hierarchy's selection of this frame (:meth:`PatchTree.select`), its records uploaded."""
        cfg = self.config
        model = np.asarray(model, np.float64)
        mvp = np.asarray(proj, np.float64) @ np.asarray(view, np.float64) @ model
        prev, dt = self._last_eye(t)
        sel = self._tree.select(model, eye_mm, axes, cov_deg2, mvp=mvp, region_ndc=region_ndc, cull=cfg.cull,
                                shift=cfg.shift, ellipse_sigma=cfg.ellipse_sigma, level_bias=cfg.level_bias,
                                eye_prev_mm=prev, dt_s=dt)
        data = sel.records().tobytes() or bytes(32)
        if self._node_buffer is None or self._node_buffer.size < len(data):
            if self._node_buffer is not None:
                self._node_buffer.release()
            self._node_buffer = self.ctx.buffer(reserve=max(len(data), 32 * 1024))
        self._node_buffer.write(data)
        self.last_selection, self.last_nodes = sel, len(sel)
        return sel

    def levels(self, view, proj, model, eye_mm, axes, cov_deg2=None, *, t: float | None = None):
        """The control shader's continuous levels (nothing is drawn).

        Returns
        -------
        inner : (n, n) float32
            Each patch's level (row pi, column pj; -1e30 where nothing is visible).
        outer : (n, n, 4) float32
            Its edges' levels, W, S, E, N.
        culled : (n, n) bool
            Patches dropped by the frustum test.
        """
        out = self._levels_pass(view, proj, model, eye_mm, axes, cov_deg2, "csf", t, None).copy()
        return out[..., 0], out[..., 1:5], out[..., 5] > 0.5

    def triangle_samples(self, view, proj, model, eye_mm, axes, cov_deg2=None, *, mode: str = "csf",
                         capacity: int = 1 << 20) -> np.ndarray:
        """Every generated triangle as its three vertices' samples (T, 3, 2) int64 (column, row); GL 4.3."""
        ranges = self._draw_ranges(view, proj, model, eye_mm, axes, cov_deg2, mode, None, None)
        kind = "samples_tree" if self._tree_frame else "samples"
        prog = self._program(kind)
        self._set_uniforms(prog, view, proj, model, eye_mm, axes, cov_deg2, mode, None, None)
        buf = self.ctx.buffer(np.array([0, capacity, 0, 0], np.uint32).tobytes() + bytes(24 * capacity))
        try:
            buf.bind_to_storage_buffer(1)
            self._bind()
            self._fbo.use()                  # (not under RASTERIZER_DISCARD: see _levels_pass)
            for first, count in ranges:
                self._vaos[kind].render(moderngl.PATCHES, vertices=count, first=first)
            self.ctx.memory_barrier()
            raw = buf.read()
        finally:
            buf.release()
        count = int(np.frombuffer(raw[:4], np.uint32)[0])
        if count > capacity:
            raise ValueError(f"triangle_samples: {count} triangles, more than capacity={capacity}")
        return np.frombuffer(raw[16:16 + 24 * count], np.float32).reshape(count, 3, 2).round().astype(np.int64)

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
    """(4, 4) scene (m) → world (mm) of a grid placed as the built-in scene (:class:`TerrainScene`).

    The grid's centre (at height ``centre_z_m``, default the median height)
    250 mm behind the screen, 0.02 mm per m, pitched 55°.
    """
    from .projection import scene_to_world
    from .still import DEPTH_MM, PITCH_DEG, SCALE_MM_PER_M

    x0, x1, y0, y1 = grid.extent
    cz = float(np.median(grid.heights_m[::8, ::8])) if centre_z_m is None else float(centre_z_m)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, cz])
    return np.asarray(scene_to_world(SCALE_MM_PER_M, centre, screen, depth_mm=DEPTH_MM, pitch_deg=PITCH_DEG).matrix,
                      dtype=np.float64)


def head_axes(screen, eye_mm, poi_px) -> np.ndarray:
    """(3, 3) rows Ξ, Ψ, V of the head frame looking from the eye at the POI: :meth:`LevelSelector.head_axes`."""
    eye = np.asarray(eye_mm, np.float64)
    v = screen.pixel_to_world(np.asarray(poi_px, dtype=np.float64)) - eye
    v /= np.linalg.norm(v)
    right = np.asarray(screen.top_right, float) - np.asarray(screen.top_left, float)
    xi = right - v * (right @ v)
    xi /= np.linalg.norm(xi)
    return np.stack([xi, np.cross(v, xi), v])


def render_frame(renderer: TessellationRenderer, screen, model, head_mm=None, poi_px=None, cov_deg2=None, *,
                 mode: str = "csf", t: float | None = None, region_ndc=None, supersample: int = 1):
    """One frame of a :class:`TessellationRenderer` from a head and a POI: (image (H, W, 3) uint8, stats dict).

    ``head_mm`` (3,) world mm (default :func:`default_head`), ``poi_px`` (2,)
    screen px (default the centre), ``cov_deg2`` (2, 2) deg². The stats:
    ``triangles`` (generated), ``select_ms`` (the CPU's share: uniforms, the
    levels pass and its read-back), ``render_ms``, ``draw_calls``.
    """
    from .projection import off_axis_projection
    from .still import default_head

    head = default_head(screen) if head_mm is None else np.asarray(head_mm, np.float64)
    poi = np.array(screen.size_px, np.float64) / 2 if poi_px is None else np.asarray(poi_px, np.float64)
    view, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    image = renderer.render(view, proj, model, head, head_axes(screen, head, poi), cov_deg2, mode=mode, t=t,
                            region_ndc=region_ndc, supersample=supersample)
    return image, {"mode": mode, "triangles": renderer.last_triangles, "select_ms": renderer.last_setup_ms,
                   "render_ms": renderer.last_render_ms, "draw_calls": renderer.last_draw_calls,
                   "patches": renderer.last_nodes}
