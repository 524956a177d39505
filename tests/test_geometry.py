"""Geometry round trips with analytic truth: project, triangulate, fit, refine."""
import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from headplod.tracking import geometry as geo
from headplod.io import default_marker_model

MODEL = default_marker_model().points_mm


@pytest.fixture(scope="module")
def rig(sweep12_rig):
    """The sample dataset's rig (640x480, ≈350 mm baseline, real distortion)."""
    return sweep12_rig


def random_pose(rng, distance_mm=600.0):
    """A head facing the cameras with random yaw/pitch/roll within ±30°."""
    angles = np.radians(rng.uniform(-30, 30, 3))
    R_face = np.diag([1.0, -1.0, -1.0])          # G x = world x, G y up, G z toward the cameras
    R = cv2.Rodrigues(angles)[0] @ R_face
    p1 = np.array([rng.uniform(-80, 250), rng.uniform(-80, 80), distance_mm])
    return R, p1


def project_both(rig, R, p1):
    pts = (R @ MODEL.T).T + p1
    left = geo.project(pts, np.eye(3), np.zeros(3), rig.K1, rig.D1)
    right = geo.project(pts, rig.R, rig.T, rig.K2, rig.D2)
    return pts, left, right


def test_undistort_inverts_projection(rig):
    rng = np.random.default_rng(1)
    pts = rng.uniform([-200, -150, 400], [300, 150, 1500], (50, 3))
    px = geo.project(pts, np.eye(3), np.zeros(3), rig.K1, rig.D1)
    xn = geo.undistort(px, rig.K1, rig.D1)
    np.testing.assert_allclose(xn, pts[:, :2] / pts[:, 2:], atol=1e-9)


def test_triangulation_round_trip(rig):
    rng = np.random.default_rng(2)
    R, p1 = random_pose(rng)
    pts, left, right = project_both(rig, R, p1)
    xl = geo.undistort(left, rig.K1, rig.D1)
    xr = geo.undistort(right, rig.K2, rig.D2)
    tri, gap = geo.triangulate_midpoint(xl, xr, rig.R, rig.T)
    np.testing.assert_allclose(tri, pts, atol=1e-6)        # exact data: exact points
    assert gap.max() < 1e-6
    E = geo.essential_matrix(rig.R, rig.T)
    assert geo.epipolar_error_px(xl, xr, E, 640.0, 650.0).max() < 1e-6
    # A 2 px vertical shift in one view shows as ≈2 px of epipolar error (horizontal baseline).
    shifted = geo.undistort(right + [0, 2.0], rig.K2, rig.D2)
    err = geo.epipolar_error_px(xl, shifted, E, 640.0, 650.0)
    assert np.all((err > 1.5) & (err < 2.5))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_kabsch_recovers_pose(seed):
    rng = np.random.default_rng(seed)
    R, p1 = random_pose(rng)
    pts = (R @ MODEL.T).T + p1
    R_fit, t_fit, rms = geo.kabsch(MODEL, pts)
    np.testing.assert_allclose(R_fit, R, atol=1e-9)
    np.testing.assert_allclose(t_fit, p1, atol=1e-8)
    assert rms < 1e-8


def test_axes_follow_conventions():
    axes_G = geo.model_axes(MODEL)
    np.testing.assert_allclose(axes_G, np.eye(3), atol=1e-12)      # default model: axes = rotation world→G
    curved = MODEL.copy()
    curved[3:, 2] = -8.0
    axes = geo.model_axes(curved)
    # Recessed lower markers make the glasses face downward: V = (0, −8, 30)/|·| by hand.
    np.testing.assert_allclose(axes[2], np.array([0, -8, 30]) / np.hypot(8, 30), atol=1e-12)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)


def test_refinement_converges_and_reports_residuals(rig):
    rng = np.random.default_rng(3)
    R, p1 = random_pose(rng, 900.0)
    _, left, right = project_both(rig, R, p1)
    noise = rng.normal(0, 0.05, (2, 5, 2))
    R0 = cv2.Rodrigues(np.array([0.02, -0.01, 0.015]))[0] @ R     # about 1.5° off
    R_fit, t_fit, res, JtJ, _ = geo.refine_reprojection(R0, p1 + [3, -2, 5], MODEL, left + noise[0], right + noise[1],
                                                     np.ones(5, bool), np.ones(5, bool), rig)
    v_err = np.degrees(np.arccos(np.clip((R_fit @ [0, 0, 1]) @ (R @ [0, 0, 1]), -1, 1)))
    assert v_err < 0.2
    assert np.linalg.norm(t_fit - p1) < 0.5
    assert res.max() < 0.2
    # Hidden marker in one view: 9 observations still give the pose.
    vis = np.ones(5, bool)
    vis[3] = False
    R_h, t_h, res_h, _, _ = geo.refine_reprojection(R0, p1, MODEL, left, right, np.ones(5, bool), vis, rig)
    # Exact data: the fit stops once a step is below 3e-3 rad / 2 mm, which
    # leaves ~1e-5 rad of error: residuals of a few 1e-6 px, not zero.
    assert np.isnan(res_h[1, 3]) and np.nanmax(res_h) < 1e-4
    np.testing.assert_allclose(t_h, p1, atol=1e-3)


def test_covariance_is_spd_and_scales_with_noise(rig):
    rng = np.random.default_rng(4)
    R, p1 = random_pose(rng)
    JtJ = geo.reprojection_jacobian(R, p1, MODEL, np.ones(5, bool), np.ones(5, bool), rig)
    c1 = geo.view_angle_covariance(R, JtJ, 0.1, np.eye(3))
    c2 = geo.view_angle_covariance(R, JtJ, 0.2, np.eye(3))
    assert np.all(np.linalg.eigvalsh(c1) > 0)
    np.testing.assert_allclose(c2, 4 * c1, rtol=1e-9)
    far = p1 * [1, 1, 2]
    c_far = geo.view_angle_covariance(R, geo.reprojection_jacobian(R, far, MODEL, np.ones(5, bool),
                                                                   np.ones(5, bool), rig), 0.1, np.eye(3))
    assert np.trace(c_far) > 2 * np.trace(c1)        # farther head: fewer pixels per mm, larger spread


