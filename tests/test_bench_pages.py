"""tools/bench_tables.py: each bench's page carries the JSON's figures, the command, the date and --quick."""
from __future__ import annotations

import json

import pytest

from conftest import load_tool

UNCERTAINTY = {"default": "first_order_smoothed",
               "sets": {"static 55 cm": {"mean_pose_ms": 1.0, "estimators": {
                   "first_order_smoothed": {"mean_nees": 2.345, "trace_change_mean": 0.012, "ratio_to_mean_pose": 0.97},
                   "paper": {"mean_nees": 9e-5, "trace_change_mean": 0.045, "ratio_to_mean_pose": 23.3}}}},
               "goals": [{"goal": "default mean NEES within (1.5, 2.6) on every set", "worst": [2.345, 2.345],
                          "met": True}],
               "fig17": {"ratio": [0.1, 0.3], "var_phi_deg2": [22.5, 23.4], "var_theta_deg2": [1.9, 2.0]}}
LIVE = {"recording": "rec", "repeats": 3, "results": {"replay": {
    "frames": 150, "ok": 149, "latency_from": "reading", "rate_hz": 138.7, "latency_ms_p50": 7.04,
    "latency_ms_p95": 8.7, "latency_ms_max": 9.9, "read_ms_mean": 5.1, "track_ms_mean": 1.75,
    "output_ms_mean": 0.3, "capture_over_tracking": 2.9}},
    "camera": {"preset": "glints_lamp", "rate_hz": 120.0, "frames": 360, "repeats": 3, "image_size": [640, 480],
               "offered": 1080, "tracked": 1000, "ok": 998, "dropped_busy": 80, "processing_hz": 111.1,
               "capacity_hz": 104.0, "latency_ms_p50": 6.12, "latency_ms_p99": 14.37, "latency_ms_max": 21.5,
               "latency_from": "the tick", "track_ms_mean": 8.0, "track_ms_max": 19.9,
               "goals": [{"goal": "every frame of a 120 Hz camera tracked", "worst": 80, "met": False},
                         {"goal": "capture-to-pose p99 <= 8 ms", "worst": 14.37, "met": False}]},
    "load_avg": {"before": [1.5, 1.2, 1.0], "after": [2.25, 1.5, 1.1], "cores": 2}}
PAPER = {"config": {"frames": 30, "warmup": 10, "viewpoints": ["mountains"], "noise_deg": 0.5,
                    "gaze_priors": {"default": [10.7, 6.3], "head only": [0.0, 0.0]}},
         "conditions": {"honest": {"poses": "tracked once", "frames_with_pose": 30, "frames": 30,
                                   "sigma_deg_median": 0.5, "nees_mean": 2.1, "true_gaze_frames": 27,
                                   "table1": [{"scenario": "adaptive", "hysteresis": True, "changes": 4.2,
                                               "flicker": 0.1, "fps": 20.0, "fps_ratio_to_full": 6.3,
                                               "triangles": 123456, "psnr_tracked_disc_db": 48.2,
                                               "psnr_true_disc_db": 46.75, "prior": "default",
                                               "gaze_prior_deg": [10.7, 6.3], "psnr_gaze_disc_db": 41.26,
                                               "tracker_cov_share": 0.0031},
                                              {"scenario": "adaptive", "hysteresis": True, "changes": 5.0,
                                               "flicker": 0.2, "fps": 24.0, "fps_ratio_to_full": 7.0,
                                               "triangles": 100000, "psnr_tracked_disc_db": 48.0,
                                               "psnr_true_disc_db": 46.0, "prior": "head only",
                                               "gaze_prior_deg": [0.0, 0.0], "psnr_gaze_disc_db": 38.04,
                                               "tracker_cov_share": 1.0}],
                                   "true_poi": {"mountains": {"on": {"none_below": 12, "frames": 20,
                                                                     "kept_fraction": {"fixed": 1.0, "adaptive": 0.95,
                                                                                       "smoothed": 0.9}},
                                                              "triangles": {"adaptive": 100000, "fixed": 120000}}}}},
         "goals": [{"status": "met", "condition": "honest", "viewpoint": "all", "goal": "adaptive keeps >= 95%",
                    "figure": 0.95, "frames": 12}],
         "findings": ["adaptive flickers no more than fixed"]}
PLOD = {"size": [1280, 720], "px_per_deg": 25.2,
        "modes": {"full": {"triangles": 2097152, "select_ms": 0.1, "build_ms": 0.2, "render_ms": 120.0,
                           "frame_ratio_full_over_mode": 1.0, "select_build_over_full_render": 0.0,
                           "psnr_db": float("inf"), "psnr_disc_5deg_db": float("inf"), "flip": 0.0},
                  "change": {"triangles": 254357, "select_ms": 2.0, "build_ms": 1.5, "render_ms": 25.0,
                             "frame_ratio_full_over_mode": 4.44, "select_build_over_full_render": 0.029,
                             "psnr_db": 40.1, "psnr_disc_5deg_db": 46.3, "flip": 0.0512}},
        "velocity_sweep": {"csf": [{"set_speed_deg_s": 0.0, "triangles": 212000}, {"set_speed_deg_s": 5.0,
                                                                                    "triangles": 19000}]},
        "ellipse": {"sigma_deg": [1.5, 3.0], "none": {"fraction_inside_at_full_detail": 0.38},
                    "fixed_eq1": {"fraction_inside_at_full_detail": 0.55},
                    "fixed": {"fraction_inside_at_full_detail": 1.0}},
        "stability": {"fixed": {"mean_changes": 0.0, "max_changes": 0}},
        "goals": [{"goal": "frame at least 5x faster than full", "value": 4.44, "met": False}]}

_STAGE = {"p50_ms": 1.25, "p99_ms": 9.5, "max_ms": 12.0, "p50_x": 70.0, "p99_x": 530.0, "max_x": 670.0}
CLUTTER = {"quick": True, "blobs": [5, 60], "frames_per_n": 2, "threshold_pass_ms": 0.018,
           "machine": {"cpus": 2, "load_1_5_15": [3.5, 2.25, 1.0]},
           "runs": {"acquire": {n: {"frames": 2, "frames_with_pose": ok, "wrong_poses": 0, "blobs_median": float(n),
                                    "hypotheses_median": h, "hypotheses_max": int(2 * h), "stages": {"total": _STAGE}}
                                for n, ok, h in (("5", 2, 1.0), ("60", 1, 1339.0))}}}


@pytest.fixture(scope="module")
def tool():
    return load_tool("bench_tables")


@pytest.mark.parametrize("kind, data, figures", [
    ("uncertainty", UNCERTAINTY, ["| static 55 cm | 2.35 | 1.2% | 0.97 |", "22.5", "met: default mean NEES"]),
    ("live", LIVE, ["| replay | 139 | 7.0 | 8.7 |", "149 / 150", "A camera at 120 Hz: `glints_lamp` (640x480)",
                    "| 1080 | 1000 | 80 | 998 | 111.1 | 104 | 8.00 | 19.90 | 6.12 | 14.37 | 21.50 |",
                    "on 2 cores: 1.50, 1.20, 1.00 before the bench, 2.25, 1.50, 1.10 after",
                    "**not met**: capture-to-pose p99 <= 8 ms: 14.4"]),
    ("clutter", CLUTTER, ["| 60 | 60 | 1/2 | 0 | 1339 | 2678 | 1.2 / 9.5 / 12.0 | 70 / 530 / 670 |",
                          "| 5 | total | 1.25 / 9.50 / 12.00 | 70 / 530 / 670 |", "3.50 / 2.25 / 1.00", "0.018 ms",
                          "a quick run", "--chart docs/img/bench_clutter.png"]),
    ("paper", PAPER, ["## honest", "| adaptive | on | 10.7° × 6.3° | 4.2 | 0.1 |", "46.8",
                      "| 46.8 | 41.3 | 0.003 |", "| adaptive | on | head only | 5.0 | 0.2 |", "| 38.0 | 1.000 |",
                      "gaze_truth.csv: on 27 frames", "gaze prior σ 10.7° × 6.3°, and each scenario again head only",
                      "| honest | mountains | 12/20 |",
                      "- met: honest, all: adaptive keeps >= 95%: 95%", "adaptive flickers no more than fixed",
                      "--quick", "a quick run"]),
    ("plod", PLOD, ["| `change` | 254,357 |", "4.44", "| `full` | 2,097,152 |", "identical", "212,000",
                    "`fixed` (the default ellipse shift) 100%", "**not met**: frame at least 5x faster than full"]),
])
def test_each_page_carries_the_json_figures_and_where_they_came_from(tool, tmp_path, kind, data, figures):
    source = tmp_path / f"bench_{kind}.json"
    source.write_text(json.dumps(data))
    page = tmp_path / f"bench-{kind}.md"
    assert tool.main([kind, str(source), str(page)]) == 0
    text = page.read_text()
    assert f"`headplod bench {kind}" in text and str(source) in text and "(UTC)" in text
    for figure in figures:
        assert figure in text, figure


def test_quick_is_said_when_the_json_does_not(tool, tmp_path):
    source = tmp_path / "u.json"
    source.write_text(json.dumps(UNCERTAINTY))
    page = tmp_path / "u.md"
    assert tool.main(["uncertainty", str(source), str(page), "--quick"]) == 0
    assert "bench uncertainty --quick" in page.read_text() and "a quick run" in page.read_text()


def test_a_json_of_another_bench_is_refused_and_nothing_written(tool, tmp_path, capsys):
    source = tmp_path / "live.json"
    source.write_text(json.dumps({"sets": {"x": {"estimators": 3}}}))
    page = tmp_path / "page.md"
    assert tool.main(["uncertainty", str(source), str(page)]) == 2
    assert "not the JSON of 'headplod bench uncertainty'" in capsys.readouterr().err
    assert not page.exists()
