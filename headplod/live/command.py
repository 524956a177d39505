"""``headplod track``: its arguments (:func:`add_track_arguments`) and its run (:func:`run_track`).

    headplod track [--source SPEC] [--out FILE|-] [--estimator reproj|rigid|paper] ...

The source is named as everywhere else (:func:`headplod.capture.open_source`):
a dataset folder, ``LEFT.avi,RIGHT.avi``, ``synthetic[:PRESET]`` (the
default: the built-in sequence, rendered on first use) or
``v4l2:/dev/video0,/dev/video2`` / ``v4l2:auto`` with ``--calib``. The old
spellings, a positional ``DATASET`` and ``--camera LEFT RIGHT|auto``, still
work for one release and print a note with the new one.

Exit status: 0 on success (a fault inside one frame is that frame's ``ok:
false``, ``internal error: TYPE: message``, and the run goes on); 1 when the
run failed before its first frame (nothing is written then) or ended early
(a full disk, a folder gone, a closed pipe, a bug: what was made is kept,
and one line says where); 2 on bad usage (nothing is written then); 3 when
the run tracked no frame at all (every frame failed, or there was none).

Nothing is lost, nothing is hidden (``docs/outputs.md``): every option is
checked, the source opened and the output folders found writable before
the first frame; ``--out`` and ``--record`` are then written under their
own names as the run goes (:mod:`headplod.io.progressive`), what they
replace is moved to a visible ``.previous`` name (deleted when the run ends
as it should, kept when it ends early), and the output of a killed run is
announced and kept by the next run that writes there. No output may lie
inside the dataset folder being read. Ctrl-C, SIGTERM and SIGHUP stop the
run cleanly between frames: the records and frames so far are kept, whole.

``--realtime`` paces a replay at its frame times (:class:`~headplod.capture.sources._Pacer`: no burst after
a late one) and reads it as live cameras are read, by a capture thread into a drop-oldest mailbox
(:mod:`headplod.capture.mailbox`: the tracker takes the newest frame, those it had no time for are dropped
and counted); it is refused with live cameras. Without it, a replay tracks every frame, in order.
``--realtime --loop`` replays a folder back and forth without end (:class:`~headplod.capture.sources.BackAndForth`:
no jump back to the first pose; times keep increasing, frames numbered on); Ctrl-C ends it as a live run ends. With ``--udp``, the key ``c`` and
SIGUSR1 recentre what is sent (:mod:`headplod.live.recentre`; the math in
:func:`~headplod.live.opentrack.opentrack_values`), from the next frame; the records are not recentred.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import traceback
from pathlib import Path

import numpy as np

from .. import io
from ..io.progressive import folder_unwritable
from ..argtypes import add_quiet_argument, frame_count, note_old_spelling, readout_ms, threshold_dn
from ..capture import DatasetRecorder, open_source, source_kind, synthetic_preset, v4l2_devices
from ..capture.signals import StopSignals
from ..capture.synthetic import ensure_dataset, rerender
from ..capture.command import add_camera_settings
from ..tracking import evaluate
from ..tracking.detect import DetectionParams
from ..tracking.filters import PoseFilter
from ..tracking.geometry import ESTIMATORS
from ..tracking.rig_refine import RigRefineConfig
from ..tracking.uncertainty import COVARIANCE_ESTIMATORS, DEFAULT_COVARIANCE
from .frame_notes import FrameNotes, warning_kind
from .opentrack import DEFAULT_PIVOT_MM, OPENTRACK_FRAMES, check_pivot_mm, parse_host_port
from .recentre import RecentreControls
from ..streams import dropping_stderr
from .status import StatusLine
from .track_checks import Usage as _Usage, check_outputs as _check_outputs, check_save_rig as _check_save_rig
from .udp import OpentrackSender

__all__ = ["add_track_arguments", "run_track", "track_source_spec", "note_old_spelling", "EXIT_NO_FRAME_TRACKED"]

#: Exit status of a run that tracked no frame at all.
EXIT_NO_FRAME_TRACKED = 3
#: Exit status of a run whose records went to standard output when the program reading them left (``track
#: --out - | head -1``): 128 + SIGPIPE, what a shell reports for a writer killed by SIGPIPE (``seq`` or ``yes``
#: into ``head``), so that a pipeline treats it as such a writer; the records it read are whole.
EXIT_READER_LEFT = 128 + signal.SIGPIPE

TRACK_EPILOG = ("exit status: 0 success (a fault in one frame is that frame's 'ok: false'); 1 the run failed "
                "before its first frame (nothing is written) or ended early (what was made is kept, and one line "
                "says where); 2 bad usage (nothing is written); 3 no frame was tracked (every frame failed, or "
                "there was none); 141 the program reading --out - left (a closed pipe, as a writer killed by "
                "SIGPIPE). Ctrl-C, SIGTERM or SIGHUP stops cleanly between frames: the records and frames "
                "so far are kept (and, when a replay had not reached its end, the outputs they replaced). With "
                "--udp, the key c (standard input a terminal) or SIGUSR1 (kill -USR1 PID) "
                "recentres what is sent to opentrack, from the next frame: the current pose becomes its zero.")


def add_track_arguments(track: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``track``'s options to a (sub)parser; returns it."""
    track.add_argument("--source", metavar="SPEC",
                       help="what to track: a dataset folder (docs/contract.md), LEFT.avi,RIGHT.avi, "
                            "'synthetic[:PRESET]' (default: the built-in synthetic sequence, rendered on first "
                            "use), or live cameras 'v4l2:/dev/video0,/dev/video2' or 'v4l2:auto' (the cameras "
                            "named in --calib, found by USB identity; see 'headplod cameras') with --calib")
    track.add_argument("dataset", nargs="?", metavar="DATASET",
                       help="old spelling of --source DATASET (goes in the next release)")
    track.add_argument("--out", help="pose records, JSON Lines ('-' for standard output), written under this "
                                     "name as the run goes, one whole record per frame; an existing file is "
                                     "moved to NAME.previous.jsonl first, deleted when the run ends as it should "
                                     "and kept when it ends early; not inside the dataset folder being read")
    track.add_argument("--estimator", choices=ESTIMATORS, default="reproj",
                       help="pose estimator (default reproj, the most accurate in 'headplod bench track')")
    track.add_argument("--threshold", type=threshold_dn, default=None, metavar="DN|adaptive",
                       help="blob threshold in DN (the paper: 100) or 'adaptive' (default)")
    track.add_argument("--paper-detection", action="store_true",
                       help="the paper's detection: threshold 100, 9x9 smoothing, raw intensity weights")
    track.add_argument("--uncertainty", choices=COVARIANCE_ESTIMATORS, default=DEFAULT_COVARIANCE, metavar="NAME",
                       help=f"estimator of the covariance of V: {DEFAULT_COVARIANCE} (default), "
                            + ", ".join(n for n in COVARIANCE_ESTIMATORS if n != DEFAULT_COVARIANCE))
    track.add_argument("--no-tracking", action="store_true",
                       help="detect and identify from scratch in every frame")
    add_quiet_argument(track, help="no per-frame lines and no progress (the summary at the end is still printed)")
    track.add_argument("--refine-rig", choices=("on", "off"), default="on",
                       help="refine the rig online from the tracked glasses (right camera's turn and shift, "
                            "baseline scale, right focal length, exposure offset); rig.yaml is never "
                            "overwritten (default on)")
    track.add_argument("--readout-ms", type=readout_ms, default=None, metavar="MS",
                       help="the cameras' rolling-shutter readout, ms: the time from an image's first row to its "
                            "last (0 for a global-shutter camera). Default: estimated online, starting from the "
                            "frame period (nearly every USB webcam exposes its rows one after another)")
    track.add_argument("--save-rig", metavar="FILE",
                       help="at the end of the run, write the refined rig to FILE (a new rig.yaml; not the "
                            "rig.yaml being read, nor inside the dataset or --record folder). Nothing is "
                            "written, and the exit status is 3, when no frame was tracked")
    live = track.add_argument_group("live cameras, recording and outputs")
    live.add_argument("--camera", nargs="+", metavar="DEV",
                      help="old spelling of --source v4l2:LEFT,RIGHT (or --source v4l2:auto for 'auto'); goes in "
                           "the next release")
    live.add_argument("--calib", help="rig.yaml of the cameras (required with --source v4l2:...)")
    live.add_argument("--markers", help="markers.yaml (default: the dataset's, else the default model)")
    live.add_argument("--screen", help="screen.yaml, for the POI in the records (default: the dataset's)")
    add_camera_settings(live)
    live.add_argument("--record", metavar="DIR",
                      help="write the frames as a dataset folder while tracking (not the dataset being read, "
                           "nor inside it); a folder that holds a recording is refused unless --overwrite")
    live.add_argument("--overwrite", action="store_true",
                      help="with --record: replace the recording already in DIR; the old one is moved to "
                           "DIR.previous first, deleted when the run ends as it should and kept when it ends "
                           "early")
    add_udp_arguments(live)
    live.add_argument("--filter", nargs="?", const="1.0,0.02", metavar="MIN_CUTOFF,BETA",
                      help="One Euro filter on the recorded/sent poses (default off; 1.0 Hz, 0.02 when given "
                           "without values)")
    live.add_argument("--status", action="store_true",
                      help="a status line (rate, latency, skew, drops); on by default with live cameras")
    live.add_argument("--frames", type=frame_count, metavar="N", help="stop after N frames (at least 1)")
    live.add_argument("--realtime", action="store_true",
                      help="replay a recording (dataset folder, video pair, synthetic) at the pace of its frame "
                           "times, as the cameras gave them (e.g. to try opentrack without cameras); as with "
                           "cameras, the tracker takes the newest frame and those it had no time for are dropped "
                           "and counted. Default off: every frame, in order, as fast as tracked. Not with live "
                           "cameras (they are real time already)")
    live.add_argument("--loop", action="store_true",
                      help="with --realtime: replay the recording (a dataset folder or synthetic) without end, "
                           "forward then backward then forward, so that opentrack sees continuous motion (no "
                           "jump back to the first pose) and frame times keep increasing; the records keep the "
                           "recording's frame numbers. Ctrl-C (or --frames N) ends it, as a live run ends")
    track.epilog = TRACK_EPILOG
    return track


def pivot_arg(text: str) -> np.ndarray:
    """``--pivot X,Y,Z`` (mm, head frame) as a checked (3,) array; argparse's type."""
    try:
        values = [float(v) for v in str(text).split(",")]
        return check_pivot_mm(values)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in mm such as 0,-80,-90 ({exc})") from None


def add_udp_arguments(group) -> None:
    """``--udp``, ``--pivot`` and ``--udp-axes`` (for ``track`` and any command that sends to opentrack)."""
    group.add_argument("--udp", metavar="HOST[:PORT]|PORT",
                       help="send each pose to opentrack's 'UDP over network' input (six float64: x, y, z cm, "
                            "yaw, pitch, roll deg; default port 4242; a port alone is on this machine, 4242 "
                            "meaning 127.0.0.1:4242; IPv6 as [::1]:4242), with the axes and signs of opentrack's "
                            "point tracker: nothing to invert in opentrack. A frame without a pose sends nothing "
                            "(opentrack holds the last pose it got); press c or send SIGUSR1 to recentre")
    group.add_argument("--pivot", type=pivot_arg, metavar="X,Y,Z",
                       help="with --udp: the point sent, the head's pivot (the neck), from the bridge of the "
                            "glasses in the head frame (x to the wearer's left, y up, z forward), mm. Default: "
                            "pivot.yaml next to rig.yaml ('headplod pivot' measures it), else "
                            + ",".join(f"{v:g}" for v in DEFAULT_PIVOT_MM) + " (a typical head); 0,0,0 sends "
                            "the bridge")
    group.add_argument("--udp-axes", choices=OPENTRACK_FRAMES, default="tracker-pt",
                       help="with --udp: the position's axes: tracker-pt (default: x right, y up, z away from "
                            "the camera, as opentrack's point tracker) or opencv (y down, as opentrack's ArUco "
                            "tracker, and headplod's earlier output)")
    group.add_argument("--recentre-at-start", action="store_true",
                       help="with --udp: the first tracked pose is opentrack's zero (default off: the pose as "
                            "tracked, zero facing the cameras). During the run, press c (when standard input is "
                            "this terminal) or send SIGUSR1 (kill -USR1 PID, the PID printed at the start) to make "
                            "the current pose the zero: later poses are sent relative to it, in opentrack's axes. "
                            "Only what is sent is recentred; --out keeps the camera frame")


def udp_pivot(args, rig=None, source=None) -> tuple[np.ndarray, str]:
    """The pivot ``--udp`` sends and where it comes from: ``--pivot``, a ``pivot.yaml`` next to the rig, else the
    default. Raises :class:`~headplod.io.ContractError` for a broken pivot.yaml."""
    from .pivot import find_pivot_file, read_pivot

    if args.pivot is not None:
        return np.asarray(args.pivot, float), "--pivot"
    folders = []
    for r in (rig, getattr(source, "rig", None)):
        if r is not None and getattr(r, "path", None):
            folders.append(Path(r.path).expanduser().parent)
    if getattr(args, "calib", None):
        folders.append(Path(args.calib).expanduser().parent)
    dataset = getattr(source, "dataset", None)
    if dataset is not None:
        folders.append(Path(dataset.folder))
    found = find_pivot_file(*folders)
    if found is not None:
        return read_pivot(found), str(found)
    return np.asarray(DEFAULT_PIVOT_MM, float), "the default for a typical head; 'headplod pivot' measures yours"


def track_source_spec(args) -> str:
    """The source ``track`` reads, as an :func:`~headplod.capture.open_source` SPEC.

    From ``--source``, or from an old spelling (a positional DATASET,
    ``--camera LEFT RIGHT``, ``--camera auto``), for which a one-line note on
    standard error gives the new spelling. Raises _Usage when the source is named
    twice or ``--camera`` has the wrong number of devices.
    """
    given = [name for name, value in (("--source", args.source), ("DATASET", args.dataset),
                                      ("--camera", args.camera)) if value]
    if len(given) > 1:
        raise _Usage(f"the source is named twice ({' and '.join(given)}); give it once, as --source SPEC")
    if args.camera:
        if args.camera == ["auto"]:
            spec = "v4l2:auto"
        elif len(args.camera) == 2:
            spec = "v4l2:{},{}".format(*args.camera)
        else:
            raise _Usage("--camera takes LEFT RIGHT (two devices) or 'auto'; it is now --source v4l2:LEFT,RIGHT "
                         "or --source v4l2:auto")
        note_old_spelling(f"--camera {' '.join(args.camera)}", f"--source {spec}")
        return spec
    if args.dataset:
        note_old_spelling(f"'headplod track {args.dataset}'", f"'headplod track --source {args.dataset}'")
        return args.dataset
    return args.source or "synthetic"


def open_source_or_report(args, spec: str, check=None):
    """:func:`_open_track_source` for a command: (source, rig, live), or the exit status with its one-line
    reason printed (2: usage, or a name OpenCV cannot open; 1: a file or device that cannot be used).
    ``check(spec)``, run before opening, may raise ``_Usage`` too."""
    try:
        if check is not None:
            check(spec)
        return _open_track_source(args, spec)
    except (_Usage, io.UnnamablePath) as exc:          # a path OpenCV cannot take: the name given is the fault
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError, LookupError) as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1


def _open_track_source(args, spec: str):
    """The frame source of ``headplod track``, the rig and whether it is live."""
    realtime = bool(getattr(args, "realtime", False))
    if realtime and source_kind(spec) == "v4l2":
        raise _Usage(f"--realtime paces a replay; --source {spec} is live cameras, real time already "
                     "(drop --realtime)")
    loop = bool(getattr(args, "loop", False))
    if loop and not realtime:
        raise _Usage("--loop goes with --realtime (a replay without end, at the pace of its frame times); "
                     "give both, or neither")
    if loop and source_kind(spec) == "video":
        raise _Usage(f"--loop plays a dataset folder or synthetic back and forth; --source {spec} is a video pair, "
                     "read forward only (make it a folder once: headplod track --source "
                     f"{spec} --record DIR; then --source DIR --realtime --loop)")
    rig = io.read_rig(args.calib) if args.calib else None
    if source_kind(spec) == "v4l2":
        if rig is None:
            raise _Usage(f"--source {spec} needs --calib rig.yaml (the calibration of these cameras; "
                         "'headplod calibrate' makes one)")
        width, height = rig.image_size
        source = open_source(spec, width=width, height=height, fps=args.fps, fourcc=args.fourcc,
                             exposure=args.exposure, gain=args.gain, rig=rig)
        if v4l2_devices(spec) == "auto":
            left, right = source.devices
            print(f"cameras from {args.calib}: left {left}, right {right}", file=sys.stderr)
        print(source.settings_report(text=True), file=sys.stderr)
        return source, rig, True
    preset = synthetic_preset(spec)
    if preset is not None:
        spec = str(ensure_dataset(preset, quiet=args.quiet))
        print(f"tracking the built-in synthetic sequence: {spec}", file=sys.stderr)
    source = open_source(spec, realtime=True, **({"loop": True} if loop else {})) if realtime else open_source(spec)
    if loop:
        print("replaying back and forth without end (--loop); Ctrl-C ends the run", file=sys.stderr)
    return source, rig or source.rig, False


def run_track(args) -> int:
    """Run ``headplod track`` from parsed arguments; the exit status.

    Standard error is wrapped so that a closed terminal (SIGHUP, then EIO
    on every write) silences the messages without ending the run (the
    command line's :func:`headplod.streams.dropping_stderr`, here too for a
    caller that is not the command line).
    """
    with dropping_stderr():
        return _run_track(args)


def _run_track(args) -> int:
    try:                                                # the options, then the source's name: exit 2 if wrong
        config = _tracker_config(args)
        pose_filter = _pose_filter(args)
        udp = _udp_address(args)
        spec = track_source_spec(args)
    except _Usage as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    opened = _open_checked_source(args, spec)
    if isinstance(opened, int):
        return opened
    source, rig, live = opened
    run = _TrackRun(args, source, live)
    stop = StopSignals()
    with stop:                                          # from here, Ctrl-C, SIGTERM and SIGHUP stop between frames
        code = run.start(config, rig, udp)
        if code is not None:
            return code
        with RecentreControls(run.sender) as recentre:  # SIGUSR1 and the key c recentre what is sent
            if run.sender is not None:
                print(recentre.note(), file=run.log)
                if getattr(args, "recentre_at_start", False):
                    run.sender.request_recentre("--recentre-at-start")
            failure, kept = run.run(stop, pose_filter)
    return run.finish(spec, stop, failure, kept)


def _tracker_config(args):
    """The tracker's configuration from ``track``'s options (a TrackerConfig)."""
    # Imported on use: the tracker pulls in scipy.stats, slow to import, and `headplod --help` imports this module.
    from ..tracking.tracker import TrackerConfig

    detection = DetectionParams.paper() if args.paper_detection else DetectionParams(threshold_dn=args.threshold)
    if args.paper_detection and args.threshold is not None:
        detection = DetectionParams(threshold_dn=args.threshold, smooth_px=9, subtract_background=False)
    return TrackerConfig(estimator=args.estimator, detection=detection, track=not args.no_tracking,
                         uncertainty=args.uncertainty,
                         readout_s=None if args.readout_ms is None else args.readout_ms * 1e-3,
                         rig_refine=RigRefineConfig(enabled=args.refine_rig == "on"))


def _pose_filter(args) -> PoseFilter | None:
    """``--filter MIN_CUTOFF_HZ,BETA`` as a One Euro filter, None without it; raises _Usage when it is wrong."""
    if not args.filter:
        return None
    try:
        min_cutoff, beta = (float(v) for v in args.filter.split(","))
        return PoseFilter(min_cutoff_hz=min_cutoff, beta=beta)
    except ValueError as exc:
        raise _Usage(f"--filter expects MIN_CUTOFF_HZ,BETA such as 1.0,0.02 ({exc})") from None


def _udp_address(args) -> tuple[str, int] | None:
    """``--udp HOST[:PORT]`` as ``(host, port)``, None without it; raises _Usage when it is wrong, or when
    ``--pivot``, ``--udp-axes`` or ``--recentre-at-start`` come without it."""
    if args.udp:
        try:
            return parse_host_port(args.udp)
        except ValueError as exc:
            raise _Usage(str(exc)) from None
    if args.pivot is not None or args.udp_axes != "tracker-pt" or getattr(args, "recentre_at_start", False):
        raise _Usage("--pivot, --udp-axes and --recentre-at-start go with --udp (they shape what is sent to "
                     "opentrack)")
    return None


def _open_checked_source(args, spec: str):
    """The source opened once the outputs are checked against it: (source, rig, live), or the exit status with
    its one-line reason printed (the source is closed then). The source's warnings are printed."""
    def check(spec):                                    # what can be checked before opening the source
        _check_save_rig(args, spec=spec)
        _check_outputs(args, spec=spec)

    opened = open_source_or_report(args, spec, check)
    if isinstance(opened, int):
        return opened
    source, rig, live = opened
    try:
        _check_save_rig(args, source=source, rig=rig)   # the rig.yaml and dataset folder the source read
        _check_outputs(args, source=source, rig=rig)
    except _Usage as exc:
        source.close()
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    for warning in source.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    return source, rig, live


class _TrackRun:
    """One ``headplod track`` run once its source is open: its outputs, its records, its steps.

    :meth:`start` opens the tracker and the outputs, :meth:`run` tracks the frames (:meth:`on_record` takes
    each record), :meth:`finish` reports and gives the exit status. The per-frame messages and the summary go
    to ``log`` (standard error).
    """

    def __init__(self, args, source, live: bool):
        from .loop import LiveStats

        self.args, self.source, self.live = args, source, live
        self.endless = live or bool(getattr(source, "loop", False))     # a signal is how its run ends
        self.truth = getattr(source, "truth", None) or {}       # by the source's frame numbers (a loop's too)
        self.log = sys.stderr
        self.writer = self.sender = self.recorder = self.status = self.tracker = self.screen = None
        self.records = []
        self.notes = FrameNotes(stream=self.log)        # per-frame warnings: the first of each kind, then a count
        self.stats = LiveStats()

    def on_record(self, record, result) -> None:
        """Keep one finished record: write it, say how sending goes, print its line."""
        self.records.append(record)
        if self.writer is not None:
            try:
                self.writer.write(record)
            except OSError as exc:
                raise OutputFailed(f"--out {self.args.out}", exc) from exc
        if self.sender is not None:
            news = self.sender.news()                   # sending failed, or works again: said as it happens
            if news:
                print(news, file=self.log)
        if self.args.quiet or self.status is not None:
            return
        print(_frame_line(record, result, self.truth, self.notes), file=self.log)

    def start(self, config, rig, udp) -> int | None:
        """Open the tracker and the outputs; None, or the exit status 1 when one fails (nothing written, the
        source closed)."""
        from .loop import make_tracker

        args, source, log = self.args, self.source, self.log
        # Everything that can fail comes before the first frame: the files read, the tracker, the UDP socket,
        # then the outputs (a refusal there puts back what was moved aside).
        try:
            markers = io.read_markers(args.markers) if args.markers else None
            self.screen = io.read_screen(args.screen) if args.screen else None
            self.tracker = make_tracker(source, config, rig=rig, markers=markers)
            if udp is not None:
                pivot_mm, pivot_from = udp_pivot(args, rig=rig, source=source)
                self.sender = OpentrackSender(*udp, pivot_mm=pivot_mm, frame=args.udp_axes)
                print(f"udp: to {self.sender.where}, the pivot ({', '.join(f'{v:.0f}' for v in pivot_mm)}) mm "
                      f"({pivot_from}), axes {args.udp_axes}", file=log)
            if args.save_rig:                           # written at the end: found unwritable before the run
                folder = Path(args.save_rig).expanduser().resolve().parent
                unwritable = folder_unwritable(folder)
                if unwritable is not None:
                    raise PermissionError(f"--save-rig {args.save_rig}: the folder {folder} cannot be written "
                                          f"({unwritable})")
            if args.record:
                self.recorder = DatasetRecorder(args.record, rig, markers=markers or source.markers,
                                                screen=self.screen or source.screen, overwrite=args.overwrite)
            self.writer = io.PoseWriter(args.out) if args.out else None
        except (ValueError, OSError, LookupError) as exc:
            if self.recorder is not None:
                self.recorder.discard()                 # nothing recorded yet: the old recording goes back
            for thing in (self.sender, source):
                if thing is not None:
                    thing.close()
            print(f"headplod: {exc} (nothing was written)", file=sys.stderr)
            return 1
        for output in (self.recorder, self.writer):
            for note in getattr(output, "notes", None) or ():
                print(f"note: {note}", file=log)
        if args.status or (self.live and not args.quiet):
            self.status = StatusLine(stream=log, sender=self.sender)
        return None

    def run(self, stop: StopSignals, pose_filter) -> tuple[BaseException | None, dict]:
        """Track every frame, then close the outputs; ``(failure, kept)``: what ended the run early (None when
        nothing did) and where the outputs being replaced are kept (:func:`_close_outputs`)."""
        from .loop import run_source

        args, recorder = self.args, self.recorder
        failure = None                                  # what ended the run early, after its start
        try:
            run_source(self.source, screen=self.screen, on_record=self.on_record,
                       recorder=None if recorder is None else _Labelled(recorder, f"--record {args.record}"),
                       sender=self.sender, pose_filter=pose_filter, status=self.status, max_frames=args.frames,
                       tracker=self.tracker, stop=stop, notes=self.notes, stats=self.stats)
        except KeyboardInterrupt:                       # a second signal: stop at once, keep what is whole
            stop.received = stop.received or signal.SIGINT
        except Exception as exc:                        # noqa: BLE001 - the policy below applies to every fault
            failure = exc
        finally:
            stop.finishing()                            # the closes are short: a signal now cannot cut them
            # A live camera has no end: a signal is how its run ends. A file source stopped by one is cut
            # short: what its outputs replaced is kept (docs/outputs.md).
            complete = failure is None and (self.endless or not stop())
            kept, close_failure = _close_outputs(args, self.status, recorder, self.sender, self.writer,
                                                 self.source, complete=complete)
            failure = failure or close_failure
        return failure, kept

    def finish(self, spec: str, stop: StopSignals, failure: BaseException | None, kept: dict) -> int:
        """The run's end: how it stopped, its summary and reports; the exit status."""
        args, records, log = self.args, self.records, self.log
        if stop():
            print(_stop_line(stop, records, self.endless, kept), file=sys.stderr)
        summary = evaluate.summarize(records, self.truth or None)
        name = self.source.name if self.live else Path(str(self.source.name)).name
        print(evaluate.format_summary(name, summary), file=log)
        self.notes.report()
        _report_run(self.stats, self.sender, log, self.live or args.status)
        if failure is not None:
            reader_left = (isinstance(failure, OutputFailed) and isinstance(failure.cause, BrokenPipeError)
                           and _to_stdout(self.writer))
            if reader_left:
                _silence_stdout()                       # else Python's own flush at exit fails again, loudly
            print(_early_end_line(failure, records, args, self.recorder, self.writer, kept), file=sys.stderr)
            _traceback_on_request(failure)
            return EXIT_READER_LEFT if reader_left else 1
        if synthetic_preset(spec) is not None:         # a cached frame that cannot be read: render it all again
            unreadable = next((r["reason"] for r in records if not r["ok"] and r["reason"]
                               and (".png: missing" in r["reason"] or ".png: unreadable (" in r["reason"])), None)
            if unreadable is not None:
                rerender(self.source.dataset.folder, unreadable)
        tracked = sum(bool(r["ok"]) for r in records)
        code = _report_rig(args, self.tracker, tracked=tracked, log=log)
        if args.record:
            print(f"recording: {args.record} (replay: headplod track --source {args.record})", file=log)
        if args.out and not _to_stdout(self.writer):
            print(f"pose records: {args.out}", file=log)
        if tracked == 0:
            print(f"headplod: no frame tracked (of {len(records)}); exit status {EXIT_NO_FRAME_TRACKED}",
                  file=sys.stderr)
            return EXIT_NO_FRAME_TRACKED
        return code


class OutputFailed(Exception):
    """An output could not be written during the run (a full disk, a folder gone, a closed pipe).

    ``what`` names it as the user did (``"--out poses.jsonl"``); ``cause`` is the OSError.
    """

    def __init__(self, what: str, cause: OSError):
        super().__init__(f"{what}: {_os_error_text(cause)}")
        self.what, self.cause = what, cause


class _Labelled:
    """A recorder whose write errors name the option it came from (:class:`OutputFailed`)."""

    def __init__(self, recorder, what: str):
        self._recorder, self._what = recorder, what

    def write(self, frame):
        try:
            return self._recorder.write(frame)
        except OSError as exc:
            raise OutputFailed(self._what, exc) from exc


def _os_error_text(exc: OSError) -> str:
    """An OSError in a few words: its text without the file name (the option names it), or the pipe's fate."""
    if isinstance(exc, BrokenPipeError):
        return "the program reading it closed the pipe"
    return exc.strerror or str(exc) or type(exc).__name__


def _frame_line(record, result, truth, notes) -> str:
    """The per-frame line of ``headplod track`` (without ``-q``)."""
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
    flags = [f for f in record.get("flags") or () if warning_kind(f) not in notes.kinds]
    if flags:                                           # the frame's warnings are shown once, by notes
        line += "  [" + "; ".join(flags) + "]"
    return line


def _close_outputs(args, status, recorder, sender, writer, source, complete: bool):
    """Close everything, each on its own (one failing does not skip the others).

    Returns ``(kept, failure)``: where the outputs that were being replaced are
    kept (``{option: path}``; only when the run did not complete), and the first
    OSError of a close as an :class:`OutputFailed` (None when all closed).
    """
    kept, failure = {}, None
    for what, thing in ((None, status), (f"--record {args.record}", recorder), (None, sender),
                        (f"--out {args.out}", writer), (None, source)):
        if thing is None:
            continue
        try:
            if what is None:
                thing.close()
                continue
            previous = thing.close(complete=complete and failure is None)
        except OSError as exc:
            failure = failure or OutputFailed(what or "closing", exc)
            previous = getattr(thing, "previous", None)
        if previous:
            kept[what] = previous
    if failure is not None and not complete:
        return kept, None
    return kept, failure


def _stop_line(stop, records: list, live: bool, kept: dict) -> str:
    """The one line of a run stopped by a signal: its frames are kept; what its outputs replaced is deleted
    (``live``: a live camera's or a looped replay's run, which ends so) or kept, and where (a replay cut
    short)."""
    how = ", at once on a second signal" if stop.insisted else ""
    line = f"headplod: stopped ({stop.name}{how}); the {len(records)} frames so far are kept"
    if kept:
        line += "; the source had not ended, so " + "; ".join(
            f"the {'recording' if option.startswith('--record') else 'file'} {option} replaced is kept as {path}"
            for option, path in kept.items())
    elif live:
        line += " (a live or looped run ends so: any output it replaced is deleted)"
    return line


def _early_end_line(failure: BaseException, records: list, args, recorder, writer, kept: dict) -> str:
    """The one line of a run that ended early: what failed, and where everything made is."""
    n = len(records)
    if isinstance(failure, OutputFailed):
        what = f"{failure}"
    elif isinstance(failure, OSError):
        what = f"{failure.filename + ': ' if failure.filename else ''}{_os_error_text(failure)}"
    else:
        what = (f"internal error: {type(failure).__name__}: {' '.join(str(failure).split())[:200]} "
                "(a bug: please report it; HEADPLOD_TRACEBACK=1 shows where)")
    where = []
    if args.out and not _to_stdout(writer):
        out = Path(args.out).expanduser()
        where.append(f"{writer.count} records in {args.out}" if out.exists() else f"no records ({args.out} is gone)")
    if recorder is not None:
        folder = Path(args.record).expanduser()
        where.append(f"{recorder.count} frames in {args.record}" if (folder / "times.csv").exists()
                     else f"no recording ({args.record} is gone)")
    for option, path in kept.items():
        where.append(f"the {'recording' if option.startswith('--record') else 'file'} {option.split(' ', 1)[0]} "
                     f"replaced is kept as {path}")
    return (f"headplod: the run ended early after {n} frames: {what}"
            + (f"; kept: {'; '.join(where)}" if where else ""))


def _to_stdout(writer) -> bool:
    """Whether the records go to standard output: ``--out -``, or a path that is it (``/dev/stdout``)."""
    return writer is not None and writer.to_stdout


def _silence_stdout() -> None:
    """Point standard output at /dev/null (its reader is gone), so nothing more is written to the dead pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):   # not a real file (a test's capture): nothing to do
        pass


def _traceback_on_request(failure: BaseException) -> None:
    """The traceback of a bug, when HEADPLOD_TRACEBACK is set (an environmental fault has none to show)."""
    if os.environ.get("HEADPLOD_TRACEBACK") and not isinstance(failure, (OutputFailed, OSError)):
        traceback.print_exception(type(failure), failure, failure.__traceback__, file=sys.stderr)


def _report_run(stats, sender, log, rates: bool) -> None:
    """The run's own lines at its end: rate and latency, timestamps, internal errors, UDP."""
    if stats.frames and rates:
        s = stats.summary()
        print(f"rate {s['rate_hz'] or 0:.1f} Hz, latency p50 {s['latency_ms_p50'] or 0:.1f} ms, "
              f"p99 {s['latency_ms_p99'] or 0:.1f} ms, max {s['latency_ms_max'] or 0:.1f} ms, "
              f"from {s['latency_from'] or '-'}", file=log)
        if s["capture_thread"]:
            print(f"dropped while tracking: {s['dropped_busy']} of {s['offered']} pairs captured (the newest "
                  "pair is tracked, older ones dropped)"
                  + ("; the capture thread did not end in time" if s["capture_stuck"] else ""), file=log)
    line = stats.timestamps.summary()
    if line:
        print(line, file=log)
    if stats.time_jumps:
        print(f"timestamps: {stats.time_jumps} discontinuities (a time gone back or far ahead), tracked afresh "
              f"after each; first: {stats.first_time_jump}", file=log)
    if stats.internal_errors:
        print(f"internal errors: {stats.internal_errors} frames could not be processed (first: "
              f"{stats.first_internal_error}); each has ok false and the reason in its record", file=log)
    if sender is not None:
        print(sender.failure_summary() or f"udp: {sender.sent} poses sent to {sender.host}:{sender.port}", file=log)


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
        if refiner.estimator.updates or refiner.estimator.bumps:
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
        # The best estimate, not only what was in use; FILE is whole or untouched.
        io.write_atomically(args.save_rig, lambda name: io.write_rig(name, refiner.estimator.estimate.rig()),
                            suffix=".tmp.yaml")
    except OSError as exc:                              # the OS's words, not the temporary name it was about
        print(f"headplod: --save-rig {args.save_rig}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except ValueError as exc:
        print(f"headplod: --save-rig {args.save_rig}: {exc}", file=sys.stderr)
        return 1
    note = "" if refiner.estimator.updates else " (no update from the tracked frames: rig.yaml's values)"
    print(f"refined rig: {args.save_rig}{note}", file=log)
    return 0
