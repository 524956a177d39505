"""``headplod doctor``: is this machine ready for two webcams? One line per check, and the fix.

    headplod doctor [--calib rig.yaml] [--source SPEC] [-q]

A webcam user's first step (issue 25). Each check prints one line: its
status (``ok``, ``warn``, ``FAIL``, ``skip``), what it checked and found,
and under a warning or a failure the fix, a command to run:

- ``video devices``: the ``/dev/video*`` nodes, capture or metadata nodes
  (the V4L2 index sysfs gives, as ``headplod cameras`` tells them apart);
- ``video group``: whether the user is in the ``video`` group, in the group
  file and in this login session;
- ``device access``: whether each capture node opens read/write;
- ``formats DEVICE``: per capture node, the GREY / YUYV / MJPG rates it
  offers at the rig's image size (else 640x480), through the V4L2
  enumeration ioctls (:mod:`headplod.capture.formats`);
- ``libusb``: whether pyusb can load libusb-1.0;
- ``camera identity``: each camera's USB vendor:product and serial, and
  whether two share one (``v4l2:auto`` can then tell them apart by USB port
  only);
- ``rig``, ``rig age``, ``rig RMS``, ``rig cameras``: the rig.yaml of
  ``--calib`` (else the dataset folder's of ``--source``, else the config
  file's ``calib``, else ``rig.yaml`` in the current folder): readable, how old, its RMS reprojection error,
  whether the cameras it names are the ones connected;
- ``EGL``: a headless OpenGL context, its renderer and version;
- ``config``: the config file (``headplod.toml``) and the ``calib`` and V4L2
  ``source`` doctor takes from it when not given;
- ``source``: with ``--source``, whether the spec is one ``track`` opens.

The thresholds are :class:`~.machine.DoctorSettings`. Checks take everything they look
at from a :class:`~.machine.Machine` (device lister, opener, group lookup, clock, GL
context factory, ...), so tests simulate machines without hardware. A check
that raises is reported as its own ``FAIL`` line; doctor itself never
raises. Exit status: 0 when no check FAILs, 1 when one does.

The parts: :mod:`.machine` (the settings, a check's :class:`~.machine.Result`, the
:class:`~.machine.Machine`), :mod:`.checks` (the run's :class:`~.checks.Survey` and every check but
the rig's), :mod:`.rig_checks` (the rig's four lines); this module runs them in order
(:data:`CHECKS`), prints the report and is the command.
"""
from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ..argtypes import add_quiet_argument
from .checks import (Survey, check_access, check_config, check_devices, check_egl, check_formats, check_group,
                     check_identity, check_libusb, check_source)
from .machine import FAIL, STATUSES, WARN, DoctorSettings, Machine, Result, config_from_args, guard
from .rig_checks import check_rig

__all__ = ["doctor", "format_results", "add_doctor_arguments", "run_doctor", "CHECKS"]


#: The checks in the order they run and print.
CHECKS = (check_config, check_source, check_devices, check_group, check_access, check_formats, check_libusb,
          check_identity, check_rig, check_egl)
_CHECK_NAMES = {check_config: "config", check_source: "source", check_devices: "video devices",
                check_group: "video group", check_access: "device access", check_formats: "formats",
                check_libusb: "libusb", check_identity: "camera identity", check_rig: "rig", check_egl: "EGL"}



def doctor(machine: Machine | None = None, settings: DoctorSettings | None = None, *,
           calib: str | None = None, source: str | None = None) -> list[Result]:
    """Run every check; their lines, in order. Never raises (a check's error is its FAIL line).

    Parameters
    ----------
    machine : Machine, optional
        What to look at (default: this machine).
    settings : DoctorSettings, optional
    calib : str, optional
        The rig.yaml to check (``--calib``).
    source : str, optional
        The source spec ``track`` would be given (``--source``).
    """
    machine = machine or Machine()
    settings = settings or DoctorSettings()
    sv = Survey(machine, settings, calib, source)
    return [r for check in CHECKS for r in guard(_CHECK_NAMES[check], check, sv)]


def format_results(results: Sequence[Result], quiet: bool = False) -> str:
    """The printed report: one line per result, its fix indented below, then a count (no trailing newline).

    With ``quiet`` only the warn and FAIL lines (and nothing when there are none).
    """
    shown = [r for r in results if not quiet or r.status in (WARN, FAIL)]
    width = max((len(r.check) for r in shown), default=0)
    lines = []
    for r in shown:
        lines.append(f"{r.status:<4}  {r.check:<{width}}  {r.found}")
        if r.fix and r.status in (WARN, FAIL):
            lines.append(f"{'':<4}  {'':<{width}}  fix: {r.fix}")
    if not quiet:
        counts = ", ".join(f"{sum(r.status == s for r in results)} {s}" for s in STATUSES)
        lines.append(f"headplod doctor: {len(results)} checks: {counts}")
    return "\n".join(lines)


# ---------------------------------------------------------------------------
# the command
# ---------------------------------------------------------------------------

def add_doctor_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``doctor``'s options to a (sub)parser; returns it."""
    parser.add_argument("--calib", metavar="RIG_YAML",
                        help="the rig.yaml to check (age, RMS, its cameras); without it the --source dataset's, "
                             "else ./rig.yaml, else the rig checks are skipped")
    parser.add_argument("--source", metavar="SPEC",
                        help="the source you will track: v4l2:/dev/video0,/dev/video2 checks those two devices, "
                             "v4l2:auto the ones --calib names (as 'headplod track --source')")
    add_quiet_argument(parser, help="print only the warn and FAIL lines")
    return parser


def run_doctor(args, machine: Machine | None = None, settings: DoctorSettings | None = None) -> int:
    """Run ``headplod doctor`` from parsed arguments; 0 when no check FAILs, else 1."""
    given = config_from_args(args)
    if machine is None:
        machine = Machine(config=lambda: given)
    # what the command line gave; the config file's values are reported as the config's
    calib = None if given.calib is not None else getattr(args, "calib", None)
    source = None if given.source is not None else getattr(args, "source", None)
    results = doctor(machine, settings, calib=calib, source=source)
    text = format_results(results, quiet=getattr(args, "quiet", False))
    if text:
        print(text)
    sys.stdout.flush()
    return 1 if any(r.status == FAIL for r in results) else 0
