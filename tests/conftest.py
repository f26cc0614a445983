"""Shared pytest configuration and helpers. Fixtures for one device live beside that device's tests or in
tests/fakes/.

:func:`wait_until` is how a test waits for something another thread or process does: a condition polled with
a deadline, never a bare sleep. Import it (``from tests.conftest import wait_until``) or take the fixture of the
same name.

The checkout stays as it was: a test writes into ``tmp_path``, never into the work tree (an .rrd a command saves
by default under ``runs/`` of the current folder, a file with a relative path). Run one process (``-p no:xdist``)
and the test that wrote a file fails, naming it; with ``-n 2`` the other worker's files would be blamed on the
wrong test, so the whole run fails at its end instead, naming the files.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Callable, TypeVar

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the ftacq command (ftacq/app/cli.py), for the workers and
# every process the tests start: xdist starts its workers after this file is read, before they import numpy
os.environ.setdefault("FTACQ_SIM_REALTIME_PRIORITY", "5")  # simulated controllers keep their cycle on a loaded machine
# (tests/fakes/ur_process.py REALTIME_PRIORITY_VARIABLE; normal scheduling where SCHED_FIFO is not allowed)

CHECKOUT = Path(__file__).resolve().parents[1]
NOT_OUTPUT = {".git", ".venv", "__pycache__", ".pytest_cache", ".hypothesis", ".mypy_cache", ".ruff_cache"}
"""Folders of the checkout that tools (git, the environment, caches) write: not looked at by the guard."""


def checkout_files(root: Path = CHECKOUT) -> set[str]:
    """Every file and folder of the checkout, relative, outside :data:`NOT_OUTPUT` (and the egg-info); source files
    (``*.py``, ``*.md``) left out: one made during the run is the developer's, not a test's output."""
    found: set[str] = set()
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if d not in NOT_OUTPUT and not d.endswith(".egg-info")]
        base = os.path.relpath(folder, root)
        found.update(os.path.normpath(os.path.join(base, name)) for name in (*dirs, *files)
                     if not name.endswith((".py", ".md")))
    return found


def _sigint_reaches_children() -> None:
    """A suite started in the background by a shell without job control (``cmd &``, nohup) inherits SIGINT
    *ignored*, and so would every program the tests start: Python keeps an inherited SIG_IGN (no
    KeyboardInterrupt), so the Ctrl-C tests would see a tool ignore Ctrl-C. A terminal's Ctrl-C is what they
    stand for: SIGINT gets its default handling here (pytest-xdist's workers run this too)."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


_sigint_reaches_children()


def _one_process(config: pytest.Config) -> bool:
    return not hasattr(config, "workerinput") and getattr(config.option, "numprocesses", None) in (None, 0)


def pytest_sessionstart(session: pytest.Session) -> None:
    if not hasattr(session.config, "workerinput"):  # the controlling process (or the only one)
        session.config.stash[_BEFORE] = checkout_files()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    before = session.config.stash.get(_BEFORE, None)
    if before is None:
        return
    written = sorted(checkout_files() - before)
    if written:
        print(f"\ntests wrote into the checkout {CHECKOUT} (write into tmp_path): {', '.join(written)}")
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


_BEFORE = pytest.StashKey[set]()


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Order and group the suite for ``./run.sh test`` (``-n 4 --dist loadgroup``): the tests marked ``slow`` first,
    longest first (``@pytest.mark.slow(seconds=…)``: the test's usual length on the 2-core machine, default
    :data:`SLOW_TEST_S`), each dealt out alone; every other test in one group per module (``xdist_group``), so a
    module's shared fixtures (a simulated cell, an identified run) are built once. The real-time quick calibrations
    (a minute and a half each) then start at once on different workers and the modules fill in around them,
    instead of one long test ending the suite while the other workers idle. Every process orders alike."""
    def expected_s(item: pytest.Item) -> float:
        marker = item.get_closest_marker("slow")
        return 0.0 if marker is None else float(marker.kwargs.get("seconds", SLOW_TEST_S))

    items.sort(key=lambda item: -expected_s(item))
    for item in items:
        if item.get_closest_marker("slow") is None:
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


SLOW_TEST_S = 5.0
"""A ``slow`` test's length when its marker does not say, s."""


@pytest.fixture(autouse=True)
def _checkout_untouched(request: pytest.FixtureRequest):
    """Fail the test that wrote into the checkout (one process only; see the module docstring)."""
    if not _one_process(request.config):
        yield
        return
    before = checkout_files()
    yield
    written = sorted(checkout_files() - before)
    if written:
        pytest.fail(f"the test wrote into the checkout {CHECKOUT} (write into tmp_path): {', '.join(written)}",
                    pytrace=False)

WAIT_TIMEOUT_S = 10.0
"""Default deadline of :func:`wait_until`: generous, since a loaded 2-core machine runs the suite in parallel."""
POLL_PERIOD_S = 0.005

T = TypeVar("T")


def wait_until(predicate: Callable[[], T], what: str = "condition", timeout_s: float = WAIT_TIMEOUT_S) -> T:
    """Poll ``predicate()`` until it returns something true and return that; fail the test naming ``what`` after
    ``timeout_s`` seconds."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(POLL_PERIOD_S)


@pytest.fixture(name="wait_until")
def wait_until_fixture() -> Callable[..., object]:
    """:func:`wait_until`, for tests that prefer a fixture."""
    return wait_until
