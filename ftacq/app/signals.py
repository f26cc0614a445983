"""SIGTERM handled as Ctrl-C: the CLI (:func:`ftacq.app.cli.main`) runs every command inside it.

``kill PID`` (or a service manager stopping ``ftacq``) then takes the same clean path as Ctrl-C: a procedure
stops the robot and keeps its data, recordings are finished, the drivers and the simulated cell are closed, and
the CLI exits 130.

A command that moves the arm calls :func:`warn_if_sigint_ignored` first: a process started in the background by a
shell without job control (``cmd &`` in a script, ``nohup``) inherits SIGINT ignored, so ``kill -INT`` and Ctrl-C
would not stop it (``ftacq monitor`` says the same through :mod:`procedures.monitor`).

SIGUSR1 (:func:`stack_dump_on_sigusr1`) writes every thread's Python stack to stderr and carries on: the way to see
where a process that does not stop is waiting (``kill -USR1 PID``), written by :mod:`faulthandler` from C, so it
works while the main thread is blocked.
"""

from __future__ import annotations

import contextlib
import faulthandler
import signal
import sys
from collections.abc import Iterator
from types import FrameType


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises KeyboardInterrupt (like Ctrl-C); the previous handler comes back after.

    Outside the main thread (where Python cannot install handlers) the block runs with the handler unchanged.
    """
    try:
        previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        if previous is not None:  # None: the previous handler was not installed from Python; nothing to restore
            signal.signal(signal.SIGTERM, previous)


SIGINT_IGNORED = ("Ctrl-C (SIGINT) is ignored in this process (started in the background with `&` or nohup?): "
                  "`kill -INT` will not stop it; stop it with SIGTERM (kill PID) or the pendant")
"""What a command says when it starts with SIGINT ignored (the monitor's warning, in the same words)."""


def warn_if_sigint_ignored(command: str, moves_the_arm: bool = True) -> bool:
    """Say on stderr, loudly, that SIGINT is ignored in this process (inherited from the shell); return whether it
    is. ``moves_the_arm``: the warning says that the robot will not stop on Ctrl-C."""
    try:
        ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    except ValueError:  # not the main thread
        return False
    if ignored:
        print(f"{command}: WARNING: {SIGINT_IGNORED}"
              + ("; the robot moves without a Ctrl-C to stop it" if moves_the_arm else ""), file=sys.stderr,
              flush=True)
    return ignored


def stack_dump_on_sigusr1() -> bool:
    """Make SIGUSR1 dump every thread's stack to stderr (the process goes on); False where it cannot (no SIGUSR1,
    or stderr without a file descriptor, e.g. under a test capturing it)."""
    if not hasattr(signal, "SIGUSR1"):
        return False
    try:
        faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True, chain=False)
    except (ValueError, OSError, AttributeError, RuntimeError, TypeError):  # io.StringIO and the like: no fileno
        return False
    return True
