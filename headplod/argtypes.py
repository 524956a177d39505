"""Value types of the command line's options, shared by the commands (argparse ``type=``)."""
from __future__ import annotations

import argparse
import difflib
import math
import re
import sys

__all__ = ["cache_mb", "floats", "frame_count", "max_level", "non_negative", "level_bias", "triangle_budget",
           "gaze_prior", "attach_negative_lists", "note_old_spelling", "add_quiet_argument", "CommandParser"]

#: What ``-q`` means, for every command.
QUIET_HELP = "no progress and no notes on standard error (errors and the requested output still appear)"


def add_quiet_argument(parser, help: str = QUIET_HELP, below: bool = False) -> None:
    """``-q/--quiet`` on ``parser`` (dest ``quiet``). ``below``: a subcommand of a parser that has it too (its
    default is then SUPPRESS, so ``headplod bench -q live`` and ``headplod bench live -q`` both mean it)."""
    parser.add_argument("--quiet", "-q", action="store_true", default=argparse.SUPPRESS if below else False,
                        help=help)


def note_old_spelling(old: str, new: str) -> None:
    """The one-line note (standard error) for an old spelling that still works: what to write instead, and
    that it goes. Printed even with ``-q`` (it is about the command line, not the run). ``synthetic/`` writes
    the same line itself (it never imports headplod)."""
    print(f"note: {old} is now {new}; the old spelling goes in the next release", file=sys.stderr)


def floats(n: int):
    """An argparse type: ``n`` comma-separated finite numbers, as a tuple of floats."""
    def parse(text: str):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated numbers, got {text!r}")
        if len(values) != n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"expected {n} comma-separated finite numbers, got {text!r}")
        return tuple(values)
    return parse


def frame_count(text: str) -> int:
    """An argparse type: a number of frames, a whole number of at least 1 (0 or -1 would run nothing)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of frames, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1 frame, got {value}")
    return value


def non_negative(text: str) -> float:
    """An argparse type: a finite number of at least 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {text!r}")
    return value


def readout_ms(text: str) -> float:
    """An argparse type: a rolling shutter's readout in ms (first row to last), 0 to 1000 (0: a global shutter)."""
    value = non_negative(text)
    if not value < 1000.0:
        raise argparse.ArgumentTypeError(f"a readout is under a second (a frame's rows), got {text!r} ms")
    return value


#: Levels ``--max-level`` accepts (as :data:`headplod.render.still.MAX_LEVELS`; kept here so the parser
#: does not import the renderer).
MAX_LEVEL_RANGE = (1, 8)


def max_level(text: str) -> int:
    """An argparse type: the finest PLOD level, a whole number in 1..8 (8: 134 M triangles at full detail)."""
    lo, hi = MAX_LEVEL_RANGE
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number {lo}..{hi}, got {text!r}") from None
    if not lo <= value <= hi:
        raise argparse.ArgumentTypeError(f"must lie in {lo}..{hi} (5: the default 1025 x 1025 mesh; each level "
                                         f"doubles the samples per side), got {value}")
    return value


def cache_mb(text: str) -> float:
    """An argparse type: a cache budget in MB, a finite number from 1 to 65536."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of MB, got {text!r}") from None
    if not (math.isfinite(value) and 1 <= value <= 65536):
        raise argparse.ArgumentTypeError(f"must lie in 1..65536 MB, got {text!r}")
    return value


def level_bias(text: str) -> float:
    """An argparse type: a bias on every continuous level, levels, a finite number within ±8 (the finest mesh
    has 8 levels: beyond that every triangle is at one end)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of levels, got {text!r}") from None
    if not (math.isfinite(value) and abs(value) <= 8):
        raise argparse.ArgumentTypeError(f"expected a number of levels in -8..8, got {text!r}")
    return value


def triangle_budget(text: str) -> int:
    """An argparse type: a triangle budget, a whole number of at least 1 (``1e5`` and ``100_000`` read too)."""
    try:
        value = float(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of triangles, got {text!r}") from None
    if not (math.isfinite(value) and value == int(value) and value >= 1):
        raise argparse.ArgumentTypeError(f"expected a whole number of triangles >= 1, got {text!r}")
    return int(value)


#: The largest σ ``--gaze-prior`` accepts, deg (as :data:`headplod.plod.select.MAX_GAZE_PRIOR_DEG`, which
#: SelectorConfig checks; kept here so the parser's types import nothing of the library; a test checks they agree).
MAX_GAZE_PRIOR_DEG = 45.0


def gaze_prior(text: str) -> tuple[float, float]:
    """An argparse type: the σ of the eyes' offset in the head, ``SH,SV`` (horizontal, vertical) deg, two finite
    numbers in 0..:data:`MAX_GAZE_PRIOR_DEG` (``0,0``: the head alone, the paper's view); a tuple of two floats
    (:attr:`headplod.plod.select.SelectorConfig.gaze_prior_deg`)."""
    expected = (f"expected SH,SV: two σ in 0..{MAX_GAZE_PRIOR_DEG:g} deg, horizontal and vertical "
                "(0,0: the head alone)")
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}") from None
    if len(values) != 2 or not all(math.isfinite(v) and 0 <= v <= MAX_GAZE_PRIOR_DEG for v in values):
        raise argparse.ArgumentTypeError(f"{expected}, got {text!r}")
    return tuple(v + 0.0 for v in values)           # -0 reads as 0


#: A comma-separated list of numbers that starts with a minus sign ("-120,40,650", "-0.5,1e3"): never an option.
_NEGATIVE_LIST = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(,[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)+$")


def attach_negative_lists(argv):
    """``argv`` (list of str) with each long option followed by a negative number list joined to it
    (``--head -120,40,650`` → ``--head=-120,40,650``).

    argparse reads a token that starts with ``-`` as an option unless it is a single negative number, so a
    coordinate list starting with a negative value needed the ``=`` form ("expected one argument").
    """
    argv = list(argv)
    out = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if (token.startswith("--") and "=" not in token and i + 1 < len(argv)
                and _NEGATIVE_LIST.match(argv[i + 1])):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


# ---------------------------------------------------------------------------
# usage errors: one line, a "did you mean", and where the help is
# ---------------------------------------------------------------------------

def _did_you_mean(word: str, candidates) -> str:
    """``, did you mean X?`` for the candidate closest to ``word`` (difflib's ratio), or ``""``."""
    close = difflib.get_close_matches(word, [str(c) for c in candidates], n=1)
    return f", did you mean {close[0]}?" if close else ""


class _Subcommands(argparse._SubParsersAction):
    """The subparsers' action: what the chosen subcommand did not recognise is refused by that subcommand's
    parser (``headplod track: error: unknown option --sorce``), not by the top level's."""

    def __call__(self, parser, namespace, values, option_string=None):
        super().__call__(parser, namespace, values, option_string)
        extras = getattr(namespace, argparse._UNRECOGNIZED_ARGS_ATTR, None)
        if extras:
            self.choices[values[0]].error(self.choices[values[0]].unrecognized(extras))


class CommandParser(argparse.ArgumentParser):
    """The command line's parser (every subcommand's too, by inheritance): a usage error is one line on
    standard error, ``PROG: error: WHAT[, did you mean X?] see PROG --help``, exit status 2, instead of
    argparse's usage block before it. An unknown option is refused by the subcommand it was given to, with
    the closest option; an invalid choice (of an option or of a subcommand) with the closest choice.
    ``--help`` is argparse's own."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.register("action", "parsers", _Subcommands)

    def error(self, message: str):
        for action in self._actions:        # no command: name them (argparse's usage, which did, is not shown)
            if (isinstance(action, argparse._SubParsersAction)
                    and message == f"the following arguments are required: {action.dest}"):
                message = f"give a command: {', '.join(action.choices)}"
        self.exit(2, f"{self.prog}: error: {message}{' ' if message.endswith('?') else '; '}see {self.prog} --help\n")

    def _check_value(self, action, value):
        if action.choices is None or value in action.choices:
            return
        if isinstance(action, argparse._SubParsersAction):
            raise argparse.ArgumentError(None, f"unknown command {value!r} (one of {', '.join(action.choices)})"
                                               f"{_did_you_mean(value, action.choices)}")
        choices = ", ".join(map(repr, action.choices))
        raise argparse.ArgumentError(action, f"invalid choice: {value!r} (choose from {choices})"
                                             f"{_did_you_mean(value, action.choices)}")

    def unrecognized(self, extras) -> str:
        """The message for arguments this parser does not take: the first unknown option, with the closest
        of this parser's options; else the unexpected values."""
        for token in extras:
            if token.startswith("-") and not self._negative_number_matcher.match(token):
                option = token.split("=", 1)[0]
                return f"unknown option {option}{_did_you_mean(option, self._option_string_actions)}"
        return f"unexpected argument{'s' if len(extras) > 1 else ''}: {' '.join(extras)}"

    def parse_args(self, args=None, namespace=None):
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            self.error(self.unrecognized(extras))
        return namespace


def threshold_dn(text: str) -> float | None:
    """A detection threshold: ``adaptive`` (None: from each image's background) or DN in (0, 255)."""
    if text == "adaptive":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"threshold must be 'adaptive' or a number of DN, got {text!r}")
    if not 0 < value < 255:
        raise argparse.ArgumentTypeError(f"threshold must lie between 0 and 255 DN, got {value}")
    return value
