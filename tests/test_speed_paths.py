"""The tracking fast paths' shortcuts against the plain computations they replace.

``geometry``: the pose fit projects each camera's points already turned
into its axes and takes the rotation columns as lever × translation row in
one go (:func:`geometry._fill_rows`), and composes a late right image's
motion without composeRT; both must give the derivatives of the
projections and the cameras composeRT gives. ``detect``: a window's edge mean comes from one matrix product,
and the Gaussian-windowed centroid shares sums between both axes; both must
give the same numbers to the bit. (Speed itself is measured by ``headplod
bench track``, not asserted here.)
"""
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.tracking import detect
from headplod.tracking import geometry as geo

RIG = io.read_rig(Path(__file__).parent / "data" / "sweep12" / "rig.yaml")
MODEL = io.default_marker_model().points_mm
FACING = cv2.Rodrigues(np.array([np.pi, 0.0, 0.0]))[0]     # G's z towards the cameras


def _pose(rng):
    """A head 55-80 cm away, turned up to ±25° from facing the cameras."""
    R = cv2.Rodrigues(np.radians(rng.uniform(-25, 25, 3)))[0] @ FACING
    return R, np.array([rng.uniform(-250, 50), rng.uniform(-60, 60), rng.uniform(550, 800)])


def _projected(R, p1, cameras):
    """Both views' projected centres (2, 5, 2), px, by geometry.project through each camera's pose."""
    points = MODEL @ R.T + p1
    return np.stack([geo.project(points, cv2.Rodrigues(cameras.rvec[c])[0], cameras.tvec[c], cameras.K[c],
                                 cameras.D[c]) for c in (0, 1)])


def _numeric_rows(R, p1, cameras, h=1e-6):
    """Central differences (2, 5, 2, 6) of the projected centres w.r.t. (δ, ε): R ← exp([δ]×) R, p1 ← p1 + ε."""
    rows = np.empty((2, 5, 2, 6))
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        plus = _projected(cv2.Rodrigues(e[:3])[0] @ R, p1 + e[3:], cameras)
        minus = _projected(cv2.Rodrigues(-e[:3])[0] @ R, p1 - e[3:], cameras)
        rows[..., j] = (plus - minus) / (2 * h)
    return rows


@pytest.mark.parametrize("seed", range(4))
def test_jacobian_rows_are_the_projections_derivatives(seed):
    rng = np.random.default_rng(seed)
    R, p1 = _pose(rng)
    cameras = geo.StereoCameras(RIG)
    rows = geo.reprojection_rows(R, p1, MODEL, np.ones((2, 5), bool), cameras)
    np.testing.assert_allclose(rows, _numeric_rows(R, p1, cameras), rtol=1e-5, atol=1e-3)
    # A hidden centre: its rows are NaN, the others unchanged.
    visible = np.ones((2, 5), bool)
    visible[1, seed % 5] = False
    hidden = geo.reprojection_rows(R, p1, MODEL, visible, cameras)
    assert np.isnan(hidden[1, seed % 5]).all()
    np.testing.assert_allclose(hidden[visible], rows[visible], rtol=1e-12, atol=1e-12)


def test_jacobian_rows_keep_exact_zeros():
    """A turn about a marker's own lever moves it by exactly nothing: facing the cameras
    (a half turn about x), P0, P1 and P2 lie on G's x axis, and their rows' δ_x column is 0 to the
    bit in both views, as the chain rule gives it (rig_residual_rows relies on exact dependence)."""
    rows = geo.reprojection_rows(FACING, np.array([-170.0, 0.0, 150.0]), MODEL, np.ones((2, 5), bool),
                                 geo.StereoCameras(RIG))
    assert np.all(rows[:, :3, :, 0] == 0.0)
    assert np.all(rows[:, 1, :, :3] == 0.0)                     # P1: no lever at all
    assert np.all(np.abs(rows[:, 3:, :, 0]) > 1e-3)


@pytest.mark.parametrize("seed", range(4))
def test_right_motion_composes_as_compose_rt(seed):
    rng = np.random.default_rng(10 + seed)
    cameras = geo.StereoCameras(RIG)
    motion = (rng.normal(0, 0.02, 3), rng.normal(0, 3.0, 3))        # up to ~1°, a few mm
    moved = cameras.with_right_motion(motion)
    rvec, tvec = cv2.composeRT(motion[0].reshape(3, 1), motion[1].reshape(3, 1), cameras.rvec[1], cameras.tvec[1])[:2]
    np.testing.assert_allclose(moved.rvec[1], rvec, atol=1e-14)
    np.testing.assert_allclose(moved.tvec[1], tvec, atol=1e-12)
    np.testing.assert_allclose(moved.R_cam_world[1], cv2.Rodrigues(rvec)[0], atol=1e-14)
    np.testing.assert_array_equal(moved.R_cam_world[0], np.eye(3))
    assert cameras.with_right_motion(None) is cameras
    # The moved rig's Jacobian is the derivative of its projections too.
    R, p1 = _pose(rng)
    J = geo._jacobian_rows(R, p1, MODEL, np.ones((2, 5), bool), moved)[0].reshape(2, 5, 2, 6)
    np.testing.assert_allclose(J, _numeric_rows(R, p1, moved), rtol=1e-5, atol=1e-3)


def test_refinement_info_is_the_weighted_normal_matrix():
    rng = np.random.default_rng(20)
    R, p1 = _pose(rng)
    cameras = geo.StereoCameras(RIG)
    observed = _projected(R, p1, cameras) + rng.normal(0, 0.05, (2, 5, 2))
    sigma = rng.uniform(0.03, 0.1, (2, 5))
    both = (observed[0], observed[1], np.ones(5, bool), np.ones(5, bool), RIG)
    start = cv2.Rodrigues(np.array([0.01, -0.02, 0.01]))[0] @ R
    fit = geo.refine_reprojection(start, p1 + [2, -1, 4], MODEL, *both, sigma_px=sigma, cameras=cameras)
    fit = geo.refine_reprojection(fit.R_world_G, fit.p1_world_mm, MODEL, *both, sigma_px=sigma, cameras=cameras)
    # Converged: the residuals returned (predicted after the last, tiny step) are the pose's own.
    np.testing.assert_allclose(fit.residual_vectors_px, _projected(fit.R_world_G, fit.p1_world_mm, cameras)
                               - observed, atol=1e-6)
    np.testing.assert_allclose(fit.residuals_px, np.linalg.norm(fit.residual_vectors_px, axis=-1))
    rows = geo.reprojection_rows(fit.R_world_G, fit.p1_world_mm, MODEL, np.ones((2, 5), bool), cameras)
    for right_gain in (0.0, 0.3):
        # One small step from a pose: info is Jᵀ Σ⁻¹ J there, the right rows scaled by 1 + gain.
        step = geo.refine_reprojection(fit.R_world_G, fit.p1_world_mm, MODEL, *both, sigma_px=sigma,
                                       cameras=cameras, right_gain=right_gain, iterations=0)
        scaled = rows.copy()
        scaled[1] *= 1.0 + right_gain
        weighted = (scaled / sigma[..., None, None]).reshape(-1, 6)
        np.testing.assert_allclose(step.info, weighted.T @ weighted, rtol=1e-9)
        assert step.info.flags.c_contiguous


@pytest.mark.parametrize("side", [3, 9, 27, 41])
def test_border_levels_are_the_edge_means(side):
    rng = np.random.default_rng(side)
    windows = rng.integers(0, 256, (7, side, side)).astype(np.float32)
    levels = detect._border_levels(windows)
    # The plain sums, as the tracking path took them before (whole DN: exact either way).
    plain = (windows.sum(axis=(1, 2)) - windows[:, 1:-1, 1:-1].sum(axis=(1, 2))) * (1.0 / (4 * side - 4))
    np.testing.assert_array_equal(levels, plain)
    assert levels.dtype == np.float32


def _windowed_centroid_by_axis(signal, start, size, iterations, converged_px):
    """The Gaussian-windowed centroid with one sum per quantity and axis (the computation the fast path
    shares sums for), float32 as there."""
    n, side = signal.shape[:2]
    ramp = np.arange(side, dtype=np.float32)
    c = start.astype(np.float32)
    inv = (1.0 / size.astype(np.float32) ** 2)[:, None, None]
    proj = np.empty((n, 2, side), np.float32)
    for _ in range(max(iterations, 1)):
        d = ramp - c[:, :, None]
        d2 = d * d
        g = np.exp(-0.5 * d2 * inv)
        np.matmul(g[:, 1, None, :], signal, out=proj[:, 0:1, :])
        np.matmul(signal, g[:, 0, :, None], out=proj[:, 1, :, None])
        proj *= g
        total = proj[:, 0].sum(axis=1)
        slope = total[:, None] - (proj * d2).sum(axis=2) * inv[:, :, 0]
        slope = np.maximum(slope, 0.25 * total[:, None])
        step = np.clip((proj * d).sum(axis=2) / slope, -1.0, 1.0)
        if iterations:
            c = c + step
            if converged_px and float(np.abs(step).max()) <= converged_px:
                break
    g2 = g * g
    slope = slope.astype(np.float64)
    spread = ((g2 * d2).sum(axis=2)[:, 0] * g2.sum(axis=2)[:, 1] / slope[:, 0] ** 2
              + (g2 * d2).sum(axis=2)[:, 1] * g2.sum(axis=2)[:, 0] / slope[:, 1] ** 2)
    return c.astype(np.float64), spread, total.astype(np.float64)


@pytest.mark.parametrize("iterations, converged_px", [(0, 0.0), (1, 0.0), (2, 0.0), (2, 0.08), (3, 0.08)])
def test_windowed_centroid_equals_the_per_axis_sums(iterations, converged_px):
    rng = np.random.default_rng(iterations)
    n, side = 10, 25
    y, x = np.mgrid[:side, :side]
    centres = rng.uniform(9, 15, (n, 2))
    sizes = rng.uniform(1.0, 2.5, n)
    blobs = 120 * np.exp(-((x - centres[:, 0, None, None]) ** 2 + (y - centres[:, 1, None, None]) ** 2)
                         / (2 * sizes[:, None, None] ** 2))
    signal = (blobs + rng.normal(0, 2, blobs.shape)).astype(np.float32)
    start = (centres + rng.normal(0, 0.3, (n, 2))).astype(np.float32)
    c, spread, total, shot = detect._gaussian_windowed_centroid(signal, start, sizes, iterations, with_total=True,
                                                                converged_px=converged_px)
    c0, spread0, total0 = _windowed_centroid_by_axis(signal, start, sizes, iterations, converged_px)
    np.testing.assert_array_equal(c, c0)
    np.testing.assert_array_equal(spread, spread0)
    np.testing.assert_array_equal(total, total0)
    assert shot.shape == (n, 2) and np.all(shot > 0)
    # An empty window (NaN start) stays NaN and stops nothing early.
    start[3] = np.nan
    c, _ = detect._gaussian_windowed_centroid(signal, start, sizes, iterations, converged_px=converged_px)
    c0 = _windowed_centroid_by_axis(signal, start, sizes, iterations, converged_px)[0]
    assert np.isnan(c[3]).all()
    np.testing.assert_array_equal(c, c0)
