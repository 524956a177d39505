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
framebuffers (the same view), each clipped to the square of the disc it
covers, each from the triangles of the base faces that can reach its ring,
and composited on the CPU while reading back, with a smooth blend
``blend_deg`` wide at each border; the fovea stays at full resolution.

What it costs on llvmpipe (measured by ``headplod bench plod``'s foveated
part): the layers' draws can take less than the plain frame's on the close
views, but the face spans, the indirect commands and the composite take
part or all of it back. A frame there is bound by the per-triangle set-up
on the main thread, which the layers do not reduce (the faces on a border
are drawn twice); the pixels they save are filled by the raster threads.
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import cv2
import numpy as np

from ..plod.csf import CSF_MODELS, max_visible_freq_cpd
from ..tol import tol

__all__ = ["FoveationConfig", "Layer", "layer_plan", "layer_regions", "face_layer_span", "LayerAnchor",
           "FoveatedRenderer"]


@dataclass(frozen=True)
class FoveationConfig:
    """Settings of the foveated layers.

    Attributes
    ----------
    max_layers : int
        Most layers, the fovea included (scales 1, 1/2, ... 2^-(max_layers-1)).
        2 by default: on llvmpipe a layer's cost is mostly its triangles'
        set-up, not its pixels, and the faces on a border are drawn by both
        layers; a third layer at 1/4 (which the CSF allows far from the POI)
        measured slower than a single 1/2 layer for the whole periphery on
        every viewpoint (interleaved frames of ``headplod bench plod``'s
        foveated part).
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

    max_layers: int = 2
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


@functools.lru_cache(maxsize=16)
def _fmax_table(config: FoveationConfig):
    """(e grid (N,) deg, f_max on it (N,) cpd) for a config, computed once."""
    # Geometric from 1e-3 deg: steps of 0.028 % (0.002° at the fovea's ~6.5°, 0.02° at 63°).
    grid = np.concatenate([[0.0], np.geomspace(1e-3, 1e4, 65537)])
    f = np.asarray(max_visible_freq_cpd(config.contrast, config.speed_deg_s, grid, model=config.csf_model),
                   dtype=np.float64)
    return grid, f


def _ecc_for_frequency(freq_cpd: float, config: FoveationConfig) -> float:
    """The eccentricity (deg) beyond which f_max falls below ``freq_cpd`` (0 if it is below already).

    f_max falls with e: the first point of a table made once per config
    (:func:`_fmax_table`) where f_max <= ``freq_cpd``, so at most one step
    of the table beyond the crossing, never before it (a scalar bisection
    per frame cost more than the rest of the plan).
    """
    grid, f = _fmax_table(config)
    if f[0] <= freq_cpd:
        return 0.0
    above = f > freq_cpd
    if above[-1]:
        return math.inf
    return float(grid[int(np.argmin(above))])


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


def layer_regions(layers: list[Layer], px_per_deg: float, blend_deg: float) -> np.ndarray:
    """Where each layer shows in the composite: (n, 2) [lo, hi) distances from the POI, output px.

    Layer 0 (the fovea) shows inside ``outer_0``; layer k ≥ 1 from
    ``outer_{k-1} - blend`` (where the finer layer starts to fade out) to
    ``outer_k`` (inf for the last).
    """
    blend = blend_deg * px_per_deg
    out = np.empty((len(layers), 2))
    for k, layer in enumerate(layers):
        out[k, 0] = 0.0 if k == 0 else max(layers[k - 1].outer_deg * px_per_deg - blend, 0.0)
        out[k, 1] = layer.outer_deg * px_per_deg
    return out


_PRISMS: dict = {}


def _prism_points(corners, z_range) -> np.ndarray:
    """(6, F, 4) homogeneous corners of the faces' bounding prisms, scene units (cached per input arrays)."""
    key = (id(corners), id(z_range))
    hit = _PRISMS.get("last")
    if hit is not None and hit[0] == key and hit[1] is corners and hit[2] is z_range:
        return hit[3]
    c = np.asarray(corners, dtype=np.float64)
    z = np.asarray(z_range, dtype=np.float64)
    pts = np.empty((6, len(c), 4))          # corner-major: the reductions over a face's corners run along rows
    pts[:3, :, :2] = c[:, :, :2].transpose(1, 0, 2)
    pts[3:, :, :2] = c[:, :, :2].transpose(1, 0, 2)
    pts[:3, :, 2] = z[:, 0]
    pts[3:, :, 2] = z[:, 1]
    pts[..., 3] = 1.0
    _PRISMS["last"] = (key, corners, z_range, pts)
    return pts


def face_layer_span(corners, z_range, model, view, proj, size, poi_gl, regions, scales) -> np.ndarray:
    """The layers each base face can touch: (F, 2) int (first, last), (-1, -1) for a face off screen.

    Parameters
    ----------
    corners : (F, 3, 3) float
        Corners of the base faces, scene units (their x, y are used).
    z_range : (F, 2) float
        Lowest and highest z of any vertex of the face, scene units
        (``AdaptiveMesh.z_range``): the face lies in the prism of its base
        triangle between them.
    model, view, proj : (4, 4)
        ``T_world_scene``, ``T_eye_world``, ``T_clip_eye``.
    size : (W, H)
        Output image, px.
    poi_gl : (2,)
        POI, output px, GL origin (bottom-left).
    regions : (n, 2)
        :func:`layer_regions`.
    scales : (n,)
        Linear scale of each layer; a layer's region is widened by two of its
        pixels plus one output pixel (the bilinear upsampling reads that far).

    A face's screen rectangle is the bounding box of its prism's six
    corners' images (conservative: a perspective projection maps the
    prism, convex, to the hull of its corners' images when all lie in front
    of the eye); a face with a corner at or behind the eye plane touches
    every layer. The layers are annuli about the POI, so the ones a
    rectangle meets are contiguous: from the first whose outer edge lies
    beyond the rectangle's nearest point to the last whose inner edge lies
    within its farthest.
    """
    pts = _prism_points(corners, z_range)
    w, h = size
    mvp = np.asarray(proj, dtype=np.float64) @ np.asarray(view, dtype=np.float64) @ np.asarray(model, dtype=np.float64)
    clip = pts.reshape(-1, 4) @ mvp[[0, 1, 3]].T                       # (6F, 3): x, y, w
    wc = clip[:, 2].reshape(6, -1)
    behind = (wc <= tol.small).any(axis=0)
    inv = 0.5 / np.where(wc > tol.small, wc, 1.0)
    x = (clip[:, 0].reshape(6, -1) * inv + 0.5) * w
    y = (clip[:, 1].reshape(6, -1) * inv + 0.5) * h
    xmin, xmax, ymin, ymax = x.min(axis=0), x.max(axis=0), y.min(axis=0), y.max(axis=0)
    off = ~behind & ((xmax < -1) | (xmin > w + 1) | (ymax < -1) | (ymin > h + 1))
    x0, x1 = np.clip(xmin, 0, w), np.clip(xmax, 0, w)
    y0, y1 = np.clip(ymin, 0, h), np.clip(ymax, 0, h)
    px, py = float(poi_gl[0]), float(poi_gl[1])
    dmin = np.hypot(np.maximum(np.maximum(x0 - px, px - x1), 0), np.maximum(np.maximum(y0 - py, py - y1), 0))
    dmax = np.hypot(np.maximum(np.abs(x0 - px), np.abs(x1 - px)), np.maximum(np.abs(y0 - py), np.abs(y1 - py)))
    margin = 2.0 / np.asarray(scales, dtype=np.float64) + 1.0
    lo = np.asarray(regions, dtype=np.float64)[:, 0] - margin
    hi = np.asarray(regions, dtype=np.float64)[:, 1] + margin
    touched = (dmin[:, None] <= hi[None, :]) & (dmax[:, None] >= lo[None, :])       # (F, n)
    n = len(lo)
    first = np.argmax(touched, axis=1)
    last = n - 1 - np.argmax(touched[:, ::-1], axis=1)
    span = np.stack([first, last], axis=1).astype(np.int64)
    span[behind] = (0, n - 1)
    span[off | ~(touched.any(axis=1) | behind)] = (-1, -1)
    return span


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """GLSL's smoothstep (0 below ``e0``, 1 above ``e1``, C¹ between), float32."""
    t = np.clip((x - e0) / max(e1 - e0, tol.floor), 0.0, 1.0).astype(np.float32)
    return t * t * (3.0 - 2.0 * t)


def _read_rect(fbo, rect, buffers: dict) -> np.ndarray:
    """The pixels of ``fbo`` in ``rect`` (x, y, w, h) GL px (bottom-left origin) as (h, w, 3) uint8 RGB, top row first."""
    x, y, rw, rh = rect
    buf = buffers.get((rw, rh))
    if buf is None:
        buf = buffers[rw, rh] = np.empty((rh, rw, 4), np.uint8)
    fbo.read_into(buf, viewport=(x, y, rw, rh), components=4)
    return cv2.cvtColor(buf[::-1], cv2.COLOR_RGBA2RGB)


def _covers(outer: np.ndarray, inner: np.ndarray) -> bool:
    """Whether every span (first, last) of ``inner`` (F, 2) lies within ``outer``'s (off screen: (-1, -1), inside all)."""
    off = inner[:, 0] < 0
    return bool(np.all(off | ((outer[:, 0] >= 0) & (outer[:, 0] <= inner[:, 0]) & (inner[:, 1] <= outer[:, 1]))))


class LayerAnchor:
    """Holds the layers' centre and borders against small changes, so a still head gives a still frame.

    The POI given is already filtered (the selector's One Euro filter); its
    residual drift and the covariance's frame-to-frame noise would still move
    the blends by fractions of a pixel every frame. The anchor keeps the
    centre until the POI has moved more than ``hold_deg`` from it, and keeps
    each border until it should grow (at once: the uncertainty rose) or
    shrink by more than ``hold_deg``. Every border is pushed out by
    ``hold_deg`` so the held fovea still holds the planned one.

    Parameters
    ----------
    hold_deg : float
        Hysteresis, deg (> 0).
    """

    def __init__(self, hold_deg: float = 0.25):
        if not (isinstance(hold_deg, (int, float)) and math.isfinite(hold_deg) and hold_deg > 0):
            raise ValueError(f"LayerAnchor: hold_deg must be a finite number > 0, got {hold_deg!r}")
        self.hold_deg = float(hold_deg)
        self.reset()

    def reset(self) -> None:
        """Forget the held centre and borders (the next update takes the new ones)."""
        self.poi_px = None
        self.layers = None

    def update(self, poi_px, layers: list[Layer], px_per_deg: float):
        """The held (POI (2,) output px, whole pixels; layers) for a new filtered POI (2,) output px and layer plan."""
        poi = np.asarray(poi_px, dtype=np.float64).reshape(2)
        hold_px = self.hold_deg * px_per_deg
        widened = [Layer(l.scale, l.inner_deg + (self.hold_deg if k else 0.0), l.outer_deg + self.hold_deg)
                   for k, l in enumerate(layers)]
        if (self.poi_px is None or self.layers is None or len(self.layers) != len(widened)
                or np.hypot(*(poi - self.poi_px)) > hold_px):
            # Whole pixels (0.7 px at most, within the hold): the blend weights are then slices of
            # one map (FoveatedRenderer._weight).
            self.poi_px, self.layers = np.round(poi), widened
            return self.poi_px, self.layers
        outer = [h.outer_deg if h.outer_deg - self.hold_deg <= w.outer_deg <= h.outer_deg else w.outer_deg
                 for w, h in zip(widened, self.layers)]
        self.layers = [Layer(l.scale, 0.0 if k == 0 else outer[k - 1], outer[k]) for k, l in enumerate(widened)]
        return self.poi_px, self.layers


class FoveatedRenderer:
    """Draws a :class:`~headplod.render.gl.TerrainRenderer`'s mesh as foveated layers and composites them.

    The fovea is drawn at full resolution into the renderer's framebuffer,
    clipped (scissor) to its disc's square; each coarser layer k into its
    own framebuffer at scale 2^-k, clipped to its disc's square (the last
    layer: all of it). The composite is made while reading back (the frame
    is read back anyway): from the coarsest layer inwards, the image so far
    is upsampled x2 (bilinear, as GL's texture filter: pixel centres at
    half-integers) and the next layer is cross-faded in across its border
    (``blend_deg``, a smoothstep); the fovea last, at full resolution. On
    llvmpipe a full-screen GPU pass sampling two layers cost several times
    more than this.

    With the mesh given to :meth:`set_mesh` with each triangle's base face
    and the faces' bounding prisms, each layer draws only the triangles of
    the faces whose screen rectangle meets the ring it shows
    (:func:`face_layer_span`): one indirect draw of the runs of those faces'
    triangles in the mesh's own order (``subset_draw="indirect"``; the
    "levels" view, whose colours follow gl_PrimitiveID, sorts the indices by
    the faces' layer spans instead and draws ranges). Within a layer the
    triangles wholly outside its square or inside the finer layer's inner
    disc are dropped before set-up (clip distances, ``cull``). On llvmpipe a
    small triangle costs about as much to set up as to fill, so a coarse
    layer drawing the whole mesh costs nearly as much as the plain frame.

    Parameters
    ----------
    renderer : TerrainRenderer
        Its context, output size and framebuffer are used (``samples`` must be 0).
    config : FoveationConfig

    Attributes
    ----------
    last_layers : list of Layer
        The layers of the last frame (as drawn: after the anchor's hold, if any).
    last_render_ms : float
        GPU time of the last frame's layers (draws to ``ctx.finish()``), ms.
    last_readback_ms : float
        Read-back and composite, ms.
    last_stage_ms : dict
        ``composite`` (ms), and with :attr:`profile` set ``layer<k>`` (draw, ms).
    last_sort_ms : float
        Face spans and the layers' indirect commands (or re-sort and upload of the indices), ms.
    last_triangles_per_layer : list of int
    """

    def __init__(self, renderer, config: FoveationConfig = FoveationConfig()):
        if renderer.samples:
            raise ValueError("FoveatedRenderer: the renderer must have samples=0 (the fovea is drawn in place)")
        self.renderer = renderer
        self.config = config
        ctx = renderer.ctx
        w, h = renderer.size
        self._targets = [(None, renderer._fbo)]
        for k in range(1, config.max_layers):
            lw, lh = max(1, int(round(w * 2.0 ** -k))), max(1, int(round(h * 2.0 ** -k)))
            color = ctx.renderbuffer((lw, lh), components=4)
            self._targets.append((color, ctx.framebuffer(color_attachments=[color],
                                                         depth_attachment=ctx.depth_renderbuffer((lw, lh)))))
        self._buffers: dict = {}
        self._weights: dict = {}
        self._mesh = None              # (indices (T, 3), levels (T,), face of each triangle (T,) or None, bounds)
        self._order_key = None         # the face spans the uploaded order was made for
        self._ranges = None            # per layer: (first, count) triangle ranges
        self._uploaded_plain = True    # the renderer holds the mesh in its own order
        #: How much wider than needed (output px) the rings are when the faces are sorted.
        self.sort_margin_px = 8.0
        #: How a layer draws its subset: "indirect" (one indirect draw of the runs of its faces'
        #: triangles, the indices in the mesh's order) or "sorted" (the indices re-sorted by the
        #: faces' layer spans and uploaded, a draw call per range).
        self.subset_draw = "indirect"
        self._indirect: list = []
        self._blocks = None
        #: Wait for each layer to finish and time it (``last_stage_ms``); off, the layers overlap.
        self.profile = False
        #: Drop the triangles outside each layer's rectangle and inside its inner disc before set-up
        #: (clip distances; with the subsets only).
        self.cull = True
        self.last_layers: list[Layer] = []
        self.last_render_ms = float("nan")
        self.last_readback_ms = float("nan")
        self.last_sort_ms = 0.0
        self.last_stage_ms: dict = {}
        self.last_triangles_per_layer: list[int] = []

    # -- the mesh ---------------------------------------------------------------

    def set_mesh(self, indices, levels=None, face_per_triangle=None, bounds=None) -> None:
        """The mesh to draw, as indices into the renderer's uploaded vertex table (uploaded here).

        Parameters
        ----------
        indices : (3T,) or (T, 3) int
            Triangles, rows of the renderer's vertices.
        levels : (T,) int, optional
            Level of each triangle (the "levels" view).
        face_per_triangle : (T,) int, optional
            Base face of each triangle (``AdaptiveMesh.face_per_triangle()``).
        bounds : tuple of (F, 3, 3) and (F, 2) float, optional
            The base faces' corners and z ranges, scene units
            (``AdaptiveMesh.corners``, ``AdaptiveMesh.z_range``).

        With ``face_per_triangle`` and ``bounds`` each layer draws a subset;
        without, every layer draws the whole mesh.
        """
        idx = self.renderer._check_indices(indices, self.renderer.n_vertices).reshape(-1, 3)
        t = len(idx)
        lv = np.zeros(t, np.uint8) if levels is None else np.asarray(levels).reshape(-1)
        if len(lv) != t:
            raise ValueError(f"FoveatedRenderer.set_mesh: {len(lv)} levels for {t} triangles")
        lv = self.renderer._levels_per_triangle(lv, t, idx[:, 2], self.renderer.n_vertices)
        faces = None
        if face_per_triangle is not None and bounds is not None:
            faces = np.asarray(face_per_triangle).reshape(-1)
            if len(faces) != t:
                raise ValueError(f"FoveatedRenderer.set_mesh: {len(faces)} faces for {t} triangles")
            corners, z_range = bounds
            if not (isinstance(corners, np.ndarray) and isinstance(z_range, np.ndarray)):
                corners, z_range = np.asarray(corners, dtype=np.float64), np.asarray(z_range, dtype=np.float64)
            if corners.ndim != 3 or corners.shape[1:] != (3, 3) or z_range.shape != (len(corners), 2):
                raise ValueError(f"FoveatedRenderer.set_mesh: bounds must be (F, 3, 3) corners and (F, 2) "
                                 f"z ranges, got {corners.shape} and {z_range.shape}")
            if t and (faces.min() < 0 or faces.max() >= len(corners)):
                raise ValueError(f"FoveatedRenderer.set_mesh: faces in {faces.min()}..{faces.max()}, "
                                 f"expected 0..{len(corners) - 1}")
            bounds = (corners, z_range)
        self._mesh = (idx, lv, faces, bounds if faces is not None else None)
        self._order_key = self._ranges = None
        self._blocks = None
        if faces is not None and t:
            # The mesh's triangles come in one run per base face: (first triangle, count, face) per run.
            starts = np.flatnonzero(np.r_[True, faces[1:] != faces[:-1]])
            self._blocks = (starts, np.diff(np.r_[starts, t]), faces[starts])
        self._uploaded_plain = faces is None or self.subset_draw == "indirect"
        if self._uploaded_plain:
            self.renderer._set_checked_indices(idx.reshape(-1), lv)   # "sorted": render uploads them sorted

    def _indirect_commands(self, span: np.ndarray, n: int):
        """Per layer (indirect buffer, commands, triangles): the runs of consecutive triangles whose faces' spans
        hold the layer, in the mesh's own order."""
        starts, counts, block_face = self._blocks
        first, last = span[block_face, 0], span[block_face, 1]
        out = []
        for k in range(n):
            sel = (first >= 0) & (first <= k) & (last >= k)
            edge = np.diff(np.concatenate([[0], sel.view(np.int8), [0]]))
            run_s, run_e = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1) - 1
            cmds = np.zeros((len(run_s), 5), np.uint32)
            cmds[:, 0] = 3 * (starts[run_e] + counts[run_e] - starts[run_s])
            cmds[:, 1] = 1
            cmds[:, 2] = 3 * starts[run_s]
            raw = cmds.tobytes()
            if len(self._indirect) <= k:
                self._indirect.append(self.renderer.ctx.buffer(reserve=max(len(raw), 20)))
            buf = self._indirect[k]
            if len(raw) > buf.size:
                buf.orphan(len(raw))
            if raw:
                buf.write(raw)
            out.append((buf, len(run_s), int(cmds[:, 0].sum()) // 3))
        return out

    def _layer_ranges(self, span: np.ndarray, n: int):
        """Re-sort and upload the triangles by their faces' layer span; per layer its (first, count) ranges."""
        idx, lv, faces, _ = self._mesh
        key = np.where(span[:, 0] < 0, 0, span[:, 0] * n + span[:, 1] + 1).astype(np.uint8)   # 0: off screen
        tri_key = key[faces]
        order = np.argsort(tri_key, kind="stable")
        counts = np.bincount(tri_key, minlength=n * n + 1)
        starts = np.concatenate([[0], np.cumsum(counts)])
        # np.take gathers whole rows several times faster than idx[order].
        self.renderer._set_checked_indices(np.take(idx, order, axis=0).reshape(-1), lv[order])  # checked in set_mesh
        self._uploaded_plain = False
        ranges = []
        for k in range(n):
            # Faces spanning first..last with first <= k <= last: for each first, the keys with
            # last >= k are the tail of its block.
            rk = []
            for first in range(k + 1):
                lo, hi = starts[1 + first * n + k], starts[1 + first * n + n]
                if hi > lo:
                    rk.append((int(lo), int(hi - lo)))
            ranges.append(rk)
        return ranges

    # -- drawing ----------------------------------------------------------------

    def _weight(self, k: int, rect_td, layer_size, outer_px: float, blend_px: float, poi) -> np.ndarray:
        """Weight (h, w) float32 of layer k over the coarser ones in its rectangle (top-down layer px).

        A pixel's weight depends on its offset from the POI only: it is sliced
        from a map about the POI made once per (layer, border, blend, POI's
        sub-pixel phase), so a POI moving by whole pixels (the anchor rounds
        it) costs a slice, not a recomputation.
        """
        (x0, y0, x1, y1), (lw, lh) = rect_td, layer_size
        w, h = self.renderer.size
        fx, fy = w / lw, h / lh
        # Pixel i's centre lies (i + 0.5) f - p from the POI: f (i - q), q = p / f - 0.5.
        qx, qy = poi[0] / fx - 0.5, poi[1] / fy - 0.5
        ix, iy = math.floor(qx), math.floor(qy)
        phase = (round(qx - ix, 6), round(qy - iy, 6))
        half = int(math.ceil((outer_px + 2.0 * max(fx, fy) + 1.0) / min(fx, fy))) + 2
        key = (lw, lh, outer_px, blend_px, phase, half)
        hit = self._weights.get(k)
        if hit is None or hit[0] != key:
            xs = fx * (np.arange(-half, half + 1) - phase[0])
            ys = fy * (np.arange(-half, half + 1) - phase[1])
            r = np.sqrt(ys[:, None] ** 2 + xs[None, :] ** 2)
            hit = self._weights[k] = (key, 1.0 - _smoothstep(outer_px - blend_px, outer_px, r))
        full = hit[1]
        out = np.zeros((y1 - y0, x1 - x0), np.float32)          # beyond the map: past the border, 0
        c0, c1 = max(x0 - ix + half, 0), min(x1 - ix + half, 2 * half + 1)
        r0, r1 = max(y0 - iy + half, 0), min(y1 - iy + half, 2 * half + 1)
        if c1 > c0 and r1 > r0:
            out[r0 - (y0 - iy + half):r1 - (y0 - iy + half), c0 - (x0 - ix + half):c1 - (x0 - ix + half)] = \
                full[r0:r1, c0:c1]
        return out

    def render(self, view, proj, model, poi_px, px_per_deg: float, cov_deg2=None, view_mode: str = "shaded",
               subsets: bool = True, layers: list[Layer] | None = None):
        """The foveated frame (H, W, 3) uint8 RGB, row 0 at the top.

        Parameters
        ----------
        view, proj, model : (4, 4)
            As :meth:`TerrainRenderer.render`.
        poi_px : (2,)
            The layers' centre, output px, top-left origin.
        px_per_deg : float
            The output's pixels per degree at full resolution.
        cov_deg2 : (2, 2), optional
            The POI's covariance, deg² (widens the layers, :func:`layer_plan`).
        view_mode : str
        subsets : bool
            False: every layer draws the whole mesh (the reference the subsets must match).
        layers : list of Layer, optional
            The layers to draw (e.g. :class:`LayerAnchor`'s); default
            ``layer_plan(px_per_deg, cov_deg2, config)``.
        """
        r = self.renderer
        ctx = r.ctx
        w, h = r.size
        cfg = self.config
        n = cfg.max_layers
        if layers is None:
            layers = layer_plan(px_per_deg, cov_deg2, cfg)
        if len(layers) != n:
            raise ValueError(f"FoveatedRenderer.render: {len(layers)} layers, the config has {n}")
        self.last_layers = layers
        poi = np.asarray(poi_px, dtype=np.float64).reshape(-1)
        if poi.shape != (2,) or not np.isfinite(poi).all():
            raise ValueError(f"FoveatedRenderer.render: poi_px must be a finite (2,) point, got {poi_px!r}")
        poi_gl = (float(poi[0]), float(h - poi[1]))
        blend_deg = max(cfg.blend_deg, 0.5 / px_per_deg)
        blend_px = blend_deg * px_per_deg
        regions = layer_regions(layers, px_per_deg, blend_deg)
        scales = np.array([l.scale for l in layers])
        r.prepare(view, proj, model, view_mode)
        ts = time.perf_counter()
        ranges, indirect = self._subsets(view, proj, model, view_mode, subsets, poi_gl, regions, scales)
        self.last_sort_ms = (time.perf_counter() - ts) * 1e3
        self.last_triangles_per_layer = [
            (r.n_triangles if rk is None else int(sum(c for _, c in rk))) if ik is None else ik[2]
            for rk, ik in zip(ranges, indirect)]
        ctx.finish()
        t0 = time.perf_counter()
        rects, stage_ms = self._draw_layers(view_mode, ranges, indirect, poi_gl, regions, scales, t0)
        ctx.finish()
        t1 = time.perf_counter()
        image = self._composite(rects, regions, blend_px, poi)
        t2 = time.perf_counter()
        stage_ms["composite"] = (t2 - t1) * 1e3
        self.last_stage_ms = stage_ms
        self.last_render_ms = (t1 - t0) * 1e3
        self.last_readback_ms = (t2 - t1) * 1e3
        return image

    def _subsets(self, view, proj, model, view_mode, subsets, poi_gl, regions, scales):
        """Each layer's draw: (ranges per layer (list of (first, count)) or None for the whole mesh,
        indirect commands per layer or None); sorts the mesh's faces by layer span when needed."""
        r, n = self.renderer, self.config.max_layers
        w, h = r.size
        ranges = [None] * n
        indirect = [None] * n
        mesh = self._mesh
        use_indirect = self.subset_draw == "indirect" and view_mode != "levels"
        if subsets and mesh is not None and mesh[2] is not None and use_indirect and self._blocks is not None:
            if not self._uploaded_plain:
                r._set_checked_indices(mesh[0].reshape(-1), mesh[1])
                self._uploaded_plain = True
            self._order_key = self._ranges = None
            span = face_layer_span(mesh[3][0], mesh[3][1], model, view, proj, (w, h), poi_gl, regions, scales)
            indirect = self._indirect_commands(span, n)
            ranges = [()] * n
        elif subsets and mesh is not None and mesh[2] is not None:
            corners, z_range = mesh[3]
            old = self._order_key
            # The order drawn stays while it still covers every face's span (each layer then
            # draws a superset of what it needs); else the faces are sorted again by spans
            # widened by ``sort_margin_px``, so small head motions do not re-sort every frame.
            if old is None or not _covers(old, face_layer_span(corners, z_range, model, view, proj, (w, h),
                                                               poi_gl, regions, scales)):
                wide = regions + np.array([-1.0, 1.0]) * self.sort_margin_px
                wide[:, 0] = np.maximum(wide[:, 0], 0.0)
                loose = face_layer_span(corners, z_range, model, view, proj, (w, h), poi_gl, wide, scales)
                self._ranges = self._layer_ranges(loose, n)
                self._order_key = loose
            ranges = self._ranges
        elif mesh is not None and not self._uploaded_plain:
            r._set_checked_indices(mesh[0].reshape(-1), mesh[1])      # the mesh in its own order
            self._order_key = self._ranges = None
            self._uploaded_plain = True
        return ranges, indirect

    def _layer_rect(self, k, poi_gl, regions, scales):
        """The rectangle (x0, y0, width, height) of layer k's framebuffer that its disc (and its filter) reaches."""
        w, h = self.renderer.size
        (lw, lh), s = self._targets[k][1].size, scales[k]
        hi = regions[k, 1]
        if not math.isfinite(hi):
            return (0, 0, lw, lh)
        # Only the square of the disc this layer shows (and its filter's reach) is shaded.
        reach = hi + 2.0 / s + 1.0
        x0 = max(int(math.floor((poi_gl[0] - reach) * lw / w)), 0)
        y0 = max(int(math.floor((poi_gl[1] - reach) * lh / h)), 0)
        x1 = min(int(math.ceil((poi_gl[0] + reach) * lw / w)), lw)
        y1 = min(int(math.ceil((poi_gl[1] + reach) * lh / h)), lh)
        return (x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))

    def _draw_layers(self, view_mode, ranges, indirect, poi_gl, regions, scales, t0):
        """Draw every layer into its framebuffer; (rects per layer, stage ms of the profile)."""
        r, n = self.renderer, self.config.max_layers
        w, h = r.size
        stage_ms = {}
        rects = [None] * n
        # Coarsest first, the fovea last, without waiting in between: llvmpipe rasterizes a
        # layer on its threads while the main thread transforms and sets up the next one
        # (``profile``: wait after each, for per-layer times).
        for k in range(n - 1, -1, -1):
            fbo = self._targets[k][1]
            (lw, lh), s = fbo.size, scales[k]
            rect = rects[k] = self._layer_rect(k, poi_gl, regions, scales)
            cull = None
            if self.cull and ranges[k] is not None:
                # Drop, before set-up, the triangles outside the rectangle (2 px beyond it, so
                # what is clipped lies outside the scissor) or inside the finer layer's inner
                # disc (less the filter's reach): the face subsets are coarse.
                x0, y0, rw, rh = rect
                drop = (regions[k, 0] - 2.0 / s - 2.0) * s
                disc = (poi_gl[0] * lw / w, poi_gl[1] * lh / h, drop) if k > 0 and drop > 0 else None
                cull = ((x0 - 2, y0 - 2, x0 + rw + 2, y0 + rh + 2), disc)
            r.draw(fbo, (0, 0, lw, lh), view_mode, scissor=None if rect == (0, 0, lw, lh) else rect,
                   ranges=ranges[k], cull=cull, indirect=None if indirect[k] is None else indirect[k][:2])
            if self.profile:
                r.ctx.finish()
                stage_ms["layer%d" % k] = (time.perf_counter() - t0) * 1e3 - sum(stage_ms.values())
        return rects, stage_ms

    def _composite(self, rects, regions, blend_px: float, poi) -> np.ndarray:
        """Read the layers back and blend them, coarsest first; (H, W, 3) uint8 RGB, top row first."""
        w, h = self.renderer.size
        n = len(rects)
        image = None
        for k in range(n - 1, -1, -1):
            fbo = self._targets[k][1]
            lw, lh = fbo.size
            x, y, rw, rh = rects[k]
            if image is None:
                if (x, y, rw, rh) == (0, 0, lw, lh):
                    image = _read_rect(fbo, rects[k], self._buffers)
                    continue
                image = np.empty((lh, lw, 3), np.uint8)       # a finite outermost layer: background beyond
                image[:] = np.round(np.asarray(self.renderer.background) * 255).astype(np.uint8)
            elif image.shape[:2] != (lh, lw):
                image = cv2.resize(image, (lw, lh), interpolation=cv2.INTER_LINEAR)
            if rw == 0 or rh == 0:
                continue
            patch = _read_rect(fbo, rects[k], self._buffers)
            td = (x, lh - (y + rh), x + rw, lh - y)                    # top-down (x0, y0, x1, y1)
            weight = self._weight(k, td, (lw, lh), float(regions[k, 1]), blend_px, poi)
            under = image[td[1]:td[3], td[0]:td[2]]
            image[td[1]:td[3], td[0]:td[2]] = cv2.blendLinear(patch, under, weight, 1.0 - weight)
        if image.shape[:2] != (h, w):
            image = cv2.resize(image, (w, h), interpolation=cv2.INTER_LINEAR)
        return image

    def release(self) -> None:
        """Free the layers' GL objects (the renderer and its context stay)."""
        for color, fbo in self._targets[1:]:
            fbo.release()
            color.release()
        for buf in self._indirect:
            buf.release()
        self._targets, self._indirect = [], []
