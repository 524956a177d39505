"""``headplod track`` in a process of its own that waits after recording a chosen frame, for tests that signal or
kill a run part-way: the test acts on an event (the run says it is there), not after a delay.

A test helper, not a test module (pytest collects only ``test_*.py``); test modules import it as
``from paused_track import start_paused, signal_paused``, as they import ``conftest``.

The child is the real command (``headplod.cli.main``) with :class:`~headplod.capture.DatasetRecorder`'s
``write`` wrapped (the run must ``--record``): when frame ``frame`` (its index in the recording) is about
to be recorded (``when="before"``: it is tracked, its pose record not yet written) or has just been
(``when="after"``), it prints ``at N`` and reads its standard input, a line at a time: ``next`` is answered
with ``ok`` (by then a signal sent before it has reached the run's handler), ``go`` lets the run go on.
"""
from __future__ import annotations

import signal
import subprocess
import sys
from typing import Mapping, Sequence

__all__ = ["start_paused", "signal_paused"]

_CHILD = """
import sys
import headplod.capture.record
from headplod.cli import main

record = sys.modules["headplod.capture.record"]      # (headplod.capture.record is also a function's name)
frame, when = int(sys.argv[1]), sys.argv[2]
real_write = record.DatasetRecorder.write

def pause():
    print(f"at {frame}", flush=True)
    for line in sys.stdin:
        if line.strip() != "next":
            break
        print("ok", flush=True)

def write(self, source_frame):
    if when == "before" and self.count == frame:
        pause()
    index = real_write(self, source_frame)
    if when == "after" and index == frame:
        pause()
    return index

record.DatasetRecorder.write = write
sys.exit(main(sys.argv[3:]))
"""


def start_paused(track_args: Sequence[str], frame: int, env: Mapping[str, str], when: str = "before"
                 ) -> subprocess.Popen:
    """Start ``headplod track TRACK_ARGS`` (with ``--record``) and return once it waits ``when`` (``"before"``
    or ``"after"``) recording frame ``frame``; stdin, stdout and stderr are text pipes.
    ``proc.communicate(input="go\\n")`` lets it go on; raises AssertionError when the run ends first."""
    if when not in ("before", "after"):
        raise ValueError(f"when is {when!r}, expected 'before' or 'after'")
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(frame), when, "track", *track_args], env=dict(env),
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    said = proc.stdout.readline()
    if said != f"at {frame}\n":
        proc.kill()
        _, err = proc.communicate()
        raise AssertionError(f"the run did not reach frame {frame}: {said!r}; stderr:\n{err}")
    return proc


def signal_paused(proc: subprocess.Popen, signals: Sequence[signal.Signals]) -> None:
    """Send ``signals`` in turn to a paused run, each after the run's handler has taken the one before (two
    equal signals sent together could arrive as one)."""
    for k, sig in enumerate(signals):
        proc.send_signal(sig)
        if k < len(signals) - 1:
            proc.stdin.write("next\n")
            proc.stdin.flush()
            answer = proc.stdout.readline()
            assert answer == "ok\n", f"the run did not take signal {sig!r}: {answer!r}"
