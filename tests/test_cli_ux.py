"""Issue 36: the command line for the person at the desk.

- a usage error is one line, ``PROG: error: WHAT[, did you mean X?] see PROG --help``, exit status 2, for
  every subcommand (no usage block before it); unknown options are refused by the subcommand they were
  given to, with the closest option; invalid choices and commands with the closest choice;
"""
from __future__ import annotations

import argparse

import pytest

from headplod import cli


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
