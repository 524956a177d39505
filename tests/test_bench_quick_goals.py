"""bench track --quick explains itself (issue 36, item 6): goals its short sets cannot judge say "not judged in
a quick run" instead of NOT MET, the tables stay aligned for long set names, the chart's legend is beside the
data. Fast: the reports are made from results built here, no tracking runs."""
import numpy as np

from headplod.bench import rig as bench_rig
from headplod.bench import track as bench_track
from headplod.bench.goals import NOT_JUDGED, frames_for_mean, frames_for_quantile
from headplod.tracking.tracker import ESTIMATORS

LONG = "random poses, glints, hidden markers, and then some"


def _track_results(frames: int, slow_tail: bool = True) -> dict:
    """Every estimator on three sets, accurate, with a slowest 1 % far above the clean set's median frame."""
    one = {"frames": frames, "tracked_fraction": 1.0, "v_err_deg_median": 0.05, "v_err_deg_p95": 0.1,
           "pos_err_mm_median": 0.05, "wrong_identifications": 0, "mean_pose_ms": 1.0,
           "mean_pose_ratio_to_threshold": 10.0, "frame_ms_median": 1.0,
           "frame_ms_p99": 10.0 if slow_tail else 1.5, "frame_ms_max": 20.0 if slow_tail else 2.0}
    return {name: {e: dict(one) for e in ESTIMATORS} for name in (bench_track.CLEAN_SET, "static 55 cm", LONG)}


def test_frames_a_statistic_needs():
    assert frames_for_quantile(0.99) == 100 and frames_for_quantile(0.95) == 20 and frames_for_quantile(0.5) == 2
    assert frames_for_mean(2.0, 0.25) == 64


def test_a_quick_run_does_not_judge_the_tail_goals_of_short_sets():
    quick = bench_track._report(_track_results(frames=20), quick=True)
    lines = [t for t in quick["text"].splitlines() if t.startswith("  [")]
    tail = [t for t in lines if "slowest" in t]
    assert len(tail) == 2 and all(t.startswith(f"  [{NOT_JUDGED}]") and "100 frames" in t for t in tail), tail
    assert not any("NOT MET" in t for t in lines), lines
    assert all(t.startswith("  [met]") for t in lines if "slowest" not in t), lines      # the rest is judged
    judged = {g["goal"]: g for g in quick["json"]["goals"]}
    assert all(g["met"] is None and g["judged"] is False for k, g in judged.items() if "slowest" in k)
    # Long enough sets, or a full run: judged, and the slow tail is missed.
    for results, quick_run in ((_track_results(frames=150), True), (_track_results(frames=20), False)):
        text = bench_track._report(results, quick=quick_run)["text"]
        assert text.count("[NOT MET] slowest") == 2 and NOT_JUDGED not in text


def test_the_track_table_stays_aligned_for_a_long_set_name():
    text = bench_track._report(_track_results(frames=150))["text"]
    table = text.split("\n\n")[0].splitlines()
    ends = {len(row) for row in table}
    assert len(ends) == 1, table                               # every row as long as the header: columns aligned
    assert all(row.index(" x thresh") > len(LONG) for row in table[:1])


def _rig_result(frames: int) -> dict:
    final = {"turn_err_deg": 0.01, "scale_err": 0.0, "focal_err": 0.0, "offset_err_ms": 0.0, "readout_err_ms": 0.0}
    return {"frames": frames, "settle_s": 1.0, "pose_fraction": 59 / 60, "wrong_poses": 0, "v_err_deg_median": 0.05,
            "pos_err_mm_median": 0.1, "v_err_deg_median_settled": 0.05, "pos_err_mm_median_settled": 0.1,
            "nees_mean": 1.0, "readout_ok": 0, "repeated_with_pose": 0, "frame_p99_to_median": 4.0,
            "final": final, "mean_pose_ratio_to_threshold": 10.0, "refine_ms_mean": 1.0, "refine_ms_max": 2.0,
            "refine_ratio_to_threshold": 1.0}


def test_a_quick_rig_run_does_not_judge_goals_its_two_seconds_cannot_show():
    results = {"stale rig 0.1°": _rig_result(60), "board scale 2% and a name longer than any column": _rig_result(60)}
    report = bench_rig.rig_report(results, quick=True)
    lines = [t for t in report["text"].splitlines() if t.startswith("  [")]
    for goal in ("pose ≥ 99%", "NEES within 1.5-3", "readout recovered", "99th percentile"):
        line = next(t for t in lines if goal in t)
        assert line.startswith(f"  [{NOT_JUDGED}]"), line
    assert not any("NOT MET" in t for t in lines), lines
    table = report["text"].split("\n(")[0].splitlines()
    assert len({len(row) for row in table}) == 1, table       # aligned
    full = bench_rig.rig_report(results, quick=False)["text"]
    assert NOT_JUDGED not in full and full.count("[NOT MET]") == 4


def test_the_charts_legend_lies_outside_the_data(tmp_path, monkeypatch):
    shown = {}

    def keep(fig, path, dpi=100, rect=None):
        fig.canvas.draw()
        shown["fig"] = fig

    monkeypatch.setattr(bench_track, "save_figure", keep)
    bench_track._chart(_track_results(frames=20), str(tmp_path / "c.png"))
    ax = shown["fig"].axes[0]
    renderer = shown["fig"].canvas.get_renderer()
    legend, axes = ax.get_legend().get_window_extent(renderer), ax.get_window_extent(renderer)
    assert legend.x0 >= axes.x1, (legend, axes)                  # beside the axes, over no point
    assert np.isfinite(legend.width) and legend.width > 0
