"""Level selection over a quadtree of the base grid: cost that follows what is seen.

:class:`LevelSelector` evaluates its criterion on every base triangle of the
grid on every frame. :class:`QuadtreeSelector` gives the same levels while
evaluating it only where some triangle could need more than level 0:

- :class:`QuadTree`: a quadtree over the quads of a ``BaseMesh.grid``
  (``nx x ny`` quads, two base triangles each, face ``2 (j nx + i) + k``):
  a leaf is one quad, a node at depth ``d`` the ``2^(D-d) x 2^(D-d)`` quads
  below it (``D = ceil(log2(max(nx, ny)))``; the grid is padded to
  ``2^D x 2^D`` with empty nodes). Each node keeps, computed once, the
  axis-aligned box (world frame, mm) of its triangles' corners and centroids,
  its largest triangle diameter and corner reach, its highest contrast and
  its widest culling margin.
- Per frame the tree is walked breadth-first, one depth at a time, with
  numpy over the whole frontier (no Python loop over nodes). A node is
  dropped, all its triangles at level 0, when no triangle below it can get
  a level above 0: either all its centroids project outside the screen
  (culled: the flat selection gives them the continuous level 0), or an
  upper bound of the criterion over the node is <= 0. The bound of mode
  ``csf`` is ``log2(f_max · diameter)`` with the smallest eccentricity
  (the angle from the POI's direction to the node's bounding sphere, less
  the uncertainty shift's largest reach, less the largest angle from a
  centroid to its corners), the largest angular diameter (longest triangle
  side seen from the box's nearest point), the highest contrast and the
  highest f_max over every speed (:func:`sup_max_visible_freq_cpd`); ``gp``
  and ``distance`` have theirs. With hysteresis a node is also entered when
  a triangle below it holds a level above 0 from the last frame (the dead
  band could keep it there, so only the exact criterion can tell).
- The leaves reached are evaluated with :class:`LevelSelector`'s own
  per-triangle criterion and hysteresis rule (``_criterion``,
  ``Hysteresis.update_rows``) on those triangles only. Every dropped
  triangle is at level 0 in the flat selection too, so the levels are the
  flat selection's (``tests/test_quadtree.py``).

Modes whose criterion is not per-triangle (``acuity``, ``sse``, ``ipv``,
``dpv`` use the median distance of all visible triangles) are refused.
"""
from __future__ import annotations

import math

import numpy as np

from . import perception as pc
from .select import LevelSelector, SelectorConfig, View

HIERARCHY_MODES = ("csf", "gp", "distance", "full")
"""Modes :class:`QuadtreeSelector` supports: those whose level is a function of the triangle alone."""

# Slack on the bounds against rounding, deg and levels: the bound is a chain of closed forms whose
# float error is ~1e-12; these are far above it and far below anything that changes a level.
_ANGLE_SLACK_DEG = 1e-6
_LEVEL_SLACK = 1e-6
# Relative margin on the sup of f_max over the speed grid (the grid's error is ~1e-5).
_FMAX_MARGIN = 1.001


def sup_max_visible_freq_cpd(contrast, model: str = "kelly_scaled", speeds_deg_s=None):
    """Highest foveal f_max over all retinal speeds, per contrast, cpd, with a safety margin.

    ``max_visible_freq_cpd(C, v, 0)`` is not monotone in the speed ``v``
    (it peaks near 0.2 deg/s for low contrasts), so a bound valid for any
    speed takes its maximum over a fine logarithmic speed grid from the
    floor (0.1 deg/s) to 30 deg/s, times 1.001 (the grid's own error is
    ~1e-5 relative; f_max only falls beyond 30 deg/s).

    Parameters
    ----------
    contrast : (n,) array_like
        Michelson contrasts.
    model : one of perception.CSF_MODELS
    speeds_deg_s : (m,) array_like, optional
        The speed grid, deg/s.

    Returns
    -------
    (n,) ndarray
        sup over v of f_max(C, v, e=0), cpd (x 1.001); non-decreasing in C.
    """
    c = np.asarray(contrast, dtype=np.float64).reshape(-1)
    v = (np.logspace(math.log10(pc.MIN_SPEED_DEG_S), math.log10(30.0), 600) if speeds_deg_s is None
         else np.asarray(speeds_deg_s, dtype=np.float64))
    f = pc.max_visible_freq_cpd(c[:, None], v[None, :], 0.0, model=model)
    return f.max(axis=1) * _FMAX_MARGIN


class QuadTree:
    """Per-node bounds of a quadtree over a grid of quads (two base triangles per quad).

    Parameters
    ----------
    corners_mm : (F, 3, 3)
        Base triangles' corners, world frame, mm; F = 2 nx ny in
        ``BaseMesh.grid``'s order (face ``2 (j nx + i) + k`` in quad column i, row j).
    centroids_mm : (F, 3)
        Their centroids (the points the criterion is evaluated at), world mm.
    nx, ny : int
        Quads along the grid's x and y.
    margin_mm : (F,)
        Each triangle's culling margin on the screen plane, mm (its
        ``cull_margin_edges`` level-0 edges).

    Attributes
    ----------
    depth : int
        D: the leaves (quads) are at depth D, the root at 0.
    lo_mm, hi_mm : list of (4^d, 3) float64
        Per depth d, node ``j 2^d + i``'s box corners, world mm (+inf / -inf for an empty node).
    diameter_mm : list of (4^d,) float64
        Longest side of any triangle below the node, mm.
    reach_mm : list of (4^d,) float64
        Largest distance from a triangle's centroid to one of its corners below the node, mm.
    margin_mm : list of (4^d,) float64
        Widest culling margin below the node, mm.
    valid : list of (4^d,) bool
        The node holds at least one quad.
    """

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
        margin = np.asarray(margin_mm, dtype=np.float64).reshape(-1)

        def leaf(values, fill, reduce):
            reduced = reduce(values)                      # (ny, nx, ...)
            out = np.full((n, n) + reduced.shape[2:], fill)
            out[:ny, :nx] = reduced
            return out

        lo = leaf(points, np.inf, lambda p: p.min(axis=2))
        hi = leaf(points, -np.inf, lambda p: p.max(axis=2))
        per_quad = {"diameter": side, "reach": reach, "margin": margin}
        grids = {k: leaf(v.reshape(ny, nx, 2), -np.inf, lambda a: a.max(axis=2)) for k, v in per_quad.items()}
        valid = np.zeros((n, n), bool)
        valid[:ny, :nx] = True
        self.lo_mm, self.hi_mm, self.valid = [None] * (D + 1), [None] * (D + 1), [None] * (D + 1)
        self.diameter_mm, self.reach_mm, self.margin_mm = [None] * (D + 1), [None] * (D + 1), [None] * (D + 1)
        for d in range(D, -1, -1):                        # loop over depths, leaves up
            m = 2 ** d
            self.lo_mm[d], self.hi_mm[d] = lo.reshape(m * m, 3), hi.reshape(m * m, 3)
            self.valid[d] = valid.reshape(-1)
            self.diameter_mm[d] = grids["diameter"].reshape(-1)
            self.reach_mm[d] = grids["reach"].reshape(-1)
            self.margin_mm[d] = grids["margin"].reshape(-1)
            if d:
                lo = lo.reshape(m // 2, 2, m // 2, 2, 3).min(axis=(1, 3))
                hi = hi.reshape(m // 2, 2, m // 2, 2, 3).max(axis=(1, 3))
                valid = valid.reshape(m // 2, 2, m // 2, 2).any(axis=(1, 3))
                grids = {k: g.reshape(m // 2, 2, m // 2, 2).max(axis=(1, 3)) for k, g in grids.items()}
        self.contrast = None
        self._contrast_source = None

    @property
    def n_nodes(self) -> int:
        return sum(len(v) for v in self.valid)

    def set_contrast(self, contrast) -> None:
        """Per-node highest contrast from the triangles' (F,); recomputed only for a new array."""
        if contrast is self._contrast_source:
            return
        D, n = self.depth, 2 ** self.depth
        c = np.full((n, n), -np.inf)
        c[:self.ny, :self.nx] = np.asarray(contrast, dtype=np.float64).reshape(self.ny, self.nx, 2).max(axis=2)
        out = [None] * (D + 1)
        for d in range(D, -1, -1):                        # loop over depths
            out[d] = c.reshape(-1)
            if d:
                m = 2 ** d
                c = c.reshape(m // 2, 2, m // 2, 2).max(axis=(1, 3))
        self.contrast, self._contrast_source = out, contrast

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
    """:class:`LevelSelector` with the same ``select(View) -> (levels, info)``, walking a :class:`QuadTree`.

    The arguments are ``LevelSelector``'s, with ``corners_scene`` required
    and ``grid_shape = (ny, nx)``: the base triangles are those of
    ``BaseMesh.grid(terrain, nx, ny)``, in its order. The levels equal the
    flat selection's for the same sequence of views (module notes); the
    criterion is evaluated only on the triangles of the leaves reached.

    ``info`` has ``poi_px`` and ``cov_deg2`` as ``LevelSelector``'s, and
    the features for the evaluated triangles only: ``rows`` (k,) int, the
    base triangles evaluated, and ``eccentricity_deg``, ``speed_deg_s``,
    ``distance_mm``, ``continuous`` (k,) theirs (eccentricity NaN for the
    culled ones, continuous 0 for them as in the flat selection). Every
    other triangle is at level 0. :attr:`last_stats` gives
    ``nodes_visited`` (nodes whose bound was evaluated, leaves included),
    ``leaves`` (quads reached), ``triangles_evaluated`` and
    ``nodes_per_depth``.
    """

    def __init__(self, centroids_scene, edge_len_scene, geometric_error_scene, contrast, model, screen,
                 config: SelectorConfig = SelectorConfig(), *, corners_scene, grid_shape):
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
        self.tree = QuadTree(self.corners_mm, self.centroids_mm, nx, ny,
                             config.cull_margin_edges * self.edge_len_mm[:, 0])
        self._hot = None                # per depth: nodes with a triangle above level 0 (hysteresis)
        self._fmax_table = None         # (contrast grid, sup f_max) of mode csf
        self.last_stats: dict = {}
        tl = np.asarray(screen.top_left, dtype=np.float64)
        self._screen_uvn = (tl, np.asarray(screen.top_right, dtype=np.float64) - tl,
                            np.asarray(screen.bottom_left, dtype=np.float64) - tl)

    # ------------------------------------------------------------------ bounds
    def _fmax_sup(self, contrast):
        """sup over speeds of the foveal f_max at each contrast (k,), cpd, from a table (rounded up in C)."""
        top = max(1.0, float(np.max(contrast, initial=0.0)))
        if self._fmax_table is None or self._fmax_table[0][-1] < top:
            grid = np.concatenate([[0.0], np.logspace(-4, math.log10(top), 801)])
            self._fmax_table = (grid, sup_max_visible_freq_cpd(grid, self.config.csf_model))
        grid, table = self._fmax_table
        k = np.searchsorted(grid, contrast, side="left")        # grid[k] >= contrast: f_max rises with C
        return table[np.minimum(k, len(grid) - 1)]

    def _bound(self, d, nodes, eye, axes, cov):
        """Upper bound (k,) of the continuous level of any base triangle below ``nodes`` at depth d."""
        t, cfg = self.tree, self.config
        lo, hi = t.lo_mm[d][nodes], t.hi_mm[d][nodes]
        dmin = np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0), axis=1)
        if cfg.mode == "distance":
            return (self.max_level - np.log2(np.maximum(dmin / cfg.distance_ref_mm, 1e-9))
                    + float(cfg.level_bias) + _LEVEL_SLACK)
        # Smallest angle from the POI's direction V to the node's bounding sphere, deg. The offsets'
        # norm |(φ, θ)| is at least that angle, and the eccentricity of shifted offsets P' at least
        # atan(|P'| in rad).
        centre, radius = 0.5 * (lo + hi), 0.5 * np.linalg.norm(hi - lo, axis=1)
        rel = centre - eye
        dc = np.linalg.norm(rel, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_c = np.clip((rel @ axes[2]) / dc, -1.0, 1.0)
            half = np.degrees(np.arcsin(np.minimum(radius / dc, 1.0)))
        angle = np.maximum(np.degrees(np.arccos(cos_c)) - np.where(radius < dc, half, 180.0), 0.0)
        if cov is not None:
            S = np.asarray(cov, dtype=np.float64)
            lam = float(np.linalg.eigvalsh(0.5 * (S + S.T))[-1])
            if lam > 0:
                if cfg.shift == "ellipse":
                    angle = np.maximum(angle - cfg.ellipse_sigma * math.sqrt(lam), 0.0)
                else:                           # eq1: |P'| = (1 - exp(-q/2)) |P|, q >= |P|² / λmax
                    angle = -np.expm1(-0.5 * angle ** 2 / lam) * angle
        ecc = np.degrees(np.arctan(np.radians(angle)))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = t.reach_mm[d][nodes] / dmin
            reach = np.where(ratio < 1.0, np.degrees(np.arcsin(np.minimum(ratio, 1.0))), 180.0)
            diameter = np.degrees(2 * np.arcsin(np.minimum(t.diameter_mm[d][nodes] / (2 * dmin), 1.0)))
        diameter = np.where(dmin > 0, diameter, 180.0)
        ecc = np.maximum(ecc - reach - _ANGLE_SLACK_DEG, 0.0)
        contrast = t.contrast[d][nodes]
        if cfg.mode == "gp":
            fmax = pc.gp_cutoff_cpd(contrast, ecc)
        elif cfg.csf_model == "kelly_scaled":
            fmax = self._fmax_sup(contrast) / pc.eccentricity_factor(ecc)
        else:                                   # f_max(C, v, e) = f_max(C / (1 + 0.29 e), v, 0)
            fmax = self._fmax_sup(contrast / pc.eccentricity_factor(ecc))
        with np.errstate(divide="ignore"):
            return np.log2(np.maximum(fmax, 1e-12) * diameter) + float(cfg.level_bias) + _LEVEL_SLACK

    def _culled(self, d, nodes, eye):
        """(k,) bool: every centroid below the node projects outside the screen (with its margin), or behind."""
        t = self.tree
        lo, hi = t.lo_mm[d][nodes], t.hi_mm[d][nodes]
        box = np.stack([np.where(np.array(bits, bool), hi, lo)
                        for bits in np.ndindex(2, 2, 2)], axis=1) - eye           # (k, 8, 3)
        tl, u, v = self._screen_uvn
        normal = np.cross(u, v)
        k = (tl - eye) @ normal
        along = box @ normal                                                        # (k, 8)
        width, height = self.screen.size_px
        # Margin on the screen plane, widened by a hair against rounding.
        m = t.margin_mm[d][nodes][:, None] * (1 + 1e-9) + 1e-9
        out = np.zeros(len(nodes), bool)
        for axis, size_px in ((u, width), (v, height)):   # two screen axes, two sides each
            a = box @ axis
            h0 = (eye - tl) @ axis
            scale = axis @ axis
            mpx = m * self.px_per_mm / size_px * scale       # margin in the units of hit · axis
            # In front of the eye (s > 0): hit·axis >= -mpx  <=>  rel·axis + (h0 + mpx) (rel·n) / k >= 0.
            low_side = a + (h0 + mpx) / k * along
            high_side = -a + (scale + mpx - h0) / k * along
            out |= np.all(low_side < 0, axis=1) | np.all(high_side < 0, axis=1)
        return out

    # ------------------------------------------------------------------ selection
    def select(self, view: View):
        """Levels (F,) int, equal to ``LevelSelector.select``'s; info (class notes)."""
        cfg = self.config
        if cfg.mode == "full":
            return super().select(view)
        view, eye, axes, cov = self._frame(view)
        tree = self.tree
        tree.set_contrast(self.contrast)
        hot = self._hot if (self.hysteresis is not None and self.hysteresis.levels is not None) else None
        frontier = np.flatnonzero(tree.valid[0])
        visited = []
        for d in range(tree.depth + 1):                    # loop over depths, numpy over the frontier
            visited.append(len(frontier))
            keep = ~self._culled(d, frontier, eye) & (self._bound(d, frontier, eye, axes, cov) > 0)
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
        offsets = pc.view_offsets_deg(self.centroids_mm[seen], eye, axes)
        shifted = pc.uncertainty_shift(offsets, cov, cfg.shift, cfg.ellipse_sigma) if cov is not None else offsets
        ecc = np.full(len(rows), np.nan)
        continuous = np.zeros(len(rows))
        ecc[inside], continuous[inside] = self._criterion(seen, eye, shifted, distance[inside],
                                                          directions[inside], speed[inside])
        if self.hysteresis is not None:
            eager = None
            if self._gaze_speed(view.t, axes[2]) > cfg.hysteresis_eager_deg_s:
                with np.errstate(invalid="ignore"):
                    eager = ecc < cfg.hysteresis_eager_deg
            row_levels = self.hysteresis.update_rows(rows, continuous, self.max_level, eager=eager)
            levels = np.clip(self.hysteresis.levels, 0, self.max_level).astype(np.int64)
            self._hot = self._mark_hot(rows[row_levels > 0])
        else:
            levels = np.zeros(len(self.centroids_mm), dtype=np.int64)
            levels[rows] = pc.round_level(continuous, self.rounding, self.max_level)
        self.last_stats = {"nodes_visited": int(sum(visited)), "nodes_per_depth": visited,
                           "leaves": int(len(frontier)), "triangles_evaluated": int(len(rows))}
        return levels, {"rows": rows, "eccentricity_deg": ecc, "speed_deg_s": speed, "distance_mm": distance,
                        "continuous": continuous, "poi_px": np.asarray(view.poi_px, dtype=np.float64),
                        "cov_deg2": cov}

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
        dt = t - previous[0]
        rel = self.centroids_mm[rows] - previous[1]
        before = rel / np.linalg.norm(rel, axis=1)[:, None]
        cos = np.clip(np.einsum("ij,ij->i", directions, before), -1.0, 1.0)
        return np.maximum(np.degrees(np.arccos(cos)) / dt, pc.MIN_SPEED_DEG_S)

    def reset(self):
        super().reset()
        self._hot = None
