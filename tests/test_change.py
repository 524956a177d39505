"""Mode ``change``: what each level removes (plod.change), its visibility (plod.criteria) and the selector's use."""
import dataclasses

import numpy as np
import pytest

from conftest import FlatTerrain
from headplod.plod import criteria
from headplod.plod.change import display_luminance, drawn_colour, level_change_contrast, normal_cone
from headplod.plod.csf import (CORTICAL_E2_DEG, csf_coefficients, display_nyquist_cpd, eccentricity_factor,
                               max_visible_freq_cpd, sensitivity)
from headplod.plod.mesh import AdaptiveMesh, BaseMesh
from headplod.plod.select import SelectorConfig
from raw_views import RawViews


class Ripples(FlatTerrain):
    """z = A sin(2π x / λ): shading that coarse levels cannot follow, and finer levels follow better."""

    amplitude, wavelength = 20.0, 400.0

    def heights(self, x, y):
        x, _ = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        return self.amplitude * np.sin(2 * np.pi * x / self.wavelength)

    def normals(self, x, y):
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        slope = self.amplitude * 2 * np.pi / self.wavelength * np.cos(2 * np.pi * x / self.wavelength)
        n = np.stack([-slope, np.zeros_like(x), np.ones_like(x)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)


@pytest.fixture(scope="module")
def ripples_mesh():
    t = Ripples()
    return AdaptiveMesh(BaseMesh.grid(t, 6, 4), t, max_level=4, normal_filter=0.0)


def test_flat_ground_loses_nothing_at_any_level():
    t = FlatTerrain()                                        # nothing any level removes
    mesh = AdaptiveMesh(BaseMesh.grid(t, 4, 3), t, max_level=3)
    assert mesh.change_contrast.shape == (mesh.n_faces, 4)
    np.testing.assert_allclose(mesh.change_contrast, 0.0, atol=1e-12)
    np.testing.assert_allclose(mesh.normal_cone_deg, 0.0, atol=1e-6)
    np.testing.assert_allclose(mesh.normal_axis, np.tile([0.0, 0.0, 1.0], (mesh.n_faces, 1)), atol=1e-9)


def test_coarser_levels_remove_more_and_the_finest_nothing(ripples_mesh):
    change = ripples_mesh.change_contrast
    assert np.all(change[:, -1] == 0.0)
    assert np.all(change[:, :-1] > 0.0)
    # Each level halves the spacing: the shading it misses shrinks level by level (on average: a coarse level
    # can happen to line up with a wave on one face), and the finest level but one misses less than level 0 on
    # every face.
    assert np.all(np.diff(change.mean(axis=0)) < 0)
    assert np.all(change[:, -2] < change[:, 0])
    # A ripple of 400 m over a face some 500 m wide: level 0 misses a whole wave, tens of percent of contrast.
    assert np.median(change[:, 0]) > 0.1


def test_change_contrast_is_the_drawn_difference(ripples_mesh):
    """One face by hand: interpolate level 0's corner colours over the face's lattice, against each point's."""
    mesh, t = ripples_mesh, Ripples()
    z_lo, z_hi = mesh.z_range[:, 0].min(), mesh.z_range[:, 1].max()
    corners = mesh.corners[0]
    rng = np.random.default_rng(1)
    bary = rng.dirichlet(np.ones(3), 400)                       # points over the face
    pts = bary @ corners
    fine = display_luminance(drawn_colour(t.heights(pts[:, 0], pts[:, 1]), t.normals(pts[:, 0], pts[:, 1]),
                                          (z_lo, z_hi)))
    corner_rgb = drawn_colour(corners[:, 2], t.normals(corners[:, 0], corners[:, 1]), (z_lo, z_hi))
    coarse = display_luminance(bary @ corner_rgb)
    by_hand = np.sqrt(2 * np.mean((coarse - fine) ** 2)) / fine.mean()
    # The lattice samples the face at 17 points per side, the hand at 400 random ones: the same within 15 %.
    assert mesh.change_contrast[0, 0] == pytest.approx(by_hand, rel=0.15)


def test_level_change_contrast_checks_nothing_but_computes_per_face():
    """Two identical faces give identical rows; a face whose drawn colours are the fine ones gives 0."""
    from scipy import sparse

    fine = np.zeros((2, 3, 3))
    fine[..., 0] = [0.0, 1.0, 0.0]
    fine[..., 1] = [0.0, 0.0, 1.0]
    normals = np.tile([0.0, 0.0, 1.0], (2, 3, 1))
    identity = sparse.identity(3, format="csr")
    out = level_change_contrast(fine, normals, [identity], [np.arange(3)], lambda L, x, y: np.tile([0, 0, 1.0],
                                                                                                   (len(x), 1)),
                                (0.0, 1.0))
    np.testing.assert_array_equal(out, np.zeros((2, 2)))


def test_normal_cone_holds_every_normal():
    rng = np.random.default_rng(2)
    n = rng.normal(size=(50, 30, 3)) * [0.3, 0.3, 1.0] + [0.0, 0.0, 2.0]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    axis, half = normal_cone(n)
    angles = np.degrees(np.arccos(np.clip(np.einsum("fpk,fk->fp", n, axis), -1, 1)))
    assert np.all(angles <= half[:, None] + 1e-9)
    assert np.all(np.isclose(angles.max(axis=1), half))


# --- the eye's fall-off and the display's cap -------------------------------------------------------------


def test_cortical_magnification_falls_slower_than_acuity():
    e = np.array([0.0, 5.0, 20.0])
    np.testing.assert_allclose(eccentricity_factor(e, "cortical", 0.6), (1 + e / CORTICAL_E2_DEG) ** 0.6)
    assert eccentricity_factor(20.0, "cortical", 0.6) == pytest.approx(3.06, abs=0.01)
    assert eccentricity_factor(20.0, "kelly_scaled") == pytest.approx(6.8)
    # Frequency scaling: f_max(e) = f_max(0) / m(e), and the sensitivity at f m(e) is the fovea's at f.
    f0 = max_visible_freq_cpd(0.3, 0.1, 0.0, model="cortical")
    np.testing.assert_allclose(max_visible_freq_cpd(0.3, 0.1, e, model="cortical", cortical_exponent=0.9),
                               f0 / eccentricity_factor(e, "cortical", 0.9), rtol=1e-9)
    assert sensitivity(2.0, 0.1, 20.0, "cortical") == pytest.approx(
        sensitivity(2.0 * eccentricity_factor(20.0, "cortical"), 0.1, 0.0, "cortical"))


def test_the_display_caps_cortical_fmax():
    nyquist = display_nyquist_cpd(3.6, 600.0)                     # 3.6 px/mm seen from 600 mm
    assert nyquist == pytest.approx(0.5 * 3.6 * 600 * np.pi / 180)
    capped = criteria.fmax_cpd(1.0, 0.1, 0.0, csf_model="cortical", nyquist_cpd=5.0)
    assert capped == pytest.approx(5.0)
    assert criteria.fmax_cpd(1.0, 0.1, 0.0, csf_model="cortical") > 5.0
    # The paper's form is left alone.
    assert criteria.fmax_cpd(1.0, 0.1, 0.0, csf_model="kelly_scaled", nyquist_cpd=5.0) > 5.0


# --- visibility and the continuous level -------------------------------------------------------------------


def test_crossing_level_interpolates_where_the_finest_visible_level_falls_below_zero():
    v = np.array([[5.0, 3.0, 1.0, -1.0, -3.0, -60.0],      # level 2 visible, level 3 not: 2 + 1 / 2
                  [-2.0, -3.0, -4.0, -5.0, -6.0, -60.0],   # nothing visible: v0
                  [-9.0, -9.0, -9.0, -9.0, -9.0, -60.0],   # far below: clipped at -(L + 1)
                  [9.0, 8.0, 7.0, 6.0, 5.0, -60.0]])       # all visible: past L, along the last fall
    out = criteria.crossing_level(v)
    assert out[0] == pytest.approx(2.5)
    assert out[1] == pytest.approx(-2.0)
    assert out[2] == pytest.approx(-6.0)
    assert out[3] == pytest.approx(5 + 4.0 / 1.0)            # v_L extrapolated as 5 - 1 = 4 (>= 0): L + 4 / 1
    assert np.ceil(out[0]) == 3


def test_a_lower_threshold_never_lowers_a_level():
    rng = np.random.default_rng(3)
    v = np.sort(rng.normal(0, 3, (200, 6)), axis=1)[:, ::-1]
    v[:, -1] = criteria.VISIBILITY_FLOOR
    levels = [criteria.crossing_level(v + b) for b in np.linspace(-6, 6, 49)]
    assert np.all(np.diff(np.stack(levels), axis=0) >= -1e-12)


def test_visibility_falls_with_eccentricity_and_takes_the_peak_below_it():
    change = np.tile([0.2, 0.1, 0.05, 0.0], (3, 1))
    small = np.tile([0.2, 0.1, 0.05, 0.025], (3, 1))             # deg: 2.5-20 cpd, above the CSF's peak
    v = criteria.change_visibility(change, small, np.full(3, 0.1), np.array([0.0, 10.0, 30.0]))
    assert np.all(np.diff(v[:, :3], axis=0) < 0)                 # farther out, less visible
    assert np.all(v[:, 3] == criteria.VISIBILITY_FLOOR)          # the finest level removes nothing
    # Below the peak the sensitivity is the peak's, wherever the piece is: its visibility is its contrast's.
    big = np.tile([4.0, 2.0, 1.0, 0.5], (3, 1))                  # 0.125-1 cpd: below the peak out to 20°
    v = criteria.change_visibility(change, big, np.full(3, 0.1), np.array([0.0, 10.0, 20.0]))
    _, b = csf_coefficients(0.1, "cortical")
    peak = sensitivity(2.0 / b, 0.1, 0.0, "cortical")
    np.testing.assert_allclose(v[:, :3], np.log2(change[:, :3] * peak))


def test_displacement_is_judged_against_half_a_period_of_fmax():
    error = np.array([[1.0, 0.25, 0.0]])                          # mm at 600 mm
    v = criteria.displacement_visibility(error, np.array([600.0]), np.array([1.0]), np.array([0.1]), np.array([0.0]),
                                         nyquist_cpd=20.0)
    fmax = min(max_visible_freq_cpd(1.0, 0.1, 0.0, model="cortical"), 20.0)
    np.testing.assert_allclose(v[0, :2], np.log2(np.degrees(error[0, :2] / 600.0) / (0.5 / fmax)))
    assert v[0, 2] == criteria.VISIBILITY_FLOOR


# --- the selector ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_change_needs_the_meshs_features(terrain_scene):
    from headplod.plod.select import LevelSelector

    m = terrain_scene.mesh
    with pytest.raises(ValueError, match="change"):
        LevelSelector(m.centroids, m.edge_length, m.geometric_error, m.contrast, terrain_scene.model,
                      terrain_scene.screen, SelectorConfig(mode="change"))


@pytest.mark.slow
def test_change_refines_near_the_poi_and_a_higher_threshold_draws_less(terrain_scene):
    from headplod.plod.view import View, default_head

    screen = terrain_scene.screen
    view = View(default_head(screen), np.array(screen.size_px, float) / 2, np.diag([0.01, 0.01]), 0.0)
    counts = []
    for threshold in (4.0, 8.0, 16.0):
        sel = RawViews(terrain_scene.selector("change", "adaptive", change_threshold=threshold, hysteresis=False))
        levels, info = sel.select(view)
        counts.append(terrain_scene.mesh.triangle_count(levels))
        ecc = info["eccentricity_deg"]
        near, far = levels[ecc < 5].mean(), levels[ecc > 15].mean()
        assert near > far, threshold
    assert counts[0] > counts[1] > counts[2]


@pytest.mark.slow
def test_a_silhouette_is_judged_against_the_silhouette_contrast(terrain_scene):
    sel = terrain_scene.selector("change", "adaptive", silhouette_contrast=0.9)
    seen = np.arange(4)
    axis = sel.normal_axis_world[seen]
    # Rays along each face's normal (face-on) and perpendicular to it (edge-on).
    side = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[0, 2]) < 0.9 else [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    face_on = sel._displacement_contrast(seen, -axis, np.zeros(4))
    edge_on = sel._displacement_contrast(seen, side, np.zeros(4))
    cone = sel.normal_cone_deg[seen]
    own = terrain_scene.mesh.contrast[seen]
    np.testing.assert_allclose(edge_on, np.maximum(own, 0.9))
    np.testing.assert_allclose(face_on[cone < 80], own[cone < 80])


def test_change_and_the_default_take_their_own_csf():
    cfg = SelectorConfig()
    assert cfg.mode == "hybrid" and cfg.csf == "cortical"             # issue 32: hybrid mixes change's
    assert dataclasses.replace(cfg, mode="change").csf == "cortical"
    assert dataclasses.replace(cfg, mode="csf").csf == "kelly_scaled"


def test_each_back_end_draws_a_mode_it_takes_when_none_is_given():
    from headplod.render.frame import BACKENDS, CAPABILITIES, default_mode, options_problem

    assert default_mode("mesh") == SelectorConfig().mode
    for backend in BACKENDS:
        assert default_mode(backend) in CAPABILITIES[backend].modes
        assert options_problem(backend, mode=default_mode(backend)) is None
    assert "does not take --mode change" in options_problem("tessellation", mode="change")
