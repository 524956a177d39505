"""A quadtree over a :class:`PatchGrid`'s patches: variable-size tessellation patches, refined where the CSF needs it.

The flat tessellation back end evaluates the CSF on every patch of ``P``
samples on every frame and draws every patch in view: its cost grows with the
terrain (16384 patches at 8193² samples). Here the patches are the leaves of
a quadtree whose node at depth ``d`` is a square of ``S = P 2^(D-d)`` samples
(``D = log2(n)``, ``n`` patches per side, a power of two; the root at depth 0
is the whole grid). Per frame (:meth:`PatchTree.select`):

1. **Walk** the tree breadth-first, one depth at a time, with numpy over the
   whole frontier. A node whose box (its samples' x, y; its height range) is
   outside the view frustum is culled. Otherwise its *need* is evaluated: an
   upper bound ``L_ub`` on the CSF level of every leaf patch (and every leaf
   edge) below it, with the closed form of
   :func:`headplod.plod.patches.patch_levels`, taken at the node's worst
   case: the highest contrast over the node and its four neighbours (a leaf
   edge takes its neighbour's contrast too), the smallest eccentricity over
   its box (the angle of the box's centre from the view axis, less the
   angle to the box's farthest corner, less the uncertainty shift's largest
   reach, less the largest leaf diameter), and the largest angular diameter
   a leaf of the node can have (its largest corner-to-corner chord, with the
   largest height range of a leaf below the node, seen from the box's
   nearest point). A node of ``S`` samples shows every leaf below it at
   that level with the tessellation factor ``F = (S / P) 2^ceil(L_ub)``
   (the leaves' levels rounded as the flat path rounds them, then ``S / P``
   leaves per side). If ``F`` exceeds ``split_factor`` (or the node's own
   limit ``min(S, max_tess_level)``) the node is split and its four children
   join the next frontier. Leaves (``S = P``) get the flat path's exact
   levels (:func:`levels_of_patches`). The cost is that of the nodes in
   view along the refined path, not of the grid.
2. **Balance** the tree 2:1 (neighbours across an edge differ by at most one
   depth), bottom-up: a split node forces the split of its edge neighbours'
   parents. Nodes this adds are evaluated as in step 1.
3. **Edge factors**, crack-free by construction:

   - between leaves, the flat path's edge factor (from the edge alone: both
     leaves compute the same number);
   - between two nodes of the same size above the leaves, the larger of
     their factors (both sides take the same max);
   - on a transition edge (a node of ``S`` samples beside two of ``S/2``),
     ``F = max(big's need, 2 x each small's need on that edge)``, clamped
     to ``[2, min(S, max_tess_level)]``, on the big side and ``F / 2`` on
     each small side: with ``equal_spacing`` both sides then put vertices on
     the same samples (spacing ``S / F``), and the big edge's midpoint,
     the small nodes' shared corner, is one of them.

   Every vertex is on the sample grid (``S / F`` is a whole number of
   samples), so shared vertices are identical.

The output (:class:`NodeSelection`) is the drawn (unculled) nodes: origin
sample, size in samples, inner factor and the four outer factors (W, S, E, N
as ``gl_TessLevelOuter``). The bound makes a node conservative: every leaf
patch below a drawn node gets at least the spacing the flat selection gives
it (``tests/test_patch_tree.py`` checks it on random views). Pure numpy; the
GL side is :mod:`headplod.render.tessellate` (``TessellationConfig.hierarchy``).

Not here (yet): hysteresis (per-node state), as the flat path.
Frames: grid frame as :mod:`headplod.plod.patches` (row 0 south, column 0 west);
node ``(d, row, col)`` covers samples ``row S .. (row + 1) S`` by ``col S .. (col + 1) S``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import perception as pc
from .patches import PatchGrid, levels_of_patches, max_level_for, tess_factors

__all__ = ["PatchTree", "NodeSelection", "EDGE_STEP", "OPPOSITE"]

#: (row, column) step to the neighbour across each edge, in ``EDGE_NAMES`` order (W, S, E, N).
EDGE_STEP = ((0, -1), (-1, 0), (0, 1), (1, 0))
#: The edge of the neighbour that faces each edge: W <-> E, S <-> N.
OPPOSITE = (2, 3, 0, 1)
#: The two children (row, column offsets) along each edge of a node, W, S, E, N.
_CHILDREN_ON_EDGE = (((0, 0), (1, 0)), ((0, 0), (0, 1)), ((0, 1), (1, 1)), ((1, 0), (1, 1)))
# Slack against rounding on the bound's angles, deg: far above the float error, far below a level.
_ANGLE_SLACK_DEG = 1e-6


@dataclass(frozen=True)
class NodeSelection:
    """The nodes one frame draws (culled nodes dropped).

    Attributes
    ----------
    depth : (m,) int32
        Each node's depth (0: the whole grid; ``tree.depth``: a patch of ``P`` samples).
    row, col : (m,) int32
        Its index at its depth (row 0 south).
    origin : (m, 2) int32
        Its south-west sample (column, row).
    size : (m,) int32
        Its side, sample spacings.
    inner : (m,) int32
        Inner tessellation factor, a power of two in ``[1, min(size, max_tess_level)]``.
    outer : (m, 4) int32
        Outer factors W, S, E, N.
    evaluated : int
        Nodes whose need was evaluated this frame (the walk's cost).
    capped : int
        Edges or nodes given less than their need because a factor hit ``max_tess_level``
        (0 unless ``split_factor`` is at the limit; a diagnostic).
    """

    depth: np.ndarray
    row: np.ndarray
    col: np.ndarray
    origin: np.ndarray
    size: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    evaluated: int = 0
    capped: int = 0

    def __len__(self) -> int:
        return len(self.size)

    def records(self) -> np.ndarray:
        """(m, 8) int32 rows ``column, row, size, inner, W, S, E, N``: the GPU's node records."""
        return np.column_stack([self.origin, self.size, self.inner, self.outer]).astype(np.int32)

    def vertex_bound(self) -> np.ndarray:
        """(m,) int64 upper bound on the vertices each node's tessellation generates."""
        return (self.inner.astype(np.int64) + 1) ** 2 + (self.outer.astype(np.int64) + 1).sum(axis=1)


def _halve(a: np.ndarray, fn) -> np.ndarray:
    """(h/2, w/2) reduction ``fn`` (np.max/np.min) over 2x2 blocks of (h, w)."""
    h, w = a.shape
    return fn(a.reshape(h // 2, 2, w // 2, 2), axis=(1, 3))


def _cross_max(a: np.ndarray) -> np.ndarray:
    """Max over each cell and its four edge neighbours (the border repeated)."""
    p = np.pad(a, 1, mode="edge")
    return np.maximum.reduce([p[1:-1, 1:-1], p[1:-1, :-2], p[1:-1, 2:], p[:-2, 1:-1], p[2:, 1:-1]])


def _angle_deg(u, v):
    """Angle between unit vectors (..., 3), deg, from their chord."""
    return np.degrees(2 * np.arcsin(np.minimum(np.linalg.norm(u - v, axis=-1) / 2, 1.0)))


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class PatchTree:
    """Per-depth bounds of a quadtree over a :class:`PatchGrid`'s patches, and the per-frame selection.

    Parameters
    ----------
    grid : PatchGrid
        Its patches per side ``n`` must be a power of two.
    split_factor : int
        Largest tessellation factor (segments per side) a node above the
        leaves is drawn with; a node that needs more is split (a power of
        two, 1..max_tess_level). Smaller: more, smaller nodes, closer to the
        per-leaf levels; larger: fewer nodes, each at its worst leaf's level.
    max_tess_level : int
        Largest factor GL is given (a power of two; GL guarantees 64).

    Attributes
    ----------
    depth : int
        D = log2(n): leaves (patches of ``P`` samples) are at depth D.
    z_min_m, z_max_m : list of (2^d, 2^d) float64
        Per depth d, each node's height range, metres.
    contrast_near : list of (2^d, 2^d) float64
        Per depth, the highest contrast of the node's leaves and of its four edge neighbours' leaves.
    leaf_z_range_m : list of (2^d, 2^d) float64
        Per depth, the largest height range of one leaf below the node, metres.
    """

    def __init__(self, grid: PatchGrid, split_factor: int = 16, max_tess_level: int = 64):
        n = grid.n_patches
        if n < 1 or n & (n - 1):
            raise ValueError(f"PatchTree: the grid's patches per side must be a power of two, got {n} "
                             f"(N - 1 = {grid.heights_m.shape[0] - 1} samples, patches of {grid.patch_samples})")
        for name, v in (("split_factor", split_factor), ("max_tess_level", max_tess_level)):
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1 or v & (v - 1):
                raise ValueError(f"PatchTree: {name} must be a power of two >= 1, got {v!r}")
        if split_factor > max_tess_level:
            raise ValueError(f"PatchTree: split_factor ({split_factor}) must be <= max_tess_level ({max_tess_level})")
        self.grid, self.split_factor, self.max_tess_level = grid, int(split_factor), int(max_tess_level)
        self.depth = int(round(math.log2(n)))
        self.leaf_max_level = max_level_for(grid.patch_samples, max_tess_level)
        zmin, zmax = [grid.z_min_m.astype(np.float64)], [grid.z_max_m.astype(np.float64)]
        contrast, zr = [grid.contrast.astype(np.float64)], [zmax[0] - zmin[0]]
        for _ in range(self.depth):
            zmin.insert(0, _halve(zmin[0], np.min))
            zmax.insert(0, _halve(zmax[0], np.max))
            contrast.insert(0, _halve(contrast[0], np.max))
            zr.insert(0, _halve(zr[0], np.max))
        self.z_min_m, self.z_max_m, self.leaf_z_range_m = zmin, zmax, zr
        self.contrast_near = [_cross_max(c) for c in contrast]
        padded = np.pad(grid.contrast.astype(np.float64), 1, mode="edge")
        self._leaf_neighbour_contrast = np.stack([padded[1:-1, :-2], padded[:-2, 1:-1], padded[1:-1, 2:],
                                                  padded[2:, 1:-1]], axis=-1)                 # (n, n, 4) W S E N
        self._sup_table = None

    # -- per-frame constants ---------------------------------------------------

    def _frame(self, model, eye_mm, axes, cov_deg2, mvp, region_ndc, shift, ellipse_sigma, level_bias, speed_deg_s,
               eye_prev_mm, dt_s, cull):
        model = np.asarray(model, np.float64)
        eye = np.asarray(eye_mm, np.float64)
        sv = np.linalg.svd(model[:3, :3], compute_uv=False)
        eye_scene = np.linalg.solve(model, np.r_[eye, 1.0])[:3]
        # Largest displacement of an offset (φ, θ) by the uncertainty shift, deg: the ellipse form moves
        # it by ellipse_sigma Mahalanobis units, eq. 1 by at most e^-1/2 of one.
        reach = 0.0
        if cov_deg2 is not None and np.any(np.asarray(cov_deg2) != 0):
            lam = float(np.linalg.eigvalsh(0.5 * (np.asarray(cov_deg2, float) + np.asarray(cov_deg2, float).T)).max())
            reach = (ellipse_sigma if shift == "ellipse" else math.exp(-0.5)) * math.sqrt(max(lam, 0.0))
        moving = eye_prev_mm is not None and dt_s > 0
        return dict(model=model, eye=eye, axes=np.asarray(axes, np.float64), cov=cov_deg2, shift=shift,
                    sigma=ellipse_sigma, bias=float(level_bias), speed=speed_deg_s, eye_prev=eye_prev_mm,
                    dt=float(dt_s), moving=moving, s_min=float(sv.min()), s_max=float(sv.max()),
                    eye_scene=eye_scene, shift_reach=reach, cull=bool(cull) and mvp is not None,
                    mvp=None if mvp is None else np.asarray(mvp, np.float64),
                    region=None if region_ndc is None else np.asarray(region_ndc, np.float64))

    def _fmax_bound(self, contrast, ecc_deg, f):
        """f_max bound, cpd: at the frame's speed when still; the sup over every speed when the eye moves."""
        if not f["moving"]:
            return pc.max_visible_freq_cpd(contrast, f["speed"], ecc_deg, model="kelly_scaled")
        if self._sup_table is None:
            from .quadtree import sup_max_visible_freq_cpd
            grid = np.concatenate([[0.0], np.logspace(-4, 0, 801)])
            self._sup_table = (grid, sup_max_visible_freq_cpd(grid, "kelly_scaled"))
        grid, sup = self._sup_table
        k = np.minimum(np.searchsorted(grid, contrast, side="left"), len(grid) - 1)     # the grid point at or above
        return sup[k] / pc.eccentricity_factor(ecc_deg)

    # -- node evaluation -------------------------------------------------------

    def _boxes(self, d, rows, cols):
        """(m, 8, 3) scene corners of the nodes' boxes (x fastest, then y, then z)."""
        g = self.grid
        s = g.patch_samples << (self.depth - d)
        x0 = g.origin_m[0] + cols * (s * g.dx_m)
        y0 = g.origin_m[1] + rows * (s * g.dy_m)
        lo = np.stack([x0, y0, self.z_min_m[d][rows, cols]], axis=-1)
        hi = np.stack([x0 + s * g.dx_m, y0 + s * g.dy_m, self.z_max_m[d][rows, cols]], axis=-1)
        k = np.arange(8)
        pick = np.stack([(k & 1) > 0, (k & 2) > 0, (k & 4) > 0], axis=-1)          # (8, 3)
        return np.where(pick[None], hi[:, None, :], lo[:, None, :]), lo, hi

    @staticmethod
    def _culled(corners, f):
        """(m,) bool: boxes wholly outside one frustum plane, or (all in front) missing the NDC region.

        The shader's ``outside`` test of the flat path."""
        m = len(corners)
        if not f["cull"] or m == 0:
            return np.zeros(m, bool)
        c = np.concatenate([corners, np.ones(corners.shape[:-1] + (1,))], axis=-1) @ f["mvp"].T     # (m, 8, 4)
        w = c[..., 3]
        out = np.zeros(m, bool)
        for axis in range(3):
            out |= np.all(c[..., axis] < -w, axis=1) | np.all(c[..., axis] > w, axis=1)
        if f["region"] is not None:
            front = np.all(w > 0, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                ndc = c[..., :2] / w[..., None]
            mn, mx = ndc.min(axis=1), ndc.max(axis=1)
            r = f["region"]
            miss = (mx[:, 0] < r[0]) | (mn[:, 0] > r[2]) | (mx[:, 1] < r[1]) | (mn[:, 1] > r[3])
            out |= front & miss
        return out

    def node_level_bound(self, d, rows, cols, f):
        """(m,) upper bound on the continuous CSF level of every leaf patch and leaf edge below nodes at depth d.

        ``f``: the frame's constants (:meth:`_frame`). See the module notes for the bound.
        """
        g = self.grid
        corners, lo, hi = self._boxes(d, rows, cols)
        w = (np.concatenate([corners, np.ones(corners.shape[:-1] + (1,))], axis=-1) @ f["model"].T)[..., :3]
        eye = f["eye"]
        centre = 0.5 * (w[:, 0] + w[:, 7])                       # the box's centre (affine map of its centre)
        cdir = _unit(centre - eye)
        reach = _angle_deg(cdir[:, None, :], _unit(w - eye)).max(axis=1)
        ecc_c = _angle_deg(cdir, f["axes"][2])
        # Nearest point of the box to the eye (scene frame), then world distance >= s_min x scene distance.
        gap = np.maximum(np.maximum(lo - f["eye_scene"], f["eye_scene"] - hi), 0.0)
        r_min = f["s_min"] * np.linalg.norm(gap, axis=-1)
        p = g.patch_samples
        chord = f["s_max"] * np.sqrt((p * g.dx_m) ** 2 + (p * g.dy_m) ** 2 + self.leaf_z_range_m[d][rows, cols] ** 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            diam = np.where(r_min > chord / 2, np.degrees(2 * np.arcsin(np.minimum(chord / (2 * r_min), 1.0))), 180.0)
        ecc = np.maximum(ecc_c - reach - f["shift_reach"] - diam - _ANGLE_SLACK_DEG, 0.0)
        fmax = self._fmax_bound(self.contrast_near[d][rows, cols], ecc, f)
        with np.errstate(divide="ignore"):
            return np.log2(fmax) + np.log2(diam + _ANGLE_SLACK_DEG) + f["bias"], corners

    def _leaf_levels(self, rows, cols, f):
        """Exact (flat) continuous levels of leaves: inner (m,), outer (m, 4) (:func:`levels_of_patches`)."""
        g, p = self.grid, self.grid.patch_samples
        z = g.heights_m
        r0, c0 = rows * p, cols * p
        zc = np.stack([z[r0, c0], z[r0, c0 + p], z[r0 + p, c0 + p], z[r0 + p, c0]], axis=-1).astype(np.float64)
        xs = g.origin_m[0] + np.stack([c0, c0 + p, c0 + p, c0], axis=-1) * g.dx_m
        ys = g.origin_m[1] + np.stack([r0, r0, r0 + p, r0 + p], axis=-1) * g.dy_m
        corners = np.stack([xs, ys, zc], axis=-1)                                        # (m, 4, 3) SW SE NE NW
        return levels_of_patches(corners, g.contrast[rows, cols], self._leaf_neighbour_contrast[rows, cols],
                                 f["model"], f["eye"], f["axes"], f["cov"], shift=f["shift"],
                                 ellipse_sigma=f["sigma"], speed_deg_s=f["speed"], level_bias=f["bias"],
                                 eye_prev_mm=f["eye_prev"], dt_s=f["dt"])

    def _evaluate(self, d, rows, cols, f, st):
        """Fill the frame's per-depth state for nodes (d, rows, cols): need exponent, culled; leaves' factors."""
        D = self.depth
        st["evaluated"] += len(rows)
        s = self.grid.patch_samples << (D - d)
        if d == D:
            corners, _, _ = self._boxes(d, rows, cols)
            culled = self._culled(corners, f)
            st["culled"][d][rows, cols] = culled
            live = ~culled
            r, c = rows[live], cols[live]
            inner, outer = self._leaf_levels(r, c, f)
            fi, fo = tess_factors(inner, self.leaf_max_level), tess_factors(outer, self.leaf_max_level)
            st["need"][d][r, c] = np.log2(fi).astype(np.int32)
            st["edge"][d][r, c] = fo
            return np.zeros(len(rows), bool), np.zeros(len(rows), bool)
        level, corners = self.node_level_bound(d, rows, cols, f)
        culled = self._culled(corners, f)
        st["culled"][d][rows, cols] = culled
        x = np.nan_to_num(level, nan=-1e3, posinf=float(self.leaf_max_level), neginf=-1e3)
        k = np.ceil(np.minimum(x, self.leaf_max_level)).astype(np.int64) + (D - d)     # log2 of the factor it needs
        top = int(math.log2(min(s, self.max_tess_level)))
        split = ~culled & (k > min(int(math.log2(self.split_factor)), top))
        e = np.clip(k, 0, top)
        st["need"][d][rows, cols] = e
        st["edge"][d][rows, cols] = (1 << e)[:, None]
        return split, ~culled & (k > top)

    # -- the frame -------------------------------------------------------------

    def select(self, model, eye_mm, axes, cov_deg2=None, *, mvp=None, region_ndc=None, cull: bool = True,
               shift: str = "ellipse", ellipse_sigma: float = 2.0, level_bias: float = 0.0,
               speed_deg_s: float = pc.MIN_SPEED_DEG_S, eye_prev_mm=None, dt_s: float = 0.0) -> NodeSelection:
        """The nodes to draw this frame, with their factors (module notes).

        Parameters
        ----------
        model : (4, 4)
            ``T_world_scene`` (scene m → world mm).
        eye_mm : (3,)
            Eye, world frame, mm.
        axes : (3, 3)
            Rows Ξ, Ψ, V of the head frame.
        cov_deg2 : (2, 2) or None
            Covariance of the viewing direction, deg².
        mvp : (4, 4) or None
            ``T_clip_scene`` for culling; None: nothing is culled.
        region_ndc : (4,) or None
            Only boxes reaching this NDC rectangle (x0, y0, x1, y1) are drawn.
        cull : bool
            Cull by the frustum (with ``mvp``).
        shift, ellipse_sigma, level_bias, speed_deg_s
            As :func:`headplod.plod.patches.patch_levels`.
        eye_prev_mm : (3,) or None; dt_s : float
            The last frame's eye (world mm) and the time since (s): leaves take each point's angular
            speed (the shader's rule), nodes above them the highest f_max over every speed.
        """
        f = self._frame(model, eye_mm, axes, cov_deg2, mvp, region_ndc, shift, ellipse_sigma, level_bias,
                        speed_deg_s, eye_prev_mm, dt_s, cull)
        D = self.depth
        sizes = [1 << d for d in range(D + 1)]
        st = {"need": [np.zeros((m, m), np.int32) for m in sizes],
              "edge": [np.ones((m, m, 4), np.int64) for m in sizes],
              "culled": [np.zeros((m, m), bool) for m in sizes],
              "evaluated": 0, "capped": 0}
        refined = [np.zeros((m, m), bool) for m in sizes]
        done = [np.zeros((m, m), bool) for m in sizes]
        quad_r, quad_c = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1])
        rows, cols = np.zeros(1, np.int64), np.zeros(1, np.int64)
        # 1. the walk, one depth at a time over the frontier.
        for d in range(D + 1):
            if not len(rows):
                break
            split, _ = self._evaluate(d, rows, cols, f, st)
            done[d][rows, cols] = True
            refined[d][rows[split], cols[split]] = True
            rows = (2 * rows[split][:, None] + quad_r).ravel()
            cols = (2 * cols[split][:, None] + quad_c).ravel()
        # 2. 2:1 balance, bottom-up: a split node's edge neighbours' parents are split.
        for d in range(D - 1, 0, -1):
            r = refined[d]
            if not r.any():
                continue
            grown = r.copy()
            grown[1:] |= r[:-1]
            grown[:-1] |= r[1:]
            grown[:, 1:] |= r[:, :-1]
            grown[:, :-1] |= r[:, 1:]
            refined[d - 1] |= _halve(grown, np.max)
        drawn = [~refined[0]]
        for d in range(1, D + 1):
            drawn.append(np.repeat(np.repeat(refined[d - 1], 2, axis=0), 2, axis=1) & ~refined[d])
        for d in range(D + 1):            # nodes the balance added
            r, c = np.nonzero(drawn[d] & ~done[d])
            if len(r):
                st["capped"] += int(np.count_nonzero(self._evaluate(d, r, c, f, st)[1]))
        # 3. the drawn nodes' factors.
        out = {k: [] for k in ("depth", "row", "col", "origin", "size", "inner", "outer")}
        capped = st["capped"]
        p = self.grid.patch_samples
        for d in range(D + 1):
            r, c = np.nonzero(drawn[d] & ~st["culled"][d])
            if not len(r):
                continue
            s = p << (D - d)
            m = sizes[d]
            edge = st["edge"][d]
            own = edge[r, c]                                                        # (k, 4)
            outer = own.copy()
            for e, (dr, dc) in enumerate(EDGE_STEP):
                opp = OPPOSITE[e]
                nr, nc = r + dr, c + dc
                inside = (nr >= 0) & (nr < m) & (nc >= 0) & (nc < m)
                nr_, nc_ = np.clip(nr, 0, m - 1), np.clip(nc, 0, m - 1)
                same = inside & drawn[d][nr_, nc_]
                outer[same, e] = np.maximum(own[same, e], edge[nr_[same], nc_[same], opp])
                big = inside & refined[d][nr_, nc_]            # beside two nodes of half the size
                if big.any():
                    (a0, b0), (a1, b1) = _CHILDREN_ON_EDGE[opp]
                    ch = st["edge"][d + 1]
                    want = np.maximum.reduce([own[big, e], 2 * ch[2 * nr_[big] + a0, 2 * nc_[big] + b0, opp],
                                              2 * ch[2 * nr_[big] + a1, 2 * nc_[big] + b1, opp]])
                    lim = min(s, self.max_tess_level)
                    capped += int(np.count_nonzero(want > lim))
                    outer[big, e] = np.clip(want, 2, lim)
                small = inside & ~drawn[d][nr_, nc_] & ~refined[d][nr_, nc_]   # beside half a node twice the size
                if small.any():
                    (a0, b0), (a1, b1) = _CHILDREN_ON_EDGE[e]
                    pr, pc_ = r[small] // 2, c[small] // 2
                    want = np.maximum.reduce([st["edge"][d - 1][nr_[small] // 2, nc_[small] // 2, opp],
                                              2 * edge[2 * pr + a0, 2 * pc_ + b0, e],
                                              2 * edge[2 * pr + a1, 2 * pc_ + b1, e]])
                    outer[small, e] = np.clip(want, 2, min(2 * s, self.max_tess_level)) // 2
            out["depth"].append(np.full(len(r), d, np.int32))
            out["row"].append(r.astype(np.int32))
            out["col"].append(c.astype(np.int32))
            out["origin"].append(np.stack([c * s, r * s], axis=-1).astype(np.int32))
            out["size"].append(np.full(len(r), s, np.int32))
            out["inner"].append((1 << st["need"][d][r, c]).astype(np.int32))
            out["outer"].append(outer.astype(np.int32))
        if not out["size"]:
            z = np.zeros(0, np.int32)
            return NodeSelection(z, z, z, np.zeros((0, 2), np.int32), z, z, np.zeros((0, 4), np.int32),
                                 st["evaluated"], capped)
        cat = {k: np.concatenate(v) for k, v in out.items()}
        return NodeSelection(cat["depth"], cat["row"], cat["col"], cat["origin"], cat["size"], cat["inner"],
                             cat["outer"], st["evaluated"], capped)
