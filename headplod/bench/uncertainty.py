"""``headplod bench uncertainty``: which covariance of V to trust, and at what cost.

For every set and estimator (:mod:`headplod.tracking.uncertainty`):

- calibration: the mean NEES, eᵀ cov⁻¹ e with e the (φ, θ) of the true V in
  the reported head frame; 2 for a calibrated estimator (the issue asks the
  default to lie within 1.5-2.6 on every set);
- stability: the mean frame-to-frame relative change of the covariance's
  trace (for a still head the goal is ≤ 5%);
- cost: the estimator's time per frame, with the preparation of its input
  (Jacobian rows, shot-noise terms), as a ratio to the mean-pose time of the
  same frames, measured in the same run.

It also reproduces the paper's Fig. 10 (histogram of the distance between
the two viewing rays of pixel pairs, with the 2.0 mm threshold) and Fig. 17
(variance of φ and θ against the sub-sampling ratio).
"""
from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from .. import io
from ..capture.synthetic import ensure_dataset
from ..live.loop import track_frames
from ..progress import Progress, note
from ..tracking.tracker import Tracker, TrackerConfig
from ..tracking.uncertainty import COVARIANCE_ESTIMATORS, DEFAULT_COVARIANCE, PaperPixelClouds, make_covariance_estimator, view_angles_deg
from .outputs import pyplot, save_figure, write_json

# (set, preset, frames full/quick, options, still head?)
UNCERTAINTY_SETS = [
    ("static 55 cm", "static", 90, 30, {"distance_mm": 550.0}, True),
    ("static 120 cm", "static", 90, 30, {"distance_mm": 1200.0}, True),
    ("yaw sweep", "yaw_sweep", 90, 30, {}, False),
    ("pitch sweep", "pitch_sweep", 60, 30, {}, False),
    ("roll sweep", "roll_sweep", 60, 30, {}, False),
    ("extreme yaw 60 roll 35", "extreme", 40, 20, {}, False),
    ("dim IR", "dim_ir", 60, 30, {}, False),
    ("glints + lamp", "glints_lamp", 60, 30, {}, False),
    ("wide-angle HD", "wide_hd", 40, 20, {}, False),
]
NEES_RANGE = (1.5, 2.6)
STABILITY_GOAL = 0.05
COST_GOAL = 2.0


def nees(cov: np.ndarray, true_v: np.ndarray, axes: np.ndarray) -> float:
    """eᵀ cov⁻¹ e for the (φ, θ) of the true V in the reported head frame (deg, deg²)."""
    e = view_angles_deg(true_v[None, :], axes)[0]
    return float(e @ np.linalg.solve(cov, e))


def run_set(dataset: io.Dataset, estimators) -> dict:
    """Track a dataset once; run every covariance estimator on the same frames."""
    tracker = Tracker(dataset.rig, dataset.markers, TrackerConfig())
    est = {name: make_covariance_estimator(name, dataset.rig, dataset.markers.points_mm, tracker.axes_G)
           for name in estimators}
    out = {name: {"nees": [], "trace": [], "time": []} for name in estimators}
    pose_times, input_times = [], []
    for frame, result in track_frames(dataset, tracker):
        if result is None or not result.ok or dataset.truth is None or frame.index not in dataset.truth:
            continue                           # result None: an error frame (the tracker was reset)
        pose_times.append(result.timings_s["mean_pose"])
        # What every estimator needs first (Jacobian rows, shot-noise terms).
        input_times.append(result.timings_s["covariance_input"])
        true_v = dataset.truth[frame.index][1][2]
        for name, estimator in est.items():
            t0 = time.perf_counter()
            cov = estimator(result.cov_input)
            out[name]["time"].append(time.perf_counter() - t0)
            if np.isfinite(cov).all() and np.linalg.det(cov) > 0:
                out[name]["nees"].append(nees(cov, true_v, result.axes))
                out[name]["trace"].append(float(np.trace(cov)))
    mean_pose = float(np.mean(pose_times)) if pose_times else float("nan")
    prep = float(np.mean(input_times)) if input_times else 0.0
    summary = {}
    for name, r in out.items():
        trace = np.array(r["trace"])
        change = np.abs(np.diff(trace)) / trace[:-1] if len(trace) > 1 else np.array([np.nan])
        summary[name] = {
            "frames": len(r["nees"]),
            "mean_nees": float(np.mean(r["nees"])) if r["nees"] else float("nan"),
            "median_nees": float(np.median(r["nees"])) if r["nees"] else float("nan"),
            "trace_change_mean": float(np.mean(change)),
            "trace_change_p95": float(np.percentile(change, 95)),
            "mean_trace_deg2": float(np.mean(trace)) if len(trace) else float("nan"),
            "time_ms": (float(np.mean(r["time"])) + prep) * 1e3 if r["time"] else float("nan"),
            "ratio_to_mean_pose": (float(np.mean(r["time"])) + prep) / mean_pose if r["time"] else float("nan"),
        }
    return {"mean_pose_ms": mean_pose * 1e3, "estimators": summary}


def fig17(dataset: io.Dataset, ratios=(0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0), frames: int = 10) -> dict:
    """Variance of φ and θ of the paper's estimator against the sub-sampling ratio (its Fig. 17)."""
    tracker = Tracker(dataset.rig, dataset.markers, TrackerConfig())
    inputs = []
    for _, result in track_frames(dataset, tracker, max_frames=frames):
        if result is not None and result.ok:
            inputs.append(result.cov_input)
    curves = {"ratio": list(ratios), "var_phi_deg2": [], "var_theta_deg2": []}
    gaps = None
    for ratio in ratios:
        est = PaperPixelClouds(dataset.rig, dataset.markers.points_mm, ratio=ratio)
        covs = [est(x) for x in inputs]
        covs = [c for c in covs if np.isfinite(c).all()]
        curves["var_phi_deg2"].append(float(np.mean([c[0, 0] for c in covs])))
        curves["var_theta_deg2"].append(float(np.mean([c[1, 1] for c in covs])))
        if gaps is None:
            gaps = np.concatenate([_gaps(est, x) for x in inputs])
    curves["ray_gaps_mm"] = gaps
    return curves


def _gaps(est: PaperPixelClouds, x) -> np.ndarray:
    est.clouds(x)
    return est.last_gaps_mm


def run_uncertainty_bench(json_path=None, chart_path=None, quick: bool = False) -> int:
    cv2.setNumThreads(1)
    results = {}
    for name, preset, n_full, n_quick, options, _ in UNCERTAINTY_SETS:
        dataset = io.Dataset(ensure_dataset(preset, frames=n_quick if quick else n_full, **options))
        bar = Progress(1, f"bench uncertainty {name}")
        results[name] = run_set(dataset, COVARIANCE_ESTIMATORS)
        bar.step()
    near = io.Dataset(ensure_dataset("static", frames=90 if not quick else 30, distance_mm=550.0))
    curves = fig17(near, frames=6 if quick else 12)
    text, summary = _report(results)
    print(text)
    if json_path:
        write_json(json_path, {"sets": results, "goals": summary, "default": DEFAULT_COVARIANCE,
                               "fig17": {k: v for k, v in curves.items() if k != "ray_gaps_mm"}})
        note(f"results: {json_path}")
    if chart_path:
        _charts(results, curves, chart_path)
    return 0


def _report(results: dict):
    lines = [f"{'set':24s} {'estimator':22s} {'NEES':>7s} {'Δtrace':>8s} {'cost':>6s}"]
    for name, r in results.items():
        for est, s in r["estimators"].items():
            lines.append(f"{name:24s} {est:22s} {s['mean_nees']:7.3g} {s['trace_change_mean']:8.1%} "
                         f"{s['ratio_to_mean_pose']:6.2f}")
    d = DEFAULT_COVARIANCE
    nees_values = [r["estimators"][d]["mean_nees"] for r in results.values()]
    still = [r["estimators"][d]["trace_change_mean"] for (n, r), spec in zip(results.items(), UNCERTAINTY_SETS) if spec[5]]
    cost = [r["estimators"][d]["ratio_to_mean_pose"] for r in results.values()]
    goals = [
        {"goal": f"default mean NEES within {NEES_RANGE} on every set", "worst": [min(nees_values), max(nees_values)],
         "met": bool(NEES_RANGE[0] <= min(nees_values) and max(nees_values) <= NEES_RANGE[1])},
        {"goal": f"default trace change ≤ {STABILITY_GOAL:.0%} for a still head", "worst": max(still),
         "met": bool(max(still) <= STABILITY_GOAL)},
        {"goal": f"default costs ≤ {COST_GOAL}x the mean-pose time", "worst": max(cost),
         "met": bool(max(cost) <= COST_GOAL)},
    ]
    lines.append("")
    lines.append(f"goals (default '{d}'):")
    for g in goals:
        lines.append(f"  [{'met' if g['met'] else 'NOT MET'}] {g['goal']}: {g['worst']}")
    return "\n".join(lines), goals


def _charts(results: dict, curves: dict, chart_path: str) -> None:
    plt = pyplot()
    base = Path(chart_path)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 5.5))
    colors = dict(zip(COVARIANCE_ESTIMATORS, plt.cm.tab10(np.linspace(0, 1, 10))))
    for name, r in results.items():
        for est, s in r["estimators"].items():
            a1.plot(s["ratio_to_mean_pose"], s["mean_nees"], "o", color=colors[est], label=est if name == next(iter(results)) else None)
            a2.plot(s["ratio_to_mean_pose"], s["trace_change_mean"] * 100, "o", color=colors[est])
    a1.axhspan(*NEES_RANGE, color="green", alpha=0.1)
    a1.axhline(2, color="green", lw=1)
    a1.set_yscale("log")
    a1.set_xscale("log")
    a1.set_xlabel("time per frame / mean-pose time")
    a1.set_ylabel("mean NEES (2 = calibrated), one point per set")
    a1.legend(fontsize=8)
    a2.axhline(STABILITY_GOAL * 100, color="k", ls=":")
    a2.set_xscale("log")
    a2.set_yscale("log")
    a2.set_xlabel("time per frame / mean-pose time")
    a2.set_ylabel("mean frame-to-frame change of trace (%)")
    fig.suptitle("covariance of V: calibration and stability against cost")
    save_figure(fig, base, dpi=110)

    fig, (b1, b2) = plt.subplots(1, 2, figsize=(12, 4.5))
    b1.plot(curves["ratio"], curves["var_phi_deg2"], "o-", label="var φ")
    b1.plot(curves["ratio"], curves["var_theta_deg2"], "s-", label="var θ")
    b1.set_xlabel("sub-sampling ratio")
    b1.set_ylabel("variance (deg²)")
    b1.set_title("paper's estimator against the sub-sampling ratio (their Fig. 17)")
    b1.legend()
    gaps = curves["ray_gaps_mm"]
    b2.hist(gaps[gaps < 10], bins=100)
    b2.axvline(2.0, color="r", label="2.0 mm (the paper's threshold)")
    b2.set_xlabel("distance between the viewing rays of a pixel pair (mm)")
    b2.set_ylabel("pairs")
    b2.set_title("reconstruction error of pixel pairs (their Fig. 10)")
    b2.legend()
    other = save_figure(fig, base.with_name(base.stem + "_paper" + base.suffix), dpi=110)
    note(f"charts: {base}, {other}")
