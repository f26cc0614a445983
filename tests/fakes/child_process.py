"""Ending a simulated device's own process: ask, then terminate, then kill, each with a deadline.

Shared by :mod:`tests.fakes.netft_process` and :mod:`tests.fakes.ur_process` (a simulated box or controller run in
its own process, so that the host's scheduler treats it as the separate machine it stands for)."""

from __future__ import annotations

import subprocess

STOP_TIMEOUT_S = 5.0
"""How long a simulated device's process is given to exit after each request (asked, terminated, killed), s."""


def end_process(process: subprocess.Popen, timeout_s: float = STOP_TIMEOUT_S) -> None:
    """Wait for ``process`` (already asked to quit) to exit; terminate it, then kill it, if it does not in time."""
    try:
        process.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.terminate()
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=timeout_s)
