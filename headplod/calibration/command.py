"""``headplod calibrate``: its arguments (:func:`add_calibrate_arguments`) and its run (:func:`run_calibrate`).

    headplod calibrate --source FOLDER|v4l2:LEFT,RIGHT --board chessboard|charuco --cols N --rows M
                       --square-mm S [--marker-mm S] --out rig.yaml [-q]

The pairs are named as every source is (``--source``): a folder of image pairs,
or ``v4l2:/dev/video0,/dev/video2`` (``v4l2:0,2``) to capture them live. The
old spellings, a positional FOLDER and ``--camera LEFT RIGHT``, still work for
one release and print a note with the new one.

Exit status: 0 on success, 1 when the calibration failed, 2 on bad usage.

A calibration is never lost: the report (RMS errors) is printed before
``--out`` is written (whole or not at all: a temporary name, then a rename);
when ``--out`` cannot be written, the rig goes beside the image pairs (or,
failing that, to the temporary folder), one line says where, and the exit
status is 1.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import cv2

from .. import io
from ..argtypes import add_quiet_argument, floats, note_old_spelling
from ..capture import V4L2StereoSource, source_kind, v4l2_devices
from ..io.files import Inputs, OutputRefused, check_not_input, output_kind
from ..progress import Progress, note
from .board import BOARD_KINDS
from .calibrate import (BoardSpec, CalibrationError, calibrate_stereo, coverage_guide, detect_board, find_pairs,
                        format_report)

__all__ = ["add_calibrate_arguments", "run_calibrate"]


def add_board_spec_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The board's options, the same for ``headplod board`` (printing it) and ``headplod calibrate`` (finding it):
    the same numbers go to both."""
    default = BoardSpec()
    parser.add_argument("--board", choices=BOARD_KINDS, default=BOARD_KINDS[0],
                        help=f"the printed board's kind (default {BOARD_KINDS[0]})")
    parser.add_argument("--cols", type=int, required=True, help="inner corners per row (board and calibrate alike)")
    parser.add_argument("--rows", type=int, required=True, help="inner corners per column (board and calibrate alike)")
    parser.add_argument("--square-mm", type=float, required=True, help="side of a square as printed, mm")
    parser.add_argument("--marker-mm", type=float, help="ChArUco: side of a marker, mm (default 0.7 square)")
    parser.add_argument("--dictionary", default=default.dictionary,
                        help=f"ChArUco dictionary (default {default.dictionary})")
    return parser


def add_calibrate_arguments(calibrate: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``calibrate``'s options to a (sub)parser; returns it."""
    calibrate.add_argument("--source", metavar="FOLDER|v4l2:LEFT,RIGHT",
                           help="the image pairs: a folder (left/ and right/ with matching names, or leftNN.* and "
                                "rightNN.* side by side), or live cameras v4l2:/dev/video0,/dev/video2 (or "
                                "v4l2:0,2), captured with a guide to the poses still missing and kept in --save")
    calibrate.add_argument("folder", nargs="?", metavar="FOLDER",
                           help="old spelling of --source FOLDER (goes in the next release)")
    calibrate.add_argument("--camera", nargs="+", metavar="DEV",
                           help="old spelling of --source v4l2:LEFT,RIGHT (goes in the next release)")
    add_board_spec_arguments(calibrate)
    calibrate.add_argument("--out", required=True,
                           help="rig.yaml to write (after the report is printed; if it cannot be written, the "
                                "rig is kept beside the image pairs and the exit status is 1)")
    calibrate.add_argument("--save", help="live: folder for the captured pairs (default: beside --out)")
    calibrate.add_argument("--pairs", type=int, default=20, help="live: pairs to capture (default 20)")
    calibrate.add_argument("--size", type=floats(2), help="live: camera image size W,H (default 640,480)")
    add_quiet_argument(calibrate, help="no progress and no notes (the report and errors are still printed)")
    return calibrate


class _Usage(ValueError):
    """A calibrate command line that cannot be run (exit status 2)."""


def calibrate_source(args) -> tuple[str | None, tuple | None]:
    """``(folder, None)`` or ``(None, (left, right))``: the pairs' folder, or the two cameras to capture them from.

    From ``--source``, or from an old spelling (a positional FOLDER, ``--camera LEFT RIGHT``), for which a
    one-line note gives the new one. Raises _Usage for a source named twice, a missing one, or one calibrate
    cannot read (video files, the synthetic sequence, ``v4l2:auto``).
    """
    given = [name for name, value in (("--source", args.source), ("FOLDER", args.folder),
                                      ("--camera", args.camera)) if value]
    if len(given) > 1:
        raise _Usage(f"the pairs are named twice ({' and '.join(given)}); give them once, as --source SPEC")
    if args.camera:
        if len(args.camera) != 2:
            raise _Usage("--camera takes LEFT RIGHT (two devices); it is now --source v4l2:LEFT,RIGHT")
        spec = "v4l2:{},{}".format(*args.camera)
        note_old_spelling(f"--camera {' '.join(args.camera)}", f"--source {spec}")
        return None, v4l2_devices(spec)
    if args.folder:
        note_old_spelling(f"'headplod calibrate {args.folder}'", f"'headplod calibrate --source {args.folder}'")
        return args.folder, None
    spec = (args.source or "").strip()
    if not spec:
        raise _Usage("calibrate needs the image pairs: --source FOLDER, or --source v4l2:LEFT,RIGHT to capture "
                     "them live")
    kind = source_kind(spec)
    if kind == "v4l2":
        devices = v4l2_devices(spec)
        if devices == "auto":
            raise _Usage("calibrate --source v4l2:auto: name the two cameras, v4l2:LEFT,RIGHT (auto finds the "
                         "cameras a rig.yaml names, and calibrate is what makes it)")
        if devices is None:
            raise _Usage(f"calibrate --source {spec}: expected two devices, left first, as "
                         "v4l2:/dev/video0,/dev/video2 or v4l2:0,2")
        return None, devices
    if kind in ("synthetic", "video"):
        raise _Usage(f"calibrate --source {spec}: calibrate reads board pairs from a folder of images or from two "
                     "cameras: --source FOLDER or --source v4l2:LEFT,RIGHT")
    return spec, None


def run_calibrate(args) -> int:
    """Run ``headplod calibrate`` from parsed arguments; the exit status."""
    try:
        spec = BoardSpec(kind=args.board, cols=args.cols, rows=args.rows, square_mm=args.square_mm,
                         marker_mm=args.marker_mm, dictionary=args.dictionary)
    except ValueError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    if Path(args.out).expanduser().is_dir():
        print(f"headplod: --out {args.out}: is a folder; give the file to write, e.g. "
              f"{Path(args.out) / 'rig.yaml'}", file=sys.stderr)
        return 2
    try:                                                # a device node, a FIFO: refused before any work
        output_kind(args.out, option="--out", stream=True)
        if args.save:
            output_kind(args.save, option="--save", folder=True, entries=("left", "right"))
    except OutputRefused as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    try:
        folder, devices = calibrate_source(args)
    except _Usage as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    if devices is not None:
        folder = args.save or str(Path(args.out).with_suffix("")) + "_pairs"
        try:
            code = _capture_calibration_pairs(args, spec, devices, Path(folder))
        except OSError as exc:                          # SourceOpenError: a camera that is not there
            print(f"headplod: {exc}", file=sys.stderr)
            return 1
        if code:
            return code
    try:
        pairs = find_pairs(folder)         # a folder without pairs is one line, before any progress bar
    except CalibrationError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    try:                                   # rig.yaml may go beside the pairs, never over one of them
        check_not_input(args.out, Inputs().files("an image of the pairs being read",
                                                 [image for _, *sides in pairs for image in sides]), option="--out")
    except OutputRefused as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    progress = Progress(len(pairs), "detect board", unit="pair", disable=args.quiet)
    try:
        result = calibrate_stereo(pairs, spec, progress=lambda done, total: progress.step())
    except CalibrationError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    finally:
        progress.close()
    print(format_report(result))                       # first: the numbers are never lost with the file
    return _write_rig_or_keep(result.rig, args.out, folder)


def _write_rig_or_keep(rig, out: str, folder) -> int:
    """Write ``rig`` to ``out``; if it cannot be, beside the pairs in ``folder`` (else the temporary folder),
    with one line that says where. The exit status: 0, or 1 when ``out`` was not written."""
    try:
        Path(out).expanduser().parent.mkdir(parents=True, exist_ok=True)
        io.write_atomically(out, lambda name: io.write_rig(name, rig), suffix=".tmp.yaml")
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        stem = Path(out).stem or "rig"
        for place in (Path(folder), Path(tempfile.gettempdir())):
            kept = None
            try:
                fd, kept = tempfile.mkstemp(prefix=f"{stem}.", suffix=".yaml", dir=place)
                os.close(fd)
                io.write_rig(kept, rig)
            except (OSError, ValueError):
                if kept is not None:
                    Path(kept).unlink(missing_ok=True)
                continue
            print(f"headplod: --out {out}: cannot be written ({reason}); the calibration is kept in {kept}",
                  file=sys.stderr)
            return 1
        print(f"headplod: --out {out}: cannot be written ({reason}), nor beside the pairs or in "
              f"{tempfile.gettempdir()}; the report above is all that is left", file=sys.stderr)
        return 1
    note(f"rig: {out}")
    return 0


def _capture_calibration_pairs(args, spec, devices, folder: Path) -> int:
    """Live: keep board pairs seen by both cameras ``devices`` (left, right), with a guide to the poses still
    missing (not with ``-q``)."""
    width, height = (int(v) for v in (args.size or (640, 480)))
    kept, last_kept = [], None
    with V4L2StereoSource(devices[0], devices[1], width=width, height=height, fps=15, fourcc=None) as source:
        (folder / "left").mkdir(parents=True, exist_ok=True)        # once the cameras are open: nothing before
        (folder / "right").mkdir(parents=True, exist_ok=True)
        note(source.settings_report(text=True))
        note(f"show the board to both cameras; {args.pairs} pairs are kept, at least 1 s apart "
             "(Ctrl-C to stop early)")
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
                io.write_image(folder / "left" / name, frame.left)
                io.write_image(folder / "right" / name, frame.right)
                kept.append(det_l)
                last_kept = frame.t
                missing = coverage_guide(kept, (width, height))
                note(f"  pair {len(kept)}/{args.pairs} kept" + (": still missing: " + "; ".join(missing)
                                                                 if missing else ": coverage is good"))
        except KeyboardInterrupt:
            note("  stopped; calibrating with the pairs kept")
    note(f"pairs: {folder}")
    return 0
