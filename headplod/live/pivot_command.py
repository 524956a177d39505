"""``headplod pivot``: measure the head's pivot (the neck) for ``track --udp``.

    headplod pivot --source v4l2:auto --calib rig.yaml [--seconds 10] [--out pivot.yaml]
    headplod pivot --source DATASET | synthetic:neck_turns [--out pivot.yaml]

The wearer turns the head left and right, then nods up and down, for a few
seconds, keeping the shoulders still; the fixed point of that motion
(:func:`headplod.live.pivot.fit_pivot`) is the pivot, in the head frame. It is
written to ``pivot.yaml`` next to ``rig.yaml`` (the folder of ``--calib``, or
the dataset folder), where ``headplod track --udp`` finds it; ``--out`` writes
elsewhere. Nothing is written for the built-in synthetic sequences without
``--out`` (their folder is a cache).

Exit status: 0 with a pivot, 1 when the motion did not determine it or a file
could not be read or written (the reason on one line), 2 on bad usage.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from .. import io
from ..argtypes import add_quiet_argument
from ..capture import synthetic_preset
from ..io.files import Inputs, OutputRefused, check_output, file_id
from .pivot import PIVOT_FILE, PivotFitConfig, fit_pivot, write_pivot
from .track_checks import Usage as _Usage, track_inputs

__all__ = ["add_pivot_arguments", "run_pivot"]

_INSTRUCTIONS = ("keep the shoulders still and, slowly: turn the head left and right (about ±30°), then nod up "
                 "and down (about ±15°); repeat until the time is up")


def _positive(kind):
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
        return value
    return parse


def add_pivot_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``pivot``'s options to a (sub)parser; returns it."""
    parser.add_argument("--source", metavar="SPEC", default="synthetic:neck_turns",
                        help="what to track, as for 'headplod track': live cameras 'v4l2:auto' or "
                             "'v4l2:/dev/video0,/dev/video2' with --calib, a dataset folder, or "
                             "'synthetic[:PRESET]' (default synthetic:neck_turns, a head turning about a known neck)")
    parser.add_argument("--calib", help="rig.yaml of the cameras (required with --source v4l2:...)")
    parser.add_argument("--markers", help="markers.yaml (default: the dataset's, else the default model)")
    parser.add_argument("--seconds", type=_positive(float), default=10.0,
                        help="live cameras: how long to record the head turns, s (default 10)")
    parser.add_argument("--frames", type=_positive(int), help="stop after N frames")
    parser.add_argument("--out", metavar="FILE",
                        help=f"where to write the pivot (default: {PIVOT_FILE} next to rig.yaml, where "
                             "'headplod track --udp' finds it)")
    add_quiet_argument(parser, help="no instructions nor progress")
    return parser


def _default_out(args, source, live: bool, spec: str) -> Path | None:
    if args.calib:
        return Path(args.calib).expanduser().parent / PIVOT_FILE
    if live or synthetic_preset(spec) is not None:
        return None
    dataset = getattr(source, "dataset", None)
    return Path(dataset.folder) / PIVOT_FILE if dataset is not None else None


def _check_out(args, spec=None, source=None, rig=None) -> None:
    """Refuse an ``--out`` that is a special file or a file the run reads (raises the commands' _Usage). Its
    default place is in the dataset folder: that folder may hold it, not its ``left/`` and ``right/``."""
    if not args.out:
        return
    dataset = getattr(getattr(source, "dataset", None), "folder", None) or spec
    home = file_id(dataset) if dataset and Path(dataset).expanduser().is_dir() else None
    inputs = Inputs(tuple(item for item in track_inputs(args, spec, source, rig)
                          if not (item.folder and home is not None and item.id.same(home))))
    try:
        check_output(args.out, inputs, option="--out", stream=True)
    except OutputRefused as exc:
        raise _Usage(str(exc)) from None


def run_pivot(args, clock: Callable[[], float] = time.monotonic) -> int:
    """Run ``headplod pivot`` from parsed arguments; the exit status.

    ``clock`` gives the time, s, that ``--seconds`` and the progress lines count (a monotonic one).
    """
    from .command import open_source_or_report
    from ..tracking.tracker import TrackerConfig
    from .loop import make_tracker, run_source

    if args.out and Path(args.out).expanduser().is_dir():
        print(f"headplod: --out {args.out}: is a folder; give the file, e.g. {Path(args.out) / PIVOT_FILE}",
              file=sys.stderr)
        return 2
    if args.out and not Path(args.out).expanduser().resolve().parent.is_dir():
        print(f"headplod: --out {args.out}: the folder {Path(args.out).parent} does not exist", file=sys.stderr)
        return 2
    spec = args.source
    opener = argparse.Namespace(calib=args.calib, fps=60.0, fourcc=None, exposure=None, gain=None, quiet=args.quiet)
    opened = open_source_or_report(opener, spec, lambda spec: _check_out(args, spec=spec))
    if isinstance(opened, int):
        return opened
    source, rig, live = opened
    try:
        _check_out(args, source=source, rig=rig)
    except _Usage as exc:
        source.close()
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    log = sys.stderr
    positions, axes = [], []
    seen = {"start": None, "printed": None}         # the time starts with the first frame, not the camera's start-up

    def on_record(record, result):
        if record["ok"]:
            positions.append(record["position"])
            axes.append(record["axes"])
        now = clock()
        if seen["start"] is None:
            seen["start"] = seen["printed"] = now
        if live and not args.quiet and now - seen["printed"] >= 1.0:
            seen["printed"] = now
            print(f"  {now - seen['start']:4.1f} s of {args.seconds:g}: {len(positions)} poses", file=log)

    def stop() -> bool:
        return live and seen["start"] is not None and clock() - seen["start"] >= args.seconds

    try:
        markers = io.read_markers(args.markers) if args.markers else None
        if live and not args.quiet:
            print(f"pivot: {_INSTRUCTIONS}; {args.seconds:g} s from the first frame", file=log)
        tracker = make_tracker(source, TrackerConfig(), rig=rig, markers=markers)
        run_source(source, on_record=on_record, max_frames=args.frames, stop=stop, tracker=tracker)
    except (ValueError, OSError) as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("headplod: stopped (Ctrl-C); fitting the poses so far", file=log)
    finally:
        source.close()
    if not positions:
        print("headplod: pivot: no frame was tracked; nothing to fit", file=sys.stderr)
        return 1
    fit = fit_pivot(np.asarray(positions, float), np.asarray(axes, float), PivotFitConfig())
    if not fit:
        print(f"headplod: {fit.describe()}", file=sys.stderr)
        return 1
    print(fit.describe(), file=log)
    out = Path(args.out).expanduser() if args.out else _default_out(args, source, live, spec)
    c = ",".join(f"{v:.0f}" for v in fit.pivot_mm)
    if out is None:
        print(f"pivot not written (a built-in synthetic sequence; give --out to keep it); "
              f"use it as: headplod track ... --udp HOST --pivot={c}", file=log)
        return 0
    try:
        write_pivot(out, fit)
    except (OSError, ValueError) as exc:
        print(f"headplod: {out}: cannot write ({exc}); use it as: headplod track ... --udp HOST --pivot={c}",
              file=sys.stderr)
        return 1
    print(f"pivot: {out} ('headplod track --udp' reads it from beside rig.yaml; or pass --pivot={c})", file=log)
    return 0
