"""The paper-conditions run (``headplod bench paper``): its pose jitter, its statistics, the true POI and the
trackers' calibration."""
import io
from pathlib import Path

import numpy as np
import pytest

from headplod.bench.harness import poi_disc
from headplod.render.image_metrics import psnr_db
from headplod.bench.paper_report import format_tables, goal_verdicts, true_poi_goals
from headplod.bench.paper_tables import (OVERCONFIDENT_NEES, JitteredPoses, PaperTablesConfig, paper_tables,
                                         point_disc, pose_nees, prior_variants, track_poses, tracker_share,
                                         true_pois)
from headplod.io import GazeTruth, read_truth, write_gaze_truth
from headplod.plod.view import gaze_covariance
from headplod.plod.select import SelectorConfig
from headplod.demo.loop import ReplayPoses
from headplod.demo import loop as lp
from headplod.plod.view import poi_direction
from headplod.render.still import default_head


def test_jitter_turns_the_viewing_direction_by_its_sigma_and_says_so():
    screen = lp.default_screen()
    eye = default_head(screen)
    centre = np.array(screen.size_px, dtype=np.float64) / 2
    cov = np.diag([0.002, 0.003])
    poses = [lp.Pose(k / 30, True, eye, centre, cov) for k in range(400)]
    jittered = JitteredPoses(ReplayPoses(poses, screen), noise_deg=0.5, seed=1)
    out = [jittered.read() for _ in poses]
    assert jittered.read() is None
    d0 = poi_direction(screen, eye, centre)
    angles = np.array([np.degrees(np.arccos(np.clip(poi_direction(screen, eye, p.poi_px) @ d0, -1, 1)))
                       for p in out])
    # The angle between two directions with independent N(0, σ²) offsets per axis is Rayleigh(σ).
    assert np.sqrt(np.mean(angles ** 2) / 2) == pytest.approx(0.5, rel=0.1)
    np.testing.assert_allclose(out[0].cov_deg2, cov + 0.25 * np.eye(2))
    assert all(p.eye_mm is eye for p in out)


def test_jitter_leaves_failed_poses_alone():
    screen = lp.default_screen()
    lost = lp.Pose(0.0, False, reason="markers hidden")

    class Once(lp.PoseSource):                   # gives the very object (ReplayPoses gives copies)
        name = "once"

        def read(self):
            return lost

    source = Once()
    source.screen = screen
    assert JitteredPoses(source, noise_deg=1.0).read() is lost


def test_disc_psnr_sees_only_the_disc():       # the paper tables' PSNR within the disc about the POI
    def disc_psnr_db(image, reference, centre_px, radius_px):
        return psnr_db(image, reference, poi_disc(reference.shape, centre_px, radius_px))

    ref = np.zeros((100, 200, 3), np.uint8)
    img = ref.copy()
    img[:, 150:] = 255                                   # outside a 20 px disc about pixel (50, 50)'s centre
    assert disc_psnr_db(img, ref, (50.5, 50.5), 20) == float("inf")
    img[50, 50] = 10
    assert disc_psnr_db(img, ref, (50.5, 50.5), 20) == pytest.approx(
        10 * np.log10(255 ** 2 / (3 * 100 / (3 * np.count_nonzero(
            (np.arange(200)[None] - 50) ** 2 + (np.arange(100)[:, None] - 50) ** 2 <= 400)))), rel=1e-9)


@pytest.mark.parametrize("bad", [{"frames": 2}, {"warmup": 60}, {"viewpoints": ("moon",)},
                                 {"conditions": ()}, {"noise_deg": float("nan")}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError, match="PaperTablesConfig"):
        PaperTablesConfig(**bad)


# --- Where the viewer really looks: the true POI, the conditions' NEES, the report's goals -------------------

SWEEP12 = str(Path(__file__).parent / "data" / "sweep12")


def test_true_poi_is_where_the_true_viewing_ray_meets_the_screen():
    screen = lp.default_screen()
    eye = default_head(screen) + np.array([40.0, -25.0, 10.0])
    target = np.array([300.0, 200.0])                       # a known screen pixel
    v = screen.pixel_to_world(target) - eye
    v /= np.linalg.norm(v)
    pois = true_pois(screen, np.stack([eye, eye, [np.nan] * 3]), np.stack([v, -v, v]))
    np.testing.assert_allclose(pois[0], target, atol=1e-6)
    assert np.isnan(pois[1:]).all()                       # a ray away from the screen; a frame without truth
    # The tracked POI's own construction (poi_direction) points the same way.
    np.testing.assert_allclose(poi_direction(screen, eye, pois[0]), v, atol=1e-9)


def test_bad_true_rays_are_refused():
    screen = lp.default_screen()
    with pytest.raises(ValueError, match="true_pois"):
        true_pois(screen, np.zeros((2, 3)), np.zeros((3, 3)))


@pytest.fixture(scope="module")
def jittered_runs():
    """The sample sequence (12 frames, with truth.csv) tracked as honest and as overconfident."""
    return {c: track_poses(c, 12, source=SWEEP12) for c in ("honest", "overconfident")}


@pytest.mark.slow
def test_overconfident_tracker_is_far_less_calibrated_than_the_honest_one(jittered_runs):
    nees = {c: pose_nees(r.screen, r.poses, r.true_v) for c, r in jittered_runs.items()}
    assert all(np.isfinite(n).sum() == 12 for n in nees.values())
    honest, over = (float(np.mean(nees[c])) for c in ("honest", "overconfident"))
    assert honest < 4.0                                    # about 2 for a calibrated covariance
    assert over > 8.0 and over > 5 * honest
    # The same jitter (same seed), only the covariance shrunk: the POIs agree, the NEES scales by its inverse.
    for a, b in zip(*(r.poses for r in jittered_runs.values())):
        np.testing.assert_allclose(a.poi_px, b.poi_px)
    np.testing.assert_allclose(nees["overconfident"], nees["honest"] * OVERCONFIDENT_NEES / 2, rtol=1e-9)


def test_truth_is_matched_to_each_pose(jittered_runs):
    run = jittered_runs["honest"]
    truth = read_truth(Path(SWEEP12) / "truth.csv")
    assert len(run.poses) == len(run.true_v) == 12
    np.testing.assert_allclose(run.true_eye_mm[3], truth[3][0])
    np.testing.assert_allclose(run.true_v[3], truth[3][1][2], atol=1e-6)   # normalised


def _row(vp, scenario, hysteresis, psnr, triangles):
    return {"viewpoint": vp, "scenario": scenario, "hysteresis": hysteresis, "triangles": triangles,
            "per_frame": {"psnr_true_db": psnr}}


def test_goals_count_the_frames_none_loses_and_the_scenarios_keep():
    # Frame 0 is the warm-up; none is below 45 dB on frames 1, 2 and 4 (frame 3 has no true POI: None).
    none = [30.0, 40.0, 44.9, None, 40.0, 50.0]
    rows = [_row("a", "none", True, none, 100),
            _row("a", "fixed", True, [50.0, 45.0, 44.0, 50.0, 46.0, 50.0], 300),
            _row("a", "adaptive", True, [50.0, 45.0, float("inf"), 50.0, 46.0, 50.0], 200),
            _row("a", "smoothed", True, [10.0, 10.0, 10.0, 10.0, 10.0, 10.0], 250)]
    g = true_poi_goals(rows, warmup=1)["a"]
    assert g["on"]["none_below"] == 3 and g["on"]["frames"] == 5
    assert g["on"]["kept"] == {"fixed": 2, "adaptive": 3, "smoothed": 0}
    assert g["on"]["kept_fraction"]["adaptive"] == 1.0
    assert g["adaptive_fewer_triangles_than_fixed"] is True
    assert "off" not in g
    report = {"conditions": {"honest": {"true_poi": {"a": g}},
                             "overconfident": {"true_poi": {"a": true_poi_goals(
                                 [_row("a", sc, True, [50.0] * 6 if sc == "none" else [0.0] * 6, 1) for sc in
                                  ("none", "fixed", "adaptive", "smoothed")], warmup=1)["a"]}}}}
    verdicts = goal_verdicts(report)
    honest = [(v["goal"].startswith("adaptive keeps"), v["figure"], v["status"]) for v in verdicts
              if v["condition"] == "honest"]
    assert honest == [(True, 1.0, "met"), (False, [200.0, 300.0], "met")]
    assert [v["status"] for v in verdicts if v["condition"] == "overconfident"] == ["no frames"]


def test_a_non_positive_covariance_scale_is_refused():
    with pytest.raises(ValueError, match="cov_scale"):
        JitteredPoses(ReplayPoses([], lp.default_screen()), noise_deg=0.5, cov_scale=0.0)


@pytest.mark.slow
def test_report_has_the_true_poi_figures(gl_context, default_screen):
    from headplod.render.still import TerrainScene

    scene = TerrainScene.build(default_screen, max_level=2)          # small: the figures' keys are tested here
    config = PaperTablesConfig(frames=4, warmup=1, viewpoints=("mountains",), conditions=("honest",),
                               size=(96, 54), source=SWEEP12)
    report = paper_tables(config, err=io.StringIO(), scene=scene, ctx=gl_context)
    c = report["conditions"]["honest"]
    assert c["nees_frames"] == 4 and c["nees_mean"] > 0
    assert report["config"]["mode"] == SelectorConfig().mode
    row = next(r for r in c["rows"] if r["scenario"] == "adaptive" and r["hysteresis"])
    for key in ("psnr_true_disc_db", "psnr_tracked_disc_db", "triangles"):
        assert key in row
    assert len(row["per_frame"]["psnr_true_db"]) == 4 and len(row["per_frame"]["psnr_tracked_db"]) == 4
    assert set(c["true_poi"]) == {"mountains", "all"}
    assert {"none_below", "kept", "kept_fraction", "frames"} <= set(c["true_poi"]["all"]["on"])
    assert {g["condition"] for g in report["goals"]} == {"honest"}
    text = format_tables(report)
    assert "PSNR true" in text and "NEES" in text



# --- The true gaze (head and eyes) and the gaze prior ---------------------------------------------------------

def test_tracker_share_is_the_trackers_part_of_the_pois_variance():
    cov = np.array([[0.3, 0.05], [0.05, 0.2]])
    for prior in ((8.0, 6.0), (2.0, 0.0), (0.0, 0.0)):
        share = tracker_share(gaze_covariance(cov, prior), prior)
        assert 0.0 <= share <= 1.0
        assert share == pytest.approx(0.5 / (0.5 + prior[0] ** 2 + prior[1] ** 2), rel=1e-12)
    assert tracker_share(gaze_covariance(cov, (0.0, 0.0)), (0.0, 0.0)) == 1.0         # head only: all the tracker's
    assert tracker_share(gaze_covariance(None, (8.0, 6.0)), (8.0, 6.0)) == 0.0        # none with a prior
    assert np.isnan(tracker_share(gaze_covariance(None, (0.0, 0.0)), (0.0, 0.0)))     # nothing uncertain


def test_the_gaze_disc_is_centred_on_the_gaze_point():
    screen = lp.default_screen()
    eye = default_head(screen)
    size = (192, 108)
    gaze_px = np.array([1400.0, 300.0])                          # screen px
    disc = point_disc((108, 192, 3), screen, gaze_px, eye, size)
    ys, xs = np.nonzero(disc)
    centre = gaze_px * np.array(size) / np.array(screen.size_px)
    # The mask's centroid is the point (pixel centres at integers + 0.5 in poi_disc's convention): within a pixel.
    assert np.hypot(xs.mean() + 0.5 - centre[0], ys.mean() + 0.5 - centre[1]) < 1.0
    assert point_disc((108, 192, 3), screen, [np.nan, np.nan], eye, size) is None


def test_priors_compared_are_the_default_and_head_only():
    assert [v[0] for v in prior_variants(PaperTablesConfig(gaze_prior_deg=(8.0, 6.0)))] == ["default", "head only"]
    assert prior_variants(PaperTablesConfig(gaze_prior_deg=(8.0, 6.0)))[0][2] == (8.0, 6.0)
    assert [v[0] for v in prior_variants(PaperTablesConfig(gaze_prior_deg=(0.0, 0.0)))] == ["default"]
    assert [v[0] for v in prior_variants(PaperTablesConfig(gaze_prior_deg=(8.0, 6.0), head_only=False))] == ["default"]
    own = SelectorConfig().gaze_prior
    assert prior_variants(PaperTablesConfig())[0][2] == own
    with pytest.raises(ValueError, match="gaze_prior_deg"):
        PaperTablesConfig(gaze_prior_deg=(-1.0, 2.0))
    with pytest.raises(ValueError, match="mode"):
        PaperTablesConfig(mode="full")


@pytest.fixture()
def sweep12_with_gaze(tmp_path):
    """The sample sequence with a gaze_truth.csv: on even frames the gaze is the true POI (eyes centred), on odd
    ones it misses the screen plane. Returns the folder and each frame's true POI."""
    import shutil

    folder = tmp_path / "sweep12"
    shutil.copytree(SWEEP12, folder)
    screen = lp.default_screen()
    truth = read_truth(folder / "truth.csv")
    rows, pois = {}, {}
    for k, (position, axes) in truth.items():
        v = axes[2] / np.linalg.norm(axes[2])
        pois[k] = true_pois(screen, position, v)[0]
        rows[k] = (GazeTruth(np.zeros(2), v, pois[k]) if k % 2 == 0
                   else GazeTruth(np.zeros(2), v, np.full(2, np.nan)))
    write_gaze_truth(folder / "gaze_truth.csv", rows)
    return folder, pois


@pytest.mark.slow
def test_tracked_run_carries_the_gaze_truth_of_each_pose(sweep12_with_gaze):
    folder, pois = sweep12_with_gaze
    run = track_poses("today", 12, source=str(folder))
    assert run.true_gaze_px.shape == (12, 2)
    np.testing.assert_allclose(run.true_gaze_px[::2], np.array([pois[k] for k in range(0, 12, 2)]))
    assert np.isnan(run.true_gaze_px[1::2]).all()
    assert np.isnan(track_poses("today", 3, source=SWEEP12).true_gaze_px).all()     # no file: no gaze


@pytest.mark.slow
def test_report_at_the_true_gaze_with_and_without_the_prior(gl_context, default_screen, sweep12_with_gaze):
    from headplod.render.still import TerrainScene

    folder, _ = sweep12_with_gaze
    scene = TerrainScene.build(default_screen, max_level=2)
    config = PaperTablesConfig(frames=4, warmup=1, viewpoints=("mountains",), conditions=("honest",),
                               size=(96, 54), source=str(folder), gaze_prior_deg=(8.0, 6.0))
    report = paper_tables(config, err=io.StringIO(), scene=scene, ctx=gl_context)
    c = report["conditions"]["honest"]
    assert c["true_gaze_frames"] == 2
    assert report["config"]["gaze_priors"] == {"default": [8.0, 6.0], "head only": [0.0, 0.0]}
    rows = {(r["scenario"], r["hysteresis"], r.get("prior")): r for r in c["rows"]}
    assert len(c["rows"]) == 13                                     # 4 x 2 default, 4 head only, full
    for scenario in ("none", "fixed", "adaptive", "smoothed"):
        default, head = rows[scenario, True, "default"], rows[scenario, True, "head only"]
        assert default["gaze_prior_deg"] == [8.0, 6.0] and head["gaze_prior_deg"] == [0.0, 0.0]
        for row in (default, head):
            per = row["per_frame"]
            # The gaze disc is the true POI's where the gaze truth puts the gaze there, and none where it misses.
            assert per["psnr_gaze_db"][0::2] == per["psnr_true_db"][0::2]
            assert per["psnr_gaze_db"][1::2] == [None, None]
            shares = [v for v in per["tracker_cov_share"] if v is not None]
            assert all(0.0 <= v <= 1.0 for v in shares)
        if scenario == "none":
            assert default["per_frame"]["tracker_cov_share"] == [0.0] * 4           # all the prior's
            assert head["per_frame"]["tracker_cov_share"] == [None] * 4             # nothing uncertain
        else:
            assert head["per_frame"]["tracker_cov_share"] == [1.0] * 4              # all the tracker's
            assert 0.0 < default["tracker_cov_share"] < 0.05                        # σ 0.5° against 8° x 6°
    # The goals and Table 1's first block stay the default prior's; the head-only rows follow them.
    assert {r["prior"] for r in c["table1"]} == {"default", "head only"}
    assert c["true_poi"]["all"]["on"]["frames"] == 3
    text = format_tables(report)
    assert "PSNR gaze" in text and "trk share" in text and " head " in text and "8x6" in text
