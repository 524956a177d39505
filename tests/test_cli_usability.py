"""What a new user meets on the command line (issue 25): defaults in --help, negative coordinates, render --compare."""
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


def test_render_compares_with_full_and_refuses_where_it_cannot(tmp_path, capsys):
    assert cli.main(["render", "--size", "96,54", "--compare", "full", "--out", str(tmp_path / "a.png")]) == 0
    line = next(t for t in capsys.readouterr().err.splitlines() if t.startswith("against full"))
    assert "PSNR" in line and "within 5° of the POI" in line and "FLIP" in line
    psnr = float(line.split("PSNR ")[1].split(" dB")[0])
    assert 20 < psnr < 80                                    # a real difference: not identical, not garbage
    assert cli.main(["render", "--mode", "full", "--size", "96,54", "--compare", "full",
                     "--out", str(tmp_path / "b.png")]) == 0
    assert "PSNR inf dB" in capsys.readouterr().err          # full against itself is identical
    assert cli.main(["render", "--backend", "tessellation", "--compare", "full", "--out", str(tmp_path / "c.png")]) == 2
    assert not (tmp_path / "c.png").exists()
