"""A quadtree over a :class:`PatchGrid`'s patches: variable-size tessellation patches, refined where the CSF needs it.

The flat tessellation back end evaluates the CSF on every patch of ``P``
samples on every frame and draws every patch in view: its selection grows
with the terrain (16384 patches at 8193² samples). Here the patches are the
leaves of a quadtree whose node at depth ``d`` is a square of
``S = P 2^(D-d)`` samples (``D = log2(n)``, ``n`` patches per side, a power
of two; the root, depth 0, is the whole grid). Per frame
(:meth:`PatchTree.select`):

1. **Walk** the tree top-down with numpy over the whole frontier (no loop
   over nodes): the frontier and its descendants down to ``batch_depths``
   depths are evaluated in one pass, then the splits are resolved top-down
   (a few wasted evaluations for fewer numpy passes: the passes' fixed cost,
   not the nodes, is most of the walk). For each node:

   - its box (the samples' x, y; the node's height range) is culled when its
     circumscribed sphere is wholly outside one frustum plane;
   - its *need*: ``L_ub``, an upper bound on the continuous CSF level
     (:func:`headplod.plod.patches.patch_levels`' closed form) of every leaf
     patch and leaf edge below it: the node's highest contrast, the smallest
     eccentricity over its box (the angle of the box's centre from the view
     axis, less the angle its sphere subtends, less the uncertainty shift's
     largest reach, less the largest leaf diameter), and the largest angular
     diameter a leaf below it can have (its corner-to-corner chord with the
     largest leaf height range below the node, seen from the box's nearest
     point). A leaf of level ``L`` asks for a vertex every ``P 2^-L``
     samples; the node gets the whole-number factor ``F = ceil(S / g)``,
     ``g`` that gap rounded down to whole samples, so every gap between its
     vertices (each rounded to a sample) is at most ``g``. Factors are not
     restricted to powers of two (GL's ``equal_spacing`` takes any integer):
     a power of two would round the bound up to 2x per side.
   - If ``F`` exceeds ``split_factor`` (or ``min(S, max_tess_level)``), the
     node is split and its children join the frontier.

   Leaves (``S = P``) get the flat path's exact levels and factors
   (:func:`levels_of_patches` and :func:`tess_factors`, the same code as the flat twin).
   The cost is that of the nodes in view along the refined paths.
2. **Balance** the tree 2:1 (neighbours across an edge differ by at most one
   depth), bottom-up: a split node forces the split of its edge neighbours'
   parents. Nodes this adds are evaluated as in step 1.
3. **Edge factors**, crack-free by construction:

   - between two leaves, the flat path's edge factor (from the edge alone:
     both sides compute the same number);
   - between two nodes of the same size above the leaves, the larger of
     their factors (both sides take the same max);
   - on a transition edge (a node of ``S`` samples beside two of ``S/2``):
     ``F = max(big's need, 2 x each small's need on that edge)`` rounded up
     to even and clamped to ``[2, min(S, max_tess_level)]`` on the big side,
     ``F / 2`` on each small side: with ``equal_spacing`` the big edge's
     vertex ``k`` is at ``round(k S / F)`` samples and the small edges' at
     the same samples (the big edge's midpoint, the small nodes' shared
     corner, is its vertex ``F / 2``); ``S / F`` is never a half-integer
     tie when ``S`` is a power of two and ``F <= S``.

   Every vertex is rounded to the sample grid, so shared vertices are identical.

The output (:class:`NodeSelection`) is the drawn (unculled) nodes: origin
sample, size in samples, inner factor and the four outer factors (W, S, E, N
as ``gl_TessLevelOuter``). The bound makes a node conservative: every leaf
patch below a drawn node, and every leaf edge along its border, gets at least
the vertex density its continuous level asks for (``tests/test_patch_tree.py``,
random views). With the eye moving, nodes above the leaves take the highest
f_max over every speed (:func:`headplod.plod.quadtree.sup_max_visible_freq_cpd`);
leaves the shader's per-point speed. Pure numpy; the GL side is
:mod:`headplod.render.tessellate` (``TessellationConfig.hierarchy``).

The price of merging: a node shows all its leaves at its worst leaf's need
(bounded, ~0.2 levels above the true worst on the scale bench's view), so it
draws more triangles than the flat per-patch levels would there; a smaller
``split_factor`` trades those triangles for more nodes to evaluate and draw.
A cost rule was tried and not kept: also splitting a node whose four
children's bounds would draw 16 or more fewer triangles (one more depth
evaluated per pass) gave 149k triangles instead of 174k at 134M, still above
the flat path's 109k (both with whole-number factors), for 2.3x the
selection (9.8 against 4.2 ms).

Not here (yet): hysteresis (per-node state), as in the flat path.
Frames: grid frame as :mod:`headplod.plod.patches` (row 0 south, column 0 west);
node ``(d, row, col)`` covers samples ``row S .. (row + 1) S`` by ``col S .. (col + 1) S``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import perception as pc
from .patches import FACTOR_RULES, PatchGrid, levels_of_patches, max_level_for, tess_factors, vertex_gap_samples

__all__ = ["PatchTree", "NodeSelection", "EDGE_STEP", "OPPOSITE"]

#: (row, column) step to the neighbour across each edge, in ``EDGE_NAMES`` order (W, S, E, N).
EDGE_STEP = ((0, -1), (-1, 0), (0, 1), (1, 0))
#: The edge of the neighbour that faces each edge: W <-> E, S <-> N.
OPPOSITE = (2, 3, 0, 1)
#: The two children (row, column offsets) along each edge of a node, W, S, E, N.
_CHILDREN_ON_EDGE = (((0, 0), (1, 0)), ((0, 0), (0, 1)), ((0, 1), (1, 1)), ((1, 0), (1, 1)))
# Slack against rounding on the bound's angles, deg: far above the float error, far below a level.
_ANGLE_SLACK_DEG = 1e-6
#: The 8 corners of a box as fractions of its extent (x fastest, then y, then z).
_BOX_CORNERS = np.array([[(k & 1) > 0, (k & 2) > 0, (k & 4) > 0] for k in range(8)], np.float64)


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
        Inner tessellation factor in ``[1, min(size, max_tess_level)]``: a leaf's is the flat path's (a power
        of two), a larger node's any whole number.
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


class PatchTree:
    """Per-node bounds of a quadtree over a :class:`PatchGrid`'s patches, and the per-frame selection.

    Nodes of every depth share one index: node ``(d, row, col)`` is
    ``offset[d] + row 2^d + col`` with ``offset[d] = (4^d - 1) / 3``, so a
    frontier spanning several depths is one numpy array.

    Parameters
    ----------
    grid : PatchGrid
        Its patches per side ``n`` must be a power of two.
    split_factor : int
        Largest tessellation factor (segments per side) a node above the
        leaves is drawn with; a node that needs more is split (1..max_tess_level).
        Smaller: more, smaller nodes, closer to the per-leaf levels (fewer
        triangles, more nodes to evaluate and draw); larger: fewer nodes,
        each at its worst leaf's level.
    max_tess_level : int
        Largest factor GL is given (a power of two; GL guarantees 64).
    factors : {"whole", "power_of_two"}
        The leaves' rule from level to factor (:func:`tess_factors`; the flat path's
        ``TessellationConfig.factors``). Nodes above the leaves always take whole numbers.
    batch_depths : int
        Depths evaluated per numpy pass of the walk (a node's descendants down to this many depths are
        evaluated together, whether or not the node splits): fewer passes, a few wasted evaluations.

    Attributes
    ----------
    depth : int
        D = log2(n): leaves (patches of ``P`` samples) are at depth D.
    offset : (D + 2,) int64
        First index of each depth's nodes.
    node_depth, node_row, node_col, node_size : (total,) int64
        Each node's depth, row, column and side (samples).
    box_lo_m, box_hi_m : (total, 3) float64
        Each node's box, scene frame, metres: its samples' x, y and its height range.
    contrast : (total,) float64
        Each node's highest leaf contrast.
    leaf_chord_m : (total,) float64
        The longest corner-to-corner distance a leaf below the node can have, scene metres
        (its diagonal with the largest height range of a leaf below the node).
    """

    def __init__(self, grid: PatchGrid, split_factor: int = 16, max_tess_level: int = 64, batch_depths: int = 2,
                 factors: str = "whole"):
        n = grid.n_patches
        if n < 1 or n & (n - 1):
            raise ValueError(f"PatchTree: the grid's patches per side must be a power of two, got {n} "
                             f"(N - 1 = {grid.heights_m.shape[0] - 1} samples, patches of {grid.patch_samples})")
        if not isinstance(split_factor, (int, np.integer)) or isinstance(split_factor, bool) or split_factor < 1:
            raise ValueError(f"PatchTree: split_factor must be an int >= 1, got {split_factor!r}")
        if (not isinstance(max_tess_level, (int, np.integer)) or isinstance(max_tess_level, bool)
                or max_tess_level < 2 or max_tess_level & (max_tess_level - 1)):
            raise ValueError(f"PatchTree: max_tess_level must be a power of two >= 2, got {max_tess_level!r}")
        if split_factor > max_tess_level:
            raise ValueError(f"PatchTree: split_factor ({split_factor}) must be <= max_tess_level ({max_tess_level})")
        if factors not in FACTOR_RULES:
            raise ValueError(f"PatchTree: factors must be one of {FACTOR_RULES}, got {factors!r}")
        self.factors = factors
        if int(batch_depths) < 1:
            raise ValueError(f"PatchTree: batch_depths must be >= 1, got {batch_depths!r}")
        self.grid, self.split_factor, self.max_tess_level = grid, int(split_factor), int(max_tess_level)
        self.batch_depths = int(batch_depths)
        D = self.depth = int(round(math.log2(n)))
        self.leaf_max_level = max_level_for(grid.patch_samples, max_tess_level)
        p = grid.patch_samples
        zmin, zmax = [grid.z_min_m.astype(np.float64)], [grid.z_max_m.astype(np.float64)]
        contrast, zr = [grid.contrast.astype(np.float64)], [zmax[0] - zmin[0]]
        for _ in range(D):
            zmin.insert(0, _halve(zmin[0], np.min))
            zmax.insert(0, _halve(zmax[0], np.max))
            contrast.insert(0, _halve(contrast[0], np.max))
            zr.insert(0, _halve(zr[0], np.max))
        self.offset = np.array([(4 ** d - 1) // 3 for d in range(D + 2)], np.int64)
        depth = np.concatenate([np.full(4 ** d, d, np.int64) for d in range(D + 1)])
        local = np.arange(len(depth)) - self.offset[depth]
        self.node_depth, self.node_row, self.node_col = depth, local >> depth, local & ((1 << depth) - 1)
        self.node_size = p << (D - depth)
        self.node_top = np.minimum(self.node_size, self.max_tess_level)           # largest factor of each node
        x0 = grid.origin_m[0] + self.node_col * self.node_size * grid.dx_m
        y0 = grid.origin_m[1] + self.node_row * self.node_size * grid.dy_m
        lo_z, hi_z = np.concatenate([z.ravel() for z in zmin]), np.concatenate([z.ravel() for z in zmax])
        self.box_lo_m = np.stack([x0, y0, lo_z], axis=-1)
        self.box_hi_m = np.stack([x0 + self.node_size * grid.dx_m, y0 + self.node_size * grid.dy_m, hi_z], axis=-1)
        self.box_radius_m = 0.5 * np.linalg.norm(self.box_hi_m - self.box_lo_m, axis=-1)
        self.contrast = np.concatenate([c.ravel() for c in contrast])
        self.leaf_chord_m = np.sqrt((p * grid.dx_m) ** 2 + (p * grid.dy_m) ** 2
                                    + np.concatenate([z.ravel() for z in zr]) ** 2)
        self._leaf_neighbour_contrast = grid.neighbour_contrast()                          # (n, n, 4) W S E N
        # Foveal f_max at the speed floor (a still eye), cpd, once: of each node's highest contrast, and of each
        # leaf's inner piece and edges (the contrasts levels_of_patches gives them).
        v0 = pc.MIN_SPEED_DEG_S
        self._node_f0 = pc.max_visible_freq_cpd(self.contrast, v0, 0.0, model="kelly_scaled")
        leaf_c = grid.contrast.astype(np.float64)[..., None]
        self._leaf_f0 = pc.max_visible_freq_cpd(
            np.concatenate([leaf_c, np.maximum(leaf_c, self._leaf_neighbour_contrast)], axis=-1), v0, 0.0,
            model="kelly_scaled")                                                          # (n, n, 5)
        self._sup_table = None

    @property
    def n_nodes(self) -> int:
        """Nodes of every depth."""
        return int(self.offset[-1])

    def node_id(self, depth, row, col) -> np.ndarray:
        """Index of nodes (depth, row, col) (arrays broadcast)."""
        depth = np.asarray(depth, np.int64)
        return self.offset[depth] + (np.asarray(row, np.int64) << depth) + np.asarray(col, np.int64)

    def _children(self, ids) -> np.ndarray:
        """(4 m,) the children of nodes ``ids`` (not leaves), in (row, col) order per parent."""
        d = self.node_depth[ids] + 1
        r, c = 2 * self.node_row[ids], 2 * self.node_col[ids]
        base = self.offset[d] + (r << d) + c
        return (base[:, None] + np.stack([np.zeros_like(d), np.ones_like(d), 1 << d, (1 << d) + 1], axis=-1)).ravel()

    # -- per-frame constants ---------------------------------------------------

    def _frame(self, model, eye_mm, axes, cov_deg2, mvp, region_ndc, shift, ellipse_sigma, level_bias, speed_deg_s,
               eye_prev_mm, dt_s, cull):
        model = np.asarray(model, np.float64)
        eye = np.asarray(eye_mm, np.float64)
        sv = np.linalg.svd(model[:3, :3], compute_uv=False)
        eye_scene = np.linalg.solve(model[:3, :3], eye - model[:3, 3])
        # Largest displacement of an offset (φ, θ) by the uncertainty shift, deg: the ellipse form moves
        # it by ellipse_sigma Mahalanobis units, eq. 1 by at most e^-1/2 of one.
        reach = 0.0
        if cov_deg2 is not None and np.any(np.asarray(cov_deg2) != 0):
            cov = np.asarray(cov_deg2, float)
            lam = float(np.linalg.eigvalsh(0.5 * (cov + cov.T)).max())
            reach = (ellipse_sigma if shift == "ellipse" else math.exp(-0.5)) * math.sqrt(max(lam, 0.0))
        # A still eye (the same position, or no last frame): every speed is the floor, as the shader's rule gives.
        moving = eye_prev_mm is not None and dt_s > 0 and bool(np.any(np.asarray(eye_prev_mm, np.float64) != eye))
        planes = None
        if mvp is not None:        # the frustum's planes (a, b, c, d), scene frame, a x + b y + c z + d >= 0 inside
            m4 = np.asarray(mvp, np.float64)
            planes = np.stack([m4[3] + m4[0], m4[3] - m4[0], m4[3] + m4[1], m4[3] - m4[1], m4[3] + m4[2],
                               m4[3] - m4[2]])
            planes /= np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
        return dict(planes=planes, model=model, eye=eye, axes=np.asarray(axes, np.float64), cov=cov_deg2, shift=shift,
                    sigma=ellipse_sigma, bias=float(level_bias), speed=speed_deg_s, eye_prev=eye_prev_mm,
                    dt=float(dt_s), moving=moving, s_min=float(sv.min()), s_max=float(sv.max()),
                    eye_scene=eye_scene, shift_reach=reach, cull=bool(cull) and mvp is not None,
                    mvp=None if mvp is None else np.asarray(mvp, np.float64),
                    region=None if region_ndc is None else np.asarray(region_ndc, np.float64))

    def _fmax_bound(self, ids, ecc_deg, f):
        """f_max bound of nodes, cpd: at the frame's speed when still; the sup over every speed when the eye moves."""
        if not f["moving"]:
            if f["speed"] == pc.MIN_SPEED_DEG_S:
                return self._node_f0[ids] / pc.eccentricity_factor(ecc_deg)
            return pc.max_visible_freq_cpd(self.contrast[ids], f["speed"], ecc_deg, model="kelly_scaled")
        if self._sup_table is None:
            from .quadtree import sup_max_visible_freq_cpd
            grid = np.concatenate([[0.0], np.logspace(-4, 0, 801)])
            self._sup_table = (grid, sup_max_visible_freq_cpd(grid, "kelly_scaled"))
        grid, sup = self._sup_table
        k = np.minimum(np.searchsorted(grid, self.contrast[ids], side="left"), len(grid) - 1)   # grid point >= C
        return sup[k] / pc.eccentricity_factor(ecc_deg)

    # -- node evaluation -------------------------------------------------------

    def _culled(self, corners, f):
        """(m,) bool: boxes (m, 8, 3) wholly outside one frustum plane, or (all in front) missing the NDC region.

        The flat path's shader test (``outside``)."""
        m = len(corners)
        if not f["cull"] or m == 0:
            return np.zeros(m, bool)
        mvp = f["mvp"]
        c = corners @ mvp[:, :3].T + mvp[:, 3]                                       # (m, 8, 4)
        w = c[..., 3:]
        out = ((c[..., :3] < -w).all(axis=1) | (c[..., :3] > w).all(axis=1)).any(axis=1)
        if f["region"] is not None:
            front = np.all(w[..., 0] > 0, axis=1)
            with np.errstate(divide="ignore", invalid="ignore"):
                ndc = c[..., :2] / w
            mn, mx = ndc.min(axis=1), ndc.max(axis=1)
            r = f["region"]
            miss = (mx[:, 0] < r[0]) | (mn[:, 0] > r[2]) | (mx[:, 1] < r[1]) | (mn[:, 1] > r[3])
            out |= front & miss
        return out

    def node_level_bound(self, ids, f):
        """Nodes' bounds: (level (m,), culled (m,) bool).

        ``level``: an upper bound on the continuous CSF level of every leaf patch and leaf edge below each
        node (module notes); ``f``: the frame's constants (:meth:`_frame`). The box is bounded by its
        circumscribed sphere for the reach and the frustum test (cheaper than its 8 corners, and
        conservative: a sphere is culled only if wholly outside a plane).
        """
        lo, hi = self.box_lo_m[ids], self.box_hi_m[ids]
        centre_s = 0.5 * (lo + hi)
        radius_s = self.box_radius_m[ids]
        culled = np.zeros(len(ids), bool)
        if f["cull"]:
            if f["region"] is None:
                planes = f["planes"]                                                    # (6, 4) scene frame
                culled = ((centre_s @ planes[:, :3].T + planes[:, 3]) < -radius_s[:, None]).any(axis=1)
            else:
                culled = self._culled(lo[:, None, :] + (hi - lo)[:, None, :] * _BOX_CORNERS, f)
        model = f["model"]
        centre = centre_s @ model[:3, :3].T + (model[:3, 3] - f["eye"])                # world, from the eye
        dist = np.sqrt(np.einsum("mi,mi->m", centre, centre))
        cdir = centre / dist[:, None]
        # Every point of the box is within asin(R / |c|) of the centre's direction (R: the sphere's radius).
        with np.errstate(divide="ignore", invalid="ignore"):
            reach = np.where(dist > f["s_max"] * radius_s,
                             np.degrees(np.arcsin(np.minimum(f["s_max"] * radius_s / dist, 1.0))), 180.0)
        v = cdir - f["axes"][2]
        ecc_c = np.degrees(2 * np.arcsin(np.minimum(np.sqrt(np.einsum("mi,mi->m", v, v)) / 2, 1.0)))
        # Nearest point of the box to the eye (scene frame); world distance >= s_min x scene distance.
        gap = np.maximum(np.maximum(lo - f["eye_scene"], f["eye_scene"] - hi), 0.0)
        r_min = f["s_min"] * np.sqrt(np.einsum("mi,mi->m", gap, gap))
        leaf = f["s_max"] * self.leaf_chord_m[ids]
        with np.errstate(divide="ignore", invalid="ignore"):
            diam = np.where(r_min > leaf / 2, np.degrees(2 * np.arcsin(np.minimum(leaf / (2 * r_min), 1.0))), 180.0)
        ecc = np.maximum(ecc_c - reach - f["shift_reach"] - diam - _ANGLE_SLACK_DEG, 0.0)
        with np.errstate(divide="ignore"):
            level = np.log2(self._fmax_bound(ids, ecc, f) * (diam + _ANGLE_SLACK_DEG)) + f["bias"]
        return level, culled

    def _node_need(self, ids, f):
        """Nodes above the leaves: (factor each needs (m,) int64, culled (m,) bool)."""
        level, culled = self.node_level_bound(ids, f)
        x = np.nan_to_num(level, nan=-1e3, posinf=float(self.leaf_max_level), neginf=-1e3)
        # The leaves need a vertex every P 2^-L samples: the largest whole spacing within that, and the
        # factor that keeps every gap between the node's vertices (rounded to samples) at most it.
        spacing = vertex_gap_samples(x, self.grid.patch_samples, self.leaf_max_level)
        return np.ceil(self.node_size[ids] / spacing).astype(np.int64), culled

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
                                 eye_prev_mm=f["eye_prev"] if f["moving"] else None, dt_s=f["dt"],
                                 fmax_foveal=self._leaf_f0[rows, cols] if f["speed"] == pc.MIN_SPEED_DEG_S else None)

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
        D, off, total = self.depth, self.offset, self.n_nodes
        need = np.ones(total, np.int64)            # factor each evaluated node needs (leaves: their inner factor)
        culled = np.zeros(total, bool)
        known = np.zeros(total, bool)
        refined = np.zeros(total, bool)
        evaluated = 0
        split_at = np.minimum(self.split_factor, self.node_top)
        # 1. The walk: from the frontier at depth d, it and its descendants down to batch_depths depths (above
        #    the leaves) evaluated in one pass; then the splits resolved top-down within the batch.
        front, d = np.zeros(1, np.int64), 0
        while len(front) and d < D:
            levels = [front]
            while len(levels) < self.batch_depths and d + len(levels) < D:
                levels.append(self._children(levels[-1]))
            ids = np.concatenate(levels)
            k, cul = self._node_need(ids, f)
            need[ids], culled[ids], known[ids] = k, cul, True
            evaluated += len(ids)
            split = ~cul & (k > split_at[ids])
            refined[ids] = split
            for j in range(1, len(levels)):         # a node below an unsplit one is not in the tree
                parent = self._parent(levels[j])
                refined[levels[j]] &= refined[parent]
            last = levels[-1]
            front = self._children(last[refined[last]])
            d += len(levels)
        # 2. 2:1 balance, bottom-up: a split node's edge neighbours' parents are split.
        for dd in range(D - 1, 0, -1):
            r = refined[off[dd]:off[dd + 1]].reshape(1 << dd, 1 << dd)
            if not r.any():
                continue
            grown = r.copy()
            grown[1:] |= r[:-1]
            grown[:-1] |= r[1:]
            grown[:, 1:] |= r[:, :-1]
            grown[:, :-1] |= r[:, 1:]
            refined[off[dd - 1]:off[dd]].reshape(1 << (dd - 1), 1 << (dd - 1))[...] |= _halve(grown, np.max)
        drawn = np.zeros(total, bool)
        drawn[0] = not refined[0]
        for dd in range(1, D + 1):
            up = refined[off[dd - 1]:off[dd]].reshape(1 << (dd - 1), 1 << (dd - 1))
            drawn[off[dd]:off[dd + 1]] = (np.repeat(np.repeat(up, 2, axis=0), 2, axis=1).ravel()
                                          & ~refined[off[dd]:off[dd + 1]])
        # Nodes the balance added (above the leaves), and the leaves, evaluated.
        extra = np.flatnonzero(drawn[:off[D]] & ~known[:off[D]])
        capped = 0
        if len(extra):
            k, cul = self._node_need(extra, f)
            need[extra], culled[extra] = k, cul
            evaluated += len(extra)
            capped += int(np.count_nonzero(~cul & (k > self.node_top[extra])))
        top = np.minimum(need, self.node_top)
        edge = np.repeat(top[:, None], 4, axis=1)                  # each node's own need on each edge
        leaves = off[D] + np.flatnonzero(drawn[off[D]:])
        if len(leaves):
            lr, lc = self.node_row[leaves], self.node_col[leaves]
            lo, hi = self.box_lo_m[leaves], self.box_hi_m[leaves]
            cul = self._culled(lo[:, None, :] + (hi - lo)[:, None, :] * _BOX_CORNERS, f)
            culled[leaves] = cul
            live = leaves[~cul]
            inner, outer = self._leaf_levels(lr[~cul], lc[~cul], f)
            p, rule = self.grid.patch_samples, self.factors
            top[live] = tess_factors(inner, self.leaf_max_level, p, rule)
            edge[live] = tess_factors(outer, self.leaf_max_level, p, rule)
            evaluated += len(leaves)
        # 3. The drawn nodes' outer factors.
        ids = np.flatnonzero(drawn & ~culled)
        dd, r, c = self.node_depth[ids], self.node_row[ids], self.node_col[ids]
        m = 1 << dd
        own = edge[ids]
        outer = own.copy()
        lim = self.node_top[ids]
        for e, (dr, dc) in enumerate(EDGE_STEP):
            opp = OPPOSITE[e]
            nr, nc = r + dr, c + dc
            inside = (nr >= 0) & (nr < m) & (nc >= 0) & (nc < m)
            nid = off[dd] + (np.clip(nr, 0, m - 1) << dd) + np.clip(nc, 0, m - 1)
            same = inside & drawn[nid]
            outer[same, e] = np.maximum(own[same, e], edge[nid[same], opp])
            big = inside & refined[nid]                 # beside two nodes of half the size: their edge factors x 2
            if big.any():
                (a0, b0), (a1, b1) = _CHILDREN_ON_EDGE[opp]
                d1 = dd[big] + 1
                base = off[d1] + ((2 * nr[big]) << d1) + 2 * nc[big]
                want = np.maximum.reduce([own[big, e], 2 * edge[base + (a0 << d1) + b0, opp],
                                          2 * edge[base + (a1 << d1) + b1, opp]])
                want += want & 1                                   # even: the small sides get half
                capped += int(np.count_nonzero(want > lim[big]))
                outer[big, e] = np.clip(want, 2, lim[big])
            small = inside & ~drawn[nid] & ~refined[nid]  # beside half of a node twice the size
            if small.any():
                (a0, b0), (a1, b1) = _CHILDREN_ON_EDGE[e]
                ds = dd[small]
                parent = off[ds - 1] + ((nr[small] >> 1) << (ds - 1)) + (nc[small] >> 1)
                base = off[ds] + (((r[small] >> 1) * 2) << ds) + (c[small] >> 1) * 2
                want = np.maximum.reduce([edge[parent, opp], 2 * edge[base + (a0 << ds) + b0, e],
                                          2 * edge[base + (a1 << ds) + b1, e]])
                want += want & 1
                outer[small, e] = np.clip(want, 2, self.node_top[parent]) // 2
        size = self.node_size[ids]
        return NodeSelection(dd.astype(np.int32), r.astype(np.int32), c.astype(np.int32),
                             np.stack([c * size, r * size], axis=-1).astype(np.int32), size.astype(np.int32),
                             top[ids].astype(np.int32), outer.astype(np.int32), evaluated, capped)

    def _parent(self, ids) -> np.ndarray:
        d = self.node_depth[ids] - 1
        return self.offset[d] + ((self.node_row[ids] >> 1) << d) + (self.node_col[ids] >> 1)
