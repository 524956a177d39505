"""The config file (issue 25, headplod/config.py): lookup order, precedence, one-line errors, ``track`` with no
arguments."""
import argparse

import numpy as np
import pytest

from headplod import cli, config


@pytest.fixture
def home(tmp_path, monkeypatch):
    """An empty current folder and XDG folder: no config file anywhere until a test writes one."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    return tmp_path


def _write(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _parse(argv):
    return config.parse_args(cli.build_parser(), argv)


# ---------------------------------------------------------------------------
# where the file is
# ---------------------------------------------------------------------------

def test_lookup_order_is_explicit_then_current_folder_then_xdg(home, monkeypatch):
    xdg = _write(home / "xdg" / "headplod" / "config.toml", 'source = "synthetic:from_xdg"\n')
    assert config.find_config() == xdg
    assert _parse(["track"]).source == "synthetic:from_xdg"
    cwd = _write(home / "work" / "headplod.toml", 'source = "synthetic:from_cwd"\n')
    assert config.find_config() == cwd
    assert _parse(["track"]).source == "synthetic:from_cwd"
    mine = _write(home / "elsewhere.toml", 'source = "synthetic:explicit"\n')
    assert _parse(["track", "--config", str(mine)]).source == "synthetic:explicit"
    assert _parse(["--config", str(mine), "track"]).source == "synthetic:explicit"       # top level too
    assert _parse(["track", "--no-config"]).source is None
    monkeypatch.delenv("XDG_CONFIG_HOME")                   # the default: ~/.config/headplod/config.toml
    monkeypatch.setenv("HOME", str(home / "h"))
    assert config.user_config_path() == home / "h" / ".config" / "headplod" / "config.toml"
    monkeypatch.setenv("XDG_CONFIG_HOME", "relative/dir")   # ignored, as the XDG spec says
    assert config.user_config_path() == home / "h" / ".config" / "headplod" / "config.toml"


def test_no_file_changes_nothing(home):
    args = _parse(["track"])
    assert args.source is None and args.udp is None and args.fps == 60.0


def test_a_missing_explicit_file_and_both_config_options_are_usage_errors(home, capsys):
    with pytest.raises(SystemExit) as stop:
        _parse(["track", "--config", "nope.toml"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nope.toml" in err and "no such file" in err
    _write(home / "work" / "headplod.toml", 'source = "synthetic"\n')
    with pytest.raises(SystemExit) as stop:
        _parse(["track", "--config", "headplod.toml", "--no-config"])
    assert stop.value.code == 2


# ---------------------------------------------------------------------------
# precedence: the command line, then the file, then the default
# ---------------------------------------------------------------------------

CONFIG = '''
source = "v4l2:auto"
calib = "rig.yaml"

[track]
udp = "127.0.0.1:5555"
pivot = [-10, -80, -90]
filter = [2.0, 0.05]
fps = 30
fourcc = "mjpg"
udp-axes = "opencv"

[demo]
source = "synthetic:static"
'''


def test_the_command_line_wins_over_the_file_which_wins_over_the_default(home):
    _write(home / "work" / "headplod.toml", CONFIG)
    args = _parse(["track"])
    assert args.source == "v4l2:auto" and args.calib == str(home / "work" / "rig.yaml")
    assert args.udp == "127.0.0.1:5555" and list(args.pivot) == [-10, -80, -90]
    assert args.filter == "2.0,0.05" and args.fps == 30.0 and args.fourcc == "MJPG" and args.udp_axes == "opencv"
    assert args.estimator == "reproj"                       # not in the file: the default
    args = _parse(["track", "--udp", "otherhost", "--fps", "15", "--pivot", "0,-70,-80", "--filter", "1,0.01",
                   "--calib", "mine.yaml", "--source", "v4l2:0,2", "--udp-axes", "tracker-pt"])
    assert args.udp == "otherhost" and args.fps == 15.0 and list(args.pivot) == [0, -70, -80]
    assert args.filter == "1,0.01" and args.calib == "mine.yaml" and args.source == "v4l2:0,2"
    assert args.udp_axes == "tracker-pt"                    # given as the default's value: still the command line's
    assert _parse(["demo"]).source == "synthetic:static"    # the command's table over the top level
    assert _parse(["pivot"]).source == "v4l2:auto"          # the top level for every command that has the key
    assert _parse(["preview"]).source == "v4l2:auto"
    assert _parse(["track", "--no-config"]).udp is None


def test_the_rig_and_camera_keys_apply_to_live_cameras_and_pivot_goes_with_udp(home):
    _write(home / "work" / "headplod.toml", 'calib = "/r/rig.yaml"\nmarkers = "/r/m.yaml"\n'
                                             '[track]\nfps = 30\npivot = "0,-80,-90"\n')
    ds = _parse(["track", "--source", str(home)])           # a dataset keeps its own rig, glasses, rate
    assert ds.calib is None and ds.markers is None and ds.fps == 60.0 and ds.pivot is None
    live = _parse(["track", "--source", "v4l2:0,2", "--udp", "h"])
    assert live.calib == "/r/rig.yaml" and live.markers == "/r/m.yaml" and live.fps == 30.0
    assert list(live.pivot) == [0, -80, -90]
    assert _parse(["glasses", "--out", "g.pdf"]).markers == "/r/m.yaml"


def test_filter_takes_true_false_arrays_and_text(home):
    path = home / "work" / "headplod.toml"
    for value, expected in (("true", "1.0,0.02"), ("false", None), ("[1, 0.5]", "1,0.5"), ('"3,0.1"', "3,0.1")):
        _write(path, f"[track]\nfilter = {value}\n")
        assert _parse(["track"]).filter == expected, value


def test_an_old_spelling_on_the_command_line_wins_over_the_files_source(home, sample, capsys):
    _write(home / "work" / "headplod.toml", 'source = "synthetic"\n')
    args = _parse(["track", str(sample)])
    assert args.source is None and args.dataset == str(sample)      # not "named twice"
    assert _parse(["track", "--camera", "0", "2"]).source is None


def test_the_note_names_the_file_and_keys_unless_quiet(home, capsys):
    path = _write(home / "work" / "headplod.toml", CONFIG)
    _parse(["track", "--udp", "h"])
    assert capsys.readouterr().err.splitlines() == [f"config: {path} (source, calib, pivot, udp-axes, filter, fps, "
                                                    "fourcc)"]
    _parse(["track", "-q"])
    assert capsys.readouterr().err == ""
    _parse(["render", "--out", "x.png"])                   # read, but nothing in it for render
    assert capsys.readouterr().err == ""


def test_relative_paths_are_from_the_files_folder(home):
    path = _write(home / "cfg" / "c.toml", 'source = "rec/ds"\ncalib = "~/rig.yaml"\n[demo]\nsource = "a.avi,b.avi"\n'
                                           '[preview]\nsource = "v4l2:0,2"\ncalib = "rig.yaml"\n')
    assert _parse(["track", "--config", str(path)]).source == str(home / "cfg" / "rec" / "ds")
    assert _parse(["demo", "--config", str(path)]).source == f"{home / 'cfg' / 'a.avi'},{home / 'cfg' / 'b.avi'}"
    preview = _parse(["preview", "--config", str(path)])
    assert preview.source == "v4l2:0,2" and preview.calib == str(home / "cfg" / "rig.yaml")


# ---------------------------------------------------------------------------
# a file that cannot be used: one line naming the file and the key, exit 2, nothing written
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("text, key, words", [
    ('sourse = "x"\n', "sourse", "unknown key"),
    ('[track]\nudp_axes = "opencv"\n', "udp_axes", "did you mean udp-axes"),
    ('[track]\nestimator = "rigid"\n', "estimator", "unknown key"),
    ('[render]\nudp = "h"\n', "udp", "not a key of 'headplod render'"),
    ('[trak]\nudp = "h"\n', "[trak]", "no such command"),
    ('[board]\ncols = 9\n', "[board]", "takes no config keys"),
    ('track = 5\n', "track", "a [track] table"),
    ('source = 5\n', "source", "expected a string"),
    ('[track]\nfps = "fast"\n', "fps", "expected a frame rate in Hz"),
    ('[track]\nfps = [1, 2]\n', "fps", "expected a number"),
    ('[track]\npivot = [1, 2]\n', "pivot", "X,Y,Z"),
    ('[track]\npivot = ["a", 2, 3]\n', "pivot", "array of numbers"),
    ('[track]\nfilter = [1, 2, 3]\n', "filter", "2 comma-separated"),
    ('[track]\nudp = "h:99999"\n', "udp", "port"),
    ('[track]\nudp-axes = "sideways"\n', "udp-axes", "tracker-pt, opencv"),
    ('[track]\nfourcc = "NOPE"\n', "fourcc", "is not one of"),
    ('[demo]\nsource = "x"\nbogus = 1\n', "bogus", "unknown key"),      # another command's table: checked too
    ('[track\n', "headplod.toml", "not valid TOML"),
])
def test_a_bad_file_is_one_line_and_exit_2_before_anything_is_written(home, text, key, words, capsys):
    path = _write(home / "work" / "headplod.toml", text)
    out = home / "work" / "poses.jsonl"
    with pytest.raises(SystemExit) as stop:
        cli.main(["track", "--source", "synthetic", "--out", str(out)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("headplod: config ") and str(path) in err, err
    assert key in err and words in err, err
    assert not out.exists()
    assert cli.main(["track", "--no-config", "--source", "nothing/here"]) == 1     # --no-config: not read
    capsys.readouterr()


def test_a_command_without_config_keys_does_not_read_the_file(home, capsys):
    _write(home / "work" / "headplod.toml", "this is not toml\n")
    args = _parse(["board", "--cols", "9", "--rows", "6", "--square-mm", "25", "--out", "b.pdf"])
    assert args.cols == 9 and capsys.readouterr().err == ""


# ---------------------------------------------------------------------------
# the declaration and the parsers agree
# ---------------------------------------------------------------------------

def test_every_key_is_an_option_of_a_command_it_names_and_checks_like_it():
    parser = cli.build_parser()
    commands = config._subparsers(parser)
    for name, key in config.KEYS.items():
        takers = [c for c in key.commands if c in commands and config._action(commands[c], name) is not None]
        assert takers, f"config key {name}: no command has --{name}"
        assert key.meaning and key.kind in ("text", "address", "path", "source", "number", "numbers",
                                            "numbers-or-flag")
        dests = {config._action(commands[c], name).dest for c in takers}
        assert dests == {name.replace("-", "_")}, name


def test_every_command_that_tracks_a_head_takes_the_source_and_rig_keys():
    commands = config._subparsers(cli.build_parser())
    for name in ("track", "pivot", "demo", "preview"):
        if name in commands:
            assert {"source", "calib"} <= set(config._command_keys(name, commands[name])), name


def test_every_subcommand_takes_config_and_no_config():
    def walk(parser, path=()):
        yield path, parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk(sub, path + (name,))

    for path, parser in walk(cli.build_parser()):
        assert {"--config", "--no-config"} <= set(parser._option_string_actions), path


# ---------------------------------------------------------------------------
# headplod track with no arguments
# ---------------------------------------------------------------------------

def test_track_with_no_arguments_tracks_the_configs_source(home, sample, capsys):
    path = _write(home / "work" / "headplod.toml", f'source = "{sample}"\n[track]\nfilter = true\n')
    assert cli.main(["track"]) == 0
    err = capsys.readouterr().err
    assert f"config: {path} (source, filter)" in err.splitlines()
    assert f"{sample.name}: 12/12 frames tracked" in err
    args = _parse(["track"])
    assert args.source == str(sample) and args.filter == "1.0,0.02"
    assert np.isfinite(args.fps)
