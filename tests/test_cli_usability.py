"""What a new user meets on the command line (issue 25): defaults in --help, negative coordinates, render --compare."""
import argparse

import pytest

from headplod import cli


def _options(parser, path=()):
    """(command path, option, default, help) of every option of ``parser`` and its subcommands."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, path + (name,))
        elif action.option_strings and not isinstance(action, argparse._HelpAction):
            yield " ".join(path), action.option_strings[-1], action.default, action.help


def test_every_option_with_a_default_names_it_in_its_help():
    missing = [(command, option, default) for command, option, default, text in _options(cli.build_parser())
               if default not in (None, False, argparse.SUPPRESS) and text != argparse.SUPPRESS
               and "default" not in (text or "").lower()]
    assert missing == []


def test_the_walk_sees_the_subcommands():
    commands = {command for command, *_ in _options(cli.build_parser())}
    assert {"render", "demo", "calibrate", "track"} <= commands


def test_a_coordinate_list_may_start_with_a_minus_sign(tmp_path):
    """``render --head -120,40,650`` used to fail with "expected one argument"; only ``--head=...`` worked."""
    from headplod.argtypes import attach_negative_lists

    assert attach_negative_lists(["render", "--head", "-120,40,650", "--poi", "-5.5,3e2", "--level-bias", "-1",
                                  "-q"]) == ["render", "--head=-120,40,650", "--poi=-5.5,3e2", "--level-bias", "-1",
                                             "-q"]
    args = cli.build_parser().parse_args(attach_negative_lists(
        ["render", "--head", "-120,40,650", "--out", str(tmp_path / "r.png")]))
    assert list(args.head) == [-120.0, 40.0, 650.0]


@pytest.mark.slow
def test_the_command_line_takes_a_negative_coordinate_list(tmp_path, capsys):
    out = tmp_path / "r.png"
    assert cli.main(["render", "--head", "-40,20,640", "--size", "64,36", "--out", str(out)]) == 0
    assert out.is_file()


@pytest.mark.slow
def test_render_compares_with_full_and_refuses_where_it_cannot(tmp_path, capsys):
    assert cli.main(["render", "--size", "96,54", "--compare", "full", "--out", str(tmp_path / "a.png")]) == 0
    line = next(t for t in capsys.readouterr().err.splitlines() if t.startswith("against full"))
    assert "PSNR" in line and "within 5° of the POI" in line and "FLIP" in line
    psnr = float(line.split("PSNR ")[1].split(" dB")[0])
    assert 20 < psnr < 80                                    # a real difference: not identical, not garbage
    assert cli.main(["render", "--mode", "full", "--size", "96,54", "--compare", "full",
                     "--out", str(tmp_path / "b.png")]) == 0
    assert "PSNR inf dB" in capsys.readouterr().err          # full against itself is identical
    assert cli.main(["render", "--backend", "tessellation", "--compare", "full", "--out", str(tmp_path / "c.png")]) == 2
    assert not (tmp_path / "c.png").exists()


# ---------------------------------------------------------------------------
# one spelling everywhere: -q on every subcommand, --source on every command that reads frames
# ---------------------------------------------------------------------------

NOTE_END = "the old spelling goes in the next release"


def _parsers(parser, path=()):
    """(command path, parser) of every subcommand at every depth (``bench live`` too)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield path + (name,), sub
                yield from _parsers(sub, path + (name,))


def test_every_subcommand_takes_quiet():
    missing = [" ".join(path) for path, sub in _parsers(cli.build_parser())
               if not {"-q", "--quiet"} <= set(sub._option_string_actions)]
    assert missing == []


#: The commands that read cameras or recordings (a later one that does too belongs here).
READERS = ("track", "pivot", "demo", "calibrate", "cameras", "bench live", "preview", "doctor")


def test_every_command_that_reads_frames_names_them_with_source():
    parsers = {" ".join(path): sub for path, sub in _parsers(cli.build_parser())}
    missing = [name for name in READERS if name in parsers and "--source" not in parsers[name]._option_string_actions]
    assert missing == []
    assert {"track", "calibrate", "cameras", "bench live"} <= set(parsers)
    # an option that takes cameras by another name is an old spelling, and says so
    for name, sub in parsers.items():
        for option in ("--camera",):
            action = sub._option_string_actions.get(option)
            assert action is None or "old spelling" in action.help, (name, option)


@pytest.mark.slow
def test_quiet_is_honoured_by_render_and_the_progress_it_reaches(tmp_path, capsys):
    assert cli.main(["render", "--size", "64,36", "--out", str(tmp_path / "a.png")]) == 0
    assert "triangles" in capsys.readouterr().err
    assert cli.main(["render", "--size", "64,36", "--out", str(tmp_path / "b.png"), "-q"]) == 0
    assert capsys.readouterr().err == "" and (tmp_path / "b.png").is_file()
    from headplod import progress
    assert not progress.is_quiet()                          # the switch is the command's only
    with progress.quiet():
        bar = progress.Progress(2, "x")
        bar.step(), bar.step()
        progress.note("nothing")
    assert capsys.readouterr().err == ""


def test_quiet_board_and_glasses_print_nothing_but_write_the_file(tmp_path, capsys):
    assert cli.main(["board", "--cols", "4", "--rows", "3", "--square-mm", "20", "--out", str(tmp_path / "b.png"),
                     "--dpi", "72", "-q"]) == 0
    assert cli.main(["glasses", "--out", str(tmp_path / "g.svg"), "-q"]) == 0
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    assert (tmp_path / "b.png").is_file() and (tmp_path / "g.svg").is_file()


# ---------------------------------------------------------------------------
# the old spellings still work, with their note
# ---------------------------------------------------------------------------

def _notes(err):
    return [line for line in err.splitlines() if line.startswith("note:")]


def test_calibrate_source_and_its_old_spellings(tmp_path, capsys):
    board = ["--cols", "9", "--rows", "6", "--square-mm", "25", "--out", str(tmp_path / "rig.yaml")]
    missing = tmp_path / "no_pairs"
    assert cli.main(["calibrate", "--source", str(missing), *board]) == 1
    err = capsys.readouterr().err
    assert not _notes(err) and str(missing) in err
    assert cli.main(["calibrate", str(missing), *board]) == 1
    assert _notes(capsys.readouterr().err) == [f"note: 'headplod calibrate {missing}' is now 'headplod calibrate "
                                               f"--source {missing}'; {NOTE_END}"]
    assert cli.main(["calibrate", "--camera", "0", *board]) == 2
    assert "--camera takes LEFT RIGHT" in capsys.readouterr().err
    assert cli.main(["calibrate", str(missing), "--source", str(missing), *board]) == 2
    assert "named twice" in capsys.readouterr().err
    for bad in ("v4l2:auto", "synthetic", "a.avi,b.avi"):
        assert cli.main(["calibrate", "--source", bad, *board]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "--source" in err, err
    assert cli.main(["calibrate", *board]) == 2
    assert "--source FOLDER" in capsys.readouterr().err
    assert not (tmp_path / "rig.yaml").exists() and not (tmp_path / "rig_pairs").exists()


def test_calibrate_names_cameras_as_track_does(monkeypatch):
    from headplod.calibration.command import calibrate_source
    args = argparse.Namespace(source=None, folder=None, camera=None)
    for spec, devices in (("v4l2:/dev/video0,/dev/video2", ("/dev/video0", "/dev/video2")), ("v4l2:0,2", (0, 2)),
                          ("0,2", (0, 2))):
        args.source = spec
        assert calibrate_source(args) == (None, devices)


def test_cameras_store_takes_the_source_and_the_old_spelling_says_so(tmp_path, monkeypatch, capsys):
    from headplod.capture import command
    stored = []

    def store(rig, left, right, cams):
        stored.append((rig, left, right))
        return argparse.Namespace(extra={"left_camera": {"serial": "L"}, "right_camera": {"serial": "R"}})

    monkeypatch.setattr(command, "list_cameras", lambda all_nodes=False: [])
    monkeypatch.setattr(command, "store_rig_cameras", store)
    rig = str(tmp_path / "rig.yaml")
    assert cli.main(["cameras", "--store", "--source", "v4l2:/dev/video0,/dev/video2", "--rig", rig]) == 0
    err = capsys.readouterr().err
    assert not _notes(err) and "left camera" in err
    assert cli.main(["cameras", "--store", "/dev/video0", "/dev/video2", "--rig", rig, "-q"]) == 0
    assert capsys.readouterr().err.splitlines() == [f"note: --store /dev/video0 /dev/video2 is now --store --source "
                                                    f"v4l2:/dev/video0,/dev/video2; {NOTE_END}"]
    assert stored == [(rig, "/dev/video0", "/dev/video2")] * 2
    for argv in (["--store", "--rig", rig], ["--store", "--source", "v4l2:auto", "--rig", rig],
                 ["--store", "0", "--rig", rig], ["--store", "0", "2", "--source", "v4l2:0,2", "--rig", rig],
                 ["--source", "v4l2:0,2"], ["--store", "--source", "v4l2:0,2"]):
        assert cli.main(["cameras", *argv]) == 2, argv
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert len(stored) == 2


def test_synth_out_and_the_old_positional(tmp_path, capsys):
    new, old = tmp_path / "new", tmp_path / "old"
    assert cli.main(["synth", "static", "--out", str(new), "--frames", "1", "-q"]) == 0
    assert capsys.readouterr().err == ""
    assert cli.main(["synth", "static", str(old), "--frames", "1", "-q"]) == 0
    assert _notes(capsys.readouterr().err) == [f"note: 'headplod synth static {old}' is now 'headplod synth static "
                                               f"--out {old}'; {NOTE_END}"]
    assert sorted(p.name for p in new.iterdir()) == sorted(p.name for p in old.iterdir())
    for argv in (["static"], ["static", str(old), "--out", str(new)]):
        with pytest.raises(SystemExit) as stop:
            cli.main(["synth", *argv])
        assert stop.value.code == 2


# ---------------------------------------------------------------------------
# negative numbers in coordinate options
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("argv, dest, expected", [
    (["track", "--udp", "h", "--pivot", "-10,-80,-90"], "pivot", [-10, -80, -90]),
    (["track", "--udp", "h", "--pivot=-10,-80,-90"], "pivot", [-10, -80, -90]),
    (["track", "--pivot", "-0.5,1e2,-3"], "pivot", [-0.5, 100, -3]),
    (["render", "--out", "x.png", "--head=-120,40,650"], "head", [-120, 40, 650]),
    (["render", "--out", "x.png", "--head", "-120,-40,650"], "head", [-120, -40, 650]),
    (["render", "--out", "x.png", "--poi", "-5,-3"], "poi", [-5, -3]),
    (["render", "--out", "x.png", "--cov", "-1,0.5,2"], "cov", [-1, 0.5, 2]),
    (["render", "--out", "x.png", "--level-bias", "-1"], "level_bias", -1.0),
    (["bench", "plod", "--level-bias", "-0.5"], "level_bias", -0.5),
])
def test_coordinates_may_be_negative_in_either_spelling(argv, dest, expected):
    from headplod.argtypes import attach_negative_lists
    args = cli.build_parser().parse_args(attach_negative_lists(argv))
    value = getattr(args, dest)
    assert (list(value) if hasattr(value, "__len__") else value) == expected


def test_a_negative_pivot_runs_through_main(tmp_path, monkeypatch, capsys):
    """``headplod track --udp H --pivot -10,-80,-90`` reaches the run with the pivot (the source is refused after)."""
    assert cli.main(["track", "--udp", "127.0.0.1:9", "--pivot", "-10,-80,-90", "--source", str(tmp_path / "no"),
                     "-q"]) == 1
    err = capsys.readouterr().err
    assert "expected one argument" not in err and "--pivot" not in err


def test_track_and_preview_ask_the_cameras_alike_and_say_how_to_set_them(capsys):
    """One declaration of --fps/--fourcc/--exposure/--gain (capture.command.add_camera_settings) for every command
    that opens cameras: the same checks, and the advice the issue found missing."""
    import pytest

    parser = cli.build_parser()
    for command in ("track", "preview"):
        with pytest.raises(SystemExit) as stop:
            parser.parse_args([command, "--fps", "0"])
        assert stop.value.code == 2
        assert "a frame rate is above 0" in capsys.readouterr().err
        helps = {a.dest: a.help for a in parser._subparsers._group_actions[0].choices[command]._actions}
        assert "saturated" in helps["exposure"] and "noise" in helps["gain"]
    assert parser.parse_args(["track"]).fps == 60.0 and parser.parse_args(["preview"]).fps is None
