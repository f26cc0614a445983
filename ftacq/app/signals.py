"""SIGTERM handled as Ctrl-C: the CLI (:func:`ftacq.app.cli.main`) runs every command inside it.

``kill PID`` (or a service manager stopping ``ftacq``) then takes the same clean path as Ctrl-C: a procedure
stops the robot and keeps its data, recordings are finished, the drivers and the simulated cell are closed, and
the CLI exits 130.
"""

from __future__ import annotations

import contextlib
import signal
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
