"""The motion recorder (procedures/motion_runner.MotionRecorder): paced reads, every sample kept."""

from __future__ import annotations

import time

import numpy as np

from drivers.sensor import WrenchBatch
from procedures.motion_runner import READ_PERIOD_S, MotionRecorder
from tests.conftest import wait_until


class EveryCallSensor:
    """A sensor that always has a new sample: each read returns one more (an unpaced reader would read as fast as
    it can)."""

    def __init__(self) -> None:
        self.produced = 0

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        self.produced += 1
        k = self.produced
        return WrenchBatch(time_s=np.array([float(k)]), wrench=np.zeros((1, 6)),
                           counts=np.zeros((1, 6), dtype=np.int64), status=np.zeros(1, dtype=np.uint32), sequence=np.array([k]), saturated=np.zeros(1, bool))


class NoStates:
    count = 0


def test_the_recorder_reads_at_its_pace_and_keeps_every_sample_to_the_end() -> None:
    sensor = EveryCallSensor()
    recorder = MotionRecorder(sensor, NoStates())
    started_s = time.monotonic()
    recorder.start()
    wait_until(lambda: len(recorder.batches) >= 10, timeout_s=30.0)
    recorder.stop()
    elapsed_s = time.monotonic() - started_s
    assert recorder.error is None
    kept = np.concatenate([b.sequence for b in recorder.batches])
    # every sample the sensor produced after start()'s first read is kept, in order, the last included (the
    # final read after the stop)
    np.testing.assert_array_equal(kept, np.arange(2, sensor.produced + 1))
    # paced: at most one read per READ_PERIOD_S (a busy reader would have read thousands of times by now)
    assert len(recorder.batches) <= elapsed_s / READ_PERIOD_S + 2
