"""headplod.bench.harness: the benches' frames are the demo's frames (issue 23)."""
import re
from pathlib import Path

import numpy as np
import pytest

from headplod.bench import harness
from headplod.bench.harness import (FRAME_DT_S, FRAME_STAGES, TRACKER_COV_DEG2, BenchScene, alternate, poi_disc,
                                    run_views, steady_stats)
from headplod.demo import loop as lp
from headplod.plod.view import View
from headplod.render import TerrainRenderer
from headplod.render.frame import FrameOutput

SMALL = (320, 180)


@pytest.fixture(scope="module")
def bench(gl_context, terrain_scene):
    b = BenchScene(SMALL, scene=terrain_scene, ctx=gl_context)
    yield b
    b.release()


def _demo(bench, path, viewpoint="mountains", **options):
    """A headless demo loop on the bench's scene and eye, the POI along ``path`` (N, 2) screen px at 60 Hz."""
    poses = lp.MousePoses(bench.screen, path=np.asarray(path, float), eye_mm=bench.head, cov_deg2=TRACKER_COV_DEG2,
                          fps=1 / FRAME_DT_S)
    return lp.DemoLoop(bench.scene, poses, TerrainRenderer(bench.ctx, size=SMALL), viewpoint=viewpoint, hud=False,
                       **options)


def _frames(loop):
    out = []
    while (r := loop.step()) is not None:
        out.append(r)
    loop.renderer.release()
    return out


@pytest.mark.slow
def test_the_steady_frame_is_the_demos_frame_of_the_still_pose(bench):
    loop = _demo(bench, [bench.poi] * bench.frames, mode="csf", uncertainty="adaptive")
    demo = _frames(loop)
    frame, stats = bench.steady(bench.mesh_step("csf", scene=loop.scene), model=loop.scene.model)
    last = demo[-1]
    assert stats["triangles"] == frame.triangles == last.triangles > 10_000
    np.testing.assert_array_equal(frame.levels, last.levels)
    np.testing.assert_array_equal(frame.image, last.image)
    assert sum(stats["triangles_per_level"]) == stats["triangles"]
    assert stats["frame_ms"] == pytest.approx(sum(stats[f"{s}_ms"] for s in FRAME_STAGES))


@pytest.mark.slow
def test_run_views_gives_the_demos_levels_on_a_moving_poi(bench):
    """A POI sweeping across the screen, then a jump (a saccade: the demo keeps its last levels)."""
    path = [bench.poi + [30.0 * k, 0.0] for k in range(6)] + [bench.poi + [-600.0, 200.0]] * 2
    loop = _demo(bench, path, mode="csf", uncertainty="fixed", selector_options={"hysteresis": False})
    demo = _frames(loop)
    views = [View(bench.head, p, TRACKER_COV_DEG2, k * FRAME_DT_S) for k, p in enumerate(path)]
    ours = run_views(bench.mesh_step("csf", "fixed", scene=loop.scene, hysteresis=False), views, loop.scene.model,
                     images=False)
    assert [o.triangles for o in ours] == [d.triangles for d in demo]
    assert [o.held for o in ours] == [d.saccade_skipped for d in demo]
    assert ours[6].held and len({o.triangles for o in ours[:6]}) > 1
    for o, d in zip(ours, demo):
        np.testing.assert_array_equal(o.levels, d.levels)
        assert o.image is None


@pytest.mark.slow
def test_alternate_leaves_out_the_warm_up_round_and_keeps_only_the_last_images(bench):
    renderers = [TerrainRenderer(bench.ctx, size=SMALL) for _ in range(2)]
    try:
        steps = {m: bench.mesh_step(m, renderer=r) for m, r in zip(("csf", "sse"), renderers)}
        timed, last = alternate(steps, bench.view_at(), bench.scene.model, rounds=2, repeats=2)
        alone, _ = bench.steady(bench.mesh_step("sse"))
    finally:
        for r in renderers:
            r.release()
    assert {m: [len(r) for r in t] for m, t in timed.items()} == {"csf": [2, 2], "sse": [2, 2]}
    assert all(f.image is None for t in timed.values() for r in t for f in r if f is not last["csf"]
               and f is not last["sse"])
    # Two steps in turn, each on its own renderer, draw what one step alone draws.
    np.testing.assert_array_equal(last["sse"].image, alone.image)
    assert timed["csf"][-1][-1] is last["csf"] and last["csf"].triangles < last["sse"].triangles


def test_steady_stats_are_medians_after_the_first_frame():
    def out(ms, tris):
        stage = {"select": ms, "build": 2 * ms, "upload": 0.5, "render": 10 * ms, "readback": 1.0}
        return FrameOutput(None, None, None, np.zeros(tris, np.uint8), tris, False, stage)

    stats = steady_stats([out(100.0, 5), out(1.0, 6), out(3.0, 6), out(2.0, 6)], levels=3)
    assert stats["select_ms"] == 2.0 and stats["render_ms"] == 20.0 and stats["readback_ms"] == 1.0
    assert stats["frame_ms"] == pytest.approx(2.0 + 4.0 + 0.5 + 20.0)            # the read-back apart
    assert stats["triangles"] == 6 and stats["triangles_per_level"] == [6, 0, 0]


def test_the_disc_is_about_pixel_centres():
    disc = poi_disc((4, 4), (2.0, 2.0), 0.8)            # the corner shared by pixels (1, 1) … (2, 2)
    assert np.argwhere(disc).tolist() == [[1, 1], [1, 2], [2, 1], [2, 2]]


@pytest.mark.slow
def test_the_benches_take_the_one_tracker_covariance(bench):
    np.testing.assert_array_equal(TRACKER_COV_DEG2, np.diag([0.05 ** 2] * 2))
    assert not TRACKER_COV_DEG2.flags.writeable
    assert bench.view().cov_deg2 is TRACKER_COV_DEG2 and bench.view(cov_deg2=None).cov_deg2 is None
    # No bench module on the harness writes the covariance again.
    literal = re.compile(r"np\.diag\(\s*\[\s*0\.05\s*\*\*\s*2")
    folder = Path(harness.__file__).parent
    users = [p for p in folder.glob("*.py") if "from .harness import" in p.read_text()]
    assert len(users) >= 6
    assert [p.name for p in users if literal.search(p.read_text())] == []
    # Nor do the scale, lazy-mesh and quadtree benches, the selector they share, or their tests.
    tests = Path(__file__).parent
    others = [folder / f"{name}.py" for name in ("plod_scale", "plod_lazy", "plod_quadtree", "quadtree_selector")]
    others += [tests / f"test_{name}.py" for name in ("bench_scale", "quadtree", "lazy_mesh", "lazy_viewer")]
    assert [p.name for p in others if literal.search(p.read_text())] == []
