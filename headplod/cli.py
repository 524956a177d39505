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
    track.add_argument("--refine-rig", choices=("on", "off"), default="on",
                       help="refine the rig online from the tracked glasses (right camera's turn and shift, "
                            "baseline scale, right focal length, exposure offset); rig.yaml is never "
                            "overwritten (default on)")
    track.add_argument("--save-rig", metavar="FILE",
                       help="at the end of the run, write the refined rig to FILE (a new rig.yaml; not the "
                            "rig.yaml being read, nor inside the dataset or --record folder). Nothing is "
                            "written, and the exit status is 1, when no frame was tracked")
    live = track.add_argument_group("live cameras, recording and outputs")
    live.add_argument("--camera", nargs="+", metavar="DEV",
                      help="track live: LEFT RIGHT (/dev/videoN or N) or 'auto' (the cameras named in --calib, "
                           "found by USB identity; see 'headplod cameras')")
    live.add_argument("--calib", help="rig.yaml of the cameras (required with --camera)")
    live.add_argument("--markers", help="markers.yaml (default: the dataset's, else the default model)")
    live.add_argument("--screen", help="screen.yaml, for the POI in the records (default: the dataset's)")
    live.add_argument("--fps", type=float, default=60.0, help="camera frame rate to request (default 60)")
    live.add_argument("--fourcc", help="camera pixel format to request: GREY, YUYV or MJPG (default: the camera's)")
    live.add_argument("--exposure", type=float, help="manual exposure (V4L2 units; auto exposure is then off)")
    live.add_argument("--gain", type=float, help="camera gain (V4L2 units)")
    live.add_argument("--record", metavar="DIR", help="write the frames as a dataset folder while tracking")
    live.add_argument("--udp", metavar="HOST[:PORT]",
                      help="send each pose to opentrack's UDP input (six float64: x, y, z cm, yaw, pitch, "
                           "roll deg; default port 4242)")
    live.add_argument("--filter", nargs="?", const="1.0,0.02", metavar="MIN_CUTOFF,BETA",
                      help="One Euro filter on the recorded/sent poses (default off; 1.0 Hz, 0.02 when given "
                           "without values)")
    live.add_argument("--status", action="store_true",
                      help="a status line (rate, latency, skew, drops); on by default with --camera")
    live.add_argument("--frames", type=int, help="stop after N frames")

    cameras = sub.add_parser("cameras", help="list the video devices with their USB identity")
    cameras.add_argument("--all-nodes", action="store_true", help="also the metadata nodes of UVC cameras")
    cameras.add_argument("--store", nargs=2, metavar=("LEFT", "RIGHT"),
                         help="record these devices' USB identities in --rig as its left and right cameras, "
                              "so 'headplod track --camera auto' finds them whatever /dev/videoN they get")
    cameras.add_argument("--rig", help="rig.yaml to update with --store")

    calibrate = sub.add_parser("calibrate", help="stereo calibration from chessboard/ChArUco pairs -> rig.yaml")
    calibrate.add_argument("folder", nargs="?", help="image pairs: left/ and right/ with matching names, or "
                                                     "leftNN.* and rightNN.* side by side")
    calibrate.add_argument("--camera", nargs="+", metavar="DEV",
                           help="capture the pairs live from LEFT RIGHT (or 'auto' with --identify-from "
                                "rig.yaml), with a guide to the poses still missing; they are kept in --save")
    calibrate.add_argument("--board", choices=("chessboard", "charuco"), default="chessboard")
    calibrate.add_argument("--cols", type=int, required=True, help="inner corners per row")
    calibrate.add_argument("--rows", type=int, required=True, help="inner corners per column")
    calibrate.add_argument("--square-mm", type=float, required=True, help="side of a square, mm")
    calibrate.add_argument("--marker-mm", type=float, help="ChArUco: side of a marker, mm (default 0.7 square)")
    calibrate.add_argument("--dictionary", default="DICT_5X5_100", help="ChArUco dictionary (default DICT_5X5_100)")
    calibrate.add_argument("--out", required=True, help="rig.yaml to write")
    calibrate.add_argument("--save", help="live: folder for the captured pairs (default: beside --out)")
    calibrate.add_argument("--pairs", type=int, default=20, help="live: pairs to capture (default 20)")
    calibrate.add_argument("--size", type=_floats(2), help="live: camera image size W,H (default 640,480)")

    bench = sub.add_parser("bench", help="benchmarks: accuracy against speed")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bt = bench_sub.add_parser("track", help="tracker accuracy and per-stage time on synthetic sets")
    bt.add_argument("--json", help="write the results as JSON")
    bt.add_argument("--chart", help="write the accuracy-against-time chart (PNG); the imperfect-rig sets' "
                                    "chart goes beside it as FILE_rig.png (in its place when only they run)")
    bt.add_argument("--quick", action="store_true", help="fewer frames (a smoke run)")
    bt.add_argument("--sets", help="comma-separated names of the sets to run (default: all); "
                                   "see headplod.bench.track.TRACK_SETS and headplod.bench.track.rig.RIG_SETS")

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
    render.add_argument("--contrast", choices=("shading", "readback"), default="shading",
                        help="triangle contrast: from the shading, no read-back (default), or the paper's "
                             "10x10 window read back from a first frame")
    render.add_argument("--out", required=True, help="output image (PNG)")
    render.add_argument("--stats", help="write triangles, select/build/render ms and per-level counts (JSON)")
    render.add_argument("--export", metavar="MESH", help="also write the frame's PLOD mesh (.glb, .ply, .obj or .stl; "
                                                         "scene metres, faces coloured by level)")

    bl = bench_sub.add_parser("live", help="rate, latency and capture-layer cost of tracking a replayed recording")
    bl.add_argument("dataset", nargs="?", help="a recording (dataset folder); default: the built-in sequence")
    bl.add_argument("--json", help="write the results as JSON")
    bl.add_argument("--repeats", type=int, default=3, help="passes over the recording (default 3)")

    bp = bench_sub.add_parser("plod", help="speed and image quality of the LOD modes against full (1280x720)")
    bp.add_argument("--json", help="write the results as JSON")
    bp.add_argument("--chart", help="write the chart (PNG); the level-colour pictures go beside it")
    bp.add_argument("--quick", action="store_true", help="fewer points on the curves and sweeps (a smoke run)")

    from .demo.cli import add_demo_arguments
    add_demo_arguments(sub.add_parser("demo", help="head-coupled PLOD terrain viewer (a window, or --headless)"))

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
            from .bench import plod as bench_plod
            return bench_plod.run_plod_bench(json_path=args.json, chart_path=args.chart, quick=args.quick)
        if args.command == "bench" and args.bench == "live":
            from .bench import live as bench_live
            return bench_live.run_live_bench(args.dataset, json_path=args.json, repeats=args.repeats)
        if args.command == "demo":
            from .demo.cli import run_demo
            return run_demo(args)
        if args.command == "cameras":
            return _cmd_cameras(args)
        if args.command == "calibrate":
            return _cmd_calibrate(args)
        if args.command == "bench" and args.bench == "uncertainty":
            from .bench import uncertainty as bench_uncertainty
            return bench_uncertainty.run_uncertainty_bench(json_path=args.json, chart_path=args.chart,
                                                           quick=args.quick)
        if args.command == "bench":
            from .bench import track as bench
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


def _open_track_source(args):
    """The frame source of ``headplod track``, the rig and whether it is live."""
    from . import io
    from .capture import open_source
    from .capture.synthetic import DEFAULT_SEQUENCE, ensure_dataset

    rig = io.read_rig(args.calib) if args.calib else None
    if args.camera:
        if rig is None:
            raise _Usage("--camera needs --calib rig.yaml (the calibration of these cameras; "
                         "'headplod calibrate' makes one)")
        if args.camera == ["auto"]:
            from .capture.usb import list_cameras, resolve_rig_cameras
            left, right = resolve_rig_cameras(rig, list_cameras())
            print(f"cameras from {args.calib}: left {left}, right {right}", file=sys.stderr)
        elif len(args.camera) == 2:
            left, right = args.camera
        else:
            raise _Usage("--camera takes LEFT RIGHT (two devices) or 'auto'")
        from .capture import V4L2StereoSource
        width, height = rig.image_size
        source = V4L2StereoSource(_device(left), _device(right), width=width, height=height, fps=args.fps,
                                  fourcc=args.fourcc, exposure=args.exposure, gain=args.gain, rig=rig)
        print(source.settings_report(text=True), file=sys.stderr)
        return source, rig, True
    spec = args.dataset
    if spec is None:
        spec = str(ensure_dataset(DEFAULT_SEQUENCE))
        print(f"tracking the built-in synthetic sequence: {spec}", file=sys.stderr)
    source = open_source(spec)
    return source, rig or source.rig, False


class _Usage(Exception):
    """A command-line mistake: the message says what to do; exit status 2."""


def _device(text: str):
    return int(text) if text.isdigit() else text


def _cmd_track(args) -> int:
    from .bench import evaluate
    from . import io
    from .tracking.detect import DetectionParams
    from .live.loop import make_tracker, run_source
    from .live.pipeline import Progress
    from .tracking.tracker import TrackerConfig

    detection = DetectionParams.paper() if args.paper_detection else DetectionParams(threshold_dn=args.threshold)
    if args.paper_detection and args.threshold is not None:
        detection = DetectionParams(threshold_dn=args.threshold, smooth_px=9, subtract_background=False)
    from .tracking.uncertainty import COVARIANCE_ESTIMATORS, DEFAULT_COVARIANCE
    if args.uncertainty is not None and args.uncertainty not in COVARIANCE_ESTIMATORS:
        print(f"headplod: --uncertainty must be one of {', '.join(COVARIANCE_ESTIMATORS)}, got {args.uncertainty!r}",
              file=sys.stderr)
        return 2
    from .tracking.rig_refine import RigRefineConfig
    config = TrackerConfig(estimator=args.estimator, detection=detection, track=not args.no_tracking,
                           uncertainty=args.uncertainty or DEFAULT_COVARIANCE,
                           rig_refine=RigRefineConfig(enabled=args.refine_rig == "on"))
    pose_filter = None
    if args.filter:
        from .tracking.filters import PoseFilter
        try:
            min_cutoff, beta = (float(v) for v in args.filter.split(","))
            pose_filter = PoseFilter(min_cutoff_hz=min_cutoff, beta=beta)
        except ValueError as exc:
            print(f"headplod: --filter expects MIN_CUTOFF_HZ,BETA such as 1.0,0.02 ({exc})", file=sys.stderr)
            return 2
    try:
        _check_save_rig(args)                           # what can be checked before opening the source
        source, rig, live = _open_track_source(args)
    except _Usage as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError, LookupError) as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    try:
        _check_save_rig(args, source, rig)              # the rig.yaml and dataset folder the source read
    except _Usage as exc:
        source.close()
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    for warning in source.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    markers = io.read_markers(args.markers) if args.markers else None
    screen = io.read_screen(args.screen) if args.screen else None
    truth = getattr(getattr(source, "dataset", None), "truth", None) or {}
    to_stdout = args.out == "-"
    log = sys.stderr
    writer = sender = recorder = status = tracker = None
    total = len(source.dataset) if hasattr(source, "dataset") else None
    progress = Progress(total, "track") if args.quiet and not to_stdout and total and not live else None
    records = []

    def on_record(record, result):
        records.append(record)
        if writer is not None:
            writer.write(record)
        if progress is not None:
            progress.step()
        if args.quiet or status is not None:
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
        if record.get("flags"):
            line += "  [" + "; ".join(record["flags"]) + "]"
        print(line, file=log)

    try:
        writer = io.PoseWriter(args.out) if args.out else None
        if args.udp:
            from .live.output import OpentrackSender, parse_host_port
            sender = OpentrackSender(*parse_host_port(args.udp))
        if args.record:
            from .capture import DatasetRecorder
            recorder = DatasetRecorder(args.record, rig, markers=markers or source.markers,
                                       screen=screen or source.screen)
        if args.status or (live and not args.quiet):
            from .live.output import StatusLine
            status = StatusLine(stream=log)
        tracker = make_tracker(source, config, rig=rig, markers=markers)
        stats = run_source(source, screen=screen, on_record=on_record, recorder=recorder, sender=sender,
                           pose_filter=pose_filter, status=status, max_frames=args.frames, tracker=tracker)
    except (ValueError, OSError) as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("headplod: stopped (Ctrl-C); everything up to here is kept", file=sys.stderr)
        stats = None
    finally:
        for thing in (status, recorder, sender, writer, source):
            if thing is not None:
                thing.close()
    summary = evaluate.summarize(records, truth or None)
    name = source.name if live else Path(str(source.name)).name
    print(evaluate.format_summary(name, summary), file=log)
    if stats is not None and (live or args.status):
        s = stats.summary()
        print(f"rate {s['rate_hz'] or 0:.1f} Hz, latency p50 {s['latency_ms_p50'] or 0:.1f} ms, "
              f"p95 {s['latency_ms_p95'] or 0:.1f} ms", file=log)
    code = _report_rig(args, tracker, tracked=sum(bool(r["ok"]) for r in records), log=log)
    if args.record:
        print(f"recording: {args.record} (replay: headplod track {args.record})", file=log)
    if args.out and args.out != "-":
        print(f"pose records: {args.out}", file=log)
    return code


def _check_save_rig(args, source=None, rig=None) -> None:
    """Refuse a ``--save-rig FILE`` that would overwrite what is read (raises _Usage); nothing is written.

    Without ``source``: what the command line alone tells (the folder of FILE
    exists; FILE is not --calib, --out, a dataset folder given as SOURCE or
    --record's folder, nor inside them). With it: not the rig.yaml the source
    read, nor inside its dataset folder.
    """
    if not args.save_rig:
        return
    target = Path(args.save_rig).expanduser()
    resolved = target.resolve()
    if source is None:
        if args.refine_rig == "off":
            raise _Usage("--save-rig needs the rig refinement (--refine-rig on): there is nothing to save")
        if target.is_dir():
            raise _Usage(f"--save-rig {args.save_rig}: is a folder; give the file to write, e.g. "
                         f"{target / 'rig_refined.yaml'}")
        if not resolved.parent.is_dir():
            raise _Usage(f"--save-rig {args.save_rig}: the folder {target.parent} does not exist")
    files, folders = [], []
    if source is None:
        if args.calib:
            files.append(("the rig being read (--calib)", args.calib))
        if args.out and args.out != "-":
            files.append(("the pose records (--out)", args.out))
        if args.dataset and Path(args.dataset).is_dir():
            files.append(("the rig being read (the dataset's)", Path(args.dataset) / "rig.yaml"))
            folders.append(("the dataset folder being read", args.dataset))
        if args.record:
            folders.append(("the --record folder (a recording keeps the rig it was tracked with)", args.record))
    else:
        for r in (rig, getattr(source, "rig", None)):
            if r is not None and getattr(r, "path", None):
                files.append(("the rig being read", r.path))
        dataset = getattr(source, "dataset", None)
        if dataset is not None:
            folders.append(("the dataset folder being read", dataset.folder))
    for what, path in files:
        if _same_file(resolved, Path(path)):
            raise _Usage(f"--save-rig {args.save_rig}: is {what}, which is never overwritten; "
                         "give another file name")
    for what, folder in folders:
        folder = Path(folder).expanduser().resolve()
        if resolved == folder or folder in resolved.parents:
            raise _Usage(f"--save-rig {args.save_rig}: lies inside {what} ({folder}); "
                         "write the refined rig elsewhere")


def _same_file(a: Path, b: Path) -> bool:
    b = Path(b).expanduser()
    if a == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False


def _report_rig(args, tracker, tracked: int, log) -> int:
    """After ``track``: how the refined rig differs from rig.yaml, advice, and ``--save-rig``. The exit status.

    ``--save-rig`` with no tracked frame writes nothing and gives exit status
    1 (the records and the rest of the run are kept): a script that expects
    the file learns that it is not there.
    """
    refiner = getattr(tracker, "refiner", None)
    if refiner is not None and args.refine_rig == "on":
        refiner.flush()                                 # the frames short of a full chunk at the end
        line = ""
        if refiner.updates or refiner.bumps:
            line = refiner.describe()
            print(line, file=log)
        else:
            print("rig.yaml: not refined (too few tracked frames); used as it is", file=log)
        advice = refiner.advice()
        if advice and advice not in line:
            print(advice, file=log)
    if not args.save_rig:
        return 0
    if refiner is None or tracked == 0:
        print(f"headplod: --save-rig: no frame was tracked, so nothing was refined; {args.save_rig} not written",
              file=sys.stderr)
        return 1
    try:
        _write_rig_atomically(args.save_rig, refiner.estimate.rig())   # the best estimate, not only what was in use
    except (OSError, ValueError) as exc:
        print(f"headplod: --save-rig {args.save_rig}: {exc}", file=sys.stderr)
        return 1
    note = "" if refiner.updates else " (no update from the tracked frames: rig.yaml's values)"
    print(f"refined rig: {args.save_rig}{note}", file=log)
    return 0


def _write_rig_atomically(path, rig) -> None:
    """io.write_rig to a temporary name in the same folder, then os.replace: FILE is whole or untouched."""
    import os
    import tempfile

    from . import io

    target = Path(path).expanduser()
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp.yaml", dir=target.resolve().parent)
    os.close(fd)
    try:
        io.write_rig(tmp, rig)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)                   # mkstemp's 0600 -> what a plain write would give
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _cmd_cameras(args) -> int:
    from .capture.usb import LibusbMissingError, format_cameras, list_cameras, store_rig_cameras

    if bool(args.store) != bool(args.rig):
        print("headplod: --store LEFT RIGHT and --rig rig.yaml go together", file=sys.stderr)
        return 2
    try:
        cams = list_cameras(all_nodes=args.all_nodes)
        if args.store:
            rig = store_rig_cameras(args.rig, *args.store, cams)
            print(f"{args.rig}: left camera {rig.extra['left_camera']}, right camera {rig.extra['right_camera']}",
                  file=sys.stderr)
            return 0
    except LibusbMissingError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    except (LookupError, ValueError) as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    print(format_cameras(cams))
    return 0


def _cmd_calibrate(args) -> int:
    from .calibration.calibrate import BoardSpec, CalibrationError, calibrate_folder, format_report

    try:
        spec = BoardSpec(kind=args.board, cols=args.cols, rows=args.rows, square_mm=args.square_mm,
                         marker_mm=args.marker_mm, dictionary=args.dictionary)
    except ValueError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    folder = args.folder
    if args.camera:
        if folder:
            print("headplod: give either FOLDER or --camera, not both", file=sys.stderr)
            return 2
        folder = args.save or str(Path(args.out).with_suffix("")) + "_pairs"
        code = _capture_calibration_pairs(args, spec, Path(folder))
        if code:
            return code
    if not folder:
        print("headplod: calibrate needs FOLDER (image pairs) or --camera LEFT RIGHT", file=sys.stderr)
        return 2
    from .live.pipeline import Progress
    progress = Progress(0, "detect board")

    def step(done, total):
        progress.total = total
        progress.step()

    try:
        result = calibrate_folder(folder, spec, out=args.out, progress=step)
    except CalibrationError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    print(format_report(result))
    print(f"rig: {args.out}", file=sys.stderr)
    return 0


def _capture_calibration_pairs(args, spec, folder: Path) -> int:
    """Live: keep board pairs seen by both cameras, with a guide to the poses still missing."""
    import cv2

    from .calibration.calibrate import coverage_guide, detect_board
    from .capture import V4L2StereoSource

    if len(args.camera) != 2:
        print("headplod: calibrate --camera takes LEFT RIGHT", file=sys.stderr)
        return 2
    width, height = (int(v) for v in (args.size or (640, 480)))
    (folder / "left").mkdir(parents=True, exist_ok=True)
    (folder / "right").mkdir(parents=True, exist_ok=True)
    kept, last_kept = [], None
    with V4L2StereoSource(_device(args.camera[0]), _device(args.camera[1]), width=width, height=height,
                          fps=15, fourcc=args.fourcc if hasattr(args, "fourcc") else None) as source:
        print(source.settings_report(text=True), file=sys.stderr)
        print(f"show the board to both cameras; {args.pairs} pairs are kept, at least 1 s apart "
              "(Ctrl-C to stop early)", file=sys.stderr)
        try:
            while len(kept) < args.pairs:
                frame = source.read(timeout_s=2.0)
                if frame is None:
                    break
                if frame.error:
                    print(f"  {frame.error}", file=sys.stderr)
                    continue
                det_l, det_r = detect_board(frame.left, spec), detect_board(frame.right, spec)
                if not (det_l and det_r) or (last_kept is not None and frame.t - last_kept < 1.0):
                    continue
                name = f"{len(kept):02d}.png"
                cv2.imwrite(str(folder / "left" / name), frame.left)
                cv2.imwrite(str(folder / "right" / name), frame.right)
                kept.append(det_l)
                last_kept = frame.t
                missing = coverage_guide(kept, (width, height))
                print(f"  pair {len(kept)}/{args.pairs} kept" + (": still missing: " + "; ".join(missing)
                                                                  if missing else ": coverage is good"),
                      file=sys.stderr)
        except KeyboardInterrupt:
            print("  stopped; calibrating with the pairs kept", file=sys.stderr)
    print(f"pairs: {folder}", file=sys.stderr)
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
    if args.export is not None:
        from .plod.export import check_export_path
        try:
            check_export_path(args.export)
        except ValueError as exc:
            print(f"headplod: --export {exc}", file=sys.stderr)
            return 2
    _, stats = render_still(screen, mode=args.mode, uncertainty=args.uncertainty, head_mm=args.head,
                            poi_px=args.poi, cov_deg2=cov, size=size, view_mode=args.view, out=args.out,
                            stats_path=args.stats, contrast=args.contrast, export=args.export)
    print(f"{stats['triangles']} triangles; select {stats['select_ms']:.1f} ms, build {stats['build_ms']:.1f} ms, "
          f"render {stats['render_ms']:.1f} ms; image: {args.out}"
          + (f"; mesh: {args.export}" if args.export else ""), file=sys.stderr)
    return 0


def _cmd_synth(args) -> int:
    from .capture.synthetic import _progress
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
