"""A quadtree over a :class:`PatchGrid`'s patches: variable-size tessellation patches, refined where the CSF needs it.

The flat tessellation back end evaluates the CSF on every patch of ``P``
samples on every frame and draws every patch in view: its selection grows
with the terrain (16384 patches of 64 samples at 8193² samples). Here the patches are the
leaves of a quadtree whose node at depth ``d`` is a square of
``S = P 2^(D-d)`` samples (``D = log2(n)``, ``n`` patches per side, a power
of two; the root, depth 0, is the whole grid). Per frame
(:meth:`PatchTree.select`):

1. **Walk** (:meth:`PatchTree._walk`) the tree top-down with numpy over the
   whole frontier (no loop over nodes): the frontier and its descendants
   down to ``batch_depths`` depths are evaluated in one pass, then the
   splits are resolved top-down (a few wasted evaluations for fewer numpy
   passes: the passes' fixed cost, not the nodes, is most of the walk). For
   each node:

   - its box (the samples' x, y; the node's height range) is culled when its
     circumscribed sphere is wholly outside one frustum plane
     (:func:`headplod.plod.cull.sphere_outside_planes`);
   - its *need*: ``L_ub``, an upper bound on the continuous CSF level
     (:func:`headplod.plod.criteria.level_bound` of the rule the leaves
     take) of every leaf patch and leaf edge below it: the node's highest
     contrast, the smallest eccentricity over its box (the angle of the
     box's centre from the view axis, less the angle its sphere subtends,
     less the uncertainty shift's largest reach, less the largest leaf
     diameter), and the largest angular diameter a leaf below it can have
     (its corner-to-corner chord with the largest leaf height range below
     the node, seen from the box's nearest point). A leaf of level ``L`` asks for a vertex every ``P 2^-L``
     samples; the node gets the whole-number factor ``F = ceil(S / g)``,
     ``g`` that gap rounded down to whole samples, so every gap between its
     vertices (each rounded to a sample) is at most ``g``. Factors are not
     restricted to powers of two (GL's ``equal_spacing`` takes any integer):
     a power of two would round the bound up to 2x per side.
   - If ``F`` exceeds ``split_factor`` (or ``min(S, max_tess_level)``), the
     node is split and its children join the frontier.

   The cost is that of the nodes in view along the refined paths.
2. **Balance** the tree 2:1 (:meth:`PatchTree._balance`; neighbours across
   an edge differ by at most one depth), bottom-up: a split node forces the
   split of its edge neighbours' parents. The **drawn set**
   (:meth:`PatchTree._drawn`) is then the tree's leaves; those the balance
   added are evaluated as in step 1, and the drawn patches of ``P`` samples
   get the flat path's exact levels and factors and its clip-box culling
   (:func:`levels_of_patches`, :func:`tess_factors`,
   :func:`headplod.plod.cull.box_outside_clip`: the same code as the flat
   twin; :meth:`PatchTree._evaluate_drawn`).
3. **Outer factors** (:meth:`PatchTree._outer_factors`), crack-free by construction:

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
random views). With the eye moving (since the last frame the tree selected
for), nodes above the leaves take the highest f_max over every speed
(:func:`headplod.plod.criteria.sup_fmax_cpd`); leaves the shader's per-point
speed. Pure numpy; the GL side is :mod:`headplod.render.tessellate`
(``TessellationConfig.hierarchy``).

The price of merging: a node shows all its leaves at its worst leaf's need
(bounded, a fraction of a level above the true worst), so it draws more
triangles than the flat per-patch levels would there; a smaller
``split_factor`` trades those triangles for more nodes to evaluate and draw.
A cost rule was tried and not kept: also splitting a node whose four
children's bounds would draw 16 or more fewer triangles (one more depth
evaluated per pass) drew fewer triangles than without it but still more
than the flat path, for a selection a few times slower (``headplod bench
plod --scale``).

Not here (yet): hysteresis (per-node state), as in the flat path.
Frames: grid frame as :mod:`headplod.plod.patches` (row 0 south, column 0 west);
node ``(d, row, col)`` covers samples ``row S .. (row + 1) S`` by ``col S .. (col + 1) S``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import criteria, cull
from . import perception as pc
from .patches import FACTOR_RULES, PatchGrid, levels_of_patches, max_level_for, tess_factors, vertex_gap_samples
from .select import SelectorConfig

__all__ = ["PatchTree", "NodeSelection", "EDGE_STEP", "OPPOSITE"]

#: (row, column) step to the neighbour across each edge, in ``EDGE_NAMES`` order (W, S, E, N).
EDGE_STEP = ((0, -1), (-1, 0), (0, 1), (1, 0))
#: The edge of the neighbour that faces each edge: W <-> E, S <-> N.
OPPOSITE = (2, 3, 0, 1)
#: The two children (row, column offsets) along each edge of a node, W, S, E, N.
_CHILDREN_ON_EDGE = (((0, 0), (1, 0)), ((0, 0), (0, 1)), ((0, 1), (1, 1)), ((1, 0), (1, 1)))


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


@dataclass(frozen=True)
class _Frame:
    """One frame's constants of the walk (:meth:`PatchTree._frame`): frames as the attribute names say."""

    model: np.ndarray                 # (4, 4) scene m -> world mm
    eye_mm: np.ndarray                # (3,) world
    axes: np.ndarray                  # (3, 3) rows Ξ, Ψ, V
    cov_deg2: np.ndarray | None
    eye_scene: np.ndarray             # (3,) the eye in the scene frame
    s_min: float                      # smallest and largest singular value of the model's 3x3: mm per m
    s_max: float
    shift_reach_deg: float            # criteria.shift_reach_deg
    moving: bool                      # the eye moved since the last frame
    eye_prev_mm: np.ndarray | None
    dt_s: float
    planes: np.ndarray | None         # (6, 4) frustum planes, scene frame (with mvp)
    mvp: np.ndarray | None            # T_clip_scene
    region_ndc: np.ndarray | None
    cull: bool


@dataclass
class _Walk:
    """The per-node state of one frame's selection, indexed by node (:attr:`PatchTree.n_nodes`)."""

    need: np.ndarray                  # factor each evaluated node needs (leaves: their inner factor)
    culled: np.ndarray
    known: np.ndarray                 # the node's need was evaluated
    refined: np.ndarray               # split: its children are in the tree
    evaluated: int = 0
    capped: int = 0


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
    batch_depths : int
        Depths evaluated per numpy pass of the walk (a node's descendants down to this many depths are
        evaluated together, whether or not the node splits): fewer passes, a few wasted evaluations.
    factors : {"whole", "power_of_two"}
        The leaves' rule from level to factor (:func:`tess_factors`; the flat path's
        ``TessellationConfig.factors``). Nodes above the leaves always take whole numbers.
    selection : SelectorConfig
        The level rule's settings: ``shift``, ``ellipse_sigma``, ``level_bias``
        (the criterion is ``csf`` with ``csf_model="kelly_scaled"``, the one the GPU evaluates).
    cull : bool
        Cull nodes by the frustum (given an ``mvp`` to :meth:`select`).

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
                 factors: str = "whole", *, selection: SelectorConfig = SelectorConfig(mode="csf"), cull: bool = True):
        self._check(grid, split_factor, max_tess_level, batch_depths, factors, selection)
        self.factors, self.selection, self.cull = factors, selection, bool(cull)
        self.grid, self.split_factor, self.max_tess_level = grid, int(split_factor), int(max_tess_level)
        self.batch_depths = int(batch_depths)
        D = self.depth = int(round(math.log2(grid.n_patches)))
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
        # leaf's inner piece and edges.
        v0 = pc.MIN_SPEED_DEG_S
        self._node_f0 = criteria.foveal_fmax_cpd(self.contrast, v0)
        self._leaf_f0 = criteria.foveal_fmax_cpd(
            criteria.patch_piece_contrast(grid.contrast, self._leaf_neighbour_contrast), v0)   # (n, n, 5)
        self._previous = None            # (eye_mm (3,), t) of the last frame selected, for the speed

    @staticmethod
    def _check(grid, split_factor, max_tess_level, batch_depths, factors, selection) -> None:
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
        if int(batch_depths) < 1:
            raise ValueError(f"PatchTree: batch_depths must be >= 1, got {batch_depths!r}")
        if not isinstance(selection, SelectorConfig):
            raise TypeError(f"PatchTree: selection must be a SelectorConfig, got {type(selection).__name__}")
        if selection.csf != "kelly_scaled":
            raise ValueError(f"PatchTree: the patches' criterion is csf with the kelly_scaled CSF, "
                             f"got csf_model={selection.csf!r}")

    @property
    def n_nodes(self) -> int:
        """Nodes of every depth."""
        return int(self.offset[-1])

    def _children(self, ids) -> np.ndarray:
        """(4 m,) the children of nodes ``ids`` (not leaves), in (row, col) order per parent."""
        d = self.node_depth[ids] + 1
        r, c = 2 * self.node_row[ids], 2 * self.node_col[ids]
        base = self.offset[d] + (r << d) + c
        return (base[:, None] + np.stack([np.zeros_like(d), np.ones_like(d), 1 << d, (1 << d) + 1], axis=-1)).ravel()

    def _parent(self, ids) -> np.ndarray:
        d = self.node_depth[ids] - 1
        return self.offset[d] + ((self.node_row[ids] >> 1) << d) + (self.node_col[ids] >> 1)

    def reset(self) -> None:
        """Forget the last frame (the next one is still: every speed at its floor)."""
        self._previous = None

    # -- per-frame constants ---------------------------------------------------

    def _frame(self, cv, model, mvp=None, region_ndc=None) -> _Frame:
        """The frame's constants for the conditioned view ``cv`` (eye, axes, covariance, time) and the model."""
        model = np.asarray(model, np.float64)
        eye = np.asarray(cv.eye_mm, np.float64)
        sel = self.selection
        sv = np.linalg.svd(model[:3, :3], compute_uv=False)
        previous = self._previous
        dt = 0.0
        if previous is not None and cv.t is not None and previous[1] is not None and cv.t > previous[1]:
            dt = float(cv.t - previous[1])
        # A still eye (the same position, or no last frame): every speed is the floor, as the shader's rule gives.
        moving = dt > 0 and bool(np.any(previous[0] != eye))
        return _Frame(model, eye, np.asarray(cv.axes, np.float64), cv.cov_deg2,
                      np.linalg.solve(model[:3, :3], eye - model[:3, 3]), float(sv.min()), float(sv.max()),
                      criteria.shift_reach_deg(cv.cov_deg2, sel.shift, sel.ellipse_sigma), moving,
                      previous[0] if moving else None, dt,
                      None if mvp is None else cull.frustum_planes(mvp),
                      None if mvp is None else np.asarray(mvp, np.float64),
                      None if region_ndc is None else np.asarray(region_ndc, np.float64), self.cull and mvp is not None)

    # -- node evaluation -------------------------------------------------------

    def _culled(self, corners, f: _Frame):
        """(m,) bool: boxes (m, 8, 3) outside the frame's clip box (:func:`cull.box_outside_clip`), if culling."""
        if not f.cull:
            return np.zeros(len(corners), bool)
        return cull.box_outside_clip(corners, f.mvp, f.region_ndc)

    def node_level_bound(self, ids, f: _Frame):
        """Nodes' bounds: (level (m,), culled (m,) bool).

        ``level``: an upper bound on the continuous CSF level of every leaf patch and leaf edge below each
        node (module notes; :func:`criteria.level_bound`); ``f``: the frame's constants (:meth:`_frame`).
        The box is bounded by its circumscribed sphere for the reach and the frustum test (cheaper than its 8
        corners, and conservative: a sphere is culled only if wholly outside a plane).
        """
        lo, hi = self.box_lo_m[ids], self.box_hi_m[ids]
        centre_s = 0.5 * (lo + hi)
        radius_s = self.box_radius_m[ids]
        culled = np.zeros(len(ids), bool)
        if f.cull:
            culled = (cull.sphere_outside_planes(centre_s, radius_s, f.planes) if f.region_ndc is None
                      else self._culled(cull.box_corners(lo, hi), f))
        centre = centre_s @ f.model[:3, :3].T + (f.model[:3, 3] - f.eye_mm)            # world, from the eye
        # Every point of the box is within the sphere of radius s_max R about the centre; the box's nearest
        # point is at least s_min times its scene distance from the eye.
        angle = criteria.angle_to_sphere_deg(centre, f.s_max * radius_s, f.axes[2])
        gap = np.maximum(np.maximum(lo - f.eye_scene, f.eye_scene - hi), 0.0)
        diam = criteria.subtended_deg(f.s_max * self.leaf_chord_m[ids],
                                      f.s_min * np.sqrt(np.einsum("mi,mi->m", gap, gap)))
        # A leaf piece's reach (its point to its farthest corner) is at most its diameter.
        ecc = criteria.eccentricity_bound_deg(angle, f.shift_reach_deg, diam)
        level = criteria.level_bound(self.contrast[ids], ecc, diam,
                                     speed_deg_s=None if f.moving else pc.MIN_SPEED_DEG_S,
                                     foveal_cpd=None if f.moving else self._node_f0[ids],
                                     level_bias=float(self.selection.level_bias))
        return level, culled

    def _node_need(self, ids, f: _Frame):
        """Nodes above the leaves: (factor each needs (m,) int64, culled (m,) bool)."""
        level, culled = self.node_level_bound(ids, f)
        x = np.nan_to_num(level, nan=-1e3, posinf=float(self.leaf_max_level), neginf=-1e3)
        # The leaves need a vertex every P 2^-L samples: the largest whole spacing within that, and the
        # factor that keeps every gap between the node's vertices (rounded to samples) at most it.
        spacing = vertex_gap_samples(x, self.grid.patch_samples, self.leaf_max_level)
        return np.ceil(self.node_size[ids] / spacing).astype(np.int64), culled

    def _leaf_levels(self, rows, cols, f: _Frame):
        """Exact (flat) continuous levels of leaves: inner (m,), outer (m, 4) (:func:`levels_of_patches`)."""
        g, p, sel = self.grid, self.grid.patch_samples, self.selection
        z = g.heights_m
        r0, c0 = rows * p, cols * p
        zc = np.stack([z[r0, c0], z[r0, c0 + p], z[r0 + p, c0 + p], z[r0 + p, c0]], axis=-1).astype(np.float64)
        xs = g.origin_m[0] + np.stack([c0, c0 + p, c0 + p, c0], axis=-1) * g.dx_m
        ys = g.origin_m[1] + np.stack([r0, r0, r0 + p, r0 + p], axis=-1) * g.dy_m
        corners = np.stack([xs, ys, zc], axis=-1)                                        # (m, 4, 3) SW SE NE NW
        return levels_of_patches(corners, g.contrast[rows, cols], self._leaf_neighbour_contrast[rows, cols],
                                 f.model, f.eye_mm, f.axes, f.cov_deg2, shift=sel.shift,
                                 ellipse_sigma=sel.ellipse_sigma, level_bias=float(sel.level_bias),
                                 eye_prev_mm=f.eye_prev_mm, dt_s=f.dt_s, fmax_foveal=self._leaf_f0[rows, cols])

    # -- the frame -------------------------------------------------------------

    def select(self, cv, model, *, mvp=None, region_ndc=None) -> NodeSelection:
        """The nodes to draw this frame, with their factors (module notes).

        Parameters
        ----------
        cv : headplod.plod.view.ConditionedView
            The frame's view: the eye, the head axes and the covariance the levels are chosen for, and
            the time (with the last frame's eye and time, the eye's motion: leaves take each point's
            angular speed, the shader's rule, nodes above them the highest f_max over every speed).
        model : (4, 4)
            ``T_world_scene`` (scene m → world mm).
        mvp : (4, 4) or None
            ``T_clip_scene`` for culling; None: nothing is culled.
        region_ndc : (4,) or None
            Only boxes reaching this NDC rectangle (x0, y0, x1, y1) are drawn.
        """
        f = self._frame(cv, model, mvp, region_ndc)
        self._previous = (np.asarray(cv.eye_mm, np.float64).copy(), cv.t)
        walk = self._walk(f)
        self._balance(walk.refined)
        drawn = self._drawn(walk.refined)
        top, edge = self._evaluate_drawn(drawn, walk, f)
        return self._outer_factors(drawn, walk, top, edge)

    def _walk(self, f: _Frame) -> _Walk:
        """Step 1: from the root, each frontier and its descendants down to ``batch_depths`` depths (above the
        leaves) evaluated in one pass, then the splits resolved top-down within the batch."""
        D, total = self.depth, self.n_nodes
        walk = _Walk(np.ones(total, np.int64), np.zeros(total, bool), np.zeros(total, bool), np.zeros(total, bool))
        split_at = np.minimum(self.split_factor, self.node_top)
        front, d = np.zeros(1, np.int64), 0
        while len(front) and d < D:
            levels = [front]
            while len(levels) < self.batch_depths and d + len(levels) < D:
                levels.append(self._children(levels[-1]))
            ids = np.concatenate(levels)
            k, cul = self._node_need(ids, f)
            walk.need[ids], walk.culled[ids], walk.known[ids] = k, cul, True
            walk.evaluated += len(ids)
            walk.refined[ids] = ~cul & (k > split_at[ids])
            for j in range(1, len(levels)):         # a node below an unsplit one is not in the tree
                walk.refined[levels[j]] &= walk.refined[self._parent(levels[j])]
            last = levels[-1]
            front = self._children(last[walk.refined[last]])
            d += len(levels)
        return walk

    def _balance(self, refined) -> None:
        """Step 2: 2:1 balance, bottom-up, in place: a split node's edge neighbours' parents are split."""
        off = self.offset
        for dd in range(self.depth - 1, 0, -1):
            r = refined[off[dd]:off[dd + 1]].reshape(1 << dd, 1 << dd)
            if not r.any():
                continue
            grown = r.copy()
            grown[1:] |= r[:-1]
            grown[:-1] |= r[1:]
            grown[:, 1:] |= r[:, :-1]
            grown[:, :-1] |= r[:, 1:]
            refined[off[dd - 1]:off[dd]].reshape(1 << (dd - 1), 1 << (dd - 1))[...] |= _halve(grown, np.max)

    def _drawn(self, refined) -> np.ndarray:
        """(total,) bool: the tree's leaves this frame (nodes whose parent is split and which are not)."""
        off = self.offset
        drawn = np.zeros(self.n_nodes, bool)
        drawn[0] = not refined[0]
        for dd in range(1, self.depth + 1):
            up = refined[off[dd - 1]:off[dd]].reshape(1 << (dd - 1), 1 << (dd - 1))
            drawn[off[dd]:off[dd + 1]] = (np.repeat(np.repeat(up, 2, axis=0), 2, axis=1).ravel()
                                          & ~refined[off[dd]:off[dd + 1]])
        return drawn

    def _evaluate_drawn(self, drawn, walk: _Walk, f: _Frame):
        """The drawn nodes' inner factors ``top`` (total,) and each node's own need on each edge ``edge`` (total, 4).

        Nodes the balance added (above the leaves) are evaluated as in the walk; the drawn patches of ``P``
        samples (leaves) take the flat path's exact levels and factors, and their clip-box culling.
        """
        off, D = self.offset, self.depth
        extra = np.flatnonzero(drawn[:off[D]] & ~walk.known[:off[D]])
        if len(extra):
            k, cul = self._node_need(extra, f)
            walk.need[extra], walk.culled[extra] = k, cul
            walk.evaluated += len(extra)
            walk.capped += int(np.count_nonzero(~cul & (k > self.node_top[extra])))
        top = np.minimum(walk.need, self.node_top)
        edge = np.repeat(top[:, None], 4, axis=1)
        leaves = off[D] + np.flatnonzero(drawn[off[D]:])
        if len(leaves):
            cul = self._culled(cull.box_corners(self.box_lo_m[leaves], self.box_hi_m[leaves]), f)
            walk.culled[leaves] = cul
            live = leaves[~cul]
            inner, outer = self._leaf_levels(self.node_row[live], self.node_col[live], f)
            p, rule = self.grid.patch_samples, self.factors
            top[live] = tess_factors(inner, self.leaf_max_level, p, rule)
            edge[live] = tess_factors(outer, self.leaf_max_level, p, rule)
            walk.evaluated += len(leaves)
        return top, edge

    def _outer_factors(self, drawn, walk: _Walk, top, edge) -> NodeSelection:
        """Step 3: the drawn, unculled nodes with their outer factors, crack-free (module notes)."""
        off, refined = self.offset, walk.refined
        ids = np.flatnonzero(drawn & ~walk.culled)
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
                walk.capped += int(np.count_nonzero(want > lim[big]))
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
                             top[ids].astype(np.int32), outer.astype(np.int32), walk.evaluated, walk.capped)
