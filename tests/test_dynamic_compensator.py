"""The live dynamic compensation's per-batch shortcuts give what the straightforward computation gives.

procedures/dynamic_compensation.py keeps the sensor clock's sums and envelope candidates between reads, reads only
the newest robot states, runs the model only for the new ones (RNEA, ftacq.dynamics.model.WrenchPredictor) and
keeps the predictions in a ring; ftacq.dynamics.timing.interpolate_rows avoids temporaries. Each is compared here
with a plain version of what it replaced: the sensor clock bit for bit, the compensated wrench to 1e-12 N (the
predictor itself against the regressor: tests/test_dynamics_identify.py).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.ur_ft_input import ControllerCycle
from ftacq.dynamics.acceleration import joint_acceleration
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import ur_model
from procedures.bridge import CycleStates
from procedures.dynamic_compensation import (
    ENVELOPE_READS,
    PERIOD_FIT_SPAN_S,
    STATE_WINDOW_ROWS,
    DynamicCompensator,
    SensorClock,
)
from tests.fakes.world import CellTruth

pytest.importorskip("pinocchio")
MODEL = ur_model("UR5e")


class PlainSensorClock:
    """The sensor clock as every read evaluated it before: sums in an array, all candidates re-evaluated."""

    def __init__(self, nominal_period_s: float | None) -> None:
        self.nominal = nominal_period_s
        self.restart()

    def restart(self) -> None:
        self.origin: tuple[float, float] | None = None
        self.sums = np.zeros(5)
        self.points = np.empty((ENVELOPE_READS, 2))
        self.count = 0
        self.last = -np.inf

    def host_times(self, arrival: np.ndarray, sequence: np.ndarray) -> np.ndarray:
        seq = np.asarray(sequence, dtype=float)
        if np.any(np.diff(seq) <= 0):
            return arrival
        if self.origin is not None and seq[0] - self.origin[0] <= self.last:
            self.restart()
        if self.origin is None:
            self.origin = (float(seq[0]), float(arrival[0]))
        s, a = seq - self.origin[0], arrival - self.origin[1]
        self.last = float(s[-1])
        self.sums += (s.size, s.sum(), a.sum(), (s * s).sum(), (s * a).sum())
        n, ss, sa, sss, ssa = self.sums
        if self.nominal is not None and self.last * self.nominal < PERIOD_FIT_SPAN_S:
            period = self.nominal
        else:
            denominator = n * sss - ss * ss
            if n < 50 or denominator <= 0:
                return arrival
            period = (n * ssa - ss * sa) / denominator
        best = int(np.argmin(a - s * period))
        self.points[self.count % ENVELOPE_READS] = s[best], a[best]
        self.count += 1
        points = self.points[:min(self.count, ENVELOPE_READS)]
        return self.origin[1] + s * period + float(np.min(points[:, 1] - points[:, 0] * period))


def sensor_reads(seconds: float, seed: int, restart_at_s: float | None = None):
    """(arrival, sequence) reads of 10-18 samples at 7 kHz with a jittered, coalesced arrival (and a restart)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 7000)
    sequence = np.arange(n) + 17
    arrival = 500.0 + sequence / 7000.0 * (1 + 3e-5) + 0.0003 + rng.exponential(0.0004, n)
    arrival = np.maximum.accumulate(arrival)
    if restart_at_s is not None:
        k = int(restart_at_s * 7000)
        sequence[k:] -= sequence[k] - 1
    reads, i = [], 0
    while i < n:
        size = int(rng.integers(10, 19))
        reads.append((arrival[i:i + size].copy(), sequence[i:i + size].copy()))
        i += size
    return reads


@pytest.mark.parametrize("nominal", [1 / 7000, None])
def test_sensor_clock_gives_the_plain_evaluation_bit_for_bit(nominal):
    # 14 s: the nominal period, then the least-squares one (PERIOD_FIT_SPAN_S), with a restarted count at 12 s
    reads = sensor_reads(14.0, seed=2, restart_at_s=12.0)
    clock, plain = SensorClock(True, nominal), PlainSensorClock(nominal)
    for arrival, sequence in reads:
        np.testing.assert_array_equal(clock.host_times(arrival, sequence), plain.host_times(arrival, sequence))


def cycles(count: int, seed: int):
    """Controller cycles of a smooth motion; target q̇ leaves actual q̇ (the derivative path) now and then."""
    rng = np.random.default_rng(seed)
    t = np.arange(count) * 0.002
    phase = 2 * np.pi * t[:, None] / np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1])
    q = np.array([0.1, -1.2, 1.0, -1.4, -1.6, 0.2]) + 0.6 * np.sin(phase)
    qd = 0.6 * np.cos(phase) * 2 * np.pi / np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1]) + rng.normal(0, 1e-4, (count, 6))
    off = (np.mod(t, 0.5) < 0.05)[:, None]
    received = 80.0 + t + rng.uniform(1e-4, 4e-4, count)
    for k in range(count):
        yield ControllerCycle(timestamp_s=float(t[k]), q=q[k], qd=qd[k], tcp_force=np.zeros(6), runtime_state=2,
                              safety_status_bits=1, received_s=float(received[k]), tcp_pose=np.zeros(6),
                              target_qd=qd[k] + 0.05 * off[k], target_qdd=-q[k] * 0.3)


def plain_compensation(compensator: DynamicCompensator, states: CycleStates, batch, kept: dict) -> np.ndarray | None:
    """What the compensator computed before: the whole window's q̈ each batch, the model for the new states,
    the newest STATE_WINDOW_ROWS predictions kept by concatenation."""
    window = states.window(last=STATE_WINDOW_ROWS)
    new = window.controller_time_s > kept["last"]
    if np.any(new):
        qdd, _ = joint_acceleration(window.time_s, window.qd, window.target_qd, window.qdd)
        predicted = compensator.predictor(window.q[new], window.qd[new], qdd[new])
        kept["times"] = np.concatenate([kept["times"], window.time_s[new]])[-STATE_WINDOW_ROWS:]
        kept["predicted"] = np.vstack([kept["predicted"], predicted])[-STATE_WINDOW_ROWS:]
        kept["last"] = float(window.controller_time_s[-1])
    times = batch.time_s - compensator.lag_s
    if kept["times"].size >= 2 and times[0] >= kept["times"][0] and times[-1] <= kept["times"][-1] + 0.05:
        return batch.wrench - interpolate_rows(times, kept["times"], kept["predicted"])
    return None


def test_dynamic_compensator_gives_the_whole_window_evaluation():
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states = CycleStates()
    # a sensor whose sequence does not count samples: the batch keeps its times (the clock is compared above)
    compensator = DynamicCompensator(calibration, MODEL, states, lag_s=0.0012, counts_samples=False)
    kept = {"times": np.empty(0), "predicted": np.empty((0, 6)), "last": -np.inf}
    rng = np.random.default_rng(6)
    compared = 0
    for k, cycle in enumerate(cycles(1400, seed=7)):
        states.append(cycle)
        if 300 <= k < 340 or k % 97 == 5:
            continue  # a stall (many new states at the next batch), and batches skipped now and then
        newest_state_s = float(states.window(last=1).time_s[-1])
        offsets = np.sort(rng.uniform(-0.003, 0.0008, int(rng.integers(8, 20))))
        batch = SimpleNamespace(time_s=newest_state_s + compensator.lag_s + offsets, sequence=np.arange(len(offsets)),
                                wrench=rng.normal(size=(len(offsets), 6)))
        if k == 700:
            batch.time_s = batch.time_s - 1.0  # no states around it: compensated statically (None without a pose)
        got = compensator.compensate(batch, None)
        expected = plain_compensation(compensator, states, batch, kept)
        if expected is None:
            assert got is None
            continue
        compared += 1
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert compared > 1000
    assert compensator.static_batches >= 1 and compensator.derivative_states > 0  # both paths ran
