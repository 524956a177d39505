"""LazyAdaptiveMesh: AdaptiveMesh's triangles made on demand, in a byte-bounded cache, watertight."""
import numpy as np
import pytest

from headplod.bench.harness import TRACKER_COV_DEG2
from headplod.bench.quadtree_selector import scene_quadtree_selector
from headplod.plod.lazy_mesh import LazyAdaptiveMesh
from headplod.plod.mesh import AdaptiveMesh, BaseMesh
from headplod.plod.terrain import Terrain
from raw_views import RawViews


@pytest.fixture(scope="module")
def terrain():
    return Terrain.jacksboro()


@pytest.fixture(scope="module")
def pair(terrain):
    """An 8 x 6 base at level 5: (AdaptiveMesh, LazyAdaptiveMesh) over the same base."""
    base = BaseMesh.grid(terrain, 8, 6)
    return AdaptiveMesh(base, terrain, max_level=5), LazyAdaptiveMesh(base, terrain, max_level=5)


def _selections(n_faces, max_level, seed):
    """Level arrays: uniform ones, random mixes (neighbours up to max_level apart), a hot spot."""
    rng = np.random.default_rng(seed)
    spot = np.zeros(n_faces, np.int64)
    spot[n_faces // 3: n_faces // 3 + 5] = max_level
    spot[n_faces // 3 + 5: n_faces // 3 + 9] = max(max_level - 1, 0)
    return [np.zeros(n_faces, np.int64), np.full(n_faces, max_level), spot,
            rng.integers(0, max_level + 1, n_faces), rng.integers(0, max_level + 1, n_faces)]


def _per_face(mesh, soup):
    """{face: (positions (3t, 3), normals (3t, 3), levels (t,))} of a soup, per base face."""
    positions, normals, tri_levels = soup
    faces = mesh.face_per_triangle()
    out = {}
    for f in np.unique(faces).tolist():     # loop over faces: a test helper
        t = np.flatnonzero(faces == f)
        rows = (3 * t[:, None] + np.arange(3)).ravel()
        out[f] = (positions[rows], normals[rows], tri_levels[t])
    return out


@pytest.mark.slow
def test_equals_adaptive_mesh_per_base_triangle(pair):
    """Same triangles, bit for bit, per base face, and in the same order as a build from scratch."""
    adaptive, lazy = pair
    for levels in _selections(adaptive.n_faces, 5, seed=1):
        adaptive.clear()
        a = adaptive.update(levels)
        b = lazy.update(levels)
        assert len(b[2]) == len(a[2]) == adaptive.triangle_count(levels)
        np.testing.assert_array_equal(np.bincount(b[2], minlength=6), np.bincount(a[2], minlength=6))
        pa, pb = _per_face(adaptive, a), _per_face(lazy, b)
        assert pa.keys() == pb.keys()
        for f in pa:
            for x, y in zip(pa[f], pb[f]):
                np.testing.assert_array_equal(x, y, err_msg=f"face {f}")
        np.testing.assert_array_equal(a[0], b[0])


@pytest.mark.slow
def test_equals_adaptive_mesh_on_the_built_in_scene():
    """The built-in scene (32 x 32 base, level 5): the default view's csf/quadtree selection and a mixed
    one give AdaptiveMesh's soup bit for bit, and the selector inputs are AdaptiveMesh's."""
    from calib import DEFAULT_SCREEN

    from headplod import io
    from headplod.plod.select import View
    from headplod.render.still import TerrainScene, default_head

    screen = io.read_screen(DEFAULT_SCREEN)
    scene = TerrainScene.build(screen)
    adaptive = scene.mesh
    lazy = LazyAdaptiveMesh(adaptive.base, scene.terrain, max_level=5)
    for name in ("centroids", "corners", "edge_length", "geometric_error", "contrast"):
        np.testing.assert_array_equal(getattr(adaptive, name), getattr(lazy, name), err_msg=name)
    selector = RawViews(scene_quadtree_selector(scene, "csf", "adaptive"))
    levels, _ = selector.select(View(default_head(screen), np.array(screen.size_px, dtype=np.float64) / 2,
                                     TRACKER_COV_DEG2, 0.0))
    assert len(np.unique(levels)) >= 4                          # neighbours at mixed levels
    for lv in (levels, _selections(adaptive.n_faces, 5, seed=3)[3]):
        adaptive.clear()
        for x, y in zip(adaptive.update(lv), lazy.update(lv)):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(adaptive.face_per_triangle(), lazy.face_per_triangle())


def test_indices_address_the_frame_table(pair):
    _, lazy = pair
    levels = _selections(lazy.n_faces, 5, seed=2)[3]
    indices, tri_levels = lazy.update_indices(levels)
    positions, normals, _ = lazy.update(levels)
    assert indices.dtype == np.uint32 and indices.max() < len(lazy.vertex_positions)
    np.testing.assert_array_equal(lazy.vertex_positions[indices], positions)
    np.testing.assert_array_equal(lazy.vertex_normals[indices], normals)
    # Compact: the rows no triangle uses are only copies of base vertices (an edge's far end).
    unused = np.setdiff1d(np.arange(len(lazy.vertex_positions)), indices)
    base = lazy.base.vertices.astype(np.float32)
    assert all(np.any(np.all(base == p, axis=1)) for p in lazy.vertex_positions[unused])


def test_equals_adaptive_mesh_at_lower_levels(terrain):
    """max_level 0..3, and the per-face data the selectors read, are AdaptiveMesh's."""
    base = BaseMesh.grid(terrain, 4, 3)
    for M in range(4):
        a, b = AdaptiveMesh(base, terrain, max_level=M), LazyAdaptiveMesh(base, terrain, max_level=M)
        for name in ("centroids", "corners", "edge_length", "geometric_error", "contrast", "z_range",
                     "bounding_radius"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        for levels in _selections(a.n_faces, M, seed=M):
            a.clear()
            for x, y in zip(a.update(levels), b.update(levels)):
                np.testing.assert_array_equal(x, y)


def _check_watertight(positions, extent):
    """Every welded edge is shared by exactly two triangles, one on the terrain's outer boundary."""
    welded, inverse = np.unique(positions, axis=0, return_inverse=True)
    tris = inverse.reshape(-1, 3)
    assert np.all((tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])), \
        "a triangle has two equal corners"
    edges = np.sort(np.stack([tris, np.roll(tris, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    x0, x1, y0, y1 = extent
    a, b = welded[unique[:, 0]], welded[unique[:, 1]]
    on_boundary = np.zeros(len(unique), bool)
    for axis, value in ((0, x0), (0, x1), (1, y0), (1, y1)):      # the four sides
        on_boundary |= (a[:, axis] == np.float32(value)) & (b[:, axis] == np.float32(value))
    assert np.all(counts[~on_boundary] == 2), \
        f"{int(np.sum(counts[~on_boundary] != 2))} interior edges not shared by exactly two triangles"
    assert np.all(counts[on_boundary] == 1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_watertight_across_every_neighbour_pair_at_mixed_levels(terrain, seed):
    """Random levels 0..7 on a 3 x 2 base: every pair of neighbours, any jump between their levels."""
    base = BaseMesh.grid(terrain, 3, 2)
    lazy = LazyAdaptiveMesh(base, terrain, max_level=7, cache_bytes=4 * 2 ** 20)
    rng = np.random.default_rng(seed)
    for _ in range(3):
        levels = rng.integers(0, 8, lazy.n_faces)
        positions, _, tri_levels = lazy.update(levels)
        assert len(tri_levels) == lazy.triangle_count(levels)
        _check_watertight(positions, terrain.extent)


@pytest.mark.slow
def test_watertight_level_8_next_to_level_0(terrain):
    """The biggest jump at the finest level: a level-8 face among level-0 and level-4 faces."""
    base = BaseMesh.grid(terrain, 2, 2)
    lazy = LazyAdaptiveMesh(base, terrain, max_level=8)
    levels = np.array([8, 0, 4, 8, 0, 0, 7, 1])
    positions, _, tri_levels = lazy.update(levels)
    assert len(tri_levels) == lazy.triangle_count(levels)
    _check_watertight(positions, terrain.extent)


@pytest.mark.slow
def test_cache_stays_within_its_budget_and_evicts(terrain):
    """A hot spot walking over the base: the cache never exceeds its budget, evicts the pieces left
    behind, and the frames stay those of an unbounded cache (pieces made again are the same)."""
    base = BaseMesh.grid(terrain, 8, 6)
    budget = 256 * 2 ** 10
    small = LazyAdaptiveMesh(base, terrain, max_level=6, cache_bytes=budget)
    large = LazyAdaptiveMesh(base, terrain, max_level=6)
    evicted = 0
    F = small.n_faces
    for k in range(0, F - 8, 6):                 # the spot moves 3 quads a frame
        levels = np.zeros(F, np.int64)
        levels[k:k + 4] = 6
        levels[k + 4:k + 8] = 5
        a = small.update(levels)
        assert small.cache_bytes <= budget
        assert small.cache_bytes == sum(p.nbytes + n.nbytes for p, n in small._cache.values())
        evicted += small.stats["evicted_pieces"]
        b = large.update(levels)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
        _check_watertight(a[0], terrain.extent)
    assert evicted > 0, "a 256 kB cache never evicted"
    # Back to a spot seen long ago: its pieces were freed and are made again.
    levels = np.zeros(F, np.int64)
    levels[:4] = 6
    small.update(levels)
    assert small.stats["generated_pieces"] > 0


def test_idle_pieces_are_freed_when_out_of_view(terrain):
    """With ``idle_frames``, a spot's pieces go once it has been out of the selection that many frames,
    though the budget has room; the cache then holds only what recent frames used."""
    base = BaseMesh.grid(terrain, 6, 4)
    lazy = LazyAdaptiveMesh(base, terrain, max_level=5, idle_frames=2)
    F = lazy.n_faces
    first = np.zeros(F, np.int64)
    first[:4] = 5
    lazy.update(first)
    held = lazy.cache_bytes
    assert held > 0 and any(k[0] == "f" and k[1] == 0 for k in lazy._cache)
    for k in range(3):                                     # three frames elsewhere (each a new selection)
        levels = np.zeros(F, np.int64)
        levels[F - 4 - k:F - k] = 5
        lazy.update(levels)
    assert not any(k[0] == "f" and k[1] == 0 for k in lazy._cache), "face 0's pieces outlived idle_frames"
    assert lazy.stats["evicted_pieces"] > 0 and lazy.cache_bytes < lazy.budget_bytes
    with pytest.raises(ValueError, match="idle_frames"):
        LazyAdaptiveMesh(base, terrain, max_level=1, idle_frames=0)


def test_rejects_bad_settings(terrain):
    base = BaseMesh.grid(terrain, 2, 2)
    with pytest.raises(ValueError, match="max_level"):
        LazyAdaptiveMesh(base, terrain, max_level=9)
    with pytest.raises(ValueError, match="cache_bytes"):
        LazyAdaptiveMesh(base, terrain, max_level=2, cache_bytes=0)
    lazy = LazyAdaptiveMesh(base, terrain, max_level=2)
    with pytest.raises(ValueError, match="levels"):
        lazy.update(np.full(lazy.n_faces, 3))


@pytest.mark.slow
def test_level_8_default_view_builds_within_the_budget():
    """The 32 x 32 base at level 8, the default view's csf/quadtree selection, and one with the level
    bias raised by 3 (so that faces reach levels 6..8): built within a 256 MB cache."""
    from calib import DEFAULT_SCREEN

    from headplod import io
    from headplod.plod.select import View
    from headplod.render.still import TerrainScene, default_head

    screen = io.read_screen(DEFAULT_SCREEN)
    scene = TerrainScene.build(screen, max_level=0)
    terrain = scene.terrain
    budget = 256 * 2 ** 20
    lazy = LazyAdaptiveMesh(BaseMesh.grid(terrain), terrain, max_level=8, cache_bytes=budget)
    assert lazy.edge_length.shape == lazy.geometric_error.shape == (2048, 9)
    assert np.all(np.diff(lazy.edge_length, axis=1) < 0)
    scene.mesh = lazy
    head, poi = default_head(screen), np.array(screen.size_px, dtype=np.float64) / 2
    for bias in (0.0, 3.0):
        selector = RawViews(scene_quadtree_selector(scene, "csf", "adaptive", level_bias=bias))
        levels, _ = selector.select(View(head, poi, TRACKER_COV_DEG2, 0.0))
        positions, normals, tri_levels = lazy.update(levels)
        assert len(tri_levels) == lazy.triangle_count(levels) > 0
        assert lazy.cache_bytes <= budget
        assert np.isfinite(positions).all() and np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-3)
        if bias:
            assert levels.max() >= 7


def test_rebuilds_only_faces_whose_case_changed(pair):
    """Frame after frame, only the faces whose case changed get new blocks, and every frame is still the
    from-scratch AdaptiveMesh frame, bit for bit and in its order (a stale block would show here)."""
    adaptive, lazy = pair
    rng = np.random.default_rng(11)
    levels = rng.integers(0, 6, lazy.n_faces)
    lazy.update_indices(levels)
    for _ in range(6):
        previous = lazy.cases(levels)
        levels = levels.copy()
        flip = rng.choice(lazy.n_faces, 3, replace=False)
        levels[flip] = rng.integers(0, 6, 3)
        b = lazy.update(levels)
        assert lazy.stats["rebuilt_faces"] == int(np.sum(lazy.cases(levels) != previous))
        adaptive.clear()
        for x, y in zip(adaptive.update(levels), b):
            np.testing.assert_array_equal(x, y)


@pytest.mark.slow
def test_the_lazy_bench_frames_are_the_frame_steps(gl_context, default_screen):
    """bench plod --only lazy: each frame through FrameStep over the mesh back end with the quadtree
    selector, the figures from its stages; a still scene's later frames reuse the cached pieces."""
    from headplod.bench.plod_lazy import WARM_KEYS, run_frames
    from headplod.render import TerrainRenderer
    from headplod.render.still import TerrainScene

    scene = TerrainScene.build(default_screen, max_level=0)
    scene.mesh = LazyAdaptiveMesh(BaseMesh.grid(scene.terrain), scene.terrain, max_level=6)
    renderer = TerrainRenderer(gl_context, size=(160, 90))
    try:
        out = run_frames(scene, renderer, default_screen, frames=2)
    finally:
        renderer.release()
    cold, warm = out["cold"], out["warm_median"]
    assert set(WARM_KEYS) <= set(warm) and cold["triangles"] == sum(cold["per_level"]) > 2048
    assert cold["generated_pieces"] > 0 and cold["nodes_visited"] > 0 and not cold["held"]
    assert cold["build_ms"] > 0 and cold["upload_ms"] > 0 and cold["render_ms"] > 0
    assert out["peak_rss_mb"] >= out["rss_mb"] * 0.9 > 0
