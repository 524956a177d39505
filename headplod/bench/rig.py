"""``headplod bench track``, the imperfect-rig sets: tracking while the rig is refined online.

Each set is the ``imperfect_rig`` synthetic preset with one fault (a right
camera turned since calibration, a board printed at the wrong scale, a wrong
focal length, an undeclared exposure offset, fused glints, a bump during the
recording): ``rig.yaml`` is wrong, and the dataset keeps the true rig aside in
``rig_truth.json`` as it keeps the head's in ``truth.csv``. Only the default
estimator runs. Per set: the frames with a pose, wrong poses, the errors of V
and P1 over the whole set and after the refinement has had ``settle_s``
seconds, the mean NEES of the covariance of V, and the refined rig's errors
against the truth frame by frame (the tracker's ``refiner`` after each
frame, against the ``rig_truth.json`` segment active at that frame).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from ..tracking import evaluate
from .. import io
from ..capture.synthetic import ensure_dataset
from ..live.loop import track_frames
from ..tracking.tracker import Tracker, TrackerConfig
from .baseline import threshold_baseline_s
from .goals import (frames_for_fraction, frames_for_mean, frames_for_quantile, not_judged, short_sets,
                    verdict)
from .outputs import pyplot, save_figure
from .uncertainty import nees
from ..tol import tol

#: Seconds of refinement before the "settled" errors are measured (full runs;
#: quick runs are 2 s long and use QUICK_SETTLE_S).
SETTLE_S = 3.0
QUICK_SETTLE_S = 1.0
FPS = 30.0

# (set name, imperfect_rig faults, frames in full / quick runs, faults that differ in quick runs);
# 5-6 s in full runs, 2 s in quick ones (30 fps unless said)
RIG_SETS = [
    ("stale rig 0.1°", {"rotation_deg": 0.1}, 150, 60, {}),
    ("stale rig 0.5°", {"rotation_deg": 0.5}, 150, 60, {}),
    ("stale rig 1°", {"rotation_deg": 1.0}, 150, 60, {}),
    ("board scale 2%", {"baseline_scale": 1.02}, 150, 60, {}),
    ("board scale 5%", {"baseline_scale": 1.05}, 150, 60, {}),
    ("right focal 1%", {"focal_scale": 1.01}, 150, 60, {}),
    ("offset 8 ms undeclared", {"offset_s": 0.008}, 150, 60, {}),
    ("offset 33 ms undeclared", {"offset_s": round(1.0 / FPS, 4)}, 150, 60, {}),
    # fast_motion runs at 60 fps: as many seconds as the others.
    ("fast motion + blur + 6 ms offset", {"base": "fast_motion", "offset_s": 0.006, "exposure_s": 0.008},
     300, 120, {}),
    ("fused glints", {"fused_glints": 2}, 150, 60, {}),
    # Bumped at 3 s of 6 (full); at 1 s of 2 in quick runs.
    ("bump 0.4° at 3 s", {"bump_frame": 90, "bump_deg": 0.4}, 180, 60, {"bump_frame": 30}),
    ("still head + stale rig", {"base": "static", "rotation_deg": 0.3}, 150, 60, {}),
    # rig.yaml far off: the first frames, before any refinement, must not be wrong.
    ("rig far off: turned 3°", {"rotation_deg": 3.0}, 150, 60, {}),
    ("rig far off: baseline 10%", {"baseline_scale": 1.10}, 150, 60, {}),
    ("rig far off: 2°, 7%, focal 2%", {"rotation_deg": 2.0, "baseline_scale": 1.07, "focal_scale": 1.02}, 150, 60, {}),
    # What ordinary USB webcams add: a rolling shutter (readout: first row to
    # last), MJPEG, auto exposure, dropped and repeated frames, free-running clocks.
    ("global shutter, perfect rig", {}, 150, 60, {}),
    ("rolling shutter 15 ms", {"readout_s": 0.015}, 150, 60, {}),
    ("rolling shutter 30 ms", {"readout_s": 0.030}, 150, 60, {}),
    ("rolling shutter 30 ms + 12 ms offset", {"readout_s": 0.030, "offset_s": 0.012}, 150, 60, {}),
    ("rolling shutter 30 ms + blur + MJPEG", {"readout_s": 0.030, "exposure_s": 0.008, "jpeg_quality": 75},
     150, 60, {}),
    ("rolling shutter 30 ms + stale rig + glints", {"readout_s": 0.030, "rotation_deg": 0.5, "baseline_scale": 1.02,
                                                    "fused_glints": 1}, 150, 60, {}),
    ("auto exposure, dropped and repeated frames", {"auto_exposure": True, "drop_frames": 0.02,
                                                     "duplicate_frames": 2, "readout_s": 0.015}, 150, 60, {}),
    ("ordinary webcams (everything)", {"preset": "ordinary_webcams"}, 150, 60, {}),
]
FUSED_SETS = ["fused glints", "rolling shutter 30 ms + stale rig + glints", "ordinary webcams (everything)"]
PERFECT_SETS = ["global shutter, perfect rig", "rolling shutter 15 ms", "rolling shutter 30 ms"]
WEBCAM_SETS = ["ordinary webcams (everything)"]
#: Sets with a still head: nothing there shows a readout (nor needs one).
STILL_SETS = ["still head + stale rig"]
#: Sets whose readout is checked (rolling shutters, and the global shutter that must come out 0).
READOUT_GOAL = (0.001, 0.05)       # recovered within 1 ms or 5%, after 5 s
WRONG_POSITION_MM = 20.0

# (label, sets (None: every rig set), key, test, limit, frames per set the statistic needs: a quick run with
# shorter sets does not judge the goal); {settle} is replaced by the settle time.
MEDIAN = frames_for_quantile(0.5)
NEES_FRAMES = frames_for_mean(2.0, 0.25)        # NEES of V: chi-square, 2 degrees of freedom (sd 2 per frame)
READOUT_FRAMES = int(5 * FPS)                   # READOUT_GOAL holds after 5 s
RIG_GOALS = [
    ("frames with a pose ≥ 99%", "not fused", "pose_fraction", ">=", 0.99, frames_for_fraction(0.99)),
    ("frames with a pose ≥ 97% (glints)", FUSED_SETS, "pose_fraction", ">=", 0.97, frames_for_fraction(0.97)),
    ("zero wrong poses (V > 5° or P1 > 20 mm off)", None, "wrong_poses", "<=", 0, 1),
    ("median V error ≤ 0.15° (whole set)", None, "v_err_deg_median", "<=", 0.15, MEDIAN),
    ("median position error ≤ 1 mm (whole set)", None, "pos_err_mm_median", "<=", 1.0, MEDIAN),
    ("median V error ≤ 0.1° after {settle} s", "not webcam", "v_err_deg_median_settled", "<=", 0.1, MEDIAN),
    ("median position error ≤ 0.5 mm after {settle} s", "not webcam", "pos_err_mm_median_settled", "<=", 0.5,
     MEDIAN),
    ("median V error ≤ 0.15° after {settle} s (ordinary webcams)", WEBCAM_SETS, "v_err_deg_median_settled", "<=",
     0.15, MEDIAN),
    ("median position error ≤ 0.8 mm after {settle} s (ordinary webcams)", WEBCAM_SETS, "pos_err_mm_median_settled",
     "<=", 0.8, MEDIAN),
    ("mean NEES within 1.5-3", "not perfect", "nees_mean", "in", (1.5, 3.0), NEES_FRAMES),
    ("mean NEES within 1.5-2.6 (perfect rigs)", PERFECT_SETS, "nees_mean", "in", (1.5, 2.6), NEES_FRAMES),
    ("readout recovered within 1 ms or 5% at the end (moving heads)", "moving", "readout_ok", ">=", 1,
     READOUT_FRAMES),
    ("no pose from a repeated buffer", None, "repeated_with_pose", "<=", 0, 1),
    ("slowest tracked frame (99th percentile) ≤ 3x the median", None, "frame_p99_to_median", "<=", 3.0,
     frames_for_quantile(0.99)),
]


def rig_set_faults(entry, quick: bool) -> tuple[dict, int]:
    """The ``imperfect_rig`` options and frame count of a RIG_SETS entry."""
    _, faults, n_full, n_quick, quick_faults = entry
    if quick:
        return {**faults, **quick_faults}, n_quick
    return dict(faults), n_full


def load_rig_truth(folder) -> dict | None:
    """``rig_truth.json`` of a dataset folder with arrays, or None."""
    path = Path(folder) / "rig_truth.json"
    if not path.exists():
        return None
    data = json.loads(path.read_text())
    segments = [{"first_frame": int(s["first_frame"]), "R": np.asarray(s["R"], float),
                 "T": np.asarray(s["T"], float).reshape(3), "K1": np.asarray(s["K1"], float),
                 "K2": np.asarray(s["K2"], float)} for s in data["segments"]]
    segments.sort(key=lambda s: s["first_frame"])
    return {"segments": segments, "time_offset_s": float(data.get("time_offset_s", 0.0))}


def truth_segment(rig_truth: dict, frame: int) -> dict:
    """The true rig active at a frame (the last segment starting at or before it)."""
    active = rig_truth["segments"][0]
    for seg in rig_truth["segments"]:
        if seg["first_frame"] <= frame:
            active = seg
    return active


def webcam_truth(folder) -> dict:
    """What a dataset's webcams did (``webcam_truth.json``): the rolling shutter's readout (s; 0 without the
    file) and the frames whose images repeat the frame before (a buffer handed out twice)."""
    path = Path(folder) / "webcam_truth.json"
    if not path.exists():
        return {"readout_s": 0.0, "repeated_frames": set()}
    data = json.loads(path.read_text())
    return {"readout_s": float(data.get("readout_s", 0.0)),
            "repeated_frames": {int(d["frame"]) for d in data.get("duplicates", [])}}


def rig_errors(R, T, K2, offset_s, truth_seg: dict, true_offset_s: float) -> dict:
    """Errors of a rig estimate against the truth: turn (deg), baseline and focal scale (−), offset (ms)."""
    turn = cv2.Rodrigues(np.asarray(R, float) @ truth_seg["R"].T)[0].ravel()
    return {"turn_err_deg": float(np.degrees(np.linalg.norm(turn))),
            "scale_err": float(np.linalg.norm(T) / np.linalg.norm(truth_seg["T"]) - 1.0),
            "focal_err": float(math.sqrt(K2[0, 0] * K2[1, 1] / (truth_seg["K2"][0, 0] * truth_seg["K2"][1, 1])) - 1.0),
            "offset_err_ms": float((offset_s - true_offset_s) * 1e3)}


SERIES_KEYS = ("frame", "t", "ok", "v_err_deg", "pos_err_mm", "nees", "turn_err_deg", "scale_err", "focal_err",
               "offset_err_ms", "turn_sd_deg", "offset_sd_ms", "readout_err_ms", "readout_sd_ms", "mean_pose_ms",
               "refine_ms", "frame_ms", "tracked")


def run_rig_set(folder, settle_s: float = SETTLE_S, estimator: str | None = None) -> dict:
    """Track one imperfect-rig dataset (``folder`` with ``truth.csv`` and ``rig_truth.json``) with ``estimator``
    (default: the tracker's); the summary (:func:`_summarize`; "settled": frames ``settle_s`` after the first)
    and ``series``, per frame (NaN where there is no value): :data:`SERIES_KEYS`, e.g. ``scale_err``
    (|T|/|T_true| − 1), ``focal_err`` (right focal / true − 1), ``offset_err_ms`` (the refined exposure
    offset, timestamps included, minus the true one), ``turn_sd_deg`` (largest 1σ of the turn).
    """
    dataset = io.Dataset(folder)
    rig_truth = load_rig_truth(folder)
    if rig_truth is None:
        raise ValueError(f"{folder}: no rig_truth.json (not an imperfect_rig dataset)")
    config = TrackerConfig() if estimator is None else TrackerConfig(estimator=estimator)
    tracker = Tracker(dataset.rig, dataset.markers, config)
    webcams = webcam_truth(folder)
    true_readout = webcams["readout_s"]
    series = {k: [] for k in SERIES_KEYS}
    repeated = []
    baselines = []
    t0 = None
    for frame, result in track_frames(dataset, tracker):
        row = dict.fromkeys(SERIES_KEYS, float("nan"))
        row["frame"], row["ok"] = frame.index, False
        row["repeated"] = frame.index in webcams["repeated_frames"]
        if frame.t is not None:
            t0 = frame.t if t0 is None else t0
            row["t"] = frame.t - t0
        if result is not None:                 # None: an error frame (the tracker was reset)
            baselines.append(threshold_baseline_s(frame.left, frame.right))
            row["ok"] = bool(result.ok)
            if "mean_pose" in result.timings_s:
                row["mean_pose_ms"] = result.timings_s["mean_pose"] * 1e3
            if "refine_rig" in result.timings_s:
                row["refine_ms"] = result.timings_s["refine_rig"] * 1e3
            row["frame_ms"] = result.timings_s.get("total", float("nan")) * 1e3
            row["tracked"] = result.mode == "track"
            truth = dataset.truth.get(frame.index) if dataset.truth else None
            if result.ok and truth is not None:
                pos_true, axes_true = truth
                row["v_err_deg"] = float(evaluate.angle_deg(result.axes[2], axes_true[2]))
                row["pos_err_mm"] = float(np.linalg.norm(result.position_mm - pos_true))
                cov = result.cov_deg2
                if cov is not None and np.isfinite(cov).all() and np.linalg.det(cov) > 0:
                    row["nees"] = nees(cov, axes_true[2], result.axes)
            refiner = tracker.refiner
            if refiner is not None:
                state = refiner.estimator.state
                declared = (frame.t_right - frame.t) if (frame.t_right is not None and frame.t is not None) else 0.0
                row.update(rig_errors(state.R, state.T, state.K2(), state.offset_s + declared,
                                      truth_segment(rig_truth, frame.index), rig_truth["time_offset_s"]))
                sd = refiner.estimator.sigma()
                row["turn_sd_deg"] = float(np.degrees(np.max(sd[:3])))
                row["offset_sd_ms"] = float(sd[7] * 1e3)
                if len(sd) > 8:
                    row["readout_err_ms"] = (float(state.readout_s) - true_readout) * 1e3
                    row["readout_sd_ms"] = float(sd[8] * 1e3)
        for k in SERIES_KEYS:
            series[k].append(row[k])
        repeated.append(row["repeated"])
    out = _summarize(series, settle_s, np.asarray(repeated, bool))
    baseline = float(np.median(baselines)) if baselines else float("nan")
    out["threshold_pass_ms"] = baseline * 1e3
    out["mean_pose_ratio_to_threshold"] = out["mean_pose_ms"] / out["threshold_pass_ms"]
    out["refine_ratio_to_threshold"] = out["refine_ms_mean"] / out["threshold_pass_ms"]
    out["readout_true_ms"] = true_readout * 1e3
    final = out["final"] or {}
    err = final.get("readout_err_ms")
    out["readout_ok"] = int(err is not None and np.isfinite(err)
                            and abs(err) <= max(READOUT_GOAL[0] * 1e3, READOUT_GOAL[1] * true_readout * 1e3))
    out["faults"] = {"time_offset_s": rig_truth["time_offset_s"],
                     "segments_first_frame": [s["first_frame"] for s in rig_truth["segments"]]}
    out["series"] = {k: np.asarray(v, float if k != "frame" else int).tolist() for k, v in series.items()}
    return out


def _nanmedian(values) -> float | None:
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else None


def _summarize(series: dict, settle_s: float, repeated=None) -> dict:
    """Summary of a set's series (see :func:`run_rig_set`). ``repeated`` (frames,) bool: frames whose images
    repeat the frame before's; refusing them is right (no new exposure), so the share of frames with a pose
    is over the others."""
    ok = np.asarray(series["ok"], bool)
    fresh = ~np.asarray(repeated, bool) if repeated is not None and len(repeated) == len(ok) else np.ones(len(ok), bool)
    t = np.asarray(series["t"], float)
    v = np.asarray(series["v_err_deg"], float)
    p = np.asarray(series["pos_err_mm"], float)
    n = np.asarray(series["nees"], float)
    settled = t >= settle_s - tol.small
    out = {
        "frames": int(len(ok)), "ok": int(ok.sum()),
        "pose_fraction": float(ok[fresh].mean()) if fresh.any() else 0.0,
        "repeated_frames": int((~fresh).sum()), "repeated_with_pose": int(ok[~fresh].sum()),
        "wrong_poses": int(np.sum((np.nan_to_num(v) > evaluate.WRONG_IDENTIFICATION_DEG)
                                  | (np.nan_to_num(p) > WRONG_POSITION_MM))),
        "v_err_deg_median": _nanmedian(v), "pos_err_mm_median": _nanmedian(p),
        "v_err_deg_p95": float(np.nanpercentile(v, 95)) if np.isfinite(v).any() else None,
        "settle_s": settle_s, "frames_settled": int(settled.sum()),
        "v_err_deg_median_settled": _nanmedian(v[settled]), "pos_err_mm_median_settled": _nanmedian(p[settled]),
        "nees_mean": float(np.mean(n[np.isfinite(n)])) if np.isfinite(n).any() else None,
        "nees_median": _nanmedian(n),
        "nees_mean_settled": float(np.mean(n[settled & np.isfinite(n)])) if (settled & np.isfinite(n)).any() else None,
        "mean_pose_ms": float(np.nanmean(series["mean_pose_ms"])) if ok.any() else float("nan"),
        "refine_ms_mean": float(np.nanmean(series["refine_ms"])) if ok.any() else float("nan"),
        "refine_ms_max": float(np.nanmax(series["refine_ms"])) if ok.any() else float("nan"),
    }
    frame_ms = np.asarray(series["frame_ms"], float)[np.asarray(series["tracked"], float) == 1]
    frame_ms = frame_ms[np.isfinite(frame_ms)]
    out["frame_ms_median"] = float(np.median(frame_ms)) if len(frame_ms) else None
    out["frame_ms_p99"] = float(np.percentile(frame_ms, 99)) if len(frame_ms) else None
    out["frame_p99_to_median"] = (out["frame_ms_p99"] / out["frame_ms_median"]) if len(frame_ms) else None
    keys = ("turn_err_deg", "scale_err", "focal_err", "offset_err_ms", "turn_sd_deg", "offset_sd_ms",
            "readout_err_ms", "readout_sd_ms")
    known = np.flatnonzero(np.isfinite(np.asarray(series["turn_err_deg"], float)))
    out["initial"] = {k: float(series[k][known[0]]) for k in keys} if len(known) else None
    out["final"] = {k: float(series[k][known[-1]]) for k in keys} if len(known) else None
    at = [i for i in known if settled[i]]
    out["at_settle"] = {k: float(series[k][at[0]]) for k in keys} if at else None
    return out


def run_rig_sets(chosen, quick: bool, progress=None) -> dict:
    """Run RIG_SETS entries; {name: run_rig_set output}."""
    settle = QUICK_SETTLE_S if quick else SETTLE_S
    results = {}
    for entry in chosen:
        faults, frames = rig_set_faults(entry, quick)
        preset = faults.pop("preset", "imperfect_rig")
        folder = ensure_dataset(preset, frames=frames, quiet=True, **faults)
        results[entry[0]] = run_rig_set(folder, settle_s=settle)
        if progress is not None:
            progress(entry[0])
    return results


# ---------------------------------------------------------------------- report
def _check(value, test, limit) -> bool:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return False
    if test == ">=":
        return value >= limit
    if test == "<=":
        return value <= limit
    lo, hi = limit
    return lo <= value <= hi


def _fmt(value, spec: str, width: int) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-".rjust(width)
    return format(value, spec).rjust(width)


#: The groups of RIG_GOALS' "not ..." (and "moving") sets: every set but these.
_ALL_BUT = {"not fused": FUSED_SETS, "not webcam": WEBCAM_SETS, "moving": STILL_SETS, "not perfect": PERFECT_SETS}


def rig_goals(results: dict, quick: bool = False) -> list[dict]:
    """The goals over the rig sets present: worst value, the sets that miss, met; ``quick``: a goal whose sets
    are too short for its statistic is not judged (:mod:`headplod.bench.goals`)."""
    settle = next(iter(results.values()))["settle_s"] if results else SETTLE_S
    goals = []
    for label, sets, key, test, limit, needs in RIG_GOALS:
        if isinstance(sets, list):
            names = [n for n in sets if n in results]
        else:       # None: every set; else the sets but those of a group
            names = [n for n in results if n not in _ALL_BUT.get(sets, ())]
        if not names:
            continue
        values = {n: results[n].get(key) for n in names}
        missed = [n for n, v in values.items() if not _check(v, test, limit)]
        finite = {n: v for n, v in values.items() if v is not None and np.isfinite(v)}
        if test == ">=":
            worst = min(finite.values()) if finite else None
        elif test == "<=":
            worst = max(finite.values()) if finite else None
        else:
            worst = [min(finite.values()), max(finite.values())] if finite else None
        goal = {"goal": label.format(settle=f"{settle:g}"), "key": key, "test": test, "limit": limit,
                "worst": worst, "missed": missed, "met": not missed}
        short = short_sets({n: results[n].get("frames", 0) for n in names}, needs)
        goals.append(not_judged(goal, needs, short) if quick and short else goal)
    return goals


def rig_report(results: dict, quick: bool = False) -> dict:
    """Table and goals of the rig sets: {'text', 'json'}."""
    settle = QUICK_SETTLE_S if quick else SETTLE_S
    s_lab = f"{settle:g}s"
    width = max([33] + [len(name) for name in results])          # the longest set name sets the first column
    head = (f"{'imperfect-rig set':{width}s} {'pose':>6s} {'wrong':>5s} {'V med°':>7s} {'P med':>6s} "
            f"{'V>' + s_lab:>7s} {'P>' + s_lab:>6s} {'NEES':>5s} {'turn°':>6s} {'scale%':>7s} {'focal%':>7s} "
            f"{'off ms':>7s} {'ro ms':>6s} {'pose x':>6s} {'rig ms':>6s} {'rig x':>5s} {'p99/50':>6s}")
    lines = [head]
    for name, s in results.items():
        f = s["final"] or {}
        lines.append(
            f"{name:{width}s} {s['pose_fraction']:6.1%} {s['wrong_poses']:5d} {_fmt(s['v_err_deg_median'], '.3f', 7)} "
            f"{_fmt(s['pos_err_mm_median'], '.3f', 6)} {_fmt(s['v_err_deg_median_settled'], '.3f', 7)} "
            f"{_fmt(s['pos_err_mm_median_settled'], '.3f', 6)} {_fmt(s['nees_mean'], '.2f', 5)} "
            f"{_fmt(f.get('turn_err_deg'), '.3f', 6)} {_fmt(100 * f['scale_err'] if f else None, '+.2f', 7)} "
            f"{_fmt(100 * f['focal_err'] if f else None, '+.2f', 7)} {_fmt(f.get('offset_err_ms'), '+.2f', 7)} "
            f"{_fmt(f.get('readout_err_ms'), '+.2f', 6)} "
            f"{_fmt(s['mean_pose_ratio_to_threshold'], '.1f', 6)} {_fmt(s['refine_ms_mean'], '.3f', 6)} "
            f"{_fmt(s['refine_ratio_to_threshold'], '.1f', 5)} {_fmt(s['frame_p99_to_median'], '.1f', 6)}")
    lines.append(f"(pose: frames with a pose; V/P med: median errors of V (°) and P1 (mm), whole set and after "
                 f"{settle:g} s; NEES: mean; turn°/scale%/focal%/off ms: the refined rig's errors at the last "
                 f"frame; ro ms: the rolling-shutter readout's error at the last frame; pose x: mean-pose time / one "
                 f"threshold pass; rig ms, rig x: mean time of the 'refine_rig' stage per frame with a pose, and as a "
                 f"ratio to one threshold pass; p99/50: the 99th-percentile tracked frame's time over the median)")
    if quick:
        lines.append(f"(quick run: 2 s per set, so the settled errors are those after {settle:g} s and the bump "
                     f"is at 1 s)")
    goals = rig_goals(results, quick=quick)
    lines.append("")
    lines.append(f"goals on imperfect rigs (default estimator '{TrackerConfig().estimator}'):")
    for g in goals:
        if g["test"] == "in":
            worst = "-" if g["worst"] is None else f"{g['worst'][0]:.2f} .. {g['worst'][1]:.2f}"
            limit = f"{g['limit'][0]}-{g['limit'][1]}"
        else:
            worst = "-" if g["worst"] is None else f"{g['worst']:.3f}"
            limit = f"{g['limit']}"
        missed = f"; missed on: {', '.join(g['missed'])}" if g["missed"] else ""
        if g.get("judged") is False:
            lines.append(f"  [{verdict(g)}] {g['goal']}: {g['why']} (measured: worst {worst}, limit {limit})")
        else:
            lines.append(f"  [{verdict(g)}] {g['goal']}: worst {worst} (limit {limit}){missed}")
    refine = [s["refine_ms_mean"] for s in results.values() if np.isfinite(s["refine_ms_mean"])]
    ratio = [s["mean_pose_ratio_to_threshold"] for s in results.values()
             if np.isfinite(s["mean_pose_ratio_to_threshold"])]
    rratio = [s["refine_ratio_to_threshold"] for s in results.values() if np.isfinite(s["refine_ratio_to_threshold"])]
    timing = None
    if refine:
        timing = {"refine_ms_mean": float(np.median(refine)), "refine_ratio_to_threshold": float(np.median(rratio)),
                  "mean_pose_ratio_to_threshold": float(np.median(ratio)),
                  "refine_ms_max": float(max(s["refine_ms_max"] for s in results.values()))}
        lines.append(f"  [reported] rig refinement, its own stage: {timing['refine_ms_mean']:.3f} ms per frame "
                     f"({timing['refine_ratio_to_threshold']:.1f}x one threshold pass; slowest frame "
                     f"{timing['refine_ms_max']:.1f} ms), next to a mean pose of "
                     f"{timing['mean_pose_ratio_to_threshold']:.1f}x (medians over the sets)")
    return {"text": "\n".join(lines),
            "json": {"settle_s": settle, "sets": results, "goals": goals, "timing": timing}}


# ----------------------------------------------------------------------- chart
def rig_chart(results: dict, path) -> None:
    """Per set a column of three panels: errors of V and P1, NEES, the refined rig's errors (one PNG)."""
    plt = pyplot()

    names = list(results)
    ncols = min(4, max(len(names), 1))
    blocks = math.ceil(len(names) / ncols)
    fig, axes = plt.subplots(3 * blocks, ncols, figsize=(4.2 * ncols, 8.4 * blocks), squeeze=False)
    for i, name in enumerate(names):
        s = results[name]
        ser = {k: np.asarray(v, float) for k, v in s["series"].items()}
        col, top = i % ncols, 3 * (i // ncols)
        frames, t = ser["frame"], ser["t"]
        title = f"{name}\npose {s['pose_fraction']:.1%}"
        settle_frame = frames[np.argmax(t >= s["settle_s"] - tol.small)] if np.any(t >= s["settle_s"] - tol.small) else None
        bumps = s["faults"]["segments_first_frame"][1:]

        ax = axes[top, col]
        ax.plot(frames, ser["v_err_deg"], ".-", ms=2, lw=0.6, color="C0", label="V error (°)")
        ax.set_ylabel("V error (°)", color="C0", fontsize=7)
        ax2 = ax.twinx()
        ax2.plot(frames, ser["pos_err_mm"], ".-", ms=2, lw=0.6, color="C3", label="P1 error (mm)")
        ax2.set_ylabel("P1 error (mm)", color="C3", fontsize=7)
        ax.set_ylim(bottom=0)
        ax2.set_ylim(bottom=0)
        ax2.tick_params(labelsize=6)
        ax.set_title(f"{title}: pose errors", fontsize=8)
        ax.set_xlabel("frame", fontsize=7)

        ax = axes[top + 1, col]
        ax.axhspan(1.5, 3.0, color="g", alpha=0.15, label="goal 1.5-3")
        ax.axhline(2.0, color="g", lw=0.6, ls=":")
        ok = np.isfinite(ser["nees"]) & (ser["nees"] > 0)
        ax.semilogy(frames[ok], ser["nees"][ok], ".", ms=2.5, color="C2")
        if s["nees_mean"] is not None:
            ax.axhline(s["nees_mean"], color="C2", lw=0.8, label=f"mean {s['nees_mean']:.2f}")
        ax.set_title(f"pose {s['pose_fraction']:.1%}: NEES of V", fontsize=8)
        ax.set_xlabel("frame", fontsize=7)
        ax.legend(fontsize=6, loc="upper right")

        ax = axes[top + 2, col]
        for key, scale, label, color in (("turn_err_deg", 1.0, "turn (°)", "C0"),
                                          ("scale_err", 100.0, "baseline scale (%)", "C1"),
                                          ("focal_err", 100.0, "right focal (%)", "C4"),
                                          ("offset_err_ms", 1.0, "exposure offset (ms)", "C3"),
                                          ("readout_err_ms", 1.0, "shutter readout (ms)", "C5")):
            y = np.abs(ser[key]) * scale
            good = np.isfinite(y)
            ax.semilogy(t[good], np.maximum(y[good], 1e-4), lw=1.0, color=color, label=label)
        ax.set_ylim(1e-4, None)
        ax.set_title(f"pose {s['pose_fraction']:.1%}: |refined rig − truth|", fontsize=8)
        ax.set_xlabel("time (s)", fontsize=7)
        ax.legend(fontsize=6, loc="upper right")
        for a in axes[top:top + 3, col]:
            a.tick_params(labelsize=6)
            a.grid(True, which="both", alpha=0.25)
        for a, unit in ((axes[top, col], "frame"), (axes[top + 1, col], "frame"), (axes[top + 2, col], "t")):
            if settle_frame is not None:
                x = settle_frame if unit == "frame" else s["settle_s"]
                a.axvline(x, color="k", ls=":", lw=0.8)
            for b in bumps:
                at = np.flatnonzero(frames == b)
                if len(at):
                    a.axvline(b if unit == "frame" else t[at[0]], color="m", ls="--", lw=0.8)
    for j in range(len(names), blocks * ncols):
        for r in range(3):
            axes[3 * (j // ncols) + r, j % ncols].set_visible(False)
    fig.suptitle("headplod tracker on imperfect rigs (refined online): dotted line = settle time, "
                 "dashed = bump", fontsize=10)
    save_figure(fig, path, dpi=100, rect=(0, 0, 1, 0.985))
