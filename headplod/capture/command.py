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

from ..argtypes import note_old_spelling
from ..progress import note
from .usb import format_cameras, list_cameras, store_rig_cameras

__all__ = ["add_cameras_arguments", "run_cameras"]


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
    cameras.add_argument("--quiet", "-q", action="store_true",
                         help="no note of what --store wrote (the list and errors are still printed)")
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
    spec = (args.source or "").strip()
    body = spec[5:] if spec.lower().startswith("v4l2:") else spec
    devices = [d.strip() for d in body.split(",")]
    if body.strip().lower() == "auto":
        raise ValueError("cameras --store --source v4l2:auto: name the two devices, v4l2:LEFT,RIGHT (auto finds "
                         "the cameras a rig names, and --store is what names them)")
    if not spec or len(devices) != 2 or not all(devices):
        raise ValueError("--store needs the two cameras, left first: --store --source v4l2:/dev/video0,/dev/video2 "
                         "--rig rig.yaml")
    return devices[0], devices[1]


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
