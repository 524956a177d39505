"""Tests of headplod.io: the contract's files (docs/contract.md)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from headplod.io import GAZE_TRUTH_COLUMNS, GazeTruth, read_gaze_truth, write_gaze_truth
from headplod.io import ContractError, Dataset, Frame, MarkerModel, PoseWriter, Rig, Screen, default_marker_model, pose_record, read_markers, read_poses, read_rig, read_screen, read_times, read_truth, rig_calibration_std, write_markers, write_rig, write_screen, write_times, write_truth


# ---------------------------------------------------------------------------
# helpers (the rig and dataset fixtures are in conftest.py)
# ---------------------------------------------------------------------------


def raw_yaml(path: Path, **entries) -> Path:
    """Write entries with cv2.FileStorage directly, bypassing headplod's checks."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    for k, v in entries.items():
        if isinstance(v, np.ndarray):
            fs.write(k, np.ascontiguousarray(v, dtype=np.float64))
        else:
            fs.write(k, v)
    fs.release()
    return path


def rig_entries(rig: Rig, **changes):
    """The rig.yaml entries of ``rig`` in the contract's layout (T 3x1, D 1xN), with changes (None: drop)."""
    e = dict(
        image_width=rig.image_size[0],
        image_height=rig.image_size[1],
        K1=rig.K1, D1=rig.D1[None, :], K2=rig.K2, D2=rig.D2[None, :], R=rig.R, T=rig.T[:, None],
    )
    e.update(changes)
    return {k: v for k, v in e.items() if v is not None}


def assert_contract_error(excinfo, path: Path, *fragments: str):
    err = excinfo.value
    msg = str(err)
    assert isinstance(err, ValueError)
    assert err.path == str(path), (err.path, str(path))
    assert path.name in msg, msg
    for f in fragments:
        assert f in msg, f"{f!r} not in {msg!r}"


# ---------------------------------------------------------------------------
# the sample dataset (made by independent code)
# ---------------------------------------------------------------------------


def test_sweep12_rig_equals_yaml(sweep12_dir):
    rig = read_rig(sweep12_dir / "rig.yaml")
    fs = cv2.FileStorage(str(sweep12_dir / "rig.yaml"), cv2.FILE_STORAGE_READ)
    for key in ("K1", "K2", "R"):
        np.testing.assert_array_equal(getattr(rig, key), fs.getNode(key).mat())
    for key in ("D1", "D2"):
        np.testing.assert_array_equal(getattr(rig, key), fs.getNode(key).mat().ravel())
    np.testing.assert_array_equal(rig.T, fs.getNode("T").mat().ravel())
    fs.release()
    # values copied by hand from the file
    assert rig.image_size == (640, 480)
    assert rig.K1[0, 0] == 644.43411432307755
    assert rig.K2[1, 2] == 230.68579582059849
    assert rig.D1.shape == (5,) and rig.D1[0] == -0.093617702363023136
    assert rig.T.shape == (3,)
    np.testing.assert_array_equal(
        rig.T, [-348.87800301163929, -4.3824756796778503, 27.687699482567155])
    assert rig.extra == {}
    assert rig.path == str(sweep12_dir / "rig.yaml")
    assert rig.baseline_mm == pytest.approx(np.linalg.norm(rig.T))
    # the right camera centre maps to the right camera's origin
    np.testing.assert_allclose(rig.R @ rig.right_center_mm + rig.T, 0, atol=1e-9)


def test_sweep12_frames(sweep12_dir):
    ds = Dataset(sweep12_dir)
    assert len(ds) == 12
    assert ds.indices == list(range(12))
    assert ds.warnings == []
    assert ds.screen is None
    assert ds.markers == default_marker_model()
    frames = list(ds)
    assert [f.index for f in frames] == list(range(12))
    for f in frames:
        assert f.error is None and f.ok
        assert f.left.shape == (480, 640) and f.left.dtype == np.uint8
        assert f.right.shape == (480, 640) and f.right.dtype == np.uint8
    # images are the files' content
    np.testing.assert_array_equal(
        frames[3].right, cv2.imread(str(sweep12_dir / "right" / "000003.png"), cv2.IMREAD_UNCHANGED))


def test_sweep12_times(sweep12_dir):
    ds = Dataset(sweep12_dir)
    assert ds.times == {i: (pytest.approx(0.1 * i), None) for i in range(12)}
    for f in ds:
        assert f.t == pytest.approx(0.1 * f.index, abs=1e-12)
        assert f.t_right is None


def test_sweep12_truth_axes(sweep12_dir):
    truth = read_truth(sweep12_dir / "truth.csv")
    assert sorted(truth) == list(range(12))
    pos, axes = truth[0]
    np.testing.assert_array_equal(pos, [128.147301, -4.763876, 634.213003])
    np.testing.assert_array_equal(axes[2], [0.074418, 0.011800, -0.997157])
    for frame, (pos, axes) in truth.items():
        assert pos.shape == (3,) and axes.shape == (3, 3)
        xi, psi, v = axes
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-5)
        assert np.linalg.det(axes) == pytest.approx(1.0, abs=1e-5)
        np.testing.assert_allclose(np.cross(v, xi), psi, atol=1e-5)
    assert Dataset(sweep12_dir).truth.keys() == truth.keys()


def test_dataset_without_times_uses_30_fps(tmp_path, make_dataset):
    ds = Dataset(make_dataset(tmp_path / "d", n=4))
    assert ds.times is None and ds.truth is None
    assert [f.t for f in ds] == [i / 30 for i in range(4)]


def test_dataset_times_missing_row_is_interpolated(tmp_path, make_dataset):
    folder = make_dataset(tmp_path / "d", n=4)
    write_times(folder / "times.csv", {0: 0.0, 1: 0.1, 3: 0.3})
    ds = Dataset(folder)
    assert any("times.csv has no row for frames 2" in w for w in ds.warnings)
    f2 = ds.frame(2)
    assert f2.t == pytest.approx(0.2) and f2.ok
    assert "interpolated" in f2.warning


# ---------------------------------------------------------------------------
# round trips
# ---------------------------------------------------------------------------


def test_rig_round_trip_keeps_values_and_extras(tmp_path, small_rig):
    rig = small_rig(camera1_serial="A1B2", camera2_serial="007", rms=0.213,
                    n_views=31, E=np.arange(9.0).reshape(3, 3), tags=["ir", 850])
    path = tmp_path / "rig.yaml"
    write_rig(path, rig)
    back = read_rig(path)
    assert back == rig
    assert back.extra["camera2_serial"] == "007"  # stays a string
    assert back.extra["rms"] == 0.213 and back.extra["n_views"] == 31
    # the layout the contract asks for: T 3x1, D 1xN, float64
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert fs.getNode("T").mat().shape == (3, 1)
    assert fs.getNode("D1").mat().shape == (1, 5)
    assert fs.getNode("K1").mat().dtype == np.float64
    assert fs.getNode("image_width").isInt()
    fs.release()


def test_rig_accepts_other_orientations(tmp_path, small_rig):
    e = rig_entries(small_rig(), T=np.array([[-350.0, -4.0, 27.0]]), D1=np.array([[0.1], [-0.05], [0.0], [0.0]]))
    rig = read_rig(raw_yaml(tmp_path / "rig.yaml", **e))
    np.testing.assert_array_equal(rig.T, [-350.0, -4.0, 27.0])
    np.testing.assert_array_equal(rig.D1, [0.1, -0.05, 0.0, 0.0])


def test_markers_round_trip(tmp_path):
    P = np.array([[70.0, 0, 0], [0, 0, 0], [-66, 0, 0], [41, -29, -7.5], [-39, -31, -8.25]])
    model = MarkerModel(P, 4.5)
    write_markers(tmp_path / "markers.yaml", model)
    back = read_markers(tmp_path / "markers.yaml")
    assert back == model
    assert back.diameter_mm == 4.5
    np.testing.assert_array_equal(back.points_mm, P)


def test_markers_diameter_defaults_to_6(tmp_path):
    path = raw_yaml(tmp_path / "markers.yaml", markers=default_marker_model().points_mm)
    assert read_markers(path).diameter_mm == 6.0


def screen_example() -> Screen:
    # a 520 x 320 mm screen 40 mm below the cameras, tilted back by 10 degrees
    c, s = math.cos(math.radians(10)), math.sin(math.radians(10))
    tl = np.array([-260.0, 40.0, 0.0])
    return Screen((1920, 1200), tl, tl + [520.0, 0, 0], tl + [0, 320 * c, 320 * s])


def test_screen_round_trip(tmp_path):
    scr = screen_example()
    write_screen(tmp_path / "screen.yaml", scr)
    back = read_screen(tmp_path / "screen.yaml")
    assert back == scr
    assert back.size_px == (1920, 1200)


def test_truth_round_trip(tmp_path, sweep12_dir):
    truth = read_truth(sweep12_dir / "truth.csv")
    write_truth(tmp_path / "truth.csv", truth)
    back = read_truth(tmp_path / "truth.csv")
    assert back.keys() == truth.keys()
    for k in truth:
        np.testing.assert_array_equal(back[k][0], truth[k][0])
        np.testing.assert_array_equal(back[k][1], truth[k][1])
    # also from (frame, position, axes) tuples, written sorted
    write_truth(tmp_path / "t2.csv", [(5, [1.0, 2.0, 3.0], np.eye(3)), (2, [0.5, 0, 9], np.eye(3))])
    back2 = read_truth(tmp_path / "t2.csv")
    assert list(back2) == [2, 5]
    np.testing.assert_array_equal(back2[5][0], [1.0, 2.0, 3.0])


def test_gaze_truth_round_trip_and_a_missed_screen(tmp_path):
    d = np.array([0.3, -0.1, -1.0]) / np.linalg.norm([0.3, -0.1, -1.0])
    rows = {4: GazeTruth(np.array([12.5, -3.25]), d, np.array([1200.5, 300.0])),
            1: ([0.0, 0.0], [0.0, 0.0, -1.0], [np.nan, np.nan])}           # the ray misses the screen plane
    write_gaze_truth(tmp_path / "gaze_truth.csv", rows)
    lines = (tmp_path / "gaze_truth.csv").read_text().splitlines()
    assert lines[0] == ",".join(GAZE_TRUTH_COLUMNS) and lines[1].endswith(",,")      # sorted; empty pixel cells
    back = read_gaze_truth(tmp_path / "gaze_truth.csv")
    assert list(back) == [1, 4]
    np.testing.assert_array_equal(back[4].eye_in_head_deg, [12.5, -3.25])
    np.testing.assert_array_equal(back[4].direction, d)
    np.testing.assert_array_equal(back[4].screen_px, [1200.5, 300.0])
    assert np.isnan(back[1].screen_px).all()


def test_synthetic_gaze_truth_reads_back(tmp_path):
    from synthetic.dataset import true_gaze, write_dataset
    from synthetic.scenes import make_scene

    scene = make_scene("static", n_frames=3)
    out = write_dataset(tmp_path / "ds", scene, seed=2)
    back = read_gaze_truth(out / "gaze_truth.csv")
    expected = true_gaze(scene, seed=2)
    assert list(back) == [0, 1, 2]
    for k, row in back.items():
        np.testing.assert_allclose(row.direction, expected.direction[k], atol=1e-6)   # 6 decimals
        np.testing.assert_allclose(row.screen_px, expected.screen_px[k], atol=1e-6)
    assert len(Dataset(out)) == 3                       # the dataset reader is not disturbed by it


@pytest.mark.parametrize("line, fragment", [
    ("0,1,2,0,0,1,5", "7 fields"),
    ("0,1,2,0,0,2,5,6", "length 2"),
    ("0,1,2,0,0,1,,6", "one of gaze_px_x"),
    ("0,x,2,0,0,1,5,6", "eye_h_deg"),
])
def test_bad_gaze_truth_is_a_contract_error(tmp_path, line, fragment):
    path = tmp_path / "gaze_truth.csv"
    path.write_text(",".join(GAZE_TRUTH_COLUMNS) + "\n" + line + "\n")
    with pytest.raises(ContractError, match=fragment):
        read_gaze_truth(path)
    path.write_text("frame,x,y\n")
    with pytest.raises(ContractError, match="header"):
        read_gaze_truth(path)
    with pytest.raises(ValueError, match="length"):
        write_gaze_truth(path, {0: ([0, 0], [0, 0, 2.0], [1.0, 2.0])})


def test_the_tracker_never_reads_the_gaze_truth():
    """Where the viewer looks is for benches: no module of tracking/, live/ or capture/ names the file."""
    root = Path(__file__).resolve().parents[1] / "headplod"
    for package in ("tracking", "live", "capture"):
        for path in (root / package).rglob("*.py"):
            text = path.read_text(encoding="utf-8")
            assert "gaze_truth" not in text and "read_gaze_truth" not in text, path


def test_times_round_trip(tmp_path):
    times = {0: (0.0, 0.0021), 1: (1 / 30, None), 2: (2 / 30, 2 / 30 + 0.0021)}
    write_times(tmp_path / "times.csv", times)
    assert (tmp_path / "times.csv").read_text().splitlines()[0] == "frame,t,t_right"
    assert read_times(tmp_path / "times.csv") == times
    write_times(tmp_path / "t2.csv", {3: 0.5, 1: 0.25})
    assert (tmp_path / "t2.csv").read_text().splitlines()[0] == "frame,t"
    assert read_times(tmp_path / "t2.csv") == {1: (0.25, None), 3: (0.5, None)}


def pose_examples():
    axes = cv2.Rodrigues(np.array([0.1, -0.2, 0.05]))[0]
    return [
        pose_record(0, 0.0, True, position=np.array([128.1, -4.7, 634.2]), axes=axes,
                    cov=np.array([[0.5, 0.1], [0.1, 0.8]]), n_markers=np.int64(5),
                    poi=np.array([960.5, 600.25]), timings={"detect_ms": np.float32(1.5)}),
        pose_record(1, 1 / 30, False, reason="left image: 4 marker blobs, 5 needed"),
        pose_record(3, 0.1, True, position=[1.0, 2.0, 3.0], axes=np.eye(3), cov=np.eye(2),
                    reason="P3 hidden in the right view"),
    ]


def test_poses_round_trip(tmp_path):
    records = pose_examples()
    path = tmp_path / "poses.jsonl"
    with PoseWriter(path) as out:
        for r in records:
            out.write(r)
    lines = path.read_text().splitlines()
    assert len(lines) == 3
    assert list(json.loads(lines[0]))[:7] == ["frame", "t", "ok", "position", "axes", "cov", "reason"]
    back = read_poses(path)
    assert back == records
    assert back[0]["timings"] == {"detect_ms": 1.5}
    assert back[1]["position"] is None and back[1]["axes"] is None and back[1]["cov"] is None


def test_pose_writer_stdout(capsys):
    with PoseWriter("-") as out:
        out.write(frame=7, t=0.25, ok=False, reason="no blobs")
    line = capsys.readouterr().out
    assert json.loads(line) == {"frame": 7, "t": 0.25, "ok": False, "position": None,
                                "axes": None, "cov": None, "reason": "no blobs"}


# ---------------------------------------------------------------------------
# pose records: programming errors
# ---------------------------------------------------------------------------


def test_pose_record_types_are_json_native():
    rec = pose_examples()[0]
    assert type(rec["position"][0]) is float and type(rec["axes"][2][1]) is float
    assert type(rec["n_markers"]) is int and rec["poi"] == [960.5, 600.25]
    json.dumps(rec, allow_nan=False)  # does not raise
    assert pose_record(2, 0.1, False, reason="x", residual=float("nan"))["residual"] is None


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(position=[1.0, np.nan, 3.0], axes=np.eye(3), cov=np.eye(2)), "NaN or inf"),
    (dict(position=[1.0, 2.0, 3.0], axes=np.diag([1.0, np.inf, 1.0]), cov=np.eye(2)), "NaN or inf"),
    (dict(position=[1.0, 2.0, 3.0], axes=np.diag([1.0, 1.0, -1.0]), cov=np.eye(2)), "left-handed"),
    (dict(position=[1.0, 2.0, 3.0], axes=np.eye(3) * 1.01, cov=np.eye(2)), "not orthonormal"),
    (dict(position=[1.0, 2.0], axes=np.eye(3), cov=np.eye(2)), "shape"),
    (dict(position=[1.0, 2.0, 3.0], axes=np.eye(3)), "cov"),
    (dict(position=[1.0, 2.0, 3.0], axes=np.eye(3), cov=[[1.0, 0.0], [0.0, -1.0]]), "positive definite"),
])
def test_pose_record_rejects_bad_pose(kwargs, fragment):
    with pytest.raises(ValueError, match=None) as e:
        pose_record(3, 0.1, True, **kwargs)
    assert fragment in str(e.value)


@pytest.mark.parametrize("t, kwargs, match", [
    (0.1, dict(), "reason"),
    (0.1, dict(reason="  "), "reason"),
    (0.1, dict(position=[1, 2, 3], reason="x"), "no pose"),
    (float("nan"), dict(reason="x"), "t is"),
], ids=["no-reason", "blank-reason", "failure-with-a-pose", "nan-time"])
def test_pose_record_failure_rules(t, kwargs, match):
    with pytest.raises(ValueError, match=match):
        pose_record(3, t, False, **kwargs)


def test_pose_writer_needs_increasing_frames(tmp_path):
    with PoseWriter(tmp_path / "p.jsonl") as out:
        out.write(pose_record(2, 0.0, False, reason="x"))
        with pytest.raises(ValueError, match="increasing frame order"):
            out.write(pose_record(2, 0.0, False, reason="x"))
    assert len(read_poses(tmp_path / "p.jsonl")) == 1


GOOD_POSE_LINE = json.dumps(pose_record(0, 0.0, False, reason="x"))


@pytest.mark.parametrize("second_line, fragments", [
    ('{"frame": 1, "t": NaN, "ok": false}', ["line 2", "invalid JSON"]),
    ('{"frame": 1, "t": 0.1, "ok": false, "reason": "x"}', ["line 2", "missing", "position"]),
    (GOOD_POSE_LINE, ["line 2", "frame 0 after frame 0"]),
], ids=["nan-is-not-json", "missing-key", "repeated-frame"])
def test_read_poses_bad_line_names_file_and_line(tmp_path, second_line, fragments):
    path = tmp_path / "poses.jsonl"
    path.write_text(GOOD_POSE_LINE + "\n" + second_line + "\n")
    with pytest.raises(ContractError) as e:
        read_poses(path)
    assert_contract_error(e, path, *fragments)


# ---------------------------------------------------------------------------
# marker model and V
# ---------------------------------------------------------------------------


def test_default_model_view_dir_is_z():
    m = default_marker_model()
    np.testing.assert_allclose(m.view_dir_G, [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(m.axes_G, np.eye(3), atol=1e-15)
    assert m.diameter_mm == 6.0
    np.testing.assert_array_equal(m.points_mm[3], [40, -30, 0])


def test_curved_model_view_dir_by_hand():
    # P3, P4 pushed back to z = -8: the three triangle normals, by hand, are
    # (0,-520,1950), (0,-520,1950) and -(0,640,-2400), all along (0,-4,15).
    P = default_marker_model().points_mm.copy()
    P[3, 2] = P[4, 2] = -8.0
    V = MarkerModel(P).view_dir_G
    np.testing.assert_allclose(V, np.array([0.0, -4.0, 15.0]) / math.sqrt(241.0), atol=1e-12)
    assert math.degrees(math.atan2(4, 15)) == pytest.approx(14.93, abs=0.01)
    axes = MarkerModel(P).axes_G
    np.testing.assert_allclose(axes[0], [1.0, 0, 0], atol=1e-12)  # Ξ ⊥ V keeps x
    np.testing.assert_allclose(axes[1], np.cross(V, axes[0]), atol=1e-12)


def test_asymmetric_model_view_dir_is_mean_of_normals():
    # only P3 pushed back: normals (0,-4,15)/√241, (0,0,1) and (3,-4,30)/√925 (by hand)
    P = default_marker_model().points_mm.copy()
    P[3, 2] = -8.0
    mean = (np.array([0, -4, 15]) / math.sqrt(241) + np.array([0, 0, 1.0])
            + np.array([3, -4, 30]) / math.sqrt(925)) / 3
    np.testing.assert_allclose(MarkerModel(P).view_dir_G, mean / np.linalg.norm(mean), atol=1e-12)


# ---------------------------------------------------------------------------
# screen
# ---------------------------------------------------------------------------


def test_screen_pixel_to_world_corners():
    scr = screen_example()
    w, h = scr.size_px
    got = scr.pixel_to_world([[0, 0], [w, 0], [0, h], [w, h], [w / 2, h / 2]])
    assert got.shape == (5, 3)
    np.testing.assert_allclose(got[0], scr.top_left, atol=1e-12)
    np.testing.assert_allclose(got[1], scr.top_right, atol=1e-12)
    np.testing.assert_allclose(got[2], scr.bottom_left, atol=1e-12)
    np.testing.assert_allclose(got[3], scr.top_right + scr.bottom_left - scr.top_left, atol=1e-12)
    np.testing.assert_allclose(got[4], (scr.top_right + scr.bottom_left) / 2, atol=1e-12)


def test_screen_intersect_ray():
    scr = screen_example()
    head = np.array([30.0, -20.0, 600.0])
    target = scr.pixel_to_world([1234.5, 321.0])
    np.testing.assert_allclose(scr.intersect_ray(head, (target - head) * 3.7), [1234.5, 321.0], atol=1e-9)
    assert scr.intersect_ray(head, head - target) is None  # screen behind
    assert scr.intersect_ray(head, scr.top_right - scr.top_left) is None  # parallel


# ---------------------------------------------------------------------------
# bad files: ContractError naming the file
# ---------------------------------------------------------------------------


def _text(text):
    """A writer of the file's text as given."""
    return lambda path, rig: path.write_text(text)


def _screen_yaml(**changes):
    """A writer of screen.yaml for screen_example() with changed entries."""
    scr = screen_example()
    entries = dict(size_px=np.array([[1920.0, 1200.0]]), top_left=scr.top_left, top_right=scr.top_right,
                   bottom_left=scr.bottom_left)
    entries.update(changes)
    return lambda path, rig: raw_yaml(path, **entries)


def _truth_with_a_stretched_axis(path, rig):
    """truth.csv of two frames whose second row's Ξ is (0.5, 0, 0): no longer a unit vector."""
    write_truth(path, {0: ([0.0, 0.0, 600.0], np.eye(3)), 1: ([10.0, 0.0, 600.0], np.eye(3))})
    header, first, second = path.read_text().splitlines()
    row = second.split(",")
    assert header.split(",")[4] == "xi_x"
    row[4] = "0.5"
    path.write_text("\n".join([header, first, ",".join(row)]) + "\n")


_SCREEN = screen_example()

# (file name, reader, writer(path, rig) or None for no file, fragments the message must hold)
BAD_FILES = [
    pytest.param("rig.yaml", read_rig, _text("%YAML:1.0\nK1: [1, 2\nT: }\n"), ["cannot be parsed"],
                 id="rig-malformed-yaml"),
    pytest.param("rig.yaml", read_rig, None, ["not found"], id="rig-missing"),
    pytest.param("rig.yaml", read_rig, lambda path, rig: raw_yaml(path, **rig_entries(rig, T=None)),
                 ["key 'T' is missing", "image_width"], id="rig-missing-key"),
    pytest.param("screen.yaml", read_screen, _text(""), ["empty"], id="screen-empty"),
    pytest.param("screen.yaml", read_screen, _screen_yaml(size_px=np.array([[1920.0, 1200.5]])),
                 ["size_px", "positive integer"], id="screen-fractional-size"),
    pytest.param("screen.yaml", read_screen,
                 _screen_yaml(bottom_left=2 * _SCREEN.top_right - _SCREEN.top_left),
                 ["do not span a plane"], id="screen-corners-on-a-line"),
    pytest.param("markers.yaml", read_markers,
                 lambda path, rig: raw_yaml(path, markers=default_marker_model().points_mm, diamter=4.0),
                 ["unknown key", "diamter"], id="markers-unknown-key"),
    pytest.param("markers.yaml", read_markers,
                 lambda path, rig: raw_yaml(path, markers=default_marker_model().points_mm, diameter=0.0),
                 ["diameter"], id="markers-zero-diameter"),
    pytest.param("times.csv", read_times, _text("frame,time\n0,0.0\n"), ["header is 'frame,time'", "'frame,t'"],
                 id="times-header"),
    pytest.param("times.csv", read_times, _text("frame,t\n0,0.0\n1,abc\n"), ["line 3", "'abc'"],
                 id="times-not-a-number"),
    pytest.param("times.csv", read_times, _text("frame,t\n0,0.0\n0,0.1\n"), ["frame 0 appears twice"],
                 id="times-repeated-frame"),
    pytest.param("truth.csv", read_truth, _truth_with_a_stretched_axis, ["line 3 (frame 1)", "not orthonormal"],
                 id="truth-not-orthonormal"),
]


@pytest.mark.parametrize("name, reader, write, fragments", BAD_FILES)
def test_bad_file_is_a_contract_error_naming_it(tmp_path, small_rig, name, reader, write, fragments):
    path = tmp_path / name
    if write is not None:
        write(path, small_rig())
    with pytest.raises(ContractError) as e:
        reader(path)
    assert_contract_error(e, path, *fragments)


@pytest.mark.parametrize("key, value, fragments", [
    ("T", np.array([[1.0], [2.0]]), ["key 'T' has shape 2x1, expected 3x1 or 1x3"]),
    ("K1", np.eye(2), ["key 'K1' has shape 2x2, expected 3x3"]),
    ("D2", np.zeros((1, 6)), ["key 'D2' has 6 coefficients", "1xN or Nx1"]),
    ("R", np.array([[0.1, 0.2, 0.3]]), ["key 'R' has shape 1x3", "cv2.Rodrigues"]),
    ("K2", np.array([[62.0, 0, 31], [0, 63, 23], [0, 0, np.nan]]), ["key 'K2'", "non-finite"]),
    ("T", np.array([[np.inf], [0.0], [0.0]]), ["key 'T'", "non-finite"]),
    ("R", 1.01 * np.eye(3), ["key 'R' is not a rotation", "max |R Rᵀ − I| = 0.0201"]),
    ("R", np.diag([1.0, 1.0, -1.0]), ["det(R) = -1", "reflection"]),
    ("K1", np.array([[60.0, 0, 0], [0, 61, 0], [32, 24, 1]]), ["not upper-triangular", "transposed"]),
    ("K1", np.array([[-60.0, 0, 32], [0, 61, 24], [0, 0, 1]]), ["fx", "positive"]),
    ("K2", np.array([[62.0, 0, 31], [0, 63, 23], [0, 0, 2]]), ["K2[2,2] = 2, expected 1"]),
    ("T", np.array([[-0.35], [0.0], [0.02]]), ["baseline", "metres"]),
    ("image_width", 64.5, ["key 'image_width' is 64.5, expected a positive integer"]),
    ("image_height", "tall", ["key 'image_height' is the string 'tall'"]),
])
def test_bad_rig_values(tmp_path, key, value, fragments, small_rig):
    path = raw_yaml(tmp_path / "rig.yaml", **rig_entries(small_rig(), **{key: value}))
    with pytest.raises(ContractError) as e:
        read_rig(path)
    assert_contract_error(e, path, *fragments)


def test_rig_constructor_validates(small_rig):
    r = small_rig()
    with pytest.raises(ContractError, match="Rig: field 'R' is not a rotation"):
        Rig(r.image_size, r.K1, r.D1, r.K2, r.D2, 2 * r.R, r.T)


# ---------------------------------------------------------------------------
# the calibration's uncertainty in rig.yaml
# ---------------------------------------------------------------------------

CAL_STD = dict(
    calibration_std_left=np.array([[0.5, 0.48, 0.7, 0.6]]),
    calibration_std_right=np.array([[0.52, 0.5, 0.71, 0.62]]),
    calibration_std_rotation_deg=np.array([[0.02, 0.04, 0.01]]),
    calibration_std_translation_mm=np.array([[0.13, 0.09, 0.3]]),
)


def test_rig_calibration_std_round_trip(tmp_path, small_rig):
    assert rig_calibration_std(small_rig()) is None
    assert rig_calibration_std(small_rig(rms=0.2)) is None
    rig = small_rig(**CAL_STD)
    path = tmp_path / "rig.yaml"
    write_rig(path, rig)
    back = read_rig(path)
    assert back == rig
    std = rig_calibration_std(back)
    assert set(std) == set(CAL_STD)
    for k, v in CAL_STD.items():
        assert std[k].shape == (v.size,) and std[k].dtype == np.float64
        np.testing.assert_array_equal(std[k], v.ravel())
    # only some keys, other orientations
    part = rig_calibration_std(small_rig(calibration_std_translation_mm=[[0.1], [0.2], [0.3]]))
    assert list(part) == ["calibration_std_translation_mm"]
    np.testing.assert_array_equal(part["calibration_std_translation_mm"], [0.1, 0.2, 0.3])


@pytest.mark.parametrize("key, value, fragments", [
    ("calibration_std_left", np.array([[0.5, 0.5, 0.7]]), ["key 'calibration_std_left' has shape 1x3",
                                                           "expected 1x4"]),
    ("calibration_std_rotation_deg", np.eye(3), ["key 'calibration_std_rotation_deg' has shape 3x3"]),
    ("calibration_std_translation_mm", np.array([[0.1, np.nan, 0.3]]), ["non-finite"]),
    ("calibration_std_right", np.array([[0.5, -0.5, 0.7, 0.6]]), ["negative value -0.5 at index 1"]),
    ("calibration_std_translation_mm", "small", ["the string 'small', expected 3 numbers"]),
    ("calibration_std_rotation_deg", 0.1, ["has shape a scalar"]),
])
def test_bad_rig_calibration_std(tmp_path, key, value, fragments, small_rig):
    path = raw_yaml(tmp_path / "rig.yaml", **rig_entries(small_rig()), **{key: value})
    rig = read_rig(path)  # extra keys are free for read_rig ...
    with pytest.raises(ContractError) as e:
        rig_calibration_std(rig)  # ... the helper checks them
    assert_contract_error(e, path, key, *fragments)
    with pytest.raises(ContractError, match=f"Rig.extra: key '{key}'"):
        rig_calibration_std(small_rig(**{key: value}))


@pytest.mark.parametrize("change, fragments", [
    (lambda P: P + [1.0, 0.0, 0.0], ["P1 (the bridge)", "expected the origin"]),
    (lambda P: P.T, ["shape 3x5, expected 5x3", "transposed"]),
    (lambda P: P * [-1.0, 1.0, 1.0], ["P0 has x = -65", "expected x > 0"]),
    (lambda P: np.vstack([P[:2], [[-65, 2, 0]], P[3:]]), ["P2", "x axis"]),
    (lambda P: np.vstack([P[:3], [[30, 0, 0]], P[4:]]), ["P3", "off the line"]),
])
def test_bad_markers(tmp_path, change, fragments):
    P = change(default_marker_model().points_mm.copy())
    path = raw_yaml(tmp_path / "markers.yaml", markers=P)
    with pytest.raises(ContractError) as e:
        read_markers(path)
    assert_contract_error(e, path, *fragments)


# ---------------------------------------------------------------------------
# bad datasets
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("remove, fragment", [
    ("right", "'right/' is missing"),
    ("rig.yaml", "not found"),
], ids=["frame-directory", "rig"])
def test_dataset_missing_part_names_it(tmp_path, make_dataset, remove, fragment):
    folder = make_dataset(tmp_path / "d", n=2)
    target = folder / remove
    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink()
    with pytest.raises(ContractError) as e:
        Dataset(folder)
    assert_contract_error(e, target, fragment)


def test_bad_frames_do_not_stop_the_others(tmp_path, make_dataset):
    folder = make_dataset(tmp_path / "d", n=8)
    (folder / "right" / "000005.png").unlink()                                   # missing
    data = (folder / "left" / "000002.png").read_bytes()
    (folder / "left" / "000002.png").write_bytes(data[: len(data) // 2])         # truncated
    cv2.imwrite(str(folder / "right" / "000003.png"), np.zeros((24, 32), np.uint8))  # wrong size
    (folder / "left" / "000004.png").write_text("not an image")                  # not a PNG
    cv2.imwrite(str(folder / "left" / "000006.png"), np.zeros((48, 64), np.uint16))  # 16-bit
    cv2.imwrite(str(folder / "right" / "000007.png"), np.full((48, 64, 3), 9, np.uint8))  # colour
    (folder / "left" / "notes.txt").write_text("hello")                          # stray file

    ds = Dataset(folder)
    assert ds.indices == list(range(8))
    assert "left has 8 frames, right has 7: right/000005.png missing" in ds.warnings
    assert any(w.startswith("left/notes.txt: ignored") for w in ds.warnings)

    frames = {f.index: f for f in ds}  # iterating does not raise
    assert frames[5].error == "right/000005.png: missing"
    assert frames[2].error.startswith("left/000002.png: unreadable")
    assert frames[3].error == "right/000003.png: 32x24, rig says 64x48"
    assert frames[4].error.startswith("left/000004.png: unreadable (not a PNG")
    assert frames[6].error.startswith("left/000006.png: 16-bit")
    for i in (2, 3, 4, 5, 6):
        assert frames[i].left is None and frames[i].right is None and not frames[i].ok
    for i in (0, 1, 7):
        assert frames[i].error is None
        assert frames[i].left.shape == (48, 64) and frames[i].right.shape == (48, 64)
        assert frames[i].left.dtype == np.uint8
    assert frames[7].warning == "right/000007.png: 3-channel image converted to gray, expected 8-bit grayscale"
    assert (frames[7].right == 9).all()
    assert frames[0].warning is None


def test_frame_lookup(tmp_path, make_dataset):
    ds = Dataset(make_dataset(tmp_path / "d", n=3))
    f = ds.frame(1)
    assert isinstance(f, Frame) and f.index == 1 and f.t == pytest.approx(1 / 30)
    with pytest.raises(KeyError):
        ds.frame(3)


def test_dataset_optional_files(tmp_path, make_dataset):
    folder = make_dataset(tmp_path / "d", n=2)
    P = default_marker_model().points_mm.copy()
    P[3, 2] = P[4, 2] = -8.0
    write_markers(folder / "markers.yaml", MarkerModel(P, 5.0))
    write_screen(folder / "screen.yaml", screen_example())
    ds = Dataset(folder)
    assert ds.markers == MarkerModel(P, 5.0)
    assert ds.screen == screen_example()
    (folder / "screen.yaml").write_text("%YAML:1.0\nsize_px: [1920, 1080]\n")
    with pytest.raises(ContractError) as e:
        Dataset(folder)
    assert_contract_error(e, folder / "screen.yaml", "key 'top_left' is missing")


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-500, 2500), y=st.floats(-500, 1700),
       head=st.tuples(st.floats(-300, 300), st.floats(-300, 300), st.floats(100, 1500)))
def test_screen_intersect_inverts_pixel_to_world(x, y, head):
    scr = screen_example()
    head = np.array(head)
    target = scr.pixel_to_world([x, y])
    got = scr.intersect_ray(head, target - head)
    assert got is not None
    np.testing.assert_allclose(got, [x, y], atol=1e-6)
