"""Tests of headplod.render: head-coupled projection (analytic) and the offscreen renderer.

The GL tests need a headless EGL context (Mesa llvmpipe is enough; the
``gl_context`` fixture in conftest.py) and skip, saying why, when there is none.
"""
import math

import numpy as np
import pytest

from headplod.io import Screen
from headplod.render import PALETTE, SceneTransform, TerrainRenderer, off_axis_projection, overlay_poi, scene_to_world, screen_frame

W, H = 320, 180  # screen and render size, px (1:1 so screen pixel = image pixel)


def _rot_x(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def make_screen(size_px=(W, H), tilt_deg=12.0, yaw_deg=-5.0, shear_mm=0.0):
    """A 520 x 292.5 mm display under the cameras, facing the viewer (world +z), tilted.

    World = camera frame (x right, y down, z toward the user): the viewer's
    right is the camera's −x, the viewer's up is the camera's −y.
    """
    R = _rot_y(yaw_deg) @ _rot_x(tilt_deg)
    c = np.array([0.0, 180.0, -20.0])
    tl = c + R @ np.array([260.0, -146.25, 0.0])
    tr = c + R @ np.array([-260.0, -146.25, 0.0])
    bl = c + R @ np.array([260.0 - shear_mm, 146.25, 0.0])
    return Screen(tuple(size_px), tl, tr, bl)


EYES = [
    [0.0, 150.0, 600.0],
    [120.0, 60.0, 450.0],
    [-250.0, 260.0, 700.0],
    [40.0, -80.0, 300.0],
]


def project(view, proj, points_world):
    """NDC (..., 3) of world points (mm) through float64 copies of the matrices."""
    p = np.c_[points_world, np.ones(len(points_world))]
    c = (proj.astype(np.float64) @ view.astype(np.float64) @ p.T).T
    return c[:, :3] / c[:, 3:]


def pixel_ndc(xy, size_px):
    w, h = size_px
    return np.c_[2 * xy[:, 0] / w - 1, 1 - 2 * xy[:, 1] / h]


# --------------------------------------------------------------------------
# off-axis projection, analytic (no GL)
# --------------------------------------------------------------------------


@pytest.mark.parametrize("shear_mm", [0.0, 30.0])
@pytest.mark.parametrize("eye", EYES)
def test_screen_pixels_land_on_their_ndc(eye, shear_mm):
    screen = make_screen(size_px=(1920, 1080), shear_mm=shear_mm)
    view, proj = off_axis_projection(eye, screen, 10.0, 5000.0)
    assert view.dtype == np.float32 and proj.dtype == np.float32
    xy = np.array([[0, 0], [1920, 0], [0, 1080], [1920, 1080], [960, 540], [123.5, 1001.25]])
    ndc = project(view, proj, screen.pixel_to_world(xy))
    # float32 matrices: ~1e-7 relative on mm-scale numbers
    np.testing.assert_allclose(ndc[:, :2], pixel_ndc(xy, (1920, 1080)), atol=2e-5)


@pytest.mark.parametrize("eye", EYES)
def test_points_off_the_screen_project_along_the_eye_ray(eye):
    """Behind or in front of the screen, a point is drawn where the eye's ray through it crosses the screen."""
    screen = make_screen(size_px=(1920, 1080))
    view, proj = off_axis_projection(eye, screen, 5.0, 5000.0)
    right, up, toward, center = screen_frame(screen)
    rng = np.random.default_rng(3)
    pts = center + rng.uniform(-200, 200, (20, 1)) * right + rng.uniform(-120, 120, (20, 1)) * up \
        + rng.uniform(-800, 150, (20, 1)) * toward
    ndc = project(view, proj, pts)
    xy = np.array([screen.intersect_ray(eye, p - np.asarray(eye)) for p in pts])
    np.testing.assert_allclose(ndc[:, :2], pixel_ndc(xy, (1920, 1080)), atol=2e-5)


def test_parallax_direction():
    """As the eye moves right, a point behind the screen moves right on it and a point in front moves left."""
    screen = make_screen(size_px=(1920, 1080))
    right, up, toward, center = screen_frame(screen)
    eye0 = center + 600 * toward
    behind, front = center - 300 * toward, center + 200 * toward
    x = []
    for eye in (eye0, eye0 + 100 * right):
        view, proj = off_axis_projection(eye, screen, 5.0, 5000.0)
        x.append(project(view, proj, np.array([behind, front, center]))[:, 0])
    dx = x[1] - x[0]
    assert dx[0] > 0.01 and dx[1] < -0.01 and abs(dx[2]) < 1e-6
    # similar triangles: the behind point moves 100 * 300 / 900 mm on a 520 mm wide screen
    np.testing.assert_allclose(dx[0], 2 * (100 * 300 / 900) / 520, rtol=1e-4)


def test_frustum_is_symmetric_on_the_central_axis_and_depth_maps_near_far():
    screen = make_screen()
    right, up, toward, center = screen_frame(screen)
    view, proj = off_axis_projection(center + 650 * toward, screen, 20.0, 3000.0)
    assert abs(proj[0, 2]) < 1e-6 and abs(proj[1, 2]) < 1e-6 and abs(proj[0, 1]) < 1e-6
    np.testing.assert_allclose(proj[0, 0], 2 * 650 / 520, rtol=1e-5)
    np.testing.assert_allclose(proj[1, 1], 2 * 650 / 292.5, rtol=1e-5)
    # view is a rigid motion to (right, up, toward) axes with the eye at the origin
    np.testing.assert_allclose(view[:3, :3], np.stack([right, up, toward]), atol=1e-6)
    eye = center + 650 * toward
    z = project(view, proj, np.array([eye - 20 * toward, eye - 3000 * toward]))[:, 2]
    np.testing.assert_allclose(z, [-1, 1], atol=1e-5)
    # off the axis the frustum is skewed
    _, proj2 = off_axis_projection(center + 650 * toward + 100 * right, screen, 20.0, 3000.0)
    assert abs(proj2[0, 2]) > 0.1


@pytest.mark.parametrize("eye, near, match", [
    (lambda center, toward: center - 100 * toward, 10, "behind"),
    (lambda center, toward: center + 100 * toward, 0, "near"),
    (lambda center, toward: [0, 0], 10, "eye_mm"),
], ids=["eye-behind-the-screen", "zero-near-plane", "eye-not-3d"])
def test_projection_rejects_bad_input(eye, near, match):
    screen = make_screen()
    right, up, toward, center = screen_frame(screen)
    with pytest.raises(ValueError, match=match):
        off_axis_projection(eye(center, toward), screen, near, 1000)


def test_scene_to_world_places_the_terrain():
    screen = make_screen()
    right, up, toward, center = screen_frame(screen)
    T = scene_to_world(2.5, [100.0, 200.0, 30.0], screen, depth_mm=80.0)
    np.testing.assert_allclose(T.apply([100.0, 200.0, 30.0]), center - 80 * toward, atol=1e-9)
    d = T.apply(np.array([[101.0, 200, 30], [100, 201, 30], [100, 200, 31]])) - T.apply([100.0, 200, 30])
    np.testing.assert_allclose(d, 2.5 * np.stack([right, -toward, up]), atol=1e-9)  # east, north, up
    np.testing.assert_allclose(np.asarray(T.inverse() @ T), np.eye(4), atol=1e-12)
    # map view: up toward the viewer, north along the screen's up
    M = scene_to_world(1.0, [0, 0, 0], screen, pitch_deg=90.0)
    np.testing.assert_allclose(np.asarray(M)[:3, :3], np.column_stack([right, up, toward]), atol=1e-12)
    with pytest.raises(ValueError):
        scene_to_world(0.0, [0, 0, 0], screen)
    with pytest.raises(ValueError):
        SceneTransform(np.ones((3, 3)))


def test_overlay_poi_draws_crosshair_and_2_sigma_ellipse():
    img = np.zeros((200, 300, 3), np.uint8)
    # σθ = 2 deg (horizontal), σφ = 1 deg (vertical), 10 px/deg → 2σ half-axes 40 px and 20 px
    out = overlay_poi(img, (150.0, 100.0), np.diag([1.0, 4.0]), 10.0, (0, 255, 0))
    assert img.max() == 0  # not drawn in place by default
    g = out[:, :, 1] > 100
    assert g[100, 150] and g[100, 140] and g[90, 150]  # crosshair
    cols, rows = np.nonzero(g.T)
    assert abs(cols.min() - 110) <= 1 and abs(cols.max() - 190) <= 1
    assert abs(rows.min() - 80) <= 1 and abs(rows.max() - 120) <= 1
    assert (out[:, :, [0, 2]] == 0).all()
    # positive φθ correlation: up goes with right, so the ellipse leans "/" in the image
    out = overlay_poi(img, (150.0, 100.0), [[4.0, 3.5], [3.5, 4.0]], 10.0, (255, 255, 255))
    m = out[:, :, 0] > 100
    assert m[:100, 150:].sum() > 3 * m[:100, :150].sum()
    np.testing.assert_array_equal(overlay_poi(img, None, None, 10.0, (255, 0, 0)), img)
    np.testing.assert_array_equal(overlay_poi(img, (np.nan, 3), None, 10.0, (255, 0, 0)), img)


# --------------------------------------------------------------------------
# renderer (EGL)
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def renderer(gl_context):
    r = TerrainRenderer(gl_context, (W, H))
    yield r
    r.release()


def grid_mesh(n=12, extent=1.0, levels_mod=8):
    """Flat n x n quad grid in the scene plane z = 0, [-extent, extent]², as a soup.

    Returns positions (6n², 3), normals (6n², 3) = +z, per-triangle levels (2n²,).
    """
    u = np.linspace(-extent, extent, n + 1)
    x, y = np.meshgrid(u, u)
    P = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3)
    i = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = i[:-1, :-1], i[:-1, 1:], i[1:, :-1], i[1:, 1:]
    tri = np.stack([np.stack([a, b, d], -1), np.stack([a, d, c], -1)], 2).reshape(-1, 3)
    pos = P[tri.reshape(-1)].astype(np.float32)
    nrm = np.tile(np.float32([0, 0, 1]), (len(pos), 1))
    levels = (np.arange(len(tri)) // 2 % levels_mod).astype(np.uint8)
    return pos, nrm, levels, P.astype(np.float32), tri


@pytest.fixture(scope="module")
def scene():
    """Screen, a map-view placement of the grid 60 mm behind the screen, and the eye's matrices."""
    screen = make_screen()
    right, up, toward, center = screen_frame(screen)
    model = scene_to_world(110.0, [0, 0, 0], screen, depth_mm=60.0, pitch_deg=90.0)
    view, proj = off_axis_projection(center + 600 * toward + 40 * right, screen, 50.0, 2000.0)
    return screen, model, view, proj


def test_view_modes(renderer, scene):
    screen, model, view, proj = scene
    pos, nrm, levels, *_ = grid_mesh()
    renderer.upload(pos, nrm, levels)
    bg = np.round(np.array(renderer.background) * 255).astype(np.uint8)
    imgs = {}
    for mode in ("shaded", "wire", "levels"):
        img = renderer.render(view, proj, model, mode, light_dir=(0, 0, 1))
        assert img.shape == (H, W, 3) and img.dtype == np.uint8
        assert renderer.last_render_ms > 0
        covered = (np.abs(img.astype(int) - bg).sum(-1) > 6).mean()
        assert 0.2 < covered < 0.95, f"{mode}: {covered:.0%} of the image covered"
        imgs[mode] = img
    # light along the normal: full shade, so the levels view holds the exact palette colours
    flat = imgs["levels"].reshape(-1, 3)
    for k, colour in enumerate(PALETTE):
        assert (flat == colour).all(-1).sum() > 50, f"palette colour {k} {colour.tolist()} missing"
    dark = {m: (imgs[m].astype(int).sum(-1) < 120).sum() for m in imgs}
    assert dark["wire"] > 1000 and dark["shaded"] == 0, dark


def test_render_is_deterministic_and_indexed_equals_soup(renderer, scene):
    screen, model, view, proj = scene
    pos, nrm, levels, P, tri = grid_mesh(n=20)
    renderer.upload(pos, nrm, levels)
    a = [renderer.render(view, proj, model, m, light_dir=(0.3, 0.2, 1)) for m in ("shaded", "wire", "levels")]
    b = [renderer.render(view, proj, model, m, light_dir=(0.3, 0.2, 1)) for m in ("shaded", "wire", "levels")]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    # a bigger mesh (buffers grow), then the indexed form of the first one (they shrink back)
    big = grid_mesh(n=60)
    renderer.upload(*big[:3])
    assert renderer.n_triangles == 2 * 60 * 60
    renderer.upload(P, np.tile(np.float32([0, 0, 1]), (len(P), 1)), levels, tri)
    assert renderer.n_triangles == len(tri)
    c = [renderer.render(view, proj, model, m, light_dir=(0.3, 0.2, 1)) for m in ("shaded", "wire", "levels")]
    for x, y in zip(a, c):
        np.testing.assert_array_equal(x, y)


def test_set_indices_draws_a_new_selection_over_the_uploaded_vertices(gl_context, scene):
    screen, model, view, proj = scene
    pos, nrm, levels, P, tri = grid_mesh(n=20)
    fresh = TerrainRenderer(gl_context, (W, H))
    try:
        with pytest.raises(ValueError, match="upload the vertices first"):
            fresh.set_indices(tri)
        normals = np.tile(np.float32([0, 0, 1]), (len(P), 1))
        fresh.upload(P, normals, levels, tri, tag="table")
        assert fresh.tag == "table" and fresh.indexed
        half = np.arange(0, len(tri), 2)                    # every other triangle
        fresh.set_indices(tri[half].astype(np.uint32), levels[half])
        assert fresh.n_triangles == len(half) and fresh.tag == "table"
        got = [fresh.render(view, proj, model, m, light_dir=(0.3, 0.2, 1)) for m in ("shaded", "levels")]
        fresh.upload(P[tri[half].reshape(-1)], normals[tri[half].reshape(-1)], levels[half])
        assert not fresh.indexed and fresh.tag is None
        want = [fresh.render(view, proj, model, m, light_dir=(0.3, 0.2, 1)) for m in ("shaded", "levels")]
        for x, y in zip(got, want):
            np.testing.assert_array_equal(x, y)
        with pytest.raises(ValueError, match="indices"):
            fresh.set_indices(np.array([[0, 1, 3 * len(half)]]))
    finally:
        fresh.release()


@pytest.mark.parametrize("bad_upload, match", [
    (lambda pos, nrm, levels: (pos[:-1], nrm[:-1]), "multiple of 3"),
    (lambda pos, nrm, levels: (pos, nrm, levels[:-1]), "levels"),
    (lambda pos, nrm, levels: (pos, nrm[:3]), "normals"),
    (lambda pos, nrm, levels: (pos, nrm, None, np.array([[0, 1, len(pos)]])), "indices"),
    (lambda pos, nrm, levels: (pos[:6], nrm[:6], np.arange(2), np.array([[0, 1, 2]]).repeat(3, 0)), "levels"),
], ids=["soup-not-triangles", "levels-per-triangle", "normals-per-vertex", "index-out-of-range",
        "levels-per-indexed-triangle"])
def test_upload_rejects_bad_meshes(renderer, bad_upload, match):
    pos, nrm, levels, *_ = grid_mesh(n=2)
    renderer.upload(pos, nrm, levels)
    before = (renderer.n_triangles, renderer.n_vertices, renderer.indexed)
    with pytest.raises(ValueError, match=match):
        renderer.upload(*bad_upload(pos, nrm, levels))
    assert (renderer.n_triangles, renderer.n_vertices, renderer.indexed) == before   # refused: nothing lost


def test_render_rejects_an_unknown_view_mode(renderer):
    with pytest.raises(ValueError, match="view_mode"):
        renderer.render(np.eye(4), np.eye(4), None, "xray")


def _blob(img, colour):
    """Centroid (x, y) in screen px (pixel centres at +0.5) and size of the pixels of one exact colour."""
    rows, cols = np.nonzero((img == colour).all(-1))
    return np.array([cols.mean() + 0.5, rows.mean() + 0.5]), len(rows)


def test_point_on_the_screen_stays_put_when_the_head_moves(renderer):
    """Head-coupled property, rendered: a triangle on the screen plane does not move; one behind it does."""
    screen = make_screen()
    right, up, toward, center = screen_frame(screen)
    # triangle on the screen around pixel (220, 60); another 150 mm behind around pixel (100, 120)
    on_px = np.array([[214.0, 54.0], [228.0, 56.0], [218.0, 68.0]])
    on = screen.pixel_to_world(on_px)
    behind = screen.pixel_to_world(np.array([[94.0, 114.0], [108.0, 116.0], [98.0, 128.0]])) - 150 * toward
    pos = np.vstack([on, behind]).astype(np.float32)
    nrm = np.tile(toward.astype(np.float32), (6, 1))
    renderer.upload(pos, nrm, np.array([3, 5], np.uint8))  # yellow, cyan
    yellow, cyan = PALETTE[3], PALETTE[5]
    eyes = [center + 600 * toward, center + 600 * toward + 150 * right - 80 * up]
    results = []
    for eye in eyes:
        view, proj = off_axis_projection(eye, screen, 50.0, 2000.0)
        # scene = world (mm), light along the normal: the exact palette colours
        img = renderer.render(view, proj, np.eye(4), "levels", light_dir=toward)
        c_on, n_on = _blob(img, yellow)
        c_behind, n_behind = _blob(img, cyan)
        assert n_on > 40 and n_behind > 20
        # the on-screen triangle covers its own pixels: centroid within half a pixel
        np.testing.assert_allclose(c_on, on_px.mean(0), atol=0.5)
        # the one behind is where the eye's rays through it cross the screen
        expect = np.mean([screen.intersect_ray(eye, p - eye) for p in behind], axis=0)
        np.testing.assert_allclose(c_behind, expect, atol=0.5)
        results.append((c_on, c_behind))
    assert np.abs(results[0][0] - results[1][0]).max() < 0.2
    shift = results[1][1] - results[0][1]
    assert shift[0] > 5 and shift[1] > 2  # moves with the eye: right, and down the screen (eye went down)


def test_msaa_option_renders(gl_context, scene):
    screen, model, view, proj = scene
    pos, nrm, levels, *_ = grid_mesh(n=6)
    with TerrainRenderer(gl_context, (W, H), samples=min(4, gl_context.max_samples)) as r:
        r.upload(pos, nrm, levels)
        img = r.render(view, proj, model, "wire")
    assert img.shape == (H, W, 3) and img.std() > 5


def test_screen_to_image_px_scales_corners_and_centres():
    """The one screen px -> image px mapping: continuous coordinates, corners to corners (a pure scale), and
    with ``pixel_index`` the centre of pixel (i, j) at (i, j)."""
    from headplod.render.projection import screen_to_image_px

    screen, image = (1920, 1080), (1280, 720)
    corners = np.array([[0.0, 0.0], [1920.0, 1080.0], [960.0, 540.0]])
    np.testing.assert_array_equal(screen_to_image_px(corners, screen, image), [[0, 0], [1280, 720], [640, 360]])
    # The centre of the screen's top-left pixel (0.5, 0.5) is 1/3 px into the image's (a 2/3 scale) ...
    np.testing.assert_allclose(screen_to_image_px([0.5, 0.5], screen, image), [1 / 3, 1 / 3], rtol=0, atol=1e-12)
    # ... and the centre of the image's last pixel, as a pixel index, is that pixel's index.
    last = screen_to_image_px([1920 - 0.75, 1080 - 0.75], screen, image, pixel_index=True)
    np.testing.assert_allclose(last, [1279.0, 719.0], rtol=0, atol=1e-12)
    assert screen_to_image_px(np.zeros((4, 3, 2)), screen, image).shape == (4, 3, 2)
