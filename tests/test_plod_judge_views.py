"""headplod.bench.plod_judge_views: the comparison at equal triangles, the rings, the fixation geometry, the
pursuit path, the table and charts and ``bench plod --terrain`` need only numpy (and matplotlib); the judged
video and error map need the optional extra ``.[vdp]`` and skip without it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from headplod.bench import plod_judge as pj
from headplod.bench import plod_judge_views as pv
from headplod.render.still import default_head


def _curve(points):
    return [{"budget": int(t), "triangles": int(t), "jod": j} for t, j in points]


# --- The comparison -------------------------------------------------------------------------------------------


def test_margin_at_equal_triangles_is_against_the_best_geometric_curve_in_log_triangles():
    # sse rises 1 JOD per factor 4 (0.5 per doubling); dpv is lower below 200k and crosses above it.
    curves = {"sse": _curve([(1e5, 9.0), (4e5, 10.0)]),
              "dpv": _curve([(1e5, 8.0), (2e5, 9.5), (4e5, 10.2)]),
              "csf": _curve([(1e5, 9.3), (2e5, 9.6), (4e5, 10.3)])}
    c = pv.compare_curves(curves, "csf", budgets=(100_000, 200_000, 400_000))
    m = {r["budget"]: r for r in c["margins"]}
    assert m[100_000]["geometric_mode"] == "sse" and m[100_000]["margin"] == pytest.approx(0.3)
    # At 200k sse is interpolated halfway in log triangles (9.5), dpv measured 9.5: a tie, margin 0.1.
    assert m[200_000]["geometric_jod"] == pytest.approx(9.5) and m[200_000]["margin"] == pytest.approx(0.1)
    assert m[400_000]["geometric_mode"] == "dpv" and m[400_000]["margin"] == pytest.approx(0.1)
    assert c["min_margin"] == pytest.approx(0.1) and c["margin_met"] and c["met"]
    assert c["geometric"] == ["sse", "dpv"]
    # Another point between two measured ones: 141k is a quarter of sse's log range: 9.25.
    c2 = pv.compare_curves(curves, "csf", budgets=(141_421,))
    assert c2["margins"][0]["geometric_mode"] == "sse" and c2["margins"][0]["geometric_jod"] == pytest.approx(9.25)
    # The margin is short of the goal at one budget: not met.
    curves["csf"][1]["jod"] = 9.52
    c3 = pv.compare_curves(curves, "csf", budgets=(100_000, 200_000, 400_000))
    assert not c3["margin_met"] and c3["min_margin"] == pytest.approx(0.02)


def test_triangle_saving_at_equal_jod_inverts_the_geometric_curve():
    curves = {"sse": _curve([(1e5, 9.0), (2e5, 9.5), (4e5, 10.0)]),
              "csf": _curve([(1e5, 9.5), (2e5, 9.75), (4e5, 10.4)])}
    c = pv.compare_curves(curves, "csf", budgets=(100_000, 200_000, 400_000))
    s = {r["triangles"]: r for r in c["savings"]}
    # csf's 9.5 at 100k: sse needs 200k → 50 % fewer triangles.
    assert s[100_000]["geometric_triangles"] == pytest.approx(2e5) and s[100_000]["saving"] == pytest.approx(0.5)
    assert s[100_000]["bound"] is None
    # 9.75 at 200k: sse's 9.75 is halfway (in log) between 200k and 400k: 283k → 1 − 200/282.8.
    assert s[200_000]["geometric_triangles"] == pytest.approx(2e5 * math.sqrt(2), rel=1e-9)
    assert s[200_000]["saving"] == pytest.approx(1 - 1 / math.sqrt(2))
    # 10.4 at 400k: sse never reaches it; it would need more than its 400k: saving at least 0.
    assert s[400_000]["bound"] == "at_least" and s[400_000]["saving"] == pytest.approx(0.0)
    assert not c["saving_met"] and c["min_saving"] == pytest.approx(0.0)
    # A default below every geometric point: a geometric curve needs fewer than its first count (an upper bound).
    curves["csf"] = _curve([(1e5, 8.0), (4e5, 8.5)])
    c = pv.compare_curves(curves, "csf", budgets=(100_000,))
    assert c["savings"][0]["bound"] == "at_most" and c["savings"][0]["saving"] == pytest.approx(0.0)
    assert c["savings"][1]["saving"] == pytest.approx(-3.0)
    assert not c["met"]


def test_saving_goal_met_when_every_point_saves_a_quarter():
    curves = {"ipv": _curve([(1e5, 9.0), (2e5, 9.5), (4e5, 10.0)]),
              "change": _curve([(1e5, 9.25), (1.4e5, 9.5), (2.8e5, 10.0)])}
    c = pv.compare_curves(curves, "change", budgets=(100_000, 400_000))
    assert [r["bound"] for r in c["savings"]] == [None, None, None]
    np.testing.assert_allclose([r["saving"] for r in c["savings"]], [1 - 1 / math.sqrt(2), 0.3, 0.3])
    assert c["saving_met"] and c["met"]
    # 400k is beyond the default's 280k by more than the slack: its margin there is missing, so not "margin met".
    assert c["margins"][1]["margin"] is None and not c["margin_met"] and c["min_margin"] is None


def test_curve_ends_count_within_the_budget_slack_and_no_further():
    xs, ys = [98_000.0, 196_000.0, 392_000.0], [9.0, 9.5, 10.0]
    assert pv.interp_log(100_000, xs, ys) == pytest.approx(9.0 + 0.5 * math.log(100 / 98) / math.log(2))
    assert pv.interp_log(400_000, xs, ys) == pytest.approx(10.0)          # 2 % beyond the last point: its value
    assert pv.interp_log(420_000, xs, ys) is None                          # 7 % beyond: no value
    assert pv.interp_log(90_000, xs, ys, slack=0.05) is None
    assert pv.first_crossing_log(9.5, xs, ys) == (pytest.approx(196_000.0), "crossed")
    # Not monotonic: the first crossing counts.
    assert pv.first_crossing_log(9.4, [1.0, 2.0, 4.0, 8.0], [9.0, 9.8, 9.2, 9.9])[0] == pytest.approx(2 ** 0.5)
    assert pv.first_crossing_log(11.0, xs, ys) == (None, "beyond")
    assert pv.first_crossing_log(8.0, xs, ys) == (None, "below")
    assert pv.compare_curves({"csf": _curve([(1e5, 9.0)])}, "csf") is None        # nothing geometric to compare


def test_foveation_goal_needs_the_default_to_drop_and_more_than_sse():
    assert pv.foveation_goal({"csf": {"drop": 0.2}, "sse": {"drop": 0.01}}, "csf") is True
    assert pv.foveation_goal({"csf": {"drop": 0.2}, "sse": {"drop": 0.3}}, "csf") is False
    # Both rise when the fixation moves away: the default's JOD is not lowered, whatever sse does.
    assert pv.foveation_goal({"csf": {"drop": -0.08}, "sse": {"drop": -0.14}}, "csf") is False
    assert pv.foveation_goal({"csf": {"drop": 0.2}}, "csf") is None
    assert pv.foveation_goal({"sse": {"drop": 0.2}}, "sse") is None


def test_default_modes_put_the_configured_default_first_once():
    from headplod.plod.select import SelectorConfig

    modes = pv.default_modes()
    assert modes[0] == SelectorConfig().mode and len(modes) == len(set(modes))
    assert {"sse", "dpv", "ipv"} <= set(modes)
    assert pv.default_modes("change")[:4] == ["change", "sse", "dpv", "ipv"]
    assert pv._settings_for("change[cortical]", {"change": {"csf_model": "x"}}) == {"csf_model": "x"}
    assert pv._settings_for("change[a]", {"change[a]": {"a": 1}, "change": {"b": 2}}) == {"a": 1}
    assert pv._mode("change[cortical]") == "change"


# --- Geometry: eccentricity, the moved fixation, rings, the pursuit ----------------------------------------------


@pytest.fixture(scope="module")
def display(default_screen):
    return pj.display_geometry(default_screen, default_head(default_screen), (1280, 720))


def test_fixation_moved_20_degrees_is_d_tan_20_on_the_screen(default_screen, display):
    poi = np.array(default_screen.size_px, dtype=float) / 2
    fix = pj.fixation_px(default_screen, poi, (1280, 720))
    moved = pv.moved_fixation_px(display, fix, 20.0)
    # The screen's centre, 600 mm away on its normal: 20° is 600 tan 20° = 218.4 mm to the left, at 1280 px per
    # 531.4 mm; the row stays.
    assert moved[1] == fix[1]
    assert fix[0] - moved[0] == pytest.approx(600 * math.tan(math.radians(20)) / 531.4 * 1280, rel=1e-3)
    # The angle at the eye between the two points on the screen (world mm), from the screen's own geometry.
    head = default_head(default_screen)
    to = [default_screen.pixel_to_world((p + 0.5) * np.array(default_screen.size_px) / (1280, 720)) - head
          for p in (fix, moved)]
    angle = math.degrees(math.acos(to[0] @ to[1] / np.linalg.norm(to[0]) / np.linalg.norm(to[1])))
    assert angle == pytest.approx(20.0, abs=0.05)
    assert pv.eccentricity_deg(display, moved, fix[0] + 0.5, fix[1] + 0.5) == pytest.approx(20.0, abs=1e-9)
    # Near the left edge the fixation moves right instead, still 20° in the metric's terms.
    left = np.array([100.0, 200.0])
    right = pv.moved_fixation_px(display, left, 20.0)
    assert right[0] > left[0] and pv.eccentricity_deg(display, right, 100.5, 200.5) == pytest.approx(20.0)
    with pytest.raises(ValueError, match="no point"):
        pv.moved_fixation_px(display, fix, 80.0)


def test_eccentricity_is_the_metrics_angle_difference(display):
    fix = np.array([639.5, 359.5])                                   # the image's centre
    ecc = pv.eccentricity_deg(display, fix)
    assert ecc.shape == (720, 1280)
    assert ecc[359:361, 639:641].max() < 0.05                        # the four pixels about the centre
    d_px = 600 * math.tan(math.radians(10)) / 531.4 * 1280
    assert pv.eccentricity_deg(display, fix, 640 + d_px, 360.0) == pytest.approx(10.0, abs=1e-6)
    assert pv.eccentricity_deg(display, fix, 640.0, 360 - 600 * math.tan(math.radians(5)) / 298.9 * 720) == \
        pytest.approx(5.0, abs=1e-6)
    assert ecc.max() == pytest.approx(math.hypot(math.degrees(math.atan(265.7 / 600)),
                                                 math.degrees(math.atan(149.45 / 600))), abs=0.05)


def test_rings_average_a_synthetic_heatmap(display):
    fix = np.array([639.5, 359.5])
    ecc = pv.eccentricity_deg(display, fix)
    # The map is the ring's index + 1 (1 within 2°, 2 in 2-5°, ...): each ring's mean is its value.
    edges = np.array(pv.RINGS_DEG)
    heat = np.digitize(ecc, edges).astype(np.float32)
    r = pv.ring_reduce(heat, ecc)
    assert r["edges_deg"] == list(pv.RINGS_DEG)
    assert r["mean"][:4] == pytest.approx([1.0, 2.0, 3.0, 4.0])
    assert r["mean"][4] == pytest.approx(5.0)                           # 20-40°: the screen's corners reach 27°
    assert sum(r["pixels"]) + r["outside_pixels"] == 1280 * 720 and r["outside_pixels"] == 0
    assert sum(r["share"]) == pytest.approx(1.0)
    # An error only within 2° of the fixation: all of it in the first ring.
    only = pv.ring_reduce(np.where(ecc < 2, 0.5, 0.0), ecc)
    assert only["mean"][0] == pytest.approx(0.5) and only["mean"][1:] == [0.0] * 4
    assert only["share"] == pytest.approx([1.0, 0, 0, 0, 0])
    # The first ring's pixels: a disc of 2° (about 25 px/deg), so about π (2 · 25.2)² pixels.
    assert r["pixels"][0] == pytest.approx(math.pi * (2 * display.px_per_deg) ** 2, rel=0.02)
    # Rings no pixel reaches, and a map with no error at all.
    empty = pv.ring_reduce(np.zeros_like(ecc), ecc, edges=(0, 2, 50, 60))
    assert empty["mean"][2] is None and empty["share"] == [None, None, None]
    with pytest.raises(ValueError, match="same shape"):
        pv.ring_reduce(heat[:-1], ecc)
    with pytest.raises(ValueError, match="ascending"):
        pv.ring_reduce(heat, ecc, edges=(0, 5, 2))


def test_pursuit_path_moves_at_the_set_angular_speed_with_one_saccade(default_screen, display):
    p = pv.Pursuit(frames=30, fps=60, speed_deg_s=10.0, saccade_deg=5.0, saccade_frame=20)
    path = pv.pursuit_path_px(default_screen, display, p)
    assert path.shape == (30, 2)
    assert np.all(path[:, 1] == default_screen.size_px[1] / 2)
    # The metric's horizontal angle of each POI, from the screen px through the image px.
    fix = np.stack([pj.fixation_px(default_screen, q, (1280, 720)) for q in path])
    angle = pv._view_angles_deg(display, fix[:, 0] + 0.5, fix[:, 1] + 0.5)[:, 0]
    step = np.diff(angle)
    np.testing.assert_allclose(np.delete(step, 19), 10.0 / 60, atol=1e-9)
    assert step[19] == pytest.approx(10.0 / 60 + 5.0)
    assert angle[0] == pytest.approx(-angle[-1])                        # centred on the screen
    with pytest.raises(ValueError):
        pv.Pursuit(frames=10, saccade_frame=10)
    no_saccade = pv.pursuit_path_px(default_screen, display, pv.Pursuit(frames=5, saccade_frame=None))
    assert no_saccade[2, 0] == pytest.approx(default_screen.size_px[0] / 2)


# --- Output and the command line ----------------------------------------------------------------------------------


def _report():
    curves = {"csf": _curve([(1e5, 9.2), (2e5, 9.5), (4e5, 9.8)]),
              "sse": _curve([(1e5, 9.0), (2e5, 9.6), (4e5, 9.9)])}
    for pts in curves.values():
        for p in pts:
            p.update(frame_ms=20.0, render_ms=15.0, budget_bias=0.0, seconds=1.0)
    rings = {n: {"jod": 9.5, **pv.ring_reduce(np.arange(12.0).reshape(3, 4), np.arange(12.0).reshape(3, 4) * 3)}
             for n in curves}
    view = {"full_triangles": 2_097_152, "full_frame_ms": 200.0, "curves": curves,
            "comparison": pv.compare_curves(curves, "csf", budgets=(100_000, 200_000, 400_000)),
            "moved_fixation": {"deg": 20.0, "fixation_px": [114.0, 359.5], "budget": 200_000, "goal_met": True,
                               "modes": {"csf": {"jod": 9.5, "jod_moved": 9.2, "drop": 0.3},
                                         "sse": {"jod": 9.6, "jod_moved": 9.55, "drop": 0.05}}},
            "rings": {"budget": 200_000, "modes": rings},
            "pursuit": {"budget": 200_000, "settings": {"frames": 30, "fps": 60.0, "speed_deg_s": 10.0,
                                                        "saccade_deg": 5.0, "saccade_frame": 20},
                        "modes": {"csf": {"jod": 9.4}, "sse": {"jod": 9.5}}}}
    return {"metric": "fvvdp", "default": "csf", "modes": ["csf", "sse"], "budgets": [100_000, 200_000, 400_000],
            "seconds_per_jod": 1.0, "px_per_deg": 25.2, "display": {"width_m": 0.53, "height_m": 0.3,
                                                                    "distance_m": 0.6},
            "views": {"default": view, "plains": view}}


@pytest.mark.slow
def test_table_and_charts_of_a_synthetic_report(tmp_path):
    report = _report()
    text = pv.views_table(report)
    assert "default (full: 2,097,152 triangles" in text and "plains" in text
    assert "100k +0.200 (sse)" in text and "200k -0.100 (sse)" in text and "[NOT MET] margin" in text
    assert "csf drops +0.300" in text and "[met] the default drops, and more than sse" in text
    assert "saccade 5° at frame 20" in text and "csf 9.400" in text
    paths = pv.views_charts(report, tmp_path)
    assert [p.name for p in paths] == ["plod_jod_view_default.png", "plod_jod_view_plains.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_bench_plod_terrain_is_checked_before_the_run(monkeypatch, capsys, tmp_path):
    from headplod.bench import plod
    from headplod.cli import main

    monkeypatch.setattr(plod, "BenchScene", lambda *a, **k: pytest.fail("the bench ran"))
    monkeypatch.setattr(pj, "vdp_available", lambda metric="fvvdp": True)
    assert main(["bench", "plod", "--only", "judge", "--terrain", str(tmp_path / "missing.tif")]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "junk.tif").write_bytes(b"not a tiff")
    assert main(["bench", "plod", "--vdp", "--terrain", str(tmp_path / "junk.tif")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("headplod: --terrain") and "GeoTIFF" in err[-1]
    # The judge's terrain only: without --vdp or --only judge, or with another part, it is refused unread.
    for argv in (["bench", "plod", "--terrain", str(tmp_path / "junk.tif")],
                 ["bench", "plod", "--only", "raymask", "--vdp", "--terrain", str(tmp_path / "junk.tif")]):
        assert main(argv) == 2
        assert "--vdp or --only judge" in capsys.readouterr().err
    # A good file reaches the bench with its terrain.
    heights = np.add.outer(np.linspace(0, 50, 40), np.linspace(0, 30, 48))
    np.save(tmp_path / "dem.npy", heights)
    seen = {}
    monkeypatch.setattr(plod, "run_plod_bench", lambda **kw: seen.update(kw) or 0)
    assert main(["bench", "plod", "--only", "judge", "--terrain", str(tmp_path / "dem.npy"), "--spacing-m", "30"]) == 0
    assert seen["only"] == "judge" and seen["terrain_label"] == str(tmp_path / "dem.npy")
    assert seen["terrain"].dem_z_m.shape == (40, 48)


def test_run_plod_bench_refuses_a_terrain_without_the_judge(monkeypatch, capsys):
    from headplod.bench import plod

    monkeypatch.setattr(plod, "BenchScene", lambda *a, **k: pytest.fail("the bench ran"))
    assert plod.run_plod_bench(terrain=object()) == 2
    assert "--vdp or --only judge" in capsys.readouterr().err


# --- With the optional extra --------------------------------------------------------------------------------------


def _picture(h=180, w=320):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    base = 0.5 + 0.25 * np.sin(2 * np.pi * xx / 40.0) * np.cos(2 * np.pi * yy / 50.0)
    return np.clip(np.round(np.stack([base, 0.8 * base + 0.1, 0.6 * base + 0.2], -1) * 255), 0, 255).astype(np.uint8)


@pytest.mark.slow
def test_video_judge_follows_the_per_frame_fixation_and_maps_the_error(default_screen):
    if not pj.vdp_available("fvvdp"):
        pytest.skip("the optional extra .[vdp] (torch, pyfvvdp) is not installed")
    small = pj.display_geometry(default_screen, default_head(default_screen), (320, 180))
    ref = np.stack([_picture()] * 4)
    test = ref.copy()
    rng = np.random.default_rng(5)
    spots = [(40, 30), (100, 60), (160, 90), (220, 120)]          # a noisy patch moving across the frames
    for f, (x, y) in enumerate(spots):
        patch = test[f, y - 15:y + 15, x - 15:x + 15].astype(np.int16) + rng.integers(-40, 41, (30, 30, 3))
        test[f, y - 15:y + 15, x - 15:x + 15] = np.clip(patch, 0, 255).astype(np.uint8)
    judge = pj.Judge(small)
    # At 20 Hz (a shorter temporal filter than 60 Hz's: a faster test).
    following = judge.jod_video(ref, test, np.array(spots, dtype=float) - 0.5, fps=20.0)
    away = judge.jod_video(ref, test, np.tile([300.0, 10.0], (4, 1)), fps=20.0)
    assert following < away - 0.05, (following, away)
    with pytest.raises(ValueError, match="fixations"):
        judge.jod_video(ref, test, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="heatmap='raw'"):
        judge.jod_error_map(ref[0], test[0], (39.5, 29.5))
    with pytest.raises(ValueError, match="heatmap must be"):
        pj.Judge(small, heatmap="threshold")
    q, err = pj.Judge(small, heatmap="raw").jod_error_map(ref[0], test[0], (39.5, 29.5))
    assert q == pytest.approx(judge.jod(ref[0], test[0], (39.5, 29.5)), abs=1e-4)
    assert err.shape == (180, 320) and err.dtype == np.float32
    ecc = pv.eccentricity_deg(small, (39.5, 29.5))
    rings = pv.ring_reduce(err, ecc)
    # The patch sits at the fixation: the first ring holds the largest mean difference.
    assert rings["mean"][0] > 10 * max(m for m in rings["mean"][2:] if m is not None)
