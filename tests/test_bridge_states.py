"""procedures/bridge.py CycleStates (the controller cycles as the dynamic model's robot state stream): on the host
clock as drivers/ur_stream.py puts the same packages, following a host clock drifting ±200 ppm over simulated hours
(tests/fakes/drifting_link.py). No network, no sleeps."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.ur_ft_input import ControllerCycle
from drivers.ur_stream import OFFSET_COLUMN, ROW_COLUMNS, StateWindow
from ftacq.timebase import DeviceClock
from procedures.bridge import CycleStates
from tests.fakes.drifting_link import MIN_DELAY_S, simulate

BOUND_S = 0.0005
"""A state's host time may be off the truth plus the fastest transport by at most this, s."""


def _cycle(timestamp_s: float, received_s: float) -> ControllerCycle:
    q = np.sin(timestamp_s / np.arange(1, 7))
    return ControllerCycle(timestamp_s=timestamp_s, q=q, qd=np.cos(q), tcp_force=np.zeros(6), runtime_state=2,
                           safety_status_bits=1, received_s=received_s, tcp_pose=np.zeros(6),
                           target_qd=0.5 * np.cos(q), target_qdd=-q)


@pytest.mark.parametrize("drift", [200e-6, -200e-6], ids=["host-fast", "host-slow"])
def test_cycle_states_follow_a_drifting_host_clock(drift):
    # half a second of cycles every half minute over three hours, one package per cycle
    link = simulate(drift, 3 * 3600.0, np.random.default_rng(9), active_s=0.5, every_s=30.0)
    states = CycleStates()
    stretch_ends = np.flatnonzero(np.diff(link.timestamp_s, append=np.inf) > 1.0)
    start = 0
    for end in stretch_ends:
        for k in range(start, end + 1):
            states.append(_cycle(float(link.timestamp_s[k]), float(link.arrival_s[k])))
        window = states.window(last=64)  # what the dynamic compensator asks for, once per cycle
        truth = link.true_host_s[end - 63:end + 1] + MIN_DELAY_S
        np.testing.assert_array_equal(window.controller_time_s, link.timestamp_s[end - 63:end + 1])
        error = window.time_s - truth
        assert np.abs(error).max() < BOUND_S
        assert np.all(window.time_s <= link.arrival_s[end - 63:end + 1] + 1e-9)
        start = end + 1
    np.testing.assert_array_equal(window.q[-1], np.sin(link.timestamp_s[-1] / np.arange(1, 7)))
    np.testing.assert_array_equal(window.qdd[-1], -window.q[-1])  # target q̈, laid out as the stream's rows


def test_cycle_states_and_the_state_stream_map_the_same_packages_alike():
    link = simulate(40e-6, 30.0, np.random.default_rng(2))
    states = CycleStates(capacity=link.timestamp_s.size)
    for timestamp_s, arrival_s in zip(link.timestamp_s, link.arrival_s):
        states.append(_cycle(float(timestamp_s), float(arrival_s)))
    rows = np.zeros((link.timestamp_s.size, ROW_COLUMNS))
    rows[:, 0], rows[:, 1] = link.arrival_s, link.timestamp_s
    clock = DeviceClock()
    for k in range(link.timestamp_s.size):  # as URStateStream keeps them (here one package a read)
        clock.observe(link.timestamp_s[k:k + 1], link.arrival_s[k])
        rows[k, OFFSET_COLUMN] = clock.map_times(link.timestamp_s[k]) - link.timestamp_s[k]
    np.testing.assert_allclose(states.window(last=len(rows)).time_s, StateWindow.from_rows(rows, clock).time_s,
                               rtol=0, atol=1e-9)
    assert states.clock.offset_s == pytest.approx(rows[-1, OFFSET_COLUMN], abs=1e-9)
