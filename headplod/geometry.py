"""Stereo geometry and head-pose estimators.

Frames (conventions.md): world = left camera frame, mm; the right camera sees
``R @ X + T``; the glasses frame G has P1 at its origin. A head pose is the
transform from G to world, ``R_world_G`` (3, 3) and ``p1_world_mm`` (3,), so a
marker at ``m_G`` sits at ``R_world_G @ m_G + p1_world_mm``.

Three estimators of the pose from identified marker centres, compared by
``headplod bench track``:

- ``paper``: triangulate the five centres; position = P1; V = mean of the
  oriented normals of triangles (P0,P1,P3), (P1,P2,P4), (P1,P3,P4)
  (Martinez et al. 2008, §4.2);
- ``rigid``: least-squares rigid fit of the marker model to the triangulated
  points (Kabsch), which uses all five markers and the model's known size;
- ``reproj``: the rigid fit refined by Gauss-Newton on the reprojection error
  of the centres in both images, through the full camera model (6 DOF).
"""
from __future__ import annotations

import cv2
import numpy as np

# Triangles whose normals define V (conventions.md), as marker indices.
VIEW_TRIANGLES = np.array([[0, 1, 3], [1, 2, 4], [1, 3, 4]])

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)


def undistort(points_px: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Pixel coordinates (n, 2) → normalized image coordinates (n, 2), z = 1.

    Iterates to 1e-12 so that wide-angle lenses with strong distortion are
    inverted exactly (OpenCV's default stops after 5 iterations).
    """
    pts = np.ascontiguousarray(points_px, dtype=np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    out = cv2.undistortPoints(pts, K, D, None, None, None, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def triangulate_midpoint(xn_left: np.ndarray, xn_right: np.ndarray,
                         R: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate normalized points by the midpoint of the closest approach.

    Parameters
    ----------
    xn_left, xn_right : (..., 2)
        Normalized coordinates in the left and right cameras.
    R, T : (3, 3), (3,)
        Rig extrinsics, ``X_right = R @ X_left + T`` (mm).

    Returns
    -------
    points_mm : (..., 3)
        World (left camera) frame.
    ray_gap_mm : (...)
        Distance between the two viewing rays: the reconstruction error of
        Martinez et al. (their Fig. 9), 0 for a perfect correspondence.
    """
    shape = np.shape(xn_left)[:-1]
    d1 = np.concatenate([np.reshape(xn_left, (-1, 2)), np.ones((int(np.prod(shape)), 1))], axis=1)
    d2 = np.concatenate([np.reshape(xn_right, (-1, 2)), np.ones((int(np.prod(shape)), 1))], axis=1) @ R
    origin2 = -R.T @ np.reshape(T, 3)
    # Closest points o1 + s d1 and o2 + u d2 (o1 = 0): solve the 2x2 normal equations.
    a = np.einsum("ij,ij->i", d1, d1)
    b = np.einsum("ij,ij->i", d1, d2)
    c = np.einsum("ij,ij->i", d2, d2)
    w = -origin2                      # o1 - o2, with o1 = 0
    d = d1 @ w
    e = d2 @ w
    denom = a * c - b * b
    denom = np.where(np.abs(denom) < 1e-15, 1e-15, denom)
    s = (b * e - c * d) / denom
    u = (a * e - b * d) / denom
    p1 = d1 * s[:, None]
    p2 = origin2 + d2 * u[:, None]
    points = 0.5 * (p1 + p2)
    gap = np.linalg.norm(p1 - p2, axis=1)
    return points.reshape(*shape, 3), gap.reshape(shape)


def essential_matrix(R: np.ndarray, T: np.ndarray) -> np.ndarray:
    """E = [T]x R, so that x_rightᵀ E x_left = 0 for normalized homogeneous points."""
    t = np.reshape(T, 3)
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ R


def epipolar_error_px(xn_left: np.ndarray, xn_right: np.ndarray, E: np.ndarray,
                      focal_left_px: float, focal_right_px: float) -> np.ndarray:
    """Symmetric distance of each point to the other's epipolar line, px.

    Distances are measured in normalized coordinates and scaled by each
    camera's focal length, so a tolerance in pixels means the same in both
    views. Shapes: (..., 2) each → (...).
    """
    h1 = np.concatenate([xn_left, np.ones(xn_left.shape[:-1] + (1,))], axis=-1)
    h2 = np.concatenate([xn_right, np.ones(xn_right.shape[:-1] + (1,))], axis=-1)
    line2 = h1 @ E.T            # epipolar lines in the right image
    line1 = h2 @ E              # and in the left image
    alg = np.einsum("...i,...i->...", h2, line2)
    d2 = np.abs(alg) / np.hypot(line2[..., 0], line2[..., 1]) * focal_right_px
    d1 = np.abs(alg) / np.hypot(line1[..., 0], line1[..., 1]) * focal_left_px
    return 0.5 * (d1 + d2)


def kabsch(model_mm: np.ndarray, points_mm: np.ndarray,
           weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares rigid transform from the model to measured points, batched.

    Parameters
    ----------
    model_mm : (n, 3)
        Marker model in G.
    points_mm : (..., n, 3)
        Measured points, world frame; NaN rows are ignored via ``weights``.
    weights : (..., n), optional
        Non-negative weights (0 drops a marker).

    Returns
    -------
    R_world_G : (..., 3, 3), p1_world_mm : (..., 3), rms_mm : (...)
        ``points ≈ R @ model + p1``; rms over the weighted markers.
    """
    pts = np.asarray(points_mm, dtype=np.float64)
    if weights is None and pts.ndim == 2:
        return _kabsch_single(model_mm, pts)
    if weights is None:
        weights = np.ones(pts.shape[:-1])
    w = np.asarray(weights, dtype=np.float64)
    pts = np.where(w[..., None] > 0, pts, 0.0)
    wsum = w.sum(axis=-1, keepdims=True)
    mc = (w[..., None] * model_mm).sum(axis=-2) / wsum
    pc = (w[..., None] * pts).sum(axis=-2) / wsum
    H = np.einsum("...n,...ni,...nj->...ij", w, model_mm - mc[..., None, :], pts - pc[..., None, :])
    U, _, Vt = np.linalg.svd(H)
    det = np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2))
    fix = np.ones(det.shape + (3,))
    fix[..., 2] = np.sign(det)
    R = np.swapaxes(Vt, -1, -2) @ (fix[..., :, None] * np.swapaxes(U, -1, -2))
    t = pc - np.einsum("...ij,...j->...i", R, mc)
    fitted = np.einsum("...ij,nj->...ni", R, model_mm) + t[..., None, :]
    sq = (np.square(fitted - pts).sum(axis=-1) * w).sum(axis=-1) / wsum[..., 0]
    return R, t, np.sqrt(sq)


def _kabsch_single(model_mm: np.ndarray, pts: np.ndarray):
    """:func:`kabsch` for one unweighted set (n, 3): the tracking hot path, a third of the calls."""
    mc = model_mm.mean(axis=0)
    pc = pts.mean(axis=0)
    H = (model_mm - mc).T @ (pts - pc)
    U, _, Vt = np.linalg.svd(H)
    R = Vt.T @ U.T
    if np.linalg.det(R) < 0:
        Vt[2] *= -1
        R = Vt.T @ U.T
    t = pc - R @ mc
    rms = np.sqrt(np.mean(np.square(model_mm @ R.T + t - pts).sum(axis=1)))
    return R, t, rms


def model_axes(model_mm: np.ndarray) -> np.ndarray:
    """Rows Ξ, Ψ, V of the head axes in G, computed per conventions.md.

    For the default model this is the identity; for a curved frame V tilts.
    """
    return axes_from_points(model_mm, normal_signs(model_mm))


def normal_signs(model_mm: np.ndarray) -> np.ndarray:
    """(3,) ±1 per view triangle so that its normal, taken in vertex order, faces G's +z."""
    tri = model_mm[VIEW_TRIANGLES]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    signs = np.sign(normals[:, 2])
    if np.any(signs == 0):
        raise ValueError("marker model: a view triangle is perpendicular to the glasses' plane")
    return signs


def axes_from_points(points_mm: np.ndarray, signs: np.ndarray) -> np.ndarray:
    """Head axes (rows Ξ, Ψ, V) from five marker positions (5, 3) in any frame.

    ``signs`` (3,) orients each triangle normal to the glasses' front (from
    :func:`normal_signs` of the model): Martinez et al.'s third triangle
    (P1, P3, P4) is wound opposite to the other two, so a plain mean of the
    raw normals would cancel instead of average.
    """
    tri = points_mm[VIEW_TRIANGLES]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) * signs[:, None]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    v = normals.mean(axis=0)
    v /= np.linalg.norm(v)
    xi = points_mm[0] - points_mm[1]
    xi -= v * (xi @ v)
    xi /= np.linalg.norm(xi)
    return np.stack([xi, np.cross(v, xi), v])


def project(points_mm: np.ndarray, R_cam_world: np.ndarray, t_cam_world: np.ndarray,
            K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Project world points (n, 3) into a camera with the full OpenCV model → (n, 2) px."""
    rvec, _ = cv2.Rodrigues(R_cam_world)
    img, _ = cv2.projectPoints(points_mm.reshape(-1, 1, 3), rvec, np.reshape(t_cam_world, (3, 1)), K, D)
    return img.reshape(-1, 2)


def refine_reprojection(R_world_G: np.ndarray, p1_world_mm: np.ndarray, model_mm: np.ndarray,
                        obs_left_px: np.ndarray, obs_right_px: np.ndarray,
                        visible_left: np.ndarray, visible_right: np.ndarray, rig,
                        iterations: int = 5, right_motion=None, sigma_px=None, rig_rt=None):
    """Refine a head pose by Gauss-Newton on the reprojection error in both images.

    Parameters
    ----------
    R_world_G, p1_world_mm : (3, 3), (3,)
        Starting pose (e.g. the rigid fit).
    model_mm : (5, 3)
        Marker model in G.
    obs_left_px, obs_right_px : (5, 2)
        Marker centres in each image (rows of hidden markers are ignored).
    visible_left, visible_right : (5,) bool
    rig : headplod.io.Rig
    iterations : int
        Most Gauss-Newton steps; from the rigid fit 2 or 3 reach a step below
        3e-3 rad and 2 mm, after which the loop stops.
    right_motion : (rvec (3,), tvec (3,)), optional
        The head's motion in the world frame between the left and right
        exposures (when the cameras are not synchronized), applied to the
        points before the right camera sees them.
    sigma_px : (2, 5), optional
        Expected noise of each centre, px: residuals are weighted by 1/σ
        (maximum likelihood for independent Gaussian centroid errors).
    rig_rt : (rvec (3, 1), tvec (3, 1)), optional
        The rig's R, T as OpenCV vectors (:func:`rig_rotation_vector`), to
        skip converting them on every call.

    Returns
    -------
    R_world_G (3, 3), p1_world_mm (3,), residuals_px (2, 5), JtJ (6, 6)
        Residual norms per image and marker after refinement (NaN if hidden);
        JᵀJ of the reprojection residuals w.r.t. (rvec, tvec) at the solution,
        px² per (rad, mm)², for first-order covariance propagation.
    """
    rvec = cv2.Rodrigues(R_world_G)[0].ravel()
    tvec = np.array(p1_world_mm, dtype=np.float64).ravel()
    rig_rvec, rig_tvec = rig_rt if rig_rt is not None else rig_rotation_vector(rig)
    if right_motion is not None:
        # world → world (motion) then world → right camera.
        rig_rvec, rig_tvec = cv2.composeRT(np.reshape(right_motion[0], (3, 1)), np.reshape(right_motion[1], (3, 1)),
                                           rig_rvec, rig_tvec)[:2]
    obj = np.ascontiguousarray(model_mm, dtype=np.float64).reshape(-1, 1, 3)
    vl = np.asarray(visible_left, bool)
    vr = np.asarray(visible_right, bool)
    obs_l = obs_left_px[vl]
    obs_r = obs_right_px[vr]
    obj_l = obj[vl]
    obj_r = obj[vr]
    nl = len(obj_l)
    if sigma_px is None:
        weight = np.ones(2 * (nl + len(obj_r)))
    else:
        # Relative weights 1/σ (a common scale changes nothing).
        sig = np.concatenate([sigma_px[0][vl], sigma_px[1][vr]])
        weight = np.repeat(1.0 / np.maximum(sig, 1e-4), 2)
        weight /= weight.max()
    for _ in range(iterations + 1):
        res, J = _residuals_and_jacobian(rvec, tvec, obj_l, obj_r, obs_l, obs_r, rig, rig_rvec, rig_tvec)
        res, J = res * weight, J * weight[:, None]
        JtJ = J.T @ J
        JtJ[_DIAG6] += 1e-9
        step = cv2.solve(JtJ, -(J.T @ res)[:, None], flags=cv2.DECOMP_CHOLESKY)[1].ravel()
        # Gauss-Newton converges quadratically here (small residuals): after
        # a step of 3e-3 rad and 2 mm the error left is ~1e-5 rad (0.0005°)
        # and ~(2/z)² z ≈ 0.006 mm, far below the noise, and the linear
        # prediction of the residuals is as good. From a tracked frame's
        # predicted pose one step usually suffices.
        small = np.abs(step[:3]).max() < 3e-3 and np.abs(step[3:]).max() < 2.0
        if small:
            # Gauss-Newton converges quadratically: the residual after this
            # step is the linear prediction to ~1e-10 px, no re-projection needed.
            res = res + J @ step
        rvec = rvec + step[:3]
        tvec = tvec + step[3:]
        if small:
            break
    else:
        res, _ = _residuals_and_jacobian(rvec, tvec, obj_l, obj_r, obs_l, obs_r, rig, rig_rvec, rig_tvec)
        res = res * weight
    res = res / weight              # back to pixels
    J = J / weight[:, None]
    R_out = cv2.Rodrigues(rvec)[0]
    residuals = np.full((2, len(model_mm)), np.nan)
    norms = np.hypot(res[0::2], res[1::2])
    residuals[0, vl] = norms[:nl]
    residuals[1, vr] = norms[nl:]
    return R_out, tvec, residuals, J.T @ J


_DIAG6 = np.diag_indices(6)


def rig_rotation_vector(rig) -> tuple[np.ndarray, np.ndarray]:
    """The rig's extrinsics as OpenCV's (rvec (3, 1), tvec (3, 1) mm)."""
    return cv2.Rodrigues(np.asarray(rig.R, dtype=np.float64))[0], np.reshape(rig.T, (3, 1)).astype(np.float64)


def _residuals_and_jacobian(rvec, tvec, obj_l, obj_r, obs_l, obs_r, rig, rig_rvec, rig_tvec):
    """Stacked residuals (2·n,) and their Jacobian (2·n, 6) w.r.t. (rvec, tvec)."""
    blocks_r, blocks_j = [], []
    if len(obj_l):
        pl, jl = cv2.projectPoints(obj_l, rvec, tvec, rig.K1, rig.D1)
        blocks_r.append((pl.reshape(-1, 2) - obs_l).ravel())
        blocks_j.append(jl[:, :6])
    if len(obj_r):
        comp = cv2.composeRT(rvec.reshape(3, 1), tvec.reshape(3, 1), rig_rvec, rig_tvec)
        r2, t2, dr3dr1, dr3dt1, _, _, dt3dr1, dt3dt1 = comp[:8]
        pr, jr = cv2.projectPoints(obj_r, r2, t2, rig.K2, rig.D2)
        chain = np.empty((6, 6))
        chain[:3, :3], chain[:3, 3:], chain[3:, :3], chain[3:, 3:] = dr3dr1, dr3dt1, dt3dr1, dt3dt1
        blocks_r.append((pr.reshape(-1, 2) - obs_r).ravel())
        blocks_j.append(jr[:, :6] @ chain)
    return np.concatenate(blocks_r), np.concatenate(blocks_j)


def reprojection_jacobian(R_world_G, p1_world_mm, model_mm, visible_left, visible_right, rig) -> np.ndarray:
    """JᵀJ (6, 6) of the reprojection residuals at a pose, w.r.t. (rvec, tvec)."""
    rvec = cv2.Rodrigues(R_world_G)[0].ravel()
    tvec = np.asarray(p1_world_mm, dtype=np.float64).ravel()
    obj = np.ascontiguousarray(model_mm, dtype=np.float64).reshape(-1, 1, 3)
    vl, vr = np.asarray(visible_left, bool), np.asarray(visible_right, bool)
    rig_rvec, rig_tvec = rig_rotation_vector(rig)
    _, J = _residuals_and_jacobian(rvec, tvec, obj[vl], obj[vr], np.zeros((vl.sum(), 2)),
                                   np.zeros((vr.sum(), 2)), rig, rig_rvec, rig_tvec)
    return J.T @ J


def view_angle_covariance(R_world_G: np.ndarray, JtJ: np.ndarray, sigma_px: float,
                          axes_G: np.ndarray) -> np.ndarray:
    """First-order covariance of (φ, θ), deg², from the pose fit's JᵀJ.

    The pose parameters (rvec, tvec) have covariance σ² (JᵀJ)⁻¹ for centroid
    noise σ (px) in every coordinate. A change of rvec rotates the head by
    δ = J_l(rvec) drvec (J_l the left Jacobian of SO(3)), which moves V by
    δ × V; in the reported head frame (conventions.md) that is
    dφ = Ψ·(δ × V) = −Ξ·δ and dθ = Ξ·(δ × V) = Ψ·δ (radians).
    """
    rvec = cv2.Rodrigues(R_world_G)[0].ravel()
    cov_r = sigma_px ** 2 * np.linalg.inv(JtJ)[:3, :3]
    axes = axes_G @ R_world_G.T
    A = np.stack([-axes[0], axes[1]]) @ _left_jacobian(rvec)
    cov = A @ cov_r @ A.T * np.degrees(1.0) ** 2
    return 0.5 * (cov + cov.T)


def _left_jacobian(rvec: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3) at rvec (3,): d(exp(rvec))·exp(rvec)⁻¹ per d rvec."""
    angle = float(np.linalg.norm(rvec))
    k = np.array([[0, -rvec[2], rvec[1]], [rvec[2], 0, -rvec[0]], [-rvec[1], rvec[0], 0]])
    if angle < 1e-8:
        return np.eye(3) + 0.5 * k
    return (np.eye(3) + (1 - np.cos(angle)) / angle ** 2 * k
            + (angle - np.sin(angle)) / angle ** 3 * (k @ k))
