"""Temporal stability of the PLOD level selection: a still head through the real tracker.

The issue: "a still head fed through the real tracker on synthetic noisy
frames: level changes per frame after the first 10 frames for none, fixed,
adaptive and smoothed adaptive; the fixed and smoothed modes reach zero."
"""
import numpy as np
import pytest

from headplod.plod.select import View
from headplod.bench.stability import level_changes, levels_sequence, plot_stability, stability_report, still_head_views
from headplod.render import TerrainRenderer
from headplod.render.still import TerrainScene
from raw_views import RawViews

FRAMES = 40
WARMUP = 10


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    """(tracked views, truth views, scene) of 40 static frames at 600 mm; the scene is built once."""
    root = tmp_path_factory.mktemp("stability")
    tracked, truth, screen = still_head_views(FRAMES, 600.0, seed=0, root=root)
    return tracked, truth, TerrainScene.build(screen)


@pytest.fixture(scope="module")
def renderer(gl_context):
    """What the frame steps draw on: small (the levels do not depend on the image's size)."""
    r = TerrainRenderer(gl_context, size=(160, 90))
    yield r
    r.release()


@pytest.mark.slow
def test_the_tracker_sees_a_still_head(still):
    tracked, truth, scene = still
    assert len(tracked) == FRAMES and tracked.lost == 0
    poi = np.array([v.poi_px for v in tracked])
    true_poi = np.array([v.poi_px for v in truth])
    assert np.all(np.abs(poi - true_poi) < 15.0)          # the real tracker, not the truth
    assert np.ptp(poi, axis=0).max() > 0.1                 # with noise
    assert all(v.cov_deg2 is not None and np.trace(v.cov_deg2) > 0 for v in tracked)


@pytest.mark.slow
@pytest.mark.parametrize("uncertainty", ["fixed", "smoothed"])
def test_fixed_and_smoothed_reach_zero_changes_with_hysteresis(still, renderer, uncertainty):
    tracked, _, scene = still
    result = level_changes(scene, tracked, "csf", uncertainty, hysteresis=True, warmup=WARMUP, renderer=renderer)
    assert len(result["changes_per_frame"]) == FRAMES - WARMUP
    assert result["changes_per_frame"] == [0] * (FRAMES - WARMUP), result


@pytest.mark.slow
def test_the_truth_driven_reference_is_still(still, renderer):
    _, truth, scene = still
    # The true pose does not move: without uncertainty nothing may change even without hysteresis.
    assert level_changes(scene, truth, "csf", "none", hysteresis=False, warmup=WARMUP,
                         renderer=renderer)["max_changes"] == 0
    # The per-frame covariance still varies a little (it is the tracker's): hysteresis absorbs it.
    assert level_changes(scene, truth, "csf", "adaptive", hysteresis=True, warmup=WARMUP,
                         renderer=renderer)["max_changes"] == 0


def _still_then_jump(still, renderer, uncertainty, jump_px=300.0):
    """Levels of the last still frame, of the frame after a POI jump, its features, and a fresh selection."""
    tracked, _, scene = still
    selector = RawViews(scene.selector("csf", uncertainty, hysteresis=True))
    levels = [selector.select(view)[0] for view in tracked]
    last = tracked[-1]
    moved = View(last.eye_mm, np.asarray(last.poi_px) + [jump_px, 0.0], last.cov_deg2,
                 last.t + (last.t - tracked[-2].t))
    after, info = selector.select(moved)
    fresh = levels_sequence(scene, [moved], "csf", uncertainty, hysteresis=False, renderer=renderer)[0]
    return levels[-1], after, info, fresh


@pytest.mark.slow
@pytest.mark.parametrize("uncertainty", ["fixed", "smoothed"])
def test_levels_still_follow_a_real_movement(still, renderer, uncertainty):
    """The zero above is not a frozen selector: a 300 px POI jump changes levels in the same frame."""
    before, after, info, _ = _still_then_jump(still, renderer, uncertainty)
    changed = np.count_nonzero(after != before)
    assert changed >= 100, changed
    # The detail follows the POI: the triangle nearest the new POI is among the finest.
    nearest = np.nanargmin(info["eccentricity_deg"])      # NaN: outside the view
    assert after[nearest] == after.max() > before[nearest]


@pytest.mark.slow
def test_after_a_real_movement_levels_match_a_fresh_selection(still, renderer):
    _, after, _, fresh = _still_then_jump(still, renderer, "smoothed")
    assert np.count_nonzero(after != fresh) <= 0.02 * len(after)


@pytest.mark.slow
def test_report_and_chart(still, renderer, tmp_path):
    tracked, truth, scene = still
    report = stability_report(scene, frames=FRAMES, uncertainties=("adaptive", "smoothed"),
                              views=(tracked, truth), warmup=WARMUP, renderer=renderer)
    assert [(r["hysteresis"], r["uncertainty"]) for r in report["runs"]] == [
        (True, "adaptive"), (True, "smoothed"), (False, "adaptive"), (False, "smoothed")]
    for run in report["runs"]:
        assert {"changes_per_frame", "mean_changes", "max_changes", "frames_with_changes", "triangles",
                "differs_from_truth"} <= set(run)
        assert run["triangles"] > scene.mesh.n_faces
        assert 0 <= run["differs_from_truth"] <= 0.05 * scene.mesh.n_faces
    path = plot_stability(report, tmp_path / "stability.png")
    assert path.exists() and path.stat().st_size > 10_000


def test_bench_stability_refuses_an_unknown_mode_before_it_runs(monkeypatch, capsys):
    from headplod.bench import stability
    from headplod.cli import main

    monkeypatch.setattr(stability, "stability_report", lambda *a, **k: pytest.fail("the report ran"))
    assert main(["bench", "stability", "--modes", "csf,bogus"]) == 2
    assert "unknown mode 'bogus'" in capsys.readouterr().err


def test_bench_stability_refuses_too_few_frames_before_it_runs(monkeypatch, capsys):
    """--frames 8 used to crash (max() of an empty sequence): every frame lay in the warm-up."""
    from headplod.bench import stability
    from headplod.cli import main

    monkeypatch.setattr(stability, "stability_report", lambda *a, **k: pytest.fail("the report ran"))
    assert main(["bench", "stability", "--frames", "8"]) == 2
    err = capsys.readouterr().err
    assert "leaves no frame to count" in err and len(err.strip().splitlines()) == 1
