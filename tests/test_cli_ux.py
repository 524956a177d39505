"""Issue 36: the command line for the person at the desk.

- a usage error is one line, ``PROG: error: WHAT[, did you mean X?] see PROG --help``, exit status 2, for
  every subcommand (no usage block before it); unknown options are refused by the subcommand they were
  given to, with the closest option; invalid choices and commands with the closest choice;
- ``--udp 4242`` (a port alone) sends to 127.0.0.1:4242; a bad host is refused naming the forms taken;
- ``--realtime --loop`` replays back and forth without end, times increasing; Ctrl-C ends it as a live run
  ends; ``--loop`` alone is refused in one line;
- smaller things: ``v4l2:auto``'s advice is today's spelling; ``pivot`` on a short recording says what it
  needs (no nan); docs/plod.md's xvfb-run names its package; Mesa's shader cache goes into headplod's cache;
  ``pytest -q`` shows the "N passed" line.
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import socket
import subprocess
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


@pytest.mark.parametrize("value", ["4242", '"4242"'])
def test_the_config_files_udp_takes_a_port_alone(value, tmp_path, monkeypatch):
    from headplod import config
    monkeypatch.chdir(tmp_path)
    (tmp_path / "headplod.toml").write_text(f"[track]\nudp = {value}\n")
    args = config.parse_args(cli.build_parser(), ["track", "-q"])
    assert parse_host_port(args.udp) == ("127.0.0.1", 4242)


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


@pytest.mark.slow
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


# ---------------------------------------------------------------------------
# smaller things
# ---------------------------------------------------------------------------

def test_v4l2_auto_without_identities_advises_a_command_that_parses_as_it_is_now(tmp_path, sweep12_dir):
    from headplod.capture.usb import resolve_rig_cameras
    path = tmp_path / "my rig.yaml"
    path.write_bytes((sweep12_dir / "rig.yaml").read_bytes())
    with pytest.raises(LookupError) as refused:
        resolve_rig_cameras(io.read_rig(path), [])
    advice = str(refused.value).split("store their identities with: ", 1)[1]
    argv = shlex.split(advice)
    assert argv[0] == "headplod"
    args = cli.build_parser().parse_args(argv[1:])
    # today's spelling: --store with no devices (the old --store LEFT RIGHT prints a note and goes)
    assert args.command == "cameras" and args.store == [] and args.source == "v4l2:LEFT,RIGHT"
    assert Path(args.rig) == path


def test_pivot_on_a_short_recording_says_what_it_needs_not_nan(sweep12_dir, capsys):
    from headplod.live.pivot import PivotFitConfig
    config = PivotFitConfig()
    assert cli.main(["pivot", "--source", str(sweep12_dir), "-q"]) == 1
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "nan" not in line, line
    n = len(io.Dataset(sweep12_dir).indices)
    assert f"{n} tracked poses, {config.min_frames} needed" in line, line
    assert f"at least {config.min_spread_deg:g}° rms about each axis" in line, line


def test_the_docs_xvfb_run_names_its_package_or_setup_installs_it():
    setup = (ROOT / "setup.sh").read_text()
    apt = re.search(r'APT_PACKAGES="([^"]*)"', setup).group(1).split()
    for doc in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for paragraph in doc.read_text().split("\n\n"):
            if "xvfb-run" in paragraph:
                assert "xvfb" in apt or "package xvfb" in " ".join(paragraph.split()), (doc, paragraph)


@pytest.mark.slow
def test_mesa_and_matplotlib_caches_go_into_headplods_cache(tmp_path):
    """A render with an OpenGL context, its home and XDG cache in tmp_path: Mesa's shader cache is made in
    HEADPLOD_CACHE, nothing in the home folder or XDG_CACHE_HOME (where Mesa puts it by default)."""
    home, cache, xdg = tmp_path / "home", tmp_path / "cache", tmp_path / "xdg"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MESA_", "MPLCONFIGDIR", "XDG_CACHE"))}
    env.update(HOME=str(home), HEADPLOD_CACHE=str(cache), XDG_CACHE_HOME=str(xdg),
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    done = subprocess.run([sys.executable, "-m", "headplod.cli", "render", "--size", "32,18", "--out",
                           str(tmp_path / "x.png"), "-q"], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    assert any(p.is_file() for p in (cache / "mesa").rglob("*")), sorted(cache.rglob("*"))
    assert not xdg.exists() and not list(home.iterdir())


def test_a_library_cache_variable_the_user_set_is_kept(tmp_path, monkeypatch):
    monkeypatch.setenv("HEADPLOD_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("MESA_SHADER_CACHE_DIR", str(tmp_path / "mine"))
    monkeypatch.delenv("MESA_GLSL_CACHE_DIR", raising=False)
    monkeypatch.delenv("MPLCONFIGDIR", raising=False)
    cli._keep_libraries_caches_in_ours()
    assert os.environ["MESA_SHADER_CACHE_DIR"] == str(tmp_path / "mine")
    assert "MESA_GLSL_CACHE_DIR" not in os.environ      # the user chose Mesa's place: not half overridden
    assert os.environ["MPLCONFIGDIR"] == str(tmp_path / "cache" / "matplotlib")


@pytest.mark.slow
def test_pytest_q_shows_how_many_passed(tmp_path):
    """pyproject's addopts had -q: ``pytest -q`` became -qq, which hides the "N passed" line."""
    (tmp_path / "test_one.py").write_text("def test_one():\n    assert True\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-c", str(ROOT / "pyproject.toml"),
                           "-p", "no:cacheprovider", str(tmp_path / "test_one.py")],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.search(r"^1 passed", done.stdout, re.MULTILINE), done.stdout
