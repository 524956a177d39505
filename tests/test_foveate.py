"""Foveated resolution layers (issue 13, first part): the layers' densities follow the CSF, the uncertainty
widens them, and the composite is the plain frame inside the fovea."""
import math

import numpy as np
import pytest

from headplod.plod.csf import max_visible_freq_cpd
from headplod.plod.select import SelectorConfig
from headplod.render.foveate import FoveationConfig, layer_plan
from raw_views import RawViews
from render_hooks import layer_image


@pytest.mark.parametrize("ppd", [15.0, 25.2, 40.0])
def test_each_layer_carries_every_visible_frequency_it_covers(ppd):
    cfg = FoveationConfig(max_layers=4)
    layers = layer_plan(ppd, None, cfg)
    assert [l.scale for l in layers] == [1.0, 0.5, 0.25, 0.125]
    assert layers[0].inner_deg == 0.0 and math.isinf(layers[-1].outer_deg)
    for a, b in zip(layers, layers[1:]):
        assert a.outer_deg == b.inner_deg                              # nested, no gap
    for layer in layers[1:]:
        # Nyquist at the layer's inner border: its pixels per degree carry twice f_max there ...
        e = np.linspace(layer.inner_deg, min(layer.outer_deg, layer.inner_deg + 40.0), 50)
        f = max_visible_freq_cpd(cfg.contrast, cfg.speed_deg_s, e, model=cfg.csf_model)
        assert np.all(2.0 * f <= layer.scale * ppd * (1 + 1e-6))
        # ... and the coarser scale would not have (the border is where it starts to suffice).
        f_in = max_visible_freq_cpd(cfg.contrast, cfg.speed_deg_s, layer.inner_deg - 0.05, model=cfg.csf_model)
        assert 2.0 * f_in > layer.scale * ppd


def test_the_uncertainty_moves_every_border_out_by_its_2_sigma():
    base = layer_plan(25.0, None)
    cov = np.array([[0.8, 0.3], [0.3, 0.4]])                            # deg²
    shifted = layer_plan(25.0, cov)
    two_sigma = 2.0 * math.sqrt(np.linalg.eigvalsh(cov).max())
    for a, b in zip(base[:-1], shifted[:-1]):
        assert b.outer_deg == pytest.approx(a.outer_deg + two_sigma)


def test_settings_are_checked():
    with pytest.raises(ValueError, match="max_layers"):
        FoveationConfig(max_layers=0)
    with pytest.raises(ValueError, match="csf_model"):
        FoveationConfig(csf_model="nope")
    with pytest.raises(ValueError, match="px_per_deg"):
        layer_plan(0.0)


@pytest.mark.slow
def test_composite_is_the_plain_frame_inside_the_fovea(gl_context, default_screen, terrain_scene):
    from headplod.plod.select import View
    from headplod.render import TerrainRenderer, off_axis_projection
    from headplod.render.foveate import FoveatedRenderer
    from headplod.render.still import default_head, px_per_deg_at

    size = (1280, 720)           # 25 px/deg: the fovea is a disc of the frame (a small frame is all fovea)
    renderer = TerrainRenderer(gl_context, size=size)
    foveated = FoveatedRenderer(renderer, FoveationConfig(blend_deg=1.0))
    try:
        head = default_head(default_screen)
        poi_screen = np.array(default_screen.size_px, dtype=float) / 2
        levels, _ = RawViews(terrain_scene.selector("csf", "none", hysteresis=False)).select(View(head, poi_screen))
        renderer.upload(*terrain_scene.mesh.update(levels))
        view, proj = off_axis_projection(head, default_screen, near_mm=50.0, far_mm=5000.0)
        plain = renderer.render(view, proj, terrain_scene.model)
        ppd = px_per_deg_at(default_screen, head, size)
        poi = poi_screen * np.array(size) / np.array(default_screen.size_px)
        image = foveated.render(view, proj, terrain_scene.model, poi, ppd)
        fovea = foveated.last_layers[0]
        yy, xx = np.mgrid[0:size[1], 0:size[0]]
        r_px = np.hypot(xx - poi[0], yy - poi[1])
        inside = r_px < (fovea.outer_deg - foveated.config.blend_deg) * ppd - 1
        assert inside.sum() > 100
        assert np.array_equal(image[inside], plain[inside])              # the fovea at full resolution
        outside = r_px > fovea.outer_deg * ppd + 1
        assert outside.sum() > 1000
        err = np.abs(image[outside].astype(int) - plain[outside].astype(int))
        assert err.mean() < 12                                            # coarser, not wrong
    finally:
        foveated.release()
        renderer.release()


@pytest.mark.slow
def test_render_foveate_reports_its_layers(gl_context, tmp_path):
    import json

    from headplod.cli import main as cli_main

    out, stats = tmp_path / "fov.png", tmp_path / "fov.json"
    assert cli_main(["render", "--foveate", "--cov", "0.2,0,0.2", "--out", str(out), "--stats", str(stats)]) == 0
    layers = json.loads(stats.read_text())["foveate_layers"]
    assert [layer["scale"] for layer in layers] == [1.0, 0.5]
    assert layers[-1]["outer_deg"] is None and out.stat().st_size > 1000


# --------------------------------------------------------------------------
# layer subsets, stability, seams (issue 13, second part)
# --------------------------------------------------------------------------

def _still_view(default_screen, terrain_scene, viewpoint, size=(1280, 720), poi_frac=(0.5, 0.5)):
    """(model, view, proj, poi output px, poi screen px, ppd, head) of a still view of a viewpoint."""
    from headplod.demo.viewpoints import place
    from headplod.render import off_axis_projection
    from headplod.render.still import default_head, px_per_deg_at

    head = default_head(default_screen)
    poi_screen = np.array(default_screen.size_px, dtype=float) * np.array(poi_frac)
    view, proj = off_axis_projection(head, default_screen, near_mm=50.0, far_mm=5000.0)
    return (place(terrain_scene, viewpoint).model, view, proj, poi_screen * np.array(size) / np.array(default_screen.size_px),
            poi_screen, px_per_deg_at(default_screen, head, size), head)


@pytest.mark.slow
@pytest.mark.parametrize("viewpoint,poi_frac", [("mountains", (0.5, 0.5)), ("plains", (0.3, 0.7))])
def test_face_spans_hold_every_triangle_touching_a_layer(default_screen, terrain_scene, viewpoint, poi_frac):
    """Each triangle whose own screen rectangle meets a layer's ring belongs to a face whose span has that layer."""
    from headplod.plod.select import View
    from headplod.render.foveate import face_layer_span, layer_plan, layer_regions

    size = (1280, 720)
    model, view, proj, poi, poi_screen, ppd, head = _still_view(default_screen, terrain_scene, viewpoint, size, poi_frac)
    placed_sel = __import__("headplod.demo.viewpoints", fromlist=["place"]).place(terrain_scene, viewpoint)
    mesh = terrain_scene.mesh.share()
    levels, _ = RawViews(placed_sel.selector("csf", "none", hysteresis=False)).select(View(head, poi_screen))
    idx, _ = mesh.update_indices(levels)
    faces = mesh.face_per_triangle()
    cfg = FoveationConfig(max_layers=3)
    layers = layer_plan(ppd, None, cfg)
    regions = layer_regions(layers, ppd, cfg.blend_deg)
    scales = np.array([l.scale for l in layers])
    poi_gl = (poi[0], size[1] - poi[1])
    span = face_layer_span(mesh.corners, mesh.z_range, model, view, proj, size, poi_gl, regions, scales)
    # Every vertex of every triangle, projected (float64), and each triangle's rectangle.
    p = mesh.vertex_positions[idx].astype(np.float64)
    clip = np.c_[p, np.ones(len(p))] @ (proj @ view @ model).T
    assert (clip[:, 3] > 0).all()
    x = ((clip[:, 0] / clip[:, 3] + 1) * 0.5 * size[0]).reshape(-1, 3)
    y = ((clip[:, 1] / clip[:, 3] + 1) * 0.5 * size[1]).reshape(-1, 3)
    x0, x1 = np.clip(x.min(1), 0, size[0]), np.clip(x.max(1), 0, size[0])
    y0, y1 = np.clip(y.min(1), 0, size[1]), np.clip(y.max(1), 0, size[1])
    on_screen = (x.max(1) >= 0) & (x.min(1) <= size[0]) & (y.max(1) >= 0) & (y.min(1) <= size[1])
    dmin = np.hypot(np.maximum(np.maximum(x0 - poi_gl[0], poi_gl[0] - x1), 0),
                    np.maximum(np.maximum(y0 - poi_gl[1], poi_gl[1] - y1), 0))
    dmax = np.hypot(np.maximum(abs(x0 - poi_gl[0]), abs(x1 - poi_gl[0])),
                    np.maximum(abs(y0 - poi_gl[1]), abs(y1 - poi_gl[1])))
    tri_span = span[faces]
    checked = 0
    for k, (lo, hi) in enumerate(regions):
        needs = on_screen & (dmin <= hi) & (dmax >= lo)
        assert needs.any()
        assert np.all((tri_span[needs, 0] >= 0) & (tri_span[needs, 0] <= k) & (tri_span[needs, 1] >= k)), k
        checked += int(needs.sum())
    # ... and the subsets are subsets: fewer triangles in all than the layers' count of the whole mesh.
    drawn = sum(int(((tri_span[:, 0] <= k) & (tri_span[:, 1] >= k) & (tri_span[:, 0] >= 0)).sum()) for k in range(3))
    assert checked <= drawn < 3 * len(faces)


@pytest.mark.slow
@pytest.mark.parametrize("max_layers,viewpoint", [(2, "mountains"), (3, "plains")])
def test_layer_subsets_give_the_pixels_of_the_whole_mesh(gl_context, default_screen, terrain_scene, max_layers,
                                                         viewpoint):
    """Each layer drawn from its subset has the pixels of the same layer drawn from the whole mesh, wherever the
    composite reads it; so the composites are identical."""
    from headplod.plod.select import View
    from headplod.demo.viewpoints import place
    from headplod.render import TerrainRenderer
    from headplod.render.foveate import FoveatedRenderer, layer_regions

    size = (1280, 720)
    model, view, proj, poi, poi_screen, ppd, head = _still_view(default_screen, terrain_scene, viewpoint, size,
                                                                (0.45, 0.55))
    mesh = terrain_scene.mesh.share()
    selector = RawViews(place(terrain_scene, viewpoint).selector("csf", "none", hysteresis=False))
    levels, _ = selector.select(View(head, poi_screen))
    idx, lv = mesh.update_indices(levels)
    renderer = TerrainRenderer(gl_context, size=size)
    renderer.upload(mesh.vertex_positions, mesh.vertex_normals, lv, idx)
    fov = FoveatedRenderer(renderer, FoveationConfig(max_layers=max_layers))
    try:
        fov.set_mesh(idx, lv, mesh.face_per_triangle(), (mesh.corners, mesh.z_range))
        image_sub = fov.render(view, proj, model, poi, ppd)
        assert sum(fov.last_triangles_per_layer) < max_layers * len(lv)       # the subsets are smaller
        layers_sub = [layer_image(fov, k) for k in range(max_layers)]
        image_all = fov.render(view, proj, model, poi, ppd, subsets=False)
        layers_all = [layer_image(fov, k) for k in range(max_layers)]
        assert np.array_equal(image_sub, image_all)
        regions = layer_regions(fov.last_layers, ppd, fov.config.blend_deg)
        for k, (a, b) in enumerate(zip(layers_sub, layers_all)):
            s = fov.last_layers[k].scale
            lh, lw = a.shape[:2]
            yy, xx = np.mgrid[0:lh, 0:lw]
            r = np.hypot((xx + 0.5) / s - poi[0], (yy + 0.5) / s - poi[1])
            used = (r >= regions[k, 0] - 1 / s) & (r <= regions[k, 1] + 1 / s)
            if k == 0:
                used &= r <= regions[0, 1]          # the fovea's framebuffer is only drawn in its square
            assert used.sum() > 100
            assert np.array_equal(a[used], b[used]), k
        # The levels view reads each triangle's level at gl_PrimitiveID, which restarts with every
        # draw call of a subset: its fovea is the plain levels frame's too.
        plain_levels = renderer.render(view, proj, model, view_mode="levels")
        fov_levels = fov.render(view, proj, model, poi, ppd, view_mode="levels")
        yy, xx = np.mgrid[0:size[1], 0:size[0]]
        inside = np.hypot(xx + 0.5 - poi[0], yy + 0.5 - poi[1]) < regions[1, 0] - 1
        assert inside.sum() > 1000 and np.array_equal(fov_levels[inside], plain_levels[inside])
    finally:
        fov.release()
        renderer.release()


@pytest.mark.slow
def test_a_still_head_gives_identical_frames_after_warm_up(gl_context, default_screen, terrain_scene):
    """The POI jitters by tracker-like noise (σ 4 screen px, ~0.1°; the covariance ±20 %): the layers sit on the filtered
    POI, held by the anchor, so the frames stop changing once the filters settle."""
    from headplod.demo import loop as lp
    from headplod.render import TerrainRenderer

    rng = np.random.default_rng(7)
    n = 30
    centre = np.array(default_screen.size_px, dtype=float) * np.array([0.5, 0.5])
    path = centre + rng.normal(0.0, 4.0, (n, 2))

    class Noisy(lp.MousePoses):
        def read(self):
            pose = super().read()
            if pose is not None:
                pose.cov_deg2 = np.diag([0.05 ** 2, 0.05 ** 2]) * rng.uniform(0.8, 1.2)
            return pose

    renderer = TerrainRenderer(gl_context, size=(640, 360))
    loop = lp.DemoLoop(terrain_scene, Noisy(default_screen, path=path), renderer, mode="csf",
                       uncertainty="adaptive", viewpoint="mountains", hud=False, foveate=True)
    try:
        frames, anchors = [], []
        while (r := loop.step()) is not None:
            frames.append(r.image.copy())
            anchors.append((tuple(loop.anchor.poi_px), tuple(l.outer_deg for l in loop.anchor.layers)))
        assert len(frames) == n
        warm = 10
        assert len(set(anchors[warm:])) == 1                           # the layers stay put ...
        assert all(np.array_equal(frames[warm], f) for f in frames[warm + 1:])   # ... and so does the frame
        assert np.ptp(path[warm:], axis=0).min() > 10                    # though the raw POI moved (screen px)
    finally:
        loop.foveated.release()
        renderer.release()


@pytest.mark.slow
def test_seams_step_no_more_than_full_does(gl_context, default_screen, terrain_scene):
    """Across the fovea's border the foveated frame's luminance steps as full's does (within 0.25 % of white)."""
    from headplod.bench.plod_foveate import seam_profiles, viewpoint_frames

    frames = viewpoint_frames(terrain_scene, ["mountains"], ctx=gl_context)
    borders = seam_profiles(frames)["mountains"]
    assert borders and borders[0]["coverage"] > 0.9
    for b in borders:
        assert abs(b["step_vs_full"]["foveate"]) <= 0.0025
        assert b["sector_step_vs_full_rms"]["foveate"] <= 0.005
        prof = np.asarray(b["profile"]["foveate"]) - np.asarray(b["profile"]["full"])
        assert np.nanmax(np.abs(prof)) < 0.01                          # no bump along the band either
    f = frames["mountains"]
    assert f["layers"][0].outer_deg > 5.0                            # the 5° disc is all fovea
    h, w = f["full"].shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    disc = np.hypot(xx + 0.5 - f["poi_px"][0], yy + 0.5 - f["poi_px"][1]) <= 5 * f["px_per_deg"]
    assert np.array_equal(f["foveate"][disc], f["plain"][disc])


def test_foveation_settings_are_checked(gl_context):
    from headplod.render import TerrainRenderer
    from headplod.render.foveate import FoveatedRenderer, LayerAnchor

    with pytest.raises(ValueError, match="hold_deg"):
        LayerAnchor(hold_deg=0.0)
    renderer = TerrainRenderer(gl_context, size=(64, 36))
    renderer.upload(np.zeros((3, 3), np.float32), np.tile([0, 0, 1], (3, 1)).astype(np.float32), None, [0, 1, 2])
    fov = FoveatedRenderer(renderer)
    try:
        with pytest.raises(ValueError, match="bounds"):
            fov.set_mesh([0, 1, 2], None, [0], (np.zeros((1, 3)), np.zeros((1, 2))))
        with pytest.raises(ValueError, match="layers"):
            fov.render(np.eye(4), np.eye(4), np.eye(4), (3, 3), 1.0, layers=layer_plan(1.0)[:1])
        with pytest.raises(ValueError, match="poi_px"):
            fov.render(np.eye(4), np.eye(4), np.eye(4), (np.nan, 3), 1.0)
    finally:
        fov.release()
        renderer.release()


@pytest.mark.slow
def test_headless_demo_runs_the_mode_again_foveated(tmp_path, gl_context, terrain_scene):
    import argparse
    import json

    import cv2

    from headplod.demo.cli import add_demo_arguments, run_headless
    from headplod.render import TerrainRenderer

    renderer = TerrainRenderer(gl_context, size=(320, 180))
    args = add_demo_arguments(argparse.ArgumentParser()).parse_args(
        ["--headless", "--mouse", "--frames", "3", "--out", str(tmp_path / "demo"), "--size", "320,180",
         "--viewpoints", "mountains", "--scenarios", "adaptive", "--foveate"])
    try:
        with open(tmp_path / "table.txt", "w") as stream:
            summary = run_headless(args, out=stream, err=stream, scene=terrain_scene, renderer=renderer)
    finally:
        renderer.release()
    runs = {(r["mode"], r["uncertainty"], r["foveate"]) for r in summary["runs"]}
    default = SelectorConfig().mode                          # the demo compares the default mode with full
    assert runs == {(default, "adaptive", False), (default, "adaptive", True), ("full", "none", False)}
    ratios = json.loads((tmp_path / "demo" / "summary.json").read_text())["fps_ratio_to_full"]
    assert ratios["mountains foveate"]["mode"] == f"{default} --foveate" and ratios["mountains foveate"]["ratio"] > 0
    picture = cv2.imread(summary["pictures"]["mountains foveate"])
    assert picture.shape == (180, 320, 3)
    assert f"{default}+fov" in (tmp_path / "table.txt").read_text()
