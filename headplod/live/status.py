"""The live status line of ``headplod track``: :class:`StatusLine` (frame rate in Hz over a
sliding window, capture-to-pose latency and left/right skew in ms, counts over the run (dropped
pairs: the source's losses and those dropped while the tracker was busy), the
opentrack sender's failures, the rig refinement's message shortened by :func:`short_rig_message`).
"""
from __future__ import annotations

import math
import re
import sys
import time
from collections import deque
from typing import TYPE_CHECKING, Mapping, TextIO

import numpy as np

if TYPE_CHECKING:
    from .udp import OpentrackSender


def short_rig_message(message: str, width: int = 90) -> str:
    """A tracker's ``rig_message`` shortened for a status line.

    Drops the leading ``"rig.yaml: "``, long parenthesized explanations and
    the ± of the time offset. When that is still longer than ``width`` and
    the message recommends recalibrating, the recommendation is what is
    kept; then trailing "; " clauses are dropped until it fits (a single
    clause too long is cut at a word, ending in "…"). The full
    text is in the records (``rig_message``) and printed at the end of
    ``headplod track``.

    Examples
    --------
    >>> short_rig_message("rig.yaml: right camera turned ~0.42°, baseline x1.021, "
    ...                   "time offset 7.9 ms ±0.5; refining")
    'right camera turned ~0.42°, baseline x1.021, time offset 7.9 ms; refining'
    """
    text = re.sub(r"^rig\.yaml:\s*", "", str(message).strip())
    text = re.sub(r"\s*\([^()]{13,}\)", "", text)
    text = re.sub(r"\s*±\s*[0-9.]+", "", text)
    text = re.sub(r"\s+", " ", text).strip()
    if len(text) > width and "recalibrate:" in text:
        text = text[text.index("recalibrate:"):]
    parts = text.split("; ")
    while len(parts) > 1 and len("; ".join(parts)) > width:
        parts.pop()                                   # the least important clause is the last
    text = "; ".join(parts)
    if len(text) > width:
        cut = text[:max(width - 1, 1)]
        text = (cut.rsplit(" ", 1)[0] if " " in cut else cut).rstrip(" ,;") + "…"
    return text


class StatusLine:
    """A one-line live summary of tracking, for a terminal.

    Call :meth:`update` once per frame. At most every ``every_s`` seconds the
    line is written: on a terminal it overwrites itself (``'\\r'``), otherwise
    (a pipe, a log file) each rendering is its own line. Example::

        59.8 Hz | latency 4.2/7.9/9.0 ms (p50/p99/max) | skew 0.3/1.1 ms (med/max) | dropped 2 | dropped while busy 5 | ...
          | rig: right camera turned ~0.42°, baseline x1.021; refining

    Parameters
    ----------
    stream : text stream
        Where to write (default standard error).
    every_s : float
        Minimum interval between two renderings, s (> 0).
    window_s : float
        Length of the sliding window for the rate, latency and skew, s.
    sender : OpentrackSender, optional
        When given, sends that failed are shown: ``udp: N not sent (first:
        ...)``.

    Notes
    -----
    Rate: (frames in the window - 1) / (time between the first and the last),
    Hz. Latency (capture time to pose, ms; a live camera's capture time is the
    driver's buffer timestamp or the grab time, see
    :data:`headplod.live.loop.LATENCY_FROM`): median, 99th percentile and
    maximum over the window (the slowest frames are the ones a user feels).
    Skew (left/right capture-time difference, ms): median and
    maximum of its absolute value over the window. Dropped frames (the
    source's losses; ``dropped while busy N``: those the capture thread dropped while the
    tracker was busy, shown once there is one, over the run), frames
    dropped for a zero or non-increasing time (``bad time N (first: ...)``,
    shown once there is one), % ok and the last failure reason are over the
    whole run. The rig part is the last record's
    ``rig_message`` (the tracker's online refinement of ``rig.yaml``),
    shortened by :func:`short_rig_message`.
    """

    def __init__(self, stream: TextIO | None = None, every_s: float = 1.0, window_s: float = 5.0,
                 sender: OpentrackSender | None = None):
        if not every_s > 0:
            raise ValueError(f"every_s must be > 0, got {every_s}")
        if not window_s > 0:
            raise ValueError(f"window_s must be > 0, got {window_s}")
        self.stream = sys.stderr if stream is None else stream
        self.every_s = float(every_s)
        self.window_s = float(window_s)
        self.sender = sender
        try:
            self._tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self._tty = False
        self._times: deque[float] = deque()
        self._latency: deque[tuple[float, float]] = deque()
        self._skew: deque[tuple[float, float]] = deque()
        self.frames = 0
        self.ok = 0
        self.failed = 0
        self.dropped = 0
        self.dropped_busy = 0
        self.time_dropped = 0
        self.time_dropped_first: str | None = None
        self.last_failure: str | None = None
        self.internal_errors = 0
        self.rig_message: str | None = None
        self._last_render: float | None = None
        self._last_len = 0
        self._rendered = False
        self._closed = False

    def update(self, record: Mapping, latency_ms: float | None = None, skew_ms: float | None = None,
               dropped: int = 0, now: float | None = None, time_dropped: int | None = None,
               time_dropped_first: str | None = None, dropped_busy: int = 0) -> str | None:
        """Account for one frame, and write the line when it is due.

        Parameters
        ----------
        record : mapping
            The frame's pose record (``ok``, ``reason``, optional
            ``rig_message``: kept until a later record brings another).
        latency_ms : float, optional
            Capture time (a live camera's: the driver's buffer timestamp or
            the grab time, not mid-exposure) to pose, ms.
        skew_ms : float, optional
            Left minus right capture time, ms (its absolute value is used).
        dropped : int
            Frames the source lost since the previous update.
        dropped_busy : int
            Frames dropped since the previous update because the tracker
            was busy (the capture thread's drop-oldest mailbox).
        time_dropped : int, optional
            Frames dropped so far for a zero or non-increasing time (a
            running count, not an increment); shown with the first one.
        time_dropped_first : str, optional
            The first of them.
        now : float, optional
            The current time, s, on any monotonic clock (default
            ``time.monotonic()``).

        Returns
        -------
        str or None
            The line when it was written, else None.
        """
        now = time.monotonic() if now is None else float(now)
        self.frames += 1
        self.dropped += int(dropped)
        self.dropped_busy += int(dropped_busy)
        if time_dropped is not None:
            self.time_dropped = int(time_dropped)
            self.time_dropped_first = time_dropped_first
        if record.get("ok"):
            self.ok += 1
        else:
            self.failed += 1
            self.last_failure = record.get("reason") or "no reason given"
            self.internal_errors += self.last_failure.startswith("internal error")
        if record.get("rig_message"):
            self.rig_message = str(record["rig_message"])
        self._times.append(now)
        if latency_ms is not None and math.isfinite(latency_ms):
            self._latency.append((now, float(latency_ms)))
        if skew_ms is not None and math.isfinite(skew_ms):
            self._skew.append((now, abs(float(skew_ms))))
        self._expire(now)
        if self._last_render is None:
            self._last_render = now
            return None
        if now - self._last_render < self.every_s:
            return None
        self._last_render = now
        line = self.render()
        self._write(line)
        return line

    def _expire(self, now: float) -> None:
        start = now - self.window_s
        while self._times and self._times[0] < start:
            self._times.popleft()
        for q in (self._latency, self._skew):
            while q and q[0][0] < start:
                q.popleft()

    def rate_hz(self) -> float | None:
        """Frame rate over the sliding window, Hz; None with fewer than two frames."""
        if len(self._times) < 2 or self._times[-1] <= self._times[0]:
            return None
        return (len(self._times) - 1) / (self._times[-1] - self._times[0])

    def summary(self) -> dict:
        """The current statistics.

        Returns
        -------
        dict
            ``frames``, ``ok``, ``failed``, ``dropped``, ``dropped_busy``
            (counts over the run),
            ``time_dropped`` and ``time_dropped_first`` (frames dropped for
            a zero or non-increasing time, and the first),
            ``ok_percent``, ``rate_hz``, ``latency_ms_median``,
            ``latency_ms_p95``, ``latency_ms_p99``, ``latency_ms_max``,
            ``skew_ms_median``, ``skew_ms_max`` (over the
            window; None when there is no data), ``last_failure`` and
            ``rig_message`` (the last record's, in full), ``udp_failed``
            (datagrams not sent; None without a sender),
            ``udp_first_error``, ``udp_state`` (what is wrong with sending
            now, e.g. "opentrack not listening on HOST:PORT"; None when the
            last sends went through) and ``internal_errors`` (frames whose
            reason is an internal error).
        """
        lat = np.array([v for _, v in self._latency])
        skew = np.array([v for _, v in self._skew])
        return {
            "frames": self.frames,
            "ok": self.ok,
            "failed": self.failed,
            "dropped": self.dropped,
            "dropped_busy": self.dropped_busy,
            "time_dropped": self.time_dropped,
            "time_dropped_first": self.time_dropped_first,
            "ok_percent": 100.0 * self.ok / self.frames if self.frames else None,
            "rate_hz": self.rate_hz(),
            "latency_ms_median": float(np.median(lat)) if lat.size else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if lat.size else None,
            "latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else None,
            "latency_ms_max": float(lat.max()) if lat.size else None,
            "skew_ms_median": float(np.median(skew)) if skew.size else None,
            "skew_ms_max": float(skew.max()) if skew.size else None,
            "last_failure": self.last_failure,
            "rig_message": self.rig_message,
            "udp_failed": None if self.sender is None else self.sender.failed,
            "udp_first_error": None if self.sender is None else self.sender.first_error,
            "udp_state": None if self.sender is None else self.sender.state(),
            "internal_errors": self.internal_errors,
        }

    def render(self) -> str:
        """The status line for the current statistics (no newline, no ``'\\r'``)."""
        s = self.summary()

        def num(x, fmt="{:.1f}"):
            return "--" if x is None else fmt.format(x)

        parts = [f"{num(s['rate_hz'])} Hz",
                 f"latency {num(s['latency_ms_median'])}/{num(s['latency_ms_p99'])}/{num(s['latency_ms_max'])} ms "
                 "(p50/p99/max)",
                 f"skew {num(s['skew_ms_median'])}/{num(s['skew_ms_max'])} ms (med/max)",
                 f"dropped {s['dropped']}",
                 *([f"dropped while busy {s['dropped_busy']}"] if s["dropped_busy"] else []),
                 *([f"bad time {s['time_dropped']} (first: {s['time_dropped_first']})"]
                   if s["time_dropped"] else []),
                 f"ok {num(s['ok_percent'])}%",
                 *([f"internal errors {s['internal_errors']}"] if s["internal_errors"] else [])]
        if s["udp_state"]:
            parts.append(f"udp: {s['udp_state']} ({s['udp_failed']} not sent)")
        elif s["udp_failed"]:
            parts.append(f"udp: {s['udp_failed']} not sent (first: {s['udp_first_error']})")
        if s["last_failure"]:
            parts.append(f"last failure: {s['last_failure']}")
        if s["rig_message"]:
            parts.append("rig: " + short_rig_message(s["rig_message"]))
        return " | ".join(parts)

    def _write(self, line: str) -> None:
        if self._tty:
            pad = max(0, self._last_len - len(line))
            self.stream.write("\r" + line + " " * pad)
            self._last_len = len(line)
        else:
            self.stream.write(line + "\n")
        self.stream.flush()
        self._rendered = True

    def close(self) -> None:
        """End the line on a terminal (a final newline); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._tty and self._rendered:
            self.stream.write("\n")
            self.stream.flush()

    def __enter__(self) -> "StatusLine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
