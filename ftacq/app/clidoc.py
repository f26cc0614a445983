"""The CLI reference pages (docs/cli*.md), generated from the parsers so they cannot drift.

``python -m ftacq.app.clidoc`` rewrites them; ``tests/test_cli_doc.py`` fails when a page differs from
what the parsers say. Each command's description, usage, options (with their help, defaults and choices) and
examples come from its ``add_parser`` call: to change the reference, change the parser.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ftacq.app.cli import EXIT_STATUS_TEXT, build_parser
from ftacq.fileio import atomic_write

PAGES: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "cli.md": ("CLI reference: calibrate",
               "Calibrating a cell. The other commands: files ([cli-files.md](cli-files.md): import, identify, "
               "compensate, export), live use ([cli-live.md](cli-live.md): monitor, tare) and the devices "
               "([cli-devices.md](cli-devices.md): sensor, robot, bridge).",
               ("calibrate", "config")),
    "cli-files.md": ("CLI reference: files",
                     "The commands that read and write pose records and calibrations. Calibrating: [cli.md](cli.md).",
                     ("import", "identify", "compensate", "export")),
    "cli-live.md": ("CLI reference: live use",
                    "The compensated stream, live. Calibrating: [cli.md](cli.md).",
                    ("monitor", "tare")),
    "cli-devices.md": ("CLI reference: the devices",
                       "Inspecting the sensor and the robot, and feeding the controller. Calibrating: [cli.md](cli.md).",
                       ("sensor", "robot", "bridge")),
}
"""Page file name → (title, lead paragraph, commands in order)."""

INTRO = ("Generated from the parsers (`python -m ftacq.app.clidoc`; a test checks it): `ftacq COMMAND --help` says the "
         "same. `source .venv/bin/activate` puts `ftacq` on your PATH.")


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help_of(action: argparse.Action, parser: argparse.ArgumentParser) -> str:
    formatter = parser._get_formatter()
    text = formatter._expand_help(action) if action.help else ""
    return " ".join(text.split()).replace("|", "\\|")


def _option_rows(parser: argparse.ArgumentParser, path: str, seen: dict[str, str]) -> list[str]:
    """The options table's rows; an option already described alike under an earlier command is named in one row
    that points there (``seen``: row → the command that described it first)."""
    rows = []
    repeated: dict[str, list[str]] = {}
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._SubParsersAction)) or action.help == argparse.SUPPRESS:
            continue
        if action.option_strings:
            metavar = ""
            if action.nargs != 0:
                metavar = " " + parser._get_formatter()._format_args(action, action.dest.upper())
            name = ", ".join(f"`{o}{metavar}`" for o in action.option_strings)
        else:
            name = f"`{parser._get_formatter()._format_args(action, action.dest)}`"
        row = f"| {name} | {_help_of(action, parser)} |"
        if row in seen:
            repeated.setdefault(seen[row], []).append(name)
            continue
        seen[row] = path
        rows.append(row)
    rows += [f"| {', '.join(names)} | as for `{first}` |" for first, names in repeated.items()]
    return rows


def _section(path: str, parser: argparse.ArgumentParser, level: int, seen: dict[str, str]) -> list[str]:
    # the synopsis: the positionals in order, the options in the table below
    formatter = parser._get_formatter()
    positionals = [formatter._format_args(a, a.dest) if not isinstance(a, argparse._SubParsersAction) else "ACTION"
                   for a in parser._actions if not a.option_strings]
    has_options = any(a.option_strings and not isinstance(a, argparse._HelpAction) for a in parser._actions)
    usage = " ".join([parser.prog, *(["[options]"] if has_options else []), *positionals])
    lines = [f"{'#' * level} {path}", ""]
    if parser.description:
        lines += [" ".join(parser.description.split()), ""]
    lines += ["```", usage, "```", ""]
    rows = _option_rows(parser, path, seen)
    if rows:
        lines += ["| option | meaning |", "|---|---|", *rows, ""]
    if parser.epilog:
        example_lines = [e.strip() for e in parser.epilog.splitlines()[1:] if e.strip()]
        if example_lines:
            lines += ["```bash", *example_lines, "```", ""]
    for name, sub in _subcommands(parser).items():
        lines += _section(f"{path} {name}", sub, level + 1, seen)
    return lines


def render_pages(parser: argparse.ArgumentParser | None = None) -> dict[str, str]:
    """Return every reference page's markdown, by file name."""
    parser = parser or build_parser()
    commands = _subcommands(parser)
    missing = set(commands) - {c for _, _, names in PAGES.values() for c in names}
    if missing:
        raise ValueError(f"commands on no reference page (add them to PAGES): {sorted(missing)}")
    pages = {}
    seen: dict[str, str] = {}
    for file_name, (title, lead, names) in PAGES.items():
        common = [INTRO, "", EXIT_STATUS_TEXT, ""] if file_name == "cli.md" else []  # once, on the first page
        lines = [f"# {title}", "", lead, "", *common]
        for name in names:
            lines += _section(f"ftacq {name}", commands[name], 2, seen)
        pages[file_name] = "\n".join(lines).rstrip() + "\n"
    return pages


def main(argv: list[str] | None = None) -> int:
    """Rewrite the reference pages in the given docs folder (default: docs/ of the checkout)."""
    docs = Path(argv[0] if argv else Path(__file__).resolve().parents[2] / "docs")
    for file_name, text in render_pages().items():
        with atomic_write(docs / file_name) as out:
            out.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
