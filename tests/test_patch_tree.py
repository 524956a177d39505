"""The hierarchy over the tessellation patches (headplod.plod.patch_tree) and its GL draw path.

Against ground truth, each able to fail:

- A node's level bound equals a direct, one-node-at-a-time evaluation of the
  same closed form (scalar ``math`` plus ``perception.max_visible_freq_cpd``
  with its Lambert W, not the precomputed foveal f_max).
- Leaves reached by the tree get the flat selection's factors
  (:func:`patch_levels` + :func:`tess_factors`), inner and edges between leaves.
- Nodes are conservative on random views: every flat patch below a drawn node,
  and every flat patch edge along its border, gets at least its continuous
  CSF need (the largest gap between the node's vertices, rounded to samples,
  is at most the gap the patch's level asks for); every patch the flat box
  test keeps is under a drawn node.
- The drawn nodes tile the grid and are 2:1 balanced.
- The GPU's triangles are watertight across every neighbour pair, with
  forced mixed node sizes and on the scale bench's view (128² patches).
"""
import math

import numpy as np
import pytest

from headplod.plod import criteria, cull
from headplod.plod import perception as pc
from headplod.plod.patch_tree import EDGE_STEP, PatchTree
from headplod.plod.patches import PatchGrid, height_grid, patch_levels, tess_factors
from headplod.plod.select import SelectorConfig
from headplod.plod.terrain import Terrain
from headplod.plod.view import ConditionedView, head_axes
from headplod.render.projection import off_axis_projection
from headplod.render.still import default_head
from render_hooks import triangle_samples

COV = np.diag([0.05 ** 2, 0.05 ** 2])       # the bench's tracker σ


@pytest.fixture(scope="module")
def grid():
    """513² samples in patches of 16: 32² patches, a tree of depth 5."""
    terrain = Terrain.jacksboro(detail_min_wavelength_m=40.0)
    z, dx, dy = height_grid(terrain, 513)
    return PatchGrid.build(z, dx, dy, 16, origin_m=terrain.extent[::2])


def _view(screen, grid, poi_px=None, head_mm=None):
    from headplod.render.tessellate import grid_model

    head = default_head(screen) if head_mm is None else np.asarray(head_mm, float)
    poi = np.array(screen.size_px, float) / 2 if poi_px is None else np.asarray(poi_px, float)
    view, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    model = grid_model(grid, screen)
    return view, proj, model, head, head_axes(screen, head, poi), proj @ view @ model


def _cv(head, axes, cov, t=None):
    """The conditioned view of an unfiltered eye (world mm) and head axes, covariance (deg²) and time (s)."""
    return ConditionedView(t, np.asarray(head, float), np.zeros(2), axes, cov, np.asarray(head, float), np.zeros(2),
                           cov)


def _random_views(screen, grid, count, seed):
    rng = np.random.default_rng(seed)
    base = default_head(screen)
    for _ in range(count):
        head = base + rng.uniform([-150, -100, -200], [150, 100, 300])
        poi = rng.uniform([0, 0], screen.size_px)
        cov = np.diag(rng.uniform(0.0005, 0.5, 2))
        yield _view(screen, grid, poi, head), cov, float(rng.choice([0.0, -1.0, -2.5, 1.0]))


# ------------------------------------------------------------------------------------------------------------
# numpy


def test_node_bound_equals_direct_evaluation(grid, default_screen):
    tree = PatchTree(grid, split_factor=16, selection=SelectorConfig(mode="csf", level_bias=-0.5))
    view, proj, model, head, axes, mvp = _view(default_screen, grid, poi_px=(700.0, 500.0))
    f = tree._frame(_cv(head, axes, COV), model, mvp)
    ids = np.random.default_rng(0).choice(tree.offset[tree.depth], 60, replace=False)
    level, culled = tree.node_level_bound(ids, f)
    s_max = np.linalg.svd(model[:3, :3], compute_uv=False).max()
    s_min = np.linalg.svd(model[:3, :3], compute_uv=False).min()
    eye_s = np.linalg.solve(model, np.r_[head, 1.0])[:3]
    reach_shift = 2.0 * 0.05
    p = grid.patch_samples
    for k, i in enumerate(ids):
        d, r, c = (int(a[i]) for a in (tree.node_depth, tree.node_row, tree.node_col))
        s = p << (tree.depth - d)
        k0, k1 = r * s, (r + 1) * s
        j0, j1 = c * s, (c + 1) * s
        block = grid.heights_m[k0:k1 + 1, j0:j1 + 1]
        lo = np.array([grid.origin_m[0] + j0 * grid.dx_m, grid.origin_m[1] + k0 * grid.dy_m, block.min()])
        hi = np.array([grid.origin_m[0] + j1 * grid.dx_m, grid.origin_m[1] + k1 * grid.dy_m, block.max()])
        centre = model[:3, :3] @ ((lo + hi) / 2) + model[:3, 3] - head
        dist = math.sqrt(centre @ centre)
        radius = s_max * 0.5 * math.sqrt((hi - lo) @ (hi - lo))
        reach = math.degrees(math.asin(radius / dist)) if dist > radius else 180.0
        ecc_c = math.degrees(math.acos(np.clip(centre @ axes[2] / dist, -1, 1)))
        gap = np.maximum(np.maximum(lo - eye_s, eye_s - hi), 0)
        r_min = s_min * math.sqrt(gap @ gap)
        leaf_zr = max(float(np.ptp(grid.heights_m[a:a + p + 1, b:b + p + 1]))
                      for a in range(k0, k1, p) for b in range(j0, j1, p))
        chord = s_max * math.sqrt((p * grid.dx_m) ** 2 + (p * grid.dy_m) ** 2 + leaf_zr ** 2)
        diam = math.degrees(2 * math.asin(chord / (2 * r_min))) if r_min > chord / 2 else 180.0
        ecc = max(ecc_c - reach - reach_shift - diam - 1e-6, 0.0)
        contrast = grid.contrast[r << (tree.depth - d):(r + 1) << (tree.depth - d),
                                 c << (tree.depth - d):(c + 1) << (tree.depth - d)].max()
        fmax = float(pc.max_visible_freq_cpd(contrast, pc.MIN_SPEED_DEG_S, ecc, model="kelly_scaled"))
        expected = math.log2(max(fmax, criteria.FMAX_FLOOR_CPD) * (diam + 1e-6)) - 0.5 + criteria.LEVEL_SLACK
        # acos against the chord form, float64: ~1e-7 deg on ecc_c, far below a level.
        assert level[k] == pytest.approx(expected, abs=1e-6), (d, r, c)
        planes_out = False
        corners = np.array([[(lo, hi)[(q >> a) & 1][a] for a in range(3)] + [1.0] for q in range(8)]) @ mvp.T
        for a in range(3):
            planes_out |= bool(np.all(corners[:, a] < -corners[:, 3]) or np.all(corners[:, a] > corners[:, 3]))
        if culled[k]:
            assert planes_out                                       # the sphere test culls only boxes outside


def test_tree_leaves_equal_flat_levels(grid, default_screen):
    """Where the tree refines to leaves (patches of P samples), their factors are the flat selection's."""
    view, proj, model, head, axes, mvp = _view(default_screen, grid, poi_px=(700.0, 500.0))
    for split_factor, bias in ((16, 0.0), (4, -2.0)):
        tree = PatchTree(grid, split_factor=split_factor, selection=SelectorConfig(mode="csf", level_bias=bias))
        sel = tree.select(_cv(head, axes, COV), model, mvp=mvp)
        inner, outer = patch_levels(grid, model, head, axes, COV, level_bias=bias)
        top = tree.leaf_max_level
        leaf = sel.depth == tree.depth
        assert leaf.sum() > 50 and (~leaf).sum() >= (0 if split_factor == 16 else 10)
        r, c = sel.row[leaf], sel.col[leaf]
        np.testing.assert_array_equal(sel.inner[leaf], tess_factors(inner[r, c], top, grid.patch_samples, tree.factors))
        # Edges between two leaves: the flat edge factor (both sides compute it from the edge alone).
        depth_map = _depth_map(tree, sel)
        n = grid.n_patches
        for e, (dr, dc) in enumerate(EDGE_STEP):
            nr, nc = r + dr, c + dc
            inside = (nr >= 0) & (nr < n) & (nc >= 0) & (nc < n)
            both = inside.copy()
            both[inside] = depth_map[nr[inside], nc[inside]] == tree.depth
            np.testing.assert_array_equal(sel.outer[leaf][both, e], tess_factors(outer[r[both], c[both], e], top,
                                                                                    grid.patch_samples, tree.factors))


def _depth_map(tree, sel):
    """(n, n) depth of the drawn node over each leaf cell (-1: none)."""
    n = tree.grid.n_patches
    out = np.full((n, n), -1)
    for d, r, c in zip(sel.depth, sel.row, sel.col):
        k = tree.depth - d
        assert (out[r << k:(r + 1) << k, c << k:(c + 1) << k] == -1).all(), "nodes overlap"
        out[r << k:(r + 1) << k, c << k:(c + 1) << k] = d
    return out


@pytest.mark.slow
def test_nodes_are_conservative_on_random_views(grid, default_screen):
    """Every flat patch (and patch edge on a node's border) below a drawn node gets at least its need."""
    p = grid.patch_samples
    mixed = 0
    for (view, proj, model, head, axes, mvp), cov, bias in _random_views(default_screen, grid, 12, seed=7):
        tree = PatchTree(grid, split_factor=8, selection=SelectorConfig(mode="csf", level_bias=bias))
        sel = tree.select(_cv(head, axes, cov), model, mvp=mvp)
        assert sel.capped == 0
        inner, outer = patch_levels(grid, model, head, axes, cov, level_bias=bias)
        top = tree.leaf_max_level
        # The gap the flat patch's continuous level asks for, samples (its level clamped to what a patch can show).
        need_gap = p * np.exp2(-np.clip(np.nan_to_num(inner, neginf=-60.0), -60.0, top))
        need_gap_edge = p * np.exp2(-np.clip(np.nan_to_num(outer, neginf=-60.0), -60.0, top))
        mixed += len(np.unique(sel.depth)) > 1
        for d, r, c, size, fi, fo in zip(sel.depth, sel.row, sel.col, sel.size, sel.inner, sel.outer):
            k = tree.depth - d
            rows, cols = slice(r << k, (r + 1) << k), slice(c << k, (c + 1) << k)
            if k == 0:
                continue                                             # leaves: the flat factors (test above)
            assert math.ceil(size / fi) <= need_gap[rows, cols].min() + 1e-9, (d, r, c, fi)
            # Border edges: the node's edge factor against each flat patch edge along it.
            borders = (need_gap_edge[rows, (c << k)][:, 0], need_gap_edge[(r << k), cols][:, 1],
                       need_gap_edge[rows, ((c + 1) << k) - 1][:, 2], need_gap_edge[((r + 1) << k) - 1, cols][:, 3])
            for e in range(4):
                assert math.ceil(size / fo[e]) <= borders[e].min() + 1e-9, (d, r, c, e, fo[e])
        # Coverage: every patch the flat box test keeps is under a drawn node.
        leaves = tree.offset[tree.depth] + np.arange(grid.n_patches ** 2)
        visible = ~cull.box_outside_clip(cull.box_corners(tree.box_lo_m[leaves], tree.box_hi_m[leaves]), mvp)
        assert np.all(_depth_map(tree, sel).ravel()[visible] >= 0)
    assert mixed >= 6                                                # the views do mix node sizes


def test_nodes_tile_the_grid_balanced(grid, default_screen):
    for (view, proj, model, head, axes, mvp), cov, bias in _random_views(default_screen, grid, 6, seed=3):
        tree = PatchTree(grid, split_factor=4, selection=SelectorConfig(mode="csf", level_bias=bias - 1.0))
        sel = tree.select(_cv(head, axes, cov), model, mvp=None)                          # nothing culled
        depth = _depth_map(tree, sel)
        assert (depth >= 0).all()                                                          # tiled, no overlap
        assert np.abs(np.diff(depth, axis=0)).max() <= 1 and np.abs(np.diff(depth, axis=1)).max() <= 1
        assert sel.inner.min() >= 1 and np.all(sel.inner <= np.minimum(sel.size, 64))
        assert np.all(sel.outer <= np.minimum(sel.size, 64)[:, None])


def test_rejects_bad_grids_and_settings(grid):
    terrain = Terrain.jacksboro(detail_min_wavelength_m=80.0)
    z, dx, dy = height_grid(terrain, 97)
    with pytest.raises(ValueError, match="power of two"):
        PatchTree(PatchGrid.build(z, dx, dy, 16))                    # 6 patches per side
    with pytest.raises(ValueError, match="split_factor"):
        PatchTree(grid, split_factor=128)
    with pytest.raises(ValueError, match="max_tess_level"):
        PatchTree(grid, max_tess_level=48)
    with pytest.raises(ValueError, match="kelly_scaled"):
        PatchTree(grid, selection=SelectorConfig(mode="csf", csf_model="kelly"))


# ------------------------------------------------------------------------------------------------------------
# GL


def _assert_watertight(tri, n):
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]).reshape(-1, 4)
    swap = (e[:, 0] > e[:, 2]) | ((e[:, 0] == e[:, 2]) & (e[:, 1] > e[:, 3]))
    e[swap] = e[swap][:, [2, 3, 0, 1]]
    a, b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    assert np.all(area > 0)
    assert area.sum() == pytest.approx(float(n) ** 2, abs=1e-6)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    border = (((edges[:, 0] == edges[:, 2]) & np.isin(edges[:, 0], (0, n)))
              | ((edges[:, 1] == edges[:, 3]) & np.isin(edges[:, 1], (0, n))))
    assert np.all(counts[border] == 1)
    assert np.all(counts[~border] == 2), f"{np.sum(counts[~border] != 2)} edges not shared by two triangles"


@pytest.mark.slow
@pytest.mark.parametrize("split_factor, bias, poi", [(4, -3.0, (700.0, 500.0)), (16, -3.0, (100.0, 900.0)),
                                                     (8, -2.0, (1500.0, 300.0))])
def test_hierarchy_is_watertight_across_sizes(ctx430, grid, default_screen, split_factor, bias, poi):
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    cfg = TessellationConfig(patch_samples=16, cull=False, hierarchy=True, split_factor=split_factor)
    view, proj, model, head, axes, _ = _view(default_screen, grid, poi_px=poi)
    with TessellationRenderer(ctx430, grid, size=(64, 36), config=cfg,
                              selection=SelectorConfig(mode="csf", level_bias=bias)) as r:
        tri = triangle_samples(r, view, proj, model, _cv(head, axes, COV))
        sel = r.last_selection
    assert len(np.unique(sel.size)) >= 3                          # nodes of three sizes or more meet
    assert np.any(sel.outer & (sel.outer - 1))                    # whole-number factors that are not powers of two
    assert sel.evaluated > 0 and sel.capped == 0
    _assert_watertight(tri, grid.heights_m.shape[0] - 1)


@pytest.mark.slow
def test_hierarchy_is_watertight_on_the_scale_view(ctx430, default_screen):
    """The scale bench's view (head, POI at the centre, σ 0.05°) over 128² patches, as 8193² in patches of 64."""
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    terrain = Terrain.jacksboro(detail_min_wavelength_m=40.0)
    z, dx, dy = height_grid(terrain, 2049)
    big = PatchGrid.build(z, dx, dy, 16, origin_m=terrain.extent[::2])
    view, proj, model, head, axes, _ = _view(default_screen, big)
    cfg = TessellationConfig(patch_samples=16, cull=False, hierarchy=True)
    with TessellationRenderer(ctx430, big, size=(64, 36), config=cfg) as r:
        tri = triangle_samples(r, view, proj, model, _cv(head, axes, COV), capacity=1 << 22)
        sel = r.last_selection
    assert len(np.unique(sel.depth)) >= 3
    _assert_watertight(tri, 2048)


@pytest.mark.slow
def test_hierarchy_renders_like_flat(ctx430, grid, default_screen):
    """Both paths draw the terrain; where the tree refines to leaves the frames agree within the disc."""
    from headplod.render.frame import FrameSettings, one_frame
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer, grid_model

    model = grid_model(grid, default_screen)
    images = {}
    for hierarchy in (False, True):
        cfg = TessellationConfig(patch_samples=16, hierarchy=hierarchy)
        with TessellationRenderer(ctx430, grid, size=(320, 180), config=cfg) as r:
            first = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=COV, t=0.0, renderer=r)
            again = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=COV, t=1 / 60, renderer=r)
        images[hierarchy] = first.image
        assert np.array_equal(first.image, again.image) and again.triangles == first.triangles > 0
    diff = np.abs(images[True].astype(int) - images[False].astype(int))
    assert np.mean(diff) < 1.0


def test_moving_eye_nodes_stay_conservative(grid, default_screen):
    """With the eye moving, leaves take each point's speed and nodes the sup of f_max over every speed:
    every flat patch (evaluated with the shader's per-point speed) below a node still gets its need."""
    from headplod.plod.patches import levels_of_patches

    view, proj, model, head, axes, mvp = _view(default_screen, grid, poi_px=(500.0, 400.0))
    prev, dt = head + np.array([8.0, -3.0, 5.0]), 1 / 60
    tree = PatchTree(grid, split_factor=8, selection=SelectorConfig(mode="csf", level_bias=-1.0))
    tree.select(_cv(prev, axes, COV, t=0.0), model, mvp=mvp)           # the last frame: the eye at prev
    sel = tree.select(_cv(head, axes, COV, t=dt), model, mvp=mvp)
    tree.reset()
    still = tree.select(_cv(head, axes, COV, t=dt), model, mvp=mvp)
    n, p = grid.n_patches, grid.patch_samples
    inner, _ = levels_of_patches(grid.corners_scene(), grid.contrast, grid.neighbour_contrast(), model, head, axes, COV,
                                 level_bias=-1.0, eye_prev_mm=prev, dt_s=dt)
    need_gap = p * np.exp2(-np.clip(np.nan_to_num(inner, neginf=-60.0), -60.0, tree.leaf_max_level))
    assert not np.array_equal(sel.inner, still.inner) or len(sel) != len(still)      # the motion is seen
    for d, r, c, size, fi in zip(sel.depth, sel.row, sel.col, sel.size, sel.inner):
        k = tree.depth - d
        if k:
            assert math.ceil(size / fi) <= need_gap[r << k:(r + 1) << k, c << k:(c + 1) << k].min() + 1e-9
        else:
            assert fi == tess_factors(inner[r, c], tree.leaf_max_level, p, tree.factors)
    assert n == 32
