"""Outputs to other programs, gathered under one name: opentrack's UDP protocol and sender, and the
live status line.

The code lives in three modules; this one re-exports their public names, so that ``from
headplod.live.output import ...`` keeps working:

- :mod:`headplod.live.opentrack`: the six values of a head pose (the pivot's position in cm, in the
  ``"tracker-pt"`` or ``"opencv"`` axes; yaw, pitch, roll in degrees), their datagram, the default
  pivot in the head frame (mm) and ``HOST:PORT`` parsing, with the opentrack sources they follow;
- :mod:`headplod.live.udp`: :class:`OpentrackSender`, the socket that sends them;
- :mod:`headplod.live.status`: :class:`StatusLine` (rate in Hz, latency and skew in ms, counts),
  :func:`short_rig_message` and :class:`ForgivingStream`.

The names are the same objects as in those modules: patch a class's attribute here or there alike,
but patch a module-level function where it is looked up (the module that calls it).
"""
from __future__ import annotations

from .opentrack import (DEFAULT_PIVOT_MM, OPENTRACK_FRAMES, OPENTRACK_PACKET_BYTES, OPENTRACK_PORT,
                        axes_from_opentrack, check_pivot_mm, decode_opentrack, encode_opentrack, opentrack_values,
                        parse_host_port, pivot_position_mm)
from .status import ForgivingStream, StatusLine, short_rig_message
from .udp import OpentrackSender

__all__ = ["DEFAULT_PIVOT_MM", "OPENTRACK_FRAMES", "OPENTRACK_PACKET_BYTES", "OPENTRACK_PORT", "ForgivingStream",
           "OpentrackSender", "StatusLine", "axes_from_opentrack", "check_pivot_mm", "decode_opentrack",
           "encode_opentrack", "opentrack_values", "parse_host_port", "pivot_position_mm", "short_rig_message"]
