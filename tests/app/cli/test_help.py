"""Every `semanticxr COMMAND --help` prints its help: argparse formats help text with %, so a
knob's docstring that says "1 % of depth" must reach it escaped."""

import contextlib
import io

import pytest

from app.cli import build_parser


def commands() -> list[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    return sorted(sub.choices)


@pytest.mark.parametrize("command", commands())
def test_help_of_every_command_prints(command):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args([command, "--help"])
    assert exit_info.value.code == 0
    assert out.getvalue().startswith("usage:")
