"""``ftacq config``: write a commented example CELL.toml, or check one.

    ftacq config init [PATH] [--force]     write the example (default CELL.toml; refuses to overwrite)
    ftacq config check PATH [--strict]     validate a file and print the plan settings it gives; WARN for keys
                                           marked EDIT still at the template's value (FAIL, exit 1, --strict)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ftacq.app.helptext import examples
from ftacq.errors import InputError

DEFAULT_CONFIG_PATH = Path("CELL.toml")


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``config`` sub-command with its ``init`` and ``check`` actions."""
    from ftacq.app.config import EDIT_MARK

    parser = subparsers.add_parser(
        "config", help="write or check a cell configuration (CELL.toml)",
        description="Write a commented example CELL.toml (robot, sensor, tool, poses, sampling, output; SI units), "
                    "or validate one.",
        **examples("ftacq config init CELL.toml  # then set robot.host, sensor.url and the tool",
                   "ftacq config check CELL.toml"))
    actions = parser.add_subparsers(dest="config_action", metavar="ACTION", required=True)
    init = actions.add_parser("init", help="write a commented example CELL.toml",
                              description="Write a commented example configuration with every key at its default.",
                              **examples("ftacq config init  # writes CELL.toml here",
                                         "ftacq config init cells/ur5e-lab.toml"))
    init.add_argument("path", nargs="?", type=Path, default=DEFAULT_CONFIG_PATH,
                      help="where to write it (default %(default)s)")
    init.add_argument("--force", action="store_true", help="overwrite an existing file")
    init.set_defaults(func=run_init)
    check = actions.add_parser("check", help="validate a CELL.toml and print its values",
                               description="Validate every key (type, range, unknown keys); exit 2 on a bad value. "
                                           f"Warn about the keys marked {EDIT_MARK} (the robot, the sensor, the tool "
                                           "and the sensor offset) still at the template's value or not set.",
                               **examples("ftacq config check CELL.toml", "ftacq config check --strict CELL.toml"))
    check.add_argument("path", type=Path, help="the configuration file")
    check.add_argument("--strict", action="store_true",
                       help=f"fail (exit 1) when a key marked {EDIT_MARK} is still at the template's value or not set")
    check.set_defaults(func=run_check)


def run_init(args: argparse.Namespace) -> int:
    """Write the example configuration; refuse to overwrite without --force."""
    from ftacq.app.config import EDIT_MARK, SCHEMA, example_config_text
    from ftacq.fileio import atomic_write

    from ftacq.validation import check_output_file

    path: Path = args.path
    if path.exists() and path.is_dir():
        raise InputError(f"{path}: is a folder; give a file name such as {path / DEFAULT_CONFIG_PATH}")
    if path.exists() and not args.force:
        raise InputError(f"{path}: already exists; pass --force to overwrite it")
    check_output_file(path, "configuration file")
    with atomic_write(path) as handle:
        handle.write(example_config_text())
    to_edit = ", ".join(key.key for keys in SCHEMA.values() for key in keys.values() if key.edit)
    print(f"wrote {path}: set the keys marked {EDIT_MARK} for your cell ({to_edit}), then run "
          f"`ftacq calibrate --config {path} --dry-run` to check the plan", file=sys.stderr)
    return 0


def run_check(args: argparse.Namespace) -> int:
    """Validate a configuration and print it as the procedure will use it."""
    import json

    from ftacq.app.config import EDIT_MARK, load_config, unedited_keys

    config = load_config(args.path)
    print(json.dumps(config.to_dict(), indent=2))
    unedited = unedited_keys(config)
    status = "FAIL" if unedited and args.strict else "WARN" if unedited else "OK"
    for line in unedited:
        print(f"{args.path}: {status}: {line}", file=sys.stderr)
    print(f"{args.path}: {status}" + (f" ({len(unedited)} keys marked {EDIT_MARK} to set for your cell"
                                      + ("" if args.strict else "; --strict fails on them") + ")" if unedited else ""),
          file=sys.stderr)
    return 1 if status == "FAIL" else 0
