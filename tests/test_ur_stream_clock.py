"""drivers/ur_stream.py's host times over simulated hours: the RTDE bytes of a controller whose clock and the
host's drift ±50 ppm apart, with random queueing delays (tests/fakes/drifting_link.py), read by the stream's own
reader loop from a socket stand-in, with the host's monotonic clock read from the simulation. No network, no
sleeps: three hours take about a second."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import drivers.ur_stream as ur_stream
from drivers.ur_stream import URStateStream
from tests.fakes.drifting_link import MIN_DELAY_S, Link, data_packages, simulate, text_message

BOUND_S = 0.0005
"""A state's host time may be off the truth plus the fastest transport by at most this, s."""


def _values(timestamp_s: np.ndarray) -> np.ndarray:
    """Output values (N, 25) whose joint states are functions of the controller time (to check every row)."""
    t = timestamp_s[:, None]
    joints = np.arange(1, 7)[None, :]
    return np.hstack([t, np.sin(t / joints), np.cos(t / joints), 0.5 * np.cos(t / joints), -0.1 * np.sin(t)
                      * joints])


class _Socket:
    """What the reader loop needs of a socket: ``recv`` handing out the reads of a link in order, each at its
    arrival on the simulated host clock, then b"" (the controller closed the connection)."""

    def __init__(self, link: Link, clock: list[float]) -> None:
        self._clock = clock
        bounds = np.flatnonzero(np.diff(link.read)) + 1
        values = _values(link.timestamp_s)
        self._reads: list[tuple[float, bytes]] = []
        carry = b""
        for k, part in enumerate(np.split(np.arange(link.timestamp_s.size), bounds)):
            data = carry + data_packages(values[part])
            carry = b""
            if k % 97 == 0:
                data += text_message("a controller message")  # other packages are skipped
            if k % 13 == 0 and len(data) > 100:
                data, carry = data[:-100], data[-100:]  # a package split over two reads
            self._reads.append((float(link.arrival_s[part[0]]), data))
        self._reads.append((self._reads[-1][0], carry))
        self._reads.reverse()

    def recv(self, _size: int) -> bytes:
        if not self._reads:
            return b""
        arrival_s, data = self._reads.pop()
        self._clock[0] = arrival_s
        return data


def _stream(link: Link, monkeypatch) -> URStateStream:
    clock = [0.0]
    monkeypatch.setattr(ur_stream, "time", SimpleNamespace(monotonic=lambda: clock[0]))
    stream = URStateStream("controller.invalid", capacity=1 << 17)
    stream._read_loop(_Socket(link, clock))  # type: ignore[arg-type] - the reader's own loop, run to the end
    return stream


@pytest.mark.parametrize("drift", [50e-6, -50e-6], ids=["host-fast", "host-slow"])
def test_state_times_stay_on_the_truth_through_hours_of_clock_drift(drift, monkeypatch):
    # one second of 500 Hz packages every minute over three hours: the clocks drift through the gaps as well
    link = simulate(drift, 3 * 3600.0, np.random.default_rng(5), active_s=1.0, every_s=60.0)
    stream = _stream(link, monkeypatch)
    assert stream.error == "the controller closed the connection"
    assert stream.count == link.timestamp_s.size  # every data package, once; the text messages skipped
    window = stream.window()
    np.testing.assert_array_equal(window.controller_time_s, link.timestamp_s)
    np.testing.assert_array_equal(window.q, _values(link.timestamp_s)[:, 1:7])
    np.testing.assert_array_equal(window.qdd, _values(link.timestamp_s)[:, 19:25])  # target q̈
    assert np.all(window.arrival_s >= link.arrival_s - 1e-9)  # a split package is stamped by the read ending it
    # the host time of every state: the truth plus the fastest transport within a fraction of a millisecond (a plain
    # lower envelope of arrival − timestamp puts them 50 ppm × 3 h = 0.54 s early when the host runs fast)
    error = window.time_s - (link.true_host_s + MIN_DELAY_S)
    assert error.min() > -BOUND_S
    assert error.max() < BOUND_S
    assert np.all(np.diff(window.time_s) > 0)
    assert np.all(window.time_s <= window.arrival_s + 1e-12)
    # the newest states, as the live compensation asks for them, and a window from a host time on
    np.testing.assert_array_equal(stream.window(last=64).time_s, window.time_s[-64:])
    since = stream.window(since_s=float(window.time_s[-300]))
    np.testing.assert_array_equal(since.time_s, window.time_s[-300:])
