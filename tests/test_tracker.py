"""The tracker against ground truth: the shared sample, synthetic sets, hard cases, bad input.

Tolerances are the tracker issue's accuracy goals where a set falls under them
(50-80 cm: median V ≤ 0.1°, p95 ≤ 0.4°, median position ≤ 0.2 mm); other sets
assert what the physics of the rendered images allows with margin, and above
all that no pose is more than 5° off (a wrong identification).
"""
import json

import cv2
import numpy as np
import pytest

from headplod.tracking import evaluate
from headplod import io
from headplod.cli import main as cli_main
from headplod.tracking.detect import DetectionParams
from dataset_run import track_dataset
from headplod.tracking.tracker import Tracker, TrackerConfig


def summary_of(dataset, config=TrackerConfig()):
    records = track_dataset(dataset, config)
    return records, evaluate.summarize(records, dataset.truth)


@pytest.mark.slow
def test_shared_sample_matches_its_truth(sweep12_dir):
    """sweep12 was rendered by independent code: the contract is read the same way on both sides."""
    records, s = summary_of(io.Dataset(sweep12_dir))
    assert s["ok"] == 12
    assert s["v_err_deg_median"] <= 0.1 and s["v_err_deg_p95"] <= 0.4
    assert s["pos_err_mm_median"] <= 0.2
    for rec in records:                   # the covariance is a real 2x2 SPD matrix in deg²
        assert np.all(np.linalg.eigvalsh(np.array(rec["cov"])) > 0)


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["reproj", "rigid", "paper"])
def test_near_accuracy_goals(synth, estimator):
    dataset = synth("static", 20, distance_mm=550.0)
    _, s = summary_of(dataset, TrackerConfig(estimator=estimator))
    assert s["ok"] == 20
    assert s["v_err_deg_median"] <= 0.1 and s["v_err_deg_p95"] <= 0.4
    assert s["pos_err_mm_median"] <= 0.2


@pytest.mark.slow
def test_sweeps_track_within_goals(synth):
    for preset in ("pitch_sweep", "roll_sweep"):
        _, s = summary_of(synth(preset, 24))
        assert s["tracked_fraction"] == 1.0, preset
        assert s["v_err_deg_median"] <= 0.1 and s["v_err_deg_p95"] <= 0.4, preset
        assert s["wrong_identifications"] == 0


@pytest.mark.slow
def test_tracking_fast_path_agrees_with_full_detection(synth):
    dataset = synth("yaw_sweep", 16, amplitude_deg=25.0)
    tracked, s_tracked = summary_of(dataset, TrackerConfig(track=True))
    full, s_full = summary_of(dataset, TrackerConfig(track=False))
    assert any(r["mode"] == "track" for r in tracked)
    assert all(r["mode"] == "acquire" for r in full)
    # Both measure the same blobs with different windows: per-frame results
    # differ by about the noise (≈0.05°), and neither is worse than the other.
    for a, b in zip(tracked, full):
        assert a["ok"] == b["ok"]
        if a["ok"]:
            assert evaluate.angle_deg(np.array(a["axes"][2]), np.array(b["axes"][2])) < 0.3
            assert np.linalg.norm(np.array(a["position"]) - b["position"]) < 0.2
    assert s_tracked["v_err_deg_median"] <= 1.3 * s_full["v_err_deg_median"] + 0.02
    assert s_tracked["pos_err_mm_median"] <= 1.3 * s_full["pos_err_mm_median"] + 0.01


@pytest.mark.slow
@pytest.mark.parametrize("preset, frames, min_tracked, max_median_deg", [
    ("far", 12, 1.0, 0.8),                 # 120 cm: depth precision ∝ z²; see the bench for the goal
    ("dim_ir", 12, 1.0, 0.2),              # marker peaks 50-110 DN: the adaptive threshold keeps them
    ("glints_lamp", 16, 0.9, 0.15),
    ("occlusion", 12, 1.0, 0.15),          # a marker hidden in one view: pose from the other nine
    ("fast_motion", 16, 0.9, 0.2),         # blur and a 4 ms left/right offset
    ("wide_hd", 12, 0.8, 0.2),             # 1280x720 wide-angle, strong distortion
    ("custom_model", 12, 1.0, 0.15),       # curved frame read from markers.yaml
    ("distance_sweep", 16, 0.8, 0.3),
])
def test_hard_sets(synth, preset, frames, min_tracked, max_median_deg):
    _, s = summary_of(synth(preset, frames))
    assert s["wrong_identifications"] == 0
    assert s["tracked_fraction"] >= min_tracked
    assert s["v_err_deg_median"] <= max_median_deg


@pytest.mark.slow
def test_random_poses_never_misidentify(synth):
    _, s = summary_of(synth("random", 120))
    assert s["wrong_identifications"] == 0
    assert s["tracked_fraction"] >= 0.8


@pytest.mark.slow
def test_paper_threshold_fails_cleanly_on_dim_ir(synth):
    """The paper's fixed threshold of 100 DN misses dim markers: no pose, with a reason, never a wrong one."""
    records, s = summary_of(synth("dim_ir", 8), TrackerConfig(detection=DetectionParams.paper()))
    assert s["wrong_identifications"] == 0
    failed = [r for r in records if not r["ok"]]
    assert failed and all("marker blobs" in r["reason"] or "layout" in r["reason"] for r in failed)


def test_every_blob_count_gets_a_reason(sweep12_dir):
    ds = io.Dataset(sweep12_dir)
    frame = ds.frame(0)
    tracker = Tracker(ds.rig, ds.markers)
    blank = np.full_like(frame.left, 12)
    result = tracker.process(blank, frame.right, 0.0)
    assert not result.ok and "left image: 0 marker blobs" in result.reason
    # Erase one marker from the left image only: a pose from nine centres, or none, never a wrong one.
    left = frame.left.copy()
    ys, xs = np.nonzero(left > 60)
    far_right = xs.max()
    left[:, far_right - 8:far_right + 2] = 12
    result = Tracker(ds.rig, ds.markers).process(left, frame.right, 0.0)
    if result.ok:
        pos, axes = ds.truth[0]
        assert evaluate.angle_deg(result.axes[2], axes[2]) < 1.0
    else:
        assert result.reason


def test_wrong_image_size_and_nan_free_records(tmp_path, sweep12_dir):
    ds = io.Dataset(sweep12_dir)
    frame = ds.frame(0)
    result = Tracker(ds.rig, ds.markers).process(cv2.resize(frame.left, (320, 240)), frame.right)
    assert not result.ok and "320x240" in result.reason and "640x480" in result.reason


@pytest.mark.slow
def test_cli_writes_contract_records_and_survives_bad_frames(tmp_path, capsys, sample):
    ds = sample
    (ds / "right" / "000004.png").unlink()                          # missing frame
    (ds / "left" / "000007.png").write_bytes(b"not a png")          # unreadable frame
    cv2.imwrite(str(ds / "left" / "000009.png"), np.zeros((240, 320), np.uint8))   # wrong size
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(ds), "--out", str(out), "-q"]) == 0
    records = io.read_poses(out)
    assert [r["frame"] for r in records] == list(range(12))
    bad = {r["frame"]: r["reason"] for r in records if not r["ok"]}
    assert set(bad) == {4, 7, 9}
    assert "000004" in bad[4] and "000007" in bad[7] and "000009" in bad[9]
    truth = io.read_truth(ds / "truth.csv")
    s = evaluate.summarize(records, truth)
    assert s["ok"] == 9 and s["v_err_deg_median"] <= 0.1


@pytest.mark.slow
def test_cli_stdout_and_malformed_rig(capsys, sample):
    ds = sample
    assert cli_main(["track", "--source", str(ds), "--out", "-", "-q"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 12 and json.loads(lines[0])["ok"] is True
    (ds / "rig.yaml").write_text("%YAML:1.0\n---\nimage_width: 640\nK1: [1, 2\n")
    assert cli_main(["track", "--source", str(ds), "-q"]) == 1
    err = capsys.readouterr().err
    assert "rig.yaml" in err


def test_cli_malformed_markers_names_the_file(capsys, sample):
    ds = sample
    (ds / "markers.yaml").write_text("%YAML:1.0\n---\nmarkers: !!opencv-matrix\n   rows: 4\n   cols: 3\n"
                                     "   dt: d\n   data: [ 65, 0, 0, 0, 0, 0, -65, 0, 0, 40, -30, 0 ]\n")
    assert cli_main(["track", "--source", str(ds), "-q"]) == 1
    err = capsys.readouterr().err
    assert "markers.yaml" in err and "5" in err


@pytest.mark.slow
def test_left_right_count_mismatch_processes_the_rest(sample):
    ds = sample
    for k in (10, 11):
        (ds / "right" / f"{k:06d}.png").unlink()
    dataset = io.Dataset(ds)
    assert any("right" in w for w in dataset.warnings)
    records = track_dataset(dataset)
    assert sum(r["ok"] for r in records) == 10 and not records[10]["ok"] and not records[11]["ok"]
