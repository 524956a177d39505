"""``headplod board`` and ``headplod glasses``: printouts at true scale (issue 25).

The PNGs are read back at 300 dpi and measured with OpenCV: the chessboard's
corner spacing is the requested square size (S / 25.4 * 300 px) within 1 %, a
ChArUco board is found by ``cv2.aruco.CharucoDetector`` with all its corners,
the template's five discs sit at the marker model's positions within 0.5 mm,
and the markers.yaml written beside it reads back as the same model.
"""
import cv2
import numpy as np
import pytest
from PIL import Image

from headplod import io
from headplod.calibration.board import BoardSpec
from headplod.calibration.printouts import PAPERS_MM
from headplod.cli import main as cli_main

DPI = 300
PX_PER_MM = DPI / 25.4


def _board(tmp_path, *args, name="board.png"):
    out = tmp_path / name
    code = cli_main(["board", "--dpi", str(DPI), *args, "--out", str(out)])
    return code, out


@pytest.mark.slow
@pytest.mark.parametrize("cols, rows, square_mm, paper", [(9, 6, 25.0, "a4"), (7, 4, 20.0, "letter"),
                                                          (8, 5, 23.3, "a4")])
def test_chessboard_png_has_the_requested_corners_and_square_size(tmp_path, cols, rows, square_mm, paper):
    code, out = _board(tmp_path, "--cols", str(cols), "--rows", str(rows), "--square-mm", str(square_mm),
                       "--paper", paper)
    assert code == 0 and out.exists()
    gray = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    w_mm, h_mm = PAPERS_MM[paper]
    assert sorted(gray.shape) == sorted((round(h_mm * PX_PER_MM), round(w_mm * PX_PER_MM)))   # the paper
    assert Image.open(out).info["dpi"] == pytest.approx((DPI, DPI), abs=0.01)
    found, corners = cv2.findChessboardCorners(gray, (cols, rows))
    assert found and len(corners) == cols * rows
    corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1),
                               (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-3)).reshape(rows, cols, 2)
    along_rows = np.linalg.norm(np.diff(corners, axis=1), axis=2)
    along_cols = np.linalg.norm(np.diff(corners, axis=0), axis=2)
    expected = square_mm / 25.4 * DPI
    for spacing in (along_rows, along_cols):
        assert np.all(np.abs(spacing / expected - 1) < 0.01), (spacing.min(), spacing.max(), expected)
    # the whole board, end to end, too
    assert np.linalg.norm(corners[0, -1] - corners[0, 0]) == pytest.approx((cols - 1) * expected, rel=0.002)
    # not one with a corner more or less
    assert not cv2.findChessboardCorners(gray, (cols + 1, rows))[0]
    # centred on the page
    centre = corners.reshape(-1, 2).mean(axis=0) + 0.5
    assert centre == pytest.approx((gray.shape[1] / 2, gray.shape[0] / 2), abs=2)


def test_charuco_png_is_detected_with_all_its_corners(tmp_path):
    spec = BoardSpec(kind="charuco", cols=7, rows=5, square_mm=24.0)
    code, out = _board(tmp_path, "--board", "charuco", "--cols", "7", "--rows", "5", "--square-mm", "24")
    assert code == 0
    gray = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))   # calibrate's default
    board = cv2.aruco.CharucoBoard((spec.cols + 1, spec.rows + 1), spec.square_mm, spec.marker, dictionary)
    ch_corners, ch_ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    assert ch_ids is not None and sorted(ch_ids.ravel()) == list(range(spec.cols * spec.rows))
    c = ch_corners.reshape(-1, 2)[np.argsort(ch_ids.ravel())].reshape(spec.rows, spec.cols, 2)
    spacing = np.linalg.norm(np.diff(c, axis=1), axis=2)
    assert np.abs(spacing / (24.0 * PX_PER_MM) - 1).max() < 0.01


@pytest.mark.slow
@pytest.mark.parametrize("ending", [".pdf", ".svg"])
def test_vector_boards_are_the_paper_size(tmp_path, ending):
    for kind in ("chessboard", "charuco"):
        code, out = _board(tmp_path, "--board", kind, "--cols", "9", "--rows", "6", "--square-mm", "25",
                           name=f"{kind}{ending}")
        assert code == 0 and out.stat().st_size > 1000
    head = out.read_bytes()
    if ending == ".svg":
        assert b'width="841.889764pt" height="595.275591pt"' in head[:2000]   # A4 landscape, 1 pt = 1/72 in
    else:
        assert b"MediaBox [ 0 0 841.88976" in head


@pytest.mark.parametrize("args, says", [
    (["--cols", "20", "--rows", "14", "--square-mm", "25"], "does not fit"),
    (["--cols", "9", "--rows", "6", "--square-mm", "40", "--paper", "letter"], "does not fit"),
    (["--cols", "9", "--rows", "6", "--square-mm", "-5"], "square_mm"),
    (["--cols", "1", "--rows", "6", "--square-mm", "25"], "cols"),
    (["--cols", "6", "--rows", "6", "--square-mm", "20"], "different numbers"),
    (["--cols", "9", "--rows", "6", "--square-mm", "25", "--dpi", "5"], "--dpi"),
    (["--cols", "15", "--rows", "12", "--square-mm", "10", "--board", "charuco"], "markers"),
])
def test_a_board_that_cannot_be_made_is_refused_with_one_line_and_no_file(tmp_path, capsys, args, says):
    code, out = _board(tmp_path, *args)
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and says in err, err
    assert list(tmp_path.iterdir()) == []                  # nothing written, not even a temporary file


def test_an_unknown_ending_is_refused(tmp_path, capsys):
    code, out = _board(tmp_path, "--cols", "9", "--rows", "6", "--square-mm", "25", name="board.jpg")
    assert code == 2 and "'.jpg'" in capsys.readouterr().err and list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
# the glasses' template
# ---------------------------------------------------------------------------

def _discs(gray, diameter_mm):
    """Centres (page mm) of the dark round blobs of about ``diameter_mm``."""
    _, binary = cv2.threshold(gray, 128, 255, cv2.THRESH_BINARY_INV)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    area = np.pi * (diameter_mm / 2 * PX_PER_MM) ** 2
    centres = []
    for c in contours:
        m = cv2.moments(c)
        perimeter = cv2.arcLength(c, True)
        if abs(m["m00"] / area - 1) < 0.2 and 4 * np.pi * m["m00"] / perimeter ** 2 > 0.8:
            centres.append(((m["m10"] / m["m00"] + 0.5) / PX_PER_MM, (m["m01"] / m["m00"] + 0.5) / PX_PER_MM))
    return np.array(centres)


@pytest.mark.parametrize("marker_mm", [None, 10.0])
def test_glasses_png_has_the_five_markers_at_the_models_positions(tmp_path, marker_mm):
    out, yaml = tmp_path / "glasses.png", tmp_path / "markers.yaml"
    extra = [] if marker_mm is None else ["--marker-mm", str(marker_mm)]
    assert cli_main(["glasses", *extra, "--dpi", str(DPI), "--out", str(out), "--yaml", str(yaml)]) == 0
    model = io.default_marker_model()
    diameter = model.diameter_mm if marker_mm is None else marker_mm
    gray = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert gray.shape == (round(297 * PX_PER_MM), round(210 * PX_PER_MM))
    found = _discs(gray, diameter)
    assert len(found) == 5, found
    # the sheet shows G from the front: page x = x_G + c, page y = c' - y_G; P1 (the origin) fixes c, c'
    expected = model.points_mm[:, :2] * [1, -1]
    ordered = np.array([found[np.argmin(np.linalg.norm(found - found.mean(0) - (e - expected.mean(0)), axis=1))]
                        for e in expected])
    offset = ordered - expected
    assert np.abs(offset - offset.mean(axis=0)).max() < 0.5, offset   # each marker within 0.5 mm
    assert np.abs(ordered[0] - ordered[2]).max() > 100                   # P0 right of P2 by 130 mm, not a mirror
    assert ordered[0][0] > ordered[2][0] and ordered[3][1] > ordered[1][1]   # x right, y up (P3 below P1)
    # the markers.yaml that goes with it
    back = io.read_markers(yaml)
    assert back == io.MarkerModel(model.points_mm, diameter)


def test_glasses_draws_a_given_model_and_refuses_bad_sizes(tmp_path, capsys):
    custom = io.MarkerModel(np.array([[70.0, 0, 0], [0, 0, 0], [-60.0, 0, 0], [35.0, -25.0, 2.0],
                                      [-45.0, -28.0, 2.0]]), 8.0)
    src = tmp_path / "in.yaml"
    io.write_markers(src, custom)
    out, yaml = tmp_path / "g.png", tmp_path / "out.yaml"
    assert cli_main(["glasses", "--markers", str(src), "--out", str(out), "--yaml", str(yaml)]) == 0
    found = _discs(cv2.imread(str(out), cv2.IMREAD_GRAYSCALE), 8.0)
    assert len(found) == 5
    assert io.read_markers(yaml) == custom
    for name in ("g.svg", "g.pdf"):
        assert cli_main(["glasses", "--out", str(tmp_path / name)]) == 0
    before = sorted(p.name for p in tmp_path.iterdir())
    for args, says in [(["--marker-mm", "0"], "--marker-mm"), (["--marker-mm", "60"], "closest"),
                       (["--dpi", "99999"], "--dpi"), (["--yaml", str(tmp_path / "m.txt")], "--yaml")]:
        assert cli_main(["glasses", *args, "--out", str(tmp_path / "new.png")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and says in err, err
    assert cli_main(["glasses", "--out", str(tmp_path / "x.gif")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.slow
@pytest.mark.parametrize("command,name", [("board", "b.png"), ("board", "b.pdf"), ("glasses", "g.pdf"),
                                          ("glasses", "g.svg")])
def test_a_full_disk_is_one_line_exit_1_and_leaves_nothing(tmp_path, command, name):
    """Writes beyond 8 kB fail as on a full disk (RLIMIT_FSIZE, in a child process): matplotlib's PDF writer
    then raises an AttributeError of its own over the OSError; the command still says what happened."""
    import resource
    import subprocess
    import sys

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

    args = ["--cols", "9", "--rows", "6", "--square-mm", "25"] if command == "board" else ["--yaml", "g.yaml"]
    run = subprocess.run([sys.executable, "-m", "headplod.cli", command, *args, "--out", name], cwd=tmp_path,
                         capture_output=True, text=True, preexec_fn=small_files, timeout=120)
    err = run.stderr.strip().splitlines()
    assert run.returncode == 1, run.stderr
    assert len(err) == 1 and name in err[0] and "disk full" in err[0]
    assert list(tmp_path.iterdir()) == []
