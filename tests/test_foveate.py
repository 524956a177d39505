"""Foveated resolution layers (issue 13, first part): the layers' densities follow the CSF, the uncertainty
widens them, and the composite is the plain frame inside the fovea."""
import math

import numpy as np
import pytest

from headplod.plod.csf import max_visible_freq_cpd
from headplod.render.foveate import FoveationConfig, layer_plan


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
        levels, _ = terrain_scene.selector("csf", "none", hysteresis=False).select(View(head, poi_screen))
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


def test_render_foveate_reports_its_layers(gl_context, tmp_path):
    import json

    from headplod.cli import main as cli_main

    out, stats = tmp_path / "fov.png", tmp_path / "fov.json"
    assert cli_main(["render", "--foveate", "--cov", "0.2,0,0.2", "--out", str(out), "--stats", str(stats)]) == 0
    layers = json.loads(stats.read_text())["foveate_layers"]
    assert [layer["scale"] for layer in layers] == [1.0, 0.5]
    assert layers[-1]["outer_deg"] is None and out.stat().st_size > 1000
