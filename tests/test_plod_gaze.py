"""headplod/bench/plod_gaze.py without FovVideoVDP or GL: where the true gaze meets the screen, the eye offsets
drawn for it, what a case's report shows (:func:`case_summary`), the goals' verdicts and the case sets.

Ground truth: the geometry against angles computed here from the screen's corners and
:meth:`Screen.pixel_to_world`; the summaries and verdicts against hand-made reports whose JODs were chosen so
that each quantity has one right value (per-fixation differences that differ from differences of means, a best
geometric mode that changes with the budget, triangles a little off the budgets).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from calib import CALIB_DIR, DEFAULT_SCREEN
from headplod import io
from headplod.bench import plod_gaze as pg
from headplod.bench.plod_judge_views import VIEWS
from headplod.plod.perception import view_offsets_deg
from headplod.plod.view import default_head, head_axes

# Angles from atan/acos of a few products of O(10³) mm vectors: rounding is ~1e-12 rad; 1e-7 deg is far above
# it and far below any error in the formulas (a wrong sign or axis is degrees).
ANGLE_TOL_DEG = 1e-7
# Screen px from a 3x2 least-squares solve over O(10³) mm: ~1e-9 px of rounding.
PX_TOL = 1e-6
# JOD arithmetic on a few values of order 10: rounding only.
JOD_TOL = 1e-12


@pytest.fixture(scope="module")
def desk():
    screen = io.read_screen(DEFAULT_SCREEN)
    return screen, default_head(screen)


@pytest.fixture(scope="module")
def wide():
    screen = io.read_screen(CALIB_DIR / "screen_wide.yaml")
    return screen, default_head(screen)


def _angle_deg(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b)))


def _centre(screen) -> np.ndarray:
    return np.array(screen.size_px, dtype=np.float64) / 2


# ---------------------------------------------------------------------------
# gaze_point_px
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("poi", [None, (300.0, 200.0), (1700.0, 950.0)], ids=["centre", "top-left", "bottom-right"])
def test_no_offset_is_the_poi(desk, poi):
    screen, eye = desk
    poi = _centre(screen) if poi is None else np.array(poi)
    np.testing.assert_allclose(pg.gaze_point_px(screen, eye, poi, (0.0, 0.0)), poi, atol=PX_TOL)


@pytest.mark.parametrize("h_deg", [3.0, 15.0, -15.0, 30.0])
def test_a_horizontal_offset_moves_along_the_row_to_the_right(desk, h_deg):
    """From the centre's normal the head frame's Ξ lies in the screen's rows: a horizontal offset keeps y and
    moves x by D tan(h) mm (D the eye's distance), right for h > 0."""
    screen, eye = desk
    centre = _centre(screen)
    p = pg.gaze_point_px(screen, eye, centre, (h_deg, 0.0))
    distance_mm = np.linalg.norm(screen.pixel_to_world(centre) - eye)
    px_per_mm = screen.size_px[0] / np.linalg.norm(screen.top_right - screen.top_left)
    assert p[1] == pytest.approx(centre[1], abs=PX_TOL)
    assert np.sign(p[0] - centre[0]) == np.sign(h_deg)
    assert p[0] - centre[0] == pytest.approx(distance_mm * math.tan(math.radians(h_deg)) * px_per_mm, abs=PX_TOL)


@pytest.mark.parametrize("v_deg", [5.0, -5.0, 12.0])
def test_a_positive_vertical_offset_moves_up(desk, v_deg):
    screen, eye = desk
    centre = _centre(screen)
    p = pg.gaze_point_px(screen, eye, centre, (0.0, v_deg))
    distance_mm = np.linalg.norm(screen.pixel_to_world(centre) - eye)
    px_per_mm = screen.size_px[1] / np.linalg.norm(screen.bottom_left - screen.top_left)
    assert p[0] == pytest.approx(centre[0], abs=PX_TOL)
    assert np.sign(centre[1] - p[1]) == np.sign(v_deg)          # screen y grows downward
    assert centre[1] - p[1] == pytest.approx(distance_mm * math.tan(math.radians(v_deg)) * px_per_mm, abs=PX_TOL)


@pytest.mark.parametrize("poi", [(960.0, 540.0), (250.0, 800.0), (1600.0, 120.0)])
@pytest.mark.parametrize("offset", [(10.0, 0.0), (-20.0, 0.0), (0.0, 8.0), (12.0, -7.0), (-5.0, 9.0)])
def test_the_gaze_is_the_offset_away_from_the_head_direction(desk, poi, offset):
    """In 3-D: the angle between eye→POI and eye→gaze point is atan(hypot(tan h, tan v)) (exactly |h| for a
    pure horizontal offset), and its components in the head frame are (h, v) with v up (−Ψ), as
    view_offsets_deg measures them, from any POI (not only the centre)."""
    screen, eye = desk
    h, v = offset
    p = pg.gaze_point_px(screen, eye, np.array(poi), offset)
    head = screen.pixel_to_world(np.array(poi)) - eye
    gaze = screen.pixel_to_world(p) - eye
    expected = math.degrees(math.atan(math.hypot(math.tan(math.radians(h)), math.tan(math.radians(v)))))
    assert _angle_deg(head, gaze) == pytest.approx(expected, abs=ANGLE_TOL_DEG)
    if v == 0.0:
        assert _angle_deg(head, gaze) == pytest.approx(abs(h), abs=ANGLE_TOL_DEG)
    phi, theta = view_offsets_deg(screen.pixel_to_world(p), eye, head_axes(screen, eye, np.array(poi)))
    assert theta == pytest.approx(h, abs=ANGLE_TOL_DEG)
    assert phi == pytest.approx(-v, abs=ANGLE_TOL_DEG)


@pytest.mark.parametrize("offset", [(90.0, 0.0), (0.0, 90.0), (-90.0, 0.0), (89.99, 0.0), (0.0, -89.99)])
def test_a_right_angle_offset_misses_the_screen(desk, offset):
    """At 90° the gaze runs along the screen plane (None); just short of it, it meets the plane far outside the
    screen: either way no point on the screen."""
    screen, eye = desk
    p = pg.gaze_point_px(screen, eye, _centre(screen), offset)
    w, h = screen.size_px
    assert p is None or not (0 <= p[0] <= w and 0 <= p[1] <= h)
    if abs(offset[0]) == 90.0 or abs(offset[1]) == 90.0:
        assert p is None


# ---------------------------------------------------------------------------
# screen_half_extent_deg
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("which", ["desk", "wide"])
def test_half_extents_from_the_centres_normal(which, request):
    """On the centre's normal at distance D, the screen's full horizontal angle is 2 atan(W / 2D): half of it is
    atan(W / 2D) (and so vertically with H)."""
    screen, eye = request.getfixturevalue(which)
    width_mm = np.linalg.norm(screen.top_right - screen.top_left)
    height_mm = np.linalg.norm(screen.bottom_left - screen.top_left)
    distance_mm = np.linalg.norm(screen.pixel_to_world(_centre(screen)) - eye)
    assert distance_mm == pytest.approx(600.0)
    half_h, half_v = pg.screen_half_extent_deg(screen, eye)
    assert half_h == pytest.approx(0.5 * 2 * math.degrees(math.atan(width_mm / 2 / distance_mm)), abs=ANGLE_TOL_DEG)
    assert half_v == pytest.approx(0.5 * 2 * math.degrees(math.atan(height_mm / 2 / distance_mm)), abs=ANGLE_TOL_DEG)


# ---------------------------------------------------------------------------
# eye_offsets_deg
# ---------------------------------------------------------------------------

@pytest.mark.slow
def test_eye_offsets_are_seeded_and_land_on_the_screen(desk, wide):
    for screen, eye in (desk, wide):
        a = pg.eye_offsets_deg(screen, eye, 40, seed=3)
        assert a.shape == (40, 2) and a.dtype == np.float64 and np.isfinite(a).all()
        np.testing.assert_array_equal(a, pg.eye_offsets_deg(screen, eye, 40, seed=3))
        assert not np.array_equal(a, pg.eye_offsets_deg(screen, eye, 40, seed=4))
        w, h = screen.size_px
        for off in a:
            p = pg.gaze_point_px(screen, eye, _centre(screen), off)
            assert p is not None and 0 <= p[0] <= w and 0 <= p[1] <= h


def test_the_wide_screen_draws_wider_horizontal_offsets(desk, wide):
    """The viewer looks about the whole screen: the 32:9 one spreads the eyes further horizontally."""
    rms = [float(np.sqrt(np.mean(pg.eye_offsets_deg(s, e, 50, seed=0)[:, 0] ** 2))) for s, e in (desk, wide)]
    assert rms[1] > 1.3 * rms[0]


@pytest.mark.parametrize("n", [1, 7])
def test_eye_offsets_give_exactly_n(desk, n):
    screen, eye = desk
    assert pg.eye_offsets_deg(screen, eye, n, seed=0).shape == (n, 2)


# ---------------------------------------------------------------------------
# case_summary
# ---------------------------------------------------------------------------

BUDGETS = (100_000, 200_000, 400_000)


def _curve(jods, triangles=BUDGETS, frame_ms=(4.0, 6.0, 10.0)):
    return [{"budget": b, "triangles": t, "frame_ms": ms, "jod": list(j)}
            for b, t, ms, j in zip(BUDGETS, triangles, frame_ms, jods)]


def _report(case=("mesas:5", "plains", "desk"), **curves):
    """A judge_case report of two fixations at :data:`BUDGETS`; ``curves`` {rule: curve} override the defaults,
    ``oracle`` a list of per-budget JOD pairs (None: no oracle)."""
    base = {"default": _curve([(9.1, 9.3), (9.5, 9.7), (9.7, 9.9)]),
            "head_only": _curve([(9.0, 9.4), (9.4, 9.6), (9.7, 9.8)]),
            "sse": _curve([(9.0, 9.2), (9.5, 9.5), (9.6, 9.6)]),
            "dpv": _curve([(9.15, 9.15), (9.4, 9.4), (9.75, 9.75)]),
            "ipv": _curve([(8.0, 8.0), (8.5, 8.5), (9.0, 9.0)])}
    oracle = curves.pop("oracle", [(9.3, 9.35), (9.6, 9.7), (9.8, 9.8)])
    base.update(curves)
    report = {"case": dict(zip(("terrain", "view", "screen"), case)), "full": {"triangles": 2_097_152,
                                                                               "frame_ms": 22.0},
              "curves": base}
    if oracle is not None:
        report["oracle"] = [{"budget": b, "triangles": [b, b], "jod": list(j)} for b, j in zip(BUDGETS, oracle)]
    return report


def test_the_margin_is_the_default_over_the_best_geometric_mode_at_each_budget():
    s = pg.case_summary(_report())
    assert [r["budget"] for r in s["budgets"]] == list(BUDGETS)
    # default means 9.2, 9.6, 9.8; sse 9.1, 9.5, 9.6; dpv 9.15, 9.4, 9.75; ipv far below.
    expected = [("dpv", 9.2 - 9.15), ("sse", 9.6 - 9.5), ("dpv", 9.8 - 9.75)]
    for row, (mode, margin) in zip(s["budgets"], expected):
        assert row["geometric_mode"] == mode
        assert row["margin"] == pytest.approx(margin, abs=JOD_TOL)
        assert row["jod"] - row["geometric_jod"] == pytest.approx(row["margin"], abs=JOD_TOL)


def _log_interp(x, xs, ys):
    """Linear in log x between the points; the end value just past an end (tests pick x within 5 % of it)."""
    if x <= xs[0]:
        return ys[0]
    if x >= xs[-1]:
        return ys[-1]
    i = max(k for k in range(len(xs) - 1) if xs[k] <= x)
    f = (math.log(x) - math.log(xs[i])) / (math.log(xs[i + 1]) - math.log(xs[i]))
    return ys[i] + f * (ys[i + 1] - ys[i])


def test_the_margin_interpolates_in_log_triangles_when_the_triangles_miss_the_budget():
    default_tris, sse_tris = (102_000, 196_000, 404_000), (98_000, 205_000, 390_000)
    default = _curve([(9.2, 9.2), (9.6, 9.6), (9.8, 9.8)], default_tris)
    sse = _curve([(9.0, 9.0), (9.4, 9.4), (9.7, 9.7)], sse_tris)
    low = _curve([(5.0, 5.0)] * 3)
    s = pg.case_summary(_report(default=default, sse=sse, dpv=low, ipv=low))
    for row in s["budgets"]:
        d = _log_interp(row["budget"], default_tris, (9.2, 9.6, 9.8))
        g = _log_interp(row["budget"], sse_tris, (9.0, 9.4, 9.7))
        assert row["geometric_mode"] == "sse"
        assert row["margin"] == pytest.approx(d - g, abs=JOD_TOL)
    # By hand at 100k: the default's first point (102k) is within the 5 % slack, sse's between 98k and 205k.
    sse_at_100k = 9.0 + math.log(100 / 98) / math.log(205 / 98) * 0.4
    assert s["budgets"][0]["margin"] == pytest.approx(9.2 - sse_at_100k, abs=JOD_TOL)


def test_a_geometric_mode_that_did_not_reach_the_budget_does_not_count():
    """A curve more than 5 % away from a budget has no value there: it is not the best, and with no geometric
    mode left the margin is None."""
    far = _curve([(9.9, 9.9)] * 3, (130_000, 260_000, 520_000))
    s = pg.case_summary(_report(sse=far))
    assert s["budgets"][0]["geometric_mode"] == "dpv"           # sse's 9.9 would win, but it starts at 130k
    s = pg.case_summary(_report(sse=far, dpv=far, ipv=far))
    assert s["budgets"][0]["margin"] is None and s["budgets"][0]["geometric_mode"] is None
    assert s["budgets"][1]["margin"] is not None


def test_the_gains_come_from_per_fixation_differences():
    s = pg.case_summary(_report())
    # head_only (9.0, 9.4), default (9.1, 9.3), oracle (9.3, 9.35) at 100k.
    row = s["budgets"][0]
    assert row["prior_gain"] == pytest.approx((0.1 - 0.1) / 2, abs=JOD_TOL)
    assert row["prior_worst"] == pytest.approx(-0.1, abs=JOD_TOL)
    assert row["oracle_gain"] == pytest.approx((0.3 - 0.05) / 2, abs=JOD_TOL)
    assert row["oracle_worst"] == pytest.approx(-0.05, abs=JOD_TOL)      # min of differences, not of JODs
    assert row["recovered"] == pytest.approx(0.0, abs=1e-10)
    # 200k: default (9.5, 9.7) − head (9.4, 9.6) = 0.1 each; oracle (9.6, 9.7) − head = (0.2, 0.1).
    row = s["budgets"][1]
    assert row["prior_gain"] == pytest.approx(0.1, abs=JOD_TOL)
    assert row["oracle_gain"] == pytest.approx(0.15, abs=JOD_TOL)
    assert row["recovered"] == pytest.approx(0.1 / 0.15, abs=1e-9)


def test_recovered_is_none_where_the_oracle_gains_nothing():
    s = pg.case_summary(_report(oracle=[(9.0, 9.4), (9.3, 9.5), (9.7, 9.8)]))
    assert s["budgets"][0]["oracle_gain"] == pytest.approx(0.0, abs=JOD_TOL)
    assert s["budgets"][0]["recovered"] is None                # gain 0
    assert s["budgets"][1]["recovered"] is None                # gain −0.1


def test_without_head_only_or_oracle_the_gains_are_absent():
    r = _report(oracle=None)
    s = pg.case_summary(r)
    assert "prior_gain" in s["budgets"][0] and "oracle_gain" not in s["budgets"][0]
    del r["curves"]["head_only"]
    s = pg.case_summary(r)
    assert "prior_gain" not in s["budgets"][0] and s["budgets"][0]["margin"] is not None


def test_the_target_is_where_the_mean_curve_crosses_it_in_log_triangles():
    target = pg.GOALS["target_jod"]
    # Curves placed about the target: the default crosses it three quarters of the way (in log) from 100k to
    # 200k; sse is already above it at 100k; ipv never reaches it; dpv reaches it exactly at 200k.
    up = lambda a, b, c: _curve([(a, a), (b, b), (c, c)])          # noqa: E731
    s = pg.case_summary(_report(default=up(target - 0.3, target + 0.1, target + 0.3),
                                sse=up(target + 0.1, target + 0.2, target + 0.3),
                                dpv=up(target - 0.2, target, target + 0.1),
                                ipv=up(target - 2, target - 1, target - 0.5)))
    t = s["target"]
    assert t["jod"] == target and t["full_triangles"] == 2_097_152
    assert t["default"]["state"] == "crossed"
    assert t["default"]["triangles"] == pytest.approx(100_000 * 2 ** 0.75, rel=1e-9)
    # frame_ms 4 → 6 over the same log step: 5.5 ms there; full's 22 ms → 4x the frame rate.
    assert t["default"]["frame_rate_ratio"] == pytest.approx(22.0 / 5.5, rel=1e-9)
    assert t["sse"] == {"triangles": None, "state": "below", "frame_rate_ratio": None}
    assert t["ipv"] == {"triangles": None, "state": "beyond", "frame_rate_ratio": None}
    assert t["dpv"]["state"] == "crossed" and t["dpv"]["triangles"] == pytest.approx(200_000, rel=1e-9)
    assert set(t) == {"jod", "full_triangles", "default", "sse", "dpv", "ipv"}     # head_only has no target


# ---------------------------------------------------------------------------
# verdicts
# ---------------------------------------------------------------------------

def _summary(terrain, view, screen, rows):
    """A case_summary-shaped summary: ``rows`` [(budget, margin, oracle_gain, oracle_worst, prior_gain)];
    None gains leave the oracle keys out."""
    budgets = []
    for b, margin, og, ow, pgain in rows:
        row = {"budget": b, "margin": margin, "geometric_mode": None if margin is None else "sse"}
        if og is not None:
            row.update(oracle_gain=og, oracle_worst=ow, prior_gain=pgain, prior_worst=pgain)
        budgets.append(row)
    return {"case": {"terrain": terrain, "view": view, "screen": screen}, "budgets": budgets}


def test_margins_count_only_held_out_cases_within_the_goal_range():
    lo, hi = pg.GOAL_RANGE
    s = [_summary("builtin", "default", "desk", [(150_000, -1.0, None, None, None)]),      # training
         _summary("hills:3", "mountains", "desk", [(150_000, -0.9, None, None, None)]),    # training
         _summary("mesas:5", "default", "desk", [(lo // 2, -0.8, None, None, None),        # below the range
                                                 (lo, 0.03, None, None, None),
                                                 (150_000, 0.01, None, None, None),
                                                 (hi, None, None, None, None),
                                                 (hi + 50_000, -0.7, None, None, None)]),  # beyond it
         _summary("builtin", "plains", "desk", [(250_000, 0.02, None, None, None)]),
         _summary("ridges:7", "overview", "wide", [(150_000, 0.2, None, None, None)])]
    v = pg.verdicts(s)
    assert v["margin_desk"]["worst"] == pytest.approx(0.01)
    assert v["margin_desk"]["worst_case"] == "mesas:5/default/desk at 150k"
    assert v["margin_desk"]["cases"] == 2
    assert v["margin_wide"]["worst"] == pytest.approx(0.2) and v["margin_wide"]["cases"] == 1
    assert v["margin_wide"]["worst_case"] == "ridges:7/overview/wide at 150k"
    assert set(v) == {"margin_desk", "margin_wide"}                # no oracle data: no oracle verdicts
    every = pg.verdicts(s, held_out_only=False)
    assert every["margin_desk"]["worst"] == pytest.approx(-1.0) and every["margin_desk"]["cases"] == 4
    assert every["margin_desk"]["worst_case"] == "builtin/default/desk at 150k"


def test_a_screen_without_held_out_margins_is_not_met():
    v = pg.verdicts([_summary("mesas:5", "plains", "desk", [(150_000, 0.5, None, None, None)])])
    assert v["margin_wide"] == {"goal": pg.GOALS["margin"]["wide"], "met": False, "worst": None, "worst_case": None,
                                "cases": 0}
    assert v["margin_desk"]["met"] is True


@pytest.mark.parametrize("screen", ["desk", "wide"])
def test_the_margin_goal_flips_exactly_at_its_bound(screen):
    goal = pg.GOALS["margin"][screen]
    for margin, met in ((goal, True), (np.nextafter(goal, -1.0), False), (np.nextafter(goal, 1.0), True)):
        v = pg.verdicts([_summary("mesas:5", "plains", screen, [(150_000, float(margin), None, None, None)])])
        assert v[f"margin_{screen}"]["met"] is met, (margin, goal)


def _oracle_summaries(worst_a=0.1, gain_a=0.25, prior_a=0.125, prior_b=0.125):
    """Two cases with the oracle: a (one budget) and b (two budgets, oracle_worst −0.01 and 0.03: mean 0.01)."""
    return [_summary("mesas:5", "plains", "desk", [(150_000, 0.1, gain_a, worst_a, prior_a)]),
            _summary("builtin", "overview", "wide", [(150_000, 0.1, 0.25, -0.01, prior_b),
                                                     (250_000, 0.1, 0.25, 0.03, prior_b)])]


def test_the_oracle_and_prior_verdicts():
    v = pg.verdicts(_oracle_summaries(worst_a=0.1, gain_a=0.25, prior_a=0.125, prior_b=0.0625))
    assert v["oracle_every_view"]["worst"] == pytest.approx(0.01)           # b: mean of −0.01 and 0.03
    assert v["oracle_every_view"]["worst_case"] == "builtin/overview/wide" and v["oracle_every_view"]["met"]
    assert v["oracle_mean"]["worst"] == pytest.approx(0.25) and v["oracle_mean"]["met"]
    assert v["prior_recovers"]["worst"] == pytest.approx((0.125 + 2 * 0.0625) / 3 / 0.25)
    assert v["prior_never_worse"]["worst"] == pytest.approx(0.0625)
    assert v["prior_never_worse"]["worst_case"] == "builtin/overview/wide"
    # The oracle's case worst is a mean over its budgets: a one-budget case lower than b's mean names a.
    v = pg.verdicts(_oracle_summaries(worst_a=0.0))
    assert v["oracle_every_view"]["worst_case"] == "mesas:5/plains/desk"


def test_the_oracle_and_prior_goals_flip_exactly_at_their_bounds():
    tol, gain, share, prior_tol = (pg.GOALS[k] for k in ("oracle_tolerance", "oracle_gain", "prior_share",
                                                          "prior_tolerance"))
    below = lambda x: float(np.nextafter(x, -1.0))                  # noqa: E731
    # oracle_every_view: the lowest case's mean oracle_worst against −tolerance (a's one budget is that mean).
    assert pg.verdicts(_oracle_summaries(worst_a=-tol))["oracle_every_view"]["met"] is True
    assert pg.verdicts(_oracle_summaries(worst_a=below(-tol)))["oracle_every_view"]["met"] is False
    # oracle_mean: every gain equal, so the mean is that gain.
    one = lambda g, p=0.0: [_summary("mesas:5", "plains", "desk", [(150_000, 0.1, g, 0.0, p)])]  # noqa: E731
    assert pg.verdicts(one(gain))["oracle_mean"]["met"] is True
    assert pg.verdicts(one(below(gain)))["oracle_mean"]["met"] is False
    # prior_recovers: prior / oracle with the oracle's gain 1 is the prior's gain itself.
    assert pg.verdicts(one(1.0, share))["prior_recovers"]["met"] is True
    assert pg.verdicts(one(1.0, below(share)))["prior_recovers"]["met"] is False
    v = pg.verdicts(one(0.0, 0.5))
    assert v["prior_recovers"]["worst"] is None and v["prior_recovers"]["met"] is False   # no gain to share
    # prior_never_worse: the lowest case's mean prior gain against −tolerance.
    assert pg.verdicts(one(1.0, -prior_tol))["prior_never_worse"]["met"] is True
    assert pg.verdicts(one(1.0, below(-prior_tol)))["prior_never_worse"]["met"] is False


def test_verdicts_from_summaries_of_reports():
    """End to end: case_summary's output is what verdicts reads."""
    summaries = [pg.case_summary(_report(("mesas:5", "plains", "desk"))),
                 pg.case_summary(_report(("builtin", "default", "desk")))]      # training: margins not counted
    v = pg.verdicts(summaries)
    assert v["margin_desk"]["cases"] == 1
    # mesas at 100k..400k: margins 0.05, 0.1, 0.05; the worst is the first in the range with that value.
    assert v["margin_desk"]["worst"] == pytest.approx(0.05, abs=1e-9)
    assert set(v) == {"margin_desk", "margin_wide", "oracle_every_view", "oracle_mean", "prior_recovers",
                      "prior_never_worse"}


# ---------------------------------------------------------------------------
# cases_of, GazeJudgeConfig
# ---------------------------------------------------------------------------

def test_training_cases_are_the_training_terrains_by_views_per_screen():
    cases = pg.cases_of(("training",))
    expected = {(t, v, s) for s in pg.SCREENS for t in pg.TRAINING["terrains"] for v in pg.TRAINING["views"]}
    assert {(c.terrain, c.view, c.screen) for c in cases} == expected and len(cases) == len(expected)
    assert {c.screen for c in pg.cases_of(("training",), screens=("wide",))} == {"wide"}


def test_held_out_cases_share_no_terrain_and_view_pair_with_training():
    from headplod.bench.landscapes import parse_name

    assert not set(pg.TRAINING["terrains"]) & set(pg.HELD_OUT["terrains"])
    assert not set(pg.TRAINING["views"]) & set(pg.HELD_OUT["views"])
    training = {(t, v) for t in pg.TRAINING["terrains"] for v in pg.TRAINING["views"]}
    held = pg.cases_of(("held_out",))
    assert held and all((c.terrain, c.view) not in training for c in held)
    assert all(c.terrain in pg.HELD_OUT["terrains"] or c.view in pg.HELD_OUT["views"] for c in held)
    # Every pair of a held-out terrain or view is there, on every screen.
    terrains = pg.TRAINING["terrains"] + pg.HELD_OUT["terrains"]
    expected = {(t, v, s) for s in pg.SCREENS for t in terrains for v in VIEWS} - {
        (t, v, s) for (t, v) in training for s in pg.SCREENS}
    assert {(c.terrain, c.view, c.screen) for c in held} == expected
    for c in held:
        assert c.view in VIEWS
        assert c.terrain == "builtin" or parse_name(c.terrain)


def test_no_case_appears_twice():
    every = pg.cases_of(("training", "held_out"))
    assert len(every) == len(set(every)) == len(pg.cases_of(("training",))) + len(pg.cases_of(("held_out",)))
    assert len({c.name for c in every}) == len(every)


@pytest.mark.parametrize("kwargs", [{"budgets": ()}, {"budgets": (0,)}, {"budgets": (100_000, -5)},
                                    {"budgets": (150_000.5,)}, {"fixations": 0}, {"fixations": -2},
                                    {"fixations": 2.5}],
                         ids=["no-budgets", "zero", "negative", "fractional", "no-fixations", "negative-fixations",
                              "fractional-fixations"])
def test_the_config_rejects_bad_budgets_and_fixations(kwargs):
    with pytest.raises(ValueError, match="budgets|fixations"):
        pg.GazeJudgeConfig(**kwargs)


def test_the_config_accepts_whole_numbers():
    c = pg.GazeJudgeConfig(budgets=(100_000, 2.0e5), fixations=3.0)
    assert c.budgets == (100_000, 2.0e5) and c.fixations == 3.0
    assert pg.GazeJudgeConfig().budgets == pg.BUDGETS


@pytest.mark.parametrize("budgets", [(float("inf"),), (None,)], ids=["inf", "none"])
def test_the_config_rejects_non_numbers_with_value_error(budgets):
    with pytest.raises(ValueError, match="budgets"):
        pg.GazeJudgeConfig(budgets=budgets)


def test_eye_offsets_refuse_an_eye_from_which_no_gaze_lands_on_the_screen(monkeypatch):
    """Where no gaze lands on the screen (here: every ray misses), a ValueError after a bounded number of draws,
    not an endless loop. (An eye in the screen's plane is refused earlier, by the viewer model's extents.)"""
    from headplod.plod.view import default_head

    screen = io.read_screen(DEFAULT_SCREEN)
    monkeypatch.setattr(pg, "gaze_point_px", lambda *args: None)
    with pytest.raises(ValueError, match="land on the screen"):
        pg.eye_offsets_deg(screen, default_head(screen), 3)
    beside = screen.pixel_to_world(np.array([-screen.size_px[0], screen.size_px[1] / 2], float))
    with pytest.raises(ValueError, match="screen_half_deg"):
        pg.eye_offsets_deg(screen, beside, 3)
