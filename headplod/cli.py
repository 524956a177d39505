"""The ``headplod`` command.

The parser and a table of commands (:data:`COMMANDS`); each command's options and body live
in its package (``live/command.py``, ``bench/command.py``, ``demo/cli.py``, ...).

    headplod doctor [--calib rig.yaml] [--source SPEC] [-q]
    headplod track [--source SPEC] [--out FILE|-] [--estimator reproj|rigid|paper] ...
    headplod preview [--source SPEC] [--calib rig.yaml] [--out DIR [--frames N]] [-q]
    headplod demo [--source SPEC | --mouse] [--headless --frames N --out DIR] ...
    headplod bench track|uncertainty|plod|live ...
    headplod calibrate --source FOLDER|v4l2:LEFT,RIGHT --cols N --rows M --square-mm S --out rig.yaml
    headplod cameras [--store --source v4l2:LEFT,RIGHT --rig rig.yaml]
    headplod synth PRESET --out DIR [--frames N] [--seed S] [-q]
    headplod board --cols N --rows M --square-mm S [--board chessboard|charuco] [--paper a4|letter] --out FILE
    headplod glasses [--markers markers.yaml] [--marker-mm D] [--yaml markers.yaml] --out FILE.pdf|.png|.svg

Every command takes ``-q`` (no progress and no notes on standard error) and ``--config FILE`` /
``--no-config``: the options a person types every day come from ``./headplod.toml`` or
``~/.config/headplod/config.toml`` (:mod:`headplod.config`; the command line wins over it).

Exit status: 0 on success, 1 when the run failed (bad files), 2 on bad usage.
"""
from __future__ import annotations

import argparse
import atexit
import os
import shutil
import sys
import tempfile
from pathlib import Path

from synthetic.cli import add_render_arguments as add_synth_arguments
from synthetic.cli import run_render as run_synth

from . import cache, config, io, streams
from .argtypes import CommandParser, attach_negative_lists
from .io.files import OutputRefused
from .bench.command import add_bench_arguments, run_bench
from .calibration.command import add_calibrate_arguments, run_calibrate
from .calibration.printouts import add_board_arguments, add_glasses_arguments, run_board, run_glasses
from .capture.command import add_cameras_arguments, run_cameras
from .demo.cli import add_demo_arguments, run_demo
from .doctor import add_doctor_arguments, run_doctor
from .live.command import add_track_arguments, run_track
from .live.pivot_command import add_pivot_arguments, run_pivot
from .live.preview import add_preview_arguments, run_preview
from .progress import quiet
from .render.command import add_render_arguments, run_render
from .render.context import GLContextError

#: ``headplod NAME``: (help, add NAME's arguments to its subparser, run(args) -> exit status), in --help's order.
COMMANDS = {
    "doctor": ("check this machine for webcam tracking: video devices, permissions, formats, USB identity, "
               "libusb, the rig, EGL; one line and a fix per check", add_doctor_arguments, run_doctor),
    "track": ("track a frame source: a dataset folder, videos, live cameras or the built-in synthetic sequence",
              add_track_arguments, run_track),
    "pivot": ("measure the head's pivot (the neck) from head turns, for track --udp", add_pivot_arguments, run_pivot),
    "cameras": ("list the video devices with their USB identity", add_cameras_arguments, run_cameras),
    "preview": ("both cameras side by side: threshold, blobs, markers, epipolar lines, rate, skew and advice",
                add_preview_arguments, run_preview),
    "calibrate": ("stereo calibration from chessboard/ChArUco pairs -> rig.yaml", add_calibrate_arguments,
                  run_calibrate),
    "board": ("print a calibration board at true scale (the --cols/--rows/--square-mm calibrate takes) -> PDF/PNG/SVG",
              add_board_arguments, run_board),
    "glasses": ("print a 1:1 template of the glasses' five markers, and its markers.yaml", add_glasses_arguments,
                run_glasses),
    "bench": ("benchmarks: accuracy against speed", add_bench_arguments, run_bench),
    "render": ("render one PLOD frame of the terrain to an image", add_render_arguments, run_render),
    "demo": ("head-coupled PLOD terrain viewer (a window, or --headless)", add_demo_arguments, run_demo),
    "synth": ("render a synthetic dataset folder (the same as 'python -m synthetic render')",
              add_synth_arguments, run_synth),
}


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="headplod", description=__doc__.split("\n")[0] + " Stereo IR head tracking.")
    config.add_config_arguments(parser)
    sub = parser.add_subparsers(dest="command", required=True)
    for name, (help_text, add_arguments, _) in COMMANDS.items():
        add_arguments(sub.add_parser(name, help=help_text))
    _add_config_arguments_below(sub)
    return parser


def _add_config_arguments_below(sub: argparse._SubParsersAction) -> None:
    """``--config FILE`` and ``--no-config`` on every subcommand, at every depth (``bench live`` too): whatever
    command the table holds, now or later, takes them."""
    for parser in sub.choices.values():
        if "--config" not in parser._option_string_actions:
            config.add_config_arguments(parser)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                _add_config_arguments_below(action)


def main(argv=None) -> int:
    # First, before anything opens a file: a closed standard descriptor gets /dev/null, so that no file
    # takes descriptor 2 (and C libraries' messages); then messages that cannot be written are dropped.
    at_start = streams.reopen_closed()
    streams.print_names_as_they_are()
    with streams.dropping_stderr():
        return _main(argv, at_start)


def _main(argv, at_start: streams.StandardStreams) -> int:
    try:
        os.getcwd()
    except FileNotFoundError:
        print("headplod: the current folder no longer exists (it was deleted); cd into a folder that exists "
              "and run the command again", file=sys.stderr)
        return 2
    _keep_libraries_caches_in_ours()
    # "--head -120,40,650": a list starting with a minus sign is the option's value, not another option.
    # The config file (headplod.toml) fills in what the command line does not give.
    args = config.parse_args(build_parser(), attach_negative_lists(sys.argv[1:] if argv is None else argv))
    refused = _closed_stream_option(args, at_start)
    if refused:
        print(f"headplod: {refused}", file=sys.stderr)
        return 2
    try:
        with quiet(getattr(args, "quiet", False)):      # -q: no progress, no notes, however deep in the command
            return COMMANDS[args.command][2](args)
    except (io.ContractError, GLContextError) as exc:      # a broken file; no OpenGL context (EGL): a failed run
        print(f"headplod: {exc}", file=sys.stderr)
        return 1
    except (OutputRefused, cache.CacheUnusable) as exc:  # a writer's own refusal (its command checks first)
        print(f"headplod: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("headplod: interrupted", file=sys.stderr)
        return 130


def _closed_stream_option(args, at_start: streams.StandardStreams) -> str | None:
    """Why an option naming a standard stream that was closed at the start cannot be used (``--out -`` with
    standard output closed: the records would go to /dev/null), or None."""
    for dest, value in vars(args).items():
        if not isinstance(value, str):
            continue
        what = at_start.closed_stream_named(value, dash=1 if dest == "out" else None)
        if what:
            option = f"--{dest.replace('_', '-')}"
            return (f"{option} {value}: {what} is closed; give {option} FILE, or run the command with its {what} "
                    "open (a pipe or a file)")
    return None


#: The libraries that keep a cache of their own in the home folder, and the environment variables that move
#: it: {folder in headplod's cache: variables}. matplotlib's font cache (~/.config/matplotlib or
#: ~/.cache/matplotlib); Mesa's shader cache (~/.cache/mesa_shader_cache, made by the first OpenGL context:
#: MESA_SHADER_CACHE_DIR since Mesa 20.3, MESA_GLSL_CACHE_DIR before; Mesa makes mesa_shader_cache inside).
LIBRARY_CACHES = {"matplotlib": ("MPLCONFIGDIR",),
                  "mesa": ("MESA_SHADER_CACHE_DIR", "MESA_GLSL_CACHE_DIR")}


def _keep_libraries_caches_in_ours() -> None:
    """Point each library's cache (:data:`LIBRARY_CACHES`) into the command's own cache folder
    (:mod:`headplod.cache`), before anything imports matplotlib or makes an OpenGL context: the home folder
    gets nothing but ~/.cache/headplod. A library whose variables the user set any of is left as set. When
    the cache cannot be used, a temporary folder removed at exit: matplotlib would otherwise advise setting
    MPLCONFIGDIR, a variable the user never set (a command that needs the cache says what is wrong with it,
    naming HEADPLOD_CACHE)."""
    wanted = {name: variables for name, variables in LIBRARY_CACHES.items()
              if not any(variable in os.environ for variable in variables)}
    if not wanted:
        return
    try:                                    # once: it makes the folder and tries a file in it
        root = cache.usable_cache_root()
    except cache.CacheUnusable:
        root = None
    for name, variables in wanted.items():
        folder = _library_cache_folder(root, name)
        if folder is not None:
            for variable in variables:
                os.environ[variable] = str(folder)


def _library_cache_folder(root: Path | None, name: str) -> Path | None:
    """``root / name``, made; or, with no usable cache (``root`` None) or when that fails, a temporary folder
    removed at exit; None when neither can be made."""
    if root is not None:
        try:
            folder = root / name
            folder.mkdir(exist_ok=True)
            return folder
        except OSError:
            pass
    try:
        folder = Path(tempfile.mkdtemp(prefix=f"headplod-{name}-"))
    except OSError:
        return None
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder

if __name__ == "__main__":
    sys.exit(main())
