"""``headplod track`` against faults nobody listed before issue 35: its own source as --record, a lens
rig.yaml cannot describe, frames that are broken links, a broadcast --udp, a replay cut by a signal, and
outputs in folders that cannot be written. Each case says what a user sees: one line naming their path or
option, and no byte of an input or an earlier output lost."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import socket
import sys
from pathlib import Path

import numpy as np
import pytest

from one_line import one_line_error as _one_line_error
from headplod import io
from headplod.cli import main as cli_main
from headplod.live.udp import OpentrackSender

#: A folder no one can create files in, root included (a pseudo file system).
UNWRITABLE = Path("/proc")




def _digest(folder: Path) -> dict:
    """Every file under ``folder`` (links followed) by its relative path: its bytes' hash."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _records(path: Path) -> list:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_recording_into_the_source_folder_is_refused_without_overwrite_advice(sample, capsys):
    before = _digest(sample)
    for extra in ([], ["--overwrite"]):
        assert cli_main(["track", "--source", str(sample), "--record", str(sample), "-q", *extra]) == 2
        line = _one_line_error(capsys.readouterr().err)
        assert "is the dataset folder being read" in line and "--overwrite" not in line, line
    assert _digest(sample) == before


def _set_distortion(rig_path: Path, key: str, coefficients) -> None:
    rig = io.read_rig(rig_path)
    values = dict(K1=rig.K1, D1=rig.D1, K2=rig.K2, D2=rig.D2, R=rig.R, T=rig.T)
    values[key] = np.asarray(coefficients, float)
    io.write_rig(rig_path, io.Rig(rig.image_size, **values))


def test_distortion_no_lens_has_is_refused_naming_the_rig_not_the_markers(sample, tmp_path, capsys):
    rig = io.read_rig(sample / "rig.yaml")
    with pytest.raises(ValueError, match=r"D1.*scales distances from the image centre"):
        io.Rig(rig.image_size, K1=rig.K1, D1=np.array([1e6, 1e6, 0, 0, 0]), K2=rig.K2, D2=rig.D2, R=rig.R, T=rig.T)
    text = (sample / "rig.yaml").read_text()               # the file a user has, as a typo makes it
    (sample / "rig.yaml").write_text(text.replace(_first_row(text, "D1"), "data: [ 1.0e6, 1.0e6, 0., 0., 0. ]"))
    out = tmp_path / "poses.jsonl"
    code = cli_main(["track", "--source", str(sample), "--out", str(out), "-q"])
    line = _one_line_error(capsys.readouterr().err)
    assert code in (1, 2) and "rig.yaml" in line and "D1" in line and "markers" not in line, line
    assert not out.exists()


def _first_row(text: str, key: str) -> str:
    """The ``data: [ ...`` text of matrix ``key`` in an OpenCV YAML file (up to its closing bracket)."""
    start = text.index("data:", text.index(f"{key}:"))
    return text[start:text.index("]", start) + 1]


def test_a_plausible_wide_lens_distortion_is_read(sample):
    _set_distortion(sample / "rig.yaml", "D2", [-0.35, 0.12, 0.001, -0.001, -0.02])   # a wide webcam's
    assert io.read_rig(sample / "rig.yaml").D2[0] == -0.35


@pytest.mark.parametrize("kind", ["loop", "broken"])
def test_a_frame_that_is_a_looping_or_broken_link_says_so(sample, tmp_path, kind):
    frame = sample / "left" / "000003.png"
    frame.unlink()
    frame.symlink_to(frame.name if kind == "loop" else "elsewhere.png")
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    reason = {r["frame"]: r for r in _records(out)}[3]["reason"]
    expected = "a symbolic link that loops" if kind == "loop" else "a symbolic link to elsewhere.png"
    assert reason.startswith(f"left/000003.png: {expected}"), reason


def test_udp_to_a_broadcast_address_is_sent():
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("0.0.0.0", 0))
    receiver.settimeout(5.0)
    sender = OpentrackSender("255.255.255.255", receiver.getsockname()[1])
    try:
        assert sender._sock.getsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST)
        record = {"frame": 0, "t": 0.0, "ok": True, "position": [0.0, 0.0, 600.0],
                  "axes": np.eye(3).tolist()}
        sent = sender.send(record)
        if not sent and "unreachable" in (sender.first_error or ""):
            pytest.skip(f"this machine has no route for broadcasts: {sender.first_error}")
        assert sent, sender.first_error                    # not EACCES, as without SO_BROADCAST
        assert len(receiver.recv(256)) == 48               # opentrack's six doubles
    finally:
        sender.close()
        receiver.close()


def _interrupt_at(monkeypatch, frame: int) -> None:
    """Raise SIGINT when the pose writer is given record ``frame`` (an event, not a delay)."""
    writer_class = io.PoseWriter
    real_write = writer_class.write

    def write(self, record):
        written = real_write(self, record)
        if record["frame"] == frame:
            signal.raise_signal(signal.SIGINT)
        return written

    monkeypatch.setattr(writer_class, "write", write)


def test_a_replay_stopped_by_ctrl_c_keeps_the_output_it_replaced(sample, tmp_path, monkeypatch, capsys):
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    complete = out.read_bytes()
    capsys.readouterr()
    _interrupt_at(monkeypatch, 4)
    previous_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    finally:
        signal.signal(signal.SIGINT, previous_handler)
    err = capsys.readouterr().err
    kept = tmp_path / "poses.previous.jsonl"
    assert kept.read_bytes() == complete                     # the complete run is not lost
    assert len(_records(out)) == 5                           # the stopped run's frames 0-4
    stop = [line for line in err.splitlines() if "stopped (Ctrl-C)" in line]
    assert len(stop) == 1 and f"kept as {kept}" in stop[0], err


@pytest.mark.skipif(not (UNWRITABLE.is_dir() and sys.platform.startswith("linux")), reason="needs Linux /proc")
@pytest.mark.parametrize("option", ["--out", "--record", "--save-rig"])
def test_an_output_in_a_folder_that_cannot_be_written_is_named_before_the_run(sample, capsys, option):
    target = UNWRITABLE / {"--out": "poses.jsonl", "--record": "rec", "--save-rig": "rig_refined.yaml"}[option]
    before = _digest(sample)
    assert cli_main(["track", "--source", str(sample), option, str(target), "-q"]) == 1
    captured = capsys.readouterr()
    line = _one_line_error(captured.err)
    assert str(target) in line and f"the folder {UNWRITABLE} cannot be written" in line, line
    assert ".headplod" not in line and ".tmp" not in line, line      # never a temporary name
    assert "frames tracked" not in captured.err + captured.out      # refused before the run
    assert _digest(sample) == before
    assert not os.path.lexists(target)


# ---------------------------------------------------------------------------
# found by trying more (issue 35's "one more round")
# ---------------------------------------------------------------------------


def test_a_frame_of_the_wrong_size_is_refused_from_its_header_before_decoding(sample, tmp_path):
    """A PNG claiming 100000 x 100000 px (10 GB decoded) is refused by its header's size: never decoded."""
    header = bytes.fromhex("89504e470d0a1a0a0000000d49484452") + (100000).to_bytes(4, "big") * 2
    (sample / "left" / "000002.png").write_bytes(header + bytes(64))
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--out", str(out), "-q"]) == 0
    reason = {r["frame"]: r for r in _records(out)}[2]["reason"]
    assert reason == "left/000002.png: 100000x100000, rig says 640x480", reason


def test_markers_all_at_one_point_are_not_called_metres(sample, tmp_path, capsys):
    text = (sample / "markers.yaml").read_text() if (sample / "markers.yaml").exists() else None
    blank = tmp_path / "blank.yaml"
    model = io.default_marker_model()
    io.write_markers(blank, model)
    raw = blank.read_text()
    blank.write_text(raw.replace(_first_row(raw, "markers"), "data: [" + ", ".join(["0."] * 15) + "]"))
    assert cli_main(["track", "--source", str(sample), "--markers", str(blank), "-q"]) == 1
    line = _one_line_error(capsys.readouterr().err)
    assert "at one point" in line and "metres" not in line, line
    assert text is None or (sample / "markers.yaml").read_text() == text


def test_an_ipv6_udp_address_is_shown_in_brackets():
    with OpentrackSender("::1", 4242) as sender:
        assert sender.where == "[::1]:4242"


def test_an_output_file_spelled_as_a_folder_is_refused(sample, tmp_path, capsys):
    """``--out poses/`` (a folder that does not exist) wrote a file named ``poses``."""
    target = tmp_path / "poses"
    assert cli_main(["track", "--source", str(sample), "--out", f"{target}/", "-q"]) == 2
    line = _one_line_error(capsys.readouterr().err)
    assert "ends with '/'" in line and f"{target}/" in line, line
    assert not os.path.lexists(target)
