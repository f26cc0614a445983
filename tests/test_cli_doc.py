"""docs/cli*.md are what the parsers say (regenerate with ``python -m ftacq.app.clidoc``)."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from ftacq.app.cli import build_parser
from ftacq.app.clidoc import PAGES, render_pages

DOCS = Path(__file__).resolve().parents[1] / "docs"


@pytest.mark.parametrize("page", sorted(PAGES))
def test_the_reference_page_is_what_the_parsers_say(page: str) -> None:
    written = (DOCS / page).read_text(encoding="utf-8")
    assert written == render_pages()[page], f"docs/{page} is stale: run `python -m ftacq.app.clidoc`"


def test_every_option_of_every_command_is_on_a_page() -> None:
    text = "".join(render_pages().values())
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    for name, command in commands.items():
        assert f"## ftacq {name}" in text
        for action in command._actions:
            for option in action.option_strings:
                if option not in ("-h", "--help"):
                    assert f"`{option}" in text, (name, option)


def test_a_changed_help_text_makes_the_page_stale() -> None:
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    commands["identify"].add_argument("--a-new-option", help="something new")
    assert "--a-new-option" in render_pages(parser)["cli-files.md"]
    assert render_pages(parser)["cli-files.md"] != (DOCS / "cli-files.md").read_text(encoding="utf-8")
