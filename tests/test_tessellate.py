"""The tessellation back end (headplod.render.tessellate) and its numpy half (headplod.plod.patches).

- The height grid equals ``Terrain.heights`` at its samples.
- The control shader's CSF levels equal :func:`patch_levels` (built from
  ``plod.perception``) within float32 tolerance, per patch and per edge.
- The tessellated surface is watertight across every neighbour pair: every
  generated triangle's vertices are read back (a storage buffer), and every
  interior edge of the triangulation is shared by exactly two triangles,
  every border edge by one, and the triangles tile the grid's area exactly.
- A still view renders identical frames.

The GL tests need OpenGL 4.3 (storage buffers; Mesa llvmpipe has it) and skip, saying why, without.
"""
import numpy as np
import pytest

from headplod.plod.patches import PatchGrid, height_grid, patch_levels, tess_factors
from headplod.plod.select import SelectorConfig
from headplod.plod.terrain import Terrain
from headplod.plod.view import ConditionedView, head_axes
from headplod.render.projection import off_axis_projection
from headplod.render.still import default_head
from render_hooks import triangle_samples

N_SAMPLES = 257      # grid side: 16 x 16 patches of 16 samples
PATCH = 16
# float32 against float64: angles from chords of unit vectors carry ~1e-7 relative error, the CSF's log
# form a few ulps; the levels are log2 of their product, so the float32 noise is of order 1e-4 levels.
LEVEL_ATOL = 2e-3


@pytest.fixture(scope="module")
def terrain():
    return Terrain.jacksboro(detail_min_wavelength_m=20.0)


@pytest.fixture(scope="module")
def grid(terrain):
    z, dx, dy = height_grid(terrain, N_SAMPLES)
    x0, _, y0, _ = terrain.extent
    return PatchGrid.build(z, dx, dy, PATCH, origin_m=(x0, y0))


def _cv(head, axes, cov, t=None):
    """The conditioned view of an unfiltered eye (world mm) and head axes, covariance (deg²) and time (s)."""
    return ConditionedView(t, np.asarray(head, float), np.zeros(2), axes, cov, np.asarray(head, float), np.zeros(2),
                           cov)


def _view(screen, grid, poi_px=None, head_mm=None):
    from headplod.render.tessellate import grid_model

    head = default_head(screen) if head_mm is None else np.asarray(head_mm, float)
    poi = np.array(screen.size_px, float) / 2 if poi_px is None else np.asarray(poi_px, float)
    view, proj = off_axis_projection(head, screen, near_mm=50.0, far_mm=5000.0)
    return view, proj, grid_model(grid, screen), head, head_axes(screen, head, poi)


@pytest.mark.slow
def test_height_grid_equals_terrain_heights(terrain):
    z, dx, dy = height_grid(terrain, 129)
    x0, _, y0, _ = terrain.extent
    rng = np.random.default_rng(3)
    i, j = rng.integers(0, 129, 300), rng.integers(0, 129, 300)
    ref = terrain.heights(x0 + j * dx, y0 + i * dy)
    # float32 heights of ~1000 m: 6e-5 m resolution; the detail waves' float32 phases add ~1e-4 m.
    np.testing.assert_allclose(z[i, j], ref, atol=2e-3)


def test_patch_grid_ranges_and_contrast(grid):
    z, p = grid.heights_m, grid.patch_samples
    assert grid.n_patches == (N_SAMPLES - 1) // PATCH
    for pi, pj in ((0, 0), (3, 7), (15, 15)):
        block = z[pi * p:(pi + 1) * p + 1, pj * p:(pj + 1) * p + 1]
        assert grid.z_min_m[pi, pj] == block.min() and grid.z_max_m[pi, pj] == block.max()
    assert np.all((grid.contrast > 0) & (grid.contrast < 1))


def test_patch_grid_rejects_bad_sizes():
    with pytest.raises(ValueError, match="multiple of patch_samples"):
        PatchGrid.build(np.zeros((20, 20)), 1.0, 1.0, 8)
    with pytest.raises(ValueError, match="square"):
        PatchGrid.build(np.zeros((17, 9)), 1.0, 1.0, 8)


def test_config_validation():
    from headplod.render.tessellate import TessellationConfig

    assert TessellationConfig().max_level == 6
    assert TessellationConfig(patch_samples=16).max_level == 4
    for bad in ({"patch_samples": 48}, {"max_tess_level": 0}, {"csf_stage": "fragment"}, {"factors": "round"}):
        with pytest.raises(ValueError):
            TessellationConfig(**bad)
    for moved in ("level_bias", "shift", "ellipse_sigma", "light_dir", "ambient"):     # SelectorConfig's, shading's
        with pytest.raises(TypeError):
            TessellationConfig(**{moved: None})


@pytest.mark.parametrize("cov_deg2, shift, bias, stage", [
    (np.diag([0.05 ** 2, 0.05 ** 2]), "ellipse", 0.0, "vertex"),     # the bench's tracker σ
    (np.diag([0.05 ** 2, 0.05 ** 2]), "ellipse", 0.0, "control"),    # the CSF in the tessellation control shader
    (np.array([[2.0, 0.6], [0.6, 0.8]]), "ellipse", 0.0, "control"),  # a wide, tilted ellipse
    (np.array([[2.0, 0.6], [0.6, 0.8]]), "eq1", 0.5, "vertex"),
    (None, "ellipse", -1.0, "control"),
])
def test_shader_csf_equals_perception(ctx430, grid, default_screen, cov_deg2, shift, bias, stage):
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    cfg = TessellationConfig(patch_samples=PATCH, csf_stage=stage)
    view, proj, model, head, axes = _view(default_screen, grid, poi_px=(700.0, 500.0))
    with TessellationRenderer(ctx430, grid, size=(64, 36), config=cfg,
                              selection=SelectorConfig(mode="csf", shift=shift, level_bias=bias)) as r:
        inner, outer, culled = r.levels(view, proj, model, _cv(head, axes, cov_deg2))
    ref_inner, ref_outer = patch_levels(grid, model, head, axes, cov_deg2, shift=shift, level_bias=bias)
    assert np.isfinite(ref_inner).all()
    assert ref_inner.max() - ref_inner.min() > 2            # the view spans several levels
    np.testing.assert_allclose(inner, ref_inner, atol=LEVEL_ATOL)
    np.testing.assert_allclose(outer, ref_outer, atol=LEVEL_ATOL)
    # The factors agree, by either rule, except where a level is within the tolerance of a rule's boundary.
    top = cfg.max_level
    for rule in ("whole", "power_of_two"):
        near = tess_factors(ref_inner - LEVEL_ATOL, top, PATCH, rule) != tess_factors(ref_inner + LEVEL_ATOL, top,
                                                                                       PATCH, rule)
        assert near.mean() < 0.1
        assert np.array_equal(tess_factors(inner, top, PATCH, rule)[~near], tess_factors(ref_inner, top, PATCH, rule)[~near])


def test_whole_factors_keep_every_gap_and_are_the_fewest():
    """The "whole" rule: with vertex k of F at round(k P / F) samples, no gap exceeds the level's spacing
    floor(P 2^-L) (at least one sample), and F - 1 segments would leave one that does; never more
    segments than the power-of-two rule, and fewer at many levels (whole samples limit the gain near the
    finest levels: a gap of 1.4 samples still needs one vertex per sample)."""
    levels = np.linspace(-2.0, 7.0, 2001)
    for p, top in ((64, 6), (16, 4), (128, 6)):
        whole = tess_factors(levels, top, p, "whole")
        pow2 = tess_factors(levels, top, p, "power_of_two")
        assert np.all(whole <= pow2) and np.all(whole >= 1) and whole.max() == 2 ** top
        spacing = np.maximum(np.floor(p * np.exp2(-np.clip(levels, -1, top))), 1)
        for f, g in zip(whole, spacing):
            gaps = np.diff(np.round(np.arange(f + 1) * p / f))
            assert gaps.max() <= g
            if f > 1:
                assert np.diff(np.round(np.arange(f) * p / (f - 1))).max() > g
        inside = (levels > 0) & (levels < top)
        assert np.mean(whole[inside] < pow2[inside]) > 0.2            # many levels get fewer segments
        assert np.mean((pow2[inside] / whole[inside]) ** 2) > 1.15     # and fewer triangles on average
    with pytest.raises(ValueError, match="rule"):
        tess_factors(levels, 6, 64, "nearest")


def test_edge_levels_agree_between_neighbours(grid, default_screen):
    _, _, model, head, axes = _view(default_screen, grid)
    _, outer = patch_levels(grid, model, head, axes, np.diag([0.05 ** 2] * 2))
    # east edge of (i, j) is the west edge of (i, j+1); north of (i, j) is south of (i+1, j)
    assert np.array_equal(outer[:, :-1, 2], outer[:, 1:, 0])
    assert np.array_equal(outer[:-1, :, 3], outer[1:, :, 1])


def _edges_and_area(tri):
    """Undirected edges (E, 4) of triangles (T, 3, 2) of sample coordinates, and their total area (samples²)."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])          # (3T, 2, 2)
    key = e.reshape(-1, 4)
    swap = (key[:, 0] > key[:, 2]) | ((key[:, 0] == key[:, 2]) & (key[:, 1] > key[:, 3]))
    key[swap] = key[swap][:, [2, 3, 0, 1]]
    a, b = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return key, area


@pytest.mark.slow
@pytest.mark.parametrize("mode, poi_px, stage, rule", [("csf", (700.0, 500.0), "vertex", "whole"),
                                                       ("csf", (100.0, 900.0), "control", "whole"),
                                                       ("csf", (700.0, 500.0), "vertex", "power_of_two"),
                                                       ("full", None, "vertex", "whole")])
def test_patches_are_watertight(ctx430, grid, default_screen, mode, poi_px, stage, rule):
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    # No culling: every patch and every neighbour pair is generated. "full" makes 66049 vertices,
    # more than one draw call may hold on llvmpipe: the split into calls is checked too.
    cfg = TessellationConfig(patch_samples=PATCH, cull=False, csf_stage=stage, factors=rule)
    view, proj, model, head, axes = _view(default_screen, grid, poi_px=poi_px)
    cv = _cv(head, axes, np.diag([0.05 ** 2] * 2))
    with TessellationRenderer(ctx430, grid, size=(64, 36), config=cfg) as r:
        tri = triangle_samples(r, view, proj, model, cv, mode=mode)
        _, outer, _ = r.levels(view, proj, model, cv)
    if mode == "csf":
        assert len(np.unique(tess_factors(outer, cfg.max_level, PATCH, rule))) >= 3   # edges of different factors meet
    key, area = _edges_and_area(tri)
    assert np.all(area > 0)                                                 # no degenerate triangles
    n = N_SAMPLES - 1
    assert area.sum() == pytest.approx(n * n, abs=1e-6)                    # the grid, tiled exactly
    edges, counts = np.unique(key, axis=0, return_counts=True)
    on_border = (((edges[:, 0] == edges[:, 2]) & np.isin(edges[:, 0], (0, n)))
                 | ((edges[:, 1] == edges[:, 3]) & np.isin(edges[:, 1], (0, n))))
    assert np.all(counts[on_border] == 1)
    assert np.all(counts[~on_border] == 2), f"{np.sum(counts[~on_border] != 2)} edges not shared by two triangles"


@pytest.mark.slow
def test_still_view_gives_identical_frames(ctx430, grid, default_screen):
    from headplod.render.frame import FrameSettings, one_frame
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer, grid_model

    cov = np.diag([0.05 ** 2] * 2)
    with TessellationRenderer(ctx430, grid, size=(320, 180), config=TessellationConfig(patch_samples=PATCH)) as r:
        model = grid_model(grid, default_screen)
        a = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=cov, t=0.0, renderer=r)
        b = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=cov, t=1 / 60, renderer=r)
    assert a.triangles == b.triangles > 0
    assert np.array_equal(a.image, b.image)
    assert (a.image != np.array([158, 184, 209], np.uint8)).any(axis=-1).mean() > 0.3    # the terrain is in view


@pytest.mark.slow
def test_many_patches_keep_their_ids(ctx430, default_screen):
    """16384 patches in one draw: on llvmpipe gl_PrimitiveID restarts within such a draw (it gave the
    control shader other patches' levels); the patch is known by its vertex instead. Both stages agree,
    and the surface stays watertight."""
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    terrain = Terrain.jacksboro(detail_min_wavelength_m=40.0)
    z, dx, dy = height_grid(terrain, 2049)
    big = PatchGrid.build(z, dx, dy, 16, origin_m=terrain.extent[::2])
    view, proj, model, head, axes = _view(default_screen, big, poi_px=(700.0, 500.0))
    cov = np.diag([0.05 ** 2] * 2)
    levels = {}
    for stage in ("vertex", "control"):
        with TessellationRenderer(ctx430, big, size=(64, 36),
                                  config=TessellationConfig(patch_samples=16, cull=False, csf_stage=stage)) as r:
            levels[stage] = r.levels(view, proj, model, _cv(head, axes, cov))
            if stage == "control":
                tri = triangle_samples(r, view, proj, model, _cv(head, axes, cov), capacity=1 << 22)
    for a, b in zip(levels["vertex"], levels["control"]):
        np.testing.assert_allclose(a, b, atol=LEVEL_ATOL)
    key, area = _edges_and_area(tri)
    assert area.sum() == pytest.approx(2048.0 ** 2, abs=1e-3)
    _, counts = np.unique(key, axis=0, return_counts=True)
    assert counts.max() == 2


@pytest.mark.slow
def test_render_cli_tessellation_backend(ctx430, tmp_path, monkeypatch, capsys):
    from headplod.cli import main as cli_main

    monkeypatch.setenv("HEADPLOD_CACHE", str(tmp_path / "cache"))
    out, stats = tmp_path / "t.png", tmp_path / "t.json"
    assert cli_main(["render", "--backend", "tessellation", "--grid-samples", "129", "--size", "160,90",
                     "--cov", "0.01,0,0.01", "--out", str(out), "--stats", str(stats)]) == 0
    import json
    st = json.loads(stats.read_text())
    assert out.exists() and st["triangles"] > 0 and st["grid_samples"] == 129
    assert cli_main(["render", "--backend", "tessellation", "--mode", "gp", "--out", str(out)]) == 2
    assert "does not take --mode gp" in capsys.readouterr().err
    assert cli_main(["render", "--backend", "tessellation", "--grid-samples", "100", "--out", str(out)]) == 2
    # A person's own terrain, resampled to the grid.
    y, x = np.mgrid[0:60, 0:80]
    np.save(tmp_path / "h.npy", (200 * np.sin(x / 9.0) * np.cos(y / 7.0) + 500).astype(np.float32))
    assert cli_main(["render", "--backend", "tessellation", "--terrain", str(tmp_path / "h.npy"), "--spacing-m", "30",
                     "--grid-samples", "129", "--size", "160,90", "--out", str(out), "--stats", str(stats)]) == 0
    assert json.loads(stats.read_text())["triangles"] > 0
    # The hierarchy's selection from the command line; it refuses a grid whose patches per side are not 2^k.
    assert cli_main(["render", "--backend", "tessellation", "--selection", "tree", "--grid-samples", "257",
                     "--size", "160,90", "--out", str(out), "--stats", str(stats)]) == 0
    assert json.loads(stats.read_text())["triangles"] > 0
    assert cli_main(["render", "--backend", "tessellation", "--selection", "tree", "--grid-samples", "193",
                     "--out", str(out)]) == 2
    assert "power-of-two number of patches" in capsys.readouterr().err


def _sample_colors(grid, height_range):
    """(n, n, 3) float32: every sample's colour as gl.py's shaded terrain computes a vertex's (ground truth, numpy)."""
    from types import SimpleNamespace

    from headplod.plod.patches import grid_normals
    from headplod.render.raymask import vertex_colors

    heights = SimpleNamespace(heights=grid.heights_m, normals=grid_normals(grid.heights_m, grid.dx_m, grid.dy_m))
    return vertex_colors(heights, height_range)


def test_texture_shading_bakes_every_samples_colour(ctx430, grid):
    """The colour texture's level 0 is each sample's own colour (its neighbours' central differences), and
    its mip levels are the averages of the samples below them: what a pixel covering them should show."""
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    with TessellationRenderer(ctx430, grid, size=(64, 36), config=TessellationConfig(patch_samples=PATCH)) as r:
        n = grid.heights_m.shape[0]
        got = np.frombuffer(r._color.read(level=0), np.uint8).reshape(n, n, 4)[..., :3] / 255.0
        want = _sample_colors(grid, r.height_range)
        assert np.abs(got - want).max() <= 0.6 / 255 + 1e-6          # 8-bit rounding only
        m = (n - 1) // 4                                             # level 2: 4 x 4 samples per texel
        mip = np.frombuffer(r._color.read(level=2), np.uint8).reshape(m, m, 4)[..., :3] / 255.0
        box = want[:4 * m, :4 * m].reshape(m, 4, m, 4, 3).mean(axis=(1, 3))
        assert np.abs(mip - box).mean() < 2.0 / 255


@pytest.mark.slow
def test_texture_shading_meets_the_full_detail_render(ctx430, default_screen):
    """On a grid whose samples are finer than a pixel, the csf frame with texture shading is within 45 dB of
    the full-detail render in the 5° disc, and clearly closer than per-vertex shading is: that shows each
    level's smoothed normals, not the average of the samples' shading."""
    from headplod.render.image_metrics import disc_mask, psnr_db
    from headplod.render.still import px_per_deg_at
    from headplod.render.frame import FrameSettings, one_frame
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer, grid_model

    terrain = Terrain.jacksboro(detail_min_wavelength_m=20.0)
    z, dx, dy = height_grid(terrain, 1025)
    fine = PatchGrid.build(z, dx, dy, 64, origin_m=terrain.extent[::2])
    size = (320, 180)                                       # 1025 samples across ~300 px: 0.3 px per sample
    head = default_head(default_screen)
    disc = disc_mask(size[::-1], (size[0] / 2, size[1] / 2), 5.0 * px_per_deg_at(default_screen, head, size))
    cov = np.diag([0.05 ** 2] * 2)
    psnr = {}
    for shading in ("texture", "vertex"):
        with TessellationRenderer(ctx430, fine, size=size, config=TessellationConfig(shading=shading)) as r:
            model = grid_model(fine, default_screen)
            out = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=cov, renderer=r)
            ref = one_frame(FrameSettings("tessellation", SelectorConfig(mode="full")), default_screen, model, cov_deg2=cov, renderer=r)
            csf, full = out.image, ref.image
        assert out.triangles < ref.triangles / 4
        psnr[shading] = psnr_db(csf, full, disc)
    assert psnr["texture"] >= 45.0, psnr
    assert psnr["vertex"] < psnr["texture"] - 5, psnr


def test_patch_samples_for_keeps_two_vertices_per_pixel():
    from headplod.plod.patches import patch_samples_for

    for n in (129, 1025, 2049, 4097, 8193, 16385):
        for px in (320, 1280, 1920):
            p = patch_samples_for(n, px)
            assert p >= 64 and (n - 1) % p == 0 and p & (p - 1) == 0
            finest = (n - 1) // p * min(p, 64)             # vertices across the terrain at the finest level
            assert finest >= 2 * px or p == 64             # enough for the image (or the smallest patch)
            if (n - 1) % (2 * p) == 0:                     # and the next size up would not be
                assert (n - 1) // (2 * p) * 64 < 2 * px
    assert patch_samples_for(8193, 1280) == 128 and patch_samples_for(1025, 1280) == 64
    with pytest.raises(ValueError, match="multiple of 64"):
        patch_samples_for(1000, 1280)


def test_shader_csf_of_a_moving_eye_equals_perception(ctx430, grid, default_screen):
    """With the eye moving the levels pass solves f_max per point (Newton on Lambert's W) instead of the
    still-head shortcut: it equals levels_of_patches given the same last eye and time step."""
    from headplod.plod.patches import levels_of_patches
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    cov = np.diag([0.05 ** 2] * 2)
    view0, proj0, model, head0, axes0 = _view(default_screen, grid, poi_px=(700.0, 500.0))
    head1 = head0 + np.array([25.0, -10.0, 0.0])               # 25 mm in 1/60 s: points move ~100 deg/s
    view1, proj1, _, _, axes1 = _view(default_screen, grid, poi_px=(700.0, 500.0), head_mm=head1)
    with TessellationRenderer(ctx430, grid, size=(64, 36), config=TessellationConfig(patch_samples=PATCH)) as r:
        still, _, _ = r.levels(view0, proj0, model, _cv(head0, axes0, cov, t=0.0))
        inner, outer, _ = r.levels(view1, proj1, model, _cv(head1, axes1, cov, t=1 / 60))   # moved since the last
    n = grid.n_patches
    ref_inner, ref_outer = levels_of_patches(grid.corners_scene(), grid.contrast, grid.neighbour_contrast(), model,
                                             head1, axes1, cov, eye_prev_mm=head0, dt_s=1 / 60)
    assert ref_inner.shape == (n, n)
    np.testing.assert_allclose(inner, ref_inner, atol=LEVEL_ATOL)
    np.testing.assert_allclose(outer, ref_outer, atol=LEVEL_ATOL)
    assert np.median(still - inner) > 0.5                       # the motion coarsens: the Newton path ran


# The level rule alone on the GPU (tess_shaders.RULE), fed explicit inputs: offsets (φ, θ), reach, diameter,
# contrast, speed and the foveal f_max; out: eccentricity, f_max and level, as criteria computes them.
_RULE_HARNESS = """
layout(std430, binding = 5) readonly buffer Inputs { vec4 inputs[]; };     // 2 per case
layout(std430, binding = 6) writeonly buffer Outputs { vec4 outputs[]; };  // ecc, f_max, level, 0
void main() {
    vec4 a = inputs[2 * gl_VertexID], b = inputs[2 * gl_VertexID + 1];
    float ecc = piece_eccentricity_deg(shift(a.xy), a.z);
    float f = piece_fmax_cpd(b.x, b.y, ecc, b.z);
    outputs[gl_VertexID] = vec4(ecc, f, frequency_level(f, a.w), 0.0);
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    gl_PointSize = 1.0;
}
"""
# float32 (ε = 1.2e-7) against float64. The eccentricity goes through tan, atan and degrees: ~1e-6 relative
# at 40° (4e-5 deg), so RULE_ECC_ATOL = 5e-4 deg. f_max's Newton step solves t - ln t = L, whose root has
# relative error ~ε |L| / (t - 1): below 1e-5 when L - 1 > 1e-3 (closer to the visibility threshold L = 1,
# f_max jumps from 2/b to 0 and either side may round the other way: those cases are left out); the level
# is log2(f_max · diameter) + bias, so its error is ~1e-5 / ln 2 plus a few ulps of log2: RULE_LEVEL_ATOL
# = 1e-4 levels.
RULE_ECC_ATOL = 5e-4
RULE_LEVEL_ATOL = 1e-4


@pytest.mark.parametrize("cov_deg2, shift", [(None, "ellipse"), (np.diag([0.05 ** 2] * 2), "ellipse"),
                                             (np.array([[2.0, 0.6], [0.6, 0.8]]), "ellipse"),
                                             (np.array([[2.0, 0.6], [0.6, 0.8]]), "eq1")])
def test_shader_rule_equals_criteria_on_a_grid(ctx430, cov_deg2, shift):
    """The GLSL level rule (tess_shaders.RULE: its constants generated from csf.py) against criteria.csf_level
    on contrast x eccentricity (offset size and direction) x speed (below, at and above the floor: the
    foveal shortcut and the Newton path) x size (diameter, reach), for each uncertainty."""
    import itertools

    import moderngl

    from headplod.plod import criteria
    from headplod.plod import perception as pc
    from headplod.plod.csf import MIN_SPEED_DEG_S, csf_coefficients
    from headplod.render import tess_shaders as ts

    grid = np.array(list(itertools.product([0.003, 0.01, 0.03, 0.1, 0.3, 0.7, 1.0],      # contrast
                                           [0.0, 0.5, 2.0, 5.0, 10.0, 20.0, 40.0],       # |offset|, deg
                                           np.radians([0.0, 35.0, 90.0, 200.0]),         # its direction
                                           [0.05, 0.1, 0.5, 3.0, 20.0, 80.0],            # speed, deg/s
                                           [1e-3, 0.05, 0.5, 4.0])))                     # diameter, deg
    contrast, size, direction, speed, diameter = grid.T
    offsets = np.stack([size * np.sin(direction), size * np.cos(direction)], axis=-1)
    reach, bias = 0.6 * diameter, 0.25
    still = criteria.foveal_fmax_cpd(contrast, MIN_SPEED_DEG_S)
    inputs = np.stack([offsets[:, 0], offsets[:, 1], reach, diameter, contrast, speed, still,
                       np.zeros_like(speed)], axis=-1).astype("f4")
    prog = ctx430.program(vertex_shader="#version 430\n" + ts.RULE + _RULE_HARNESS, fragment_shader=ts.NO_FRAGMENT)
    vao = ctx430.vertex_array(prog, [])
    fbo = ctx430.framebuffer(color_attachments=[ctx430.renderbuffer((4, 4), components=4)])
    src, dst = ctx430.buffer(inputs.tobytes()), ctx430.buffer(reserve=16 * len(grid))
    try:
        prog["u_shift_form"].value = ts.SHIFT_FORMS[None if cov_deg2 is None else shift]
        prog["u_cov_inv"].write(np.linalg.inv(np.eye(2) if cov_deg2 is None else cov_deg2).astype("f4").tobytes())
        prog["u_ellipse_sigma"].value = 2.0
        prog["u_level_bias"].value = bias
        src.bind_to_storage_buffer(5)
        dst.bind_to_storage_buffer(6)
        fbo.use()
        vao.render(moderngl.POINTS, vertices=len(grid))
        ctx430.memory_barrier()
        got = np.frombuffer(dst.read(), np.float32).reshape(-1, 4).astype(np.float64)
    finally:
        for obj in (vao, prog, fbo, src, dst):
            obj.release()
    shifted = pc.uncertainty_shift(offsets, cov_deg2, shift, 2.0) if cov_deg2 is not None else offsets
    ecc = criteria.piece_eccentricity_deg(shifted, reach)
    want = criteria.csf_level(contrast, speed, ecc, diameter, level_bias=bias)
    A, b = csf_coefficients(speed)
    clear = np.abs(0.5 * np.log(A * contrast) - np.log(0.5 * b) - 1.0) > 1e-3      # not at the threshold
    assert clear.mean() > 0.95 and (want < -20).any() and (want > 3).any()      # invisible and fine pieces alike
    np.testing.assert_allclose(got[:, 0], ecc, atol=RULE_ECC_ATOL)
    np.testing.assert_allclose(got[clear, 2], want[clear], atol=RULE_LEVEL_ATOL)


@pytest.mark.slow
def test_uncertainty_none_ignores_the_covariance(ctx430, grid, default_screen):
    """Scenario ``none`` draws as without a covariance (the view is conditioned first): a wide covariance
    changes the frame only under a scenario that uses it."""
    from headplod.plod.select import SelectorConfig
    from headplod.render.frame import FrameSettings, one_frame
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer, grid_model

    wide = np.diag([9.0, 9.0])
    with TessellationRenderer(ctx430, grid, size=(160, 90), config=TessellationConfig(patch_samples=PATCH)) as r:
        model = grid_model(grid, default_screen)
        plain = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=None, renderer=r)
        none = one_frame(FrameSettings("tessellation", SelectorConfig(mode="csf", uncertainty="none")),
                         default_screen, model, cov_deg2=wide, renderer=r)
        used = one_frame(FrameSettings("tessellation"), default_screen, model, cov_deg2=wide, renderer=r)
    assert np.array_equal(plain.image, none.image) and plain.triangles == none.triangles
    assert used.triangles > none.triangles


def test_shader_culling_equals_the_clip_box_test(ctx430, grid, default_screen):
    """The levels pass's culled flags are cull.box_outside_clip's (the GLSL outside() is its float32 copy),
    on a view that culls part of the grid, with and without an NDC region; a box within float32 noise of a
    plane may go either way."""
    from headplod.plod import cull
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    view, proj, model, head, axes = _view(default_screen, grid, poi_px=(200.0, 900.0),
                                          head_mm=default_head(default_screen) + np.array([250.0, 120.0, -200.0]))
    mvp = proj @ view @ model
    p, n = grid.patch_samples, grid.n_patches
    j, i = np.meshgrid(np.arange(n), np.arange(n))
    lo = np.stack([grid.origin_m[0] + j * p * grid.dx_m, grid.origin_m[1] + i * p * grid.dy_m, grid.z_min_m], -1)
    hi = np.stack([lo[..., 0] + p * grid.dx_m, lo[..., 1] + p * grid.dy_m, grid.z_max_m], -1)
    corners = cull.box_corners(lo.reshape(-1, 3), hi.reshape(-1, 3))
    with TessellationRenderer(ctx430, grid, size=(64, 36), config=TessellationConfig(patch_samples=PATCH)) as r:
        for region in (None, (-0.3, -0.2, 0.4, 0.5)):
            culled = r._levels_pass(view, proj, model, _cv(head, axes, None), "csf", region)[..., 5] > 0.5
            want = cull.box_outside_clip(corners, mvp, region).reshape(n, n)
            assert 0.1 < want.mean() < 0.9
            assert np.count_nonzero(culled != want) <= 2


@pytest.mark.parametrize("moving", [False, True], ids=["still", "moving"])
@pytest.mark.parametrize("cov_deg2, shift", [(None, "ellipse"), (np.array([[2.0, 0.6], [0.6, 0.8]]), "ellipse"),
                                             (np.array([[0.3, -0.1], [-0.1, 0.2]]), "eq1")])
@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_levels_pass_equals_criteria_on_a_grid(ctx430, grid, default_screen, moving, cov_deg2, shift, scale):
    """The GPU's levels pass against criteria (patches.levels_of_patches) on a grid of inputs: every patch's
    contrast from 0.002 to 1 (log-spaced, shuffled: invisible to fully visible pieces at every eccentricity),
    the eccentricity across the grid's patches about the POI, the eye still or moving 2 mm in 1/60 s
    (the foveal shortcut and the Newton path), three uncertainties and two sizes of the terrain (the model
    scaled about the grid's centre). Tolerance LEVEL_ATOL (float32, above); a piece within 1e-3 of the
    visibility threshold (L = 1, where f_max jumps to 0) is left out."""
    import dataclasses

    from headplod.plod import criteria
    from headplod.plod.csf import csf_coefficients
    from headplod.plod.patches import levels_of_patches
    from headplod.render.tessellate import TessellationConfig, TessellationRenderer

    n = grid.n_patches
    rng = np.random.default_rng(5)
    contrast = rng.permutation(np.logspace(np.log10(0.002), 0.0, n * n)).reshape(n, n).astype(np.float32)
    g = dataclasses.replace(grid, contrast=contrast)
    view, proj, model, head, axes = _view(default_screen, g, poi_px=(700.0, 500.0))
    centre_scene = np.array([*np.mean(np.reshape(g.extent, (2, 2)), axis=1), g.heights_m.mean()])
    centre = model[:3, :3] @ centre_scene + model[:3, 3]
    model = model.copy()
    model[:3, :3] *= scale
    model[:3, 3] = centre + scale * (model[:3, 3] - centre)
    prev = head + (np.array([2.0, -1.0, 0.0]) if moving else 0.0)
    with TessellationRenderer(ctx430, g, size=(64, 36), config=TessellationConfig(patch_samples=PATCH, cull=False),
                              selection=SelectorConfig(mode="csf", shift=shift, level_bias=0.3)) as r:
        r.levels(view, proj, model, _cv(prev, axes, cov_deg2, t=0.0))             # the last frame's eye
        inner, outer, _ = r.levels(view, proj, model, _cv(head, axes, cov_deg2, t=1 / 60))
    corners, neighbours = g.corners_scene(), g.neighbour_contrast()
    want_inner, want_outer = levels_of_patches(corners, g.contrast, neighbours, model, head, axes, cov_deg2,
                                               shift=shift, level_bias=0.3, eye_prev_mm=prev if moving else None,
                                               dt_s=1 / 60)
    homog = np.concatenate([corners, np.ones(corners.shape[:-1] + (1,))], axis=-1)
    points, _, _ = criteria.patch_pieces((homog @ model.T)[..., :3], head)
    speed = criteria.point_speed_deg_s(points, head, prev if moving else None, 1 / 60)
    A, b = csf_coefficients(speed)
    L = 0.5 * np.log(A * criteria.patch_piece_contrast(g.contrast, neighbours)) - np.log(0.5 * b)
    clear = np.abs(L - 1.0) > 1e-3
    got, want = np.concatenate([inner[..., None], outer], -1), np.concatenate([want_inner[..., None], want_outer], -1)
    assert clear.mean() > 0.97 and (want < -20).any() and (want > 2).any()      # invisible and fine pieces alike
    np.testing.assert_allclose(got[clear], want[clear], atol=LEVEL_ATOL)
