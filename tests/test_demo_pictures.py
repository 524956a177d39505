"""Demo pictures a newcomer understands (issue 36, item 5): every viewpoint's POI lies on the terrain it shows,
the uncertainty ellipse is drawn at a visible size with its true size in the label, the level legend is
legible, and one contact sheet labels every picture. Fast: geometry and OpenCV drawing, no OpenGL."""
import numpy as np
import pytest

from calib import DEFAULT_SCREEN
from headplod import io
from headplod.demo import hud
from headplod.demo.viewpoints import VIEWPOINTS, terrain_under
from headplod.plod.terrain import Terrain
from headplod.plod.view import default_head
from headplod.render import PALETTE


@pytest.fixture(scope="module")
def terrain():
    return Terrain.jacksboro()


@pytest.mark.parametrize("name", list(VIEWPOINTS))
def test_the_screens_middle_shows_terrain_in_every_viewpoint(terrain, name):
    # Where the demo's POIs go (the middle of the screen, 10-90 % across, 25-75 % down), the line of sight
    # meets the terrain, not the sky or the background beside it.
    screen = io.read_screen(DEFAULT_SCREEN)
    w, h = screen.size_px
    model = VIEWPOINTS[name].model(terrain, screen)
    eye = default_head(screen)
    missed = [(fx, fy) for fx in np.linspace(0.1, 0.9, 9) for fy in np.linspace(0.25, 0.75, 5)
              if terrain_under(model, terrain, screen, eye, (fx * w, fy * h)) is None]
    assert not missed, missed


def _info(cov_deg2, ppd=20.0, poi=(320.0, 180.0)):
    return hud.HudInfo(fps=30.0, stage_ms={}, frame_ms=1.0, triangles=1, mode="hybrid", uncertainty="adaptive",
                       viewpoint="overview", view_mode="levels", poi_image_px=np.array(poi), cov_deg2=cov_deg2,
                       px_per_deg=ppd)


def _red(image):
    return (image[..., 0] > 200) & (image[..., 1] < 120) & (image[..., 2] < 120)


def test_a_small_ellipse_is_drawn_visible_and_its_label_gives_its_true_size():
    image = np.zeros((360, 640, 3), np.uint8)
    sigma = 0.06                                       # 2-sigma 2.4 px at 20 px/deg: inside the crosshair
    hud.draw_poi(image, _info(np.diag([sigma ** 2, sigma ** 2])))
    least = hud.min_ellipse_px(360)
    ys, xs = np.nonzero(_red(image))
    r = np.hypot(xs - 320.0, ys - 180.0)
    diagonal = np.abs(np.abs(xs - 320.0) - np.abs(ys - 180.0)) < 2     # off the cross's arms
    assert least > 6 and np.any(diagonal & (np.abs(r - least) < 1.5)), (least, r[diagonal])
    words = hud.ellipse_words(np.diag([sigma ** 2, sigma ** 2]), 20.0, 360)
    assert "sigma 0.06 deg" in words and "2-sigma 2.4 px" in words and f"enlarged to {least} px" in words
    # A large one is drawn at its true size, and said to be.
    big = np.zeros((360, 640, 3), np.uint8)
    hud.draw_poi(big, _info(np.diag([1.0, 1.0])))
    ys, xs = np.nonzero(_red(big))
    assert np.hypot(xs - 320.0, ys - 180.0).max() == pytest.approx(40.0, abs=1.5)
    assert "enlarged" not in hud.ellipse_words(np.diag([1.0, 1.0]), 20.0, 360)


def test_the_level_legend_labels_sit_beside_their_swatches_on_a_dark_box():
    # A light terrain (the picture's sky-blue): before, white labels were drawn over it and over the swatches.
    image = np.full((720, 1280, 3), (170, 200, 225), np.uint8)
    plain = image.copy()
    hud.draw_legend(image, 5, present={0, 1, 2, 3})
    changed = np.any(image != plain, axis=2)
    ys, xs = np.nonzero(changed)
    box = image[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
    white = np.all(box > 230, axis=2)
    assert white.sum() > 50                                          # the labels are there
    luminance = box.astype(float).mean(axis=2)
    assert np.median(luminance[~white]) < 80                         # on a dark box, not the light terrain
    for level in range(4):                                           # every swatch whole, in its own colour
        colour = np.array(PALETTE[level], np.uint8)
        swatch = np.all(box == colour, axis=2)
        assert swatch.sum() >= (hud.min_ellipse_px(720) // 2) ** 2, level
    for level in (4, 5):                                             # absent levels: hollow
        assert np.all(box == np.array(PALETTE[level], np.uint8), axis=2).sum() < 4 * 24


def test_the_contact_sheet_labels_each_picture():
    from headplod.demo.sheet import SheetEntry, contact_sheet
    red, blue = np.zeros((90, 160, 3), np.uint8), np.zeros((90, 160, 3), np.uint8)
    red[..., 0], blue[..., 2] = 255, 255
    sheet = contact_sheet([SheetEntry("a.png", "the red one " * 12, red), SheetEntry("b.png", "the blue", blue)],
                          heading="demo", columns=2, cell_px=320)
    # Each picture appears scaled to its cell, below its label's lines; the labels are text (light pixels).
    is_red = np.all(sheet == (255, 0, 0), axis=2)
    is_blue = np.all(sheet == (0, 0, 255), axis=2)
    assert is_red.sum() == 320 * 180 and is_blue.sum() == 320 * 180
    top_red, top_blue = np.nonzero(is_red.any(axis=1))[0][0], np.nonzero(is_blue.any(axis=1))[0][0]
    assert top_red == top_blue                                     # side by side, one text band above both
    band = sheet[:top_red]
    assert (band.max(axis=2) > 150).sum() > 200                     # words were written above the pictures
    left_words = (sheet[60:top_red, :340].max(axis=2) > 150).sum()
    right_words = (sheet[60:top_red, 340:].max(axis=2) > 150).sum()
    assert left_words > 2 * right_words > 0                         # the long label wrapped to more lines
