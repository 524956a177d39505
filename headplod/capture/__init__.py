"""The capture layer: stereo frame sources and a recorder.

One interface, :class:`FrameSource`, for a recorded dataset folder, two video
files, the synthetic renderer and two live V4L2 cameras, so that replay and
live capture run the same code; :func:`open_source` picks the source from a
spec string. :class:`DatasetRecorder` writes frames back into the contract's
dataset layout (``spec/conventions.md``).

Modules
-------
sources
    :class:`CaptureFrame`, :class:`SourceStatus`, :class:`FrameSource`, the
    replay sources and the registry (:func:`open_source`).
v4l2
    :class:`V4L2StereoSource`: two cameras, synchronised grabs, skew and
    dropped-frame accounting, stall and reconnect handling.
record
    :class:`DatasetRecorder` and :func:`record`.
"""
from .record import DatasetRecorder, RecordingSummary, record
from .sources import (
    SOURCE_STATES,
    CaptureFrame,
    DatasetSource,
    FrameSource,
    SourceOpenError,
    SourceStatus,
    SyntheticSource,
    VideoSource,
    open_source,
    register_source,
    source_forms,
    to_gray,
)
from .v4l2 import CameraSetting, V4L2StereoSource

__all__ = [
    "CaptureFrame",
    "SourceStatus",
    "SourceOpenError",
    "FrameSource",
    "DatasetSource",
    "SyntheticSource",
    "VideoSource",
    "V4L2StereoSource",
    "CameraSetting",
    "open_source",
    "register_source",
    "source_forms",
    "to_gray",
    "SOURCE_STATES",
    "DatasetRecorder",
    "RecordingSummary",
    "record",
]
