"""The lazy mesh in the viewer: ``--max-level`` / ``--lazy`` in ``headplod render`` and ``headplod demo``.

Ground truths: the whole-table AdaptiveMesh's image (the lazy mesh draws the
same triangles at level 5, so the same pixels), the terrain's own heights
(a level-7 vertex lies on the DEM's interpolant), the mesh's triangle count
for the frame's levels, and the cache's byte budget. Small images and a
small synthetic DEM keep this to seconds.
"""
import dataclasses
import json

import numpy as np
import pytest

from headplod.cli import main as cli_main

SIZE = (320, 180)
#: A DEM finer than the default mesh: 1400 x 1200 samples 5 m apart, whose detail (a few samples across)
#: the 1025-sample level-5 lattice (6.8 m apart) cannot show and level 7's (1.7 m) can.
DEM_SHAPE = (1200, 1400)
DEM_SPACING_M = 5.0


def _fine_dem(path):
    """Write the DEM as .npy (row 0 north); returns the path."""
    from scipy import ndimage as ndi

    rng = np.random.default_rng(7)
    ny, nx = DEM_SHAPE
    y, x = np.mgrid[0:ny, 0:nx] * DEM_SPACING_M
    hills = 300 * np.sin(x / 1500) * np.cos(y / 1100)
    detail = ndi.gaussian_filter(rng.normal(size=DEM_SHAPE), 1.5) * 40       # ~10 m features, metres
    np.save(path, (hills + detail).astype(np.float32))
    return path


@pytest.fixture(scope="module")
def lazy_level5_scene(terrain_scene):
    """The built-in scene with a LazyAdaptiveMesh at level 5 over the same base and terrain."""
    from headplod.plod.lazy_mesh import LazyAdaptiveMesh

    mesh = terrain_scene.mesh
    return dataclasses.replace(terrain_scene, mesh=LazyAdaptiveMesh(mesh.base, terrain_scene.terrain, max_level=5))


@pytest.mark.slow
@pytest.mark.usefixtures("gl_context")
@pytest.mark.parametrize("view", ["shaded", "levels"])
def test_lazy_mesh_at_level_5_renders_the_table_mesh_image(default_screen, terrain_scene, lazy_level5_scene,
                                                         gl_context, view):
    """The lazy path (compact frame table, indexed) gives the default path's image pixel for pixel: the same
    triangles, bit-equal vertices, in the same order (the levels view colours by primitive order)."""
    from headplod.render import TerrainRenderer
    from headplod.plod.select import SelectorConfig
    from headplod.render.frame import FrameSettings
    from headplod.render.still import StillSettings, render_still

    poi = np.array([700.0, 500.0])
    with TerrainRenderer(gl_context, size=SIZE) as renderer:
        settings = StillSettings(FrameSettings("mesh", SelectorConfig(mode="csf")), poi_px=poi, size=SIZE,
                                 view_mode=view)
        table, st_table = render_still(settings, default_screen, scene=terrain_scene, renderer=renderer)
        lazy, st_lazy = render_still(settings, default_screen, scene=lazy_level5_scene, renderer=renderer)
    assert st_table["mesh"]["kind"] == "table" and st_lazy["mesh"]["kind"] == "lazy"
    assert st_lazy["triangles"] == st_table["triangles"] > 10_000
    assert st_lazy["triangles_per_level"] == st_table["triangles_per_level"]
    np.testing.assert_array_equal(lazy, table)


@pytest.fixture(scope="module")
def fine_dem(tmp_path_factory):
    return _fine_dem(tmp_path_factory.mktemp("dem") / "fine.npy")


@pytest.mark.slow
@pytest.mark.usefixtures("gl_context")
def test_level_7_frames_show_the_dem_near_the_poi(default_screen, fine_dem, gl_context):
    """Frames of a DemoLoop at --max-level 7 on the fine DEM: levels above 5 are selected near the POI, the
    triangle count is the lazy mesh's for the frame's levels, the level-7 vertices lie on the DEM's own
    interpolant, an unchanged selection uploads nothing, and scenario loops share one cache."""
    from headplod.demo import loop as lp
    from headplod.plod.lazy_mesh import LazyAdaptiveMesh
    from headplod.plod.terrain_file import TerrainFileOptions, terrain_from_file
    from headplod.render import TerrainRenderer
    from headplod.render.still import TerrainScene

    terrain, _ = terrain_from_file(fine_dem, TerrainFileOptions(spacing_m=(DEM_SPACING_M, DEM_SPACING_M)))
    budget = 64 * 2 ** 20
    scene = TerrainScene.build(default_screen, 7, terrain=terrain, cache_bytes=budget)
    assert isinstance(scene.mesh, LazyAdaptiveMesh) and scene.mesh.max_level == 7
    still = [(960.0, 540.0)] * 3
    with TerrainRenderer(gl_context, size=SIZE) as r1, TerrainRenderer(gl_context, size=SIZE) as r2:
        a = lp.DemoLoop(scene, lp.MousePoses(default_screen, path=still), r1, mode="csf", uncertainty="none",
                        viewpoint="mountains", hud=True)
        b = lp.DemoLoop(scene, lp.MousePoses(default_screen, path=still), r2, mode="csf", uncertainty="adaptive",
                        viewpoint="mountains", hud=False)
        assert a.base_scene.mesh._pieces_cache is b.base_scene.mesh._pieces_cache is scene.mesh._pieces_cache
        assert "raymask" not in a._backends and "full" in a._modes            # level 7: full still fits
        sent = []                                  # what r1 was given per frame: the GPU's uploads
        for name in ("upload", "set_indices"):
            def spy(*args, _name=name, _real=getattr(r1, name), **kwargs):
                sent[-1].append(_name)
                return _real(*args, **kwargs)
            setattr(r1, name, spy)
        results = []
        for _ in still:
            sent.append([])
            results.append(a.step())
            b.step()
        mesh = a.base_scene.mesh
        for res in results:
            assert res.triangles == mesh.triangle_count(res.levels)
            assert res.cache_bytes is not None and 0 < res.cache_bytes <= budget
            assert res.image.std() > 10
        assert results[0].levels.max() > 5, "nothing finer than level 5 was selected near the POI"
        assert sent[0] == ["upload"] and sent[-1] == []                     # still POI: nothing re-sent
        assert r1.tag is mesh.vertex_positions and r1.n_vertices == len(mesh.vertex_positions)
        # The finest vertices lie on the DEM's interpolant (float32 output), not on a 1025-sample resampling.
        indices, tri_levels = mesh.update_indices(results[-1].levels)
        rows = np.unique(indices.reshape(-1, 3)[tri_levels == tri_levels.max()])
        xyz = mesh.vertex_positions[rows].astype(np.float64)
        np.testing.assert_allclose(xyz[:, 2], terrain.heights(xyz[:, 0], xyz[:, 1]), atol=1e-3, rtol=0)
        assert a.stats.summary()["triangles_median"] == results[-1].triangles


@pytest.mark.slow
def test_headless_demo_at_level_7_stays_within_the_cache_budget(tmp_path, fine_dem, capfd):
    """``headplod demo --headless --max-level 7 --terrain`` end to end: frames written, the summary says the
    mesh is lazy at level 7, its triangles are counted per frame, and the shared cache never held more than
    the --cache-mb budget (which is small enough to evict)."""
    out = tmp_path / "demo"
    status = cli_main(["demo", "--headless", "--mouse", "--terrain", str(fine_dem), "--spacing-m", str(DEM_SPACING_M),
                       "--max-level", "7", "--cache-mb", "2", "--frames", "3", "--size", "160,90",
                       "--viewpoints", "mountains", "--scenarios", "adaptive", "--no-full", "--out", str(out)])
    assert status == 0, capfd.readouterr().err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mesh"]["kind"] == "lazy" and summary["mesh"]["max_level"] == 7
    assert summary["mesh"]["full_triangles"] == 2048 * 4 ** 7
    (run,) = summary["runs"]
    assert run["frames"] == 3 and run["mesh"]["kind"] == "lazy"
    assert 0 < run["mesh"]["cache_bytes_max"] <= 2 * 2 ** 20
    assert all(t > 2048 for t in run["per_frame"]["triangles"])
    assert len(list((out / "frames").glob("*.png"))) == 2
    import io

    from headplod.demo.cli import print_table

    table = io.StringIO()
    print_table(summary, table)
    assert "mesh: lazy, level 7" in table.getvalue() and "of 2 MB" in table.getvalue()


@pytest.mark.parametrize("command", ["demo", "render"])
@pytest.mark.parametrize("extra, words", [
    (["--max-level", "0"], "1..8"), (["--max-level", "9"], "1..8"), (["--max-level", "x"], "whole number"),
    (["--max-level", "5.5"], "whole number"), (["--cache-mb", "64"], "lazy mesh only"),
    (["--max-level", "7", "--cache-mb", "0.1"], "1..65536"),
    (["--max-level", "8", "--mode", "full"], "--max-level 7 or lower"),
    (["--max-level", "6", "--backend", "raymask"], "lazy mesh does not keep"),
    (["--lazy", "--backend", "raymask"], "lazy mesh does not keep")])
def test_bad_mesh_options_exit_2_with_one_line_before_writing(tmp_path, capsys, command, extra, words):
    out = tmp_path / "out"
    target = ["--headless", "--out", str(out)] if command == "demo" else ["--out", str(out / "x.png")]
    assert cli_main([command, *extra, *target]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and words in err, err
    assert not out.exists()


def test_mesh_options_choose_the_lazy_mesh_above_level_5():
    from headplod.render.still import MeshOptions

    assert MeshOptions() == MeshOptions(5, False, 256.0) and not MeshOptions().lazy
    assert MeshOptions(6).lazy and MeshOptions(8).lazy and MeshOptions(5, lazy=True).lazy
    assert MeshOptions(7, cache_mb=2).cache_bytes == 2 * 2 ** 20
    for bad in ({"max_level": 9}, {"max_level": 5.5}, {"cache_mb": 0.5}, {"cache_mb": float("nan")}):
        with pytest.raises(ValueError):
            MeshOptions(**bad)
