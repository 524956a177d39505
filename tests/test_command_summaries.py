"""The command summaries agree with argparse (issue 25).

- docs/commands.md is what tools/commands_page.py makes from headplod.cli.build_parser(): every subcommand,
  every option (with its default); rerun the script after adding a command or an option.
- The README's synopsis (its "Commands" block) names every top-level command, and each option it lists
  exists for that command.
- Every ``headplod ...`` command written in the README and in docs/*.md, in a code block or in inline code,
  names a command that exists and only options that command takes.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from conftest import load_tool
from headplod.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "commands.md")]
OPTION = re.compile(r"(?<![\w/.-])(--[a-z][a-z0-9-]*|-[a-zA-Z])(?![\w-])")
FENCE = re.compile(r"^ *```([^\n]*)\n(.*?)^ *```", re.S | re.M)
SHELL = ("", "sh", "bash", "console", "shell")     # the blocks that hold commands (not ```python, ```toml)
INLINE = re.compile(r"(?<!`)`([^`\n]+)`(?!`)")


@pytest.fixture(scope="module")
def tool():
    return load_tool("commands_page")


@pytest.fixture(scope="module")
def commands(tool):
    """'headplod track' -> its parser, for every command and bench's subcommands."""
    return {name: parser for name, parser, _ in tool.subcommands(build_parser())}


def _command_of(text: str, commands: dict):
    """The longest known command that ``text`` (from 'headplod ' on) starts with, and the rest of the text."""
    words = text.split()
    for n in (3, 2):
        name = " ".join(words[:n])
        if name in commands:
            return name, " ".join(words[n:])
    return " ".join(words[:2]), None


def _commands_written(text: str):
    """Every 'headplod NAME ...' written in the page's code blocks (with their continuation lines) and inline
    code: (the command text from 'headplod' on, where it was)."""
    for language, block in FENCE.findall(text):
        if language.strip() not in SHELL:
            continue
        current = None
        for line in block.splitlines():
            body = line.split(" #", 1)[0]
            hit = re.search(r"(?:^|[\s/])headplod\s+[a-z]", body)
            if hit:
                if current:
                    yield current
                current = body[hit.start():].lstrip(" /")
            elif current is not None and (line.startswith((" ", "\t")) or current.rstrip().endswith("\\")):
                current += " " + body.strip()
            else:
                if current:
                    yield current
                current = None
        if current:
            yield current
    prose = FENCE.sub("", text)
    for span in INLINE.findall(prose):
        hit = re.search(r"(?:^|[\s/])headplod\s+[a-z]", span)
        if hit:
            yield span[hit.start():].lstrip(" /")


def test_the_commands_page_is_what_the_parser_gives(tool):
    page = ROOT / "docs" / "commands.md"
    assert page.exists(), "run python tools/commands_page.py"
    assert page.read_text() == tool.page(), "docs/commands.md is stale: run python tools/commands_page.py"


def test_the_commands_page_has_every_command_and_every_option(tool, commands):
    text = (ROOT / "docs" / "commands.md").read_text()
    sections = dict(re.findall(r"^## `([^`]+)`\n(.*?)(?=^## `|\Z)", text, re.S | re.M))
    assert set(sections) == set(commands)
    for name, parser in commands.items():
        for option in tool.option_strings(parser) - {"-h", "--help"}:
            assert f"`{option}`" in sections[name], (name, option)


def test_the_readme_synopsis_lists_every_command_with_options_that_exist(commands):
    text = (ROOT / "README.md").read_text()
    part = re.search(r"^## Commands\n(.*?)(?=^## )", text, re.S | re.M)
    assert part, "the README has a '## Commands' section"
    block = FENCE.search(part.group(1))
    assert block, "the README's '## Commands' section has a synopsis block"
    written = list(_commands_written("```\n" + block.group(2) + "```\n"))
    named = {_command_of(c, commands)[0] for c in written}
    named |= {" ".join(n.split()[:2]) for n in named}          # "headplod bench plod" names "headplod bench"
    top = {name for name in commands if name.count(" ") == 1}
    assert top - named == set(), "commands missing from the README's synopsis"
    _check_options(written, commands, "README.md synopsis")


def _check_options(written, commands, where):
    wrong = []
    for text in written:
        name, rest = _command_of(text, commands)
        if rest is None:
            wrong.append((where, text, f"no command {name!r}"))
            continue
        known = {s for a in commands[name]._actions for s in a.option_strings}
        wrong += [(where, text, option) for option in OPTION.findall(rest) if option not in known]
    assert wrong == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_command_written_in_the_docs_exists_with_its_options(page, commands):
    _check_options(list(_commands_written(page.read_text())), commands, page.relative_to(ROOT).as_posix())


def test_the_checks_catch_what_they_are_for(commands):
    """A made-up option or command is found, a real one passes."""
    text = "```\nheadplod track --source synthetic --no-such-option\nheadplod nosuch --x\n```\n" \
           "and `headplod render --head=-1,2,3 --out a.png`"
    written = list(_commands_written(text))
    assert written[0].startswith("headplod track") and len(written) == 3
    with pytest.raises(AssertionError):
        _check_options(written[:1], commands, "t")
    with pytest.raises(AssertionError):
        _check_options(written[1:2], commands, "t")
    _check_options(written[2:], commands, "t")
