"""The level rules (headplod.plod.criteria), the culling tests (headplod.plod.cull) and the shader's constants.

Against ground truth, each able to fail:

- the level is Martinez eq. 4 on hand-computed values, with its floors;
  the foveal shortcut of ``kelly_scaled`` is the full solve's number;
- a triangle's angular diameter is perception.triangle_frequency_cpd's
  (another formula of the same angle); a patch edge's numbers are the
  same from either patch sharing it;
- the bounds hold on random pieces: the shifted eccentricity of a point at
  angle A from V is at least A - shift_reach_deg (both shift forms, tilted
  covariances); level_bound is at least the level of any piece it covers;
  the sup of f_max bounds every speed;
- the screen pyramid's point test is the pixel test of
  contrast.project_to_screen_px (behind the eye included), and a box is
  outside only if every point in it is; a sphere outside a frustum plane
  means its box is outside the clip box;
- the GLSL's #define block carries csf.py's and criteria's values.
"""
import math

import numpy as np
import pytest

from headplod.plod import criteria, cull
from headplod.plod import perception as pc
from headplod.plod.csf import MIN_SPEED_DEG_S, max_visible_freq_cpd


def test_frequency_level_is_martinez_eq4_with_its_floors():
    # f_max 8 cpd, a piece of 0.5 deg (2 cpd): two doublings; bias added.
    assert criteria.frequency_level(8.0, 0.5) == pytest.approx(2.0, abs=1e-12)
    assert criteria.frequency_level(8.0, 0.5, level_bias=-0.75) == pytest.approx(1.25, abs=1e-12)
    # Nothing visible: the f_max floor, about 40 levels below any real one (finite, for the rounding).
    assert criteria.frequency_level(0.0, 1.0) == pytest.approx(math.log2(criteria.FMAX_FLOOR_CPD), abs=1e-9)
    # A piece of no size: the diameter floor.
    assert criteria.frequency_level(4.0, 0.0) == pytest.approx(math.log2(4.0 * criteria.DIAMETER_FLOOR_DEG))


def test_kelly_scaled_foveal_shortcut_is_the_full_solve():
    rng = np.random.default_rng(0)
    contrast, speed, ecc = rng.uniform(0.001, 1, 500), rng.uniform(0, 40, 500), rng.uniform(0, 60, 500)
    full = criteria.fmax_cpd(contrast, speed, ecc)
    short = criteria.fmax_cpd(contrast, speed, ecc, foveal_cpd=criteria.foveal_fmax_cpd(contrast, speed))
    np.testing.assert_array_equal(full, short)
    np.testing.assert_array_equal(full, max_visible_freq_cpd(contrast, speed, ecc, model="kelly_scaled"))
    # Other forms ignore the shortcut (it is kelly_scaled's), gp ignores the speed.
    np.testing.assert_array_equal(criteria.fmax_cpd(contrast, speed, ecc, csf_model="kelly", foveal_cpd=full * 0),
                                  max_visible_freq_cpd(contrast, speed, ecc, model="kelly"))
    np.testing.assert_array_equal(criteria.fmax_cpd(contrast, speed, ecc, mode="gp"), pc.gp_cutoff_cpd(contrast, ecc))


def test_triangle_diameter_is_the_projections_diameter():
    rng = np.random.default_rng(1)
    eye = np.array([10.0, -20.0, 600.0])
    corners = rng.uniform(-200, 200, (50, 3, 3)) + np.array([0, 0, -300.0])
    centroids = corners.mean(axis=1)
    directions = criteria.unit(centroids - eye)
    sizes, reach = criteria.triangle_sizes_deg(eye, directions, corners_mm=corners, level_scale=np.ones((50, 1)))
    np.testing.assert_allclose(sizes[:, 0], 1.0 / pc.triangle_frequency_cpd(corners, eye), rtol=1e-9)
    far = [max(math.degrees(math.acos(np.clip(d @ criteria.unit(c - eye), -1, 1))) for c in tri)
           for d, tri in zip(directions, corners)]
    np.testing.assert_allclose(reach, far, atol=1e-6)


def test_a_shared_edge_gets_the_same_numbers_from_both_patches():
    rng = np.random.default_rng(2)
    sw, se, ne, nw, ee, en = (rng.uniform(-100, 100, 3) for _ in range(6))
    west = np.array([sw, se, ne, nw])                  # its east edge is SE-NE
    east = np.array([se, ee, en, ne])                  # its west edge is NW-SW = NE-SE
    eye = np.array([0.0, 0.0, 500.0])
    pa, ra, da = criteria.patch_pieces(west, eye)
    pb, rb, db = criteria.patch_pieces(east, eye)
    # Piece 0 is the inside; then W, S, E, N: west's E (3) is east's W (1).
    np.testing.assert_array_equal(pa[3], pb[1])
    assert ra[3] == rb[1] and da[3] == db[1]
    c = criteria.patch_piece_contrast(np.array([0.2, 0.5]), np.array([[0.2, 0.1, 0.5, 0.3], [0.2, 0.4, 0.1, 0.9]]))
    np.testing.assert_array_equal(c, [[0.2, 0.2, 0.2, 0.5, 0.3], [0.5, 0.5, 0.5, 0.5, 0.9]])


@pytest.mark.parametrize("shift", ["ellipse", "eq1"])
def test_the_shift_moves_the_eccentricity_by_at_most_its_reach(shift):
    """The bounds' premise: a point at angle A from V has a shifted eccentricity of at least A - reach."""
    rng = np.random.default_rng(3)
    for _ in range(30):
        a = rng.normal(size=(2, 2))
        cov = a @ a.T * rng.uniform(0.01, 4.0) + np.diag(rng.uniform(0, 0.1, 2))
        offsets = rng.uniform(-60, 60, (2000, 2))
        angle = pc.eccentricity_deg(offsets)                         # the true angle from V
        shifted = pc.eccentricity_deg(pc.uncertainty_shift(offsets, cov, shift, 2.0))
        assert np.all(shifted >= angle - criteria.shift_reach_deg(cov, shift, 2.0) - 1e-9)
    assert criteria.shift_reach_deg(None) == 0.0 and criteria.shift_reach_deg(np.zeros((2, 2))) == 0.0


def test_level_bound_covers_every_piece_below_it():
    """A node's bound at its smallest eccentricity, largest diameter and contrast, over every speed, is at least
    each piece's level (csf kelly_scaled and kelly, gp)."""
    rng = np.random.default_rng(4)
    contrast, speed = rng.uniform(0.0, 1.0, (200, 8)), rng.uniform(0.0, 40.0, (200, 8))
    ecc, diameter = rng.uniform(0.0, 50.0, (200, 8)), rng.uniform(0.01, 5.0, (200, 8))
    for mode, model in (("csf", "kelly_scaled"), ("csf", "kelly"), ("gp", "kelly_scaled")):
        levels = criteria.csf_level(contrast, speed, ecc, diameter, mode=mode, csf_model=model, level_bias=0.4)
        bound = criteria.level_bound(contrast.max(1), ecc.min(1), diameter.max(1), mode=mode, csf_model=model,
                                     level_bias=0.4)
        assert np.all(bound >= levels.max(1)), mode
    # With a known speed: the bound at that speed.
    levels = criteria.csf_level(contrast, 2.0, ecc, diameter)
    assert np.all(criteria.level_bound(contrast.max(1), ecc.min(1), diameter.max(1), speed_deg_s=2.0) >= levels.max(1))


def test_sup_of_fmax_bounds_every_speed_and_rises_with_the_contrast():
    contrast = np.array([0.0, 0.003, 0.02, 0.1, 0.4, 1.0])
    speeds = np.concatenate([[0.1, 0.1001, 0.15, 0.2, 0.25], np.logspace(-1, 2.5, 500)])
    every = max_visible_freq_cpd(contrast[:, None], speeds[None, :], 0.0)
    assert np.all(criteria.sup_fmax_cpd(contrast) >= every.max(axis=1))
    assert np.all(np.diff(criteria.sup_fmax_cpd(np.linspace(0, 1, 200))) >= 0)


def test_angular_speed_is_the_angle_over_the_time():
    rng = np.random.default_rng(5)
    d0 = criteria.unit(rng.normal(size=(100, 3)))
    axis = criteria.unit(np.cross(d0, rng.normal(size=(100, 3))))
    angle = rng.uniform(0.0, 0.5, 100)                                # rad
    d1 = d0 * np.cos(angle)[:, None] + np.cross(axis, d0) * np.sin(angle)[:, None]
    speed = criteria.angular_speed_deg_s(d1, d0, 0.02)
    np.testing.assert_allclose(speed, np.maximum(np.degrees(angle) / 0.02, MIN_SPEED_DEG_S), rtol=1e-9)
    assert np.all(criteria.point_speed_deg_s(rng.normal(size=(5, 3)), np.zeros(3)) == MIN_SPEED_DEG_S)


def test_screen_pyramid_is_the_pixel_test(default_screen):
    """Points: outside iff their projection misses the widened screen (or they are behind the eye); boxes:
    outside only when every point in them is."""
    from headplod.plod.contrast import project_to_screen_px
    from headplod.render.still import default_head

    rng = np.random.default_rng(6)
    eye = default_head(default_screen)
    pyramid = cull.screen_pyramid(default_screen, eye)
    points = eye + rng.uniform([-900, -700, -2500], [900, 700, 300], (20000, 3))
    margin = rng.uniform(0, 60, len(points))                         # mm on the screen plane
    w, h = default_screen.size_px
    px_per_mm = w / np.linalg.norm(np.asarray(default_screen.top_right) - default_screen.top_left)
    xy = project_to_screen_px(points, eye, default_screen)
    m = margin * px_per_mm
    with np.errstate(invalid="ignore"):
        inside = (xy[:, 0] >= -m) & (xy[:, 0] <= w + m) & (xy[:, 1] >= -m) & (xy[:, 1] <= h + m)
    out = cull.outside_screen(points - eye, margin, pyramid)
    assert 0.2 < out.mean() < 0.8 and np.isnan(xy[:, 0]).any()
    np.testing.assert_array_equal(out, ~inside)
    # Boxes of 100 points: a box found outside holds only outside points.
    centres, half = points[:200], rng.uniform(0, 80, (200, 3))
    box_out = cull.outside_screen(centres - eye, margin[:200], pyramid, half)
    inner = centres[:, None] + half[:, None] * rng.uniform(-1, 1, (200, 100, 3))
    each = cull.outside_screen((inner - eye).reshape(-1, 3), np.repeat(margin[:200], 100), pyramid).reshape(200, 100)
    assert box_out.any() and np.all(each[box_out])


def test_a_sphere_outside_a_plane_culls_its_box():
    from calib import DEFAULT_SCREEN

    from headplod import io
    from headplod.render.projection import off_axis_projection
    from headplod.render.still import default_head

    screen = io.read_screen(DEFAULT_SCREEN)
    view, proj = off_axis_projection(default_head(screen), screen, near_mm=50.0, far_mm=5000.0)
    mvp = proj @ view
    rng = np.random.default_rng(7)
    lo = rng.uniform([-2000, -2000, -4000], [2000, 2000, 500], (3000, 3))
    hi = lo + rng.uniform(1, 300, (3000, 3))
    radius = 0.5 * np.linalg.norm(hi - lo, axis=1)
    sphere = cull.sphere_outside_planes(0.5 * (lo + hi), radius, cull.frustum_planes(mvp))
    box = cull.box_outside_clip(cull.box_corners(lo, hi), mvp)
    assert sphere.any() and (box & ~sphere).any()                     # the sphere is the more conservative
    assert np.all(box[sphere])
    region = cull.box_outside_clip(cull.box_corners(lo, hi), mvp, (-0.2, -0.2, 0.2, 0.2))
    assert np.all(region[box]) and (region & ~box).any()               # a region drops more


def test_the_shaders_constants_are_generated_from_python():
    from headplod.plod import csf
    from headplod.render import tess_shaders as ts

    defines = dict(line.split()[1:3] for line in ts.rule_defines().splitlines())
    for name, value in (("KELLY_K0", csf.KELLY_K0), ("KELLY_K1", csf.KELLY_K1), ("ECC_SLOPE", csf.ECC_SLOPE),
                        ("KELLY_SPEED_REF", csf.KELLY_SPEED_REF_DEG_S), ("KELLY_PEAK", csf.KELLY_PEAK_CONSTANT),
                        ("KELLY_SPEED_OFFSET", csf.KELLY_SPEED_OFFSET_DEG_S), ("MIN_SPEED", csf.MIN_SPEED_DEG_S),
                        ("FMAX_FLOOR", criteria.FMAX_FLOOR_CPD), ("DIAMETER_FLOOR", criteria.DIAMETER_FLOOR_DEG)):
        assert float(defines[name]) == value, name
    assert ts.rule_defines() in ts.RULE and ts.RULE in ts.LEVELS_VERTEX and ts.RULE in ts.CONTROL
    # The numbers written in the rule are csf's: the CSF's coefficients A, b at a speed from those constants.
    v = 1.7
    lg = abs(math.log10(v / float(defines["KELLY_SPEED_REF"])))
    k = float(defines["KELLY_K0"]) + float(defines["KELLY_K1"]) * lg ** 3
    A, b = csf.csf_coefficients(v, "kelly_scaled")
    assert A == pytest.approx(4 * math.pi ** 2 * k * v, rel=1e-15)
    assert b == pytest.approx(4 * math.pi * (v + float(defines["KELLY_SPEED_OFFSET"])) / float(defines["KELLY_PEAK"]),
                              rel=1e-15)
