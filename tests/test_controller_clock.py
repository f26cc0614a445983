"""ftacq/dynamics/timing.py ControllerClock and settled_offsets: the UR controller's timestamp on the host clock over
simulated hours with a host clock drifting ±50 ppm and random queueing delays (tests/fakes/drifting_link.py); no
network, no sleeps."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.dynamics.timing import CLOCK_DRIFT_ALLOWANCE, ControllerClock, settled_offsets
from tests.fakes.drifting_link import MIN_DELAY_S, Link, simulate

HOURS_S = 3 * 3600.0
BOUND_S = 0.001
"""A mapped state time may be later than the truth plus the fastest transport by at most this, s."""


def _observe_by_read(clock: ControllerClock, link: Link) -> np.ndarray:
    """Each package's offset as the clock gives it, one read (a batch sharing one arrival stamp) at a time."""
    bounds = np.flatnonzero(np.diff(link.read)) + 1
    pieces = [clock.observe(link.arrival_s[part[0]], link.timestamp_s[part])
              for part in np.split(np.arange(link.timestamp_s.size), bounds)]
    return np.concatenate(pieces)


def _observe_in_chunks(clock: ControllerClock, link: Link, rows: int = 5000) -> np.ndarray:
    """The same in batches of many reads (each row with its read's stamp): equal, and fast for hours of packages."""
    return np.concatenate([clock.observe(link.arrival_s[i:i + rows], link.timestamp_s[i:i + rows])
                           for i in range(0, link.timestamp_s.size, rows)])


@pytest.mark.parametrize("drift", [50e-6, -50e-6], ids=["host-fast", "host-slow"])
def test_mapped_times_stay_on_the_truth_over_hours_of_drift(drift):
    rng = np.random.default_rng(7)
    clock = ControllerClock()
    for hour in range(3):  # three hours at 500 Hz in one-hour pieces (5.4 M packages in all)
        link = simulate(drift, 3600.0, rng, start_timestamp_s=12.0 + 3600.0 * hour)
        offsets = _observe_in_chunks(clock, link)
        truth = link.true_host_s + MIN_DELAY_S
        error = link.timestamp_s + offsets - truth
        settled = link.timestamp_s + settled_offsets(link.timestamp_s, offsets) - truth
        if hour == 0:
            error = error[500:]  # in the first second the first reads' delays are all there is to go by
        # never earlier than the truth plus the fastest transport (the envelope is a bound), at most 1 ms later,
        # at every package and still after three hours (50 ppm of three hours is 0.54 s)
        assert error.min() > -1e-9 and settled.min() > -1e-9
        assert error.max() < BOUND_S and settled.max() < BOUND_S
        assert abs(error[-1]) < BOUND_S and np.median(error) < 0.2e-3
    assert clock.offset_s == pytest.approx(offsets[-1])


@pytest.mark.parametrize("drift", [50e-6, -50e-6], ids=["host-fast", "host-slow"])
def test_a_plain_lower_envelope_drifts_where_the_clock_does_not(drift):
    """What the clock fixes: the plain min of (arrival − timestamp) never rises, so with the host fast the states
    end up 50 ppm × the run's duration older than they are (0.54 s after three hours)."""
    link = simulate(drift, HOURS_S, np.random.default_rng(3), active_s=1.0, every_s=60.0)
    truth = link.true_host_s + MIN_DELAY_S
    plain = link.timestamp_s[-1] + np.min(link.arrival_s - link.timestamp_s) - truth[-1]
    mapped = link.timestamp_s[-1] + _observe_by_read(ControllerClock(), link)[-1] - truth[-1]
    assert 0 <= mapped < BOUND_S
    if drift > 0:
        assert plain == pytest.approx(-drift * (link.timestamp_s[-1] - link.timestamp_s[0]), abs=0.01)
    else:
        assert 0 <= plain < BOUND_S  # a slower host lowers the envelope: the min follows at once


def test_one_package_at_a_time_equals_the_batches():
    link = simulate(-30e-6, 20.0, np.random.default_rng(11))
    batched = _observe_by_read(ControllerClock(), link)
    np.testing.assert_array_equal(_observe_in_chunks(ControllerClock(), link, rows=777), batched)
    one = ControllerClock()
    singles = np.array([one.observe_one(float(a), float(t)) for a, t in zip(link.arrival_s, link.timestamp_s)])
    np.testing.assert_allclose(singles, batched, rtol=0, atol=1e-9)
    assert one.offset_s == pytest.approx(batched[-1], abs=1e-9)


def test_the_offset_rises_at_most_by_the_allowance_and_falls_at_once():
    clock = ControllerClock()
    assert clock.offset_s is None
    assert clock.observe_one(100.0, 0.0) == 100.0
    # a package that waited 5 ms longer one second later: the offset rises by the allowance only
    assert clock.observe_one(101.005, 1.0) == pytest.approx(100.0 + CLOCK_DRIFT_ALLOWANCE)
    # one that waited less: followed at once
    assert clock.observe_one(101.9999, 2.0) == pytest.approx(99.9999)
    offsets = clock.observe(np.array([103.5, 104.5]), np.array([3.0, 4.0]))  # both queued
    np.testing.assert_allclose(offsets, [99.9999 + CLOCK_DRIFT_ALLOWANCE, 99.9999 + 2 * CLOCK_DRIFT_ALLOWANCE])


def test_a_timestamp_going_backwards_starts_the_mapping_anew():
    clock = ControllerClock()
    clock.observe(np.array([100.0, 100.002]), np.array([50.0, 50.002]))  # offset 50 s
    # another session: the controller's clock restarted near 0, the host's did not
    offsets = clock.observe(np.array([200.0, 200.002, 200.0041]), np.array([50.004, 0.0, 0.002]))
    np.testing.assert_allclose(offsets, [50.0 + 0.004 * CLOCK_DRIFT_ALLOWANCE, 200.002,
                                         200.002 + 0.002 * CLOCK_DRIFT_ALLOWANCE])
    assert clock.observe_one(300.0, 1.0) == pytest.approx(200.002 + CLOCK_DRIFT_ALLOWANCE * 1.0)
    assert clock.observe_one(300.0, 0.5) == 299.5


def test_settled_offsets_lower_the_rows_before_a_faster_package_and_keep_the_order():
    timestamp = 0.002 * np.arange(6)
    # the stream starts with a queue: the first rows waited 8 to 2 ms, the fifth arrived as fast as any
    arrival = 1000.0 + timestamp + np.array([0.008, 0.006, 0.004, 0.002, 0.0002, 0.0003])
    clock = ControllerClock()
    causal = clock.observe(arrival, timestamp)
    assert np.any(np.diff(timestamp + causal) < 0)  # as they arrived, host times ran backwards
    settled = settled_offsets(timestamp, causal)
    np.testing.assert_allclose(settled[:5], 1000.0002 - CLOCK_DRIFT_ALLOWANCE * (timestamp[4] - timestamp[:5]))
    assert settled[5] == causal[5]  # the newest row has nothing after it
    assert np.all(np.diff(timestamp + settled) > 0)
    assert np.all(np.abs(np.diff(settled)) <= CLOCK_DRIFT_ALLOWANCE * np.diff(timestamp) + 1e-12)
    # only later rows change a row: a shorter window settles its rows as the whole one does
    np.testing.assert_array_equal(settled_offsets(timestamp[3:], causal[3:]), settled[3:])
    np.testing.assert_array_equal(settled_offsets(timestamp[::-1], causal[::-1]), causal[::-1])  # not in order
