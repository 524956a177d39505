"""``headplod bench live``: the live pipeline's rate, latency and capture-layer cost on a replayed recording.

The recording goes through the live cameras' loop (:func:`headplod.live.loop.run_source`) as fast as it goes,
three ways: ``replay``; ``replay + outputs`` (the One Euro filter and opentrack datagrams to a local socket);
``replay + recording`` (every frame written back as a dataset). Reported: frames per second, latency from
asking for a frame to its finished record (median, p95, max), frames dropped for a bad time, and the
capture layer's time (``source.read``) as a ratio to the tracker's.
"""
from __future__ import annotations

import socket
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..capture import DatasetRecorder, DatasetSource
from ..capture.synthetic import DEFAULT_SEQUENCE, ensure_dataset
from ..live.loop import run_source
from ..live.udp import OpentrackSender
from ..progress import note
from ..tracking.filters import PoseFilter
from .outputs import write_json


def run_live_bench(dataset=None, json_path=None, repeats: int = 3) -> int:
    cv2.setNumThreads(1)
    folder = Path(dataset) if dataset else ensure_dataset(DEFAULT_SEQUENCE)
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setblocking(False)
    port = receiver.getsockname()[1]
    results = {}
    variants = ("replay", "replay + outputs", "replay + recording")
    for variant in variants:
        summaries = []
        for _ in range(repeats):
            source = DatasetSource(folder)
            sender = recorder = None
            tmp = None
            try:
                kwargs = {}
                if variant == "replay + outputs":
                    sender = OpentrackSender("127.0.0.1", port)
                    kwargs = {"sender": sender, "pose_filter": PoseFilter()}
                if variant == "replay + recording":
                    tmp = tempfile.TemporaryDirectory()
                    recorder = DatasetRecorder(Path(tmp.name) / "rec", source.rig, source.markers, source.screen)
                    kwargs = {"recorder": recorder}
                stats = run_source(source, **kwargs)
                summaries.append(stats.summary())
            finally:
                for thing in (recorder, sender, source):
                    if thing is not None:
                        thing.close()
                if tmp is not None:
                    tmp.cleanup()
            _drain(receiver)
        best = min(summaries, key=lambda s: s["track_ms_mean"])
        results[variant] = {k: (float(np.median([s[k] for s in summaries])) if isinstance(best[k], float) else best[k])
                            for k in best}
        results[variant]["time_dropped"] = max(s["time_dropped"] for s in summaries)
        note(f"bench live: {variant}")
    receiver.close()
    lines = [f"recording: {folder} ({results['replay']['frames']} frames, {repeats} passes each, medians)",
             f"{'variant':20s} {'rate Hz':>8s} {'lat p50':>8s} {'lat p95':>8s} {'lat max':>8s} "
             f"{'read ms':>8s} {'track ms':>9s} {'out ms':>7s} {'read/track':>11s}"]
    for variant, r in results.items():
        lines.append(f"{variant:20s} {r['rate_hz']:8.0f} {r['latency_ms_p50']:8.2f} {r['latency_ms_p95']:8.2f} "
                     f"{r['latency_ms_max']:8.2f} {r['read_ms_mean']:8.2f} {r['track_ms_mean']:9.2f} "
                     f"{r['output_ms_mean']:7.2f} {r['capture_over_tracking']:11.2f}")
    first = results["replay"]
    lines.append(f"latency: from {first['latency_from']} to the finished record")
    lines.append(f"timestamps: {first['time_dropped']} frames dropped for a zero or non-increasing time"
                 + (f" (first: {first['time_dropped_first']})" if first["time_dropped"] else ""))
    lines.append("read: the capture layer (for a recording: PNG decoding of both images); with live cameras the "
                 "frames arrive decoded, so this ratio is an upper bound for them")
    print("\n".join(lines))
    if json_path:
        write_json(json_path, {"recording": str(folder), "repeats": repeats, "results": results})
    return 0


def _drain(sock) -> int:
    n = 0
    while True:
        try:
            sock.recv(64)
            n += 1
        except BlockingIOError:
            return n
