"""Tests of the synthetic IR stereo renderer (package ``synthetic``).

The expected values are computed here with OpenCV / numpy directly
(cv2.projectPoints, cv2.moments, cv2.FileStorage), not with the code under
test.  ``synthetic`` never imports ``headplod``.
"""
from __future__ import annotations

import ast
import csv
from pathlib import Path

import cv2
import numpy as np
import pytest

from synthetic.conventions import (
    DEFAULT_DIAMETER_MM,
    DEFAULT_MARKERS_MM,
    head_rotation,
    model_view_direction,
    viewing_axes,
)
from synthetic.dataset import GAZE_TRUTH_HEADER, gaze_seed, true_gaze, write_dataset
from synthetic.render import Lamp, RenderOptions, marker_radiance, render_pair, render_pair_float
from synthetic.scenes import CURVED_MARKERS_MM, PRESETS, make_pose_fn, make_scene
from synthetic.setups import (
    NOMINAL_HEAD_M,
    default_setup,
    distortion_is_monotonic,
    wide_hd_setup,
)

ROOT = Path(__file__).resolve().parents[1]

#: noise-free, blur-free, no background
CLEAN = RenderOptions(noise=False, blur_sigma_px=0.0, ambient_dn=0.0, ambient_variation_dn=0.0)


def _const(v):
    v = np.asarray(v, float)
    return lambda t: v


def _pose(setup, pos_m, ypr=(0.0, 0.0, 0.0), target_m=(0.0, 0.0, 0.0), model=DEFAULT_MARKERS_MM):
    return make_pose_fn(setup, _const(pos_m), _const(target_m), _const(ypr), model)


def _cams(setup):
    """(K, D, rvec, tvec) of the left and right cameras, straight from the setup."""
    return [
        (setup.K1, setup.D1, np.zeros(3), np.zeros(3)),
        (setup.K2, setup.D2, cv2.Rodrigues(np.asarray(setup.R))[0].ravel(), np.asarray(setup.T, float).ravel()),
    ]


def _project(cam, pts):
    K, D, rvec, tvec = cam
    uv, _ = cv2.projectPoints(np.asarray(pts, float).reshape(-1, 3), rvec, tvec, K, D)
    return uv.reshape(-1, 2)


def _centroid(img, u, v, half):
    x0, y0 = int(round(u)) - half, int(round(v)) - half
    roi = img[y0:y0 + 2 * half + 1, x0:x0 + 2 * half + 1].astype(np.float64)
    m = cv2.moments(roi)
    return m["m10"] / m["m00"] + x0, m["m01"] / m["m00"] + y0, roi


def _random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


# ----------------------------------------------------------------------------
# conventions
# ----------------------------------------------------------------------------

@pytest.mark.slow
def test_synthetic_never_imports_headplod():
    for f in (ROOT / "synthetic").glob("*.py"):
        tree = ast.parse(f.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not any(n == "headplod" or n.startswith("headplod.") for n in names), f.name


def test_default_axes_equal_world_to_G_rotation():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R = _random_rotation(rng)
        p = rng.uniform(-500, 500, 3)
        pts = DEFAULT_MARKERS_MM @ R.T + p
        axes = viewing_axes(pts)
        np.testing.assert_allclose(axes, R.T, atol=1e-9)
        np.testing.assert_allclose(viewing_axes(pts, R_world_from_G=R), R.T, atol=1e-9)


@pytest.mark.parametrize("model", [DEFAULT_MARKERS_MM, CURVED_MARKERS_MM], ids=["default", "curved"])
def test_axes_orthonormal_right_handed_and_V_is_mean_normal(model):
    rng = np.random.default_rng(2)
    for _ in range(20):
        R = _random_rotation(rng)
        pts = model @ R.T + rng.uniform(-300, 300, 3)
        axes = viewing_axes(pts, model)
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(axes) == pytest.approx(1.0, abs=1e-12)
        # V per conventions.md, computed here independently
        zG = R[:, 2]  # G's +z in world
        normals = []
        for a, b, c in ((0, 1, 3), (1, 2, 4), (1, 3, 4)):
            n = np.cross(pts[b] - pts[a], pts[c] - pts[a])
            n /= np.linalg.norm(n)
            normals.append(n if n @ zG > 0 else -n)
        v = np.mean(normals, axis=0)
        v /= np.linalg.norm(v)
        np.testing.assert_allclose(axes[2], v, atol=1e-12)
        xi = (pts[0] - pts[1]) - ((pts[0] - pts[1]) @ v) * v
        np.testing.assert_allclose(axes[0], xi / np.linalg.norm(xi), atol=1e-12)
        np.testing.assert_allclose(axes[1], np.cross(v, axes[0]), atol=1e-12)


def test_curved_model_view_direction_tilts():
    v = model_view_direction(CURVED_MARKERS_MM)
    assert v[2] > 0.9 and abs(v[1]) > 0.05  # P3, P4 behind the line: V tilts
    np.testing.assert_allclose(model_view_direction(DEFAULT_MARKERS_MM), [0, 0, 1], atol=1e-15)


def test_head_rotation_convention():
    np.testing.assert_allclose(head_rotation(0, 0, 0), np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    R = head_rotation(30, 0, 0)  # yaw toward the wearer's left (toward P0, head +x)
    R0 = head_rotation(0, 0, 0)
    v = R[:, 2]
    assert v @ R0[:, 0] == pytest.approx(np.sin(np.radians(30)))
    R = head_rotation(0, 20, 0)  # chin down
    assert R[:, 2] @ R0[:, 1] == pytest.approx(-np.sin(np.radians(20)))
    R = head_rotation(0, 0, 25)  # P0 side up
    assert R[:, 0] @ R0[:, 1] == pytest.approx(np.sin(np.radians(25)))
    for ypr in [(10, -20, 30), (-45, 30, -30)]:
        R = head_rotation(*ypr, facing=[0.3, -0.1, -1.0])
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


# ----------------------------------------------------------------------------
# setups and calib files
# ----------------------------------------------------------------------------

def test_default_setup_geometry():
    s = default_setup()
    assert s.image_size == (640, 480)
    c_r = -s.R.T @ s.T
    assert np.linalg.norm(c_r) == pytest.approx(600.0, abs=1e-9)
    assert c_r[0] > 500  # right camera at +x of the left one
    # the left camera is at x_M = -300 (user's right), the right one at +300
    M_from_world = lambda x: s.R_world_from_M.T @ (x - s.t_world_from_M)  # noqa: E731
    np.testing.assert_allclose(M_from_world(np.zeros(3)), [-300, 0, 20], atol=1e-9)
    np.testing.assert_allclose(M_from_world(c_r), [300, 0, 20], atol=1e-9)
    # both optical axes pass through H0; camera x axes are horizontal
    H0 = s.nominal_head_mm
    np.testing.assert_allclose(s.m_to_world(NOMINAL_HEAD_M), H0)
    assert np.hypot(*H0[:2]) < 1e-9 and H0[2] > 0
    Hr = s.R @ H0 + s.T
    assert np.hypot(*Hr[:2]) < 1e-9 and Hr[2] > 0
    yM = s.dir_m_to_world([0, 1, 0])
    assert abs(yM[0]) < 1e-12 and abs((s.R.T[:, 0]) @ yM) < 1e-12
    assert yM[1] > 0.9  # image y is down
    # screen: pixel (0, 0) is the user's top-left = +x_M, -y_M
    tl = M_from_world(s.top_left)
    np.testing.assert_allclose(tl, [265.7, -149.45, 0], atol=1e-9)
    np.testing.assert_allclose(M_from_world(s.top_right), [-265.7, -149.45, 0], atol=1e-9)
    np.testing.assert_allclose(M_from_world(s.bottom_left), [265.7, 149.45, 0], atol=1e-9)
    for K in (s.K1, s.K2):
        assert 690 < K[0, 0] < 710 and abs(K[0, 2] - 319.5) < 8 and abs(K[1, 2] - 239.5) < 8


def test_wide_hd_distortion_monotonic_and_wide():
    s = wide_hd_setup()
    assert s.image_size == (1280, 720)
    for K, D in ((s.K1, s.D1), (s.K2, s.D2)):
        assert distortion_is_monotonic(K, D, s.image_size)
        edge = cv2.undistortPoints(np.array([[[-0.5, K[1, 2]]], [[1279.5, K[1, 2]]]]), K, D,
                                   R=np.eye(3), P=np.eye(3),
                                   criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))
        hfov = np.degrees(np.arctan(-edge[0, 0, 0]) + np.arctan(edge[1, 0, 0]))
        assert 95 < hfov < 105
        assert D[0] < -0.25


def test_calib_files_match_default_setup():
    from calib import DEFAULT_MARKERS, DEFAULT_RIG, DEFAULT_SCREEN

    s = default_setup()
    fs = cv2.FileStorage(str(DEFAULT_RIG), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("image_width").real()) == 640
    assert int(fs.getNode("image_height").real()) == 480
    for key, val in (("K1", s.K1), ("K2", s.K2), ("R", s.R)):
        np.testing.assert_allclose(fs.getNode(key).mat(), val, atol=1e-12)
    np.testing.assert_allclose(fs.getNode("D1").mat().ravel(), s.D1, atol=1e-15)
    np.testing.assert_allclose(fs.getNode("D2").mat().ravel(), s.D2, atol=1e-15)
    assert fs.getNode("T").mat().shape == (3, 1)
    np.testing.assert_allclose(fs.getNode("T").mat().ravel(), s.T, atol=1e-9)
    fs.release()
    fs = cv2.FileStorage(str(DEFAULT_SCREEN), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("size_px").mat().ravel(), [1920, 1080])
    np.testing.assert_allclose(fs.getNode("top_left").mat().ravel(), s.top_left, atol=1e-9)
    fs.release()
    fs = cv2.FileStorage(str(DEFAULT_MARKERS), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("markers").mat(), DEFAULT_MARKERS_MM)
    assert fs.getNode("diameter").real() == 6.0
    fs.release()


# ----------------------------------------------------------------------------
# rendering
# ----------------------------------------------------------------------------

def test_render_is_deterministic_with_seed():
    sc = make_scene("glints_lamp", n_frames=4)
    args = (sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, float(sc.times[2]), sc.options)
    a = render_pair(*args, np.random.default_rng(7))
    b = render_pair(*args, np.random.default_rng(7))
    c = render_pair(*args, np.random.default_rng(8))
    for x, y in zip(a, b):
        assert x.dtype == np.uint8 and x.shape == (480, 640)
        np.testing.assert_array_equal(x, y)
    assert np.any(a[0] != c[0]) and np.any(a[1] != c[1])


def _check_centroids(setup, pose_fn, options, tol, min_checked, margin=15, max_offcentre=None):
    R, p = pose_fn(0.0)
    pts = DEFAULT_MARKERS_MM @ R.T + p
    imgs = render_pair(setup, DEFAULT_MARKERS_MM, DEFAULT_DIAMETER_MM, pose_fn, 0.0, options,
                       np.random.default_rng(0))
    w, h = setup.image_size
    checked, worst, far_out = 0, 0.0, 0.0
    for img, cam in zip(imgs, _cams(setup)):
        uv = _project(cam, pts)
        for u, v in uv:
            if not (margin <= u < w - margin and margin <= v < h - margin):
                continue
            cu, cv_, roi = _centroid(img, u, v, 9)
            assert roi.max() < 255, "clipped blob"
            assert roi.max() > 20
            worst = max(worst, np.hypot(cu - u, cv_ - v))
            far_out = max(far_out, np.hypot(u - cam[0][0, 2], v - cam[0][1, 2]))
            checked += 1
    assert checked >= min_checked
    assert worst < tol, worst
    if max_offcentre is not None:
        assert far_out > max_offcentre  # the test really reached the distorted periphery
    return worst


@pytest.mark.parametrize("pos_m, ypr", [
    ((0, -80, 650), (0, 0, 0)),
    ((60, -40, 560), (25, -10, 20)),
    ((-120, -100, 800), (-30, 15, -25)),
    ((100, -150, 1000), (10, 25, 0)),
])
def test_clean_blob_centroid_matches_projection(pos_m, ypr):
    s = default_setup()
    _check_centroids(s, _pose(s, pos_m, ypr), CLEAN, tol=0.05, min_checked=10)
    # with the default PSF (blur before pixel integration) the centroid is even closer
    _check_centroids(s, _pose(s, pos_m, ypr), CLEAN.replace(blur_sigma_px=0.6), tol=0.02, min_checked=10)


@pytest.mark.parametrize("pos_m", [(-420, -250, 480), (-150, 200, 420), (300, -300, 700)])
def test_clean_blob_centroid_wide_hd_strong_distortion(pos_m):
    s = wide_hd_setup()
    _check_centroids(s, _pose(s, pos_m), CLEAN.replace(brightness_scale=0.5), tol=0.05, min_checked=4,
                     max_offcentre=400)


@pytest.mark.slow
def test_clean_blob_centroid_matches_exact_area_centroid_wide_hd():
    """Against the exact centroid of the disk's image (dense back-projection
    of sub-pixel samples here, with cv2.undistortPoints): isolates rendering
    error from the physical offset between the image of a disk's centre and
    the centroid of the disk's image (≈ 0.04 px at the wide rig's corner)."""
    s = wide_hd_setup()
    pf = _pose(s, (-420, -250, 480))
    R, p = pf(0.0)
    pts = DEFAULT_MARKERS_MM @ R.T + p
    L = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, CLEAN)[0]
    K, D = s.K1, s.D1
    uv = _project(_cams(s)[0], pts)
    n = R[:, 2]
    S, half = 16, 7
    for i in (1, 4):  # the two markers nearest the corner
        u, v = uv[i]
        x0, y0 = int(round(u)) - half, int(round(v)) - half
        g = x0 - 0.5 + (np.arange((2 * half + 1) * S) + 0.5) / S
        gy = y0 - 0.5 + (np.arange((2 * half + 1) * S) + 0.5) / S
        uu, vv = np.meshgrid(g, gy)
        und = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], 1).reshape(-1, 1, 2), K, D,
                                  R=np.eye(3), P=np.eye(3),
                                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)).reshape(-1, 2)
        rays = np.c_[und, np.ones(len(und))]
        X = rays * ((n @ pts[i]) / (rays @ n))[:, None]
        inside = np.linalg.norm(X - pts[i], axis=1) <= 3.0
        exact = np.array([uu.ravel()[inside].mean(), vv.ravel()[inside].mean()])
        cu, cv_, _ = _centroid(L, u, v, half)
        assert np.hypot(cu - exact[0], cv_ - exact[1]) < 0.015
        assert np.hypot(u - exact[0], v - exact[1]) < 0.06  # the physical offset is small too


def test_brightness_model():
    o = RenderOptions()
    assert marker_radiance([0, 0, 800], [0, 0, -1], o) == pytest.approx(130.0)
    assert marker_radiance([0, 0, 400], [0, 0, -1], o) == pytest.approx(520.0)
    c60 = [0, 0, 800]
    n60 = [np.sin(np.radians(60)), 0, -np.cos(np.radians(60))]
    assert marker_radiance(c60, n60, o) == pytest.approx(130 * 0.5 ** 1.5)
    assert marker_radiance([0, 0, 800], [0, 0, 1], o) == 0.0  # back side
    # rendered: saturated at 40 cm, dim at 150 cm
    s = default_setup()
    near = render_pair(s, DEFAULT_MARKERS_MM, 6.0, _pose(s, (0, -80, 380)), 0.0, RenderOptions(noise=False))
    far = render_pair(s, DEFAULT_MARKERS_MM, 6.0, _pose(s, (0, -80, 1500)), 0.0, RenderOptions(noise=False))
    assert near[0].max() == 255 and near[1].max() == 255
    assert 25 < far[0].max() < 80 and 25 < far[1].max() < 80


def test_background_and_noise_statistics():
    s = default_setup()
    L, R = render_pair(s, DEFAULT_MARKERS_MM, 6.0, _pose(s, (0, -80, 650)), 0.0, RenderOptions(),
                       np.random.default_rng(3))
    for img in (L, R):
        med = np.median(img)
        assert 10 <= med <= 20
        hp = img.astype(float) - cv2.GaussianBlur(img.astype(float), (0, 0), 8)
        assert 1.6 < hp[50:150, 50:150].std() < 2.8  # shot (6 e-/DN) + 1.5 DN read noise


def test_occluded_marker_is_absent():
    s = default_setup()
    pf = _pose(s, (0, -80, 650), (10, 0, 0))
    R, p = pf(0.0)
    pts = DEFAULT_MARKERS_MM @ R.T + p
    opts = CLEAN.replace(occluded=frozenset({(1, 2), ("left", 4)}))
    L, Rimg = render_pair(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, opts)
    cams = _cams(s)
    for cam_i, img in enumerate((L, Rimg)):
        uv = _project(cams[cam_i], pts)
        for m, (u, v) in enumerate(uv):
            peak = img[int(v) - 4:int(v) + 5, int(u) - 4:int(u) + 5].max()
            hidden = (cam_i, m) in {(1, 2), (0, 4)}
            assert (peak == 0) if hidden else (peak > 60), (cam_i, m, peak)


def _n_blobs(img, thr=100):
    n, _, st, _ = cv2.connectedComponentsWithStats((img > thr).astype(np.uint8))
    return n - 1, st[1:]


def test_glints_and_lamp_add_blobs():
    s = default_setup()
    pf = _pose(s, (0, -80, 650))
    base = RenderOptions(noise=False)
    L0, R0 = render_pair(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, base)
    assert _n_blobs(L0)[0] == 5 and _n_blobs(R0)[0] == 5
    glint = base.replace(glints=(3, 3), glint_peak_dn=(400.0, 400.0))
    L1, R1 = render_pair(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, glint, np.random.default_rng(5))
    for img in (L1, R1):
        n, st = _n_blobs(img)
        assert 6 <= n <= 8  # 3 glints (one may merge with a marker)
        assert (st[:, cv2.CC_STAT_AREA] <= 4).sum() >= 1  # small sharp spots
    lamp = base.replace(lamps=(Lamp(tuple(s.m_to_world([-80.0, -420.0, 2200.0])), 45.0, 420.0),))
    L2, R2 = render_pair(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, lamp)
    for img in (L2, R2):
        n, st = _n_blobs(img)
        assert n == 6
        assert st[:, cv2.CC_STAT_AREA].max() > 150  # a large bright blob
        assert (img == 255).sum() > 100


def test_dim_ir_peaks():
    sc = make_scene("dim_ir", n_frames=8)
    cams = _cams(sc.setup)
    for k, t in enumerate(sc.times[::2]):
        imgs = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, t, sc.options,
                           np.random.default_rng(k))
        pts = sc.marker_positions(t)
        for img, cam in zip(imgs, cams):
            for u, v in _project(cam, pts):
                peak = int(img[int(v) - 4:int(v) + 5, int(u) - 4:int(u) + 5].max())
                assert 50 <= peak <= 110, peak


def test_motion_blur_and_time_offset():
    s = default_setup()
    vel = np.array([1000.0, 0.0, 0.0])  # 1 m/s along x_M

    def pf(t):
        return _pose(s, np.array([0.0, -80.0, 650.0]) + vel * t)(0.0)

    still = CLEAN.replace(blur_sigma_px=0.6)
    blurred = still.replace(exposure_s=0.008, motion_samples=8)
    A = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, still)[0]
    B = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, blurred)[0]
    assert A.sum() == pytest.approx(B.sum(), rel=0.02)  # same energy, spread out
    assert B.max() < 0.8 * A.max()
    assert (B > 5).sum() > 1.3 * (A > 5).sum()
    # right image at t + offset == right image rendered at that time
    off = still.replace(right_time_offset_s=0.004)
    R_off = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, off)[1]
    R_later = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.004, still)[1]
    R_now = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, still)[1]
    np.testing.assert_array_equal(R_off, R_later)
    assert np.abs(R_off - R_now).max() > 20


@pytest.mark.slow
def test_all_presets_build_and_render():
    for name in PRESETS:
        sc = make_scene(name, n_frames=3, seed=1)
        assert sc.n_frames == 3 and np.all(np.diff(sc.times) > 0)
        R, p = sc.pose_fn(float(sc.times[1]))
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        L, Rimg = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, float(sc.times[1]),
                              sc.options, np.random.default_rng(0))
        assert L.shape == (sc.setup.image_size[1], sc.setup.image_size[0]) == Rimg.shape
        assert L.max() > 40 or Rimg.max() > 40, name


def test_random_preset_heads_look_at_screen_and_stay_visible():
    sc = make_scene("random", n_frames=40, seed=3)
    s = sc.setup
    n = np.cross(s.top_right - s.top_left, s.bottom_left - s.top_left)
    n /= np.linalg.norm(n)
    for t in sc.times:
        p1, axes = sc.truth(t)
        v = axes[2]
        assert (v @ n) * ((s.top_left - p1) @ n) > 0  # V points toward the screen plane
        dist = abs((p1 - s.top_left) @ n)
        assert 330 < dist < 1600


# ----------------------------------------------------------------------------
# dataset folder
# ----------------------------------------------------------------------------

@pytest.mark.slow
def test_write_dataset_contract(tmp_path):
    sc = make_scene("fast_motion", n_frames=3)
    out = write_dataset(tmp_path / "ds", sc, seed=4)
    fs = cv2.FileStorage(str(out / "rig.yaml"), cv2.FILE_STORAGE_READ)
    w, h = int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real())
    assert (w, h) == (640, 480)
    assert fs.getNode("K1").mat().shape == (3, 3) and fs.getNode("K2").mat().shape == (3, 3)
    assert fs.getNode("D1").mat().shape == (1, 5) and fs.getNode("D2").mat().shape == (1, 5)
    assert fs.getNode("R").mat().shape == (3, 3) and fs.getNode("T").mat().shape == (3, 1)
    assert fs.getNode("K1").mat().dtype == np.float64
    fs.release()
    assert (out / "rig.yaml").read_text().startswith("%YAML")
    fs = cv2.FileStorage(str(out / "markers.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("markers").mat(), DEFAULT_MARKERS_MM)
    assert fs.getNode("diameter").real() == 6.0
    fs.release()
    fs = cv2.FileStorage(str(out / "screen.yaml"), cv2.FILE_STORAGE_READ)
    for key in ("top_left", "top_right", "bottom_left"):
        assert fs.getNode(key).mat().size == 3
    assert fs.getNode("size_px").mat().ravel().tolist() == [1920, 1080]
    fs.release()
    for side in ("left", "right"):
        files = sorted((out / side).glob("*.png"))
        assert [f.name for f in files] == ["000000.png", "000001.png", "000002.png"]
        img = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (480, 640)
    times = list(csv.reader(open(out / "times.csv")))
    assert times[0] == ["frame", "t", "t_right"]
    assert [float(r[2]) - float(r[1]) for r in times[1:]] == pytest.approx([0.004] * 3)
    rows = list(csv.reader(open(out / "truth.csv")))
    assert rows[0] == "frame,x,y,z,xi_x,xi_y,xi_z,psi_x,psi_y,psi_z,v_x,v_y,v_z".split(",")
    assert len(rows) == 4 and all(len(r) == 13 for r in rows)
    assert all(len(x.split(".")[1]) == 6 for x in rows[1][1:])
    for r in rows[1:]:
        k = int(r[0])
        p1, axes = sc.truth(sc.times[k])
        vals = np.array([float(x) for x in r[1:]])
        np.testing.assert_allclose(vals[:3], p1, atol=1e-6)
        np.testing.assert_allclose(vals[3:].reshape(3, 3), axes, atol=1e-6)
        np.testing.assert_allclose(vals[3:].reshape(3, 3) @ vals[3:].reshape(3, 3).T, np.eye(3), atol=1e-5)
    # The viewer's true gaze sits in a file of its own, one row per frame, as true_gaze computes it.
    gaze_rows = list(csv.reader(open(out / "gaze_truth.csv")))
    assert gaze_rows[0] == GAZE_TRUTH_HEADER.split(",") and len(gaze_rows) == 4
    expected = true_gaze(sc, seed=4)
    for k, r in enumerate(gaze_rows[1:]):
        assert int(r[0]) == k
        np.testing.assert_allclose([float(x) for x in r[1:3]], expected.eye_in_head_deg[k], atol=1e-6)
        np.testing.assert_allclose([float(x) for x in r[3:6]], expected.direction[k], atol=1e-6)
        np.testing.assert_allclose([float(x) for x in r[6:8]], expected.screen_px[k], atol=1e-6)


def test_write_dataset_custom_model_and_plain_times(tmp_path):
    sc = make_scene("custom_model", n_frames=2)
    out = write_dataset(tmp_path / "cm", sc)
    fs = cv2.FileStorage(str(out / "markers.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("markers").mat(), CURVED_MARKERS_MM)
    assert fs.getNode("diameter").real() == 7.0
    fs.release()
    assert (out / "times.csv").read_text().splitlines()[0] == "frame,t"
    # deterministic: same seed, same pixels
    out2 = write_dataset(tmp_path / "cm2", sc)
    a = cv2.imread(str(out / "left" / "000001.png"), cv2.IMREAD_UNCHANGED)
    b = cv2.imread(str(out2 / "left" / "000001.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------------
# the viewer's true gaze (gaze_truth.csv)
# ----------------------------------------------------------------------------

def _contract_angles_deg(axes, d):
    """(θ, φ) deg of direction d in the head frame with rows Ξ, Ψ, V (docs/contract.md)."""
    x, y, z = axes @ d
    return np.degrees(np.arctan2(x, z)), np.degrees(np.arctan2(y, z))


def test_true_gaze_is_the_head_turned_by_the_models_eyes():
    sc = make_scene("static", n_frames=150)            # 5 s: some fifteen fixations about the screen
    g = true_gaze(sc, seed=0)
    s = sc.setup
    assert g.eye_in_head_deg.shape == (150, 2) and g.direction.shape == (150, 3) and g.screen_px.shape == (150, 2)
    # Seen from 60 cm, the 24-inch screen's half extents (the viewer model's screen).
    w, h = (np.linalg.norm(np.subtract(s.top_right, s.top_left)), np.linalg.norm(np.subtract(s.bottom_left, s.top_left)))
    assert g.screen_half_deg == pytest.approx((np.degrees(np.arctan(w / 2 / 600)), np.degrees(np.arctan(h / 2 / 600))),
                                              abs=0.5)
    moved = np.abs(g.eye_in_head_deg).max(axis=1) > 1.0
    assert moved.sum() > 50                             # the eyes do move, and within the orbit
    assert np.linalg.norm(g.eye_in_head_deg, axis=1).max() <= 35.0 + 1e-6
    np.testing.assert_allclose(np.linalg.norm(g.direction, axis=1), 1.0, atol=1e-12)
    for k in range(0, 150, 7):
        p1, axes = sc.truth(sc.times[k])
        theta, phi = _contract_angles_deg(axes, g.direction[k])
        # θ is measured toward Ξ (the wearer's left): the eye's rightward offset is -θ; up is φ.
        assert (-theta, phi) == pytest.approx(tuple(g.eye_in_head_deg[k]), abs=1e-9)
        # The written pixel lies on the gaze ray from P1 (docs/contract.md's pixel formula).
        q = s.screen_point(*g.screen_px[k]) - p1
        np.testing.assert_allclose(q / np.linalg.norm(q), g.direction[k], atol=1e-9)
    # The head looks at the screen's centre: gaze to the right lands right of it on the screen (+x px), up above it.
    centre = np.array(s.screen_size_px) / 2
    right, up = g.eye_in_head_deg[:, 0] > 1, g.eye_in_head_deg[:, 1] > 1
    assert (g.screen_px[right, 0] > centre[0]).all() and (g.screen_px[up, 1] < centre[1]).all()


def test_true_gaze_is_seeded_apart_from_the_images():
    sc = make_scene("static", n_frames=60)
    a, b, c = true_gaze(sc, seed=1), true_gaze(sc, seed=1), true_gaze(sc, seed=2)
    np.testing.assert_array_equal(a.eye_in_head_deg, b.eye_in_head_deg)
    assert not np.array_equal(a.eye_in_head_deg, c.eye_in_head_deg)
    assert gaze_seed(1) != 1 and gaze_seed(1) == gaze_seed(1) != gaze_seed(2)


def test_true_gaze_off_the_screen_plane_has_no_pixel():
    sc = make_scene("static", n_frames=3)
    # A head turned away from the screen: V points back, away from its plane.
    def away(t):
        R, p = sc.pose_fn(t)
        return np.asarray(R) @ np.diag([-1.0, 1.0, -1.0]), p
    from dataclasses import replace
    g = true_gaze(replace(sc, pose_fn=away), seed=0)
    assert np.isnan(g.screen_px).all() and np.isfinite(g.direction).all()
