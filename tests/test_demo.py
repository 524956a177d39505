"""The terrain demo viewer: headless loop, POI following, tracking loss, saccade rule, viewpoints, keys.

Small images (320x180) and few frames keep this fast on llvmpipe; the
terrain and its mesh are built once for the module.
"""
import argparse
import json
import shutil
import sys

import cv2
import numpy as np
import pytest

from headplod.plod.select import SelectorConfig
from headplod.demo import loop as lp
from headplod.demo.viewpoints import VIEWPOINTS, place
from headplod.demo.keys import DEMO_MODES, action_for_key

SIZE = (320, 180)
#: The renderer's clear colour in 8 bits (TerrainRenderer's default background).
BACKGROUND = np.round(np.array([0.62, 0.72, 0.82]) * 255)


@pytest.fixture(scope="module")
def renderer(gl_context):
    from headplod.render import TerrainRenderer

    r = TerrainRenderer(gl_context, size=SIZE)
    yield r
    r.release()


def _run(loop, n):
    results = []
    for _ in range(n):
        r = loop.step()
        if r is None:
            break
        results.append(r)
    return results


def _terrain_fraction(image):
    """Fraction of pixels that are not the clear colour."""
    return float(np.mean(np.abs(image.astype(float) - BACKGROUND).sum(axis=2) > 6))


@pytest.mark.slow
def test_headless_run_writes_frames_and_summary(tmp_path, terrain_scene, renderer):
    from headplod.demo.cli import add_demo_arguments, run_headless

    parser = add_demo_arguments(argparse.ArgumentParser())
    args = parser.parse_args(["--headless", "--mouse", "--frames", "4", "--out", str(tmp_path / "demo"),
                              "--size", "320,180", "--viewpoints", "overview", "--scenarios", "none,adaptive"])
    out = tmp_path / "table.txt"
    with open(out, "w") as stream:
        summary = run_headless(args, out=stream, err=stream, scene=terrain_scene, renderer=renderer)
    text = out.read_text()
    folder = tmp_path / "demo"
    on_disk = json.loads((folder / "summary.json").read_text())
    assert on_disk["size"] == [320, 180] and on_disk["frames_per_run"] == 4
    runs = {(r["mode"], r["uncertainty"]) for r in on_disk["runs"]}
    default = SelectorConfig().mode                              # the demo compares the default mode with full
    assert runs == {(default, "none"), (default, "adaptive"), ("full", "none")}
    for r in on_disk["runs"]:
        assert r["frames"] == 4
        for key in ("fps", "frame_ms_median", "triangles_median", "saccade_skipped", "tracking_failures"):
            assert np.isfinite(r[key]), key
        assert set(r["stage_ms_median"]) >= {"pose", "select", "build", "upload", "render"}
        assert len(r["per_frame"]["frame_ms"]) == len(r["per_frame"]["triangles"]) == 4
    csf = next(r for r in on_disk["runs"] if r["uncertainty"] == "adaptive")
    full = next(r for r in on_disk["runs"] if r["mode"] == "full")
    assert full["triangles_median"] == 2048 * 4 ** 5 and csf["triangles_median"] < full["triangles_median"] / 4
    assert on_disk["fps_ratio_to_full"]["overview"]["ratio"] > 0
    assert (folder / "summary.png").stat().st_size > 10_000
    picture = cv2.imread(summary["pictures"]["overview"])
    assert picture.shape == (180, 320, 3) and _terrain_fraction(picture[..., ::-1]) > 0.2
    frames = sorted((folder / "frames").glob("*.png"))
    assert len(frames) == 6                                    # two per run
    for path in frames:
        image = cv2.imread(str(path))
        assert image.shape == (180, 320, 3) and image.std() > 10
    assert "overview" in text and "x full" in text and "picture overview" in text
    # One index picture labelling them all (issue 36): the picture and the chart, each under its name.
    index = cv2.imread(str(folder / "index.png"))
    assert summary["index"] == str(folder / "index.png") and index.shape[1] > 2 * 320 and "index.png" in text


@pytest.mark.slow
def test_levels_follow_the_poi(terrain_scene, renderer, default_screen):
    from headplod.plod.contrast import project_to_screen_px

    w, h = default_screen.size_px
    path = [(0.25 * w, 0.5 * h)] * 4 + [(0.75 * w, 0.5 * h)] * 4
    poses = lp.MousePoses(default_screen, path=path, cov_deg2=None)
    loop = lp.DemoLoop(terrain_scene, poses, renderer, mode="csf", uncertainty="none", viewpoint="overview", hud=False)
    results = _run(loop, 8)
    assert len(results) == 8
    centroids_px = project_to_screen_px(loop.selector().centroids_mm, poses.eye_mm, default_screen)

    def finest_x(levels):
        finest = levels == levels.max()
        return float(np.nanmean(centroids_px[finest, 0]))

    left, right = finest_x(results[3].levels), finest_x(results[7].levels)
    assert abs(left - 0.25 * w) < 0.12 * w
    assert abs(right - 0.75 * w) < 0.12 * w
    assert right - left > 0.35 * w
    assert not results[7].saccade_skipped


@pytest.mark.slow
def test_tracker_failure_keeps_running_on_the_last_pose(tmp_path_factory, terrain_scene, renderer):
    """The real tracker on the synthetic sequence, two frames blanked mid-run."""
    from headplod.capture.synthetic import ensure_dataset

    root = tmp_path_factory.mktemp("demo_synth")
    folder = root / "blanked"
    shutil.copytree(ensure_dataset("looking_around", frames=8, root=root, quiet=True), folder)
    for k in (3, 4, 5):
        path = folder / "left" / f"{k:06d}.png"
        cv2.imwrite(str(path), np.zeros_like(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)))
    poses = lp.TrackerPoses(str(folder))
    loop = lp.DemoLoop(terrain_scene, poses, renderer, viewpoint="overview", hud=True)
    results = _run(loop, 20)
    assert len(results) == 8                               # ran to the end
    held = [r.pose.held for r in results]
    assert held == [False, False, False, True, True, True, False, False]
    good = results[2].pose
    traces = [np.trace(good.cov_deg2)] + [np.trace(r.pose.cov_deg2) for r in results[3:6]]
    assert np.all(np.diff(traces) > 0)                     # growing while lost
    rate = (traces[-1] - traces[0]) / (2 * (results[5].t - good.t))
    assert rate == pytest.approx(lp.GROWTH_DEG2_PER_S, rel=1e-6)
    for r in results[3:6]:
        np.testing.assert_array_equal(r.pose.eye_mm, good.eye_mm)
        np.testing.assert_array_equal(r.pose.poi_px, good.poi_px)
        assert r.tracking_lost and "blob" in r.tracking_lost
        assert r.image.shape == (180, 320, 3) and r.image.std() > 10
        info = loop.hud_info(r)
        assert info.tracking_lost == r.tracking_lost
    assert loop.stats.tracking_failures == 3 and loop.stats.summary()["tracking_failures"] == 3
    assert np.isfinite(results[6].pose.markers_px).all()  # tracked again, markers identified
    assert results[6].pose.images[0].shape == results[0].pose.images[0].shape


@pytest.mark.slow
def test_saccade_rule_keeps_levels(terrain_scene, renderer, default_screen):
    w, h = default_screen.size_px
    # 30 fps; 1920 px over 531 mm at 600 mm: 300 px per frame is ~240 deg/s, 2 px per frame ~1.6 deg/s.
    slow = [(0.2 * w + 2 * k, 0.5 * h) for k in range(4)]
    fast = [(slow[-1][0] + 300 * (k + 1), 0.5 * h) for k in range(3)]
    still = [fast[-1]] * 2
    poses = lp.MousePoses(default_screen, path=slow + fast + still, cov_deg2=None)
    loop = lp.DemoLoop(terrain_scene, poses, renderer, mode="csf", uncertainty="none", viewpoint="overview", hud=False)
    results = _run(loop, 9)
    speeds = [r.poi_speed_deg_s for r in results]
    assert max(speeds[1:4]) < 5 and min(speeds[4:7]) > lp.SACCADE_DEG_S
    assert [r.saccade_skipped for r in results] == [False] * 4 + [True] * 3 + [False] * 2
    for k in (4, 5, 6):
        np.testing.assert_array_equal(results[k].levels, results[3].levels)
    assert results[6].triangles == results[3].triangles
    assert not np.array_equal(results[7].levels, results[3].levels)      # re-selected where the POI landed
    assert loop.stats.saccade_skipped == 3


@pytest.mark.slow
def test_viewpoints_differ_and_render(terrain_scene, renderer, default_screen):
    models = {name: place(terrain_scene, name).model for name in VIEWPOINTS}
    assert set(models) == {"overview", "mountains", "plains"}
    names = list(models)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            assert not np.allclose(models[names[i]], models[names[j]])
    for name in names:
        loop = lp.DemoLoop(terrain_scene, lp.MousePoses(default_screen, path=[(960, 540)]), renderer, viewpoint=name,
                           hud=False)
        result = loop.step()
        assert result.triangles > 2048
        assert _terrain_fraction(result.image) > 0.3, name


@pytest.mark.slow
def test_key_mapping_and_apply(terrain_scene, renderer, default_screen):
    assert [action_for_key(str(k)) for k in range(1, len(DEMO_MODES) + 1)] == [("mode", m) for m in DEMO_MODES]
    assert action_for_key("N") == action_for_key("n") == ("uncertainty", "none")
    assert action_for_key("f") == ("uncertainty", "fixed")
    assert action_for_key("a") == ("uncertainty", "adaptive")
    assert action_for_key("s") == ("uncertainty", "smoothed")
    assert action_for_key("w") == ("view_mode", "wire")
    assert action_for_key("l") == ("view_mode", "levels")
    assert action_for_key("v") == ("view_mode", "shaded")
    assert action_for_key("h") == ("hud", "toggle")
    assert action_for_key("c") == ("viewpoint", "next")
    assert action_for_key("escape") == ("quit", None)
    assert action_for_key("x") is None and action_for_key("") is None
    loop = lp.DemoLoop(terrain_scene, lp.MousePoses(default_screen, path=[(960, 540)] * 3), renderer, hud=True)
    assert loop.apply(action_for_key(str(len(DEMO_MODES)))) and loop.settings["mode"] == "full"
    assert loop.apply(action_for_key("c")) and loop.settings["viewpoint"] == "mountains"
    assert loop.apply(action_for_key("l")) and loop.settings["view_mode"] == "levels"
    assert loop.apply(action_for_key("h")) and loop.hud is False
    assert loop.apply(action_for_key("4")) and loop.settings["mode"] == "gp"
    assert loop.apply(action_for_key("x"))
    assert loop.apply(action_for_key("q")) is False
    result = loop.step()
    assert result.image.shape == (180, 320, 3)
    with pytest.raises(ValueError, match="viewpoint"):
        loop.set("viewpoint", "moon")


def test_window_module_imports_without_moderngl_window():
    import importlib

    saved = {k: sys.modules.pop(k) for k in list(sys.modules) if k.startswith("moderngl_window")}
    try:
        sys.modules["moderngl_window"] = None          # import fails like an absent package
        import headplod.demo.window as window

        window = importlib.reload(window)
        assert window.action_for_key("1") == ("mode", "hybrid") and window.action_for_key("2") == ("mode", "change")
        assert window.run_window(argparse.Namespace(size=(64, 64))) == 1
    finally:
        sys.modules.pop("moderngl_window", None)
        sys.modules.update(saved)


@pytest.mark.slow
def test_window_runs_on_the_headless_backend():
    """The WindowConfig subclass on moderngl-window's headless (EGL) window: frames reach its framebuffer."""
    import weakref

    mglw = pytest.importorskip("moderngl_window")
    from headplod.demo.cli import add_demo_arguments
    from headplod.demo.window import make_window_class

    args = add_demo_arguments(argparse.ArgumentParser()).parse_args(["--mouse", "--size", "320,180"])
    try:
        wnd = mglw.get_local_window_cls("headless")(title="demo", size=(320, 180), gl_version=(3, 3),
                                                    backend="egl")
    except Exception as exc:
        pytest.skip(f"no headless moderngl-window context: {exc}")
    mglw.activate_context(window=wnd)
    config = make_window_class()(demo_args=args, ctx=wnd.ctx, wnd=wnd, timer=mglw.Timer())
    wnd._config = weakref.ref(config)
    config.on_mouse_position_event(40, 90, 0, 0)           # window px → screen px (x6 on a 1920 px screen)
    np.testing.assert_allclose(config.poses.poi_px, [240, 540])
    config.on_render(0.0, 1 / 30)
    config.on_render(1 / 30, 1 / 30)
    image = np.frombuffer(wnd.fbo.read(components=3), np.uint8).reshape(180, 320, 3)
    assert image.std() > 10 and config.loop.last.triangles > 2048
    config.on_close()


def test_prefetch_keeps_the_order_and_the_end():
    """Poses read ahead on a thread come out in order, and the end and errors come through."""
    from headplod.demo import loop as lp

    class Counting(lp.PoseSource):
        name = "counting"

        def __init__(self, n, fail_at=None):
            self.n, self.k, self.fail_at, self.closed = n, 0, fail_at, False

        def read(self):
            if self.k == self.fail_at:
                raise RuntimeError("camera gone")
            if self.k >= self.n:
                return None
            self.k += 1
            return lp.Pose(float(self.k), False, reason=f"pose {self.k}")

        def close(self):
            self.closed = True

    src = Counting(7)
    with lp.PrefetchPoses(src, depth=2) as pre:
        got = []
        while (pose := pre.read()) is not None:
            got.append(pose.t)
        assert pre.read() is None
    assert got == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0] and src.closed
    pre = lp.PrefetchPoses(Counting(5, fail_at=3))
    assert [pre.read().t for _ in range(3)] == [1.0, 2.0, 3.0]
    with pytest.raises(RuntimeError, match="camera gone"):
        pre.read()
    pre.close()


def test_tee_gives_every_consumer_every_pose_and_reads_each_once():
    """The interleaved headless runs share one tracked sequence: each run sees every pose, in order."""
    from headplod.demo import loop as lp

    class Counting(lp.PoseSource):
        name = "counting"

        def __init__(self, n):
            self.n, self.reads, self.closed = n, 0, 0

        def read(self):
            if self.reads >= self.n:
                return None
            self.reads += 1
            return lp.Pose(float(self.reads), False, reason="x")

        def close(self):
            self.closed += 1

    src = Counting(5)
    tee = lp.TeePoses(src, 3)
    a, b, c = (tee.consumer(k) for k in range(3))
    got = {0: [], 1: [], 2: []}
    for _ in range(2):                                   # uneven pace: a runs ahead, c lags
        got[0] += [a.read().t, a.read().t]
        got[1].append(b.read().t)
    while (p := c.read()) is not None:
        got[2].append(p.t)
    for k, consumer in ((0, a), (1, b)):
        while (p := consumer.read()) is not None:
            got[k].append(p.t)
    assert got[0] == got[1] == got[2] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert src.reads == 5                                # each pose read (tracked) once
    a.close()
    b.close()
    assert src.closed == 0
    c.close()
    c.close()
    assert src.closed == 1
    with pytest.raises(ValueError):
        tee.consumer(3)


@pytest.mark.slow
def test_loops_side_by_side_keep_their_own_mesh_state(terrain_scene, renderer, default_screen):
    """Two loops interleaved on one scene each rebuild only what their own selection changes."""
    fine = terrain_scene.mesh.share()
    coarse = terrain_scene.mesh.share()
    assert fine.vertex_positions is terrain_scene.mesh.vertex_positions          # the tables are shared
    n = terrain_scene.mesh.n_faces
    fine.update_indices(np.full(n, 3))
    coarse.update_indices(np.zeros(n, int))
    idx, lv = fine.update_indices(np.full(n, 3))
    assert fine.stats["rebuilt_faces"] == 0 and (lv == 3).all() and len(lv) == n * 4 ** 3
    idx0, lv0 = coarse.update_indices(np.zeros(n, int))
    assert coarse.stats["rebuilt_faces"] == 0 and len(lv0) == n


@pytest.mark.slow
def test_demo_loop_draws_raymask_frames_and_a_still_poi_repeats_them(gl_context):
    """The raymask back end in the demo's loop: a frame per pose, the mask about the filtered POI; a still POI, same frame."""
    from headplod.demo import loop as lp
    from headplod.render.still import TerrainScene

    screen = lp.default_screen()
    scene = TerrainScene.build(screen)
    poses = lp.MousePoses(screen, cov_deg2=np.diag([0.01, 0.01]))
    demo = lp.DemoLoop(scene, poses, size=(320, 180), backend="raymask", uncertainty="adaptive", hud=False)
    frames = [demo.step() for _ in range(4)]
    assert all(f is not None and f.image.shape == (180, 320, 3) for f in frames)
    assert frames[-1].stage_ms["render"] > 0           # (at 320x180 the inset covers the frame: no rings)
    np.testing.assert_array_equal(frames[-1].image, frames[-2].image)
    sky = np.array([0.62, 0.72, 0.82]) * 255
    assert np.abs(frames[-1].image.reshape(-1, 3) - sky).max(axis=1).min() < 2     # terrain and sky both drawn
    assert (np.abs(frames[-1].image.reshape(-1, 3) - sky).max(axis=1) > 20).mean() > 0.5
