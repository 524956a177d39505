"""Terrain (real DEM + synthetic detail) and the crack-free adaptive subdivision mesh."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from conftest import FlatTerrain
from headplod.plod.mesh import AdaptiveMesh, BaseMesh, build_template, triangle_count_table
from headplod.plod.terrain import Terrain, load_jacksboro_dem


class BowlTerrain(FlatTerrain):
    """z = a (x² + y²): linear interpolation error is exactly quartered per level."""

    a = 1e-4

    def heights(self, x, y):
        return self.a * (np.asarray(x) ** 2 + np.asarray(y) ** 2)

    def normals(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        n = np.stack([-2 * self.a * x, -2 * self.a * y, np.ones_like(x)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def terrain():
    return Terrain.jacksboro()


@pytest.fixture(scope="module")
def big(terrain):
    """The default mesh: 32 x 32 quads (2048 faces) up to level 5."""
    return AdaptiveMesh(BaseMesh.grid(terrain, 32, 32), terrain, max_level=5)


_small = {}


def small_mesh(kind):
    """Small meshes for property tests (module cache: hypothesis runs many examples)."""
    if kind not in _small:
        if kind == "flat":
            t = FlatTerrain()
            _small[kind] = AdaptiveMesh(BaseMesh.grid(t, 5, 4), t, max_level=4)
        else:
            t = Terrain.jacksboro()
            _small[kind] = AdaptiveMesh(BaseMesh.grid(t, 4, 3), t, max_level=4)
    return _small[kind]


def soup_topology(positions):
    """Weld a triangle soup by exact float32 coordinates.

    Returns vertices (V, 3), triangles (T, 3) int, undirected edges (E, 2) with
    use counts (E,), and directed-edge counts per undirected edge (E, 2).
    """
    rows = np.ascontiguousarray(positions).view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    vertices = positions[first]
    tris = inverse.reshape(-1, 3)
    directed = np.stack([tris, np.roll(tris, -1, axis=1)], axis=-1).reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    edges, einv, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    forward = directed[:, 0] < directed[:, 1]
    per_dir = np.stack([np.bincount(einv.ravel()[forward], minlength=len(edges)),
                        np.bincount(einv.ravel()[~forward], minlength=len(edges))], axis=1)
    return vertices, tris, edges, counts, per_dir


def check_watertight(mesh, levels):
    """Assert the soup for ``levels`` is a consistently oriented, conforming triangulation of a disk."""
    positions, normals, lv = mesh.update(levels)
    assert positions.dtype == np.float32 and positions.shape == (3 * len(lv), 3)
    assert len(lv) == mesh.triangle_count(levels)
    vertices, tris, edges, counts, per_dir = soup_topology(positions)
    # No degenerate triangle: every vertex welded to a distinct one, positive area seen from +z.
    assert np.all((tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0]))
    p = positions.astype(np.float64).reshape(-1, 3, 3)
    cross_z = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
               - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))
    assert cross_z.min() > 0, "a triangle is degenerate or flipped"
    # Conforming: interior edges used twice (once each way), boundary edges once and on the outer border.
    assert counts.max() <= 2
    assert np.all(per_dir[counts == 2] == 1), "an interior edge is traversed twice the same way"
    # Points on the domain's border lie exactly on it (edge points interpolate two border vertices).
    xmin, ymin = vertices[:, :2].min(axis=0)
    xmax, ymax = vertices[:, :2].max(axis=0)
    ends = vertices[edges[counts == 1]]                                  # (B, 2, 3)
    on_border = ((ends[..., 0] == xmin).all(1) | (ends[..., 0] == xmax).all(1)
                 | (ends[..., 1] == ymin).all(1) | (ends[..., 1] == ymax).all(1))
    assert on_border.all(), f"{(~on_border).sum()} T-junction/crack edges inside the domain"
    # A disk: V - E + F = 1.
    assert len(vertices) - len(edges) + len(tris) == 1
    # Normals are unit and, welded, one per position (bit-identical shared vertices carry one normal).
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)
    return positions, cross_z


# ---------------------------------------------------------------------------- templates
def test_templates_match_the_count_table():
    M = 4
    table = triangle_count_table(M)
    for L in range(M + 1):
        for e in np.ndindex(*(M + 1 - L,) * 3):
            edges = tuple(L + np.array(e))
            assert len(build_template(M, L, edges).triangles) == table[(L,) + edges]


def test_template_rejects_an_edge_below_its_face():
    with pytest.raises(ValueError, match="edge levels"):
        build_template(3, 2, (1, 2, 2))


# ---------------------------------------------------------------------------- watertight
@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 4), min_size=40, max_size=40))
def test_flat_watertight_and_area_kept(levels):
    mesh = small_mesh("flat")
    levels = np.array(levels)
    _, cross_z = check_watertight(mesh, levels)
    # The area of the flat domain is the same at every mix of levels: exact coordinates
    # (float32 values on a 3 km grid) and float64 sums leave ~1e-13 relative error.
    area = 0.5 * cross_z.sum()
    xmin, xmax, ymin, ymax = mesh.terrain.extent
    assert abs(area - (xmax - xmin) * (ymax - ymin)) <= 1e-9 * (xmax - xmin) * (ymax - ymin)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 4), min_size=24, max_size=24))
def test_terrain_watertight_random_levels(levels):
    check_watertight(small_mesh("dem"), np.array(levels))


class JitteryTerrain(FlatTerrain):
    """Heights differ slightly on every call, like a height function whose last bits depend on
    where a point sits in the batch (SIMD tails, summation order). Crack-freedom must not rely
    on two faces recomputing the same float: each shared vertex has to be sampled once."""

    def __init__(self):
        self.rng = np.random.default_rng(0)

    def heights(self, x, y):
        shape = np.broadcast(np.asarray(x), np.asarray(y)).shape
        return 10.0 + 1e-3 * self.rng.standard_normal(shape)


def test_shared_vertices_are_sampled_once():
    t = JitteryTerrain()
    mesh = AdaptiveMesh(BaseMesh.grid(t, 4, 3), t, max_level=3)
    rng = np.random.default_rng(4)
    for _ in range(3):
        check_watertight(mesh, rng.integers(0, 4, mesh.n_faces))


@pytest.mark.slow
@pytest.mark.parametrize("seed,smooth", [(1, False), (2, True)])
def test_default_mesh_watertight(big, seed, smooth):
    """The 2048-face mesh at arbitrary (neighbours up to 5 apart) and smooth level fields."""
    rng = np.random.default_rng(seed)
    F = big.n_faces
    if smooth:
        cx, cy = big.centroids[:, 0], big.centroids[:, 1]
        field = np.sin(cx / 4000 + seed) + np.cos(cy / 3000) + 0.3 * rng.standard_normal(F)
        levels = np.clip(np.round((field + 2.3) * 1.2), 0, 5).astype(int)
    else:
        levels = rng.integers(0, 4, F)
        levels[rng.random(F) < 0.1] = 5
    check_watertight(big, levels)


# ---------------------------------------------------------------------------- sizes
@pytest.mark.slow
def test_full_detail_reaches_two_million_triangles(big):
    full = np.full(big.n_faces, big.max_level)
    assert big.triangle_count(full) == 2048 * 4 ** 5 >= 2_000_000
    # (How long this build takes is a benchmark's figure, not this test's: ≈ 0.2 s on a 2-core machine.)
    positions, normals, lv = big.update(full)
    assert len(lv) == 2048 * 4 ** 5 and positions.shape == (3 * len(lv), 3)
    assert np.all(lv == 5)


def test_triangle_count_needs_no_build(big):
    levels = np.random.default_rng(3).integers(0, 6, big.n_faces)
    table = triangle_count_table(5)
    el = big.edge_levels(levels)[big.base.face_edges]
    expected = table[levels, el[:, 0], el[:, 1], el[:, 2]].sum()
    assert big.triangle_count(levels) == expected
    assert big.triangle_count(np.zeros(big.n_faces, int)) == 2048


def test_levels_are_checked(big):
    with pytest.raises(ValueError, match="shape"):
        big.update(np.zeros(5, int))
    with pytest.raises(ValueError, match="0..5"):
        big.update(np.full(big.n_faces, 6))


# ---------------------------------------------------------------------------- incremental
def sorted_by_face(mesh, positions, normals):
    face = mesh.face_per_triangle()
    order = np.argsort(face, kind="stable")
    p = positions.reshape(-1, 3, 3)[order]
    n = normals.reshape(-1, 3, 3)[order]
    return face[order], p, n


def test_one_face_change_rebuilds_only_it_and_its_neighbours(big):
    rng = np.random.default_rng(7)
    levels = rng.integers(1, 4, big.n_faces)
    big.update(levels)
    f = 1000                                   # an interior face
    neighbours = big.base.face_neighbors[f]
    assert np.all(neighbours >= 0)
    new = levels.copy()
    new[f] = 5                                 # above every neighbour: all three edges change level
    big.update(new)
    assert set(big.last_rebuilt_faces.tolist()) == {f, *neighbours.tolist()}
    assert big.stats["rebuilt_faces"] == 4
    new2 = new.copy()
    new2[f] = 4                                 # still above: its neighbours' edge levels change again
    big.update(new2)
    assert set(big.last_rebuilt_faces.tolist()) <= {f, *neighbours.tolist()}
    assert f in big.last_rebuilt_faces
    big.update(new2)
    assert big.stats["rebuilt_faces"] == 0


@settings(max_examples=20, deadline=None)
@given(st.lists(st.lists(st.integers(0, 4), min_size=24, max_size=24), min_size=2, max_size=4))
def test_incremental_equals_from_scratch(sequence):
    mesh = small_mesh("dem")
    for levels in sequence:
        before = mesh.cases(np.array(levels))
        p, n, _ = mesh.update(np.array(levels))
    incremental = sorted_by_face(mesh, p, n)
    mesh.clear()
    p, n, _ = mesh.update(np.array(sequence[-1]))
    scratch = sorted_by_face(mesh, p, n)
    assert mesh.stats["rebuilt_faces"] == mesh.n_faces and len(before) == mesh.n_faces
    for a, b in zip(incremental, scratch):
        assert np.array_equal(a, b)


@pytest.mark.slow
def test_indices_address_the_vertex_table_and_give_the_soup(big):
    """update_indices + the static vertex table is the soup of update, also after an incremental change."""
    rng = np.random.default_rng(5)
    table_p, table_n = big.vertex_positions, big.vertex_normals
    assert table_p.shape == table_n.shape and table_p.dtype == np.float32
    for step in range(2):
        levels = rng.integers(0, big.max_level + 1, big.n_faces)
        idx, lv = big.update_indices(levels)
        assert idx.dtype == np.uint32 and idx.size == 3 * len(lv) and int(idx.max()) < len(table_p)
        assert big.update_indices(levels)[0] is idx           # unchanged levels: the same arrays
        p, n, lv2 = big.update(levels)
        np.testing.assert_array_equal(p, table_p[idx])
        np.testing.assert_array_equal(n, table_n[idx])
        np.testing.assert_array_equal(lv, lv2)
        assert len(lv) == big.triangle_count(levels)
    big.clear()
    idx_scratch, _ = big.update_indices(levels)
    np.testing.assert_array_equal(np.unique(idx_scratch.reshape(-1, 3), axis=0), np.unique(idx.reshape(-1, 3), axis=0))


def test_rebuild_touches_only_changed_cases(big):
    rng = np.random.default_rng(11)
    levels = rng.integers(0, 4, big.n_faces)
    big.update(levels)
    new = levels.copy()
    idx = rng.choice(big.n_faces, 30, replace=False)
    new[idx] = rng.integers(0, 6, 30)
    expected = np.flatnonzero(big.cases(new) != big.cases(levels))
    big.update(new)
    assert np.array_equal(np.sort(big.last_rebuilt_faces), expected)


# ---------------------------------------------------------------------------- per-face data
def test_per_face_geometry_flat_and_bowl():
    flat = small_mesh("flat")
    assert np.all(flat.geometric_error == 0)
    assert np.allclose(flat.contrast, 0)
    ratio = flat.edge_length[:, 1:] / flat.edge_length[:, :-1]
    assert np.allclose(ratio, 0.5)                        # midpoint subdivision halves every edge
    bowl_t = BowlTerrain()
    bowl = AdaptiveMesh(BaseMesh.grid(bowl_t, 3, 2), bowl_t, max_level=5)
    err = bowl.geometric_error
    assert np.all(err[:, 5] == 0) and np.all(err[:, :5] > 0)
    # For a quadratic the interpolation error shrinks 4x per level (up to the finest
    # lattice's sampling of each piece, exact here because the maximum sits on a lattice point).
    assert np.allclose(err[:, 1:4] / err[:, 0:3], 0.25, rtol=0.05)


def test_bounding_sphere_holds_every_vertex(big):
    levels = np.random.default_rng(5).integers(0, 6, big.n_faces)
    positions, _, _ = big.update(levels)
    face = np.repeat(big.face_per_triangle(), 3)
    d = np.linalg.norm(positions.astype(np.float64) - big.centroids[face], axis=1)
    assert np.all(d <= big.bounding_radius[face])


def test_per_face_data_shapes_and_units(big):
    F, M1 = big.n_faces, big.max_level + 1
    assert big.centroids.shape == (F, 3)
    assert big.edge_length.shape == big.geometric_error.shape == (F, M1)
    assert np.all(big.geometric_error[:, -1] == 0) and np.all(big.geometric_error >= 0)
    # 32 quads across ~30 km: level-0 diagonals ~1.4 km, level-5 edges ~30-50 m (metres).
    assert 1200 < np.median(big.edge_length[:, 0]) < 1600
    assert 30 < np.median(big.edge_length[:, 5]) < 60
    assert np.all((big.contrast >= 0) & (big.contrast <= 1))


# ---------------------------------------------------------------------------- terrain
def test_dem_loads_south_up_in_metres():
    dem = load_jacksboro_dem()
    from matplotlib import cbook

    raw = cbook.get_sample_data("jacksboro_fault_dem.npz")["elevation"]
    assert dem.elevation_m.shape == (344, 403)
    assert np.array_equal(dem.elevation_m[0], raw[-1])           # row 0 = the file's last (southern) row
    # 3 arc-seconds at 36.6°N: ~74.6 m east, ~92.5 m north.
    assert dem.dx_m == pytest.approx(74.57, abs=0.05) and dem.dy_m == pytest.approx(92.47, abs=0.05)


def test_heights_equal_dem_at_samples_without_detail():
    t = Terrain.jacksboro(detail=False, vertical_exaggeration=2.0)
    rng = np.random.default_rng(0)
    i, j = rng.integers(0, 403, 2000), rng.integers(0, 344, 2000)
    dem = load_jacksboro_dem().elevation_m
    z = t.heights(t.dem_x_m[i], t.dem_y_m[j])
    assert np.allclose(z, 2.0 * dem[j, i], rtol=0, atol=1e-9 * 2000)   # metres; spline fit is exact
    assert t.extent[1] == pytest.approx(402 * t.dx_m) and t.extent[3] == pytest.approx(343 * t.dy_m)


def test_detail_lives_above_the_dem_nyquist(terrain):
    """The synthetic detail has (almost) no power the DEM grid could represent."""
    h, n = 12.0, 256
    x = 8000 + h * np.arange(n)
    X, Y = np.meshgrid(x, 20000 + h * np.arange(n))
    d = terrain.detail_heights(X, Y)
    w = np.outer(np.hanning(n), np.hanning(n))
    power = np.abs(np.fft.fft2((d - d.mean()) * w)) ** 2
    fx, fy = np.meshgrid(np.fft.fftfreq(n, h), np.fft.fftfreq(n, h))
    inside = (np.abs(fx) < terrain.nyquist_cpm[0]) & (np.abs(fy) < terrain.nyquist_cpm[1])
    # Window leakage and the smooth roughness envelope spread a little power: < 1 %.
    assert power[inside].sum() < 0.01 * power.sum()
    # And the detail is real energy at sub-sample offsets: between DEM samples the terrain
    # differs from the DEM interpolant by about the detail's RMS.
    xs, ys = np.meshgrid(terrain.dem_x_m[50:350:3] + 0.5 * terrain.dx_m,
                         terrain.dem_y_m[20:320:3] + 0.5 * terrain.dy_m)
    diff = terrain.heights(xs, ys) - terrain.dem_heights(xs, ys)
    assert 0.3 * terrain.detail_rms_m < diff.std() < 3 * terrain.detail_rms_m
    assert terrain.detail_rms_m > 0.1                              # metres: visible at level 5


def test_detail_is_deterministic_in_the_seed():
    x, y = np.linspace(100, 29000, 500), np.linspace(200, 31000, 500)
    a = Terrain.jacksboro(seed=3).heights(x, y)
    assert np.array_equal(a, Terrain.jacksboro(seed=3).heights(x, y))
    assert not np.allclose(a, Terrain.jacksboro(seed=4).heights(x, y))


def test_normals_match_finite_differences(terrain):
    rng = np.random.default_rng(2)
    x, y = rng.uniform(100, 29000, 300), rng.uniform(100, 31000, 300)
    h = 0.5                                         # metres; detail is float32 so h cannot be tiny
    gx = (terrain.heights(x + h, y) - terrain.heights(x - h, y)) / (2 * h)
    gy = (terrain.heights(x, y + h) - terrain.heights(x, y - h)) / (2 * h)
    expected = np.column_stack([-gx, -gy, np.ones_like(gx)])
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    n = terrain.normals(x, y)
    assert np.allclose(np.linalg.norm(n, axis=1), 1)
    assert np.abs(n - expected).max() < 1e-3


def test_terrain_rejects_bad_grids():
    with pytest.raises(ValueError, match="2-D grid"):
        Terrain(np.zeros(10), 1.0, 1.0)
    with pytest.raises(ValueError, match="positive"):
        Terrain(np.zeros((5, 5)), -1.0, 1.0)


def test_prefiltered_normals_keep_heights_and_tend_to_the_dem(terrain):
    rng = np.random.default_rng(3)
    x, y = rng.uniform(100, 29000, 400), rng.uniform(100, 31000, 400)
    z0, n0 = terrain.sample(x, y)
    z1, n1 = terrain.sample(x, y, smooth_m=60.0)
    np.testing.assert_array_equal(z0, z1)                     # heights stay exact
    assert np.allclose(np.linalg.norm(n1, axis=1), 1)
    _, n_zero = terrain.sample(x, y, smooth_m=0.0)
    np.testing.assert_allclose(n_zero, n0, atol=1e-6)
    # Far beyond the detail's wavelengths only the DEM's slope is left.
    _, n_wide = terrain.sample(x, y, smooth_m=1e4)
    gx, gy = (np.gradient(terrain.dem_heights(np.stack([x - 0.5, x + 0.5]), np.stack([y, y])), axis=0)[0],
              np.gradient(terrain.dem_heights(np.stack([x, x]), np.stack([y - 0.5, y + 0.5])), axis=0)[0])
    dem_n = np.column_stack([-gx, -gy, np.ones_like(gx)])
    dem_n /= np.linalg.norm(dem_n, axis=1, keepdims=True)
    assert np.abs(n_wide - dem_n).max() < 1e-2 < np.abs(n0 - dem_n).max()
    # A wider filter moves the normals monotonically toward the DEM's.
    d = [np.abs(terrain.sample(x, y, smooth_m=s)[1] - dem_n).mean() for s in (0.0, 15.0, 30.0, 60.0)]
    assert all(a > b for a, b in zip(d, d[1:]))


@pytest.mark.slow
def test_finest_level_normals_are_exact_and_coarse_ones_filtered(big, terrain):
    M = big.max_level
    assert big.normal_filter_m[M] == 0 and np.all(np.diff(big.normal_filter_m) < 0)
    for level in (M, 2):
        big.clear()
        positions, normals, _ = big.update(np.full(big.n_faces, level))
        sub = slice(0, 30000, 7)
        _, exact = terrain.sample(positions[sub, 0], positions[sub, 1])
        err = np.abs(normals[sub] - exact).max()
        if level == M:
            assert err < 1e-5
        else:
            assert err > 1e-3                 # filtered at level 2 (corners of base faces stay exact)
    big.clear()
