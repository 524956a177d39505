"""Memory of the ``--terrain FILE`` path: reading a height map and building its Terrain add no needless grids.

The peak of Python-visible allocations (numpy's arrays are traced by
``tracemalloc``) while :func:`terrain_from_file` reads and builds is
compared with the size of the file's grid as float32 (4 bytes a sample,
``G``). What the built terrain must hold: the heights (float32 where exact:
``G``; float64: ``2 G``) and its padded float64 spline coefficients
(``2 G`` and a border). Each bound below leaves half a ``G`` for masks and
the border, so any extra copy of the grid (a float64 widening, an
``np.pad`` of the coefficients, an ``|heights|`` temporary) fails it.

The rest checks that the savings change no number: the coefficients are
those of ``np.pad(spline_filter(z), 2, mode="reflect")`` bit for bit, and a
terrain kept in float32 samples and meshes exactly as one widened to float64.
"""
import tracemalloc

import numpy as np
import pytest
from scipy import ndimage as ndi

from headplod.plod.mesh import AdaptiveMesh, BaseMesh
from headplod.plod.terrain import Terrain, _padded_spline_coefficients
from headplod.plod.terrain_file import TerrainFileOptions, terrain_from_file

# rasterio's own from_origin still multiplies Affines with '*'.
pytestmark = pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning")

N = 384            # samples a side: a quick test, large enough that the grid dominates the small arrays
SPACING = TerrainFileOptions(spacing_m=(10.0, 10.0))


def _relief(n=N, dtype=np.float32):
    """(n, n) rough relief, metres (a random walk in both directions, about ±1 km)."""
    rng = np.random.default_rng(7)
    return (500.0 + rng.normal(size=(n, n)).cumsum(0).cumsum(1) / n).astype(dtype)


def _peak_of(fn):
    """(result, peak traced bytes, bytes still held by the result) of ``fn()``."""
    tracemalloc.start()
    try:
        out = fn()
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return out, peak, held


@pytest.fixture(scope="module")
def dem_files(tmp_path_factory):
    """The relief as a float32 .npy, a float64 .npy and a float32 GeoTIFF (row 0 north, as files store it)."""
    folder = tmp_path_factory.mktemp("dem")
    z = _relief()
    np.save(folder / "f32.npy", z)
    np.save(folder / "f64.npy", z.astype(np.float64))
    paths = {"f32": folder / "f32.npy", "f64": folder / "f64.npy"}
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin
    with rasterio.open(folder / "f32.tif", "w", driver="GTiff", height=N, width=N, count=1, dtype="float32",
                       crs="EPSG:32617", transform=from_origin(500_000.0, 4_000_000.0, 10.0, 10.0),
                       nodata=-32768) as dst:
        dst.write(z, 1)
    paths["tif"] = folder / "f32.tif"
    return paths


@pytest.mark.parametrize("name, bound", [("f32", 3.5), ("tif", 3.5), ("f64", 4.5)])
def test_reading_and_building_make_no_extra_grid(dem_files, name, bound):
    grid_f32 = N * N * 4
    (terrain, grid), peak, held = _peak_of(lambda: terrain_from_file(dem_files[name], SPACING))
    assert peak < bound * grid_f32, f"{name}: peak {peak / grid_f32:.2f} x the float32 grid (bound {bound})"
    # What stays is the heights and the coefficients, the heights held once (grid and terrain share them).
    assert grid.elevation_m is terrain.dem_z_m
    assert terrain.dem_z_m.dtype == (np.float64 if name == "f64" else np.float32)
    assert held < (bound - 0.4) * grid_f32


def test_building_from_a_float64_grid_handed_over_adds_only_the_coefficients():
    z = _relief(dtype=np.float64)
    terrain, peak, _ = _peak_of(lambda: Terrain(z, 10.0, 10.0, detail=False, copy=False))
    assert terrain.dem_z_m is z
    assert peak < 1.25 * z.nbytes                    # the padded coefficients (and a border), nothing else
    copied = Terrain(z, 10.0, 10.0, detail=False)    # the default: the terrain's own copy
    assert copied.dem_z_m is not z and np.array_equal(copied.dem_z_m, z)


@pytest.mark.parametrize("shape", [(4, 4), (5, 9), (37, 23)])
def test_coefficients_are_the_padded_spline_filter_bit_for_bit(shape):
    z = np.random.default_rng(shape[0]).normal(size=shape) * 300.0
    want = np.pad(ndi.spline_filter(z, order=3, mode="mirror"), 2, mode="reflect").ravel()
    assert np.array_equal(_padded_spline_coefficients(z), want)
    assert np.array_equal(_padded_spline_coefficients(z.astype(np.float32)),
                          np.pad(ndi.spline_filter(z.astype(np.float32).astype(np.float64), order=3, mode="mirror"),
                                 2, mode="reflect").ravel())


def test_a_float32_terrain_samples_and_meshes_as_the_float64_one(dem_files):
    """Heights kept in float32 (exact for a float32 file) give the float64 terrain's numbers, to the bit."""
    kept, _ = terrain_from_file(dem_files["f32"], SPACING)
    widened = Terrain(np.asarray(kept.dem_z_m, np.float64), 10.0, 10.0, detail=False)
    assert kept.dem_z_m.dtype == np.float32
    assert np.array_equal(kept._coef[0], widened._coef[0])
    rng = np.random.default_rng(3)
    x0, x1, y0, y1 = kept.extent
    x, y = rng.uniform(x0 - 50, x1 + 50, 4000), rng.uniform(y0 - 50, y1 + 50, 4000)
    for a, b in zip(kept.sample(x, y, smooth_m=25.0), widened.sample(x, y, smooth_m=25.0)):
        assert np.array_equal(a, b)
    assert float(np.ptp(kept.dem_z_m)) == float(np.ptp(widened.dem_z_m))
    meshes = [AdaptiveMesh(BaseMesh.grid(t, 6, 5), t, max_level=3) for t in (kept, widened)]
    assert np.array_equal(meshes[0].vertex_positions, meshes[1].vertex_positions)
    assert np.array_equal(meshes[0].vertex_normals, meshes[1].vertex_normals)
    assert np.array_equal(meshes[0].geometric_error, meshes[1].geometric_error)
    assert np.array_equal(meshes[0].contrast, meshes[1].contrast)


def test_scaled_heights_stay_float64(dem_files):
    """A height scale makes values float32 cannot hold exactly: the heights are float64 then."""
    terrain, grid = terrain_from_file(dem_files["f32"], TerrainFileOptions(spacing_m=(10.0, 10.0), height_scale=0.3))
    assert grid.elevation_m.dtype == np.float64 and terrain.dem_z_m.dtype == np.float64
    expected = np.load(dem_files["f32"])[::-1].astype(np.float64) * 0.3
    assert np.array_equal(grid.elevation_m, expected)
