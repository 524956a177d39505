"""The paper's read-back contrast (eq. 2) on images with known luminance."""
import numpy as np

from calib import DEFAULT_SCREEN
from headplod.io import read_screen
from headplod.plod.contrast import luminance, project_to_screen_px, readback_contrast


def _srgb(linear):
    linear = np.asarray(linear, dtype=np.float64)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def test_michelson_contrast_of_a_step_edge_and_of_a_flat_image():
    lo, hi = 0.1, 0.4                                      # linear luminances
    image = np.zeros((60, 80, 3), np.uint8)
    image[:, :40] = np.round(255 * _srgb(lo))
    image[:, 40:] = np.round(255 * _srgb(hi))
    lum = luminance(image)
    lo_q, hi_q = float(lum[0, 0]), float(lum[0, 79])       # after 8-bit quantization
    assert abs(lo_q - lo) < 0.003 and abs(hi_q - hi) < 0.003
    # Screen and image the same size: points in screen px are image px.
    points = np.array([[40.0, 30.0], [10.0, 30.0], [70.0, 30.0], [-5.0, 30.0], [np.nan, np.nan]])
    c = readback_contrast(image, points, (80, 60), window_px=10, fallback=np.full(5, 0.77))
    np.testing.assert_allclose(c[0], (hi_q - lo_q) / (hi_q + lo_q), rtol=1e-5)
    assert c[1] == 0 and c[2] == 0                         # flat windows
    assert c[3] == 0.77 and c[4] == 0.77                   # outside the image: the fallback


def test_projection_of_screen_points_is_identity():
    screen = read_screen(DEFAULT_SCREEN)
    px = np.array([[0.0, 0.0], [960.0, 540.0], [1919.0, 1079.0]])
    on_screen = screen.pixel_to_world(px)
    centre = screen.pixel_to_world(np.array([960.0, 540.0]))
    eye = centre + 600 * np.array([0.0, 0.0, -1.0])
    np.testing.assert_allclose(project_to_screen_px(on_screen, eye, screen), px, atol=1e-6)
    behind_eye = eye + (eye - centre)
    assert np.isnan(project_to_screen_px(behind_eye[None], eye, screen)).all()
