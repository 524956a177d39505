"""A person's own terrain (``--terrain FILE``): the readers, the repairs, the refusals and the command line.

Every file is made here, small, with the library a person would use
(rasterio for GeoTIFF, OpenCV for PNG, numpy for .npy). The known grid is a
ramp that rises to the north (and a little to the east): read correctly, the
Terrain is high at +y whatever the file's row order.
"""
import json
import math

import cv2
import numpy as np
import pytest
import trimesh

from headplod.cli import main as cli_main
from headplod.plod import terrain_file as tf
from headplod.plod.terrain import Terrain, metres_per_degree
from headplod.plod.terrain_file import (TerrainFileError, TerrainFileOptions, TerrainUsageError, read_terrain_file,
                                        terrain_from_file)

rasterio = pytest.importorskip("rasterio")
from rasterio.transform import Affine, from_origin  # noqa: E402

needs_gl = pytest.mark.usefixtures("gl_context")
# rasterio's own from_origin still multiplies Affines with '*'.
# Writing a GeoTIFF without georeferencing (on purpose) warns.
pytestmark = [pytest.mark.filterwarnings("ignore:Use `@` matmul:PendingDeprecationWarning"),
              pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")]

NY, NX = 12, 9


def north_high(ny=NY, nx=NX):
    """(ny, nx) heights, row 0 NORTH (as a north-up file stores them): 10 m per row northward, 1 m per column east."""
    rows_from_south = np.arange(ny)[::-1, None]
    return (100.0 + 10.0 * rows_from_south + np.arange(nx)[None, :]).astype(np.float32)


def expected_south_first(ny=NY, nx=NX):
    """The same grid in the Terrain's convention (row 0 south)."""
    return north_high(ny, nx)[::-1].astype(np.float64)


def write_geotiff(path, z, crs="EPSG:32617", transform=None, nodata=None, dtype=None, count=1):
    z = np.asarray(z)
    transform = from_origin(500_000.0, 4_000_000.0, 30.0, 20.0) if transform is None else transform
    with rasterio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=count,
                       dtype=dtype or z.dtype.name, crs=crs, transform=transform, nodata=nodata) as dst:
        for band in range(1, count + 1):
            dst.write(z.astype(dtype or z.dtype), band)
    return path


@pytest.fixture(scope="module")
def small_tif(tmp_path_factory):
    """A 9 x 12 projected (UTM, metres) GeoTIFF, 30 m east x 20 m north, north-high."""
    return write_geotiff(tmp_path_factory.mktemp("dem") / "small.tif", north_high())


# ---------------------------------------------------------------------------------------------- readers
def test_projected_geotiff_values_spacing_and_orientation(small_tif):
    grid = read_terrain_file(small_tif)
    assert grid.kind == "geotiff" and grid.crs == "EPSG:32617"
    assert (grid.dx_m, grid.dy_m) == (30.0, 20.0)
    assert np.array_equal(grid.elevation_m, expected_south_first())       # row 0 south after the flip
    terrain = Terrain(grid.elevation_m, grid.dx_m, grid.dy_m, detail=False)
    x = 0.5 * (terrain.extent[0] + terrain.extent[1])
    south, north = terrain.heights(x, terrain.extent[2]), terrain.heights(x, terrain.extent[3])
    assert north - south == pytest.approx(10.0 * (NY - 1))               # high at +y
    assert terrain.extent[1] == pytest.approx(30.0 * (NX - 1)) and terrain.extent[3] == pytest.approx(20.0 * (NY - 1))


def test_geographic_geotiff_spacing_is_metres_at_the_centre_latitude(tmp_path):
    d = 1 / 1200                                                           # 3 arc-seconds
    path = write_geotiff(tmp_path / "geo.tif", north_high().astype(np.int16), crs="EPSG:4326",
                         transform=from_origin(-84.4, 36.7, d, d))
    grid = read_terrain_file(path)
    lat_c = 36.7 - 0.5 * NY * d
    m_lon, m_lat = metres_per_degree(lat_c)
    assert grid.dx_m == pytest.approx(d * m_lon, rel=1e-9) and grid.dy_m == pytest.approx(d * m_lat, rel=1e-9)
    assert grid.dx_m == pytest.approx(74.5, abs=0.2) and grid.dy_m == pytest.approx(92.5, abs=0.2)
    assert np.array_equal(grid.elevation_m, expected_south_first())
    assert any("geographic" in n for n in grid.notes)


def test_projected_feet_become_metres_and_south_up_files_are_not_flipped(tmp_path):
    feet = read_terrain_file(write_geotiff(tmp_path / "ft.tif", north_high(), crs="EPSG:2263",
                                           transform=from_origin(1e6, 2e5, 10.0, 10.0)))
    assert feet.dx_m == pytest.approx(3.048006, rel=1e-6)                 # US survey feet
    south_up = write_geotiff(tmp_path / "s.tif", north_high()[::-1],      # row 0 south: y pixel size > 0
                             transform=Affine(30.0, 0.0, 500_000.0, 0.0, 20.0, 4_000_000.0))
    assert np.array_equal(read_terrain_file(south_up).elevation_m, expected_south_first())


def test_png16_with_spacing_and_height_scale(tmp_path):
    path = tmp_path / "h.png"
    counts = (north_high() * 10).astype(np.uint16)                        # decimetres
    assert cv2.imwrite(str(path), counts)
    grid = read_terrain_file(path, TerrainFileOptions(spacing_m=(5.0, 4.0), height_scale=0.1))
    assert (grid.dx_m, grid.dy_m) == (5.0, 4.0) and grid.kind == "png"
    assert np.allclose(grid.elevation_m, expected_south_first(), atol=1e-9)
    assert grid.notes == ()


def test_npy_is_row_0_north_and_nan_holes_are_filled_from_the_nearest_sample(tmp_path):
    z = north_high().astype(np.float64)
    z[3, 4] = np.nan                                                       # file row 3 = south row NY-4
    path = tmp_path / "h.npy"
    np.save(path, z)
    grid = read_terrain_file(path, TerrainFileOptions(spacing_m=(2.0, 2.0)))
    want = expected_south_first()
    filled = grid.elevation_m[NY - 4, 4]
    neighbours = [want[NY - 4 + di, 4 + dj] for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    assert filled in neighbours                                            # a nearest valid sample's height
    mask = np.ones_like(want, bool)
    mask[NY - 4, 4] = False
    assert np.array_equal(grid.elevation_m[mask], want[mask])
    assert grid.filled == 1 and any("filled 1 of 108 samples" in n and "NaN" in n for n in grid.notes)


def test_geotiff_nodata_tag_and_void_value_are_filled_and_counted(tmp_path):
    z = north_high()
    z[0:2, 0:3] = -9999
    grid = read_terrain_file(write_geotiff(tmp_path / "nd.tif", z, nodata=-9999))
    assert grid.filled == 6 and float(grid.elevation_m.min()) >= 100
    assert any("filled 6 of 108" in n and "nodata -9999" in n for n in grid.notes)
    z16 = north_high().astype(np.int16)
    z16[5, 5] = -32768                                                     # SRTM's void, no nodata tag
    grid = read_terrain_file(write_geotiff(tmp_path / "void.tif", z16))
    assert grid.filled == 1 and any("-32768" in n for n in grid.notes)


def test_png_details_eight_bit_grey_as_rgb_and_alpha_holes(tmp_path):
    opts = TerrainFileOptions(spacing_m=(1.0, 1.0))
    eight = tmp_path / "h8.png"
    cv2.imwrite(str(eight), (north_high() - 90).astype(np.uint8))
    assert any("256 levels" in n for n in read_terrain_file(eight, opts).notes)
    grey_rgb = tmp_path / "rgb.png"
    g = (north_high() * 10).astype(np.uint16)
    cv2.imwrite(str(grey_rgb), np.dstack([g, g, g]))
    grid = read_terrain_file(grey_rgb, opts)
    assert any("three equal channels" in n for n in grid.notes)
    assert np.allclose(grid.elevation_m, 10 * expected_south_first())
    rgba = np.dstack([g, g, g, np.full_like(g, 65535)])
    rgba[0, 0, 3] = 0
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    assert read_terrain_file(tmp_path / "a.png", opts).filled == 1


def test_terrain_from_file_has_no_synthetic_detail_and_keeps_its_source(small_tif):
    terrain, grid = terrain_from_file(small_tif)
    assert not terrain.detail and len(terrain.detail_amplitudes_m) == 0
    assert terrain.source.path == str(small_tif) and terrain.source.elevation_m is None
    assert terrain.dem_z_m.shape == (NY, NX)


# ---------------------------------------------------------------------------------------------- bad files
def _npy(tmp_path, name, array, **kw):
    path = tmp_path / name
    np.save(path, array, **kw)
    return path


@pytest.mark.parametrize("make, message", [
    (lambda p: _npy(p, "b.npy", np.ones((8, 8), bool)), "booleans"),
    (lambda p: _npy(p, "c.npy", np.ones((8, 8), complex)), "complex"),
    (lambda p: _npy(p, "o.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True), "not a plain numeric"),
    (lambda p: _npy(p, "3d.npy", np.ones((4, 8, 8))), "2-D grid"),
    (lambda p: _npy(p, "tiny.npy", np.ones((3, 40))), "too small"),
    (lambda p: _npy(p, "nan.npy", np.full((8, 8), np.nan)), "every sample is no data"),
    (lambda p: _npy(p, "huge.npy", np.full((8, 8), 1e12)), "beyond"),
    (lambda p: (p / "junk.npy").write_bytes(b"not numpy") and p / "junk.npy", "cannot be read as .npy"),
    (lambda p: (p / "junk.png").write_bytes(b"GIF89a....") and p / "junk.png", "not a PNG"),
    (lambda p: (p / "junk.tif").write_bytes(b"II*\0garbage") and p / "junk.tif", "not a readable GeoTIFF"),
    (lambda p: p / "missing.npy", "no such file"),
    (lambda p: write_geotiff(p / "nodata.tif", np.full((6, 6), -9999, np.float32), nodata=-9999), "every sample"),
    (lambda p: write_geotiff(p / "rot.tif", north_high(), transform=Affine(30, 5, 0, 5, -20, 0)), "rotated"),
    (lambda p: write_geotiff(p / "nocrs.tif", north_high(), crs=None, transform=Affine.identity()), "--spacing-m"),
    (lambda p: write_geotiff(p / "mm.tif", north_high(), transform=from_origin(0, 0, 1e-4, 1e-4)), "between 1 mm"),
])
def test_bad_files_get_one_line_errors(tmp_path, make, message):
    path = make(tmp_path)
    opts = TerrainFileOptions(spacing_m=(10.0, 10.0)) if path.suffix in (".npy", ".png") else TerrainFileOptions()
    with pytest.raises(TerrainFileError, match=message) as info:
        read_terrain_file(path, opts)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(path))


def test_colour_png_is_refused(tmp_path):
    img = np.zeros((8, 8, 3), np.uint16)
    img[..., 2] = 1000
    cv2.imwrite(str(tmp_path / "c.png"), img)
    with pytest.raises(TerrainFileError, match="colour PNG"):
        read_terrain_file(tmp_path / "c.png", TerrainFileOptions(spacing_m=(1, 1)))


def test_too_big_states_the_limit(tmp_path, monkeypatch):
    monkeypatch.setattr(tf, "MAX_SAMPLES", 100)
    with pytest.raises(TerrainFileError, match="over the limit of 100"):
        read_terrain_file(_npy(tmp_path, "big.npy", np.zeros((11, 10))), TerrainFileOptions(spacing_m=(1, 1)))
    monkeypatch.undo()                                                     # the real limit, stated in the message
    with pytest.raises(TerrainFileError, match="67,108,864"):
        tf._check_shape(tmp_path / "x.npy", (8193, 8192))


@pytest.mark.parametrize("spacing", [0.0, -1.0, math.nan, 10_001.0, 0.0009, math.inf])
def test_absurd_spacing_is_refused(spacing):
    with pytest.raises(ValueError, match="between 1 mm and 10 km"):
        TerrainFileOptions(spacing_m=(spacing, 1.0))


@pytest.mark.parametrize("scale", [0.0, -2.0, math.nan])
def test_bad_height_scale_is_refused(scale):
    with pytest.raises(ValueError, match="height_scale"):
        TerrainFileOptions(height_scale=scale)


def test_usage_problems_are_found_before_reading(tmp_path):
    with pytest.raises(TerrainUsageError, match="--spacing-m"):
        tf.check_terrain_path(tmp_path / "missing.png")                    # before looking for the file
    with pytest.raises(TerrainUsageError, match="unknown terrain format"):
        tf.check_terrain_path(tmp_path / "dem.asc")


# ---------------------------------------------------------------------------------------------- framing
def test_fit_scale_frames_any_extent_like_the_built_in():
    from headplod.demo.viewpoints import VIEWPOINTS
    from headplod.render.still import FRAME_SPAN_M, fit_scale

    class Stub:
        extent = (0.0, 3000.0, 0.0, 1500.0)
        dem_z_m = np.array([[0.0, 100.0]])

    assert fit_scale(Stub()) == pytest.approx(FRAME_SPAN_M / 3000.0)
    Stub.dem_z_m = np.array([[0.0, 4000.0]])                               # steep: relief counts twice
    assert fit_scale(Stub()) == pytest.approx(FRAME_SPAN_M / 8000.0)
    # A fit of 1 leaves a viewpoint's placement exactly as it was (the built-in scene's framing).
    terrain = Terrain(np.outer(np.arange(8.0), np.ones(8)), 100.0, 100.0, detail=False)
    from calib import DEFAULT_SCREEN
    from headplod import io
    screen = io.read_screen(DEFAULT_SCREEN)
    for vp in VIEWPOINTS.values():
        assert np.array_equal(vp.model(terrain, screen, 1.0), vp.model(terrain, screen))
        scaled = vp.model(terrain, screen, 2.0)
        a, b = scaled @ [0, 0, 0, 1], scaled @ [700, 0, 0, 1]
        assert np.linalg.norm((a - b)[:3]) == pytest.approx(2 * 700 * vp.scale_mm_per_m)


# ---------------------------------------------------------------------------------------------- command line
@pytest.mark.slow
@needs_gl
def test_render_terrain_writes_image_stats_and_a_crack_free_mesh(small_tif, tmp_path):
    """End to end; the exported mesh reloads in trimesh with the stats' triangle count, and is crack-free.

    The terrain is an open sheet, so trimesh's ``is_watertight`` (closed) is
    False by construction; "watertight" here means no cracks: after welding,
    every edge inside is shared by exactly two faces, the only open edges lie
    on the terrain's border, and the sheet is one consistently wound disk.
    """
    from test_export import _conforming_disk

    out, stats, mesh = tmp_path / "x.png", tmp_path / "x.json", tmp_path / "m.ply"
    assert cli_main(["render", "--terrain", str(small_tif), "--out", str(out), "--stats", str(stats),
                     "--export", str(mesh), "--size", "160,90"]) == 0
    assert cv2.imread(str(out)).shape == (90, 160, 3)
    s = json.loads(stats.read_text())
    assert s["terrain"]["shape"] == [NY, NX] and s["terrain"]["spacing_m"] == [30.0, 20.0]
    assert s["terrain"]["fit"] == pytest.approx(31_700.0 / max(30.0 * (NX - 1), 20.0 * (NY - 1)))
    loaded = trimesh.load(mesh, force="mesh")
    assert len(loaded.faces) == s["triangles"]
    _conforming_disk(loaded, ((0.0, 0.0), (30.0 * (NX - 1), 20.0 * (NY - 1))))
    edges = loaded.copy()
    edges.merge_vertices()
    _, counts = np.unique(edges.edges_sorted, axis=0, return_counts=True)
    assert set(counts.tolist()) <= {1, 2}                                  # no edge shared by three faces


def test_render_refuses_bad_terrain_before_writing(tmp_path, capsys):
    out = tmp_path / "sub" / "x.png"
    png = tmp_path / "h.png"
    cv2.imwrite(str(png), np.zeros((8, 8), np.uint16))
    assert cli_main(["render", "--terrain", str(png), "--out", str(out)]) == 2            # no --spacing-m
    assert "--spacing-m" in capsys.readouterr().err
    bad = _npy(tmp_path, "b.npy", np.ones((8, 8), bool))
    assert cli_main(["render", "--terrain", str(bad), "--spacing-m", "5", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    problems = [line for line in err.splitlines() if line.startswith("headplod:")]    # besides "terrain: reading"
    assert len(problems) == 1 and "booleans" in problems[0], err
    assert cli_main(["render", "--spacing-m", "5", "--out", str(out)]) == 2                # without --terrain
    with pytest.raises(SystemExit) as info:                                                 # argparse: range
        cli_main(["render", "--terrain", str(png), "--spacing-m", "0", "--out", str(out)])
    assert info.value.code == 2 and "between 1 mm" in capsys.readouterr().err
    assert not out.parent.exists()                                                          # nothing written


def test_demo_refuses_bad_terrain_before_writing(tmp_path, capsys):
    folder = tmp_path / "demo"
    npy = _npy(tmp_path, "h.npy", np.zeros((8, 8)))
    assert cli_main(["demo", "--headless", "--terrain", str(npy), "--out", str(folder)]) == 2
    assert "--spacing-m" in capsys.readouterr().err
    assert cli_main(["demo", "--headless", "--terrain", str(tmp_path / "no.tif"), "--out", str(folder)]) == 1
    assert "no such file" in capsys.readouterr().err
    assert not folder.exists()
