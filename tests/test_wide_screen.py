"""The wide screen (calib/screen_wide.yaml): its geometry, the scene filling it, the judge's display following it."""
import numpy as np
import pytest

from calib import CALIB_DIR, DEFAULT_SCREEN
from headplod import io
from headplod.render.projection import screen_fit, screen_width_mm

WIDE = CALIB_DIR / "screen_wide.yaml"


@pytest.fixture(scope="module")
def wide_screen():
    return io.read_screen(WIDE)


def test_the_wide_screen_is_a_49_inch_32_to_9_monitor_centred_where_the_desk_one_is(wide_screen, default_screen):
    w = screen_width_mm(wide_screen)
    h = float(np.linalg.norm(wide_screen.bottom_left - wide_screen.top_left))
    assert w / h == pytest.approx(32 / 9, rel=1e-3)
    assert np.hypot(w, h) / 25.4 == pytest.approx(49.0, abs=0.05)
    assert wide_screen.size_px[0] / wide_screen.size_px[1] == pytest.approx(32 / 9)
    centre = [s.pixel_to_world(np.array(s.size_px, float) / 2) for s in (wide_screen, default_screen)]
    np.testing.assert_allclose(centre[0], centre[1], atol=1e-6)
    np.testing.assert_allclose(wide_screen.normal, default_screen.normal, atol=1e-9)


def test_the_scene_is_scaled_by_the_screens_width(wide_screen, default_screen):
    assert screen_fit(default_screen) == 1.0                      # the desk screen's framing is unchanged
    assert screen_fit(wide_screen) == pytest.approx(screen_width_mm(wide_screen) / screen_width_mm(default_screen))
    assert io.read_screen(DEFAULT_SCREEN) == default_screen


@pytest.mark.slow
@pytest.mark.usefixtures("gl_context")
def test_the_terrain_fills_the_wide_screen_not_its_middle_third(gl_context, wide_screen):
    """Left and right of the middle third, the middle row shows terrain, not the sky (the background)."""
    from headplod.plod.select import SelectorConfig
    from headplod.render.frame import FrameSettings, one_frame
    from headplod.render.gl import TerrainRenderer
    from headplod.render.still import TerrainScene

    scene = TerrainScene.build(wide_screen, max_level=2)
    renderer = TerrainRenderer(gl_context, size=(384, 108))
    try:
        out = one_frame(FrameSettings("mesh", SelectorConfig(mode="sse", uncertainty="none")), wide_screen,
                        scene.model, renderer=renderer, scene=scene)
    finally:
        renderer.release()
    sky = np.round(np.array(renderer.background) * 255)
    row = out.image[54].astype(float)
    for x in (int(0.12 * 384), int(0.88 * 384)):
        assert np.abs(row[x] - sky).max() > 10, f"sky at column {x} of the middle row"


def test_the_judges_display_follows_the_screen_file(wide_screen):
    from headplod.plod.view import default_head
    from headplod.render.vdp import display_geometry

    display = display_geometry(wide_screen, default_head(wide_screen), (2560, 720))
    assert display.width_m == pytest.approx(screen_width_mm(wide_screen) / 1000)
    assert display.distance_m == pytest.approx(0.6)
    assert display.horizontal_fov_deg == pytest.approx(2 * np.degrees(np.arctan(display.width_m / 2 / 0.6)))
    assert display.horizontal_fov_deg > 80                      # a wide field, unlike the desk's ~48°
