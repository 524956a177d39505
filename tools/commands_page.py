"""Write docs/commands.md, every ``headplod`` command's usage, options and defaults, from the parser itself.

    python tools/commands_page.py            # writes docs/commands.md
    python tools/commands_page.py --check    # exit 1 when docs/commands.md is not what the parser gives

The page is made from :func:`headplod.cli.build_parser` (every subcommand, ``bench``'s included, each
option with its value, default and help, by the parser's own argument groups), so it cannot disagree with
``--help``; ``tests/test_command_summaries.py`` fails when it is stale, as ``tools/architecture.py --check``
does for the architecture picture. Rerun it after adding a command or an option.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "commands.md"
WIDTH = "100"          # the usage lines' width, fixed so the page does not depend on the terminal


def subcommands(parser: argparse.ArgumentParser, prefix: str = "headplod") -> list[tuple[str, argparse.ArgumentParser, str]]:
    """``(name, parser, help)`` of every command below ``parser`` (``headplod track``, ``headplod bench plod``,
    ...), depth first, in the parser's order; a command with subcommands of its own is listed before them."""
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                full = f"{prefix} {name}"
                out.append((full, sub, helps.get(name) or ""))
                out += subcommands(sub, full)
    return out


def options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    """The parser's options and positionals (no help action, no subcommand action)."""
    return [a for a in parser._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string the parser takes (``--source``, ``-q``, ``--help``, ...)."""
    return {s for a in parser._actions for s in a.option_strings}


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _value(action: argparse.Action) -> str:
    if action.nargs == 0:
        return ""
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        return "{" + ",".join(str(c) for c in action.choices) + "}"
    metavar = action.metavar
    if isinstance(metavar, tuple):
        return " ".join(metavar)
    name = metavar or (action.dest.upper() if action.option_strings else action.dest)
    if action.nargs == "?":
        return f"[{name}]"
    if action.nargs in ("*", "+"):
        return f"{name} ..."
    if isinstance(action.nargs, int) and action.nargs > 1:
        return " ".join([name] * action.nargs)
    return name


def _default(action: argparse.Action) -> str:
    d = action.default
    if d is None or d is argparse.SUPPRESS or (action.nargs == 0 and d in (False, True) and
                                                isinstance(action, (argparse._StoreTrueAction,
                                                                    argparse._StoreFalseAction))):
        return ""
    if isinstance(d, (list, tuple)):
        return ",".join(str(x) for x in d)
    return str(d)


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    try:
        return parser._get_formatter()._expand_help(action)
    except (KeyError, TypeError, ValueError):
        return action.help


def _section(name: str, parser: argparse.ArgumentParser, help_text: str) -> list[str]:
    usage = parser.format_usage().strip()
    if usage.startswith("usage: "):       # the continuation lines are indented under the first one
        usage = "\n".join(line[len("usage: "):] if k and line.startswith(" " * len("usage: ")) else line
                          for k, line in enumerate(usage[len("usage: "):].split("\n")))
    lines = [f"## `{name}`", ""]
    if help_text:
        lines += [_cell(help_text[0].upper() + help_text[1:]) + ".", ""]
    lines += ["```", usage, "```", ""]
    if parser.epilog:
        lines += [_cell(parser.epilog), ""]
    shown = set()
    for group in parser._action_groups:
        actions = [a for a in group._group_actions if a in options(parser) and id(a) not in shown]
        if not actions:
            continue
        shown.update(id(a) for a in actions)
        title = group.title or "options"
        lines += [f"*{title}*", "", "| option | value | default | what |", "|---|---|---|---|"]
        for a in actions:
            names = ", ".join(f"`{s}`" for s in a.option_strings) or f"`{a.metavar or a.dest}` (positional)"
            value = _value(a)
            default = _default(a)
            lines.append(f"| {names} | {f'`{_cell(value)}`' if value else ''} | "
                         f"{f'`{_cell(default)}`' if default else ''} | {_cell(_help(parser, a))} |")
        lines.append("")
    return lines


def page() -> str:
    """The whole of docs/commands.md, as the parser gives it."""
    os.environ["COLUMNS"] = WIDTH
    sys.path.insert(0, str(ROOT))
    from headplod.cli import build_parser

    parser = build_parser()
    parser.prog = "headplod"
    commands = subcommands(parser)
    out = ["# Every command and option", "",
           "Written by `python tools/commands_page.py` from the `headplod` parser itself "
           "(`headplod.cli.build_parser`); do not edit by hand. `tests/test_command_summaries.py` fails when this "
           "page is not what the parser gives, and checks every `headplod ...` command written in the README and "
           "the other pages against the parser. The same text, wrapped for a terminal: `headplod COMMAND --help`.",
           "", "| command | what |", "|---|---|"]
    out += [f"| [`{name}`](#{_anchor(name)}) | {_cell(h)} |" for name, _, h in commands]
    out.append("")
    for name, sub, h in commands:
        out += _section(name, sub, h)
    return "\n".join(out).rstrip() + "\n"


def _anchor(name: str) -> str:
    return name.lower().replace(" ", "-")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--check", action="store_true", help="only check that docs/commands.md is up to date")
    ap.add_argument("--out", default=str(PAGE), help=f"the page to write (default {PAGE.relative_to(ROOT)})")
    args = ap.parse_args(argv)
    text = page()
    out = Path(args.out)
    if args.check:
        if not out.exists() or out.read_text() != text:
            print(f"{out} is stale: run python tools/commands_page.py", file=sys.stderr)
            return 1
        return 0
    from headplod.io import write_atomically     # imported by page() above from the repository root

    write_atomically(out, lambda name: Path(name).write_text(text))
    print(f"commands: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
