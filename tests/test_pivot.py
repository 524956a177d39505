"""The head's pivot: the fit, pivot.yaml, ``headplod pivot`` and what ``track --udp`` sends with it.

The end-to-end tests track the synthetic ``neck_turns`` sequence (48 frames:
yaw ±30°, then pitch ±15°, about the neck point ``NECK_PIVOT_HEAD_MM`` =
(0, -80, -90) mm in the head frame), rendered by ``synthetic/`` and tracked
by the real tracker, so the fit sees the tracker's own noise.
"""
import re
import shutil
import socket

import numpy as np
import pytest

from headplod import io
from headplod.capture import open_source
from headplod.capture.synthetic import ensure_dataset
from headplod.cli import main
from headplod.live.loop import run_source
from headplod.live.opentrack import decode_opentrack, opentrack_values
from headplod.live.udp import OpentrackSender
from headplod.live.pivot import PivotFitConfig, fit_pivot, read_pivot, write_pivot
from synthetic.conventions import head_rotation
from synthetic.scenes import NECK_PIVOT_HEAD_MM

# 5 mm: the bound. The tracker's position error on this sequence is ~0.1 mm median, a few mm at the
# extremes of the turns; the fit averages 48 frames.
PIVOT_TOL_MM = 5.0


def exact_turns(pivot_mm, neck_world_mm=(10.0, 50.0, 700.0), yaw_deg=30.0, pitch_deg=15.0, n=20):
    """Poses (P1 (N, 3) mm, axes (N, 3, 3)) of a head turning about ``pivot_mm`` (head frame)."""
    c, q = np.asarray(pivot_mm, float), np.asarray(neck_world_mm, float)
    angles = [(y, 0.0) for y in np.linspace(-yaw_deg, yaw_deg, n)] + \
             [(0.0, p) for p in np.linspace(-pitch_deg, pitch_deg, n)]
    R = np.array([head_rotation(y, p, 0.0) for y, p in angles])   # world from head
    return q - R @ c, np.transpose(R, (0, 2, 1))


def test_fit_recovers_an_exact_pivot():
    positions, axes = exact_turns([5.0, -70.0, -100.0])
    fit = fit_pivot(positions, axes)
    assert fit and fit.pivot_mm == pytest.approx([5.0, -70.0, -100.0], abs=1e-6)
    assert fit.pivot_world_mm == pytest.approx([10.0, 50.0, 700.0], abs=1e-6)
    assert fit.rms_mm < 1e-6 and fit.spread_deg[0] > 5.0


def test_fit_with_noise_reports_its_uncertainty():
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM)
    rng = np.random.default_rng(1)
    fit = fit_pivot(positions + rng.normal(0.0, 1.0, positions.shape), axes)
    assert fit
    assert np.all(np.abs(fit.pivot_mm - NECK_PIVOT_HEAD_MM) < 4 * fit.std_mm + 0.5)
    assert 0.5 < fit.rms_mm < 1.5
    assert "pivot (" in fit.describe() and "residual" in fit.describe()


def test_fit_refuses_yaw_only():
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM)
    fit = fit_pivot(positions[:20], axes[:20])   # left-right only: the height of the pivot is free
    assert not fit and fit.pivot_mm is None
    assert "does not determine" in fit.reason and "nod up and down" in fit.reason


def test_fit_refuses_small_motion_and_few_poses():
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM, yaw_deg=3.0, pitch_deg=2.0)
    assert "does not determine" in fit_pivot(positions, axes).reason
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM, n=5)
    assert "10 tracked poses, 20 needed" in fit_pivot(positions, axes).reason


def test_fit_refuses_a_moving_body():
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM)
    sway = np.zeros_like(positions)
    sway[:, 0] = 60.0 * np.sin(np.linspace(0, 7, len(positions)))   # the shoulders swaying 6 cm
    fit = fit_pivot(positions + sway, axes)
    assert not fit and "did not turn about one point" in fit.reason


def test_fit_drops_outliers():
    positions, axes = exact_turns(NECK_PIVOT_HEAD_MM)
    positions[7] += [0.0, 40.0, 0.0]                 # one wrong pose
    fit = fit_pivot(positions, axes)
    assert fit and fit.dropped == 1 and fit.pivot_mm == pytest.approx(NECK_PIVOT_HEAD_MM, abs=1e-6)


def test_fit_config_and_input_checks():
    with pytest.raises(ValueError, match="min_frames"):
        PivotFitConfig(min_frames=2)
    with pytest.raises(ValueError, match="shape"):
        fit_pivot(np.zeros((30, 3)), np.zeros((29, 3, 3)))


@pytest.fixture(scope="module")
def neck_turns():
    """The rendered neck_turns dataset and its tracked records (the real tracker)."""
    folder = ensure_dataset("neck_turns", quiet=True)
    source = open_source(str(folder))
    records = []
    try:
        run_source(source, on_record=lambda record, result: records.append(record))
    finally:
        source.close()
    return folder, records


@pytest.mark.slow
def test_pivot_recovered_from_tracked_neck_turns(neck_turns):
    _, records = neck_turns
    ok = [r for r in records if r["ok"]]
    assert len(records) == 48 and len(ok) >= 45
    fit = fit_pivot([r["position"] for r in ok], [r["axes"] for r in ok])
    assert fit, fit.reason
    error = np.linalg.norm(fit.pivot_mm - NECK_PIVOT_HEAD_MM)
    print(f"pivot recovered {np.round(fit.pivot_mm, 2)} vs truth {NECK_PIVOT_HEAD_MM}: {error:.2f} mm; "
          f"std {np.round(fit.std_mm, 2)}; rms {fit.rms_mm:.2f} mm")
    assert error < PIVOT_TOL_MM


def _udp_positions_cm(records, pivot_mm):
    """TX, TY, TZ as opentrack receives them, (N, 3) cm, for the ok records."""
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(2.0)
    try:
        with OpentrackSender("127.0.0.1", receiver.getsockname()[1], pivot_mm=pivot_mm) as out:
            sent = sum(out.send(r) for r in records)
        return np.array([decode_opentrack(receiver.recvfrom(1024)[0])[:3] for _ in range(sent)])
    finally:
        receiver.close()


def test_udp_position_still_with_the_pivot(neck_turns):
    _, records = neck_turns
    ok = [r for r in records if r["ok"]]
    fit = fit_pivot([r["position"] for r in ok], [r["axes"] for r in ok])
    moves = {}
    for name, pivot in (("fitted", fit.pivot_mm), ("bridge", (0.0, 0.0, 0.0))):
        xyz_mm = 10.0 * _udp_positions_cm(records, pivot)
        # the largest distance between two positions sent over the whole rotation
        moves[name] = float(np.max(np.linalg.norm(xyz_mm[:, None] - xyz_mm[None], axis=2)))
    print(f"UDP position moves {moves['fitted']:.2f} mm with the pivot, {moves['bridge']:.1f} mm without")
    assert moves["fitted"] < 5.0
    assert 70.0 < moves["bridge"] < 150.0          # about 100 mm: the bridge swings about the neck


def test_pivot_yaml_round_trip_and_errors(tmp_path):
    positions, axes = exact_turns([1.0, -85.0, -95.0])
    fit = fit_pivot(positions, axes)
    path = write_pivot(tmp_path / "pivot.yaml", fit)
    assert read_pivot(path) == pytest.approx([1.0, -85.0, -95.0], abs=1e-9)
    assert not list(tmp_path.glob(".pivot.yaml.*"))          # no temporary left
    with pytest.raises(ValueError, match="no pivot to write"):
        write_pivot(tmp_path / "x.yaml", fit_pivot(positions[:20], axes[:20]))
    with pytest.raises(io.ContractError, match="no such file"):
        read_pivot(tmp_path / "missing.yaml")
    (tmp_path / "bad.yaml").write_text("%YAML:1.0\n---\nother: 1\n")
    with pytest.raises(io.ContractError, match="pivot_mm"):
        read_pivot(tmp_path / "bad.yaml")
    (tmp_path / "far.yaml").write_text("%YAML:1.0\n---\npivot_mm: !!opencv-matrix\n   rows: 1\n   cols: 3\n"
                                       "   dt: d\n   data: [ 0., -800., -900. ]\n")
    with pytest.raises(io.ContractError, match="300 mm"):
        read_pivot(tmp_path / "far.yaml")


@pytest.mark.slow
def test_pivot_command_writes_beside_the_rig_and_track_uses_it(neck_turns, tmp_path, capsys):
    folder, _ = neck_turns
    dataset = tmp_path / "turns"
    shutil.copytree(folder, dataset)
    assert main(["pivot", "--source", str(dataset), "-q"]) == 0
    err = capsys.readouterr().err
    assert (dataset / "pivot.yaml").is_file() and "pivot (" in err
    pivot = read_pivot(dataset / "pivot.yaml")
    assert np.linalg.norm(pivot - NECK_PIVOT_HEAD_MM) < PIVOT_TOL_MM

    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(2.0)
    try:
        port = receiver.getsockname()[1]
        assert main(["track", "--source", str(dataset), "-q", "--frames", "3", "--udp", f"127.0.0.1:{port}"]) == 0
        err = capsys.readouterr().err
        assert f"({dataset / 'pivot.yaml'})" in err and "udp: 3 poses sent" in err
        first = decode_opentrack(receiver.recvfrom(1024)[0])
    finally:
        receiver.close()
    truth = io.read_truth(dataset / "truth.csv")
    position, axes = truth[0]
    assert first[:3] == pytest.approx(opentrack_values(position, axes, pivot)[:3], abs=0.1)  # cm


@pytest.mark.slow
def test_pivot_command_refuses_yaw_only(capsys):
    assert main(["pivot", "--source", "synthetic:yaw_sweep", "-q"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("headplod: no pivot: the motion does not determine the pivot")
    assert "nod up and down" in err[-1]


def test_pivot_command_usage(tmp_path, capsys):
    assert main(["pivot", "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["pivot", "--seconds", "0"])
    assert exc.value.code == 2


class _FakeLive:
    """A dataset posing as live cameras at 16 Hz: each read moves the fake clock (``now``, s) on by 1/16 s
    (exact in binary, so that the time limit falls on a known frame)."""

    PERIOD_S = 1 / 16

    def __init__(self, folder):
        self.inner = open_source(str(folder))
        self.rig, self.markers, self.screen = self.inner.rig, self.inner.markers, self.inner.screen
        self.name, self.warnings = "fake cameras", []
        self.now, self.reads = 100.0, 0

    def read(self, timeout_s=1.0):
        self.now += self.PERIOD_S
        self.reads += 1
        return self.inner.read()

    def close(self):
        self.inner.close()


@pytest.mark.slow
def test_pivot_command_live_stops_on_time_and_says_what_is_missing(neck_turns, monkeypatch, capsys):
    import headplod.live.command as command
    from headplod.cli import build_parser
    from headplod.live.pivot_command import run_pivot

    folder, _ = neck_turns
    live = _FakeLive(folder)
    monkeypatch.setattr(command, "_open_track_source", lambda args, spec: (live, None, True))
    args = build_parser().parse_args(["pivot", "--source", "v4l2:auto", "--seconds", "1.3"])
    # 1.3 s from the first frame at 16 Hz: 22 of the 48 frames (the 22nd at 1.3125 s), the left-right half
    # only: the pivot's height is not determined.
    assert run_pivot(args, clock=lambda: live.now) == 1
    assert live.reads == 22
    err = capsys.readouterr().err
    assert "turn the head left and right" in err.splitlines()[0]
    assert re.search(r"^ +1\.0 s of 1\.3: \d+ poses$", err, re.M)                 # one line a second
    assert err.strip().splitlines()[-1].startswith("headplod: no pivot:") and "nod up and down" in err
