"""Stereo geometry and head-pose estimators.

Frames (docs/contract.md): world = left camera frame, mm; the right camera sees
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

from typing import NamedTuple

import cv2
import numpy as np

from .. import io

#: The pose estimators above, by name (``TrackerConfig.estimator``, ``headplod track --estimator``).
ESTIMATORS = ("paper", "rigid", "reproj")

# Triangles whose normals define V (docs/contract.md), as marker indices: the
# triples of headplod.io.VIEW_TRIANGLES as a (3, 3) int index array.
VIEW_TRIANGLES = np.array(io.VIEW_TRIANGLES)

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
    """Rows Ξ, Ψ, V of the head axes in G, computed per docs/contract.md.

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


def view_directions(points_mm: np.ndarray, signs: np.ndarray) -> np.ndarray:
    """V of marker sets (..., 5, 3) → (..., 3): the normalized mean of the oriented triangle normals.

    ``signs`` (3,) orients each triangle normal to the glasses' front (from
    :func:`normal_signs` of the model): Martinez et al.'s third triangle
    (P1, P3, P4) is wound opposite to the other two, so a plain mean of the
    raw normals would cancel instead of average.
    """
    tri = points_mm[..., VIEW_TRIANGLES, :]                                  # (..., 3, 3, 3)
    normals = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :]) * signs[:, None]
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    v = normals.mean(axis=-2)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def axes_from_points(points_mm: np.ndarray, signs: np.ndarray) -> np.ndarray:
    """Head axes (rows Ξ, Ψ, V) from five marker positions (5, 3) in any frame (V: :func:`view_directions`)."""
    v = view_directions(points_mm, signs)
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


class PoseFit(NamedTuple):
    """Result of :func:`refine_reprojection`.

    R_world_G (3, 3); p1_world_mm (3,); residuals_px (2, 5) norms (NaN if
    hidden); info (6, 6) Jᵀ Σ⁻¹ J w.r.t. (δ, ε); residual_vectors_px (2, 5, 2)
    projected minus observed centre.
    """

    R_world_G: np.ndarray
    p1_world_mm: np.ndarray
    residuals_px: np.ndarray
    info: np.ndarray
    residual_vectors_px: np.ndarray


class StereoCameras:
    """The two cameras of a rig as the pose fit needs them, computed once.

    Attributes
    ----------
    K, D : tuple of the intrinsics and distortion of camera 0 (left) and 1.
    R_cam_world : (2, 3, 3)
        World (left camera) frame to each camera frame.
    rvec, tvec : tuple of (3, 1)
        The same as OpenCV vectors.
    R_project : (2, 3, 3)
        The rotations OpenCV projects with (the Rodrigues of ``rvec``).
    t_project : (2, 3)
        ``tvec`` as rows, mm.
    """

    def __init__(self, rig):
        self.K = (np.asarray(rig.K1, np.float64), np.asarray(rig.K2, np.float64))
        self.D = (np.asarray(rig.D1, np.float64), np.asarray(rig.D2, np.float64))
        self.R_cam_world = np.stack([np.eye(3), np.asarray(rig.R, np.float64)])
        self.rvec = (np.zeros((3, 1)), cv2.Rodrigues(self.R_cam_world[1])[0])
        self.tvec = (np.zeros((3, 1)), np.reshape(rig.T, (3, 1)).astype(np.float64))
        # For _fill_rows: the projections rotate by the Rodrigues of rvec,
        # as OpenCV did when given rvec; the derivatives by R_cam_world
        # (rig.R as given), as before.
        self.R_project = np.stack([np.eye(3), cv2.Rodrigues(self.rvec[1])[0]])
        self.t_project = np.stack([np.zeros(3), self.tvec[1].ravel()])

    def project(self, points_mm: np.ndarray) -> np.ndarray:
        """World (left camera) points (n, 3) mm in both images, full camera model: (2, n, 2) px."""
        points = np.asarray(points_mm, np.float64).reshape(-1, 1, 3)
        return np.stack([cv2.projectPoints(points, self.rvec[i], self.tvec[i], self.K[i], self.D[i])[0].reshape(-1, 2)
                         for i in range(2)])

    def project_model(self, model_mm: np.ndarray, R_world_G: np.ndarray, p1_world_mm: np.ndarray) -> np.ndarray:
        """The model (n, 3) mm at a pose (R_world_G (3, 3), P1 (3,) mm) in both images: (2, n, 2) px."""
        return self.project(np.asarray(model_mm, np.float64) @ np.asarray(R_world_G).T + np.reshape(p1_world_mm, 3))

    def with_right_motion(self, right_motion):
        """The same rig with the right camera seeing the world moved by (rvec, tvec) first."""
        if right_motion is None:
            return self
        moved = object.__new__(StereoCameras)
        moved.K, moved.D = self.K, self.D
        # composeRT's composition (motion first, then the rig): R_1 M and
        # R_1 t_m + t_1, without the ten derivative matrices composeRT also
        # computes (most of its time). It runs per fit with a late right image.
        R_right = self.R_project[1] @ cv2.Rodrigues(np.asarray(right_motion[0], np.float64).reshape(3))[0]
        rotations = self.R_project.copy()
        rotations[1] = R_right
        shifts = self.t_project.copy()
        shifts[1] += self.R_project[1] @ np.reshape(right_motion[1], 3)
        moved.R_cam_world = moved.R_project = rotations
        moved.t_project = shifts
        moved.rvec = (self.rvec[0], cv2.Rodrigues(R_right)[0])
        moved.tvec = (self.tvec[0], shifts[1].reshape(3, 1))
        return moved


def refine_reprojection(R_world_G: np.ndarray, p1_world_mm: np.ndarray, model_mm: np.ndarray,
                        obs_left_px: np.ndarray, obs_right_px: np.ndarray,
                        visible_left: np.ndarray, visible_right: np.ndarray, rig,
                        iterations: int = 5, right_motion=None, sigma_px=None, cameras=None,
                        right_gain: float = 0.0):
    """Refine a head pose by Gauss-Newton on the reprojection error in both images.

    The pose is updated as R ← exp([δ]×) R, p1 ← p1 + ε (δ a rotation vector
    in the world frame, rad; ε in mm). The Jacobian of the projected points
    is read off OpenCV's projectPoints (see :func:`_fill_rows`): two
    projectPoints calls per step.

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
    cameras : StereoCameras, optional
        ``StereoCameras(rig)`` computed once by the caller.
    right_gain : float
        When ``right_motion`` is itself taken from this pose (a velocity
        from the last pose to this one, times the offset), a change of the
        pose moves the right view's model (1 + ``right_gain``) times as
        much: the right rows of the Jacobian are scaled by that, which makes
        the fit, at a fixed ``right_motion`` near its own, the maximum
        likelihood one and ``info`` its information.

    Returns
    -------
    PoseFit
        R_world_G (3, 3), p1_world_mm (3,), residuals_px (2, 5): residual
        norms per image and marker after refinement (NaN if hidden), info
        (6, 6): Jᵀ Σ⁻¹ J w.r.t. (δ, ε) at the solution (Σ from ``sigma_px``;
        plain JᵀJ in px² per (rad, mm)² without it), for first-order
        covariance propagation, and the residual vectors (2, 5, 2).
    """
    # Runs once or more per tracked frame on 10 centres: numpy's per-call
    # overhead, not the arithmetic, sets its time, so the Jacobian and the
    # residuals share one (2m, 7) array and one product gives JᵀJ and Jᵀr.
    cams = (cameras if cameras is not None else StereoCameras(rig)).with_right_motion(right_motion)
    visible = (np.asarray(visible_left, bool), np.asarray(visible_right, bool))
    model = np.asarray(model_mm, dtype=np.float64)
    n = len(model)
    counts = (int(np.count_nonzero(visible[0])), int(np.count_nonzero(visible[1])))
    m = counts[0] + counts[1]
    selection, obs, weight = _observations(obs_left_px, obs_right_px, visible, counts, n, sigma_px)
    chain = cams.R_cam_world
    if right_gain:
        chain = chain.copy()
        chain[1] *= 1.0 + right_gain
    R = np.asarray(R_world_G, dtype=np.float64)
    p1 = np.asarray(p1_world_mm, dtype=np.float64).ravel()
    rows = np.empty((2 * m, 7))          # [J | r]: Jacobian w.r.t. (δ, ε), residual, px
    res = None
    for _ in range(iterations + 1):
        _fill_rows(R, p1, model, selection, cams, chain, obs, rows)
        normal = _normal_matrix(rows, weight)
        ok, step = cv2.solve(normal[:6, :6], -normal[:6, 6:], flags=cv2.DECOMP_CHOLESKY)
        if not ok:
            break
        step = step.ravel()
        rot = step[:3].tolist()
        shift = step[3:].tolist()
        # Gauss-Newton converges quadratically here (small residuals): after
        # a step of 3e-3 rad and 2 mm the error left is ~1e-5 rad (0.0005°)
        # and ~(2/z)² z ≈ 0.006 mm, far below the noise, and the linear
        # prediction of the residuals is as good. From a tracked frame's
        # predicted pose one step usually suffices.
        small = max(map(abs, rot)) < 3e-3 and max(map(abs, shift)) < 2.0
        if small:
            res = rows[:, 6] + rows[:, :6] @ step
        R = cv2.Rodrigues(step[:3])[0] @ R
        p1 = p1 + step[3:]
        if small:
            break
    else:
        _fill_rows(R, p1, model, selection, cams, chain, obs, rows)
        normal = _normal_matrix(rows, weight)
    if res is None:
        res = rows[:, 6].copy()
    # Products of rotations drift off SO(3) by rounding; frames chain them.
    R = cv2.Rodrigues(cv2.Rodrigues(R)[0])[0]
    vectors = _residual_vectors(res, selection, visible, counts, n)
    return PoseFit(R, p1, np.hypot(vectors[..., 0], vectors[..., 1]), np.ascontiguousarray(normal[:6, :6]), vectors)


def _residual_vectors(res: np.ndarray, selection, visible, counts, n: int) -> np.ndarray:
    """The residuals (2m,) px of :func:`refine_reprojection`'s visible centres as vectors (2, n, 2), NaN
    where hidden."""
    if selection is None:
        return res.reshape(2, n, 2)
    vectors = np.full((2, n, 2), np.nan)
    vectors[0, visible[0]] = res[:2 * counts[0]].reshape(-1, 2)
    vectors[1, visible[1]] = res[2 * counts[0]:].reshape(-1, 2)
    return vectors


def _observations(obs_left_px, obs_right_px, visible, counts, n: int, sigma_px):
    """The visible centres of :func:`refine_reprojection` as one flat array (2m,) px, the selection of
    them (None when every marker is seen in both views), and each centre's weight 1/σ (m, 1, 1), or
    None without ``sigma_px``."""
    if counts == (n, n):             # the tracking case: no selection to make
        selection = None
        obs = np.concatenate([obs_left_px, obs_right_px], axis=None)
        sig = None if sigma_px is None else np.ravel(sigma_px)
    else:
        selection = visible
        obs = np.concatenate([obs_left_px[visible[0]], obs_right_px[visible[1]]]).ravel()
        sig = None if sigma_px is None else np.concatenate([sigma_px[0][visible[0]], sigma_px[1][visible[1]]])
    # Per centre (m, 1, 1): 1/σ on both of its rows.
    weight = None if sig is None else (1.0 / np.maximum(sig, 1e-4))[:, None, None]
    return selection, obs, weight


def _normal_matrix(rows: np.ndarray, weight) -> np.ndarray:
    """[[JᵀWJ, JᵀWr], [rᵀWJ, rᵀWr]] (7, 7) of rows [J | r] (2m, 7): J (2m, 6), r (2m,) px.

    ``weight`` (m, 1, 1) is 1/σ of each centre (px⁻¹), on both of its rows
    (W = weight²); None: W = I.
    """
    if weight is not None:
        rows = (rows.reshape(-1, 2, 7) * weight).reshape(-1, 7)
    return rows.T @ rows


_ZERO_RVEC = np.zeros(3)
# r × a = r_yzx a_zxy − r_zxy a_yzx: the levers' coordinates (y, z, x, z, x, y) and the columns of
# a row's a (its ε part, columns 3-5) in the order (z, x, y, y, z, x).
_YZX_ZXY = np.array([1, 2, 0, 2, 0, 1])
_A_ZXY_YZX = 3 + np.array([2, 0, 1, 1, 2, 0])


def _fill_rows(R, p1, model, visible, cams, chain, obs, out) -> None:
    """Fill ``out`` (2m, 7): the Jacobian rows (2m, 6) of the projected centres w.r.t. (δ, ε)
    (px per rad, px per mm), then the residuals (2m,), projected minus ``obs`` (2m,), px.

    ``R`` (3, 3), ``p1`` (3,) mm: the pose; ``model`` (n, 3) mm; ``visible``
    a pair of (n,) bool masks, or None when every centre of both images is
    seen (the tracking case: no selection to make); ``cams`` a
    :class:`StereoCameras`; ``chain`` its ``R_cam_world`` (2, 3, 3), the
    right camera's possibly scaled (by 1 + ``right_gain``: its rows follow).
    Rows: the left camera's visible centres, then the right's, x and y of
    each.

    A marker at lever r = R m from P1 moves by δ × r + ε, so a row's
    derivative w.r.t. ε is a = ∂x/∂X_cam · R_c (projectPoints' derivative
    w.r.t. its translation, times ``chain``) and w.r.t. δ is r × a
    (a · (δ × r) = δ · (r × a)). Each camera projects the levers turned into
    its axes, with rotation vector 0 and translation R_c p1 + t_c: the same
    points in the camera as R_c (R m + p1) + t_c.
    """
    levers = model @ R.T                                           # (n, 3) r = R m, mm
    shifts = cams.R_project @ p1 + cams.t_project                  # (2, 3) R_c p1 + t_c
    turned = levers @ cams.R_project.transpose(0, 2, 1)            # (2, n, 3) R_c r
    row = 0
    for cam in (0, 1):
        seen = turned[cam] if visible is None else turned[cam][visible[cam]]
        if not len(seen):
            continue
        end = row + 2 * len(seen)
        pts, dpts = cv2.projectPoints(seen, _ZERO_RVEC, shifts[cam], cams.K[cam], cams.D[cam])
        np.matmul(dpts[:, 3:6], chain[cam], out=out[row:end, 3:6])
        np.subtract(pts.reshape(-1), obs[row:end], out=out[row:end, 6])
        row = end
    # The rotation columns r × a in one go: each row's lever's cycled
    # coordinates (one gather from the levers, cached per visibility) against
    # the row's. (Computed from a as the chain rule did, they keep its exact
    # zeros, e.g. a lever along the axis of δ.)
    cycled = levers.take(_lever_index(visible, len(model)))        # (2m, 6) r_yzx | r_zxy
    products = cycled * out[:, _A_ZXY_YZX]                         # × a_zxy | a_yzx
    np.subtract(products[:, :3], products[:, 3:], out=out[:, :3])


_LEVER_INDEX: dict = {}


def _lever_index(visible, n: int) -> np.ndarray:
    """Flat indices (2m, 6) into the levers (n, 3) giving each row's lever's coordinates (y, z, x, z, x, y);
    rows as in :func:`_fill_rows`. Cached for all visible (``visible`` None)."""
    if visible is None and n in _LEVER_INDEX:
        return _LEVER_INDEX[n]
    seen = [np.arange(n)] * 2 if visible is None else [np.flatnonzero(v) for v in visible]
    markers = np.repeat(np.concatenate(seen), 2)                   # one per row
    index = markers[:, None] * 3 + _YZX_ZXY
    if visible is None:
        _LEVER_INDEX[n] = index
    return index


def _jacobian_rows(R_world_G, p1_world_mm, model_mm, visible, cameras):
    """Jacobian rows (2m, 6) w.r.t. (δ, ε) of the visible centres at a pose (:func:`_fill_rows`),
    and the visibility as a pair of (n,) bool arrays."""
    vis = (np.asarray(visible[0], bool), np.asarray(visible[1], bool))
    m = int(vis[0].sum() + vis[1].sum())
    out = np.empty((2 * m, 7))
    _fill_rows(np.asarray(R_world_G, np.float64), np.asarray(p1_world_mm, np.float64).ravel(),
               np.asarray(model_mm, np.float64), vis, cameras, cameras.R_cam_world, np.zeros(2 * m), out)
    return out[:, :6], vis


def reprojection_rows(R_world_G, p1_world_mm, model_mm, visible, cameras) -> np.ndarray:
    """Jacobian rows (2, 5, 2, 6) of each projected centre w.r.t. (δ, ε) at a pose (NaN if hidden)."""
    J, vis = _jacobian_rows(R_world_G, p1_world_mm, model_mm, visible, cameras)
    n0 = 2 * int(vis[0].sum())
    rows = np.full((2, len(model_mm), 2, 6), np.nan)
    rows[0, vis[0]] = J[:n0].reshape(-1, 2, 6)
    rows[1, vis[1]] = J[n0:].reshape(-1, 2, 6)
    return rows


def reprojection_jacobian(R_world_G, p1_world_mm, model_mm, visible_left, visible_right, rig,
                          cameras=None, sigma_px=None) -> np.ndarray:
    """Jᵀ Σ⁻¹ J (6, 6) of the reprojection residuals at a pose, w.r.t. (δ, ε) as in
    :func:`refine_reprojection` (plain JᵀJ without ``sigma_px`` (2, 5))."""
    cams = cameras if cameras is not None else StereoCameras(rig)
    J, visible = _jacobian_rows(R_world_G, p1_world_mm, model_mm, (visible_left, visible_right), cams)
    if sigma_px is not None:
        sig = np.concatenate([sigma_px[0][visible[0]], sigma_px[1][visible[1]]])
        J = J * np.repeat(1.0 / np.maximum(sig, 1e-4), 2)[:, None]
    return J.T @ J


def view_angle_covariance(R_world_G: np.ndarray, JtJ: np.ndarray, sigma_px: float,
                          axes_G: np.ndarray) -> np.ndarray:
    """First-order covariance of (φ, θ), deg², from the pose fit's information matrix.

    The pose parameters (δ, ε) have covariance σ² (JᵀJ)⁻¹ for centroid noise
    σ (px) in every coordinate (or s² (Jᵀ Σ⁻¹ J)⁻¹ with a scale s on a
    per-centre noise Σ). A rotation δ moves V by δ × V; in the
    reported head frame (docs/contract.md) that is dφ = Ψ·(δ × V) = −Ξ·δ and
    dθ = Ξ·(δ × V) = Ψ·δ (radians).
    """
    cov_rot = sigma_px ** 2 * np.linalg.inv(JtJ)[:3, :3]
    axes = axes_G @ R_world_G.T
    A = np.stack([-axes[0], axes[1]])
    cov = A @ cov_rot @ A.T * np.degrees(1.0) ** 2
    return 0.5 * (cov + cov.T)
