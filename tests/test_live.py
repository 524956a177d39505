"""The live loop through the command line: recording and replay, opentrack UDP, the pose filter, bench live."""
import json
import socket
import threading

import numpy as np
import pytest

from headplod import io
from headplod.cli import main as cli_main
from headplod.live.opentrack import DEFAULT_PIVOT_MM, decode_opentrack, opentrack_values


@pytest.mark.slow
def test_record_while_tracking_then_replay_gives_the_same_records(sample, tmp_path):
    rec = tmp_path / "rec"
    first, second = tmp_path / "first.jsonl", tmp_path / "second.jsonl"
    assert cli_main(["track", "--source", str(sample), "--record", str(rec), "--out", str(first), "-q"]) == 0
    replay = io.Dataset(rec)                        # the recording is a contract dataset folder
    original = io.Dataset(sample)
    assert len(replay) == len(original) == 12
    for a, b in zip(replay, original):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right) and a.t == b.t
    assert cli_main(["track", "--source", str(rec), "--out", str(second), "-q"]) == 0
    r1, r2 = io.read_poses(first), io.read_poses(second)
    keys = ("frame", "t", "ok", "position", "axes", "cov", "reason")
    assert [{k: r[k] for k in keys} for r in r1] == [{k: r[k] for k in keys} for r in r2]
    assert sum(r["ok"] for r in r1) == 12
    assert all(r["skew_ms"] == 0.0 and r["dropped"] == 0 and r["flags"] == [] for r in r1)


def test_udp_output_reaches_a_receiver(sample, tmp_path):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5.0)
    port = receiver.getsockname()[1]
    got = []

    def listen():
        try:
            while len(got) < 12:
                got.append(receiver.recv(64))
        except OSError:
            pass

    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--udp", f"127.0.0.1:{port}", "--out", str(out), "-q"]) == 0
    thread.join(timeout=10)
    receiver.close()
    records = [r for r in io.read_poses(out) if r["ok"]]
    assert len(got) == len(records) == 12
    for data, record in zip(got, records):
        assert len(data) == 48
        np.testing.assert_allclose(decode_opentrack(data),
                                   opentrack_values(record["position"], record["axes"], DEFAULT_PIVOT_MM), atol=1e-9)


@pytest.mark.slow
def test_filter_smooths_the_records_but_keeps_cov(sample, tmp_path):
    raw, smooth = tmp_path / "raw.jsonl", tmp_path / "smooth.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(raw), "-q"]) == 0
    assert cli_main(["track", "--source", str(sample), "--out", str(smooth), "--filter", "0.5,0.0", "-q"]) == 0
    a, b = io.read_poses(raw), io.read_poses(smooth)
    assert a[0]["position"] == b[0]["position"]                      # the first pose passes through
    moved = [np.linalg.norm(np.subtract(x["position"], y["position"])) for x, y in zip(a[1:], b[1:])]
    assert max(moved) > 0.1                                          # a heavy filter lags the sweep
    assert [x["cov"] for x in a] == [y["cov"] for y in b]
    for r in b:
        axes = np.asarray(r["axes"])
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-9)


def test_camera_needs_calibration(capsys):
    assert cli_main(["track", "--camera", "0", "2"]) == 2
    assert "--calib" in capsys.readouterr().err


@pytest.mark.slow
def test_bench_live_reports_rate_latency_and_capture_ratio(sample, tmp_path, capsys):
    out = tmp_path / "live.json"
    assert cli_main(["bench", "live", "--source", str(sample), "--repeats", "1", "--camera-frames", "24",
                     "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    for variant in ("replay", "replay + outputs", "replay + recording"):
        r = report["results"][variant]
        assert r["frames"] == 12 and r["ok"] == 12
        assert r["rate_hz"] > 0 and r["latency_ms_p95"] >= r["latency_ms_p50"] > 0
        assert r["capture_over_tracking"] > 0
    camera = report["camera"]                  # how many frames the tracker had time for is the machine's
    assert camera["preset"] == "glints_lamp" and camera["image_size"] == [640, 480] and camera["rate_hz"] == 120
    assert camera["offered"] == 24 == camera["tracked"] + camera["dropped_busy"] and camera["tracked"] >= 1
    assert camera["latency_ms_max"] >= camera["latency_ms_p99"] >= camera["latency_ms_p50"] > 0
    assert [g["met"] for g in camera["goals"]] == [camera["dropped_busy"] == 0, camera["latency_ms_p99"] <= 8.0]
    assert len(report["load_avg"]["before"]) == 3 and report["load_avg"]["cores"] >= 1
