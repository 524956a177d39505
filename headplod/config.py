"""The config file: the options a person would otherwise type every day (issue 25).

A TOML file whose keys are option names without the dashes (``source``,
``calib``, ``udp-axes``), at the top level (shared: each applies to every
command of :data:`KEYS` that has that option) or in a table per command
(``[track]``, ``[pivot]``, ``[demo]``, ``[preview]``, ...), which wins over the top level::

    source = "v4l2:auto"
    calib = "rig.yaml"              # relative paths: from the config file's folder

    [track]
    udp = "127.0.0.1:4242"
    pivot = [0, -80, -90]
    filter = true                   # the default 1.0,0.02; or [1.0, 0.02], or "1.0,0.02"

    [demo]
    source = "synthetic"

The file is the first of (:func:`find_config`): ``--config FILE``; ``./headplod.toml``
in the current folder; ``$XDG_CONFIG_HOME/headplod/config.toml`` (default
``~/.config/headplod/config.toml``). ``--no-config`` reads none. Precedence: the
command line, then the file, then the built-in default. Only the keys of
:data:`KEYS` may appear, each only for its commands; every value goes through
the option's own check (its argparse ``type=`` and choices), so a value the
command line would refuse is refused here too. Anything wrong in the file is
one line naming the file and the key, and exit status 2, before anything is
read or written (:class:`ConfigError`). The file's keys that were used are
named on one line of standard error (``config: FILE (source, calib)``), not
with ``-q``. Only the commands that take a key read the file (``board``,
``synth``, ``bench``, ... never do; ``doctor`` takes ``source`` and ``calib`` and reports which file gave them).

Some keys apply only where they mean something (:attr:`Key.when`): ``calib``,
``markers``, ``screen`` and the camera settings only with live cameras
(``--source v4l2:...``, from the command line or the file), so a dataset folder
or the synthetic sequence keeps its own rig, glasses and screen; ``pivot`` and
``udp-axes`` only with ``udp``. A key given in its old spelling on the command
line (``headplod track DATASET``) wins over the file as ``--source`` would.
"""
from __future__ import annotations

import argparse
import os
import sys
try:
    import tomllib
except ModuleNotFoundError:          # Python 3.10: the same parser, as the tomli package (pyproject.toml)
    import tomli as tomllib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Mapping, Optional

from .argtypes import floats

__all__ = ["KEYS", "Key", "ConfigError", "CONFIG_NAME", "find_config", "read_config", "config_values",
           "parse_args", "add_config_arguments"]

#: The config file looked for in the current folder.
CONFIG_NAME = "headplod.toml"

#: The commands that read cameras or recordings (they share ``source`` and ``calib``; ``doctor`` checks them).
_TRACKERS = ("track", "pivot", "demo", "preview", "doctor")


def _udp_address(text: str) -> str:
    from .live.opentrack import parse_host_port     # on use: the config module stays light
    try:
        parse_host_port(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


@dataclass(frozen=True)
class Key:
    """One key of the config file: the option ``--NAME`` of ``commands``.

    ``kind`` is what TOML value it takes (besides the command line's text, always accepted): ``"text"``
    (a string only), ``"address"`` (a string, or a whole number: a port), ``"path"`` (a file: ``~`` expanded, relative to the config file's folder), ``"source"``
    (a source SPEC: its folder or files as for ``"path"``), ``"number"``, ``"numbers"`` (an array of
    numbers, joined with commas as on the command line), ``"numbers-or-flag"`` (also true: the option
    without a value; false: off). ``check`` validates the text when the option itself does not
    (it raises argparse.ArgumentTypeError).
    """

    meaning: str
    commands: tuple[str, ...]
    kind: str = "text"
    check: Optional[Callable[[str], object]] = None
    #: Options that name the same thing in an old spelling: given on the command line, the key is not applied.
    yields_to: tuple[str, ...] = ()
    #: When the key applies, from the parsed arguments (the command line's, and the keys without ``when``):
    #: None, always.
    when: Optional[Callable[[argparse.Namespace], bool]] = None


def _live_cameras(args) -> bool:
    """Whether the run reads live cameras (``--source v4l2:...``, or the old ``--camera``); True for a command
    that names no source (``glasses``, ``render``). The rig, glasses, screen and camera settings of the config
    file are for the person's own cameras: a dataset folder or the synthetic sequence keeps its own."""
    if not hasattr(args, "source"):
        return True
    if getattr(args, "command", None) == "doctor" and not args.source:
        return True             # doctor with no source checks the person's own cameras and rig
    if getattr(args, "camera", None):
        return True
    from .capture.sources import source_kind      # on use, as _udp_address: the config module stays light

    return source_kind(str(args.source or "")) == "v4l2"


def _with_udp(args) -> bool:
    """``--pivot`` and ``--udp-axes`` shape what ``--udp`` sends: without it they do not apply."""
    return bool(getattr(args, "udp", None))


#: The config file's keys, what they mean and which commands take them (a command not yet in the parser is
#: skipped). Per-user constants only: the cameras, their rig, the glasses, the screen, where poses go.
KEYS: Mapping[str, Key] = MappingProxyType({
    "source": Key("what to track: v4l2:auto (the cameras --calib names), v4l2:LEFT,RIGHT, a dataset folder, "
                  "LEFT.avi,RIGHT.avi or synthetic[:PRESET]", _TRACKERS, "source", yields_to=("dataset", "camera")),
    "calib": Key("rig.yaml of the cameras (with live cameras)", _TRACKERS, "path", when=_live_cameras),
    "markers": Key("markers.yaml of the glasses (with live cameras)", ("track", "pivot", "glasses", "preview"),
                   "path", when=_live_cameras),
    "screen": Key("screen.yaml of the screen, for the POI (with live cameras)", ("track", "render"), "path",
                  when=_live_cameras),
    "udp": Key("HOST[:PORT] or PORT of opentrack's 'UDP over network' input", ("track",), "address",
               check=_udp_address),
    "pivot": Key("the head's pivot X,Y,Z mm (head frame) sent with udp", ("track",), "numbers", when=_with_udp),
    "udp-axes": Key("the axes of the position sent with udp", ("track",), when=_with_udp),
    "filter": Key("One Euro filter MIN_CUTOFF,BETA on the poses (true: the default 1.0,0.02)", ("track",),
                  "numbers-or-flag", check=floats(2)),
    "fps": Key("camera frame rate to request", ("track", "preview"), "number", when=_live_cameras),
    "fourcc": Key("camera pixel format to request", ("track", "preview"), when=_live_cameras),
    "exposure": Key("manual exposure (V4L2 units)", ("track", "preview"), "number", when=_live_cameras),
    "gain": Key("camera gain (V4L2 units)", ("track", "preview"), "number", when=_live_cameras),
    "threshold": Key("blob threshold, DN, or 'adaptive' (with live cameras)", ("track", "preview"), "number",
                     when=_live_cameras),
})


class ConfigError(ValueError):
    """A config file that cannot be used; the message is one line naming the file and the key."""


# ---------------------------------------------------------------------------
# finding and reading the file
# ---------------------------------------------------------------------------

def user_config_path(environ: Mapping[str, str] | None = None) -> Path:
    """``$XDG_CONFIG_HOME/headplod/config.toml`` (an absolute XDG_CONFIG_HOME only, as the XDG spec says),
    else ``~/.config/headplod/config.toml``."""
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_CONFIG_HOME", "")
    root = Path(base) if base and Path(base).is_absolute() else Path.home() / ".config"
    return root / "headplod" / "config.toml"


def find_config(explicit: str | None = None, cwd: Path | None = None,
                environ: Mapping[str, str] | None = None) -> Path | None:
    """The config file to read: ``explicit`` (``--config FILE``; a missing one is a :class:`ConfigError`),
    else ``./headplod.toml``, else :func:`user_config_path`; None when there is none."""
    if explicit is not None:
        path = Path(explicit).expanduser()
        if not path.is_file():
            raise ConfigError(f"--config {explicit}: {'is a folder' if path.is_dir() else 'no such file'}")
        return path
    try:
        here = [(Path.cwd() if cwd is None else Path(cwd)) / CONFIG_NAME]
    except FileNotFoundError:                  # the current folder was deleted: there is no ./headplod.toml
        here = []
    for path in here + [user_config_path(environ)]:
        if path.is_file():
            return path
    return None


def read_config(path: Path) -> dict:
    """The TOML table of ``path``; a :class:`ConfigError` when it cannot be read or is not TOML."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({' '.join(str(exc).split())})") from None


# ---------------------------------------------------------------------------
# checking it against the parser
# ---------------------------------------------------------------------------

def _subparsers(parser: argparse.ArgumentParser) -> dict:
    """``{name: subparser}`` of ``parser``'s commands ({} without any)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _action(parser: argparse.ArgumentParser, key: str):
    """The action of ``--KEY`` in ``parser``, or None."""
    return parser._option_string_actions.get(f"--{key}")


def _type_name(value) -> str:
    return {bool: "true/false", int: "a number", float: "a number", str: "a string", list: "an array",
            dict: "a table"}.get(type(value), type(value).__name__)


def _as_text(key: Key, value, where: str, action, folder: Path) -> str | None:
    """The config value as the command line's text for the option (None: the option off), checked for its
    TOML type."""
    kind = key.kind
    if isinstance(value, bool):
        if kind == "numbers-or-flag":
            return action.const if value else None
        raise ConfigError(f"{where}: expected {_expected(kind)}, got {_type_name(value)}")
    if isinstance(value, int) and kind == "address":   # udp = 4242: a port on this machine, as --udp 4242
        return str(value)
    if isinstance(value, (int, float)) and kind in ("number", "numbers", "numbers-or-flag"):
        return repr(value) if isinstance(value, float) else str(value)
    if isinstance(value, list) and kind in ("numbers", "numbers-or-flag"):
        if not value or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            raise ConfigError(f"{where}: expected an array of numbers, got {value!r}")
        return ",".join(repr(v) if isinstance(v, float) else str(v) for v in value)
    if not isinstance(value, str):
        raise ConfigError(f"{where}: expected {_expected(kind)}, got {_type_name(value)}")
    if kind == "path":
        return str(_resolve(value, folder))
    if kind == "source":
        return _resolve_source(value, folder)
    return value


def _expected(kind: str) -> str:
    return {"text": "a string", "path": "a string (a file)", "source": "a string (a SPEC)",
            "address": "a string (HOST:PORT) or a port number",
            "number": "a number", "numbers": "an array of numbers (or a string as on the command line)",
            "numbers-or-flag": "true, false, an array of numbers or a string"}[kind]


def _resolve(text: str, folder: Path) -> Path:
    path = Path(text).expanduser()
    return path if path.is_absolute() else folder / path


def _resolve_source(spec: str, folder: Path) -> str:
    """A source SPEC with its folder or video files taken from the config file's folder (``~`` expanded);
    ``v4l2:...``, two device numbers and ``synthetic[:PRESET]`` as they are."""
    text = spec.strip()
    parts = [p.strip() for p in text.split(",")]
    if (text.lower().startswith("v4l2:") or text == "synthetic" or text.startswith("synthetic:")
            or all(p.isdigit() for p in parts)):
        return text
    return ",".join(str(_resolve(p, folder)) for p in parts)


def _convert(key: Key, text: str | None, where: str, action):
    """``text`` through the option's own type and choices (and the key's check): the parsed value."""
    if text is None:
        return None
    try:
        if key.check is not None:
            key.check(text)
        value = action.type(text) if callable(action.type) else text
    except (argparse.ArgumentTypeError, ValueError, TypeError) as exc:
        reason = " ".join(str(exc).split()) or "invalid value"
        raise ConfigError(f"{where}: {reason}" + ("" if text in reason else f" (got {text!r})")) from None
    if action.choices is not None and value not in action.choices:
        raise ConfigError(f"{where}: {text!r} is not one of {', '.join(map(str, action.choices))}")
    return value


def _unknown_key(name: str, where: str, known) -> ConfigError:
    hint = ""
    if name.replace("_", "-") in KEYS:
        hint = f"; did you mean {name.replace('_', '-')} (the option's spelling)?"
    return ConfigError(f"{where}: unknown key{hint or ' (the keys: ' + ', '.join(sorted(known)) + ')'}")


def config_values(table: Mapping, path: Path, parser: argparse.ArgumentParser, command: str) -> dict:
    """Check the whole file's ``table`` against ``parser`` (the ``headplod`` parser) and return what it gives
    ``command``: ``{dest: (key, parsed value)}``, its table's keys over the top level's.

    Raises :class:`ConfigError` (one line: the file, the key, what is wrong) for an unknown table or key, a
    key in the table of a command that does not take it, and a value of the wrong type or that the option
    refuses.
    """
    commands = _subparsers(parser)
    folder = path.expanduser().resolve().parent
    shared, tables = {}, {}
    for name, value in table.items():
        if isinstance(value, dict):
            if name not in commands or not _command_keys(name, commands[name]):
                what = "no such command" if name not in commands else f"'headplod {name}' takes no config keys"
                raise ConfigError(f"{path}: [{name}]: {what} (the tables: "
                                  f"{', '.join(c for c in commands if _command_keys(c, commands[c]))})")
            tables[name] = value
        elif name in commands:
            raise ConfigError(f"{path}: {name}: is a command; its keys go in a [{name}] table")
        else:
            shared[name] = value
    out = {}
    for name, value in shared.items():          # the top level: every command that has the option
        where = f"{path}: {name}"
        if name not in KEYS:
            raise _unknown_key(name, where, KEYS)
        users = [c for c in KEYS[name].commands if c in commands and _action(commands[c], name) is not None]
        for c in users:
            action = _action(commands[c], name)
            parsed = _convert(KEYS[name], _as_text(KEYS[name], value, where, action, folder), where, action)
            if c == command:
                out[action.dest] = (name, parsed)
    for c, entries in tables.items():
        known = _command_keys(c, commands[c])
        for name, value in entries.items():
            where = f"{path}: [{c}] {name}"
            if name not in KEYS:
                raise _unknown_key(name, where, known or KEYS)
            if name not in known:
                takers = [t for t in KEYS[name].commands if t in commands and name in _command_keys(t, commands[t])]
                raise ConfigError(f"{where}: not a key of 'headplod {c}' (it is of {', '.join(takers)}"
                                  f"{'; ' + c + ' takes ' + ', '.join(sorted(known)) if known else ''})")
            if isinstance(value, dict):
                raise ConfigError(f"{where}: expected {_expected(KEYS[name].kind)}, got a table")
            action = _action(commands[c], name)
            parsed = _convert(KEYS[name], _as_text(KEYS[name], value, where, action, folder), where, action)
            if c == command:
                out[action.dest] = (name, parsed)
    return out


def _command_keys(name: str, parser: argparse.ArgumentParser) -> list[str]:
    """The keys of :data:`KEYS` that ``headplod NAME`` takes (declared for it, and an option of its parser)."""
    return [k for k, key in KEYS.items() if name in key.commands and _action(parser, k) is not None]


# ---------------------------------------------------------------------------
# the command line's side
# ---------------------------------------------------------------------------

def add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config FILE`` and ``--no-config`` on ``parser`` (the top level and every subcommand). Their default is
    SUPPRESS: absent from the parsed arguments unless given, so ``headplod --config F track`` keeps F (a
    subcommand's default would overwrite it) and the commands' arguments are what they were."""
    parser.add_argument("--config", metavar="FILE", default=argparse.SUPPRESS,
                        help="read the options' values from this TOML file instead of ./headplod.toml or "
                             "~/.config/headplod/config.toml (the command line still wins over it)")
    parser.add_argument("--no-config", action="store_true", default=argparse.SUPPRESS,
                        help="read no config file")


def _command_of(parser: argparse.ArgumentParser, args) -> tuple[str | None, argparse.ArgumentParser | None]:
    """The command ``args`` runs and its subparser (top level only: the config file has one table a command)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            name = getattr(args, action.dest, None)
            return name, action.choices.get(name)
    return None, None


def _given(parser: argparse.ArgumentParser, sub: argparse.ArgumentParser, argv, dests) -> set:
    """Which of ``dests`` (options of ``sub``) the command line ``argv`` gives: parsed again with a marker as
    their default."""
    unset = object()
    actions = [a for a in sub._actions if a.dest in dests]
    saved = [(a, a.default) for a in actions]
    saved_defaults = dict(sub._defaults)
    try:
        for a in actions:
            a.default = unset
        for d in dests:
            sub._defaults.pop(d, None)
        probe = parser.parse_args(argv)
    finally:
        for a, d in saved:
            a.default = d
        sub._defaults.clear()
        sub._defaults.update(saved_defaults)
    return {a.dest for a in actions if getattr(probe, a.dest, unset) is not unset}


def parse_args(parser: argparse.ArgumentParser, argv, cwd: Path | None = None,
               environ: Mapping[str, str] | None = None, stream=None) -> argparse.Namespace:
    """``parser.parse_args(argv)`` with the config file's values for the options the command line did not give.

    A file that cannot be used is one line on standard error and ``SystemExit(2)``; the keys used are named on
    one line (``config: FILE (key, ...)``) unless ``-q``.
    """
    stream = sys.stderr if stream is None else stream
    args = parser.parse_args(argv)
    args.config_file, args.config_used = None, ()          # which file gave which keys (headplod doctor says)
    explicit = getattr(args, "config", None)
    if getattr(args, "no_config", False):
        if explicit is not None:
            parser.error("--config and --no-config: give one")
        return args
    command, sub = _command_of(parser, args)
    if sub is None or not _command_keys(command, sub):
        return args                             # a command that takes no config key does not read the file
    try:
        path = find_config(explicit, cwd=cwd, environ=environ)
        if path is None:
            return args
        values = config_values(read_config(path), path, parser, command)
    except ConfigError as exc:
        print(f"headplod: config {exc}", file=stream)
        raise SystemExit(2) from None
    args.config_file = path
    if not values:
        return args
    given = _given(parser, sub, argv, set(values))
    used = []
    for conditional in (False, True):           # the keys that always apply first: `when` reads them
        for dest, (name, value) in values.items():
            key = KEYS[name]
            if (key.when is not None) != conditional or dest in given:
                continue
            if any(getattr(args, old, None) for old in key.yields_to) or (key.when and not key.when(args)):
                continue
            setattr(args, dest, value)
            used.append(name)
    args.config_used = tuple(used)
    if used and not getattr(args, "quiet", False):
        order = list(KEYS)
        print(f"config: {path} ({', '.join(sorted(used, key=order.index))})", file=stream)
    return args

