"""``headplod bench clutter``: per-frame time by stage against the number of blobs in the image.

The synthetic ``clutter`` sequence (the built-in head motion, ``synthetic.clutter``: the markers and
``N - 5`` shiny things as 3D points both cameras see) is rendered for each N of :data:`BLOBS` and
tracked twice, with OpenCV single-threaded as ``bench track`` does:

- **track**: as the tracker runs (acquire, then re-measure the markers where they were);
- **acquire**: acquiring every frame (``TrackerConfig(track=False)``), the identification's worst case.

Per frame it keeps the stage times of ``TrackResult.timings_s`` (``detect``, ``identify``, ``pose``,
``covariance``, ``refine_rig``; ``mean_pose`` and ``total`` run from the frame's start, so they hold the
stages before them; a stage that did not run counts 0 s), the blobs detected per image and the labelled
hypotheses the identification scored (``TrackResult.hypotheses``; 0 while tracking), and reports per N
and run the median, 99th percentile and slowest frame of each stage in ms and as ratios to the run's
threshold pass (:func:`~headplod.bench.baseline.threshold_baseline_s`, the median over every frame of the
whole benchmark), the hypotheses (median, max), the frames with a pose and the wrong poses against the
truth (:mod:`headplod.tracking.evaluate`).
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from .. import io
from ..capture.synthetic import ensure_dataset
from ..live.loop import result_record
from ..progress import Progress, note
from ..tracking import evaluate
from ..tracking.tracker import Tracker, TrackerConfig
from .baseline import threshold_baseline_s
from .outputs import pyplot, save_figure, write_json

__all__ = ["BLOBS", "STAGES", "RUNS", "run_clutter_bench", "summarize_frames", "parse_blobs"]

#: Blobs per image swept (the five markers included: 5 is the markers alone).
BLOBS = (5, 10, 20, 30, 45, 60)
#: Frames per N in a full and a ``--quick`` run.
FRAMES_FULL, FRAMES_QUICK = 20, 2
#: Stages reported, in ``TrackResult.timings_s``'s names.
STAGES = ("detect", "identify", "pose", "mean_pose", "covariance", "refine_rig", "total")
#: The runs: name -> the tracker's settings.
RUNS = {"track": TrackerConfig(), "acquire": TrackerConfig(track=False)}
#: The stages drawn on the chart (the others are in the JSON and on the page).
CHART_STAGES = ("detect", "identify", "pose", "covariance", "total")


def parse_blobs(text: str) -> tuple:
    """``--blobs`` ("5,20,60") as a tuple of ints ≥ 5; ValueError with what is wrong."""
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise ValueError(f"--blobs: comma-separated whole numbers, got {text!r}") from None
    if not values or min(values) < 5:
        raise ValueError(f"--blobs: each at least 5 (the five markers), got {text!r}")
    return values


def _track_run(frames, dataset: io.Dataset, config: TrackerConfig) -> list:
    """Track preloaded frames; per frame (record, stage seconds, blobs per image, hypotheses, baseline s,
    mode)."""
    tracker = Tracker(dataset.rig, dataset.markers, config)
    out = []
    for frame in frames:
        result = tracker.process(frame.left, frame.right, frame.t, frame.t_right)
        base = threshold_baseline_s(frame.left, frame.right)
        blobs = [len(b) for b in result.blobs if b is not None]
        out.append((result_record(frame, result, extras=False), dict(result.timings_s), blobs,
                    int(result.hypotheses), base, result.mode))
    return out


def summarize_frames(rows: list, truth: dict | None, baseline_s: float) -> dict:
    """One run at one N: stage times (ms and × ``baseline_s``: p50, p99, max), blobs, hypotheses, accuracy.

    ``rows``: :func:`_track_run`'s per-frame tuples; ``truth``: the dataset's (frame -> pose).
    """
    records = [r[0] for r in rows]
    summary = evaluate.summarize(records, truth)
    stages = {}
    for stage in STAGES:
        s = np.array([r[1].get(stage, 0.0) for r in rows], float)
        stages[stage] = {"p50_ms": float(np.median(s)) * 1e3, "p99_ms": float(np.percentile(s, 99)) * 1e3,
                         "max_ms": float(s.max()) * 1e3, "p50_x": float(np.median(s)) / baseline_s,
                         "p99_x": float(np.percentile(s, 99)) / baseline_s, "max_x": float(s.max()) / baseline_s}
    blobs = [b for r in rows for b in r[2]]
    hyps = np.array([r[3] for r in rows], float)
    return {"frames": len(rows), "frames_with_pose": summary["ok"],
            "wrong_poses": summary.get("wrong_identifications"),
            "v_err_deg_median": summary.get("v_err_deg_median"),
            "blobs_median": float(np.median(blobs)) if blobs else None, "blobs_max": int(max(blobs)) if blobs else None,
            "hypotheses_median": float(np.median(hyps)), "hypotheses_max": int(hyps.max()),
            "acquire_frames": sum(1 for r in rows if r[5] == "acquire"),
            "stages": stages}


def run_clutter_bench(json_path=None, chart_path=None, quick: bool = False, blobs=None) -> int:
    """Render and track the sweep, print the table, write the JSON and the chart; the exit status."""
    cv2.setNumThreads(1)
    blobs = tuple(blobs) if blobs else BLOBS
    n_frames = FRAMES_QUICK if quick else FRAMES_FULL
    raw = {}
    bar = Progress(len(blobs) * len(RUNS), "bench clutter")
    for n in blobs:
        folder = ensure_dataset("clutter", frames=n_frames, blobs=int(n))
        dataset = io.Dataset(folder)
        frames = list(dataset)
        for run, config in RUNS.items():
            raw[(run, n)] = (_track_run(frames, dataset, config), dataset.truth)
            bar.step(f"{n} blobs, {run}")
    baseline_s = float(np.median([r[4] for rows, _ in raw.values() for r in rows]))
    runs = {run: {str(n): summarize_frames(*raw[(run, n)], baseline_s) for n in blobs} for run in RUNS}
    report = {"quick": bool(quick), "blobs": list(blobs), "frames_per_n": n_frames,
              "threshold_pass_ms": baseline_s * 1e3, "runs": runs,
              "machine": {"cpus": os.cpu_count(), "load_1_5_15": list(os.getloadavg())}}
    print(_text(report))
    if json_path:
        write_json(json_path, report)
        note(f"results: {json_path}")
    if chart_path:
        chart(report, chart_path)
        note(f"chart: {chart_path}")
    return 0


def _text(report: dict) -> str:
    """The report as a fixed-width table, a row per run and blob count."""
    head = ["run", "blobs", "pose", "wrong", "hyp med", "hyp max", "identify p50/max ms", "total p50/p99/max ms",
            "total max x"]
    rows = []
    for run, by_n in report["runs"].items():
        for n, s in by_n.items():
            ident, total = s["stages"]["identify"], s["stages"]["total"]
            rows.append([run, n, f"{s['frames_with_pose']}/{s['frames']}", str(s["wrong_poses"] or 0),
                         f"{s['hypotheses_median']:.0f}", str(s["hypotheses_max"]),
                         f"{ident['p50_ms']:.2f}/{ident['max_ms']:.2f}",
                         f"{total['p50_ms']:.2f}/{total['p99_ms']:.2f}/{total['max_ms']:.2f}", f"{total['max_x']:.0f}"])
    widths = [max(len(c) for c in column) for column in zip(head, *rows)]
    load = ", ".join(f"{v:.2f}" for v in report["machine"]["load_1_5_15"])
    return "\n".join([f"threshold pass {report['threshold_pass_ms']:.3f} ms; {report['frames_per_n']} frames per N; "
                      f"load {load}"]
                     + ["  ".join(c.rjust(w) if i else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths)))
                        for r in [head] + rows])


def chart(report: dict, path) -> None:
    """Per-frame time (p50 solid, p99 dashed) by stage against blobs per image, one panel per run, and the
    hypotheses scored against blobs (median solid, max dashed); written to ``path`` (PNG)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(report["runs"]) + 1, figsize=(5.2 * (len(report["runs"]) + 1), 4.6))
    colors = dict(zip(CHART_STAGES, plt.cm.tab10(np.arange(len(CHART_STAGES)))))
    base_ms = report["threshold_pass_ms"]
    for ax, (run, by_n) in zip(axes, report["runs"].items()):
        ns = [int(n) for n in by_n]
        for stage in CHART_STAGES:
            # a stage that ran in no frame (0 ms) leaves a gap, not a point on the floor of the log scale
            p50 = [by_n[str(n)]["stages"][stage]["p50_ms"] or np.nan for n in ns]
            p99 = [by_n[str(n)]["stages"][stage]["p99_ms"] or np.nan for n in ns]
            ax.plot(ns, p50, "o-", color=colors[stage], label=f"{stage} p50")
            ax.plot(ns, p99, "--", color=colors[stage], alpha=0.7, label=f"{stage} p99")
        ax.set_yscale("log")
        ax.set_xlabel("blobs per image (5 = the markers alone)")
        ax.set_ylabel("time per frame (ms)")
        ax.set_title(f"{run}: " + ("acquire, then track" if run == "track" else "acquiring every frame"))
        ax.grid(True, which="both", alpha=0.3)
        right = ax.secondary_yaxis("right", functions=(lambda ms: ms / base_ms, lambda x: x * base_ms))
        right.set_ylabel("× one threshold pass")
    axes[0].legend(fontsize=7, ncol=2, loc="lower right")
    ax = axes[-1]
    for run, style in zip(report["runs"], ("tab:blue", "tab:red")):
        by_n = report["runs"][run]
        ns = [int(n) for n in by_n]
        ax.plot(ns, [by_n[str(n)]["hypotheses_median"] for n in ns], "o-", color=style, label=f"{run} median")
        ax.plot(ns, [by_n[str(n)]["hypotheses_max"] for n in ns], "--", color=style, label=f"{run} max")
    ax.set_yscale("symlog", linthresh=1.0)      # 0 (a tracked frame scores none) stays on the chart
    ax.set_xlabel("blobs per image")
    ax.set_ylabel("labelled hypotheses scored per frame")
    ax.set_title("identification's cost, counted")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle("headplod tracker under clutter (synthetic 'clutter' sequence, 640x480)" +
                 (" — quick run" if report.get("quick") else ""))
    save_figure(fig, path, dpi=110)

