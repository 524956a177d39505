"""``headplod preview`` (issue 25): the annotated pictures, what they show, the advice, the refusals.

What is measured, not just that something runs: the PNGs' count and size;
the blobs' centroids and the identified P0..P4 against the truth of the
sample dataset (tests/data/sweep12, its truth.csv projected through its
rig.yaml) within 1 px; every left marker's epipolar curve passes within 1 px
of its right partner (and back); the threshold mask is the one detection
counted; saturated, missing, extra, skewed and slow frames give their
advice; and the refusals are one line with the exit status and nothing
written.
"""
import shutil

import cv2
import numpy as np
import pytest

from headplod import io
from headplod.cli import main as cli_main
from headplod.live import preview
from headplod.live.preview import OUT_NAME, Previewer
from headplod.live.preview_analysis import AdviceSettings, epipolar_curves, threshold_mask
from headplod.live.preview_picture import NO_RIG_NOTE, composite_size, render
from headplod.tracking.detect import DetectionParams, detect_blobs, estimate_background

W, H = 640, 480


def _truth_px(dataset: io.Dataset, index: int) -> np.ndarray:
    """The true P0..P4 of a frame in both images, (2, 5, 2) px, from truth.csv through the rig."""
    rig, model = dataset.rig, np.asarray(dataset.markers.points_mm, float)
    position, axes = dataset.truth[index]
    world = position + model @ axes            # axes' rows are Ξ, Ψ, V: G's axes in the world frame
    left = cv2.projectPoints(world, np.zeros(3), np.zeros(3), rig.K1, rig.D1)[0].reshape(-1, 2)
    right = cv2.projectPoints(world, cv2.Rodrigues(rig.R)[0], rig.T, rig.K2, rig.D2)[0].reshape(-1, 2)
    return np.stack([left, right])


def _distance_to_curve(point, curve) -> float:
    """Least distance from a point (2,) to a polyline (k, 2), px."""
    a, b = curve[:-1], curve[1:]
    d = b - a
    s = np.clip(np.einsum("ij,ij->i", point - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-12), 0, 1)
    return float(np.min(np.linalg.norm(a + s[:, None] * d - point, axis=1)))


@pytest.fixture(scope="module")
def sweep(sweep12_dir):
    return io.Dataset(sweep12_dir)


def _one_line_error(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("headplod: preview: "), lines[0]
    return lines[0]


# ---------------------------------------------------------------------------
# the pictures
# ---------------------------------------------------------------------------

@pytest.mark.slow
def test_headless_writes_the_frames_asked_at_the_composite_size(sweep12_dir, sweep, tmp_path, capsys):
    out = tmp_path / "pictures"
    assert cli_main(["preview", "--source", str(sweep12_dir), "--frames", "3", "--out", str(out), "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [OUT_NAME.format(k) for k in range(3)]   # nothing else left
    cw, ch = composite_size(W, H)
    assert ch > H and cw == 2 * W
    assert f"wrote 3 annotated frames to {out}" in capsys.readouterr().out
    for k in range(3):
        picture = cv2.imread(str(out / OUT_NAME.format(k)), cv2.IMREAD_COLOR)
        assert picture.shape == (ch, cw, 3)
        b, g, r = (picture[..., i].astype(int) for i in range(3))
        coloured = (np.maximum(np.maximum(b, g), r) - np.minimum(np.minimum(b, g), r)) > 40
        # Every true marker position, in both halves, is annotated (tint, cross, line: not the gray image) ...
        for cam, points in enumerate(_truth_px(sweep, k)):
            for u, v in np.round(points).astype(int):
                assert coloured[v, u + cam * W], (k, cam, u, v)
        # ... and the dark background far from the glasses is left as it was: gray.
        assert not coloured[H - 60:H - 20, 40:W - 40].any()
        assert not coloured[H - 60:H - 20, W + 40:2 * W - 40].any()


def test_the_analysis_finds_the_truth_and_the_epipolar_lines_meet_the_partners(sweep):
    previewer = Previewer(sweep.rig, sweep.markers)
    for index in sweep.indices[:3]:
        analysis = previewer.analyse(sweep.frame(index))
        truth = _truth_px(sweep, index)
        assert analysis.error is None and analysis.identified and analysis.pose_ok, analysis.reason
        assert analysis.advice == []
        for cam in range(2):
            view = analysis.views[cam]
            assert len(view.blobs) == 5
            # every true marker has a blob within 1 px, and the label P_k sits on the true P_k
            nearest = np.linalg.norm(view.blobs.centers_px[None] - truth[cam][:, None], axis=2).min(axis=1)
            assert nearest.max() < 1.0, nearest
            assert np.linalg.norm(view.markers_px - truth[cam], axis=1).max() < 1.0
            assert len(view.epilines) == 5 and all(len(c) > 10 for c in view.epilines)
        for cam in range(2):
            other = 1 - cam
            _, curves = epipolar_curves(analysis.views[cam].markers_px, sweep.rig, cam)
            for k, curve in enumerate(curves):
                assert _distance_to_curve(analysis.views[other].markers_px[k], curve) < 1.0
                assert _distance_to_curve(truth[other][k], curve) < 1.0
            # and a marker's line misses the other markers (the lines tell them apart)
            assert _distance_to_curve(truth[other][3], curves[0]) > 5.0


@pytest.mark.parametrize("params", [DetectionParams(), DetectionParams(threshold_dn=100.0),
                                    DetectionParams(local_background=False)])
def test_the_mask_is_the_one_detection_found_its_blobs_in(sweep, params):
    """Detection's blobs are the outer contours of its mask, one-pixel gaps closed: the same boxes."""
    frame = sweep.frame(0)
    for image in (frame.left, frame.right):
        blobs = detect_blobs(image, params, background=estimate_background(image))
        mask = threshold_mask(image, blobs, params)
        assert mask.shape == image.shape and mask.dtype == bool
        assert len(blobs) == 5
        grouped = cv2.dilate(mask.astype(np.uint8) * 255, np.ones((3, 3), np.uint8))
        contours, _ = cv2.findContours(grouped, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        boxes = {tuple(cv2.boundingRect(c)) for c in contours}
        kept = set(map(tuple, blobs.bbox_px.tolist()))
        assert kept <= boxes
        for x, y, w, h in boxes - kept:                 # the rest: specks detection drops as noise
            assert mask[y:y + h, x:x + w].sum() < params.min_area_px
        for (x, y, w, h), area in zip(blobs.bbox_px, blobs.area_px):
            assert abs(int(mask[y:y + h, x:x + w].sum()) - area) <= 0.1 * area


# ---------------------------------------------------------------------------
# advice
# ---------------------------------------------------------------------------

def _scaled(frame: io.Frame, factor: float) -> io.Frame:
    def up(image):
        return np.clip(image.astype(np.float64) * factor, 0, 255).astype(np.uint8)
    return io.Frame(frame.index, frame.t, frame.t_right, up(frame.left), up(frame.right))


def test_saturated_markers_advise_lowering_the_exposure(sweep):
    previewer = Previewer(sweep.rig, sweep.markers)
    assert not [a for a in previewer.analyse(sweep.frame(0)).advice if a.kind == "saturated"]
    analysis = previewer.analyse(_scaled(sweep.frame(1), 4.0))
    saturated = [a.text for a in analysis.advice if a.kind == "saturated"]
    assert len(saturated) == 2 and all("lower --exposure" in t for t in saturated)
    assert saturated[0].startswith("left: markers saturated (5 of 5 blobs")
    assert all(view.saturated.all() for view in analysis.views)


def test_saturated_frames_end_to_end(sample, tmp_path, capsys):
    for index in range(2):
        for side in ("left", "right"):
            path = sample / side / f"{index:06d}.png"
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(path), np.clip(image.astype(int) * 4, 0, 255).astype(np.uint8))
    out = tmp_path / "out"
    assert cli_main(["preview", "--source", str(sample), "--frames", "2", "--out", str(out), "-q"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith("advice (2 of 2 frames): left: markers saturated") and "lower --exposure" in line
               for line in lines), lines


def test_no_blobs_too_few_and_too_many(sweep):
    frame = sweep.frame(0)
    previewer = Previewer(None)
    rng = np.random.default_rng(1)
    dark = rng.integers(8, 14, (H, W), dtype=np.uint8)
    kinds = [a.kind for a in previewer.analyse(io.Frame(0, 0.0, None, dark, dark.copy())).advice]
    assert kinds == ["no_blobs", "no_blobs"]
    texts = [a.text for a in previewer.analyse(io.Frame(0, 0.0, None, dark, dark.copy())).advice]
    assert "raise --exposure or --gain, or check the IR light" in texts[0]
    lamps = frame.left.copy()
    for u in (60, 120, 180):
        cv2.circle(lamps, (u, 60), 4, 200, -1)
    hidden = frame.right.copy()
    x, y, w, h = detect_blobs(hidden).bbox_px[0]
    hidden[y - 2:y + h + 2, x - 2:x + w + 2] = 10
    advice = {a.kind: a.text for a in previewer.analyse(io.Frame(1, 0.1, None, lamps, hidden)).advice}
    assert advice["too_many"].startswith("left: more than 5 blobs (8): glints or lamps")
    assert advice["too_few"].startswith("right: 4 blobs, 5 needed")


def test_skew_and_a_slow_rate_are_advised(sweep):
    previewer = Previewer(None, requested_fps=60.0)          # sweep12 runs at 10 Hz
    kinds = []
    for index in sweep.indices:
        frame = sweep.frame(index)
        skewed = io.Frame(frame.index, frame.t, frame.t + 0.020, frame.left, frame.right)
        analysis = previewer.analyse(skewed)
        kinds.append({a.kind for a in analysis.advice})
        assert analysis.skew_ms == pytest.approx(20.0)
    assert analysis.rate_hz == pytest.approx(10.0)
    assert all("skew" in k for k in kinds)
    settings = AdviceSettings()
    assert not any("rate" in k for k in kinds[:settings.rate_min_frames - 1])     # too few frames to judge yet
    assert all("rate" in k for k in kinds[settings.rate_min_frames - 1:])
    text = next(a.text for a in analysis.advice if a.kind == "rate")
    assert text.startswith("frame rate 10.0 Hz below the 60 Hz requested")


# ---------------------------------------------------------------------------
# before calibration
# ---------------------------------------------------------------------------

def test_without_a_rig_the_blobs_are_shown_and_the_note_says_why_no_more(sweep):
    analysis = Previewer(None).analyse(sweep.frame(0))
    truth = _truth_px(sweep, 0)
    assert not analysis.rig and not analysis.identified and analysis.error is None
    for cam, view in enumerate(analysis.views):
        assert view.epilines == [] and np.isnan(view.markers_px).all()
        nearest = np.linalg.norm(view.blobs.centers_px[None] - truth[cam][:, None], axis=2).min(axis=1)
        assert nearest.max() < 1.0
    assert render(analysis).shape == (*composite_size(W, H)[::-1], 3)


def _write_video(path, images) -> None:
    for codec in ("FFV1", "MJPG"):
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*codec), 10.0, (W, H), isColor=False)
        if writer.isOpened():
            for image in images:
                writer.write(image)
            writer.release()
            return
    pytest.skip("no video codec available for cv2.VideoWriter")


@pytest.mark.slow
def test_videos_without_a_rig_then_with_calib(sweep, sweep12_dir, tmp_path, capsys):
    frames = [sweep.frame(i) for i in range(2)]
    _write_video(tmp_path / "left.avi", [f.left for f in frames])
    _write_video(tmp_path / "right.avi", [f.right for f in frames])
    spec = f"{tmp_path / 'left.avi'},{tmp_path / 'right.avi'}"
    out = tmp_path / "out"
    assert cli_main(["preview", "--source", spec, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert NO_RIG_NOTE in err
    assert sorted(p.name for p in out.iterdir()) == [OUT_NAME.format(0), OUT_NAME.format(1)]   # only 2 frames
    assert cli_main(["preview", "--source", spec, "--calib", str(sweep12_dir / "rig.yaml"), "--out", str(out),
                     "-q"]) == 0
    assert NO_RIG_NOTE not in capsys.readouterr().err


# ---------------------------------------------------------------------------
# refusals and faults
# ---------------------------------------------------------------------------

def test_a_missing_source_is_one_line_exit_1_and_no_folder(tmp_path, capsys):
    out = tmp_path / "out"
    for spec in (f"{tmp_path / 'no_left.avi'},{tmp_path / 'no_right.avi'}", str(tmp_path / "no_such_folder")):
        assert cli_main(["preview", "--source", spec, "--out", str(out)]) == 1
        line = _one_line_error(capsys.readouterr().err)
        assert "no_left.avi" in line or "no_such_folder" in line
        assert not out.exists()


def test_bad_usage_is_one_line_exit_2_and_nothing_written(sample, tmp_path, capsys, monkeypatch):
    before = sorted(p.relative_to(sample) for p in sample.rglob("*"))
    for argv in (["--out", str(sample / "pictures")],                    # inside the dataset being read
                 ["--out", str(sample)],
                 ["--out", str(tmp_path / "missing" / "out")]):
        assert cli_main(["preview", "--source", str(sample), *argv]) == 2, argv
        _one_line_error(capsys.readouterr().err)
    assert sorted(p.relative_to(sample) for p in sample.rglob("*")) == before
    assert not (tmp_path / "out").exists()
    # A camera's setting for a replay is said to be ignored (the config file may give it for every command).
    assert cli_main(["preview", "--source", str(sample), "--frames", "1", "--exposure", "100",
                     "--out", str(tmp_path / "out")]) == 0
    assert "note: --exposure set live cameras; ignored for the replay" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        cli_main(["preview", "--source", str(sample), "--frames", "0", "--out", str(tmp_path / "out")])
    assert stop.value.code == 2 and "--frames" in capsys.readouterr().err
    # No window here (no GUI in the OpenCV build, or no display): the line says to use --out.
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert cli_main(["preview", "--source", str(sample)]) == 2
    assert "--out DIR" in _one_line_error(capsys.readouterr().err)


@pytest.mark.slow
def test_a_frame_that_fails_is_that_frames_picture_not_the_runs(sample, tmp_path, capsys, monkeypatch):
    (sample / "left" / "000001.png").write_bytes(b"not a png at all")
    calls = {"n": 0}
    advise = preview.advise

    def advise_failing_once(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:                       # the third frame's (the second has no images)
            raise RuntimeError("a bug in one frame")
        return advise(*a, **k)

    monkeypatch.setattr(preview, "advise", advise_failing_once)
    out = tmp_path / "out"
    assert cli_main(["preview", "--source", str(sample), "--frames", "4", "--out", str(out), "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [OUT_NAME.format(k) for k in range(4)]
    text = capsys.readouterr().out
    assert "2 of 4 frames failed (first: frame 1: left/000001.png" in text
    size = cv2.imread(str(out / OUT_NAME.format(1))).shape
    assert size == cv2.imread(str(out / OUT_NAME.format(0))).shape == (*composite_size(W, H)[::-1], 3)
    # the failed frames' pictures are the dark ones saying so; the others show the images
    means = [cv2.imread(str(out / OUT_NAME.format(k)))[:H].mean() for k in range(4)]
    assert means[1] == pytest.approx(40, abs=1) and means[2] == pytest.approx(40, abs=1)
    assert means[0] < 30 and means[3] < 30


def test_the_written_pictures_are_whole_or_absent(sweep12_dir, tmp_path, monkeypatch, capsys):
    """A write that fails (a full disk) leaves no partial picture and ends the run in one line, exit 1."""
    out = tmp_path / "out"
    real = preview.io.write_image
    count = {"n": 0}

    def write_image(name, image, *rest):
        count["n"] += 1
        if count["n"] == 2:
            with open(name, "wb") as f:
                f.write(b"\x89PNG half")
            raise OSError(28, "No space left on device", name)
        return real(name, image, *rest)

    monkeypatch.setattr(preview.io, "write_image", write_image)
    assert cli_main(["preview", "--source", str(sweep12_dir), "--frames", "3", "--out", str(out), "-q"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "No space left on device" in line and "1 pictures were written" in line
    assert sorted(p.name for p in out.iterdir()) == [OUT_NAME.format(0)]


@pytest.mark.slow
def test_a_shorter_run_leaves_one_runs_pictures(sweep12_dir, tmp_path, capsys):
    """A 2-frame preview into the folder of a 4-frame one used to leave pictures 2 and 3 of the earlier run beside
    the new ones; the user's own files there stay."""
    out = tmp_path / "pictures"
    assert cli_main(["preview", "--source", str(sweep12_dir), "--frames", "4", "--out", str(out), "-q"]) == 0
    (out / "notes.txt").write_text("mine")
    (out / "preview_old.png").write_bytes(b"not ours: no frame number")
    capsys.readouterr()
    assert cli_main(["preview", "--source", str(sweep12_dir), "--frames", "2", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", OUT_NAME.format(0), OUT_NAME.format(1),
                                                      "preview_old.png"]
    assert "removed 2 pictures of an earlier, longer preview" in capsys.readouterr().err
