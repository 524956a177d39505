"""No fault ends a run, and nothing is lost or hidden (issue 21): every case of the issue, reproduced.

For each, the outcome the issue asks for is checked:

- **records kept and visible**: under the name the user gave (``--out``),
  whole lines up to the fault; what they replaced under a visible
  ``.previous`` name, or, after a kill, what the next run announces;
- **recordings consistent**: every ``times.csv`` row with both images, the
  replay reading every frame;
- **exit status and one line**: 0 when a frame's fault was that frame's,
  1 with one ``headplod:`` line when the run ended early;
- **no traceback**.

The frames are the shared sample's (``long_dataset``: 72 frames at 30 Hz).
"""
from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from one_line import one_line_error as _one_line_error
from headplod import io
from headplod.io import progressive
from headplod.capture import DatasetRecorder, open_source
from headplod.cli import main as cli_main
from headplod.tracking.tracker import Tracker
from paused_track import signal_paused, start_paused

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
COMMAND = [sys.executable, "-m", "headplod.cli", "track"]




def _consistent_frames(rec: Path) -> int:
    """A recording's rows, images and replay agree; its number of frames."""
    rows = io.read_times(rec / "times.csv")
    names = {side: sorted(p.name for p in (rec / side).iterdir()) for side in ("left", "right")}
    expected = [f"{i:06d}.png" for i in sorted(rows)]
    assert names["left"] == expected and names["right"] == expected, (rec, names, sorted(rows))
    with open_source(str(rec)) as source:
        assert sum(1 for frame in source if frame.error is None) == len(rows)
    return len(rows)


def _whole_records(path: Path) -> list[dict]:
    """The records of a file cut by a fault: every line whole and valid (read_poses refuses a cut one)."""
    text = path.read_text()
    assert text == "" or text.endswith("\n"), "the last record is cut"
    return io.read_poses(path)


@pytest.fixture
def old_outputs(tmp_path, long_dataset):
    """An existing --out (two lines of the user's) and a recording of 4 frames, to be replaced."""
    out, rec = tmp_path / "poses.jsonl", tmp_path / "rec"
    out.write_text("precious\n")
    assert cli_main(["track", "--source", str(long_dataset), "--record", str(rec), "--frames", "4", "-q"]) == 0
    return out, rec


# ---------------------------------------------------------------------------
# an exception inside one frame is that frame's failure
# ---------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("error", [
    np.linalg.LinAlgError("Matrix is not positive definite"), RuntimeError("boom"),
    cv2.error("OpenCV(4.x) error: (-215:Assertion failed) in function 'x'"),
    ZeroDivisionError("float division by zero"), MemoryError("cannot allocate 2 GiB"),
], ids=lambda e: type(e).__name__)
def test_an_exception_in_frame_k_is_that_frames_failure_and_the_run_goes_on(error, long_dataset, tmp_path,
                                                                            monkeypatch, capsys):
    k = 5
    real = Tracker._attempt
    calls = {"n": 0}

    def attempt(self, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == k + 1:                          # the (k+1)-th attempt: frame k's, in acquisition
            raise error
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Tracker, "_attempt", attempt)
    out, rec = tmp_path / "poses.jsonl", tmp_path / "rec"
    code = cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec),
                     "--frames", "12", "--no-tracking", "-q"])
    err = capsys.readouterr().err
    assert code == 0 and "Traceback" not in err, err
    records = io.read_poses(out)
    assert [r["frame"] for r in records] == list(range(12))
    failed = [r for r in records if not r["ok"]]
    assert [r["frame"] for r in failed] == [k]
    assert failed[0]["reason"].startswith(f"internal error: {type(error).__name__}: ")
    assert str(error).split()[0] in failed[0]["reason"]
    assert _consistent_frames(rec) == 12                # the frame's images are recorded all the same
    assert "internal errors: 1 frames" in err          # counted and reported at the end


@pytest.mark.slow
def test_an_exception_while_making_a_record_is_that_frames_failure(long_dataset, tmp_path, monkeypatch, capsys):
    from headplod.live import loop
    real = loop.result_record

    def result_record(frame, result, screen=None, extras=True):
        if frame.index == 3:
            raise ZeroDivisionError("division by zero")
        return real(frame, result, screen, extras)

    monkeypatch.setattr(loop, "result_record", result_record)
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--frames", "6", "-q"]) == 0
    records = io.read_poses(out)
    assert [r["ok"] for r in records] == [True, True, True, False, True, True]
    assert records[3]["reason"] == "internal error: ZeroDivisionError: division by zero"
    assert "internal errors: 1 frames" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# what ends a run early keeps what was made, says where, one line, exit 1
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_a_bug_outside_the_frames_keeps_everything_and_replaces_nothing_behind_the_users_back(
        long_dataset, old_outputs, monkeypatch, capsys):
    from headplod.live import status
    out, rec = old_outputs
    old_rows = io.read_times(rec / "times.csv")
    real = status.StatusLine.update

    def update(self, record, **kwargs):
        if record["frame"] == 7:
            raise RuntimeError("status line broke")
        return real(self, record, **kwargs)

    monkeypatch.setattr(status.StatusLine, "update", update)
    code = cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec),
                     "--overwrite", "--status", "-q"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 1
    assert "internal error: RuntimeError: status line broke" in line and "HEADPLOD_TRACEBACK" in line
    assert len(_whole_records(out)) == 8 and _consistent_frames(rec) == 8      # frames 0-7, each whole
    previous_out, previous_rec = out.parent / "poses.previous.jsonl", rec.parent / "rec.previous"
    assert previous_out.read_text() == "precious\n" and io.read_times(previous_rec / "times.csv") == old_rows
    assert f"kept as {previous_out}" in line and f"kept as {previous_rec}" in line


@pytest.mark.slow
def test_the_record_folder_vanishing_mid_run_keeps_the_records_and_says_so(long_dataset, tmp_path, monkeypatch,
                                                                          capsys):
    real = DatasetRecorder.write

    def write(self, frame):
        if self.count == 5:
            shutil.rmtree(self.folder)                   # the folder is deleted from under the run
        return real(self, frame)

    monkeypatch.setattr(DatasetRecorder, "write", write)
    out, rec = tmp_path / "poses.jsonl", tmp_path / "rec"
    code = cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec), "-q"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 1
    assert f"--record {rec}: No such file or directory" in line
    assert f"no recording ({rec} is gone)" in line and "keeps the" not in line
    assert len(_whole_records(out)) == 5 and f"5 records in {out}" in line


def _run(args, *, fsize_bytes=None, **popen):
    limit = (lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_bytes, fsize_bytes))) if fsize_bytes else None
    return subprocess.run([*COMMAND, *args], env=ENV, capture_output=True, text=True, timeout=120,
                          preexec_fn=limit, **popen)


@pytest.mark.slow
def test_a_full_disk_for_the_records_keeps_every_whole_record(long_dataset, old_outputs):
    """``ulimit -f``: writes past the limit fail with EFBIG (Python ignores SIGXFSZ)."""
    out, rec = old_outputs
    done = _run(["--source", str(long_dataset), "--out", str(out), "-q"], fsize_bytes=20_000)
    line = _one_line_error(done.stderr)
    assert done.returncode == 1 and "--out" in line and "File too large" in line
    records = _whole_records(out)
    assert 5 < len(records) < 72 and f"{len(records)} records in {out}" in line
    assert [r["frame"] for r in records] == list(range(len(records)))
    assert (out.parent / "poses.previous.jsonl").read_text() == "precious\n"


@pytest.mark.slow
def test_a_full_disk_for_the_recording_keeps_it_consistent_and_the_old_one_aside(long_dataset, old_outputs,
                                                                                  monkeypatch, capsys):
    """The disk fills while frame 6's right image is written: the pair is dropped whole, the run ends."""
    import errno
    record_module = sys.modules["headplod.capture.record"]          # (the package's `record` is a function)
    out, rec = old_outputs
    old_rows = io.read_times(rec / "times.csv")

    def full_disk_open(path, mode="r", *args, **kwargs):
        if Path(path).name == "000006.png.part" and Path(path).parent.name == "right":
            raise OSError(errno.ENOSPC, "No space left on device")
        return open(path, mode, *args, **kwargs)

    monkeypatch.setattr(record_module, "open", full_disk_open, raising=False)
    code = cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec),
                     "--overwrite", "-q"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 1 and f"--record {rec}: No space left on device" in line
    assert _consistent_frames(rec) == 6 and f"6 frames in {rec}" in line
    assert len(_whole_records(out)) == 6 and f"6 records in {out}" in line
    assert io.read_times(rec.parent / "rec.previous" / "times.csv") == old_rows
    assert (out.parent / "poses.previous.jsonl").read_text() == "precious\n"


@pytest.mark.slow
def test_a_closed_pipe_on_standard_output_ends_the_run_in_one_line(long_dataset):
    proc = subprocess.Popen([*COMMAND, "--source", str(long_dataset), "--out", "-", "-q"], env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()                       # one record read, then the reader leaves
    proc.stdout.close()
    err = proc.stderr.read()
    proc.wait(timeout=60)
    assert json.loads(first)["frame"] == 0
    line = _one_line_error(err)
    assert proc.returncode == 141 and "--out -: the program reading it closed the pipe" in line   # 128 + SIGPIPE
    assert "Exception ignored" not in err


@pytest.mark.slow
def test_a_folder_that_cannot_be_written_is_refused_before_the_first_frame(long_dataset, old_outputs,
                                                                           monkeypatch, capsys):
    out, rec = old_outputs
    before = sorted(p.name for p in rec.rglob("*"))
    real = progressive.tempfile.mkstemp

    def refused(*args, dir=None, **kw):                 # the probe of the folder, as a read-only mount answers
        if dir is not None and Path(dir) == out.parent.resolve():
            raise PermissionError(13, "Permission denied")
        return real(*args, dir=dir, **kw)

    monkeypatch.setattr(progressive.tempfile, "mkstemp", refused)
    code = cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec),
                     "--overwrite", "-q"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 1 and "cannot be written (Permission denied)" in line and "nothing was written" in line
    assert out.read_text() == "precious\n" and sorted(p.name for p in rec.rglob("*")) == before
    assert not (rec.parent / "rec.previous").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder; the check is tested above")
def test_a_read_only_folder_is_refused_before_the_first_frame(long_dataset, tmp_path, capsys):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        assert cli_main(["track", "--source", str(long_dataset), "--out", str(folder / "p.jsonl"), "-q"]) == 1
        assert "cannot be written" in _one_line_error(capsys.readouterr().err)
    finally:
        folder.chmod(0o755)


# ---------------------------------------------------------------------------
# signals: SIGKILL, SIGHUP, two quick SIGTERMs
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_sigkill_keeps_the_records_under_their_name_and_the_next_run_announces_them(long_dataset, old_outputs,
                                                                                   capsys):
    out, rec = old_outputs
    proc = start_paused(["--source", str(long_dataset), "--out", str(out), "--record", str(rec), "--overwrite",
                         "-q"], 10, ENV)
    proc.kill()
    proc.communicate(timeout=30)
    records = _whole_records(out)                        # under the name the user gave, every line whole
    assert len(records) >= 10
    assert (out.parent / "poses.previous.jsonl").read_text() == "precious\n"
    assert (rec.parent / "rec.previous" / "times.csv").exists()
    # Without --overwrite the killed run's recording is refused, and the refusal says whose it is.
    assert cli_main(["track", "--source", str(long_dataset), "--record", str(rec), "-q"]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert f"holds the recording of a run that did not finish (pid {proc.pid}" in line and "--overwrite" in line
    # The next run that writes there announces what it found and keeps it under visible names.
    assert cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--record", str(rec),
                     "--overwrite", "--frames", "3", "-q"]) == 0
    err = capsys.readouterr().err
    kept_out = sorted(out.parent.glob("poses.unfinished-*.jsonl"))
    kept_rec = sorted(rec.parent.glob("rec.unfinished-*"))
    assert len(kept_out) == 1 and len(kept_rec) == 1
    assert io.read_poses(kept_out[0]) == records
    assert f"found the output of a run that did not finish (pid {proc.pid}" in err
    assert f"({len(records)} records); kept as {kept_out[0]}" in err
    assert f"kept as {kept_rec[0]}" in err and "the output that run was replacing is kept as" in err
    n = _consistent_frames(kept_rec[0])                  # made consistent when set aside
    assert n >= len(records) - 1
    assert len(io.read_poses(out)) == 3 and _consistent_frames(rec) == 3
    assert (out.parent / "poses.previous.jsonl").read_text() == "precious\n"   # the killed run's, still there


@pytest.mark.slow
@pytest.mark.parametrize("signals", [(signal.SIGHUP,), (signal.SIGTERM, signal.SIGTERM)],
                         ids=["sighup", "two-quick-sigterms"])
def test_a_closed_terminal_or_two_quick_sigterms_keep_everything_whole(signals, long_dataset, old_outputs):
    out, rec = old_outputs
    proc = start_paused(["--source", str(long_dataset), "--out", str(out), "--record", str(rec), "--overwrite",
                         "-q"], 10, ENV)
    signal_paused(proc, signals)                         # the second SIGTERM while the first is being honoured
    _, err = proc.communicate(input="go\n", timeout=30)
    assert "Traceback" not in err, err
    assert proc.returncode == 0, err
    records = _whole_records(out)
    assert len(records) >= 10 and _consistent_frames(rec) == len(records)
    assert "stopped (" + ("SIGHUP, the terminal closed" if signals[0] == signal.SIGHUP else "SIGTERM") in err
    # A replay stopped before its end: what it replaced is kept beside it and named in the stop line (issue 35;
    # a live camera's run, which ends so, deletes it), and no marker is left.
    previous_out, previous_rec = out.parent / "poses.previous.jsonl", rec.parent / "rec.previous"
    assert previous_out.read_text() == "precious\n" and _consistent_frames(previous_rec) == 4
    stop = [line for line in err.splitlines() if "stopped (" in line]
    assert len(stop) == 1 and f"kept as {previous_out}" in stop[0] and f"kept as {previous_rec}" in stop[0], err
    assert not list(out.parent.glob(".*headplod-run")) and not (rec / ".headplod-run").exists()


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="a second signal between the recorder's write of a frame and the writing of "
                                       "its pose record leaves the recording one frame ahead of the records "
                                       "(live/loop.py: run_source does not hold it there)")
def test_a_second_sigterm_right_after_a_frame_is_recorded_keeps_records_and_recording_alike(long_dataset,
                                                                                            old_outputs):
    out, rec = old_outputs
    proc = start_paused(["--source", str(long_dataset), "--out", str(out), "--record", str(rec), "--overwrite",
                         "-q"], 10, ENV, when="after")
    signal_paused(proc, (signal.SIGTERM, signal.SIGTERM))
    _, err = proc.communicate(input="go\n", timeout=30)
    assert proc.returncode == 0 and "Traceback" not in err, err
    assert _consistent_frames(rec) == len(_whole_records(out))


def test_hidden_leftovers_of_earlier_versions_are_brought_to_light(long_dataset, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    hidden = tmp_path / ".poses.jsonl.abc123.part"
    hidden.write_text(json.dumps(io.pose_record(0, 0.0, False, reason="kept")) + "\n")
    assert cli_main(["track", "--source", str(long_dataset), "--out", str(out), "--frames", "2", "-q"]) == 0
    err = capsys.readouterr().err
    kept = sorted(tmp_path.glob("poses.unfinished-*.jsonl"))
    assert not hidden.exists() and len(kept) == 1 and io.read_poses(kept[0])[0]["reason"] == "kept"
    assert "unknown" not in kept[0].name                 # named by when the leftover was last written
    assert f"found the hidden output of an earlier, interrupted run (1 records); kept as {kept[0]}" in err


# ---------------------------------------------------------------------------
# timestamps
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_a_far_future_time_and_a_clock_reset_cost_two_frames_not_the_rest(tmp_path, long_dataset, capsys):
    folder = tmp_path / "clock"
    shutil.copytree(long_dataset, folder)
    times = {i: i / 30 for i in range(30)}
    times[10] = 1e300                                    # one wild time
    for i in range(20, 30):
        times[i] = 0.001 + (i - 20) / 30                 # the clock restarts
    io.write_times(folder / "times.csv", times)
    for side in ("left", "right"):
        for png in (folder / side).glob("*.png"):
            if int(png.stem) >= 30:
                png.unlink()
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(folder), "--out", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    records = io.read_poses(out)
    assert [r["frame"] for r in records] == list(range(30))     # every frame read has a record
    assert sum(r["ok"] for r in records) == 30                  # each jump is tracked afresh, none lost
    jumps = [r["frame"] for r in records if any(f.startswith(("time went back", "time jumped"))
                                                for f in r.get("flags") or ())]
    assert jumps == [10, 11, 20]
    assert "time jumped 1e+300 s ahead (t=1e+300 s after 0.3" in records[10]["flags"][0]
    assert "timestamps: 3 discontinuities" in err and "clock: 30/30 frames tracked" in err


# ---------------------------------------------------------------------------
# UDP
# ---------------------------------------------------------------------------


@pytest.mark.slow
def test_opentrack_not_listening_is_said_during_the_run(long_dataset, capsys):
    import socket
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    assert cli_main(["track", "--source", str(long_dataset), "--udp", f"127.0.0.1:{port}", "--frames", "6",
                     "-q"]) == 0
    err = capsys.readouterr().err.splitlines()
    said = [i for i, line in enumerate(err) if line == f"udp: opentrack not listening on 127.0.0.1:{port}; "
                                                       "poses are not received (the run goes on)"]
    summary = [i for i, line in enumerate(err) if "frames tracked" in line]
    assert len(said) == 1 and said[0] < summary[0]      # as it happened, before the end of the run
    assert any(f"refused: opentrack was not listening on 127.0.0.1:{port}" in line for line in err)
