"""The quadtree selection (headplod.bench.quadtree_selector) against the flat one (headplod.plod.select)."""
import dataclasses

import numpy as np
import pytest

from headplod.bench.quadtree_selector import QuadTree, QuadtreeSelector, scene_quadtree_selector
from headplod.plod.criteria import sup_max_visible_freq_cpd
from headplod.plod.select import LevelSelector, SelectorConfig, View
from headplod.plod.view import ViewConditioner
from raw_views import RawViews


def _pair(mesh, model, screen, config=SelectorConfig(mode="csf"), grid_shape=(32, 32)):
    args = (mesh["centroids"], mesh["edge_length"], mesh["geometric_error"], mesh["contrast"], model, screen, config)
    return (LevelSelector(*args, corners_scene=mesh["corners"]),
            QuadtreeSelector(*args, corners_scene=mesh["corners"], grid_shape=grid_shape))


@pytest.fixture(scope="module")
def builtin(terrain_scene):
    m = terrain_scene.mesh
    return {"centroids": m.centroids, "edge_length": m.edge_length, "geometric_error": m.geometric_error,
            "contrast": m.contrast, "corners": m.corners}


def _views(screen, poi_px, cov, frames, seed, moving):
    """A noisy head at the default distance; the POI still (with noise) or sweeping 40 px per frame."""
    from headplod.render.still import default_head

    rng = np.random.default_rng(seed)
    head = default_head(screen)
    step = np.array([40.0, -15.0]) if moving else np.zeros(2)
    return [View(head + rng.normal(0, 0.5, 3), np.asarray(poi_px, float) + k * step + rng.normal(0, 3.0, 2),
                 None if cov is None else np.asarray(cov) * (1 + 0.05 * k), k / 30.0) for k in range(frames)]


W, H = 1920, 1080
POIS = {"centre": (W / 2, H / 2), "top left": (0.0, 0.0), "top right": (W, 0.0), "bottom left": (0.0, H),
        "bottom right": (W, H)}


@pytest.mark.slow
@pytest.mark.parametrize("viewpoint", [None, "overview", "mountains", "plains"])
@pytest.mark.parametrize("poi", list(POIS))
@pytest.mark.parametrize("cov", [None, ((0.4, 0.1), (0.1, 0.9))], ids=["no cov", "cov"])
def test_quadtree_levels_equal_the_flat_ones_on_the_builtin_scene(terrain_scene, builtin, viewpoint, poi, cov):
    from headplod.demo.viewpoints import place

    scene = terrain_scene if viewpoint is None else place(terrain_scene, viewpoint)
    flat, tree = (RawViews(s) for s in _pair(builtin, scene.model, scene.screen))
    # A first frame, then noise and a POI sweeping in (hysteresis, its eager band, the filters' jumps).
    for moving in (False, True):
        for view in _views(scene.screen, POIS[poi], cov, 6, seed=len(poi), moving=moving):
            a, info_a = flat.select(view)
            b, info_b = tree.select(view)
            np.testing.assert_array_equal(a, b)
            rows = info_b["rows"]
            np.testing.assert_array_equal(info_a["continuous"][rows], info_b["continuous"])
        flat.reset()
        tree.reset()


@pytest.mark.slow
def test_the_scene_gives_a_quadtree_selector_on_request(terrain_scene):
    sel = scene_quadtree_selector(terrain_scene, "csf", "adaptive")
    assert isinstance(sel, QuadtreeSelector) and (sel.tree.nx, sel.tree.ny) == (32, 32)
    flat = terrain_scene.selector("csf", "adaptive")
    view = _views(terrain_scene.screen, POIS["centre"], None, 1, seed=0, moving=False)[0]
    np.testing.assert_array_equal(RawViews(flat).select(view)[0], RawViews(sel).select(view)[0])


@pytest.mark.slow
@pytest.mark.parametrize("settings", [{"hysteresis": False}, {"mode": "gp"}, {"mode": "distance"},
                                      {"csf_model": "kelly"}, {"shift": "eq1"}, {"level_bias": -1.0},
                                      {"uncertainty": "fixed"}])
def test_quadtree_equals_flat_in_other_settings(terrain_scene, builtin, settings):
    config = dataclasses.replace(SelectorConfig(mode="csf"), **settings)
    flat, tree = (RawViews(s) for s in _pair(builtin, terrain_scene.model, terrain_scene.screen, config))
    for view in _views(terrain_scene.screen, POIS["centre"], ((0.3, 0), (0, 0.2)), 8, seed=3, moving=True):
        np.testing.assert_array_equal(flat.select(view)[0], tree.select(view)[0])


# ----------------------------------------------------------------------------- a small synthetic grid
class _Hills:
    """A small terrain-like surface (m): sines on a 3 km x 2 km extent, for :func:`grid_inputs`."""

    extent = (0.0, 3000.0, 0.0, 2000.0)

    def sample(self, x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        z = 150 * np.sin(x / 400.0) * np.cos(y / 300.0) + 40 * np.sin(x / 90.0 + y / 70.0)
        gx = 150 / 400.0 * np.cos(x / 400.0) * np.cos(y / 300.0) + 40 / 90.0 * np.cos(x / 90.0 + y / 70.0)
        gy = -150 / 300.0 * np.sin(x / 400.0) * np.sin(y / 300.0) + 40 / 70.0 * np.cos(x / 90.0 + y / 70.0)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return z, n / np.linalg.norm(n, axis=-1, keepdims=True)


def _hills_model(screen, scale_mm_per_m, pitch_deg):
    from headplod.render.projection import scene_to_world

    return np.asarray(scene_to_world(scale_mm_per_m, np.array([1500.0, 1000.0, 0.0]), screen, depth_mm=200.0,
                                     pitch_deg=pitch_deg).matrix, dtype=np.float64)


@pytest.fixture(scope="module")
def hills():
    from headplod.bench.plod_quadtree import grid_inputs

    return grid_inputs(_Hills(), 13, 9, max_level=5)       # not a power of two: padded nodes


def test_node_bounds_are_conservative_for_random_views(default_screen, hills):
    """Property: for every node of every depth, every base triangle below it has a continuous level at most
    the node's bound, and a node found culled holds only triangles the flat selection culls. Random views:
    eye within ±150 mm, POI anywhere on (and beyond) the screen, covariance or not, placements and biases."""
    from headplod.render.still import default_head

    rng = np.random.default_rng(7)
    head = default_head(default_screen)
    checked = culled_nodes = 0
    for trial in range(40):
        model = _hills_model(default_screen, rng.uniform(0.05, 0.4), rng.uniform(10, 80))
        config = SelectorConfig(hysteresis=False, level_bias=float(rng.uniform(-1, 1)),
                                mode=str(rng.choice(["csf", "csf", "gp", "distance"])),
                                shift=str(rng.choice(["ellipse", "eq1"])))
        flat, tree = _pair(hills, model, default_screen, config, grid_shape=hills["grid_shape"])
        cov = None if trial % 3 == 0 else np.diag(rng.uniform(0.01, 4.0, 2))
        view = View(head + rng.uniform(-150, 150, 3), rng.uniform([-300, -300], [W + 300, H + 300]), cov, None)
        cv = ViewConditioner(default_screen, config)(view)        # t None: the filters are bypassed
        _, info = flat.select(cv)
        frame = tree._frame_context(cv.eye_mm, cv.axes, cv.cov_deg2)
        faces = np.arange(len(hills["centroids"]))
        for d, nodes in enumerate(tree.tree.ancestors(faces)):
            culled, bound = tree._node_bounds(d, nodes, frame)
            assert np.all(info["continuous"] <= bound + 1e-9), (trial, d)
            assert np.all(np.isnan(info["eccentricity_deg"][culled])), (trial, d)
            checked += len(nodes)
            culled_nodes += int(culled.sum())
    assert checked > 10_000 and culled_nodes > 0          # the property was exercised, culling included


def test_sup_of_fmax_bounds_every_speed():
    from headplod.plod import perception as pc

    contrast = np.array([0.005, 0.02, 0.1, 0.4, 1.0])
    speeds = np.concatenate([[0.1, 0.1001, 0.15, 0.2, 0.25], np.logspace(-1, 2.5, 500)])
    every = pc.max_visible_freq_cpd(contrast[:, None], speeds[None, :], 0.0)
    assert np.all(sup_max_visible_freq_cpd(contrast) >= every.max(axis=1))
    assert np.all(np.diff(sup_max_visible_freq_cpd(np.linspace(0, 1, 50))) >= 0)   # the table's lookup relies on it


def test_tree_layout_and_padding(hills):
    corners = hills["corners"]
    tree = QuadTree(corners, hills["centroids"], 13, 9, np.ones(len(corners)))
    assert tree.depth == 4 and tree.n_nodes == sum(int(v.sum()) for v in tree.valid)
    assert tree.valid[4].sum() == 13 * 9 and tree.valid[0].all()
    # The root's box holds every corner; each leaf's faces are its quad's two triangles.
    root = tree.table[0][0]
    assert np.all(np.abs(corners.reshape(-1, 3) - root[:3]) <= root[3:6] + 1e-9)
    leaves = np.flatnonzero(tree.valid[4])
    assert sorted(tree.faces(leaves)) == list(range(len(corners)))


def test_refuses_modes_that_are_not_per_triangle(default_screen, hills):
    for mode in ("acuity", "sse", "ipv", "dpv"):
        with pytest.raises(ValueError, match="not per triangle"):
            _pair(hills, np.eye(4), default_screen, SelectorConfig(mode=mode), grid_shape=hills["grid_shape"])
    with pytest.raises(ValueError, match="grid_shape"):
        _pair(hills, np.eye(4), default_screen, grid_shape=(9, 12))


# ----------------------------------------------------------------------------- cost
@pytest.mark.slow
def test_cost_follows_what_is_seen_on_a_fine_grid(default_screen):
    """256² quads of the built-in terrain (131k base triangles) from the default view: the same levels as
    the flat selection, with a small fraction of the nodes and triangles evaluated."""
    from headplod.bench.plod_quadtree import default_model, default_views, grid_inputs
    from headplod.plod.terrain import Terrain

    terrain = Terrain.jacksboro()
    g = grid_inputs(terrain, 256, 256)
    flat, tree = _pair(g, default_model(terrain, default_screen), default_screen, grid_shape=g["grid_shape"])
    raw_flat, raw_tree = RawViews(flat), RawViews(tree)
    F = len(g["centroids"])
    for view in default_views(default_screen, 3):
        np.testing.assert_array_equal(raw_flat.select(view)[0], raw_tree.select(view)[0])
        st = tree.last_stats
        assert st["nodes_visited"] < 0.2 * F and st["triangles_evaluated"] < 0.2 * F, st


def test_the_selection_bench_runs_both_selectors_through_frame_steps(default_screen):
    """bench plod --only quadtree on the smallest grid: the frame step's select stage of each selector,
    the same levels on every frame."""
    from headplod.bench.plod_quadtree import selection_scaling

    report = selection_scaling((32,), frames=3, screen=default_screen, deep=())
    (row,) = report["rows"]
    assert row["mismatched_levels"] == 0 and row["levels_above_0"] > 0
    assert row["flat_ms"] > 0 and row["quadtree_ms"] > 0 and 0 < row["nodes_visited"] <= row["tree_nodes"]
    assert report["growth_2M_to_128M"] == {"256x256_level5": None, "32x32_level8": None}


def test_the_quadtree_selector_takes_only_a_conditioned_view(default_screen, hills):
    """Like the flat selector, it conditions nothing: a raw View is a TypeError."""
    from headplod.render.still import default_head

    _, tree = _pair(hills, np.eye(4), default_screen, grid_shape=hills["grid_shape"])
    with pytest.raises(TypeError, match=r"^QuadtreeSelector\.select takes a ConditionedView .*, got View$"):
        tree.select(View(default_head(default_screen), np.array([960.0, 540.0])))
    assert not hasattr(tree, "conditioner") and not hasattr(tree, "condition")
