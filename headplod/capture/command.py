"""``headplod cameras``: its arguments (:func:`add_cameras_arguments`) and its run (:func:`run_cameras`).

    headplod cameras [--all-nodes] [--store LEFT RIGHT --rig rig.yaml]

Lists the video devices with their USB identity (:mod:`.usb`), or records two
of them in a rig.yaml so that ``--source v4l2:auto`` finds them whatever
``/dev/videoN`` they get. Exit status: 0 on success, 1 when the cameras or
the rig cannot be read, 2 on bad usage.
"""
from __future__ import annotations

import argparse
import sys

from .usb import format_cameras, list_cameras, store_rig_cameras

__all__ = ["add_cameras_arguments", "run_cameras"]


def add_cameras_arguments(cameras: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``cameras``'s options to a (sub)parser; returns it."""
    cameras.add_argument("--all-nodes", action="store_true", help="also the metadata nodes of UVC cameras")
    cameras.add_argument("--store", nargs=2, metavar=("LEFT", "RIGHT"),
                         help="record these devices' USB identities in --rig as its left and right cameras, "
                              "so 'headplod track --source v4l2:auto' finds them whatever /dev/videoN they get")
    cameras.add_argument("--rig", help="rig.yaml to update with --store")
    return cameras


def run_cameras(args) -> int:
    """Run ``headplod cameras`` from parsed arguments; the exit status."""
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
    except (LookupError, ValueError) as exc:       # LibusbMissingError is a ValueError
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    print(format_cameras(cams))
    return 0
