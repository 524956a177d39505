"""``headplod calibrate``: its arguments (:func:`add_calibrate_arguments`) and its run (:func:`run_calibrate`).

    headplod calibrate [FOLDER | --camera LEFT RIGHT] --board chessboard|charuco --cols N --rows M
                       --square-mm S [--marker-mm S] --out rig.yaml

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
from ..argtypes import floats
from ..capture import V4L2StereoSource
from ..progress import Progress
from .board import BOARD_KINDS
from .calibrate import BoardSpec, CalibrationError, calibrate_folder, coverage_guide, detect_board, format_report

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
    calibrate.add_argument("folder", nargs="?", help="image pairs: left/ and right/ with matching names, or "
                                                     "leftNN.* and rightNN.* side by side")
    calibrate.add_argument("--camera", nargs="+", metavar="DEV",
                           help="capture the pairs live from the cameras LEFT RIGHT (/dev/videoN or N), with a "
                                "guide to the poses still missing; they are kept in --save")
    add_board_spec_arguments(calibrate)
    calibrate.add_argument("--out", required=True,
                           help="rig.yaml to write (after the report is printed; if it cannot be written, the "
                                "rig is kept beside the image pairs and the exit status is 1)")
    calibrate.add_argument("--save", help="live: folder for the captured pairs (default: beside --out)")
    calibrate.add_argument("--pairs", type=int, default=20, help="live: pairs to capture (default 20)")
    calibrate.add_argument("--size", type=floats(2), help="live: camera image size W,H (default 640,480)")
    return calibrate


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
    progress = Progress(0, "detect board", unit="pair")

    def step(done, total):
        progress.total = total
        progress.step()

    try:
        result = calibrate_folder(folder, spec, progress=step)
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
    print(f"rig: {out}", file=sys.stderr)
    return 0


def _device(text: str):
    return int(text) if text.isdigit() else text


def _capture_calibration_pairs(args, spec, folder: Path) -> int:
    """Live: keep board pairs seen by both cameras, with a guide to the poses still missing."""
    if len(args.camera) != 2:
        print("headplod: calibrate --camera takes LEFT RIGHT", file=sys.stderr)
        return 2
    width, height = (int(v) for v in (args.size or (640, 480)))
    (folder / "left").mkdir(parents=True, exist_ok=True)
    (folder / "right").mkdir(parents=True, exist_ok=True)
    kept, last_kept = [], None
    with V4L2StereoSource(_device(args.camera[0]), _device(args.camera[1]), width=width, height=height,
                          fps=15, fourcc=None) as source:
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
