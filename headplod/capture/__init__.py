"""The capture layer: stereo frame sources and a recorder.

One interface, :class:`FrameSource`, for a recorded dataset folder, two video
files, the synthetic renderer and two live V4L2 cameras, so that replay and
live capture run the same code; :func:`open_source` picks the source from a
spec string. :class:`DatasetRecorder` writes frames back into the contract's
dataset layout (``docs/contract.md``).

Modules
-------
base
    The interface: :class:`CaptureFrame`, :class:`SourceStatus`,
    :class:`FrameSource`; it imports nothing else from ``capture/``.
sources
    The replay sources and the registry (:func:`open_source`).
synthetic
    The built-in synthetic sequences, rendered once and cached.
v4l2
    :class:`V4L2StereoSource`: two cameras, synchronised grabs, skew and
    dropped-frame accounting, stall and reconnect handling.
record
    :class:`DatasetRecorder` and :func:`record`.
mailbox
    :class:`~headplod.capture.mailbox.CaptureThread`: a live source read in
    a thread into a drop-oldest :class:`~headplod.capture.mailbox.FrameMailbox`,
    so the tracker takes the newest pair.
clocked
    :class:`~headplod.capture.clocked.ClockedReplay`: decoded frames released
    on a camera's clock (``bench live``).
timestamps
    :class:`TimestampCheck`: frames whose time is zero or not increasing
    are dropped and counted (Pupil's rule), where every sequence enters the
    tracker.
usb
    Camera identity over USB (``v4l2:auto``).
command
    ``headplod cameras``.
"""
from . import base as _base
from . import record as _record
from . import sources as _sources
from .base import *
from .record import *
from .sources import *
from .timestamps import TimestampCheck
from .v4l2 import CameraSetting, V4L2StereoSource

# The modules' own lists, so a name is exported from one place.
__all__ = [*_base.__all__, *_sources.__all__, "V4L2StereoSource", "CameraSetting", "TimestampCheck", *_record.__all__]
