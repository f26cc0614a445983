"""Every command's ``--help`` ends with one to three examples, and every example parses as written."""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

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
README = Path(__file__).resolve().parents[1] / "README.md"


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


@pytest.mark.parametrize("path, parser", COMMANDS, ids=[" ".join(p) for p, _ in COMMANDS])
def test_help_names_no_run_folder_that_is_never_created(path, parser):
    # a run folder is runs/<UTC date-time>/ (procedures/run_folder.py): an example names one, or a placeholder
    for folder in re.findall(r"runs/([^/\s]+)/", parser.format_help()):
        assert re.fullmatch(r"<[^>]+>|\d{8}-\d{6}", folder), f"runs/{folder}/ is never created"


def _readme_rows() -> dict[str, str]:
    """README's command table: the command (its first two words after ``ftacq``) → the row's usage text."""
    rows = {}
    for line in README.read_text(encoding="utf-8").splitlines():
        usage = re.match(r"\| `ftacq ([^`]+)` \|", line)
        if usage:
            rows.setdefault(usage.group(1).split()[0], usage.group(1))
    return rows


@pytest.mark.parametrize("name", ["identify", "tare", "compensate", "export"])
def test_readme_shows_a_required_option_as_required(name):
    usage = _readme_rows()[name]
    parser = dict((" ".join(p), sub) for p, sub in COMMANDS)[name]
    outside_brackets = re.sub(r"\[[^\]]*\]", "", usage)
    for action in parser._actions:
        if action.option_strings and action.required:
            assert any(option in outside_brackets.split() for option in action.option_strings), (name, usage)
