"""A UR controller's RTDE packages as a host with a drifting clock receives them: no sockets, no threads, no sleeps.

The controller stamps package i with its own ``timestamp`` (its clock, s). The host's monotonic clock reads
``host_origin_s + timestamp × (1 + drift)`` at that moment (``drift`` in s/s: +50e-6 is a host clock 50 ppm faster
than the controller's). Each package then travels ``MIN_DELAY_S`` plus a random delay (exponential, as a switch
and a busy kernel give), in order (TCP), and now and then the link stalls (a queue: every package sent during the
stall arrives at its end, together). The receiving thread reads several packages at once, each read stamped when
it returns: the arrival of its last package. That is what drivers/ur_stream.py and the bridge see, over simulated
hours, in a fraction of a second.

:func:`simulate` returns the packages' timestamps, their true host times, their arrival stamps and the index of the
read each came in. :func:`data_packages` packs rows as RTDE data packages of drivers/ur_stream.py's output recipe
(docs/protocols-ur.md, "RTDE framing").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PERIOD_S = 0.002
"""The controller's output period (500 Hz, e-Series), s."""
MIN_DELAY_S = 0.0002
"""The fastest transport from the controller to the reading thread, s: part of the constant lag, not of the clock."""
MEAN_EXTRA_DELAY_S = 0.0003
STALL_PROBABILITY = 0.002
"""Chance per package that the link stalls from it on (the kernel, a descheduled reader, a switch)."""
MAX_STALL_S = 0.03
MAX_PACKAGES_PER_READ = 5


@dataclass(frozen=True)
class Link:
    """Packages of one simulated stream, oldest first (s)."""

    timestamp_s: np.ndarray
    """The controller's timestamp of each package."""
    true_host_s: np.ndarray
    """The host clock's reading when the controller stamped it (what a perfect mapping returns, less MIN_DELAY_S)."""
    arrival_s: np.ndarray
    """The host receive stamp of each package (that of the read it came in)."""
    read: np.ndarray
    """The index of the read each package came in (packages of one read are consecutive)."""


def simulate(drift: float, duration_s: float, rng: np.random.Generator, active_s: float | None = None,
             every_s: float | None = None, host_origin_s: float = 5000.0, start_timestamp_s: float = 12.0) -> Link:
    """Packages over ``duration_s`` of controller time with the host clock drifting by ``drift`` (s/s).

    With ``active_s`` and ``every_s``, only the packages of the first ``active_s`` of every ``every_s`` are made
    (a few hours at 500 Hz in a few thousand packages; the clocks drift through the gaps all the same)."""
    count = int(round(duration_s / PERIOD_S))
    timestamp = start_timestamp_s + PERIOD_S * np.arange(count)
    if active_s is not None and every_s is not None:
        timestamp = timestamp[(timestamp - start_timestamp_s) % every_s < active_s]
    n = timestamp.size
    true_host = host_origin_s + timestamp * (1.0 + drift)
    arrival = true_host + MIN_DELAY_S + rng.exponential(MEAN_EXTRA_DELAY_S, n)
    stalls = np.zeros(n)
    starts = np.nonzero(rng.random(n) < STALL_PROBABILITY)[0]
    stalls[starts] = arrival[starts] + rng.uniform(0.0, MAX_STALL_S, starts.size)
    arrival = np.maximum(arrival, np.maximum.accumulate(stalls))  # sent during a stall: arrives at its end
    arrival = np.maximum.accumulate(arrival)  # in order
    first = np.zeros(n, dtype=bool)  # packages that start a read: every 1 to 5, and the first after a gap
    starts = np.cumsum(rng.integers(1, MAX_PACKAGES_PER_READ + 1, n))
    first[starts[starts < n]] = True
    first[0] = True
    first[1:] |= np.diff(timestamp) > 1.5 * PERIOD_S
    read = np.cumsum(first) - 1
    last_of_read = np.nonzero(np.diff(read, append=read[-1] + 1))[0]
    return Link(timestamp, true_host, arrival[last_of_read][read], read)


DATA_PACKAGE = np.dtype([("size", ">u2"), ("type", "u1"), ("recipe", "u1"), ("values", ">f8", (25,))])
"""An RTDE data package (type ``U``) of the output recipe timestamp, actual_q, actual_qd, target_qd, target_qdd."""


def data_packages(values: np.ndarray, recipe: int = 1) -> bytes:
    """The wire bytes of one data package per row of ``values`` (N, 25): timestamp, then the four VECTOR6D."""
    packages = np.zeros(len(values), DATA_PACKAGE)
    packages["size"], packages["type"], packages["recipe"] = DATA_PACKAGE.itemsize, ord("U"), recipe
    packages["values"] = values
    return packages.tobytes()


def text_message(text: str) -> bytes:
    """A controller text message package (type ``M``): the stream skips it."""
    body = text.encode()
    return (3 + len(body)).to_bytes(2, "big") + b"M" + body
