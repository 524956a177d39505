"""``headplod cameras``: its arguments (:func:`add_cameras_arguments`) and its run (:func:`run_cameras`).

    headplod cameras [--all-nodes] [--store --source v4l2:LEFT,RIGHT --rig rig.yaml] [-q]

Lists the video devices with their USB identity (:mod:`.usb`), or records two
of them in a rig.yaml so that ``--source v4l2:auto`` finds them whatever
``/dev/videoN`` they get. The two are named as every source is
(``--source v4l2:/dev/video0,/dev/video2`` or ``v4l2:0,2``); the old spelling
``--store LEFT RIGHT`` still works for one release and prints a note with the
new one. Exit status: 0 on success, 1 when the cameras or the rig cannot be
read, 2 on bad usage.
"""
from __future__ import annotations

import argparse
import sys

from ..argtypes import add_quiet_argument, note_old_spelling
from ..progress import note
from .sources import v4l2_devices
from .usb import format_cameras, list_cameras, store_rig_cameras

__all__ = ["add_cameras_arguments", "run_cameras", "add_camera_settings", "DEFAULT_FPS"]

#: The frame rate asked of live cameras unless --fps says otherwise, Hz.
DEFAULT_FPS = 60.0


def _frame_rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a frame rate in Hz, got {text!r}") from None
    if not (value > 0 and value < 1000):
        raise argparse.ArgumentTypeError(f"a frame rate is above 0 and below 1000 Hz, got {text!r}")
    return value


def add_camera_settings(group, fps_default: float | None = DEFAULT_FPS) -> None:
    """``--fps``, ``--fourcc``, ``--exposure`` and ``--gain``: what every command that opens live cameras asks
    of them (``track``, ``preview``), with the advice for setting them. ``fps_default`` None leaves ``--fps``
    None when not given (the command then asks :data:`DEFAULT_FPS`, and can tell that it was not given)."""
    from .v4l2 import FOURCCS

    group.add_argument("--fps", type=_frame_rate, default=fps_default, metavar="HZ",
                       help=f"frame rate to request, Hz (default {DEFAULT_FPS:g}); a camera that cannot "
                            "gives its nearest, and the status line shows the rate measured")
    group.add_argument("--fourcc", type=str.upper, choices=FOURCCS,
                       help="pixel format to request (default: the camera's); GREY or YUYV keep the markers' "
                            "edges, MJPG compresses them but is often the only format at 60 fps")
    group.add_argument("--exposure", type=float, metavar="E",
                       help="manual exposure, in the camera's V4L2 units (auto exposure is then off; default: "
                            "the camera's auto exposure, which brightens the markers into saturation and drifts "
                            "with the room). Lower it until 'headplod preview' no longer says the markers are "
                            "saturated; a short exposure also blurs a moving head less")
    group.add_argument("--gain", type=float, metavar="G",
                       help="camera gain, in the camera's V4L2 units (default: the camera's). Raise it last, "
                            "only when the markers are too dim at the exposure you need: gain adds noise")


def add_cameras_arguments(cameras: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``cameras``'s options to a (sub)parser; returns it."""
    cameras.add_argument("--all-nodes", action="store_true", help="also the metadata nodes of UVC cameras")
    cameras.add_argument("--store", nargs="*", metavar="DEV",
                         help="record the USB identities of the --source cameras in --rig as its left and right "
                              "cameras, so 'headplod track --source v4l2:auto' finds them whatever /dev/videoN "
                              "they get (the old spelling --store LEFT RIGHT goes in the next release)")
    cameras.add_argument("--source", metavar="v4l2:LEFT,RIGHT",
                         help="with --store: the two cameras, left first, v4l2:/dev/video0,/dev/video2 or v4l2:0,2")
    cameras.add_argument("--rig", help="rig.yaml to update with --store")
    add_quiet_argument(cameras, help="no note of what --store wrote (the list and errors are still printed)")
    return cameras


def _store_devices(args) -> tuple[str, str]:
    """The (left, right) devices of ``--store``, from ``--source v4l2:LEFT,RIGHT`` or the old ``--store LEFT
    RIGHT`` (with its note); raises ValueError with the usage line."""
    if args.store and args.source:
        raise ValueError("the cameras are named twice (--store LEFT RIGHT and --source); give them once, as "
                         "--store --source v4l2:LEFT,RIGHT")
    if args.store:
        if len(args.store) != 2:
            raise ValueError("--store takes no devices now: --store --source v4l2:LEFT,RIGHT --rig rig.yaml")
        spec = "v4l2:{},{}".format(*args.store)
        note_old_spelling(f"--store {' '.join(args.store)}", f"--store --source {spec}")
        return args.store[0], args.store[1]
    devices = v4l2_devices(args.source or "")
    if devices == "auto":
        raise ValueError("cameras --store --source v4l2:auto: name the two devices, v4l2:LEFT,RIGHT (auto finds "
                         "the cameras a rig names, and --store is what names them)")
    if devices is None:
        raise ValueError("--store needs the two cameras, left first: --store --source v4l2:/dev/video0,/dev/video2 "
                         "--rig rig.yaml")
    return str(devices[0]), str(devices[1])


def run_cameras(args) -> int:
    """Run ``headplod cameras`` from parsed arguments; the exit status."""
    storing = args.store is not None
    try:
        left, right = _store_devices(args) if storing else (None, None)
        if storing != bool(args.rig) or (args.source and not storing):
            raise ValueError("--store --source v4l2:LEFT,RIGHT and --rig rig.yaml go together")
    except ValueError as exc:
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    try:
        cams = list_cameras(all_nodes=args.all_nodes)
        if storing:
            rig = store_rig_cameras(args.rig, left, right, cams)
            note(f"{args.rig}: left camera {rig.extra['left_camera']}, right camera {rig.extra['right_camera']}")
            return 0
    except (LookupError, ValueError) as exc:       # LibusbMissingError is a ValueError
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    print(format_cameras(cams))
    return 0
