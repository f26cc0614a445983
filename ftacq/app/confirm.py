"""The user's confirmation before the robot moves or the controller changes (``--yes`` answers in advance).

Without ``--yes`` the question is asked on the terminal; with no terminal on stdin (a script, a pipe) the command
refuses instead of guessing, so nothing moves that nobody confirmed.
"""

from __future__ import annotations

import argparse
import sys

from ftacq.errors import AbortedError, InputError


def confirm(args: argparse.Namespace, question: str, *, no_terminal: str, declined: str) -> None:
    """Return when confirmed: ``args.yes``, or "y"/"yes" typed at the terminal after ``question`` [y/N].

    Raises InputError(``no_terminal``) when stdin is not a terminal, AbortedError(``declined``) on any other answer.
    """
    if args.yes:
        return
    if not sys.stdin or not sys.stdin.isatty():
        raise InputError(no_terminal)
    if input(question + " [y/N] ").strip().lower() not in ("y", "yes"):
        raise AbortedError(declined)


def confirm_motion(args: argparse.Namespace) -> None:
    """Confirm a checked plan printed above before the robot moves through it (calibrate, tare, excitation)."""
    confirm(args, "Move the robot through this plan? Keep the e-stop within reach.",
            no_terminal="refusing to move the robot: no terminal to confirm the plan on (stdin is not a tty); "
                        "check the plan above (or with --dry-run) and pass --yes",
            declined="plan not confirmed: the robot did not move")
