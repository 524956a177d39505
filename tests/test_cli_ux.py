"""Issue 36: the command line for the person at the desk.

- a usage error is one line, ``PROG: error: WHAT[, did you mean X?] see PROG --help``, exit status 2, for
  every subcommand (no usage block before it); unknown options are refused by the subcommand they were
  given to, with the closest option; invalid choices and commands with the closest choice;
- ``--udp 4242`` (a port alone) sends to 127.0.0.1:4242; a bad host is refused naming the forms taken;
- ``--realtime --loop`` replays back and forth without end, times increasing; Ctrl-C ends it as a live run
  ends; ``--loop`` alone is refused in one line;
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import sys
from pathlib import Path

import numpy as np
import pytest

from headplod import cli, io
from headplod.capture.sources import DatasetSource
from headplod.live.opentrack import decode_opentrack, parse_host_port


def _usage_error(argv, capsys) -> str:
    """The one line ``headplod argv`` prints on standard error for a usage error (exit status 2)."""
    with pytest.raises(SystemExit) as stop:
        cli.main(argv)
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("argv, prog, what, meant", [
    (["render", "--view", "level", "--out", "x.png"], "headplod render", "invalid choice: 'level'", "levels"),
    (["trak"], "headplod", "unknown command 'trak'", "track"),
    (["track", "--sorce", "x"], "headplod track", "unknown option --sorce", "--source"),
    (["track", "--sorce=x"], "headplod track", "unknown option --sorce", "--source"),
    (["bench", "trak"], "headplod bench", "unknown command 'trak'", "track"),
    (["bench", "track", "--quik"], "headplod bench track", "unknown option --quik", "--quick"),
    (["render", "--mode", "csff", "--out", "x.png"], "headplod render", "invalid choice: 'csff'", "csf"),
])
def test_a_typo_is_one_line_with_the_closest_name_and_where_the_help_is(argv, prog, what, meant, capsys,
                                                                        tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = _usage_error(argv, capsys)
    assert line.startswith(f"{prog}: error: ") and what in line, line
    assert line.endswith(f", did you mean {meant}? see {prog} --help"), line
    assert not (tmp_path / "x.png").exists()


def test_a_choice_error_names_every_valid_choice(capsys):
    from headplod.render.gl import VIEW_MODES
    line = _usage_error(["render", "--view", "level", "--out", "x.png"], capsys)
    for name in VIEW_MODES:
        assert repr(name) in line, (name, line)


@pytest.mark.parametrize("argv, prog", [
    (["track", "--zzzzzz"], "headplod track"),
    (["doctor", "--qqqqqq"], "headplod doctor"),
    (["bench", "--zzzzzz", "track"], "headplod bench"),
    (["render", "--size", "x", "--out", "x.png"], "headplod render"),
    (["glasses"], "headplod glasses"),
])
def test_every_usage_error_is_one_line_naming_the_subcommand_help(argv, prog, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    line = _usage_error(argv, capsys)
    assert line.startswith(f"{prog}: error: ") and line.endswith(f"; see {prog} --help"), line
    assert "did you mean" not in line, line            # nothing is close: no guess


def test_no_command_names_the_commands(capsys):
    line = _usage_error([], capsys)
    assert line.startswith("headplod: error: give a command: ") and line.endswith("; see headplod --help")
    for name in cli.COMMANDS:
        assert name in line


def test_help_is_still_argparse_help(capsys):
    with pytest.raises(SystemExit) as stop:
        cli.main(["track", "--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: headplod track") and "--source" in out


def test_every_subcommand_parser_is_the_one_line_parser():
    """Every parser at every depth refuses in one line (a subcommand added later inherits it)."""
    def walk(parser):
        yield parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    yield from walk(sub)
    parsers = list(walk(cli.build_parser()))
    assert len(parsers) > len(cli.COMMANDS)
    for parser in parsers:
        assert type(parser).error is type(cli.build_parser()).error is not argparse.ArgumentParser.error


# ---------------------------------------------------------------------------
# --udp PORT
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, address", [
    ("4242", ("127.0.0.1", 4242)),
    (" 5555 ", ("127.0.0.1", 5555)),
    ("gamepc.local:4243", ("gamepc.local", 4243)),
    ("192.168.1.20", ("192.168.1.20", 4242)),
    ("[fe80::1%eth0]:4242", ("fe80::1%eth0", 4242)),
])
def test_a_port_alone_is_this_machine(text, address):
    assert parse_host_port(text) == address


@pytest.mark.parametrize("text", ["4242:4242", "1.2.3.4.5:4242", "a b:4242", "http://gamepc:4242", "[zz]:4242",
                                  "-gamepc", "gamepc_:4242"])
def test_a_bad_host_is_refused_with_the_expected_forms(text):
    with pytest.raises(ValueError, match=r"expected HOST:PORT, \[IPv6\]:PORT or PORT"):
        parse_host_port(text)


def test_track_refuses_a_bad_udp_host_in_one_line_before_any_work(capsys):
    assert cli.main(["track", "--source", "synthetic:static", "--udp", "4242:4242"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'4242' is not a host name" in err[0] and "or PORT" in err[0], err


def test_track_udp_port_alone_sends_to_this_machine(capsys):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    port = receiver.getsockname()[1]
    try:
        assert cli.main(["track", "--source", "synthetic:static", "--frames", "2", "--udp", str(port)]) == 0
        receiver.setblocking(False)                     # loopback: sent datagrams are queued before main returns
        got = [receiver.recv(64), receiver.recv(64)]
    finally:
        receiver.close()
    assert all(np.isfinite(decode_opentrack(data)).all() for data in got)
    assert f"udp: to 127.0.0.1:{port}," in capsys.readouterr().err


# ---------------------------------------------------------------------------
# --realtime --loop
# ---------------------------------------------------------------------------

ROOT = Path(__file__).resolve().parents[1]


def test_loop_without_realtime_is_refused_in_one_line(sweep12_dir, capsys):
    assert cli.main(["track", "--source", str(sweep12_dir), "--loop"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--loop goes with --realtime" in err[0], err


def test_a_looped_replay_goes_back_and_forth_with_times_increasing(sweep12_dir):
    dataset = io.Dataset(sweep12_dir)
    n = len(dataset.indices)
    recorded = {i: dataset.frame(i).t for i in dataset.indices}
    source = DatasetSource(sweep12_dir, loop=True)          # not realtime: no pacing, no clock involved
    frames = [source.read() for _ in range(3 * n)]
    source.close()
    assert [f.index for f in frames] == list(range(3 * n))  # numbered on: records in increasing frame order
    cycle = list(range(n)) + list(range(n - 2, 0, -1))
    played = [source.order[f.index] for f in frames]
    assert played == (cycle * 3)[:3 * n]
    for f, k in zip(frames, played):                      # each frame is the recording's frame it says
        assert np.array_equal(f.left, dataset.frame(k).left)
        np.testing.assert_array_equal(source.truth[f.index][0], dataset.truth[k][0])
    t = np.array([f.t for f in frames])
    steps = [abs(recorded[b] - recorded[a]) for a, b in zip(played, played[1:])]
    np.testing.assert_allclose(np.diff(t), steps, rtol=0, atol=1e-9)
    assert (np.diff(t) > 0).all() and t[0] == recorded[0]
    assert all(f.dropped == 0 for f in frames)


def test_ctrl_c_ends_a_looped_realtime_replay_as_a_live_run_ends(sweep12_dir, tmp_path):
    from paused_track import start_paused
    out, rec = tmp_path / "poses.jsonl", tmp_path / "rec"
    out.write_text("old\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    n = len(io.Dataset(sweep12_dir).indices)
    proc = start_paused(["--source", str(sweep12_dir), "--realtime", "--loop", "--out", str(out),
                         "--record", str(rec), "-q"], n + 4, env)      # waits past the recording's end
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(input="go\n", timeout=60)
    assert proc.returncode == 0, err
    assert "stopped (Ctrl-C)" in err and "a live or looped run ends so" in err, err
    records = io.read_poses(out)
    assert len(records) > n                                # it went on past the end of the recording
    assert (np.diff([r["frame"] for r in records]) > 0).all() and (np.diff([r["t"] for r in records]) > 0).all()
    assert not (tmp_path / "poses.previous.jsonl").exists()  # what --out replaced goes, as a live run's
