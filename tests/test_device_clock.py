"""ftacq/timebase.py: a device's own clock on the host's, from arrival stamps alone (numpy arrays, no sockets).

A sensor whose crystal runs 150 ppm off the host's, sending in bursts through a queue with random delays and
stalls, and skipping samples; a UR controller ±200 ppm off with jittered, batched reads (tests/fakes/drifting_link.py);
the Net F/T's 32-bit sample counter as device time. Each mapped time is compared with the truth.

The least-squares period fit that :class:`DeviceClock` replaced was 0.2 % off on such arrivals: 2 ms per second of
run, so a bound of 0.5 ms over ten minutes catches it many times over (as it catches a 100 ppm drift allowance
at ±200 ppm: 6 ms after a minute).
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.netft.device_time import SampleCounterClock
from ftacq.timebase import (
    MAX_RATE_ERROR,
    SETTLE_SPAN_S,
    DeviceClock,
    SampleClock,
    device_to_host_clock,
)
from tests.clock_arrivals import bursting_sensor, reads_of
from tests.fakes.drifting_link import MIN_DELAY_S, simulate

BOUND_S = 0.0005
"""A settled mapping's time of a sample may be off its true time by at most this, s."""
SETTLED_AFTER_S = 10.0
"""Device time after which the mapping must hold the bound (the first seconds have few fast samples), s."""


@pytest.mark.parametrize("rate_error", [150e-6, -150e-6], ids=["+150ppm", "-150ppm"])
def test_sensor_sample_times_stay_within_half_a_millisecond_over_ten_minutes(rate_error):
    device, truth, arrival = bursting_sensor(600.0, rate_error, seed=3)
    clock = SampleClock()
    mapped = np.empty_like(device)
    uncertainty = []
    for read in reads_of(arrival):
        mapped[read] = clock.host_times(arrival[read], device[read])
        uncertainty.append(clock.uncertainty_s)
    # never later than the sample arrived (the line is under every point of its window, the new read's included)
    assert np.all(mapped <= arrival + 1e-9)
    settled = device > device[0] + SETTLED_AFTER_S
    error = mapped[settled] - truth[settled]
    assert np.abs(error).max() <= BOUND_S
    assert clock.rate_error == pytest.approx(rate_error, abs=5e-6)
    assert clock.clock.settled and clock.clock.span_s >= SETTLE_SPAN_S
    assert np.median(uncertainty[len(uncertainty) // 2:]) < BOUND_S  # it says it is sure, and it is


def test_a_whole_recording_maps_through_its_minimum_delay_line():
    # the recorded motion for identification: 40 s with skipped samples, mapped at once
    device, truth, arrival = bursting_sensor(40.0, 150e-6, seed=8)
    mapped = device_to_host_clock(device, arrival)
    assert np.all(mapped <= arrival + 1e-9)
    assert np.abs(mapped - truth).max() <= BOUND_S
    # skipped samples are gaps of device time: the samples after them are not shifted
    np.testing.assert_allclose(np.diff(mapped), np.diff(device) * (1 + 150e-6), atol=2e-5)
    # no device clock (a polled sensor): the arrival stamps
    np.testing.assert_array_equal(device_to_host_clock(np.full(5, np.nan), arrival[:5]), arrival[:5])


@pytest.mark.parametrize("drift", [200e-6, -200e-6], ids=["host-fast", "host-slow"])
def test_controller_clock_follows_200_ppm_with_jitter_and_stalls(drift):
    link = simulate(drift, 600.0, np.random.default_rng(11))
    batched, single = DeviceClock(), DeviceClock()
    by_read = np.empty_like(link.timestamp_s)
    by_package = np.empty_like(link.timestamp_s)
    bounds = np.flatnonzero(np.diff(link.read)) + 1
    for part in np.split(np.arange(link.timestamp_s.size), bounds):
        batched.observe(link.timestamp_s[part], link.arrival_s[part[0]])  # URStateStream: one stamp per read
        by_read[part] = batched.map_times(link.timestamp_s[part])
    for k in range(link.timestamp_s.size // 4):  # the bridge: one package per controller cycle, floats (2.5 min)
        single.observe_one(float(link.timestamp_s[k]), float(link.arrival_s[k]))
        by_package[k] = single.map_time(float(link.timestamp_s[k]))
    truth = link.true_host_s + MIN_DELAY_S
    settled = link.timestamp_s > link.timestamp_s[0] + SETTLED_AFTER_S
    quarter = slice(0, link.timestamp_s.size // 4)
    for mapped, clock, rows in ((by_read, batched, slice(None)), (by_package, single, quarter)):
        assert np.all(mapped[rows] <= link.arrival_s[rows] + 1e-9)
        assert np.abs(mapped[rows][settled[rows]] - truth[rows][settled[rows]]).max() <= BOUND_S
        assert clock.rate_error == pytest.approx(drift, abs=5e-6)
        assert clock.settled


def test_restart_and_late_samples():
    clock = DeviceClock()
    clock.observe(np.arange(0.0, 20.0, 0.002), 100.0 + np.arange(0.0, 20.0, 0.002))
    assert clock.map_time(20.0) == pytest.approx(120.0)
    clock.observe_one(19.5, 200.0)  # a late sample half a second back: ignored
    assert clock.restarts == 0 and clock.map_time(20.0) == pytest.approx(120.0)
    clock.observe(np.array([1.0, 1.002]), np.array([500.0, 500.002]))  # the device restarted its count
    assert clock.restarts == 1 and clock.map_time(1.0) == pytest.approx(500.0)
    clock.observe_one(100.0, 599.0)  # a silence longer than the window: a new mapping, at the new offset
    assert clock.restarts == 2 and clock.map_time(100.0) == pytest.approx(599.0)


def test_rate_is_bounded_and_a_short_span_is_unsure():
    clock = DeviceClock()
    assert np.isnan(clock.map_times(np.array([1.0]))[0]) and clock.uncertainty_s == np.inf  # nothing seen yet
    # a queue filling: arrival − device time rising by 1 ms per second is not a clock
    device = np.arange(0.0, 3.0, 0.01)
    clock.observe(device, 50.0 + device * 1.001)
    assert abs(clock.rate_error) <= MAX_RATE_ERROR
    assert np.all(clock.map_times(device) <= 50.0 + device * 1.001 + 1e-12)
    assert not clock.settled  # 3 s of span


def test_sample_counter_unwraps_its_32_bits_and_shows_skipped_samples_as_gaps():
    counter = SampleCounterClock(internal_rate_hz=7000.0)
    first = (1 << 32) - 21
    ft = (first + 7 * np.arange(6)) & 0xFFFF_FFFF  # 1 kHz records, wrapping at the fourth
    times = counter.device_times(ft)
    np.testing.assert_allclose(np.diff(times), 0.001)
    skipped = (int(ft[-1]) + 7 * np.array([1, 2, 6, 7])) & 0xFFFF_FFFF  # three records never received
    more = counter.device_times(skipped)
    np.testing.assert_allclose(np.diff(np.concatenate([times, more])), [0.001] * 7 + [0.004, 0.001])
    # a power cycle after a day of running: the counter back near zero is device time going back a day (the
    # mapping starts anew)
    running = SampleCounterClock(internal_rate_hz=7000.0)
    before = running.device_times(np.array([604_800_000, 604_800_007]))
    after = running.device_times(np.array([3, 10]))
    assert after[0] < before[-1] - 3600.0 and after[1] - after[0] == pytest.approx(0.001)
