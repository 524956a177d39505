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


def test_a_coordinate_list_may_start_with_a_minus_sign(tmp_path):
    """``render --head -120,40,650`` used to fail with "expected one argument"; only ``--head=...`` worked."""
    from headplod.argtypes import attach_negative_lists

    assert attach_negative_lists(["render", "--head", "-120,40,650", "--poi", "-5.5,3e2", "--level-bias", "-1",
                                  "-q"]) == ["render", "--head=-120,40,650", "--poi=-5.5,3e2", "--level-bias", "-1",
                                             "-q"]
    args = cli.build_parser().parse_args(attach_negative_lists(
        ["render", "--head", "-120,40,650", "--out", str(tmp_path / "r.png")]))
    assert list(args.head) == [-120.0, 40.0, 650.0]


def test_the_command_line_takes_a_negative_coordinate_list(tmp_path, capsys):
    out = tmp_path / "r.png"
    assert cli.main(["render", "--head", "-40,20,640", "--size", "64,36", "--out", str(out)]) == 0
    assert out.is_file()
