"""The tracker on what ordinary webcams add: a rolling shutter, a far-off rig.yaml, repeated buffers.

Every dataset is rendered by ``synthetic/`` (independent of the tracker) from known poses; the truth
(``truth.csv``, ``rig_truth.json``, ``webcam_truth.json``) is read only here, to judge.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from headplod import io
from headplod.cli import main as cli_main
from headplod.tracking import evaluate
from headplod.tracking.tracker import Tracker, TrackerConfig
from headplod.tracking.rig_refine import RigRefineConfig


def _track(dataset, config=TrackerConfig()):
    tracker = Tracker(dataset.rig, dataset.markers, config)
    out = []
    for f in dataset:
        out.append((f, tracker.process(f.left, f.right, f.t, f.t_right)))
    return tracker, out


def _errors(dataset, results):
    """V (deg) and P1 (mm) errors of the frames with a pose, and their NEES."""
    from headplod.bench.uncertainty import nees

    v, p, n = [], [], []
    for f, r in results:
        if r.ok:
            pos, axes = dataset.truth[f.index]
            v.append(float(evaluate.angle_deg(r.axes[2], axes[2])))
            p.append(float(np.linalg.norm(r.position_mm - pos)))
            n.append(nees(r.cov_deg2, axes[2], r.axes))
    return np.array(v), np.array(p), np.array(n)


@pytest.mark.slow
def test_rolling_shutter_is_compensated_and_its_readout_learnt(synth):
    """30 ms from the first row to the last, and the right camera 12 ms late, undeclared: the readout and
    the offset are learnt from the motion, and the poses are as good as a global shutter's."""
    ds = synth("imperfect_rig", 150, readout_s=0.03, offset_s=0.012)
    truth = json.loads((ds.folder / "webcam_truth.json").read_text())
    assert truth["readout_s"] == pytest.approx(0.03)
    tracker, results = _track(ds)
    v, p, n = _errors(ds, results)
    assert sum(r.ok for _, r in results) >= 0.99 * len(results)
    assert np.median(v[60:]) <= 0.1 and np.median(p[60:]) <= 0.5
    assert v.max() < 5 and p.max() < 20
    assert 1.0 <= n.mean() <= 3.5
    readout = tracker.refiner.estimator.estimate.readout_s
    assert abs(readout - 0.03) <= max(1e-3, 0.05 * 0.03), readout
    assert abs(tracker.refiner.estimator.estimate.offset_s - 0.012) <= 1e-3
    assert "rolling shutter" in tracker.refiner.describe()


@pytest.mark.slow
def test_without_compensation_a_rolling_shutter_costs_accuracy(synth):
    """A head turning at up to 140°/s with the compensation off: what the compensation is worth (the test
    above is not passing for want of a rolling shutter in the images)."""
    ds = synth("imperfect_rig", 90, readout_s=0.03, base="yaw_sweep")
    _, on = _track(ds)
    _, off = _track(ds, TrackerConfig(compensate_rolling_shutter=False,
                                      rig_refine=RigRefineConfig(enabled=False)))
    v_on, _, _ = _errors(ds, on)
    v_off, _, _ = _errors(ds, off)
    assert np.median(v_off[30:]) > 2 * np.median(v_on[30:])


@pytest.mark.slow
def test_a_global_shutter_stays_one(synth):
    """A global-shutter rig (the default synthetic one): the readout is learnt as 0, nothing is compensated,
    and the accuracy is what it was."""
    ds = synth("imperfect_rig", 90)
    tracker, results = _track(ds)
    v, p, _ = _errors(ds, results)
    assert all(r.ok for _, r in results)
    assert np.median(v) <= 0.1 and np.median(p) <= 0.2
    assert abs(tracker.refiner.estimator.estimate.readout_s) <= 1e-3
    assert tracker.readout_s() == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("faults", [dict(rotation_deg=3.0), dict(baseline_scale=1.10),
                                    dict(rotation_deg=2.0, baseline_scale=1.07, focal_scale=1.02)])
def test_a_far_off_rig_gives_no_wrong_pose_from_the_first_frames(synth, faults):
    """rig.yaml far outside its error model (the right camera turned 3°, a board 10% off, a mix): the rig is
    estimated from the first frames' markers, and no frame claims a pose it is far from."""
    ds = synth("imperfect_rig", 30, **faults)
    tracker, results = _track(ds)
    v, p, n = _errors(ds, results)
    assert sum(r.ok for _, r in results) >= 28
    assert v.max() < 1.0 and p.max() < 2.0
    assert tracker.refiner.estimator.bootstrapped_at is not None
    noted = [r for _, r in results if any("rig.yaml is far from the rig" in note for note in r.notes)]
    assert len(noted) == 1 and noted[0].ok


def test_one_stray_blob_does_not_make_a_rig():
    """A frame whose identification is wrong cannot start the rig: the bootstrap needs two consecutive frames
    that agree on a rig, every centre within 5σ."""
    from headplod.tracking.rig_refine import RigErrorModel, RigRefiner, rig_jacobian_rows  # noqa: F401
    from headplod.capture.synthetic import ensure_dataset

    ds = io.Dataset(ensure_dataset("imperfect_rig", frames=4, quiet=True, rotation_deg=3.0))
    tracker, results = _track(ds)
    refiner = RigRefiner(ds.rig, tracker.model_mm)
    f = next(iter(ds))
    ok = [r for _, r in results if r.ok]
    R, p1 = ok[0].R_world_G, ok[0].position_mm
    good = ok[0].centers_px.copy()
    bad = good.copy()
    bad[1, 2] += (6.0, -4.0)                  # P2 in the right image: a blob beside it taken for it
    sigma = np.full((2, 5), 0.05)
    far = TrackerConfig().rig_far
    frames = [(0.0, good, np.ones((2, 5), bool), sigma, R, p1), (1 / 30, bad, np.ones((2, 5), bool), sigma, R, p1)]
    assert not refiner.bootstrap(frames, far)
    assert refiner.estimator.versions == 0 and refiner.estimator.bootstrapped_at is None


@pytest.mark.slow
def test_a_repeated_buffer_gets_no_pose(synth):
    """A driver handing out the same buffer again: the images were exposed a frame before their time."""
    ds = synth("imperfect_rig", 40, duplicate_frames=[10, 25])
    truth = json.loads((ds.folder / "webcam_truth.json").read_text())
    repeated = {d["frame"] for d in truth["duplicates"]}
    assert repeated == {10, 25}
    _, results = _track(ds)
    for f, r in results:
        if f.index in repeated:
            assert not r.ok and "same image as in the last frame" in r.reason
        else:
            assert r.ok, (f.index, r.reason)


@pytest.mark.slow
def test_readout_option_is_validated_and_reaches_the_tracker(synth, tmp_path, capsys):
    ds = synth("imperfect_rig", 20, readout_s=0.03)
    for bad in ("-1", "1500", "fast"):
        with pytest.raises(SystemExit) as exc:
            cli_main(["track", "--source", str(ds.folder), "--readout-ms", bad, "-q"])
        assert exc.value.code == 2
        assert "--readout-ms" in capsys.readouterr().err
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(ds.folder), "--readout-ms", "30", "--refine-rig", "off",
                     "--out", str(out), "-q"]) == 0
    records = io.read_poses(out)
    truth = ds.truth
    v = [float(evaluate.angle_deg(np.array(r["axes"][2]), truth[r["frame"]][1][2])) for r in records if r["ok"]]
    assert len(v) >= 18 and np.median(v) <= 0.1


@pytest.mark.slow
def test_the_tracker_names_its_states(synth):
    """acquire → track on the markers; rig.yaml → refining on the rig, as the frames go."""
    ds = synth("imperfect_rig", 40, rotation_deg=0.3)
    tracker = Tracker(ds.rig, ds.markers)
    assert tracker.state() == ("acquire", "rig.yaml")
    states = []
    for f in ds:
        tracker.process(f.left, f.right, f.t, f.t_right)
        states.append(tracker.state())
    assert states[0][0] == "track" and states[0][1] == "rig.yaml"
    assert states[-1] == ("track", "refining") or states[-1] == ("track", "refined")
    tracker.reset()
    assert tracker.state()[0] == "acquire"


@pytest.mark.slow
def test_a_saved_rig_brings_its_readout(synth, tmp_path):
    """--save-rig keeps the readout with the refined rig (not in rig.yaml); tracking with that rig starts from
    it: compensated from the first frames, even with the refinement off."""
    ds = synth("imperfect_rig", 150, readout_s=0.03, base="yaw_sweep")
    saved = tmp_path / "refined.yaml"
    assert cli_main(["track", "--source", str(ds.folder), "--save-rig", str(saved), "-q"]) == 0
    rig = io.read_rig(saved)
    assert abs(float(np.ravel(rig.extra["refined_readout_ms"])[0]) - 30.0) <= 1.5
    assert "refined_readout_ms" not in io.read_rig(ds.folder / "rig.yaml").extra
    tracker = Tracker(rig, ds.markers, TrackerConfig(rig_refine=RigRefineConfig(enabled=False)))
    assert tracker.readout_s() == pytest.approx(float(np.ravel(rig.extra["refined_readout_ms"])[0]) * 1e-3)
    _, off = _track(ds, TrackerConfig(rig_refine=RigRefineConfig(enabled=False)))
    tracker_results = [(f, tracker.process(f.left, f.right, f.t, f.t_right)) for f in ds]
    v_saved, _, _ = _errors(ds, tracker_results)
    v_off, _, _ = _errors(ds, off)
    assert np.median(v_saved[:30]) < 0.6 * np.median(v_off[:30])
