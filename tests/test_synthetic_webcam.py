"""What ordinary USB webcams add to the synthetic world (``synthetic``), each alone and all together.

Rolling shutter and MJPEG (``synthetic.render.RenderOptions``), auto
exposure, free-running clocks, timestamp jitter, dropped and repeated frames
(``synthetic.imperfect.imperfect_rig``) and the ``ordinary_webcams`` preset.
The expected values are computed here from the poses with OpenCV and numpy
(cv2.projectPoints, connected components), not with the code under test.
"""
from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from synthetic import imperfect
from synthetic.cli import main as synth_main
from synthetic.conventions import DEFAULT_MARKERS_MM
from synthetic.dataset import frame_rng, write_dataset
from synthetic.render import RenderOptions, render_pair, render_pair_float
from synthetic.scenes import PRESETS, make_pose_fn, make_scene
from synthetic.setups import NOMINAL_HEAD_M, default_setup

ROOT = Path(__file__).resolve().parents[1]

#: noise-free, no background (the default PSF)
CLEAN = RenderOptions(noise=False, ambient_dn=0.0, ambient_variation_dn=0.0)

#: the commit before the rolling shutter and MJPEG were added to synthetic/render.py
BEFORE_WEBCAMS = "779ce91d702abd2e4e99c743076056df295da898"


def _moving_head(setup, velocity_mm_s=(400.0, 150.0, 0.0)):
    """A head translating at a constant velocity (monitor frame, mm/s), looking at the screen's centre."""
    vel = np.asarray(velocity_mm_s, float)
    return make_pose_fn(setup, lambda t: np.asarray(NOMINAL_HEAD_M, float) + vel * t, lambda t: np.zeros(3),
                        lambda t: (0.0, 0.0, 0.0))


def _cams(setup):
    return [(setup.K1, setup.D1, np.zeros(3), np.zeros(3)),
            (setup.K2, setup.D2, cv2.Rodrigues(np.asarray(setup.R, float))[0].ravel(),
             np.asarray(setup.T, float).ravel())]


def _project(cam, pts):
    K, D, rvec, tvec = cam
    uv, _ = cv2.projectPoints(np.asarray(pts, float).reshape(-1, 3), rvec, tvec, K, D)
    return uv.reshape(-1, 2)


def _markers(pose_fn, t):
    R, p = pose_fn(t)
    return DEFAULT_MARKERS_MM @ np.asarray(R).T + np.asarray(p)


def _centroids(img, background=0.0, threshold=3.0):
    """Intensity-weighted centroids (N, 2) of the blobs above ``threshold``, sorted by x."""
    sig = np.asarray(img, float) - background
    n, lab = cv2.connectedComponents((sig > threshold).astype(np.uint8))
    out = []
    for i in range(1, n):
        ys, xs = np.nonzero(lab == i)
        w = sig[ys, xs]
        out.append(((xs * w).sum() / w.sum(), (ys * w).sum() / w.sum()))
    return np.array(sorted(out))


def _row_time_projection(cam, pose_fn, t_cam, readout_s, h):
    """Each marker's image point where the pose at the time of the row it is on projects it (fixed point)."""
    out = []
    for m in range(5):
        v = (h - 1) / 2.0
        for _ in range(20):
            uv = _project(cam, _markers(pose_fn, t_cam + (v - (h - 1) / 2.0) * readout_s / (h - 1))[m])[0]
            v = uv[1]
        out.append(uv)
    return np.array(sorted(map(tuple, out)))


# ----------------------------------------------------------------------------
# rolling shutter
# ----------------------------------------------------------------------------

def test_rolling_shutter_blob_is_where_its_rows_time_puts_it():
    s = default_setup()
    pf = _moving_head(s)
    h = s.image_size[1]
    cams = _cams(s)
    t, offset = 0.05, 0.004
    rolling = CLEAN.replace(readout_s=0.030, right_readout_s=0.020, right_time_offset_s=offset)
    A = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, t, rolling)
    B = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, t, CLEAN.replace(right_time_offset_s=offset))
    biggest = 0.0
    for ci, readout in ((0, 0.030), (1, 0.020)):
        t_cam = t + (offset if ci else 0.0)
        got = _centroids(A[ci])
        assert got.shape == (5, 2)
        # where the pose at the marker's row time projects it
        np.testing.assert_allclose(got, _row_time_projection(cams[ci], pf, t_cam, readout, h), atol=0.05)
        # against a global shutter: moved by the image velocity times the row's time
        still = _centroids(B[ci])
        uv = _project(cams[ci], _markers(pf, t_cam))
        vel = (_project(cams[ci], _markers(pf, t_cam + 1e-4)) - _project(cams[ci], _markers(pf, t_cam - 1e-4))) / 2e-4
        row_time = (uv[:, 1] - (h - 1) / 2.0) * readout / (h - 1)
        order = np.argsort(uv[:, 0])
        expected_shift = (vel * row_time[:, None])[order]
        np.testing.assert_allclose(got - still, expected_shift, atol=0.05)
        biggest = max(biggest, float(np.abs(expected_shift).max()))
    assert biggest > 0.5          # the test sees the effect


def test_rolling_shutter_shears_and_keeps_the_light():
    """With motion blur too: each row's sub-exposures centred on its own time; the blob's light is kept."""
    s = default_setup()
    pf = _moving_head(s, (600.0, 0.0, 0.0))
    blur = CLEAN.replace(exposure_s=0.008, motion_samples=8)
    A = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, blur.replace(readout_s=0.030))[0]
    B = render_pair_float(s, DEFAULT_MARKERS_MM, 6.0, pf, 0.0, blur)[0]
    np.testing.assert_allclose(A.sum(), B.sum(), rtol=2e-3)
    np.testing.assert_allclose(_centroids(A), _row_time_projection(_cams(s)[0], pf, 0.0, 0.030, 480), atol=0.05)
    # sheared: a horizontal motion tilts the blob (x moves with the row)
    _, lab = cv2.connectedComponents((A > 3).astype(np.uint8))
    ys, xs = np.nonzero(lab == lab[tuple(np.round(_centroids(A)[0][::-1]).astype(int))])
    w = A[ys, xs]
    cov_xy = np.average((xs - np.average(xs, weights=w)) * (ys - np.average(ys, weights=w)), weights=w)
    _, lab_b = cv2.connectedComponents((B > 3).astype(np.uint8))
    yb, xb = np.nonzero(lab_b == lab_b[tuple(np.round(_centroids(B)[0][::-1]).astype(int))])
    wb = B[yb, xb]
    cov_b = np.average((xb - np.average(xb, weights=wb)) * (yb - np.average(yb, weights=wb)), weights=wb)
    assert abs(cov_xy - cov_b) > 0.01


def _render_module_before(tmp_path):
    """synthetic/render.py as it was before the webcam effects, as a module of the synthetic package."""
    try:
        src = subprocess.run(["git", "-C", str(ROOT), "show", f"{BEFORE_WEBCAMS}:synthetic/render.py"],
                             capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        pytest.skip("git is not available")
    if src.returncode != 0:
        pytest.skip(f"commit {BEFORE_WEBCAMS[:7]} is not in this checkout")
    path = tmp_path / "render_before.py"
    path.write_text(src.stdout)
    spec = importlib.util.spec_from_file_location("synthetic._render_before", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    try:
        spec.loader.exec_module(module)
    finally:
        sys.modules.pop(spec.name, None)
    return module


@pytest.mark.slow
def test_readout_zero_renders_as_before(tmp_path, monkeypatch):
    before = _render_module_before(tmp_path)
    for name in ("fast_motion", "glints_lamp", "wide_hd"):
        sc = make_scene(name, n_frames=3, seed=1)
        opts = sc.options.replace(fused_glints=(1, 1)) if name == "glints_lamp" else sc.options
        old_opts = before.RenderOptions(**{k: getattr(opts, k) for k in before.RenderOptions.__dataclass_fields__})
        new = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, float(sc.times[1]),
                          opts.replace(readout_s=0.0, jpeg_quality=None), frame_rng(5, 1))
        old = before.render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, float(sc.times[1]),
                                 old_opts, frame_rng(5, 1))
        for a, b in zip(new, old):
            np.testing.assert_array_equal(a, b)
    # and never through the rolling-shutter code
    import synthetic.render as render

    def refuse(*args, **kwargs):
        raise AssertionError("readout 0 took the rolling-shutter path")

    monkeypatch.setattr(render, "_render_markers_rolling", refuse)
    sc = make_scene("fast_motion", n_frames=2)
    render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, 0.0, sc.options, frame_rng(0, 0))


# ----------------------------------------------------------------------------
# MJPEG
# ----------------------------------------------------------------------------

def test_mjpeg_changes_the_image_not_the_centroids():
    sc = make_scene("static", n_frames=2, distance_mm=500.0)
    opts = sc.options.replace(brightness_scale=1.2)
    plain = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, 0.0, opts, np.random.default_rng(3))
    jpeg = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, 0.0, opts.replace(jpeg_quality=75),
                       np.random.default_rng(3))
    for a, b in zip(plain, jpeg):
        assert a.dtype == b.dtype == np.uint8 and a.shape == b.shape
        diff = np.abs(a.astype(int) - b.astype(int))
        assert diff.max() >= 3 and diff.mean() > 0.2                  # blocks, ringing, smoothed noise
        ca, cb = _centroids(a, background=40.0, threshold=20.0), _centroids(b, background=40.0, threshold=20.0)
        assert ca.shape == cb.shape == (5, 2)
        assert np.abs(ca - cb).max() < 0.05
    # the codec itself: an 8-bit image decoded from cv2's JPEG at that quality
    ok, data = cv2.imencode(".jpg", plain[0], [cv2.IMWRITE_JPEG_QUALITY, 75])
    np.testing.assert_array_equal(jpeg[0], cv2.imdecode(data, cv2.IMREAD_GRAYSCALE))


# ----------------------------------------------------------------------------
# auto exposure
# ----------------------------------------------------------------------------

def _marker_light(sc, k, cam=0):
    """Light of the markers in frame k (sum of the noise-free image minus the image without markers), and the
    mean ambient level."""
    o = sc.options_for(k).replace(noise=False)
    hidden = o.replace(occluded=frozenset((c, m) for c in (0, 1) for m in range(5)))
    args = (sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, float(sc.times[k]))
    img = render_pair_float(*args, o)[cam]
    bg = render_pair_float(*args, hidden)[cam]
    return float((img - bg).sum()), float(bg.mean())


@pytest.mark.slow
def test_auto_exposure_steps_brightness_noise_blur_and_rate():
    sc = imperfect.imperfect_rig(n_frames=10, base="static", exposure_s=0.004,
                                 auto_exposure=[(4, 0.006, 1.2)], ae_converge_frames=2)
    truth = sc.webcam_truth
    assert [o.exposure_s for o in sc.frame_options] == pytest.approx([0.004] * 4 + [0.004 * 1.5 ** 0.5] + [0.006] * 5)
    light0, amb0 = _marker_light(sc, 0)
    light4, amb4 = _marker_light(sc, 4)
    light9, amb9 = _marker_light(sc, 9)
    assert light9 / light0 == pytest.approx(1.8, rel=1e-3)                  # 1.5x the exposure, gain 1.2
    assert light4 / light0 == pytest.approx(1.8 ** 0.5, rel=1e-3)           # half way (log) after one frame
    assert amb9 == pytest.approx(amb0, rel=1e-3)       # the room got darker by what the exposure made up for
    assert amb4 == pytest.approx(amb0 / 1.8 ** 0.5, rel=1e-3)
    o0, o9 = sc.options_for(0), sc.options_for(9)
    assert o9.gain_e_per_dn == pytest.approx(o0.gain_e_per_dn / 1.2)
    assert o9.read_noise_dn == pytest.approx(o0.read_noise_dn * 1.2)
    assert truth["frames"]["brightness"][9] == pytest.approx(1.8)
    assert truth["auto_exposure_steps"][0]["room"] == pytest.approx(1 / 1.8)
    # a dark background's noise grows with the gain
    a = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, 0.0, o0, np.random.default_rng(1))[0]
    b = render_pair(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, 0.0, o9, np.random.default_rng(1))[0]
    patch = (slice(10, 60), slice(10, 60))
    assert np.std(b[patch].astype(float)) > 1.05 * np.std(a[patch].astype(float))
    # exposures beyond the frame period: the camera slows to every other frame
    slow = imperfect.imperfect_rig(n_frames=10, base="static", exposure_s=0.01, auto_exposure=[(4, 0.05, 1.0)],
                                   ae_converge_frames=1)
    gaps = np.round(np.diff(slow.times) * 30).astype(int)
    assert gaps.tolist() == [1, 1, 1, 1, 2, 2, 2, 2, 2]
    assert {d["cause"] for d in slow.webcam_truth["dropped"]} == {
        "exposure longer than the frame period: frame rate halved"}
    assert slow.frame_options[-1].exposure_s == 0.05 and slow.frame_options[-1].motion_samples == 50


# ----------------------------------------------------------------------------
# dropped and repeated frames, clocks, timestamps
# ----------------------------------------------------------------------------

def _times(folder):
    rows = list(csv.reader(open(folder / "times.csv")))
    return rows[0], np.array([[float(v) for v in r] for r in rows[1:]])


def _truth(folder):
    rows = list(csv.reader(open(folder / "truth.csv")))[1:]
    return np.array([[float(v) for v in r] for r in rows])


@pytest.mark.slow
def test_dropped_and_repeated_frames(tmp_path):
    sc = imperfect.imperfect_rig(n_frames=8, base="yaw_sweep", drop_frames=[3, 6, 7], duplicate_frames=[2, 5])
    out = write_dataset(tmp_path / "ds", sc, seed=2)
    for side in ("left", "right"):
        assert sorted(p.name for p in (out / side).iterdir()) == [f"{k:06d}.png" for k in range(8)]
    header, times = _times(out)
    assert header == ["frame", "t"] and times[:, 0].tolist() == list(range(8))
    period = 1 / 30
    assert np.round(np.diff(times[:, 1]) / period).astype(int).tolist() == [1, 1, 2, 1, 3, 1, 1]
    truth = _truth(out)
    assert truth.shape == (8, 13)
    np.testing.assert_allclose(times[:, 1], sc.times, atol=1e-6)
    for k, t in enumerate(sc.times):                        # truth at the listed times
        p1, axes = sc.truth(t)
        np.testing.assert_allclose(truth[k, 1:4], p1, atol=1e-5)
    # a repeated frame: the same bytes as the one before, under its own time and truth
    for k in (2, 5):
        for side in ("left", "right"):
            assert (out / side / f"{k:06d}.png").read_bytes() == (out / side / f"{k - 1:06d}.png").read_bytes()
        assert np.abs(truth[k, 1:4] - truth[k - 1, 1:4]).max() > 0.5
    assert (out / "left" / "000003.png").read_bytes() != (out / "left" / "000002.png").read_bytes()
    wt = json.loads((out / "webcam_truth.json").read_text())
    assert [d["camera_frame"] for d in wt["dropped"]] == [3, 6, 7]
    assert [d["before_frame"] for d in wt["dropped"]] == [3, 5, 5]
    assert wt["duplicates"] == [{"frame": 2, "repeats": 1}, {"frame": 5, "repeats": 4}]
    assert wt["frames"]["duplicate_of"] == [None, None, 1, None, None, 4, None, None]
    assert wt["frames"]["camera_frame"] == [0, 1, 1, 4, 5, 5, 9, 10]    # what each frame's images show
    # a fraction: round(f n) frames, drawn from the seed
    frac = imperfect.imperfect_rig(n_frames=40, base="static", drop_frames=0.05, seed=3)
    gaps = np.round(np.diff(frac.times) * 30).astype(int)
    assert frac.n_frames == 40 and (gaps - 1).sum() == 2 == len(frac.webcam_truth["dropped"])


@pytest.mark.slow
def test_free_running_clock_drifts_and_wraps(tmp_path):
    period = 1 / 30
    sc = imperfect.imperfect_rig(n_frames=6, base="static", offset_s=0.012, clock_drift_ppm=100.0)
    offsets = np.array([o.right_time_offset_s for o in sc.frame_options])
    np.testing.assert_allclose(offsets, 0.012 + 100e-6 * np.asarray(sc.times), atol=1e-12)   # 0.1 ms a second
    out = write_dataset(tmp_path / "drift", sc)
    rig = json.loads((out / "rig_truth.json").read_text())
    np.testing.assert_allclose(rig["time_offset_s_per_frame"], offsets)
    assert rig["time_offset_s"] == pytest.approx(offsets.mean())
    wt = json.loads((out / "webcam_truth.json").read_text())
    np.testing.assert_allclose(wt["frames"]["right_time_offset_s"], offsets)
    assert wt["right_frame_period_s"] == pytest.approx(period * (1 + 100e-6))
    # the right image is rendered at its own time: as a global rig at t + that frame's offset
    k = 5
    o = sc.options_for(k)
    right = render_pair_float(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, sc.times[k], o)[1]
    later = render_pair_float(sc.setup, sc.model_points_mm, sc.diameter_mm, sc.pose_fn, sc.times[k] + offsets[k],
                              o.replace(right_time_offset_s=0.0))[1]
    np.testing.assert_array_equal(right, later)
    # a fast drift passes half a period: the nearest right frame is then the one before (offset - period)
    fast = imperfect.imperfect_rig(n_frames=20, base="static", offset_s=0.016, clock_drift_ppm=2000.0)
    off = np.array([o.right_time_offset_s for o in fast.frame_options])
    unwrapped = 0.016 + 2000e-6 * (np.arange(20) * period)
    wrapped = np.where(unwrapped > period / 2, unwrapped - period * (1 + 2000e-6), unwrapped)
    np.testing.assert_allclose(off, wrapped, atol=1e-12)
    assert (off < 0).any() and (off > 0).any() and np.all(np.abs(off) <= period / 2)
    right_frames = fast.webcam_truth["frames"]["right_camera_frame"]
    assert len(set(right_frames)) == 19        # one right frame paired twice where the offset wrapped


@pytest.mark.slow
def test_timestamp_jitter_on_the_declared_times(tmp_path):
    sc = imperfect.imperfect_rig(n_frames=10, base="yaw_sweep", offset_s=0.005, declare_offset=True,
                                 timestamp_jitter_s=0.002, seed=4)
    out = write_dataset(tmp_path / "jit", sc)
    header, times = _times(out)
    assert header == ["frame", "t", "t_right"]
    exposure = np.arange(10) / 30
    dt, dr = times[:, 1] - exposure, times[:, 2] - (exposure + 0.005)
    assert np.all(np.abs(dt) <= 0.002 + 1e-6) and np.all(np.abs(dr) <= 0.002 + 1e-6)
    assert np.abs(dt).max() > 0.0005 and np.abs(dr).max() > 0.0005 and np.abs(dt - dr).max() > 0.0005
    wt = json.loads((out / "webcam_truth.json").read_text())
    np.testing.assert_allclose(wt["frames"]["t_exposure_s"], exposure)
    np.testing.assert_allclose(wt["frames"]["t_listed_s"], times[:, 1], atol=1e-6)
    truth = _truth(out)
    np.testing.assert_allclose(sc.stamps, times[:, 1], atol=1e-6)
    for k in range(10):                                # truth.csv refers to the listed t, as the contract says
        np.testing.assert_allclose(truth[k, 1:4], sc.truth(sc.stamps[k])[0], atol=1e-5)
        assert np.abs(truth[k, 1:4] - sc.truth(exposure[k])[0]).max() > 1e-3 or k in (0, 5)


# ----------------------------------------------------------------------------
# everything at once
# ----------------------------------------------------------------------------

@pytest.mark.slow
def test_ordinary_webcams_preset_writes_a_valid_dataset(tmp_path):
    assert "ordinary_webcams" in PRESETS
    out = tmp_path / "webcams"
    assert synth_main(["render", "ordinary_webcams", str(out), "--frames", "30", "-q"]) == 0
    sc = make_scene("ordinary_webcams", n_frames=30)
    for fault in ("turned 0.3°", "x1.02", "12.0 ms late (undeclared)", "rolling shutter 30 ms", "+100 ppm",
                  "MJPEG quality 75", "auto exposure", "1 frames dropped", "2 frames delivered twice",
                  "glints fused", "timestamps ±1 ms"):
        assert fault in sc.description, fault
    for side in ("left", "right"):
        names = sorted(p.name for p in (out / side).iterdir())
        assert names == [f"{k:06d}.png" for k in range(30)]
        img = cv2.imread(str(out / side / names[0]), cv2.IMREAD_UNCHANGED)
        assert img.dtype == np.uint8 and img.shape == (480, 640)
    header, times = _times(out)
    assert header == ["frame", "t"] and np.all(np.diff(times[:, 1]) > 0)
    assert np.round(np.diff(times[:, 1]) * 30).max() == 2                  # the dropped frame
    assert _truth(out).shape == (30, 13)
    wt = json.loads((out / "webcam_truth.json").read_text())
    assert wt["readout_s"] == wt["right_readout_s"] == 0.03 and wt["jpeg_quality"] == 75
    assert wt["clock_drift_ppm"] == 100.0 and len(wt["duplicates"]) == 2 and len(wt["dropped"]) == 1
    assert [s["exposure_s"] for s in wt["auto_exposure_steps"]] == pytest.approx([0.012, 0.005])
    for d in wt["duplicates"]:
        assert (out / "left" / f"{d['frame']:06d}.png").read_bytes() == \
            (out / "left" / f"{d['repeats']:06d}.png").read_bytes()
    rig = json.loads((out / "rig_truth.json").read_text())
    assert 0.012 < rig["time_offset_s"] < 0.0122
    # the tracker's reader takes it as any dataset
    from headplod.io import Dataset

    ds = Dataset(out)
    assert ds.indices == list(range(30)) and ds.truth is not None and len(ds.truth) == 30
    # --overwrite replaces it (webcam_truth.json is a dataset's own file)
    assert synth_main(["render", "ordinary_webcams", str(out), "--frames", "12", "-q", "--overwrite"]) == 0
    assert len(list((out / "left").iterdir())) == 12
