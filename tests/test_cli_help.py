"""Every command's ``--help`` ends with one to three examples, and every example parses as written."""

from __future__ import annotations

import argparse
import shlex

import pytest

from ftacq.app.cli import build_parser
from ftacq.app.helptext import EXAMPLES_HEADING


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """Yield (command path, parser) for every sub-command, nested ones included."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(build_parser()))


def _examples(help_text: str) -> list[str]:
    tail = help_text.rstrip("\n").split("\n" + EXAMPLES_HEADING + "\n")
    assert len(tail) == 2, "no examples section"
    return [line.strip() for line in tail[1].splitlines()]


def test_every_command_is_checked():
    names = {" ".join(path) for path, _ in COMMANDS}
    assert {"calibrate", "identify", "monitor", "config init", "sensor record", "robot info"} <= names


@pytest.mark.parametrize("path, parser", COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_help_ends_with_examples_that_parse(path, parser):
    lines = _examples(parser.format_help())
    assert 1 <= len(lines) <= 3
    for line in lines:
        command = line.split("  #")[0].split(" | ")[0]
        words = shlex.split(command)
        assert words[: 1 + len(path)] == ["ftacq", *path], line
        args = build_parser().parse_args(words[1:])  # exits (SystemExit) on an example that does not parse
        assert getattr(args, "func", None) is not None, line
