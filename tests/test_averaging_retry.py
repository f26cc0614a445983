"""The averaging policy at a still pose (procedures.settle.average_at_pose): a short window is taken again over a
longer one, and the fullest is kept.

The sensor here is a stand-in that delivers a fixed share of its promised rate (a shared CAN bus or a starved host
delivers in bursts at a fraction of the rate): the policy is the unit under test; the wire paths of a silent or
lossy device are covered with the real protocols in test_netft_silence.py."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sensor import SensorInfo, WrenchAverage
from ftacq.errors import SensorFaultError
from procedures.settle import MAX_AVERAGE_ATTEMPTS, MIN_SAMPLE_FRACTION, SettleSettings, average_at_pose

RATE_HZ = 1000.0
SETTINGS = SettleSettings(average_time_s=0.1, sensor_timeout_s=0.5)


class TricklingSensor:
    """Delivers ``share`` of the samples its rate promises over any window (no I/O; windows are not waited)."""

    def __init__(self, share: float) -> None:
        self.share = share
        self.windows_s: list[float] = []
        self.info = SensorInfo(transport="stand-in", serial="", firmware="", force_unit="N", torque_unit="Nm",
                               counts_per_force=1.0, counts_per_torque=1.0, rate_hz=RATE_HZ)

    def average(self, duration_s: float, timeout_s: float) -> WrenchAverage:
        assert timeout_s >= duration_s  # every window may wait at least its own length
        self.windows_s.append(duration_s)
        count = int(self.share * RATE_HZ * duration_s)
        return WrenchAverage(mean=np.full(6, 1.0), std=np.full(6, 0.01), count=count, saturated=0, lost=0,
                             duration_s=duration_s)


def test_a_sensor_at_a_fifth_of_its_rate_is_averaged_over_a_longer_window() -> None:
    """20 % of the rate: 20 of the 50 samples wanted in 0.1 s, 40 in 0.2 s, 80 in 0.4 s: the third window is kept
    (the old policy repeated 0.1 s five times and kept 20 samples, or failed when a starved link gave 1)."""
    sensor = TricklingSensor(share=0.2)
    average, _, _ = average_at_pose(sensor, SETTINGS)
    assert sensor.windows_s == pytest.approx([0.1, 0.2, 0.4])
    assert average.count >= MIN_SAMPLE_FRACTION * RATE_HZ * SETTINGS.average_time_s


def test_the_fullest_window_is_kept_and_too_few_samples_fail_with_the_figures() -> None:
    sensor = TricklingSensor(share=0.001)  # 1 sample per second: 0, 0, 0, 0, 1
    with pytest.raises(SensorFaultError, match=rf"only 1 usable sample\(s\) in the fullest of {MAX_AVERAGE_ATTEMPTS}"):
        average_at_pose(sensor, SETTINGS)
    assert len(sensor.windows_s) == MAX_AVERAGE_ATTEMPTS
    assert sensor.windows_s[-1] == pytest.approx(SETTINGS.average_time_s * 2 ** (MAX_AVERAGE_ATTEMPTS - 1))


def test_a_full_first_window_is_taken_once() -> None:
    sensor = TricklingSensor(share=1.0)
    average, t_start, t_end = average_at_pose(sensor, SETTINGS)
    assert sensor.windows_s == [SETTINGS.average_time_s] and average.count == 100 and t_end >= t_start
