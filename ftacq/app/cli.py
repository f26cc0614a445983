"""The ``ftacq`` command line: one sub-command module per job under :mod:`ftacq.app.commands`.

Each module in ``COMMAND_MODULES`` exposes ``register(subparsers)``, which adds its sub-parser and sets
``func`` (``args -> int`` exit code). Modules import heavy dependencies inside their ``func`` so that
``ftacq --help`` stays fast. Library code raises :class:`ftacq.errors.FtacqError`; this is the only place
that turns an error into a message and an exit status:

- 0 success, 1 a device or procedure failure, 2 bad input (file, URL, configuration), 130 interrupted
  (Ctrl-C, SIGTERM, :class:`ftacq.errors.InterruptedByUser`), 141 a closed standard output.

The status is chosen by the exception's type (:data:`EXIT_STATUS`), never by its text. A command module that
fails to import is an installation defect: the CLI says which one and why, and exits 1 (it is never skipped).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from ftacq import __version__
from ftacq.app.helptext import examples
from ftacq.app.signals import sigterm_as_interrupt, stack_dump_on_sigusr1
from ftacq.errors import AbortedError, FtacqError, InputError, InterruptedByUser

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
"""One BLAS thread (set before anything imports numpy, which loads OpenBLAS; a user's own setting wins): ftacq's
matrices are small (22 columns) and its acquisition threads need the cores; OpenBLAS's extra threads spin between
calls, and on a 2-core cell PC the quick design took 2× the CPU and up to 3× the time with them
(benchmarks/quick_design.py, benchmarks/README.md)."""

COMMAND_MODULES = (
    "ftacq.app.commands.importing",
    "ftacq.app.commands.identify",
    "ftacq.app.commands.compensate",
    "ftacq.app.commands.sensor",
    "ftacq.app.commands.robot",
    "ftacq.app.commands.calibrate",
    "ftacq.app.commands.config",
    "ftacq.app.commands.monitor",
    "ftacq.app.commands.tare",
    "ftacq.app.commands.export",
    "ftacq.app.commands.bridge",
)

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 0, 1, 2, 130, 141
EXIT_STATUS: tuple[tuple[type[FtacqError], int], ...] = (
    (InterruptedByUser, EXIT_INTERRUPTED),
    (InputError, EXIT_BAD_INPUT),
    (FtacqError, EXIT_FAILURE),
)
"""Exception type → exit status, first match wins (subclasses before their bases)."""
EXIT_STATUS_TEXT = (
    "Exit status: 0 done, 1 a device or run fault (data kept), 2 bad input (one line: file, field, value, why; "
    "nothing half written), 130 interrupted by Ctrl-C or SIGTERM (the robot stopped, data kept), 141 standard "
    "output closed by its reader. An output file's folder must exist; a run folder (`calibrate --out`) is created."
)
"""The exit statuses in words, as the reference pages and the README say them."""


class CommandModuleError(Exception):
    """A command module could not be imported (a broken installation, never a user error)."""


def exit_status(error: FtacqError) -> int:
    """The exit status for an ftacq error, by its type."""
    return next(status for kind, status in EXIT_STATUS if isinstance(error, kind))


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser with every available sub-command registered."""
    parser = argparse.ArgumentParser(
        prog="ftacq",
        description="Calibrate a wrist-mounted ATI F/T sensor on a UR arm and stream compensated wrenches.",
        **examples("ftacq calibrate --sim --yes  # try it on the simulated cell",
                   "ftacq config init CELL.toml  # then: ftacq calibrate --config CELL.toml",
                   "ftacq COMMAND --help  # each command's options and examples"),
    )
    parser.add_argument("--version", action="version", version=f"ftacq {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ImportError as error:
            raise CommandModuleError(f"cannot load the command module {module_name} ({type(error).__name__}: "
                                     f"{error}); the installation is broken: reinstall ftacq") from error
        module.register(subparsers)
    _own_parser_on_error(parser)
    return parser


def _own_parser_on_error(parser: argparse.ArgumentParser) -> None:
    """Give every sub-command's namespace its own parser (``_parser``), so that an option it does not know is
    reported with its usage (``ftacq calibrate --foo``), not the top level's: argparse hands a sub-parser's
    unknown options back to the top-level parser."""
    parser.set_defaults(_parser=parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _own_parser_on_error(sub)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; return the exit status."""
    try:
        parser = build_parser()
    except CommandModuleError as error:
        print(f"ftacq: error: {error}", file=sys.stderr)
        return EXIT_FAILURE
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # exit 2 with the usage of the (sub-)command whose options they were meant for
        args._parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    stack_dump_on_sigusr1()  # `kill -USR1 PID`: where every thread waits (a command that does not stop)
    try:
        with sigterm_as_interrupt():  # SIGTERM stops every command as Ctrl-C does (exit 130, data kept)
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("ftacq: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader went away (`ftacq identify … | head`): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except FtacqError as error:
        # a stopped procedure is reported as it is (it says what was kept and how to resume), not as an error
        print(f"ftacq: {error}" if isinstance(error, AbortedError) else f"ftacq: error: {error}", file=sys.stderr)
        return exit_status(error)


if __name__ == "__main__":
    sys.exit(main())
