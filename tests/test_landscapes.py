"""headplod/bench/landscapes.py: the seeded landscapes of the held-out judge, and tools/make_dem.py's ``--ridges``.

Each landscape is a pure function of its kind and seed; checked here for determinism, shape, dtype and
finiteness, the ``KIND:SEED`` names, the Terrain built from one, and the property that sets mesas apart (flat
treads) against ridges.
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import load_tool
from headplod.bench import landscapes
from headplod.plod.terrain import Terrain

# A tread's slope: its fine relief (15 m over a spectral field) tilts it by well under 2 % almost everywhere,
# while ridges' crests and flanks are steeper than that nearly everywhere (measured: < 2 % of their samples).
FLAT_SLOPE = 0.02


@pytest.fixture(scope="module")
def fields():
    """{(kind, seed): heights} of every kind for seeds 5 and 24 (each ~0.1-0.2 s)."""
    return {(k, s): landscapes.heights(k, s) for k in landscapes.KINDS for s in (5, 24)}


@pytest.mark.slow
@pytest.mark.parametrize("kind", sorted(landscapes.KINDS))
def test_every_kind_is_seeded_float32_and_finite(kind, fields):
    a = fields[kind, 5]
    assert a.shape == (landscapes.SAMPLES, landscapes.SAMPLES) and a.dtype == np.float32
    assert np.isfinite(a).all() and np.ptp(a) > 100.0                       # relief, not a flat sheet
    np.testing.assert_array_equal(a, landscapes.heights(kind, 5))
    assert not np.array_equal(a, fields[kind, 24])
    assert float(np.abs(a - fields[kind, 24]).mean()) > 10.0                # different ground, not a shift of 1e-6


def test_kinds_differ_for_one_seed(fields):
    kinds = sorted(landscapes.KINDS)
    for i, a in enumerate(kinds):
        for b in kinds[i + 1:]:
            assert not np.array_equal(fields[a, 5], fields[b, 5])


def test_a_smaller_grid_on_request():
    a = landscapes.heights("hills", 1, n=65)
    assert a.shape == (65, 65) and a.dtype == np.float32 and np.isfinite(a).all()


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown landscape 'plateau'"):
        landscapes.heights("plateau", 1)


def test_parse_name():
    assert landscapes.parse_name("ridges:24") == ("ridges", 24)
    assert landscapes.parse_name("mesas:0") == ("mesas", 0)
    for kind in landscapes.KINDS:
        assert landscapes.parse_name(f"{kind}:7") == (kind, 7)


@pytest.mark.parametrize("name", ["ridges", "foo:1", "ridges:x", "ridges:", ":3", "ridges:-1", "ridges:1.5", ""])
def test_parse_name_refuses_anything_else_naming_the_form(name):
    with pytest.raises(ValueError, match="KIND:SEED") as info:
        landscapes.parse_name(name)
    assert repr(name) in str(info.value)


def test_terrain_of_a_name_has_the_heights_and_the_spacing():
    t = landscapes.terrain("mesas:5")
    assert isinstance(t, Terrain)
    assert t.dx_m == t.dy_m == landscapes.SPACING_M
    assert t.shape == (landscapes.SAMPLES, landscapes.SAMPLES)
    assert t.detail is False
    np.testing.assert_array_equal(t.dem_z_m, landscapes.heights("mesas", 5)[::-1])     # row 0 north → south
    extent = (landscapes.SAMPLES - 1) * landscapes.SPACING_M
    assert t.extent == pytest.approx((0.0, extent, 0.0, extent))
    with pytest.raises(ValueError, match="KIND:SEED"):
        landscapes.terrain("mesas")


def test_make_dem_ridges_are_the_landscape():
    make_dem = load_tool("make_dem")
    np.testing.assert_array_equal(make_dem.ridges_heights(24), landscapes.heights("ridges", 24))
    assert (make_dem.RIDGES_SAMPLES, make_dem.RIDGES_SPACING_M) == (landscapes.SAMPLES, landscapes.SPACING_M)


def test_make_dem_writes_the_ridges_npy(tmp_path):
    make_dem = load_tool("make_dem")
    out = tmp_path / "ridges.npy"
    assert make_dem.main([str(out), "--ridges", "7"]) == 0
    np.testing.assert_array_equal(np.load(out), landscapes.heights("ridges", 7))
    assert make_dem.main([str(tmp_path / "ridges.tif"), "--ridges", "7"]) == 2
    assert not (tmp_path / "ridges.tif").exists()


def _flat_share(heights) -> float:
    gy, gx = np.gradient(heights.astype(np.float64), landscapes.SPACING_M)
    return float((np.hypot(gx, gy) < FLAT_SLOPE).mean())


@pytest.mark.parametrize("seed", [5, 24])
def test_mesas_have_flat_treads_ridges_do_not(seed, fields):
    """Measured: ~60 % of mesas' samples slope under 2 %, under 2 % of ridges'; and mesas have scarps (their
    steepest 1 % is far steeper than their median)."""
    mesas, ridges = fields["mesas", seed], fields["ridges", seed]
    assert _flat_share(mesas) > 0.4
    assert _flat_share(mesas) > 10 * _flat_share(ridges)
    gy, gx = np.gradient(mesas.astype(np.float64), landscapes.SPACING_M)
    slope = np.hypot(gx, gy)
    assert np.percentile(slope, 99) > 10 * np.median(slope)


def test_the_judges_ridges_are_the_ridges_file_read_with_terrain(tmp_path):
    from headplod.plod.terrain_file import TerrainFileOptions, terrain_from_file

    make_dem = load_tool("make_dem")
    out = tmp_path / "ridges.npy"
    assert make_dem.main([str(out), "--ridges", "24"]) == 0
    from_file, _ = terrain_from_file(out, TerrainFileOptions(spacing_m=landscapes.SPACING_M))
    np.testing.assert_array_equal(from_file.dem_z_m, landscapes.terrain("ridges:24").dem_z_m)
