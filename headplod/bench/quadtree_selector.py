"""Level selection over a quadtree of the base grid (a bench's subject; README: selection over a quadtree).

Used by :mod:`.plod_quadtree` and :mod:`.plod_lazy`, not by the product's frame step. ``LevelSelector``
evaluates its criterion on every base triangle on every frame; :class:`QuadtreeSelector` gives the same
levels (``tests/test_quadtree.py``) while evaluating it only where some triangle could need more than level 0:

- :class:`QuadTree`: per-node bounds, computed once, over the quads of a ``BaseMesh.grid``.
- Per frame the tree is walked breadth-first, numpy over each depth's frontier. A node is dropped (all its
  triangles at level 0) when all its centroids project outside the screen (:func:`headplod.plod.cull.
  outside_screen` of its box, as the flat culling) or an upper bound of the criterion over it is <= 0
  (:func:`headplod.plod.criteria.level_bound`); with hysteresis, a node holding a triangle above level 0
  from the last frame is entered too.
- The leaves reached run ``LevelSelector``'s own criterion and hysteresis rule on their triangles only.

Modes whose criterion is not per-triangle (``acuity``, ``sse``, ``ipv``, ``dpv``) are refused.
"""
from __future__ import annotations

import math

import numpy as np

from ..plod import criteria, cull
from ..plod import perception as pc
from ..plod.select import LevelSelector, SelectorConfig
from ..plod.view import ConditionedView, require_conditioned
from ..tol import tol

HIERARCHY_MODES = ("csf", "gp", "distance", "full")
"""Modes :class:`QuadtreeSelector` supports: those whose level is a function of the triangle alone."""


class QuadTree:
    """Per-node bounds of a quadtree over a grid of quads (two base triangles per quad).

    ``corners_mm`` (F, 3, 3) and ``centroids_mm`` (F, 3), world mm, F = 2 nx ny in ``BaseMesh.grid``'s order
    (face ``2 (j nx + i) + k`` in quad column i, row j); ``margin_mm`` (F,): each triangle's culling margin, mm.

    ``depth`` D: the leaves (quads) at depth D (the grid padded to 2^D x 2^D with empty nodes), the root at 0.
    ``table[d]`` (4^d, 12) float64, node ``j 2^d + i``'s row of :attr:`COLUMNS`: its box's centre and
    half-size, its half diagonal, the longest triangle side, the largest centroid-to-corner distance, the
    widest culling margin (mm), the highest contrast and its highest foveal f_max over all speeds (cpd; the
    last two from :meth:`set_contrast`). ``valid[d]`` (4^d,) bool: the node holds a quad.
    """

    COLUMNS = ("cx", "cy", "cz", "hx", "hy", "hz", "radius", "diameter", "reach", "margin", "contrast", "fmax")

    def __init__(self, corners_mm, centroids_mm, nx: int, ny: int, margin_mm):
        corners = np.asarray(corners_mm, dtype=np.float64)
        centroids = np.asarray(centroids_mm, dtype=np.float64)
        nx, ny = int(nx), int(ny)
        if nx < 1 or ny < 1:
            raise ValueError(f"QuadTree: nx and ny must be >= 1, got {nx}, {ny}")
        F = 2 * nx * ny
        if corners.shape != (F, 3, 3) or centroids.shape != (F, 3):
            raise ValueError(f"QuadTree: expected corners ({F}, 3, 3) and centroids ({F}, 3) for {nx} x {ny} "
                             f"quads, got {corners.shape} and {centroids.shape}")
        self.nx, self.ny = nx, ny
        self.depth = D = max(int(math.ceil(math.log2(max(nx, ny)))), 0)
        n = 2 ** D
        points = np.concatenate([corners, centroids[:, None]], axis=1).reshape(ny, nx, 8, 3)   # 2 faces x 4
        side = np.linalg.norm(corners - corners[:, [1, 2, 0]], axis=2).max(axis=1)
        reach = np.linalg.norm(corners - centroids[:, None], axis=2).max(axis=1)
        margin = np.asarray(margin_mm, dtype=np.float64).reshape(-1) * (1 + tol.small) + tol.small

        def leaf(reduced, fill):
            out = np.full((n, n) + reduced.shape[2:], fill)
            out[:ny, :nx] = reduced
            return out

        lo, hi = leaf(points.min(axis=2), 0.0), leaf(points.max(axis=2), 0.0)
        scalars = np.stack([leaf(v.reshape(ny, nx, 2).max(axis=2), 0.0) for v in (side, reach, margin)], axis=-1)
        valid = leaf(np.ones((ny, nx), bool), False)
        self.table, self.valid = [None] * (D + 1), [None] * (D + 1)
        for d in range(D, -1, -1):                        # loop over depths, leaves up
            m = 2 ** d
            row = np.zeros((m, m, len(self.COLUMNS)))
            row[..., 0:3], row[..., 3:6] = 0.5 * (lo + hi), 0.5 * (hi - lo)
            row[..., 6] = np.linalg.norm(row[..., 3:6], axis=-1)
            row[..., 7:10] = scalars
            self.table[d], self.valid[d] = row.reshape(m * m, -1), valid.reshape(-1)
            if d:
                # A node's extremes over its valid children (padding ones hold zeros).
                blocks = lambda a: a.reshape(m // 2, 2, m // 2, 2, *a.shape[2:])                  # noqa: E731
                vb = blocks(valid)[..., None]
                lo = np.where(vb, blocks(lo), np.inf).min(axis=(1, 3))
                hi = np.where(vb, blocks(hi), -np.inf).max(axis=(1, 3))
                scalars = np.where(vb, blocks(scalars), -np.inf).max(axis=(1, 3))
                valid = blocks(valid).any(axis=(1, 3))
                lo, hi = np.where(valid[..., None], lo, 0.0), np.where(valid[..., None], hi, 0.0)
                scalars = np.where(valid[..., None], scalars, 0.0)
        self._contrast_source = None

    @property
    def n_nodes(self) -> int:
        return sum(int(v.sum()) for v in self.valid)

    def set_contrast(self, contrast, fmax_sup=None) -> None:
        """Per-node highest contrast from the triangles' (F,) and, with ``fmax_sup`` (a function of the
        contrast (k,) → cpd (k,), non-decreasing), its sup f_max; recomputed only for a new array."""
        if contrast is self._contrast_source:
            return
        D, n = self.depth, 2 ** self.depth
        c = np.full((n, n), -np.inf)
        c[:self.ny, :self.nx] = np.asarray(contrast, dtype=np.float64).reshape(self.ny, self.nx, 2).max(axis=2)
        for d in range(D, -1, -1):                        # loop over depths
            self.table[d][:, 10] = np.maximum(c.reshape(-1), 0.0)
            if fmax_sup is not None:
                self.table[d][:, 11] = fmax_sup(self.table[d][:, 10])
            if d:
                m = 2 ** d
                c = c.reshape(m // 2, 2, m // 2, 2).max(axis=(1, 3))
        self._contrast_source = contrast

    def children(self, d: int, nodes):
        """The valid children (at depth d + 1) of ``nodes`` (k,) int at depth d."""
        i, j = nodes & (2 ** d - 1), nodes >> d
        first = (2 * j) * 2 ** (d + 1) + 2 * i
        kids = (first[:, None] + np.array([0, 1, 2 ** (d + 1), 2 ** (d + 1) + 1])).reshape(-1)
        return kids[self.valid[d + 1][kids]]

    def faces(self, leaves):
        """Base triangles (2k,) int of leaf nodes (k,) int at depth D (face 2 (j nx + i) + k)."""
        D = self.depth
        q = (leaves >> D) * self.nx + (leaves & (2 ** D - 1))
        return (2 * q[:, None] + np.arange(2)).reshape(-1)

    def ancestors(self, faces):
        """Per depth d, the nodes (k,) int holding the base triangles ``faces`` (duplicates kept)."""
        q = np.asarray(faces) // 2
        i, j = q % self.nx, q // self.nx
        D = self.depth
        return [((j >> (D - d)) << d) + (i >> (D - d)) for d in range(D + 1)]


class QuadtreeSelector(LevelSelector):
    """:class:`LevelSelector` with the same ``select(ConditionedView) -> (levels, info)``, walking a :class:`QuadTree`.

    ``LevelSelector``'s arguments, with ``corners_scene`` required and ``grid_shape = (ny, nx)`` (the base
    triangles of ``BaseMesh.grid(terrain, nx, ny)``, in its order). ``info``: ``poi_px``, ``cov_deg2`` and, for
    the evaluated triangles ``rows`` (k,) only, ``eccentricity_deg`` (NaN: culled), ``speed_deg_s``,
    ``distance_mm``, ``continuous``; every other triangle is at level 0. :attr:`last_stats`:
    ``nodes_visited``, ``leaves``, ``triangles_evaluated``, ``nodes_per_depth``.
    """

    def __init__(self, centroids_scene, edge_len_scene, geometric_error_scene, contrast, model, screen,
                 config: SelectorConfig = SelectorConfig(mode="csf"), *, corners_scene, grid_shape):
        if not isinstance(config, SelectorConfig):
            raise TypeError(f"QuadtreeSelector: config must be a SelectorConfig, got {type(config).__name__}")
        if config.mode not in HIERARCHY_MODES:
            raise ValueError(f"QuadtreeSelector: mode must be one of {HIERARCHY_MODES}, got {config.mode!r} "
                             f"(its criterion is not per triangle)")
        if corners_scene is None:
            raise ValueError("QuadtreeSelector: corners_scene is required (the nodes' bounds come from them)")
        ny, nx = (int(v) for v in grid_shape)
        if 2 * nx * ny != len(centroids_scene):
            raise ValueError(f"QuadtreeSelector: grid_shape {tuple(grid_shape)} has {2 * nx * ny} base triangles, "
                             f"got {len(centroids_scene)}")
        super().__init__(centroids_scene, edge_len_scene, geometric_error_scene, contrast, model, screen, config,
                         corners_scene=corners_scene)
        self.tree = QuadTree(self.corners_mm, self.centroids_mm, nx, ny, self.margin_mm)
        self._hot = None                # per depth: nodes with a triangle above level 0 (hysteresis)
        self.last_stats: dict = {}

    def _frame_context(self, eye, axes, cov):
        """The per-frame constants of :meth:`_node_bounds`: (eye, axes, the screen's pyramid, shift reach deg).

        Also brings the nodes' contrast up to date (``self.contrast`` may be replaced between frames).
        """
        cfg = self.config
        kelly = cfg.mode == "csf" and cfg.csf == "kelly_scaled"
        self.tree.set_contrast(self.contrast, (lambda c: criteria.sup_fmax_cpd(c, cfg.csf)) if kelly else None)
        return (eye, axes, cull.screen_pyramid(self.screen, eye),
                criteria.shift_reach_deg(cov, cfg.shift, cfg.ellipse_sigma))

    def _node_bounds(self, d, nodes, frame):
        """For ``nodes`` (k,) int at depth d: (culled (k,) bool: every centroid below projects outside the screen
        with its margin or lies behind the eye; bound (k,) float: an upper bound of the continuous level, bias
        included, of every base triangle below)."""
        eye, axes, pyramid, shift_reach = frame
        row = self.tree.table[d][nodes]                                       # (k, 12)
        rel, half = row[:, 0:3] - eye, row[:, 3:6]
        culled = cull.outside_screen(rel, row[:, 9], pyramid, half)
        cfg = self.config
        dmin = np.sqrt((np.maximum(np.abs(rel) - half, 0.0) ** 2).sum(axis=1))      # the box's nearest point
        if cfg.mode == "distance":
            return culled, (criteria.distance_level(dmin, self.max_level, cfg.distance_ref_mm)
                            + float(cfg.level_bias) + criteria.LEVEL_SLACK)
        # The centroids are within the node's bounding sphere; a triangle's reach (centroid to corner) and
        # diameter (longest side) are seen from at least the box's nearest distance.
        ecc = criteria.eccentricity_bound_deg(criteria.angle_to_sphere_deg(rel, row[:, 6], axes[2]), shift_reach,
                                              criteria.sphere_reach_deg(row[:, 8], dmin))
        kelly = cfg.mode == "csf" and cfg.csf == "kelly_scaled"
        return culled, criteria.level_bound(row[:, 10], ecc, criteria.subtended_deg(row[:, 7], dmin), mode=cfg.mode,
                                            csf_model=cfg.csf, foveal_cpd=row[:, 11] if kelly else None,
                                            level_bias=float(cfg.level_bias))

    def select(self, view: ConditionedView):
        """Levels (F,) int for the frame's conditioned ``view``, equal to ``LevelSelector.select``'s; info (class
        notes)."""
        require_conditioned(view, f"{type(self).__name__}.select")
        cfg = self.config
        if cfg.mode == "full":
            return super().select(view)
        eye, axes, cov = view.eye_mm, view.axes, view.cov_deg2
        if view.restart and self.hysteresis is not None:
            self.hysteresis.reset()
        tree = self.tree
        frame = self._frame_context(eye, axes, cov)
        hot = self._hot if (self.hysteresis is not None and self.hysteresis.levels is not None) else None
        # Start below the root: the top depths are almost always entered whole.
        start = min(tree.depth, 3)
        frontier = np.flatnonzero(tree.valid[start])
        visited = []
        for d in range(start, tree.depth + 1):             # loop over depths, numpy over the frontier
            visited.append(len(frontier))
            culled, bound = self._node_bounds(d, frontier, frame)
            keep = ~culled & (bound > 0)                    # ceil(level) <= 0 for every triangle otherwise
            if hot is not None:
                keep |= hot[d][frontier]
            frontier = frontier[keep]
            if d < tree.depth:
                frontier = tree.children(d, frontier)
        rows = tree.faces(frontier)
        rel = self.centroids_mm[rows] - eye
        distance = np.linalg.norm(rel, axis=1)
        directions = rel / distance[:, None]
        speed = self._angular_speed_rows(view.t, eye, rows, directions)
        inside = np.flatnonzero(~self._outside_screen(eye, rows))
        seen = rows[inside]
        shifted = criteria.shifted_offsets_deg(self.centroids_mm[seen], eye, axes, cov, shift=cfg.shift,
                                               ellipse_sigma=cfg.ellipse_sigma)
        ecc = np.full(len(rows), np.nan)
        continuous = np.zeros(len(rows))
        ecc[inside], continuous[inside] = self._criterion(seen, eye, shifted, distance[inside],
                                                          directions[inside], speed[inside])
        if self.hysteresis is not None:
            row_levels = self.hysteresis.update_rows(rows, continuous, self.max_level, eager=self._eager(view, ecc))
            levels = np.clip(self.hysteresis.levels, 0, self.max_level).astype(np.int64)
            self._hot = self._mark_hot(rows[row_levels > 0])
        else:
            levels = np.zeros(len(self.centroids_mm), dtype=np.int64)
            levels[rows] = pc.round_level(continuous, self.rounding, self.max_level)
        self.last_stats = {"nodes_visited": int(sum(visited)), "nodes_per_depth": [0] * start + visited,
                           "leaves": int(len(frontier)), "triangles_evaluated": int(len(rows))}
        return levels, {"rows": rows, "eccentricity_deg": ecc, "speed_deg_s": speed, "distance_mm": distance,
                        "continuous": continuous, "poi_px": view.poi_px, "cov_deg2": cov}

    def _mark_hot(self, faces):
        """Per depth, (4^d,) bool: the nodes holding a triangle of ``faces`` (those above level 0)."""
        old = self._hot
        hot = old if old is not None else [np.zeros(len(v), bool) for v in self.tree.valid]
        for h in hot:                               # loop over depths: clear the last frame's marks
            h[:] = False
        for h, nodes in zip(hot, self.tree.ancestors(faces)):
            h[nodes] = True
        return hot

    def _angular_speed_rows(self, t, eye, rows, directions):
        """Angular speed (k,) deg/s of the triangles ``rows`` since the last view, >= 0.1 (as the flat one)."""
        previous, self._previous = self._previous, (t, eye, None)
        if previous is None or t is None or previous[0] is None or t <= previous[0]:
            return np.full(len(rows), pc.MIN_SPEED_DEG_S)
        rel = self.centroids_mm[rows] - previous[1]
        return criteria.angular_speed_deg_s(directions, rel / np.linalg.norm(rel, axis=1)[:, None], t - previous[0])

    def reset(self):
        super().reset()
        self._hot = None


def scene_quadtree_selector(scene, mode: str, uncertainty: str, config: SelectorConfig | None = None,
                            **settings) -> QuadtreeSelector:
    """A :class:`QuadtreeSelector` for a :class:`headplod.render.still.TerrainScene`'s mesh (a ``BaseMesh.grid``).

    ``mode``, ``uncertainty`` and the keyword ``settings`` (any other
    :class:`SelectorConfig` field) replace those of ``config`` (default
    ``SelectorConfig()``), as ``TerrainScene.selector`` does for the flat one.
    """
    import dataclasses

    config = dataclasses.replace(SelectorConfig() if config is None else config, mode=mode, uncertainty=uncertainty,
                                 **settings)
    m = scene.mesh
    vertices = m.base.vertices           # BaseMesh.grid: (nx + 1) x (ny + 1) vertices
    grid_shape = (len(np.unique(vertices[:, 1])) - 1, len(np.unique(vertices[:, 0])) - 1)
    return QuadtreeSelector(m.centroids, m.edge_length, m.geometric_error, m.contrast, scene.model, scene.screen,
                            config, corners_scene=m.corners, grid_shape=grid_shape)
