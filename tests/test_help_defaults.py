"""Every option's default is in its ``--help`` text (issue 25: a new user reads --help, not the code)."""
import argparse

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
