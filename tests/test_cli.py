"""The ``headplod`` command line: one table of commands, one home per list of choices, the source's old spellings.

Nothing here tracks more than a couple of frames: the commands' own tests
(test_live, test_tracker, test_cli_rig, ...) run them in full.
"""
import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from headplod import cli
from headplod.calibration.board import BOARD_KINDS
from headplod.capture.v4l2 import FOURCCS
from headplod.cli import main as cli_main
from headplod.plod.select import MODES, UNCERTAINTY_MODES
from headplod.render.gl import VIEW_MODES
from headplod.render.frame import BACKENDS
from headplod.render.still import CONTRAST_SOURCES
from headplod.tracking.tracker import ESTIMATORS
from headplod.tracking.uncertainty import COVARIANCE_ESTIMATORS

ROOT = Path(__file__).resolve().parents[1]
NOTE_END = "the old spelling goes in the next release"


@pytest.fixture
def sample(tmp_path):
    dst = tmp_path / "ds"
    shutil.copytree(ROOT / "tests" / "data" / "sweep12", dst)
    return dst


def _choices(argv_prefix, option):
    """The choices argparse holds for ``option`` of the subcommand ``argv_prefix``."""
    parser = cli.build_parser()
    for name in argv_prefix:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[name]
    action = next(a for a in parser._actions if option in a.option_strings)
    return tuple(action.choices)


# ---------------------------------------------------------------------------
# the table
# ---------------------------------------------------------------------------

def test_every_command_has_a_run_and_the_parser_knows_each():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == list(cli.COMMANDS)
    for name, (help_text, add_arguments, run) in cli.COMMANDS.items():
        assert help_text and callable(add_arguments) and callable(run), name


def test_cli_keeps_no_function_local_imports():
    import ast
    tree = ast.parse((ROOT / "headplod" / "cli.py").read_text())
    local = [node.lineno for fn in ast.walk(tree) if isinstance(fn, ast.FunctionDef)
             for node in ast.walk(fn) if isinstance(node, (ast.Import, ast.ImportFrom))]
    assert not local, f"headplod/cli.py imports inside functions at lines {local}"


# ---------------------------------------------------------------------------
# one home per list of choices
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("argv, option, home", [
    (["track"], "--estimator", ESTIMATORS),
    (["track"], "--uncertainty", COVARIANCE_ESTIMATORS),
    (["track"], "--fourcc", FOURCCS),
    (["render"], "--mode", MODES),
    (["render"], "--backend", BACKENDS),
    (["render"], "--uncertainty", UNCERTAINTY_MODES),
    (["render"], "--view", tuple(VIEW_MODES)),
    (["render"], "--contrast", CONTRAST_SOURCES),
    (["calibrate"], "--board", BOARD_KINDS),
    (["demo"], "--mode", MODES),
    (["demo"], "--uncertainty", UNCERTAINTY_MODES),
    (["demo"], "--view", tuple(VIEW_MODES)),
])
def test_choices_come_from_their_home_module(argv, option, home):
    assert _choices(argv, option) == tuple(home)


@pytest.mark.parametrize("argv, option, home", [
    (["track"], "--estimator", ESTIMATORS),
    (["track"], "--uncertainty", COVARIANCE_ESTIMATORS),
    (["render", "--out", "x.png"], "--mode", MODES),
    (["render", "--out", "x.png"], "--view", tuple(VIEW_MODES)),
])
def test_an_invalid_choice_is_refused_with_the_home_modules_list(argv, option, home, capsys):
    with pytest.raises(SystemExit) as stop:
        cli_main([*argv, option, "no_such_thing"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    line = next(l for l in err.splitlines() if "invalid choice" in l)
    assert "'no_such_thing'" in line and option in line
    for name in home:
        assert repr(name) in line, (name, line)


def test_the_demo_keys_help_is_made_from_the_keymap(monkeypatch):
    from headplod.demo import hud, keys
    for key, (setting, value) in keys.KEYMAP.items():
        label = "Esc" if key == "escape" else key.upper()
        assert key.isdigit() or label in hud.KEY_HELP, (key, hud.KEY_HELP)
    assert f"1-{len(keys.DEMO_MODES)} criterion" in hud.KEY_HELP
    monkeypatch.setitem(keys.KEYMAP, "g", ("grid", "toggle"))        # a new key shows up in the help
    assert keys.key_help().endswith("  G grid")
    monkeypatch.delitem(keys.KEYMAP, "g")
    for mode in keys.DEMO_MODES:
        assert mode in hud.KEY_HELP
    assert set(keys.DEMO_MODES) <= set(MODES)
    for setting, value in keys.KEYMAP.values():
        if setting == "uncertainty":
            assert value in UNCERTAINTY_MODES
        if setting == "view_mode":
            assert value in VIEW_MODES
    demo = next(a for a in cli.build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices["demo"]
    assert keys.key_help(values=("mode", "uncertainty", "view_mode"), sep="; ") in demo.description


def test_bench_plod_compares_every_csf_model():
    from headplod.bench import plod as bench_plod
    from headplod.plod.csf import CSF_MODELS
    assert bench_plod.CSF_FORMS is CSF_MODELS


# ---------------------------------------------------------------------------
# naming a source: --source, and the old spellings with their note
# ---------------------------------------------------------------------------

def test_track_old_positional_dataset_still_works_and_says_the_new_spelling(sample, tmp_path, capsys):
    old, new = tmp_path / "old.jsonl", tmp_path / "new.jsonl"
    assert cli_main(["track", str(sample), "--frames", "2", "--out", str(old), "-q"]) == 0
    err = capsys.readouterr().err
    notes = [l for l in err.splitlines() if l.startswith("note:")]
    assert notes == [f"note: 'headplod track {sample}' is now 'headplod track --source {sample}'; {NOTE_END}"]
    assert cli_main(["track", "--source", str(sample), "--frames", "2", "--out", str(new), "-q"]) == 0
    assert "note:" not in capsys.readouterr().err
    strip = lambda path: [{k: v for k, v in json.loads(l).items() if k not in ("timings_ms", "latency_ms")}
                          for l in path.read_text().splitlines()]
    assert strip(old) == strip(new) and len(strip(new)) == 2


@pytest.mark.parametrize("camera, spec", [(["0", "2"], "v4l2:0,2"),
                                          (["/dev/video0", "/dev/video2"], "v4l2:/dev/video0,/dev/video2"),
                                          (["auto"], "v4l2:auto")])
def test_track_old_camera_spelling_says_the_new_one(camera, spec, capsys):
    # Without --calib both spellings stop at the same usage error, after the note (no camera is opened).
    assert cli_main(["track", "--camera", *camera]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == f"note: --camera {' '.join(camera)} is now --source {spec}; {NOTE_END}"
    assert "--calib" in err[1] and len(err) == 2
    assert cli_main(["track", "--source", spec]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "--calib" in err[0] and not err[0].startswith("note:")


def test_track_refuses_a_source_named_twice_and_a_bad_camera_count(sample, capsys):
    assert cli_main(["track", str(sample), "--source", "synthetic"]) == 2
    assert "named twice" in capsys.readouterr().err
    assert cli_main(["track", "--camera", "0"]) == 2
    assert "--camera takes LEFT RIGHT" in capsys.readouterr().err


def test_track_bad_udp_is_refused_before_the_output_is_touched(sample, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    assert cli_main(["track", "--source", str(sample), "--udp", "host:99999", "--out", str(out), "-q"]) == 2
    assert "port" in capsys.readouterr().err
    assert not out.exists()


def test_bench_live_old_positional_says_the_new_spelling_and_refuses_cameras(sample, capsys):
    assert cli_main(["bench", "live", "--source", "v4l2:0,2"]) == 2
    err = capsys.readouterr().err
    assert "replays a recording" in err and len(err.strip().splitlines()) == 1
    assert cli_main(["bench", "live", str(sample), "--source", str(sample)]) == 2
    assert "named twice" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# headplod synth is python -m synthetic render
# ---------------------------------------------------------------------------

SYNTH_ARGVS = [
    ["static", "OUT"],
    ["still", "OUT", "--frames", "3", "--seed", "7"],
    ["looking-around", "OUT", "-q"],
    ["dim_ir", "OUT", "--quiet", "--frames", "2"],
]


@pytest.mark.parametrize("argv", SYNTH_ARGVS)
def test_synth_and_python_m_synthetic_parse_the_same_arguments(argv):
    from synthetic.cli import build_parser
    ours = vars(cli.build_parser().parse_args(["synth", *argv]))
    theirs = vars(build_parser().parse_args(["render", *argv]))
    ours.pop("command"), theirs.pop("cmd")
    assert ours == theirs


@pytest.mark.parametrize("argv", [["no_such_preset", "OUT"], ["static", "OUT", "--frames", "0"],
                                  ["static", "OUT", "--seed", "x"], ["static"]])
def test_synth_and_python_m_synthetic_refuse_the_same_arguments(argv, capsys):
    from synthetic.cli import build_parser
    errors = []
    for parse in (lambda: cli.build_parser().parse_args(["synth", *argv]),
                  lambda: build_parser().parse_args(["render", *argv])):
        with pytest.raises(SystemExit) as stop:
            parse()
        assert stop.value.code == 2
        errors.append(capsys.readouterr().err.strip().splitlines()[-1].split("error: ", 1)[1])
    assert errors[0] == f"{errors[1]}; see headplod synth --help"     # headplod's one line says where the help is


def test_synth_and_python_m_synthetic_write_the_same_dataset(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    assert cli_main(["synth", "static", str(a), "--frames", "2", "--seed", "3", "-q"]) == 0
    capsys.readouterr()
    done = subprocess.run([sys.executable, "-m", "synthetic", "render", "static", str(b), "--frames", "2",
                           "--seed", "3"], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "wrote 2 stereo pairs" in done.stderr and "2/2" in done.stderr     # progress on stderr, tqdm's
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file()) and files
    for rel in files:
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


# ---------------------------------------------------------------------------
# progress
# ---------------------------------------------------------------------------

def test_progress_writes_counts_rate_and_label_as_lines_off_a_terminal():
    import io as _io
    from headplod.progress import Progress
    stream = _io.StringIO()
    bar = Progress(4, "render static", stream=stream, every_s=0.0, unit="frame")
    for k in range(4):
        bar.step(f"frame {k}")
    text = stream.getvalue()
    assert "\r" not in text
    last = text.strip().splitlines()[-1]
    assert last.startswith("render static:") and "4/4" in last and "frame/s" in last and "frame 3" in last
    quiet = _io.StringIO()
    bar = Progress(4, "x", stream=quiet, disable=True)
    bar.step()
    bar.close()
    assert quiet.getvalue() == ""


def test_track_quiet_prints_only_the_summary(sample, capsys):
    assert cli_main(["track", "--source", str(sample), "-q"]) == 0
    err = capsys.readouterr().err
    assert "frame " not in err and "it/s" not in err and "%|" not in err
    assert f"{Path(sample).name}: 12/12 frames tracked" in err


@pytest.mark.slow
def test_calibrate_runs_from_its_package_with_progress(tmp_path, capsys):
    from headplod import io
    from synthetic.boards import Board, write_calibration_set
    rig = io.read_rig(ROOT / "calib" / "rig.yaml")
    write_calibration_set(tmp_path / "pairs", rig, Board("chessboard", 9, 6, 25.0), n_pairs=8, seed=0,
                          layout="subfolders")
    out = tmp_path / "rig.yaml"
    assert cli_main(["calibrate", str(tmp_path / "pairs"), "--cols", "9", "--rows", "6", "--square-mm", "25",
                     "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert out.exists() and f"rig: {out}" in err
    progress = [l for l in err.splitlines() if l.startswith("detect board:")]
    assert progress and "8/8" in progress[-1] and "pair/s" in progress[-1]
    with pytest.raises(SystemExit) as stop:
        cli_main(["calibrate", "--board", "hexagons", "--cols", "9", "--rows", "6", "--square-mm", "25",
                  "--out", str(out)])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and "'hexagons'" in err and all(repr(k) in err for k in BOARD_KINDS)


def test_v4l2_auto_needs_the_rig_that_names_the_cameras():
    from headplod.capture import open_source, source_kind
    assert source_kind("v4l2:auto") == "v4l2"
    with pytest.raises(ValueError, match="--calib"):
        open_source("v4l2:auto")


@pytest.mark.slow
def test_the_command_keeps_matplotlib_in_its_own_cache(tmp_path, monkeypatch):
    """matplotlib's config and font cache go under HEADPLOD_CACHE, not the home folder (unless MPLCONFIGDIR is set)."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "MPLCONFIGDIR"}
    env.update(HEADPLOD_CACHE=str(tmp_path / "cache"), HOME=str(tmp_path / "home"))
    code = ("import os, sys; from headplod.cli import main\n"
            "try:\n    main(['render', '--size', '0,0', '--out', 'x.png'])\n"
            "finally:\n    print(os.environ['MPLCONFIGDIR'])")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == str(tmp_path / "cache" / "matplotlib")
    env["MPLCONFIGDIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == str(tmp_path / "mine")
