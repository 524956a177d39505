"""The imperfect-rig sets of ``headplod bench track``: the bench's own bookkeeping against the dataset's truth.

Not a test of the tracker's accuracy: only that the numbers the bench
computes are the ones the truth says (before any refinement the rig's errors
are the faults themselves) and are consistent with one another.
"""
import numpy as np
import pytest

from headplod.bench import rig as bench_rig
from headplod.tracking import evaluate
from headplod.bench.track import run_track_bench


@pytest.mark.slow
def test_rig_set_numbers_match_the_truth(synth, tmp_path):
    faults = {"rotation_deg": 0.5, "baseline_scale": 1.02, "focal_scale": 1.01, "offset_s": 0.008}
    ds = synth("imperfect_rig", 24, **faults)
    out = bench_rig.run_rig_set(ds.folder, settle_s=0.4)
    ser = {k: np.asarray(v, float) for k, v in out["series"].items()}

    # Frame 0: nothing refined yet, so the rig's errors are the faults.
    assert ser["frame"][0] == 0
    assert abs(ser["turn_err_deg"][0] - 0.5) < 0.01
    assert abs(ser["scale_err"][0] - 0.02) < 1e-9        # rig.yaml's T is 1.02 times the true one
    assert abs(ser["focal_err"][0] - 0.01) < 1e-9        # rig.yaml's right focal is 1.01 times the true one
    assert abs(ser["offset_err_ms"][0] + 8.0) < 1e-6     # undeclared, not yet estimated: 0 − 8 ms
    assert out["initial"]["turn_err_deg"] == ser["turn_err_deg"][0]

    # The summary is the series': counts, medians, the settle split, the final values.
    assert out["frames"] == 24 == len(ser["frame"])
    assert out["ok"] == int(ser["ok"].sum()) and 0 <= out["pose_fraction"] <= 1
    v = ser["v_err_deg"][np.isfinite(ser["v_err_deg"])]
    assert np.all(v >= 0) and out["v_err_deg_median"] == np.median(v)
    assert out["wrong_poses"] == int(np.sum(v > evaluate.WRONG_IDENTIFICATION_DEG))
    settled = ser["t"] >= 0.4 - 1e-9
    assert out["frames_settled"] == int(settled.sum()) == 24 - 12      # 30 fps
    assert out["pos_err_mm_median_settled"] == np.nanmedian(ser["pos_err_mm"][settled])
    n = ser["nees"][np.isfinite(ser["nees"])]
    assert len(n) and np.all(n >= 0) and abs(out["nees_mean"] - n.mean()) < 1e-12
    assert out["final"]["offset_err_ms"] == ser["offset_err_ms"][-1]
    assert np.all(ser["turn_sd_deg"][np.isfinite(ser["turn_sd_deg"])] > 0)

    # The report and chart take it.
    report = bench_rig.rig_report({"x": out})
    assert "x" in report["text"] and {g["key"] for g in report["json"]["goals"]} >= {"pose_fraction", "nees_mean"}
    bench_rig.rig_chart({"x": out}, tmp_path / "rig.png")
    assert (tmp_path / "rig.png").stat().st_size > 10_000


def test_bump_errors_use_the_active_segment(synth):
    ds = synth("imperfect_rig", 12, bump_frame=6, bump_deg=0.4)
    truth = bench_rig.load_rig_truth(ds.folder)
    assert [s["first_frame"] for s in truth["segments"]] == [0, 6]
    assert bench_rig.truth_segment(truth, 5) is truth["segments"][0]
    assert bench_rig.truth_segment(truth, 6) is truth["segments"][1]
    first, second = truth["segments"]
    # rig.yaml is right before the bump: the turn error jumps by the bump at frame 6.
    err = bench_rig.rig_errors(first["R"], first["T"], first["K2"], 0.0, second, 0.0)
    assert abs(err["turn_err_deg"] - 0.4) < 1e-6 and abs(err["scale_err"]) < 1e-9


def test_unknown_set_names_are_refused(capsys):
    assert run_track_bench(sets=["no such set"]) == 2
    assert "stale rig 0.5°" in capsys.readouterr().err
