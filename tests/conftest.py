"""Shared pytest configuration and helpers. Fixtures for one device live beside that device's tests or in
tests/fakes/.

:func:`wait_until` is how a test waits for something another thread or process does: a condition polled with
a deadline, never a bare sleep. Import it (``from tests.conftest import wait_until``) or take the fixture of the
same name.
"""

from __future__ import annotations

import time
from typing import Callable, TypeVar

import pytest

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
