"""Tests of stereo calibration (headplod.calibration.calibrate) on synthetic board images.

The images come from ``synthetic.boards`` (which never imports headplod):
a board rendered through the full OpenCV camera model of a known rig, with
blur and noise. The recovered rig is compared with the rig the images were
made with. Tolerances:

- fx, fy within 0.5 % and the baseline |T| within 0.5 % (the task's
  requirement; measured: chessboard ≈ 0.03 %, ChArUco ≈ 0.3 % at worst, its
  corners are less accurate, ≈ 0.1 px against ≈ 0.045 px, and fewer);
- R within 0.1 degree (chessboard, measured ≈ 0.06) and 0.5 degree
  (ChArUco, measured ≈ 0.3);
- principal point within 3 px (the 1-sigma of a 12-pair calibration is
  ≈ 1 px for a chessboard, 3-5 px for the ChArUco set).

Rendered sets are made once per session (≈ 5 s each).
"""
from __future__ import annotations

import math
from pathlib import Path

import cv2
import datetime

import numpy as np
import pytest

from headplod.calibration import calibrate as cal
from headplod import io
from synthetic.boards import Board, BoardRenderOptions, write_calibration_set
from synthetic.render import project_points, rig_cameras

ROOT = Path(__file__).resolve().parents[1]

CHESS = Board("chessboard", 9, 6, 25.0)
CHESS_SPEC = cal.BoardSpec("chessboard", 9, 6, 25.0)
CHARUCO = Board("charuco", 7, 5, 36.0, 28.0, "DICT_5X5_100")
CHARUCO_SPEC = cal.BoardSpec("charuco", 7, 5, 36.0, 28.0, "DICT_5X5_100")
BAD = ("cut_off", "blurred", "mismatched", "wrong_size")


@pytest.fixture(scope="session")
def default_rig() -> io.Rig:
    return io.read_rig(ROOT / "calib" / "rig.yaml")


@pytest.fixture(scope="session")
def chess_set(tmp_path_factory, default_rig):
    """12 good chessboard pairs plus one bad pair of each kind, left/ right/ layout."""
    folder = tmp_path_factory.mktemp("chess")
    return write_calibration_set(folder, default_rig, CHESS, n_pairs=12, seed=0, layout="subfolders", bad=BAD)


@pytest.fixture(scope="session")
def chess_result(chess_set, tmp_path_factory):
    out = tmp_path_factory.mktemp("chess_out") / "rig.yaml"
    return cal.calibrate_folder(chess_set.folder, CHESS_SPEC, out=out), out


@pytest.fixture(scope="session")
def charuco_set(tmp_path_factory, default_rig):
    """14 ChArUco pairs side by side (leftNN.png, rightNN.png); big enough
    in the images for 5x5-bit markers (see write_calibration_set)."""
    folder = tmp_path_factory.mktemp("charuco")
    return write_calibration_set(folder, default_rig, CHARUCO, n_pairs=14, seed=1, layout="side_by_side",
                                 fill_range=(0.35, 0.6))


@pytest.fixture(scope="session")
def charuco_result(charuco_set):
    return cal.calibrate_folder(charuco_set.folder, CHARUCO_SPEC)


def _rotation_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return math.degrees(float(np.linalg.norm(cv2.Rodrigues(Ra @ Rb.T)[0])))


def _check_rig(rig: io.Rig, truth: io.Rig, rot_tol_deg: float) -> None:
    for name, K, Kt in (("left", rig.K1, truth.K1), ("right", rig.K2, truth.K2)):
        for i, f in ((0, "fx"), (1, "fy")):
            rel = K[i, i] / Kt[i, i] - 1.0
            assert abs(rel) < 0.005, f"{name} {f}: {K[i, i]:.2f} vs truth {Kt[i, i]:.2f} ({100 * rel:+.3f} %)"
        assert np.all(np.abs(K[:2, 2] - Kt[:2, 2]) < 3.0), f"{name} principal point {K[:2, 2]} vs {Kt[:2, 2]}"
    rel_b = rig.baseline_mm / truth.baseline_mm - 1.0
    assert abs(rel_b) < 0.005, f"baseline {rig.baseline_mm:.2f} mm vs {truth.baseline_mm:.2f} mm"
    assert _rotation_deg(rig.R, truth.R) < rot_tol_deg
    cos_t = float(rig.T @ truth.T) / (rig.baseline_mm * truth.baseline_mm)
    assert math.degrees(math.acos(min(1.0, cos_t))) < rot_tol_deg
    assert rig.image_size == truth.image_size


# ---------------------------------------------------------------------------
# accuracy
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_chessboard_recovers_default_rig(chess_set, chess_result, default_rig):
    result, _ = chess_result
    truth = io.read_rig(chess_set.truth_rig)
    assert truth == io.Rig(default_rig.image_size, default_rig.K1, default_rig.D1, default_rig.K2,
                           default_rig.D2, default_rig.R, default_rig.T)
    _check_rig(result.rig, truth, rot_tol_deg=0.1)
    # synthetic corners are good to ≈ 0.05 px
    assert result.rms_stereo_px < 0.15
    assert max(max(e) for e in result.pair_errors_px.values()) < 0.3


@pytest.mark.slow
def test_charuco_side_by_side_recovers_default_rig(charuco_set, charuco_result):
    truth = io.read_rig(charuco_set.truth_rig)
    _check_rig(charuco_result.rig, truth, rot_tol_deg=0.5)
    assert charuco_result.rms_stereo_px < 0.3
    assert len(charuco_result.used) >= 10


@pytest.mark.slow
def test_wide_angle_rig(tmp_path):
    """1280x720, ≈ 100 degree field of view, k1 ≈ -0.32 (fewer, coarser renders for speed)."""
    from synthetic.setups import wide_hd_setup

    setup = wide_hd_setup()
    cs = write_calibration_set(tmp_path, setup, CHESS, n_pairs=10, seed=0,
                               options=BoardRenderOptions(supersample=2))
    result = cal.calibrate_folder(tmp_path, CHESS_SPEC)
    _check_rig(result.rig, io.read_rig(cs.truth_rig), rot_tol_deg=0.1)


# ---------------------------------------------------------------------------
# rejection
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_bad_pairs_rejected_with_reasons(chess_set, chess_result):
    result, _ = chess_result
    rejected = dict(result.rejected)
    assert set(rejected) == set(chess_set.bad), result.rejected
    assert sorted(result.used) == sorted(chess_set.good)
    kinds = {kind: rejected[name] for name, kind in chess_set.bad.items()}
    assert "not found in the right image" in kinds["cut_off"]
    assert "not found in the right image" in kinds["blurred"]
    assert "disagree" in kinds["mismatched"] or "reprojection error" in kinds["mismatched"]
    assert "sizes differ" in kinds["wrong_size"] and "320x240" in kinds["wrong_size"]
    assert result.rig.extra["calibration_pairs"] == 12
    assert result.rig.extra["calibration_pairs_rejected"] == 4


@pytest.mark.slow
def test_too_few_pairs_is_a_clear_error(chess_set):
    pairs = cal.find_pairs(chess_set.folder)
    good = [p for p in pairs if p[0] in chess_set.good][:4]
    bad = [p for p in pairs if p[0] in chess_set.bad]
    with pytest.raises(cal.CalibrationError) as info:
        cal.calibrate_stereo(good + bad, CHESS_SPEC)
    msg = str(info.value)
    # the mismatched pair is found only by the fit, which is not reached
    assert "5 usable pair(s) of 8" in msg and f"at least {cal.MIN_PAIRS}" in msg
    for name in chess_set.bad:
        if chess_set.bad[name] != "mismatched":  # found only after a fit
            assert f"{name}:" in msg
    assert isinstance(info.value, ValueError)


@pytest.mark.slow
def test_outlier_threshold_does_not_reject_good_pairs(chess_set):
    pairs = [p for p in cal.find_pairs(chess_set.folder) if p[0] in chess_set.good]
    result = cal.calibrate_stereo(pairs, CHESS_SPEC, refine=False, clock=lambda: 1_800_000_000.0)
    assert result.rejected == []
    assert "joint refinement" not in result.rig.extra["calibration_method"]
    # the rig says when it was calibrated (headplod doctor's rig age; a copy's file time would not tell)
    assert result.rig.extra["calibration_date"] == "2027-01-15T08:00:00+00:00"


# ---------------------------------------------------------------------------
# rig.yaml
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_rig_yaml_written_and_read_back(chess_result):
    result, out = chess_result
    back = io.read_rig(out)
    assert back == result.rig  # values and extra keys
    for key in ("calibration_rms_left_px", "calibration_rms_right_px", "calibration_rms_stereo_px"):
        assert isinstance(back.extra[key], float) and 0 < back.extra[key] < 1
    assert back.extra["calibration_rms_stereo_px"] == pytest.approx(result.rms_stereo_px)
    assert back.extra["calibration_board"] == "chessboard 9x6 inner corners, 25 mm squares"
    assert back.extra["calibration_pairs"] == len(result.used)
    from headplod.doctor.rig_checks import calibration_time
    assert calibration_time(back) == pytest.approx(
        datetime.datetime.fromisoformat(result.rig.extra["calibration_date"]).timestamp())
    # X_right = R X_left + T: the right camera centre is at +x of the left one
    assert back.right_center_mm[0] > 500


STD_KEYS = {"calibration_std_left": 4, "calibration_std_right": 4,
            "calibration_std_rotation_deg": 3, "calibration_std_translation_mm": 3}


def _check_std(rig: io.Rig, truth: io.Rig, max_rot_deg: float, max_t_mm: float) -> None:
    std = io.rig_calibration_std(rig)
    assert std is not None and set(std) == set(STD_KEYS)
    for key, n in STD_KEYS.items():
        assert std[key].shape == (n,)
        assert np.all(np.isfinite(std[key])) and np.all(std[key] > 0), (key, std[key])
    # not vacuous: a 12-14 pair calibration knows the rig far better than this
    assert np.all(std["calibration_std_rotation_deg"] < max_rot_deg), std["calibration_std_rotation_deg"]
    assert np.all(std["calibration_std_translation_mm"] < max_t_mm), std["calibration_std_translation_mm"]
    # the true rig lies within 5 sigma (the stds are first-order: measured over
    # 10 chessboard and 8 ChArUco sets, mean z^2 = 1.1 and 0.9, max |z| 2.5)
    d_rot = np.degrees(cv2.Rodrigues(rig.R)[0].ravel() - cv2.Rodrigues(truth.R)[0].ravel())
    z_rot = d_rot / std["calibration_std_rotation_deg"]
    z_t = (rig.T - truth.T) / std["calibration_std_translation_mm"]
    assert np.all(np.abs(z_rot) < 5), z_rot
    assert np.all(np.abs(z_t) < 5), z_t


@pytest.mark.slow
def test_rig_yaml_has_calibration_std(chess_set, chess_result):
    result, out = chess_result
    back = io.read_rig(out)
    assert back == result.rig  # the std keys round-trip with the others
    for key, n in STD_KEYS.items():
        assert isinstance(back.extra[key], np.ndarray) and back.extra[key].shape == (1, n)
    _check_std(back, io.read_rig(chess_set.truth_rig), max_rot_deg=0.1, max_t_mm=1.0)
    std = io.rig_calibration_std(back)
    for side in ("left", "right"):
        assert std[f"calibration_std_{side}"].tolist() == pytest.approx(
            [result.std_px[side][k] for k in ("fx", "fy", "cx", "cy")])
    np.testing.assert_allclose(std["calibration_std_rotation_deg"], result.std_rotation_deg)
    np.testing.assert_allclose(std["calibration_std_translation_mm"], result.std_translation_mm)


@pytest.mark.slow
def test_charuco_calibration_std(charuco_set, charuco_result):
    _check_std(charuco_result.rig, io.read_rig(charuco_set.truth_rig), max_rot_deg=0.5, max_t_mm=5.0)


# ---------------------------------------------------------------------------
# pairs in a folder
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_find_pairs_both_layouts(chess_set, charuco_set):
    sub = cal.find_pairs(chess_set.folder)
    assert [n for n, _, _ in sub] == chess_set.names
    assert all(lp.parent.name == "left" and rp.parent.name == "right" for _, lp, rp in sub)
    side = cal.find_pairs(charuco_set.folder)
    assert [n for n, _, _ in side] == charuco_set.names
    assert side[3][1].name == "left03.png" and side[3][2].name == "right03.png"


def _touch_png(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.zeros((4, 4), np.uint8))


# (images to create under the folder, or None for no folder; fragments the ContractError must hold,
#  "{folder}" standing for the folder's path)
BAD_PAIR_FOLDERS = [
    pytest.param(None, ["folder not found"], id="no-folder"),
    pytest.param([], ["no calibration images", "{folder}", "left/"], id="empty-folder"),
    pytest.param(["left/00.png", "right/00.png", "left/01.png", "right/02.png", "left/10.png"],
                 ["2 left image(s) without a right one: 01.png, 10.png",
                  "1 right image(s) without a left one: 02.png"], id="subfolders-unpaired"),
    pytest.param(["left01.jpg", "right01.jpg", "left02.jpg"], ["left02.jpg"], id="side-by-side-unpaired"),
    pytest.param(["left/00.png"], ["no right/ subfolder"], id="only-left-subfolder"),
]


@pytest.mark.parametrize("images, fragments", BAD_PAIR_FOLDERS)
def test_find_pairs_errors(tmp_path, images, fragments):
    folder = tmp_path / "pairs"
    if images is not None:
        folder.mkdir()
        for name in images:
            _touch_png(folder / name)
    with pytest.raises(io.ContractError) as info:
        cal.find_pairs(folder)
    for fragment in fragments:
        assert fragment.format(folder=folder) in str(info.value), (fragment, str(info.value))


def test_find_pairs_natural_order(tmp_path):
    for k in (1, 2, 10):
        _touch_png(tmp_path / f"left{k}.png")
        _touch_png(tmp_path / f"right{k}.png")
    assert [n for n, _, _ in cal.find_pairs(tmp_path)] == ["1", "2", "10"]


# ---------------------------------------------------------------------------
# detection
# ---------------------------------------------------------------------------


def _truth_corners(cs, name: str, side: int, board: Board, ids: np.ndarray) -> np.ndarray:
    cam = rig_cameras(io.read_rig(cs.truth_rig))[side]
    R_wb, t_wb = cs.poses[name]
    obj = board.inner_corners_mm() if board.kind == "chessboard" else \
        np.asarray(board.aruco_board().getChessboardCorners(), float)
    return project_points(cam, obj[ids] @ R_wb.T + t_wb)


@pytest.mark.slow
@pytest.mark.parametrize("which", ["chess", "charuco"])
def test_detect_board_numbers_corners_like_the_board(which, chess_set, charuco_set):
    cs, board, spec = (chess_set, CHESS, CHESS_SPEC) if which == "chess" else (charuco_set, CHARUCO, CHARUCO_SPEC)
    for name in cs.good[:3]:
        for side, paths in ((0, cs.left_paths), (1, cs.right_paths)):
            det = cal.detect_board(cv2.imread(str(paths[name]), cv2.IMREAD_GRAYSCALE), spec)
            assert det, det.reason
            corners, ids = det
            assert corners.shape == (len(ids), 2) and corners.dtype == np.float32
            err = np.linalg.norm(corners - _truth_corners(cs, name, side, board, ids), axis=1)
            assert err.max() < 0.8, (name, side, err.max())
            assert np.allclose(det.object_mm, spec.object_points()[ids] if which == "chess"
                               else det.object_mm)


@pytest.mark.slow
def test_chessboard_numbering_survives_a_half_turn(chess_set):
    img = cv2.imread(str(chess_set.left_paths[chess_set.good[0]]), cv2.IMREAD_GRAYSCALE)
    h, w = img.shape
    det = cal.detect_board(img, CHESS_SPEC)
    det180 = cal.detect_board(np.ascontiguousarray(img[::-1, ::-1]), CHESS_SPEC)
    assert det and det180
    turned = np.column_stack([w - 1 - det180.corners[:, 0], h - 1 - det180.corners[:, 1]])
    assert np.abs(turned - det.corners).max() < 0.2


def test_detect_board_failure_is_a_value():
    blank = np.full((480, 640), 128, np.uint8)
    for spec in (CHESS_SPEC, CHARUCO_SPEC):
        det = cal.detect_board(blank, spec)
        assert not det and det.reason
        corners, ids = det
        assert corners is None and ids is None
    with pytest.raises(ValueError, match="gray image"):
        cal.detect_board(np.zeros((4, 4, 2), np.uint8), CHESS_SPEC)


@pytest.mark.parametrize("args, kwargs, match", [
    (("chessboard", 7, 7, 20.0), {}, "90 degrees"),
    (("circles", 7, 5, 20.0), {}, "kind"),
    (("charuco", 7, 5, 20.0), dict(marker_mm=25.0), "marker_mm"),
    (("charuco", 7, 5, 20.0), dict(dictionary="DICT_NOPE"), "dictionary"),
    (("chessboard", 9, 6, 0.0), {}, "square_mm"),
], ids=["square-board-is-ambiguous", "unknown-kind", "marker-larger-than-square", "unknown-dictionary",
        "zero-square"])
def test_board_spec_checks(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        cal.BoardSpec(*args, **kwargs)


def test_board_spec_describe():
    assert CHARUCO_SPEC.describe() == "charuco 7x5 inner corners, 36 mm squares, 28 mm markers, DICT_5X5_100"


# ---------------------------------------------------------------------------
# coverage guide and report
# ---------------------------------------------------------------------------


def _view(centre_px, size_px, tilt_deg=0.0, axis="x", spec=CHESS_SPEC) -> cal.BoardDetection:
    """A detection made by an affine view of the board: centred at centre_px,
    size_px wide, foreshortened by cos(tilt) along image y (axis 'x') or x."""
    obj = spec.object_points()
    xy = obj[:, :2] - obj[:, :2].mean(axis=0)
    scale = size_px / np.ptp(xy[:, 0])
    c = math.cos(math.radians(tilt_deg))
    sx, sy = (1.0, c) if axis == "x" else (c, 1.0)
    corners = (xy * scale * np.array([sx, sy]) + np.asarray(centre_px, float)).astype(np.float32)
    return cal.BoardDetection(corners, np.arange(len(obj), dtype=np.int32), obj)


def test_coverage_guide():
    size = (640, 480)
    assert cal.coverage_guide([], size) == ["no board found yet: hold the whole board in view of both cameras"]
    centre_only = [_view((320, 240), 250) for _ in range(8)]
    advice = cal.coverage_guide(centre_only, size)
    cells = next(m for m in advice if m.startswith("no board corners yet"))
    assert "top-left" in cells and "bottom-right" in cells and "centre" not in cells
    assert any("tilted up/down" in m for m in advice) and any("tilted left/right" in m for m in advice)

    spots = [(110, 90), (320, 90), (530, 90), (110, 240), (320, 240), (530, 240), (110, 390), (320, 390), (530, 390)]
    good = [_view(p, 200, 30.0, "x" if k % 2 else "y") for k, p in enumerate(spots)]
    assert cal.coverage_guide(good, size) == []
    small = [_view(p, 60, 30.0, "x" if k % 2 else "y") for k, p in enumerate(spots)]
    assert any("small" in m for m in cal.coverage_guide(small, size))
    few = cal.coverage_guide(good[:3], size)
    assert any("at least 6" in m for m in few)
    # plain corner arrays (no board coordinates): no tilt advice
    plain = [d.corners for d in centre_only]
    assert not any("tilted" in m for m in cal.coverage_guide(plain, size))


@pytest.mark.slow
def test_format_report(chess_result):
    result, _ = chess_result
    text = cal.format_report(result)
    assert "baseline: 600.0 mm" in text
    assert "rejected" in text and "sizes differ" in text
    assert f"stereo {result.rms_stereo_px:.3f} px" in text
    assert "chessboard 9x6 inner corners" in text
    line = next(l for l in text.splitlines() if l.startswith("calibration 1-sigma"))
    assert "left fx fy cx cy" in line and "right fx fy cx cy" in line
    assert f"rotation vector {result.std_rotation_deg[0]:.3g}" in line
    assert f"T {result.std_translation_mm[0]:.3g}" in line and "n/a" not in line
