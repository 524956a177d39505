"""The ``headplod`` command.

    headplod track [DATASET] [--out FILE|-] [--estimator reproj|rigid|paper] ...
    headplod bench track [--json FILE] [--chart FILE.png] [--quick]
    headplod synth PRESET OUT_DIR [--frames N] [--seed S]

Exit status: 0 on success, 1 when the run failed (bad files), 2 on bad usage.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def _threshold_arg(text: str):
    if text == "adaptive":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"threshold must be 'adaptive' or a number of DN, got {text!r}")
    if not 0 < value < 255:
        raise argparse.ArgumentTypeError(f"threshold must lie between 0 and 255 DN, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="headplod", description=__doc__.split("\n")[0] + " Stereo IR head tracking.")
    sub = parser.add_subparsers(dest="command", required=True)

    track = sub.add_parser("track", help="track a stereo dataset folder (or the built-in synthetic sequence)")
    track.add_argument("dataset", nargs="?", help="dataset folder (conventions.md); default: the built-in "
                                                  "synthetic sequence, rendered on first use")
    track.add_argument("--out", help="pose records, JSON Lines ('-' for standard output)")
    track.add_argument("--estimator", choices=("reproj", "rigid", "paper"), default="reproj",
                       help="pose estimator (default reproj, the most accurate in 'headplod bench track')")
    track.add_argument("--threshold", type=_threshold_arg, default=None, metavar="DN|adaptive",
                       help="blob threshold in DN (the paper: 100) or 'adaptive' (default)")
    track.add_argument("--paper-detection", action="store_true",
                       help="the paper's detection: threshold 100, 9x9 smoothing, raw intensity weights")
    track.add_argument("--uncertainty", default=None, metavar="NAME",
                       help="estimator of the covariance of V: first_order_smoothed (default), first_order, "
                            "first_order_fixed, paper, paper_deterministic, paper_smoothed, paper_fixed")
    track.add_argument("--no-tracking", action="store_true",
                       help="detect and identify from scratch in every frame")
    track.add_argument("--quiet", "-q", action="store_true", help="no per-frame lines")

    bench = sub.add_parser("bench", help="benchmarks: accuracy against speed")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bt = bench_sub.add_parser("track", help="tracker accuracy and per-stage time on synthetic sets")
    bt.add_argument("--json", help="write the results as JSON")
    bt.add_argument("--chart", help="write the accuracy-against-time chart (PNG)")
    bt.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")
    bt.add_argument("--sets", help="comma-separated names of the sets to run (default: all); "
                                   "see headplod.bench.TRACK_SETS")

    bu = bench_sub.add_parser("uncertainty", help="calibration (NEES), stability and cost of the covariance of V")
    bu.add_argument("--json", help="write the results as JSON")
    bu.add_argument("--chart", help="write the NEES/stability chart (PNG; a second chart *_paper.png "
                                    "reproduces the paper's Fig. 10 and 17)")
    bu.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")

    render = sub.add_parser("render", help="render one PLOD frame of the terrain to an image")
    render.add_argument("--mode", default="csf", choices=("csf", "gp", "acuity", "sse", "ipv", "dpv", "distance", "full"))
    render.add_argument("--uncertainty", default="adaptive", choices=("none", "fixed", "adaptive", "smoothed"))
    render.add_argument("--head", type=_floats(3), help="eye position X,Y,Z in the world frame, mm "
                                                          "(default: 600 mm in front of the screen centre)")
    render.add_argument("--poi", type=_floats(2), help="point of interest X,Y in screen pixels (default: centre)")
    render.add_argument("--cov", type=_floats(3), help="covariance of (φ, θ) as PP,PT,TT in deg²")
    render.add_argument("--size", type=_floats(2), default=(1280, 720), help="image size W,H (default 1280,720)")
    render.add_argument("--view", default="shaded", choices=("shaded", "wire", "levels"))
    render.add_argument("--screen", help="screen.yaml (default: the embedded 24-inch screen)")
    render.add_argument("--out", required=True, help="output image (PNG)")
    render.add_argument("--stats", help="write triangles, select/build/render ms and per-level counts (JSON)")

    bp = bench_sub.add_parser("plod", help="speed and image quality of the LOD modes against full (1280x720)")
    bp.add_argument("--json", help="write the results as JSON")
    bp.add_argument("--chart", help="write the triangles/frame time against PSNR chart (PNG)")

    synth = sub.add_parser("synth", help="render a synthetic dataset folder")
    synth.add_argument("preset")
    synth.add_argument("out")
    synth.add_argument("--frames", type=int)
    synth.add_argument("--seed", type=int, default=0)
    return parser


def _floats(n):
    def parse(text: str):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
        if len(values) != n or not all(np.isfinite(values)):
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated finite numbers, got {text!r}")
        return tuple(values)
    return parse


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from . import io

    try:
        if args.command == "track":
            return _cmd_track(args)
        if args.command == "bench" and args.bench == "plod":
            from . import bench_plod
            return bench_plod.run_plod_bench(json_path=args.json, chart_path=args.chart)
        if args.command == "bench" and args.bench == "uncertainty":
            from . import bench_uncertainty
            return bench_uncertainty.run_uncertainty_bench(json_path=args.json, chart_path=args.chart,
                                                           quick=args.quick)
        if args.command == "bench":
            from . import bench
            sets = [x.strip() for x in args.sets.split(",")] if args.sets else None
            return bench.run_track_bench(json_path=args.json, chart_path=args.chart, quick=args.quick, sets=sets)
        if args.command == "synth":
            return _cmd_synth(args)
        if args.command == "render":
            return _cmd_render(args)
    except io.ContractError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("headplod: interrupted", file=sys.stderr)
        return 130
    return 2


def _cmd_track(args) -> int:
    from . import evaluate, io
    from .detect import DetectionParams
    from .pipeline import Progress, track_dataset
    from .sequences import DEFAULT_SEQUENCE, ensure_dataset
    from .tracker import TrackerConfig

    folder = args.dataset
    if folder is None:
        folder = ensure_dataset(DEFAULT_SEQUENCE)
        print(f"tracking the built-in synthetic sequence: {folder}", file=sys.stderr)
    dataset = io.Dataset(folder)
    for warning in dataset.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    detection = DetectionParams.paper() if args.paper_detection else DetectionParams(threshold_dn=args.threshold)
    if args.paper_detection and args.threshold is not None:
        detection = DetectionParams(threshold_dn=args.threshold, smooth_px=9, subtract_background=False)
    from .uncertainty import COVARIANCE_ESTIMATORS, DEFAULT_COVARIANCE
    if args.uncertainty is not None and args.uncertainty not in COVARIANCE_ESTIMATORS:
        print(f"headplod: --uncertainty must be one of {', '.join(COVARIANCE_ESTIMATORS)}, got {args.uncertainty!r}",
              file=sys.stderr)
        return 2
    config = TrackerConfig(estimator=args.estimator, detection=detection, track=not args.no_tracking,
                           uncertainty=args.uncertainty or DEFAULT_COVARIANCE)
    writer = io.PoseWriter(args.out) if args.out else None
    to_stdout = args.out == "-"
    log = sys.stderr
    truth = dataset.truth or {}
    progress = Progress(len(dataset), "track") if args.quiet and not to_stdout else None

    def on_record(record, result):
        if writer is not None:
            writer.write(record)
        if progress is not None:
            progress.step()
        if args.quiet:
            return
        line = f"frame {record['frame']:6d} "
        if record["ok"]:
            p, v = record["position"], record["axes"][2]
            line += (f"ok   P1 ({p[0]:7.1f},{p[1]:7.1f},{p[2]:7.1f}) mm  "
                     f"V ({v[0]:+.3f},{v[1]:+.3f},{v[2]:+.3f})")
            if record["frame"] in truth:
                tp, ta = truth[record["frame"]]
                verr = float(evaluate.angle_deg(np.asarray(v), ta[2]))
                line += f"  err V {verr:6.3f}° P1 {np.linalg.norm(np.asarray(p) - tp):6.3f} mm"
            if result is not None:
                line += f"  {result.timings_s.get('total', 0) * 1e3:5.2f} ms [{result.mode}]"
        else:
            line += f"no pose: {record['reason']}"
        print(line, file=log)

    try:
        records = track_dataset(dataset, config, on_record=on_record)
    finally:
        if writer is not None:
            writer.close()
    summary = evaluate.summarize(records, dataset.truth)
    print(evaluate.format_summary(str(Path(folder).name), summary), file=log)
    if args.out and args.out != "-":
        print(f"pose records: {args.out}", file=log)
    return 0


def _cmd_render(args) -> int:
    from calib import DEFAULT_SCREEN
    from . import io
    from .plod.still import render_still

    screen = io.read_screen(args.screen or DEFAULT_SCREEN)
    cov = None
    if args.cov is not None:
        pp, pt, tt = args.cov
        cov = np.array([[pp, pt], [pt, tt]])
        if np.any(np.linalg.eigvalsh(cov) <= 0):
            print(f"headplod: --cov {args.cov} is not positive definite", file=sys.stderr)
            return 2
    size = tuple(int(v) for v in args.size)
    _, stats = render_still(screen, mode=args.mode, uncertainty=args.uncertainty, head_mm=args.head,
                            poi_px=args.poi, cov_deg2=cov, size=size, view_mode=args.view, out=args.out,
                            stats_path=args.stats)
    print(f"{stats['triangles']} triangles; select {stats['select_ms']:.1f} ms, build {stats['build_ms']:.1f} ms, "
          f"render {stats['render_ms']:.1f} ms; image: {args.out}", file=sys.stderr)
    return 0


def _cmd_synth(args) -> int:
    from .sequences import _progress
    from synthetic import dataset as synth_dataset
    from synthetic import scenes

    if args.preset not in scenes.PRESETS:
        print(f"headplod: unknown preset {args.preset!r}; choose one of {', '.join(sorted(scenes.PRESETS))}",
              file=sys.stderr)
        return 2
    scene = scenes.make_scene(args.preset, n_frames=args.frames, seed=args.seed)
    synth_dataset.write_dataset(args.out, scene, seed=args.seed, progress=_progress(len(scene.times), args.preset))
    print(f"wrote {len(scene.times)} stereo pairs to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
