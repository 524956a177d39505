"""A terrain as a regular height grid cut into square patches, and the CSF levels of patches and their edges.

The pure-numpy half of the tessellation back end (:mod:`headplod.render.tessellate`):

- :func:`height_grid`: the terrain (:class:`headplod.plod.terrain.Terrain`,
  DEM spline + synthetic detail) sampled on an ``n x n`` grid over its extent,
  separably (a few matrix products instead of per-point evaluation), so
  grids of 8193² samples (134 million triangles) are affordable.
- :class:`PatchGrid`: that grid cut into patches of ``patch_samples`` sample
  spacings, with each patch's height range (for culling) and Michelson
  contrast of its Lambert shading (for the CSF).
- :func:`patch_levels`: the continuous CSF level of every patch (its inner
  tessellation) and of every patch edge (its outer tessellation): the
  ``csf`` rule of :mod:`headplod.plod.criteria` (``kelly_scaled``,
  uncertainty shift, eccentricity at the point nearest the POI), the one
  :class:`headplod.plod.select.LevelSelector` applies to a base triangle,
  on a patch's five pieces (:func:`headplod.plod.criteria.patch_pieces`).
  The tessellation shaders evaluate the same rule in float32; this is what
  they are tested against.

Grid frame: sample ``[i, j]`` is at scene ``(x0 + j dx, y0 + i dy)`` (row 0 south,
column 0 west, as :class:`Terrain`); patch ``(pi, pj)`` covers samples
``pi P .. (pi + 1) P`` by ``pj P .. (pj + 1) P`` (``P = patch_samples``), so
neighbours share their border samples.

Edges of a patch, in the order of GL's quad outer tessellation levels
(``gl_TessLevelOuter[k]``, tess coordinate u along columns, v along rows):
0 west (u = 0), 1 south (v = 0), 2 east (u = 1), 3 north (v = 1).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage as ndi

from ..cache import usable_cache_root
from . import criteria
from . import perception as pc
from .shading import contrast_of_range, shade
from .terrain import Terrain, _bspline_weights

__all__ = ["height_grid", "jacksboro_grid", "grid_normals", "PatchGrid", "patch_levels", "levels_of_patches",
           "tess_factors", "FACTOR_RULES", "EDGE_NAMES", "patch_samples_for", "vertex_gap_samples"]

#: The detail's shortest wavelength on :func:`jacksboro_grid`'s grids, sample spacings: each grid has detail
#: down to its own resolution.
DETAIL_MIN_WAVELENGTH_SPACINGS = 2.5

EDGE_NAMES = ("west", "south", "east", "north")
"""Patch edges in the order of ``gl_TessLevelOuter`` for quads (module notes)."""


def _spline_matrix(n_out: int, n_in: int) -> np.ndarray:
    """(n_out, n_in) float64: cubic B-spline taps at ``n_out`` equally spaced points over ``0..n_in-1``.

    Mirror boundary as :class:`Terrain`'s (``np.pad(..., mode="reflect")`` of the coefficients by 2).
    """
    q = np.linspace(0.0, n_in - 1.0, n_out)
    j0 = np.minimum(q.astype(np.int64), n_in - 2)
    w, _ = _bspline_weights(q - j0)
    taps = j0[:, None] + np.arange(-1, 3)[None, :]                       # (n_out, 4)
    taps = np.abs(taps)                                                   # reflect at 0: -1 -> 1
    taps = np.where(taps > n_in - 1, 2 * (n_in - 1) - taps, taps)         # reflect at the end
    m = np.zeros((n_out, n_in))
    np.add.at(m, (np.repeat(np.arange(n_out), 4), taps.ravel()), w.ravel())
    return m


def height_grid(terrain: Terrain, n_samples: int) -> tuple[np.ndarray, float, float]:
    """The terrain's heights on an ``n_samples x n_samples`` grid spanning its extent.

    Equals ``terrain.heights`` at the grid points (the DEM's B-spline and the
    detail waves, evaluated separably: the spline as ``Wy C Wxᵀ``, the waves
    as one product of per-row and per-column cosines), up to float32.

    Parameters
    ----------
    terrain : Terrain
    n_samples : int
        Samples per side, >= 4.

    Returns
    -------
    z : (n_samples, n_samples) float32
        Heights, metres; row 0 south, column 0 west.
    dx_m, dy_m : float
        Sample spacing east and north, metres.
    """
    n = int(n_samples)
    if n < 4:
        raise ValueError(f"height_grid: n_samples must be >= 4, got {n_samples!r}")
    ny_in, nx_in = terrain.shape
    x0, x1, y0, y1 = terrain.extent
    dx, dy = (x1 - x0) / (n - 1), (y1 - y0) / (n - 1)
    wx, wy = _spline_matrix(n, nx_in), _spline_matrix(n, ny_in)
    dem = ndi.spline_filter(terrain.dem_z_m, order=3, mode="mirror")
    z = ((wy @ dem) @ wx.T).astype(np.float32)
    if terrain.detail and len(terrain._w_a):
        env = ndi.spline_filter(Terrain._roughness_envelope(terrain.dem_z_m), order=3, mode="mirror")
        env = ((wy @ env) @ wx.T).astype(np.float32)
        xr = np.linspace(x0, x1, n) - terrain._centre[0]
        yr = np.linspace(y0, y1, n) - terrain._centre[1]
        k, a, phi = (np.asarray(v, np.float64) for v in (terrain._w_k, terrain._w_a, terrain._w_phi))
        alpha = xr[:, None] * k[None, :, 0] + phi[None, :]                 # (n, W) along x
        beta = yr[:, None] * k[None, :, 1]                                 # (n, W) along y
        # Σ a cos(α + β) = Σ a (cos α cos β − sin α sin β): (n, 2W) @ (2W, n).
        rows = np.concatenate([np.cos(beta), np.sin(beta)], axis=1).astype(np.float32)
        cols = np.concatenate([a * np.cos(alpha), -a * np.sin(alpha)], axis=1).astype(np.float32)
        waves = rows @ cols.T
        waves *= env
        z += waves
    return z, float(dx), float(dy)


def jacksboro_grid(n_samples: int, cache_dir=None):
    """The built-in terrain (DEM + detail down to 2.5 spacings) on an ``n x n`` grid, cached as .npy.

    Cached under ``cache_dir`` (default ``$HEADPLOD_CACHE/scale``, ``~/.cache/headplod/scale``); a cache
    that cannot be used raises :class:`~headplod.cache.CacheUnusable` before the grid is computed.

    Returns
    -------
    z : (n, n) float32
        Heights, metres (:func:`height_grid`).
    dx_m, dy_m : float
        Sample spacing, metres.
    origin_m : (2,) tuple
        Scene (x, y) of sample [0, 0].
    """
    cache = Path(cache_dir) if cache_dir is not None else usable_cache_root() / "scale"   # checked before the work
    path, meta_path = cache / f"jacksboro_{n_samples}.npy", cache / f"jacksboro_{n_samples}.json"
    if path.exists() and meta_path.exists():
        meta = json.loads(meta_path.read_text())
        return np.load(path), meta["dx_m"], meta["dy_m"], tuple(meta["origin_m"])
    base = Terrain.jacksboro(detail=False)
    x0, x1, y0, y1 = base.extent
    spacing = max(x1 - x0, y1 - y0) / (n_samples - 1)
    terrain = Terrain.jacksboro(detail_min_wavelength_m=DETAIL_MIN_WAVELENGTH_SPACINGS * spacing)
    z, dx, dy = height_grid(terrain, n_samples)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npy")
    np.save(tmp, z)
    tmp.replace(path)
    meta_path.write_text(json.dumps({"dx_m": dx, "dy_m": dy, "origin_m": [x0, y0],
                                     "detail_min_wavelength_m": terrain.detail_min_wavelength_m}))
    return z, dx, dy, (x0, y0)


def grid_normals(z: np.ndarray, dx_m: float, dy_m: float) -> np.ndarray:
    """Unit normals of a height grid by central differences (one-sided at the border), (ny, nx, 3) float32.

    ``(-dz/dx, -dz/dy, 1) / norm``, scene frame; the tessellation shader's normals at full detail.
    """
    gy, gx = np.gradient(np.asarray(z, np.float32), dy_m, dx_m)
    n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n


def _block_reduce(z: np.ndarray, p: int, fn) -> np.ndarray:
    """(n/p, n/p) reduction ``fn`` (np.minimum / np.maximum) over each patch's (p+1)² samples."""
    starts = np.arange(0, z.shape[0] - 1, p)
    rows = fn.reduceat(z[:-1], starts, axis=0)                  # rows [k p, (k+1) p)
    rows = fn(rows, z[starts + p])                              # and the shared border row
    cols = fn.reduceat(rows[:, :-1], starts, axis=1)
    return fn(cols, rows[:, starts + p])


@dataclass(frozen=True)
class PatchGrid:
    """A height grid cut into square patches.

    Attributes
    ----------
    heights_m : (N, N) float32
        Heights, metres (grid frame: module notes). N - 1 is a multiple of ``patch_samples``.
    dx_m, dy_m : float
        Sample spacing, metres.
    origin_m : (2,) tuple
        Scene (x, y) of sample [0, 0], metres.
    patch_samples : int
        Sample spacings per patch side (P).
    z_min_m, z_max_m : (n, n) float32
        Height range of each patch's (P+1)² samples, metres; n = (N - 1) / P.
    contrast : (n, n) float32
        Michelson contrast of the Lambert shading over each patch's samples,
        with the light every back end draws with (:mod:`headplod.plod.shading`).
    """

    heights_m: np.ndarray
    dx_m: float
    dy_m: float
    origin_m: tuple
    patch_samples: int
    z_min_m: np.ndarray
    z_max_m: np.ndarray
    contrast: np.ndarray

    @classmethod
    def build(cls, heights_m, dx_m: float, dy_m: float, patch_samples: int, origin_m=(0.0, 0.0)) -> "PatchGrid":
        """Cut a square height grid (N, N) into patches of ``patch_samples``; N - 1 must be a multiple of it."""
        z = np.ascontiguousarray(heights_m, dtype=np.float32)
        p = int(patch_samples)
        if z.ndim != 2 or z.shape[0] != z.shape[1]:
            raise ValueError(f"PatchGrid: heights_m must be a square (N, N) grid, got shape {z.shape}")
        if p < 1 or (z.shape[0] - 1) % p:
            raise ValueError(f"PatchGrid: N - 1 = {z.shape[0] - 1} is not a multiple of patch_samples = {p}")
        if not np.isfinite(z).all():
            raise ValueError("PatchGrid: heights_m has NaN or inf")
        z_min, z_max = _block_reduce(z, p, np.minimum), _block_reduce(z, p, np.maximum)
        contrast = cls._contrast(z, float(dx_m), float(dy_m), p)
        return cls(z, float(dx_m), float(dy_m), (float(origin_m[0]), float(origin_m[1])), p, z_min, z_max,
                   contrast)

    @staticmethod
    def _contrast(z, dx_m, dy_m, p) -> np.ndarray:
        """(n, n) Michelson contrast of the displayed shading over each patch (:mod:`headplod.plod.shading`),
        computed a row of patches at a time."""
        n_p = (z.shape[0] - 1) // p
        out = np.empty((n_p, n_p), np.float32)
        for r in range(n_p):                     # one strip of patches: bounded temporaries
            lo, hi = max(r * p - 1, 0), min((r + 1) * p + 2, z.shape[0])
            normals = grid_normals(z[lo:hi], dx_m, dy_m)[r * p - lo:(r + 1) * p + 1 - lo]
            drawn = shade(normals)
            out[r] = contrast_of_range(_block_reduce_strip(drawn, p, np.maximum),
                                       _block_reduce_strip(drawn, p, np.minimum))
        return out

    @property
    def n_patches(self) -> int:
        """Patches per side."""
        return (self.heights_m.shape[0] - 1) // self.patch_samples

    @property
    def full_triangles(self) -> int:
        """Triangles of the grid at full detail: 2 (N - 1)²."""
        return 2 * (self.heights_m.shape[0] - 1) ** 2

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax), metres."""
        n = self.heights_m.shape[0] - 1
        return (self.origin_m[0], self.origin_m[0] + n * self.dx_m, self.origin_m[1], self.origin_m[1] + n * self.dy_m)

    def neighbour_contrast(self) -> np.ndarray:
        """(n, n, 4) float64: the contrast of the patch across each edge, W S E N (the patch's own at the border).

        An edge's level takes the larger contrast of its two patches (the shader clamps the neighbour's index
        the same way), so both patches compute the same number.
        """
        padded = np.pad(self.contrast.astype(np.float64), 1, mode="edge")
        return np.stack([padded[1:-1, :-2], padded[:-2, 1:-1], padded[1:-1, 2:], padded[2:, 1:-1]], axis=-1)

    def corners_scene(self) -> np.ndarray:
        """(n, n, 4, 3) float64 corners of every patch, scene metres, in the order SW, SE, NE, NW."""
        p, n = self.patch_samples, self.n_patches
        idx = np.arange(n + 1) * p
        zc = self.heights_m[np.ix_(idx, idx)].astype(np.float64)          # (n+1, n+1) corner heights
        xs = self.origin_m[0] + idx * self.dx_m
        ys = self.origin_m[1] + idx * self.dy_m
        X, Y = np.meshgrid(xs, ys)
        pts = np.stack([X, Y, zc], axis=-1)                               # (n+1, n+1, 3)
        return np.stack([pts[:-1, :-1], pts[:-1, 1:], pts[1:, 1:], pts[1:, :-1]], axis=2)


def _block_reduce_strip(a: np.ndarray, p: int, fn) -> np.ndarray:
    """(n,) reduction over the (p+1) x (p+1) blocks of one strip ``a`` (p+1, N)."""
    cols = fn.reduce(a, axis=0)                                          # (N,)
    starts = np.arange(0, a.shape[1] - 1, p)
    return fn(fn.reduceat(cols[:-1], starts), cols[starts + p])


def patch_levels(grid: PatchGrid, model: np.ndarray, eye_mm, axes, cov_deg2=None, *, shift: str = "ellipse",
                 ellipse_sigma: float = 2.0, speed_deg_s: float = pc.MIN_SPEED_DEG_S, level_bias: float = 0.0):
    """Continuous CSF levels of every patch (inner) and every patch edge (outer), as the shader computes them.

    A level L splits a patch (or an edge) into 2^L pieces per side; its
    continuous level is ``log2(f_max / f)`` with f = 1 / (angular diameter
    of the patch: the largest angle between two of its corners; of an edge:
    between its endpoints), f_max the ``kelly_scaled`` CSF's highest visible
    frequency at the patch's contrast (an edge: the larger contrast of the
    patches sharing it), and the eccentricity taken at the point nearest
    the POI: that of the centre (an edge: its midpoint), shifted by the
    uncertainty, less the angle to the farthest corner (endpoint), floored at
    0 — as :meth:`LevelSelector.select` does for a base triangle
    (:func:`headplod.plod.criteria.patch_piece_levels`). An edge's level
    depends on the edge alone, so both patches sharing it agree.

    Parameters
    ----------
    grid : PatchGrid
    model : (4, 4)
        Scene (m) → world (mm).
    eye_mm : (3,)
        Eye, world frame, mm.
    axes : (3, 3)
        Rows Ξ, Ψ, V of the head frame (:func:`headplod.plod.view.head_axes`).
    cov_deg2 : (2, 2) or None
        Covariance of the viewing direction, deg².
    shift, ellipse_sigma
        As :class:`SelectorConfig`'s.
    speed_deg_s : float
        Angular speed of every patch, deg/s (the floor for a still head).
    level_bias : float
        Added to every level, levels.

    Returns
    -------
    inner : (n, n) float64
        Continuous level of each patch (row pi, column pj).
    outer : (n, n, 4) float64
        Continuous level of each patch's edges in :data:`EDGE_NAMES` order.
    """
    corners = grid.corners_scene()                                               # (n, n, 4, 3)
    contrast = grid.contrast.astype(np.float64)
    return levels_of_patches(corners, contrast, grid.neighbour_contrast(), model, eye_mm, axes, cov_deg2, shift=shift,
                             ellipse_sigma=ellipse_sigma, speed_deg_s=speed_deg_s, level_bias=level_bias)


def levels_of_patches(corners_scene, contrast, neighbour_contrast, model, eye_mm, axes, cov_deg2=None, *,
                      shift: str = "ellipse", ellipse_sigma: float = 2.0, speed_deg_s=pc.MIN_SPEED_DEG_S,
                      level_bias: float = 0.0, eye_prev_mm=None, dt_s: float = 0.0, fmax_foveal=None):
    """:func:`patch_levels`' closed form on any set of patches (the flat grid's, or a quadtree's leaves).

    Parameters
    ----------
    corners_scene : (..., 4, 3)
        Each patch's corners SW, SE, NE, NW, scene metres.
    contrast : (...,)
        Each patch's shading contrast.
    neighbour_contrast : (..., 4)
        The contrast of the patch across each edge (W, S, E, N; its own at the grid's border).
    model, eye_mm, axes, cov_deg2, shift, ellipse_sigma, speed_deg_s, level_bias
        As :func:`patch_levels`.
    eye_prev_mm : (3,) or None; dt_s : float
        The last frame's eye (world mm) and the time since, s: when given (``dt_s > 0``), each point's
        speed is :func:`headplod.plod.criteria.point_speed_deg_s`'s (the shader's rule) instead of ``speed_deg_s``.
    fmax_foveal : (..., 5) or None
        Optional: the foveal f_max (eccentricity 0) of the inner piece and of each edge at
        ``speed_deg_s`` (cpd), precomputed (:class:`headplod.plod.patch_tree.PatchTree` does, once);
        ignored when the eye moves. The levels are the same numbers.

    Returns
    -------
    inner : (...,) float64
    outer : (..., 4) float64
        As :func:`patch_levels`.
    """
    model = np.asarray(model, np.float64)
    corners = np.asarray(corners_scene, np.float64)
    homog = np.concatenate([corners, np.ones(corners.shape[:-1] + (1,))], axis=-1)
    levels = criteria.patch_piece_levels((homog @ model.T)[..., :3],
                                         criteria.patch_piece_contrast(contrast, neighbour_contrast), eye_mm, axes,
                                         cov_deg2, shift=shift, ellipse_sigma=ellipse_sigma, level_bias=level_bias,
                                         speed_deg_s=speed_deg_s, eye_prev_mm=eye_prev_mm, dt_s=dt_s,
                                         foveal_cpd=fmax_foveal)
    return levels[..., 0], levels[..., 1:]


#: How a continuous level becomes a tessellation factor (``TessellationConfig.factors``).
FACTOR_RULES = ("whole", "power_of_two")


def tess_factors(levels: np.ndarray, max_level: int, patch_samples: int | None = None,
                 rule: str = "power_of_two") -> np.ndarray:
    """Tessellation factors (segments per patch side, int64, the shape of ``levels``) of continuous levels.

    ``power_of_two``: 2^L, L = ceil clamped to [0, max_level]
    (:func:`perception.round_level`): the CPU mesh's integer levels.
    ``whole`` (needs ``patch_samples`` P): level L asks for a vertex every
    ``P 2^-L`` samples; ``g`` is the largest whole number of samples within
    that (at least 1) and the factor ``F = ceil(P / g)``, at most
    ``2^max_level``: with ``equal_spacing`` and every vertex rounded to a
    sample, no gap exceeds ``g``. The same density as ``power_of_two``'s
    but without rounding the segment count up to a power of two (up to 2x
    per side, about 2x the triangles on average).
    """
    if rule == "power_of_two":
        return (2 ** pc.round_level(levels, "ceil", max_level)).astype(np.int64)
    if rule != "whole":
        raise ValueError(f"tess_factors: rule must be one of {FACTOR_RULES}, got {rule!r}")
    if patch_samples is None:
        raise ValueError("tess_factors: the 'whole' rule needs patch_samples")
    lv = np.nan_to_num(np.asarray(levels, np.float64), nan=-1.0, posinf=float(max_level), neginf=-1.0)
    gap = vertex_gap_samples(np.maximum(lv, -1.0), patch_samples, max_level)
    return np.minimum(np.ceil(patch_samples / gap), 2 ** max_level).astype(np.int64)


def vertex_gap_samples(levels: np.ndarray, patch_samples: int, max_level: int) -> np.ndarray:
    """Largest whole number of samples between vertices that level L allows: floor(P 2^-min(L, max_level)), >= 1.

    Level L of a patch of P samples asks for a vertex every ``P 2^-L`` samples; vertices sit on samples, so
    the gap is rounded down. The ``whole`` factors (:func:`tess_factors`) and the patch tree's nodes
    (``ceil(node size / gap)``) both keep every gap within it. Float64, the shape of ``levels`` (finite).
    """
    return np.maximum(np.floor(patch_samples * np.exp2(-np.minimum(levels, float(max_level)))), 1.0)


def patch_samples_for(n_samples: int, image_px: int, max_tess_level: int = 64, smallest: int = 64) -> int:
    """Patch side (samples) for an ``n x n`` grid drawn into an image ``image_px`` pixels on its longer side.

    The largest power of two ``P >= smallest`` dividing ``n - 1`` whose finest
    level (``P / max_tess_level`` samples per vertex) still puts at least two
    vertices per image pixel across the whole terrain: ``(n - 1) / P *
    max_tess_level >= 2 image_px``. Finer vertices than that cannot show
    even where the terrain fills the image, and larger patches mean fewer
    for the levels pass and the draw (8193² at 1280 px: 128, 4096 patches
    instead of 16384). ``smallest`` when no larger one qualifies.
    """
    if n_samples < 2 or (n_samples - 1) % smallest:
        raise ValueError(f"patch_samples_for: n_samples - 1 must be a positive multiple of {smallest}, "
                         f"got {n_samples}")
    p = smallest
    while ((n_samples - 1) % (2 * p) == 0
           and (n_samples - 1) / (2 * p) * min(2 * p, max_tess_level) >= 2 * image_px):
        p *= 2
    return p


def max_level_for(patch_samples: int, max_tess_level: int) -> int:
    """Finest level of a patch: 2^L segments per side, at most one per sample and at most ``max_tess_level``."""
    return int(math.floor(math.log2(min(patch_samples, max_tess_level))))
