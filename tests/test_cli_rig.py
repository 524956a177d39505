"""``headplod track --refine-rig`` / ``--save-rig``, the calibration's σ reaching the tracker, and replays
that refine the rig the same way."""
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.capture import open_source
from headplod.cli import main as cli_main
from headplod.live.loop import make_tracker, run_source
from headplod.live.status import StatusLine, short_rig_message
from headplod.tracking.tracker import TrackerConfig
from headplod.tracking.rig_refine import RigRefineConfig

TIMING_KEYS = ("timings_ms", "latency_ms")
CAL_STD = {"calibration_std_left": np.array([[0.6, 0.6, 0.5, 0.5]]),
           "calibration_std_right": np.array([[0.7, 0.7, 0.5, 0.5]]),
           "calibration_std_rotation_deg": np.array([[0.05, 0.08, 0.02]]),
           "calibration_std_translation_mm": np.array([[0.4, 0.3, 1.5]])}


def _with_calibration_std(folder: Path) -> io.Rig:
    rig = io.read_rig(folder / "rig.yaml")
    rig = io.Rig(rig.image_size, rig.K1, rig.D1, rig.K2, rig.D2, rig.R, rig.T, extra=dict(rig.extra, **CAL_STD))
    io.write_rig(folder / "rig.yaml", rig)
    return rig


def _untimed(records):
    return [{k: v for k, v in r.items() if k not in TIMING_KEYS} for r in records]


def test_refine_rig_option_is_validated_and_reaches_the_tracker(sample, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["track", "--source", str(sample), "--refine-rig", "maybe", "-q"])
    assert exc.value.code == 2
    assert "--refine-rig" in capsys.readouterr().err
    on, off = tmp_path / "on.jsonl", tmp_path / "off.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(on), "-q"]) == 0          # default: on
    err = capsys.readouterr().err
    assert "rig.yaml: right camera turned" in err                                 # the final describe()
    assert cli_main(["track", "--source", str(sample), "--out", str(off), "--refine-rig", "off", "-q"]) == 0
    r_on, r_off = io.read_poses(on), io.read_poses(off)
    assert r_on[-1]["rig"]["updates"] >= 1
    assert all(r.get("rig", {}).get("updates", 0) == 0 for r in r_off)
    assert not any(r.get("rig_message") for r in r_off)


def test_save_rig_writes_the_refined_rig_atomically(sample, tmp_path, capsys):
    rig = _with_calibration_std(sample)
    before = (sample / "rig.yaml").read_bytes()
    out = tmp_path / "refined.yaml"
    out.write_text("old content\n")                                                # replaced whole
    assert cli_main(["track", "--source", str(sample), "--save-rig", str(out), "-q"]) == 0
    assert f"refined rig: {out}" in capsys.readouterr().err
    refined = io.read_rig(out)
    assert refined.image_size == rig.image_size
    assert np.array_equal(refined.K1, rig.K1) and np.array_equal(refined.D2, rig.D2)
    assert not np.array_equal(refined.R, rig.R) or not np.array_equal(refined.T, rig.T)
    assert "refined_time_offset_ms" in refined.extra and refined.extra["refined_from"] == str(sample / "rig.yaml")
    assert io.rig_calibration_std(refined) is not None                              # the calibration's keys kept
    assert (sample / "rig.yaml").read_bytes() == before                           # rig.yaml never overwritten
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "refined.yaml"]   # no temporary left behind


@pytest.mark.parametrize("target, extra, message", [
    ("{ds}/rig.yaml", [], "is the rig being read"),
    ("{ds}/left/../rig.yaml", [], "is the rig being read"),
    ("{ds}/refined.yaml", [], "inside the dataset folder"),
    ("{tmp}/calib.yaml", ["--calib", "{tmp}/calib.yaml"], "is the rig being read (--calib)"),
    ("{tmp}/missing/refined.yaml", [], "does not exist"),
    ("{tmp}", [], "is a folder"),
    ("{tmp}/rec/rig.yaml", ["--record", "{tmp}/rec"], "--record folder"),
    ("{tmp}/refined.yaml", ["--refine-rig", "off"], "needs the rig refinement"),
])
def test_save_rig_refusals_write_nothing(sample, tmp_path, capsys, target, extra, message):
    shutil.copy(sample / "rig.yaml", tmp_path / "calib.yaml")
    (tmp_path / "rec").mkdir()
    fill = {"ds": sample, "tmp": tmp_path}
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    out = tmp_path / "poses.jsonl"
    argv = ["track", "--source", str(sample), "--out", str(out), "-q", "--save-rig", target.format(**fill)]
    assert cli_main(argv + [a.format(**fill) for a in extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before                                                        # not even --out was touched
    assert not any((tmp_path / "rec").iterdir())


def test_save_rig_without_a_tracked_frame_writes_nothing(sample, tmp_path, capsys):
    black = tmp_path / "black"
    (black / "left").mkdir(parents=True)
    (black / "right").mkdir()
    shutil.copy(sample / "rig.yaml", black / "rig.yaml")
    for i in range(3):
        for side in ("left", "right"):
            cv2.imwrite(str(black / side / f"{i:06d}.png"), np.zeros((480, 640), np.uint8))
    out = tmp_path / "refined.yaml"
    assert cli_main(["track", "--source", str(black), "--save-rig", str(out), "-q"]) == 3
    assert "no frame was tracked" in capsys.readouterr().err
    assert not out.exists()
    with pytest.raises(SystemExit) as stop:                 # --frames 0 is refused before anything runs
        cli_main(["track", "--source", str(sample), "--save-rig", str(out), "--frames", "0", "-q"])
    assert stop.value.code == 2 and not out.exists()


def test_recording_keeps_the_rig_given_and_its_replay_refines_the_same_way(sample, tmp_path):
    rig = _with_calibration_std(sample)
    rec = tmp_path / "rec"
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    assert cli_main(["track", "--source", str(sample), "--record", str(rec), "--out", str(first), "-q",
                     "--save-rig", str(tmp_path / "refined.yaml")]) == 0
    assert io.read_rig(rec / "rig.yaml") == rig                                   # not the refined one
    assert cli_main(["track", "--source", str(rec), "--out", str(second), "-q"]) == 0
    r1, r2 = io.read_poses(first), io.read_poses(second)
    assert r1[-1]["rig"]["updates"] >= 1
    assert _untimed(r1) == _untimed(r2)


def test_run_source_twice_gives_identical_records_and_uses_the_calibration_std(sample):
    _with_calibration_std(sample)
    config = TrackerConfig(rig_refine=RigRefineConfig(enabled=True))
    runs, trackers = [], []
    for _ in range(2):
        records = []
        with open_source(str(sample)) as source:
            tracker = make_tracker(source, config)
            run_source(source, on_record=lambda record, result: records.append(record), tracker=tracker)
        runs.append(_untimed(records))
        trackers.append(tracker)
    assert runs[0] == runs[1] and len(runs[0]) == 12
    with open_source(str(sample)) as source:                                      # the same rig without its σ
        bare = source.rig
        bare = io.Rig(bare.image_size, bare.K1, bare.D1, bare.K2, bare.D2, bare.R, bare.T)
        plain = make_tracker(source, config, rig=bare)
        run_source(source, tracker=plain, max_frames=1)
    assert not np.allclose(trackers[0].refiner.estimator.prior, plain.refiner.estimator.prior)


def test_status_line_shows_the_rig_message():
    import io as stdio

    out = stdio.StringIO()
    status = StatusLine(stream=out, every_s=1.0)
    msg = "rig.yaml: right camera turned ~0.42°, baseline x1.021, time offset 7.9 ms ±0.5; refining"
    status.update({"ok": True, "rig_message": msg}, now=0.0)
    line = status.update({"ok": True}, now=1.5)                    # a record without one keeps the last
    assert line.endswith("| rig: right camera turned ~0.42°, baseline x1.021, time offset 7.9 ms; refining")
    long = (msg + "; recalibrate: the right camera is turned 1.2° (refined online, but distortion and the "
            "left camera are taken from rig.yaml as they are)")
    assert short_rig_message(long) == "recalibrate: the right camera is turned 1.2°"
    bumped = "the images disagree with the refined rig (bumped?); tracking with the calibration's uncertainty"
    assert short_rig_message(bumped, width=60) == "the images disagree with the refined rig (bumped?)"
    assert len(short_rig_message("x " * 100, width=40)) <= 40
