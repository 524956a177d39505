"""Foveated resolution layers: the frame drawn as nested layers around the POI at falling resolution.

Guenter et al. (2012) drew three nested layers at falling resolution and
blended them; here each layer's pixel density comes from the same contrast
sensitivity as the mesh's levels (:mod:`headplod.plod.csf`). A layer that
starts at eccentricity e needs twice the highest visible frequency there
(Nyquist), ``2 f_max(e)`` pixels per degree; the display gives ``ppd`` at
full resolution, so the layer is drawn at the linear scale
``min(1, 2 f_max(e) / ppd)``. Scales are powers of two (1, 1/2, 1/4, ...):
layer k (scale 2^-k) covers the eccentricities from where 2^-k suffices to
where 2^-(k+1) does. Every border is pushed out by the POI's
uncertainty (``n_sigma`` σ of its covariance's larger axis), as the mesh's
eccentricity is, so a noisy tracker does not leave the viewer looking at a
coarse layer.

Units: eccentricity deg, pixel density px/deg of the output image at the
screen centre, image pixels with (0, 0) at the top-left. The layers are
drawn by :class:`headplod.render.gl.TerrainRenderer` into smaller
framebuffers (the same view), each clipped (scissor) to the disc it covers,
and composited on the GPU with a smooth blend ``blend_deg`` wide at each
border; the fovea stays at full resolution.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..plod.csf import CSF_MODELS, max_visible_freq_cpd
from .context import moderngl
from .gl import read_rgb

__all__ = ["FoveationConfig", "Layer", "layer_plan", "FoveatedRenderer"]


@dataclass(frozen=True)
class FoveationConfig:
    """Settings of the foveated layers.

    Attributes
    ----------
    max_layers : int
        Most layers, the fovea included (scales 1, 1/2, ... 2^-(max_layers-1)).
    blend_deg : float
        Width of the blend across a layer's border, deg.
    n_sigma : float
        The borders move out by this many σ of the POI's uncertainty (the
        larger axis of its covariance), as the mesh's eccentricity does.
    contrast : float
        Michelson contrast the densities are chosen for (1: the most
        demanding detail).
    speed_deg_s : float
        Retinal speed the densities are chosen for, deg/s (0.15: a fixating
        eye's drift, the most demanding).
    csf_model : str
        One of :data:`headplod.plod.csf.CSF_MODELS`.
    """

    max_layers: int = 3
    blend_deg: float = 1.0
    n_sigma: float = 2.0
    contrast: float = 1.0
    speed_deg_s: float = 0.15
    csf_model: str = "kelly_scaled"

    def __post_init__(self):
        if not (isinstance(self.max_layers, int) and 1 <= self.max_layers <= 6):
            raise ValueError(f"FoveationConfig.max_layers must be an integer 1..6, got {self.max_layers!r}")
        for name in ("blend_deg", "n_sigma", "contrast", "speed_deg_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"FoveationConfig.{name} must be a finite number >= 0, got {value!r}")
        if self.csf_model not in CSF_MODELS:
            raise ValueError(f"FoveationConfig.csf_model must be one of {CSF_MODELS}, got {self.csf_model!r}")


@dataclass(frozen=True)
class Layer:
    """One layer: drawn at ``scale`` (linear, of the output) from ``inner_deg`` to ``outer_deg`` (deg)."""

    scale: float
    inner_deg: float
    outer_deg: float


def _ecc_for_frequency(freq_cpd: float, config: FoveationConfig) -> float:
    """The eccentricity (deg) beyond which f_max falls below ``freq_cpd`` (0 if it is below already)."""
    def fmax(e):
        return float(max_visible_freq_cpd(config.contrast, config.speed_deg_s, e, model=config.csf_model))

    if fmax(0.0) <= freq_cpd:
        return 0.0
    lo, hi = 0.0, 1.0
    while fmax(hi) > freq_cpd:
        lo, hi = hi, 2.0 * hi
        if hi > 1e4:
            return math.inf
    for _ in range(50):                      # f_max falls with e: bisection
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if fmax(mid) > freq_cpd else (lo, mid)
    return 0.5 * (lo + hi)


def layer_plan(px_per_deg: float, cov_deg2=None, config: FoveationConfig = FoveationConfig()) -> list[Layer]:
    """The layers for a display of ``px_per_deg`` (px/deg at full resolution) and a POI covariance (2, 2) deg².

    Layer k (scale 2^-k) starts where 2 f_max(e) = 2^-k ppd, i.e. where the
    finer layer is no longer needed, plus the uncertainty's shift. The
    last layer reaches to infinity; a layer no frequency needs is empty
    (``inner_deg == outer_deg``) and costs nothing but its disc.
    """
    if not (math.isfinite(px_per_deg) and px_per_deg > 0):
        raise ValueError(f"layer_plan: px_per_deg must be > 0, got {px_per_deg!r}")
    shift = 0.0
    if cov_deg2 is not None:
        cov = np.asarray(cov_deg2, dtype=np.float64)
        if cov.shape != (2, 2) or not np.isfinite(cov).all():
            raise ValueError(f"layer_plan: cov_deg2 must be a finite (2, 2) matrix, got shape {cov.shape}")
        shift = config.n_sigma * math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (cov + cov.T)).max()), 0.0))
    borders = [0.0]
    for k in range(1, config.max_layers):
        # Beyond this eccentricity the scale 2^-k carries every visible frequency.
        borders.append(_ecc_for_frequency(0.5 * px_per_deg * 2.0 ** -k, config) + shift)
    borders.append(math.inf)
    for k in range(1, len(borders)):
        borders[k] = max(borders[k], borders[k - 1])
    return [Layer(2.0 ** -k, borders[k], borders[k + 1]) for k in range(config.max_layers)]


_COMPOSITE_VS = """
#version 330
out vec2 v_uv;
void main() {
    // One triangle covering the screen.
    vec2 p = vec2((gl_VertexID == 1) ? 3.0 : -1.0, (gl_VertexID == 2) ? 3.0 : -1.0);
    v_uv = 0.5 * (p + 1.0);
    gl_Position = vec4(p, 0.0, 1.0);
}
"""

def _composite_shader(n: int) -> str:
    """The compositing fragment shader for ``n`` layers, unrolled (GLSL 330 indexes samplers by constants only)."""
    lines = ["#version 330", "uniform float u_outer_px[%d];" % max(n - 1, 1), "uniform float u_blend_px;",
             "uniform vec2 u_poi_px;", "uniform vec2 u_size;", "in vec2 v_uv;", "out vec4 f_color;"]
    lines += ["uniform sampler2D u_layer%d;" % k for k in range(n)]
    lines += ["void main() {",
              "    float r = distance(v_uv * u_size, u_poi_px);",
              # From the coarsest layer inwards: a finer layer covers a coarser one inside its
              # border, fading out over u_blend_px across it.
              "    vec3 c = texture(u_layer%d, v_uv).rgb;" % (n - 1)]
    for k in range(n - 2, -1, -1):
        lines.append("    c = mix(c, texture(u_layer%d, v_uv).rgb, "
                     "1.0 - smoothstep(u_outer_px[%d] - u_blend_px, u_outer_px[%d], r));" % (k, k, k))
    lines += ["    f_color = vec4(c, 1.0);", "}"]
    return "\n".join(lines) + "\n"


class FoveatedRenderer:
    """Draws a :class:`~headplod.render.gl.TerrainRenderer`'s mesh as foveated layers and composites them.

    Parameters
    ----------
    renderer : TerrainRenderer
        Its context, output size and uploaded mesh are used.
    config : FoveationConfig
    """

    def __init__(self, renderer, config: FoveationConfig = FoveationConfig()):
        self.renderer = renderer
        self.config = config
        ctx = renderer.ctx
        w, h = renderer.size
        self._targets = []
        for k in range(config.max_layers):
            lw, lh = max(1, int(round(w * 2.0 ** -k))), max(1, int(round(h * 2.0 ** -k)))
            color = ctx.texture((lw, lh), 4)
            color.filter = (moderngl.LINEAR, moderngl.LINEAR)
            color.repeat_x = color.repeat_y = False
            self._targets.append((color, ctx.framebuffer(color_attachments=[color],
                                                         depth_attachment=ctx.depth_renderbuffer((lw, lh)))))
        n = config.max_layers
        self._program = ctx.program(vertex_shader=_COMPOSITE_VS, fragment_shader=_composite_shader(n))
        for k in range(n):
            self._program["u_layer%d" % k].value = k
        self._vao = ctx.vertex_array(self._program, [])
        self._output = ctx.framebuffer(color_attachments=[ctx.renderbuffer((w, h), components=4)])
        self._rgba = np.empty((h, w, 4), np.uint8)
        self.last_layers: list[Layer] = []
        self.last_render_ms = float("nan")
        self.last_readback_ms = float("nan")

    def render(self, view, proj, model, poi_px, px_per_deg: float, cov_deg2=None, view_mode: str = "shaded"):
        """The foveated frame (H, W, 3) uint8 RGB, row 0 at the top; ``poi_px`` (2,) in output pixels
        (top-left origin), ``px_per_deg`` the output's pixels per degree at full resolution."""
        r = self.renderer
        ctx = r.ctx
        w, h = r.size
        layers = layer_plan(px_per_deg, cov_deg2, self.config)
        self.last_layers = layers
        poi = np.asarray(poi_px, dtype=np.float64)
        poi_gl = (float(poi[0]), float(h - poi[1]))
        blend_px = self.config.blend_deg * px_per_deg
        r.prepare(view, proj, model, view_mode)
        ctx.finish()
        t0 = time.perf_counter()
        outer_px = []
        for k, layer in enumerate(layers):
            _, fbo = self._targets[k]
            lw, lh = fbo.size
            scissor = None
            if math.isfinite(layer.outer_deg):
                radius = layer.outer_deg * px_per_deg
                outer_px.append(radius)
                # Only the disc this layer shows (and its blend) is shaded.
                x0, y0 = (poi_gl[0] - radius) * lw / w, (poi_gl[1] - radius) * lh / h
                x1, y1 = (poi_gl[0] + radius) * lw / w, (poi_gl[1] + radius) * lh / h
                x0, y0 = max(int(math.floor(x0)) - 1, 0), max(int(math.floor(y0)) - 1, 0)
                x1, y1 = min(int(math.ceil(x1)) + 1, lw), min(int(math.ceil(y1)) + 1, lh)
                scissor = (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))
            else:
                outer_px.append(1e9)
            r.draw(fbo, (0, 0, lw, lh), view_mode, scissor=scissor)
        self._output.use()
        self._output.viewport = (0, 0, w, h)
        ctx.disable(moderngl.DEPTH_TEST | moderngl.BLEND)
        for k, (color, _) in enumerate(self._targets):
            color.use(k)
        prog = self._program
        for name, value in (("u_outer_px", outer_px[:-1] or [1e9]), ("u_blend_px", float(blend_px)),
                            ("u_poi_px", poi_gl), ("u_size", (float(w), float(h)))):
            if name in prog:          # one layer: the compiler drops what the blend needs
                prog[name].value = value
        self._vao.render(moderngl.TRIANGLES, vertices=3)
        ctx.finish()
        t1 = time.perf_counter()
        image = read_rgb(self._output, self._rgba)
        self.last_render_ms = (t1 - t0) * 1e3
        self.last_readback_ms = (time.perf_counter() - t1) * 1e3
        return image

    def release(self) -> None:
        """Free the layers' GL objects (the renderer and its context stay)."""
        for color, fbo in self._targets:
            fbo.release()
            color.release()
        self._output.release()
        self._vao.release()
        self._program.release()
        self._targets = []
