"""The GLSL of the tessellation back end (:mod:`headplod.render.tessellate`), assembled from Python's constants.

The levels' rule is :mod:`headplod.plod.criteria`'s ``csf`` rule with the
``kelly_scaled`` CSF, in float32. Its constants are not retyped here: the
``#define`` block of :data:`RULE` is generated when this module is imported
from :mod:`headplod.plod.csf` (Kelly's coefficients, the eccentricity slope,
the speed floor) and :mod:`headplod.plod.criteria` (the floors of the
diameter and of f_max), so the shader and the numpy reference cannot drift
apart. ``tests/test_tessellate.py`` evaluates :data:`RULE` on a grid of
inputs (contrast x eccentricity x speed x uncertainty x size) against
:func:`headplod.plod.criteria.csf_level`.

Pieces, each a string of GLSL (``#version`` first, then the chunks):

- :data:`VERTEX`: one vertex per patch, known by ``gl_VertexID``.
- :data:`COMMON`: the height texture, the patch table, the grid's frame.
- :data:`RULE`: the level rule alone (uncertainty shift, eccentricity,
  f_max by Newton's method on Lambert's W in log form, the level): no
  geometry, so it can be tested on any inputs.
- :data:`CSF`: the patches' geometry (their five pieces, as
  :func:`headplod.plod.criteria.patch_pieces`), the per-point speed, the
  factors (:func:`headplod.plod.patches.tess_factors`) and the frustum test
  ``outside()`` (:func:`headplod.plod.cull.box_outside_clip` in float32).
- :data:`LEVELS_VERTEX`, :data:`CONTROL`, :data:`EVALUATION`: the levels
  pass and the draw's stages; :data:`SHADE`, :data:`BAKE_FRAGMENT`,
  :data:`TEXTURE_FRAGMENT`: the shading (the light of
  :mod:`headplod.plod.shading`, set as uniforms); :data:`GEOMETRY_SAMPLES`,
  :data:`NO_FRAGMENT`: the test and levels passes.

:func:`variant` adds ``#define`` switches after the ``#version`` line.
"""
from __future__ import annotations

import math

from ..plod import criteria
from ..plod.shading import GLSL_HEIGHT_COLOURS
from ..plod.csf import (ECC_SLOPE, KELLY_K0, KELLY_K1, KELLY_PEAK_CONSTANT, KELLY_SPEED_OFFSET_DEG_S,
                        KELLY_SPEED_REF_DEG_S, MIN_SPEED_DEG_S)

__all__ = ["SHIFT_FORMS", "rule_defines", "VERTEX", "COMMON", "RULE", "CSF", "LEVELS_VERTEX", "CONTROL", "SHADE",
           "EVALUATION", "BAKE_FRAGMENT", "TEXTURE_FRAGMENT", "GEOMETRY_SAMPLES", "NO_FRAGMENT", "variant"]

#: ``u_shift_form`` of each uncertainty shift (:data:`headplod.plod.perception.SHIFT_FORMS`; None: no shift).
SHIFT_FORMS = {None: 0, "ellipse": 1, "eq1": 2}


def _glsl_float(value: float) -> str:
    """A GLSL float literal with Python's shortest round-trip digits (``repr``)."""
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"tess_shaders: a constant must be finite, got {value!r}")
    text = repr(v)
    return text if ("." in text or "e" in text) else text + ".0"


def rule_defines() -> str:
    """The ``#define`` block of the level rule's constants, from :mod:`headplod.plod.csf` and ``plod.criteria``."""
    values = {
        "PI": math.pi,
        "MIN_SPEED": MIN_SPEED_DEG_S,                  # deg/s: the CSF's speed floor
        "ECC_SLOPE": ECC_SLOPE,                        # 1/deg: f_max / (1 + ECC_SLOPE e)
        "KELLY_K0": KELLY_K0,
        "KELLY_K1": KELLY_K1,
        "KELLY_SPEED_REF": KELLY_SPEED_REF_DEG_S,      # deg/s
        "KELLY_SPEED_OFFSET": KELLY_SPEED_OFFSET_DEG_S,
        "KELLY_PEAK": KELLY_PEAK_CONSTANT,
        "FMAX_FLOOR": criteria.FMAX_FLOOR_CPD,         # cpd
        "DIAMETER_FLOOR": criteria.DIAMETER_FLOOR_DEG,  # deg
    }
    lines = [f"#define {name} {_glsl_float(v)}" for name, v in values.items()]
    lines += [f"#define SHIFT_{(form or 'none').upper()} {code}" for form, code in SHIFT_FORMS.items()]
    return "\n".join(lines) + "\n"


VERTEX = """
#version 430
flat out int v_patch;
// A patch is known by its vertex's number (no attributes; gl_VertexID counts from the draw's first):
// llvmpipe's gl_PrimitiveID in the control shader restarts within large draws.
void main() { v_patch = gl_VertexID; }
"""

COMMON = """
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

RULE = "\n" + rule_defines() + """
uniform mat2 u_cov_inv;           // Σ⁻¹ of the viewing direction's (φ, θ), 1/deg²
uniform int u_shift_form;         // SHIFT_NONE, SHIFT_ELLIPSE, SHIFT_EQ1
uniform float u_ellipse_sigma;
uniform float u_level_bias;

// perception.uncertainty_shift
vec2 shift(vec2 P) {
    if (u_shift_form == SHIFT_NONE) return P;
    float q = dot(P, u_cov_inv * P);
    float f = u_shift_form == SHIFT_ELLIPSE ? max(1.0 - u_ellipse_sigma / sqrt(q), 0.0) : 1.0 - exp(-0.5 * q);
    if (q == 0.0) f = 0.0;
    return f * P;
}

// perception.eccentricity_deg
float eccentricity_deg(vec2 P) { vec2 t = tan(radians(P)); return degrees(atan(length(t))); }

// criteria.piece_eccentricity_deg: the eccentricity of the shifted offsets, less the reach, floored at 0.
float piece_eccentricity_deg(vec2 shifted, float reach_deg) { return max(eccentricity_deg(shifted) - reach_deg, 0.0); }

// csf.max_visible_freq_cpd, kelly_scaled: f_max = 2 t / b / (1 + ECC_SLOPE e), t = -W_{-1}(-z),
// z = (b/2) / sqrt(A C); in log form t - ln t = L := 0.5 ln(A C) - ln(b / 2), visible iff L >= 1.
float fmax_cpd(float contrast, float speed, float ecc) {
    float v = max(abs(speed), MIN_SPEED);
    float lg = abs(log(v / KELLY_SPEED_REF) / log(10.0));
    float A = 4.0 * PI * PI * (KELLY_K0 + KELLY_K1 * lg * lg * lg) * v;
    float b = 4.0 * PI * (v + KELLY_SPEED_OFFSET) / KELLY_PEAK;
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

// criteria.fmax_cpd: at the speed floor from the pieces' foveal f_max there (fmax_still, precomputed in
// float64, cpd) without the Newton steps (a still or slow head, the common case); else solved.
float piece_fmax_cpd(float contrast, float speed, float ecc, float fmax_still) {
    return speed <= MIN_SPEED ? fmax_still / (1.0 + ECC_SLOPE * ecc) : fmax_cpd(contrast, speed, ecc);
}

// criteria.frequency_level: log2(f_max / f) with f = 1 / diameter, plus the bias.
float frequency_level(float fmax, float diameter_deg) {
    return log2(max(fmax, FMAX_FLOOR) * max(diameter_deg, DIAMETER_FLOOR)) + u_level_bias;
}
"""

CSF = """
uniform mat4 u_model;             // T_world_scene (mm per m)
uniform vec3 u_eye_mm;            // eye, world frame
uniform vec3 u_eye_prev_mm;       // eye at the last frame (speed), world frame
uniform float u_dt_s;             // time since then, s; 0: speed at its floor
uniform mat3 u_axes;              // columns Ξ, Ψ, V (world frame)
uniform int u_max_level;
uniform int u_full;               // 1: every patch at u_max_level
uniform int u_cull;
uniform vec4 u_region_ndc;        // patches whose box misses this NDC rectangle (x0, y0, x1, y1) are dropped

layout(std430, binding = 0) buffer Levels { float levels[]; };   // 6 per patch: inner, outer W S E N, culled

vec3 world(vec3 p) { return (u_model * vec4(p, 1.0)).xyz; }

// criteria.angle_between_deg
float angle_deg(vec3 u, vec3 v) { return degrees(2.0 * asin(min(length(u - v) * 0.5, 1.0))); }

// (φ, θ) of a world point about the viewing direction, deg (perception.view_offsets_deg).
vec2 offsets_deg(vec3 p) {
    vec3 loc = transpose(u_axes) * (p - u_eye_mm);
    return vec2(degrees(atan(loc.y, loc.z)), degrees(atan(loc.x, loc.z)));
}

// criteria.patch_piece_levels of one piece centred at world point c, reaching reach_deg from it.
float level_at(vec3 c, float reach_deg, float diameter_deg, float contrast, float fmax_still) {
    float ecc = piece_eccentricity_deg(shift(offsets_deg(c)), reach_deg);
    float speed = MIN_SPEED;             // criteria.point_speed_deg_s
    if (u_dt_s > 0.0)
        speed = max(angle_deg(normalize(c - u_eye_mm), normalize(c - u_eye_prev_mm)) / u_dt_s, MIN_SPEED);
    return frequency_level(piece_fmax_cpd(contrast, speed, ecc, fmax_still), diameter_deg);
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

// cull.box_outside_clip: the box is wholly outside one clip plane, or (all in front) misses the region.
bool outside(vec3 lo, vec3 hi) {
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
// Its five pieces as criteria.patch_pieces.
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
    // Edges W, S, E, N from their endpoints alone, ordered west to east and south to north (criteria.EDGE_ENDS).
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
# llvmpipe runs vertex shaders several lanes wide; a control shader of one output vertex runs one patch at a time.
LEVELS_VERTEX = """
#version 430
""" + COMMON + RULE + CSF + """
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
CONTROL = """
#version 430
layout(vertices = 1) out;
flat in int v_patch[];
patch out int p_id;               // the patch (gl_PrimitiveID in the evaluation shader is not it on llvmpipe)
""" + COMMON + RULE + CSF + """
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

# Colour of a height and a normal (gl.py's terrain shader: Lambert + ambient times the height colour, the light of
# plod.shading), and the normal of a sample from its neighbours (np.gradient: central differences, one-sided at
# the border).
SHADE = """
uniform vec3 u_light;             // unit vector toward the light, scene frame (plod.shading.light_unit)
uniform float u_ambient;          // plod.shading.AMBIENT
uniform vec2 u_height_range;      // scene z of the low and high colour

%HEIGHT_COLOURS%

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
SHADE = SHADE.replace("%HEIGHT_COLOURS%", GLSL_HEIGHT_COLOURS)       # plod.shading's colours, as gl.py's

EVALUATION = """
#version 430
layout(quads, equal_spacing, ccw) in;
patch in int p_id;
""" + COMMON + SHADE + """
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
BAKE_FRAGMENT = """
#version 430
uniform sampler2D u_height;
uniform vec2 u_spacing_m;
""" + SHADE + """
out vec4 f_color;
void main() {
    ivec2 s = ivec2(gl_FragCoord.xy);
    f_color = vec4(terrain_color(h(s), normalize(vec3(-sample_gradient(s), 1.0))), 1.0);
}
"""

TEXTURE_FRAGMENT = """
#version 430
uniform sampler2D u_color;        // RGBA8 (n, n), mipmapped: the samples' colours
in vec2 v_st;
out vec4 f_color;
void main() { f_color = vec4(texture(u_color, v_st).rgb, 1.0); }
"""

# The watertightness test's pass: every generated triangle's three samples into a storage buffer.
GEOMETRY_SAMPLES = """
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

NO_FRAGMENT = """
#version 430
out vec4 f_color;
void main() { f_color = vec4(0.0); }
"""


def variant(source: str, *defines: str) -> str:
    """``source`` with ``#define NAME 1`` for each of ``defines`` right after its ``#version`` line."""
    head, rest = source.lstrip().split("\n", 1)
    return head + "\n" + "".join(f"#define {d} 1\n" for d in defines) + rest
