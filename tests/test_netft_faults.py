"""One test per fault knob of the fake Net F/T: the driver's counters and flags match what was injected.

Each test injects a fault into a running stream, waits (on the fake's condition) until the fault went out, then reads
until the driver has seen records well past it, and checks every counter, not just the one the fault should move.
"""

from __future__ import annotations

import numpy as np
import pytest

from drivers.netft import NetFTSensor
from drivers.sensor import WrenchBatch
from ftacq.errors import DeviceTimeoutError, SensorFaultError
from tests.fakes.netft import FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RATE_HZ = 1000.0
READ_TIMEOUT_S = 2.0
STREAM_TIMEOUT_S = 2.0
"""Driver silence timeout in these tests: long, so a loaded CI machine causes no spurious reconnect (which would
make a device restart look like the driver's own)."""
SILENCE_TIMEOUT_S = 0.3
"""Driver silence timeout in the go-silent test."""
RECORDS_PAST_FAULT = 20
"""The driver must have delivered records this far past the fault before counters are checked."""
COUNTERS = ("lost", "duplicate", "out_of_order", "malformed", "foreign", "stalled", "saturated", "status_errors",
            "restarts")


@pytest.fixture
def fake():
    physics = SensorPhysics(CellTruth(), SettablePose(), seed=11)
    with FakeNetFT(physics, rate_hz=RATE_HZ, torque_unit="N-mm", counts_per_torque=1_000) as device:
        yield device


@pytest.fixture
def sensor(fake, request):
    timeout_s = SILENCE_TIMEOUT_S if "silent" in request.node.name else STREAM_TIMEOUT_S
    with NetFTSensor.from_url(fake.url, timeout_s=timeout_s) as driver:
        driver.read(timeout_s=READ_TIMEOUT_S)
        yield driver


def settle(sensor: NetFTSensor, fake: FakeNetFT) -> list:
    """Wait until the fake applied its pending faults, then read until the driver delivered records well past them;
    return the batches read."""
    fake.wait_until(lambda f: not f.faults_pending, what="faults applied")
    target = fake.records_sent + RECORDS_PAST_FAULT  # well-formed records sent, duplicates included
    fake.wait_for_records(target)
    batches = [sensor.read(timeout_s=READ_TIMEOUT_S)]
    while sensor.health().received < target:
        batches.append(sensor.read(timeout_s=READ_TIMEOUT_S))
    try:
        batches.append(sensor.read(timeout_s=0.0))  # what health() decoded last
    except DeviceTimeoutError:
        pass
    return batches


def counters(sensor: NetFTSensor) -> dict:
    health = sensor.health()
    return {name: getattr(health, name) for name in COUNTERS}


def expect(**nonzero) -> dict:
    return {name: nonzero.get(name, 0) for name in COUNTERS}


def test_dropped_records_count_as_lost(sensor, fake) -> None:
    fake.drop(5)
    settle(sensor, fake)
    assert counters(sensor) == expect(lost=5)
    assert fake.records_dropped == 5


def test_dropped_records_are_a_gap_in_device_time(sensor, fake) -> None:
    # the box's own sample counter (ft_sequence) counts the samples the host never received: the device time of the
    # delivered samples steps over them instead of compressing the clock (what the packet count would do)
    before = sensor.read(timeout_s=READ_TIMEOUT_S)  # the last records before the drop: the gap lies after them
    fake.drop(5)
    batches = [before, *settle(sensor, fake)]
    period_s = 1.0 / RATE_HZ
    for _ in range(RECORDS_PAST_FAULT):  # the records past the gap may still be held for late ones: read them
        batch = WrenchBatch.concatenate(batches)
        if np.any(np.diff(batch.device_time_s) > 1.5 * period_s):
            break
        batches.append(sensor.read(timeout_s=READ_TIMEOUT_S))
    batch = WrenchBatch.concatenate(batches)
    steps = np.diff(batch.device_time_s)
    gap = np.flatnonzero(steps > 1.5 * period_s)
    assert gap.size == 1 and steps[gap[0]] == pytest.approx(6 * period_s)
    np.testing.assert_allclose(np.delete(steps, gap), period_s)
    assert np.all(np.diff(batch.sequence)[np.delete(np.arange(steps.size), gap)] == 1)
    sent = fake.sent_records()
    ft_of = dict(zip(sent["rdt_sequence"].tolist(), sent["ft_sequence"].tolist()))
    expected = np.array([ft_of[int(r)] for r in batch.sequence]) / 7000.0
    np.testing.assert_allclose(batch.device_time_s, expected, rtol=0, atol=1e-9)


def test_duplicated_record_is_counted_and_dropped(sensor, fake) -> None:
    fake.duplicate(2)
    batches = settle(sensor, fake)
    assert counters(sensor) == expect(duplicate=2)
    sequence = np.concatenate([b.sequence for b in batches])
    assert np.all(np.diff(sequence) == 1)


def test_swapped_records_count_out_of_order_not_lost(sensor, fake) -> None:
    fake.reorder()
    batches = settle(sensor, fake)
    assert counters(sensor) == expect(out_of_order=1)
    sequence = np.concatenate([b.sequence for b in batches])
    assert np.all(np.diff(sequence) > 0)  # batches stay in order: the late record is discarded


@pytest.mark.parametrize("length", [35, 37, 0])
def test_truncated_or_padded_datagram_is_malformed(sensor, fake, length) -> None:
    fake.send_truncated(length)
    settle(sensor, fake)
    assert counters(sensor) == expect(malformed=1)


def test_garbage_datagrams_are_malformed(sensor, fake) -> None:
    fake.send_garbage(4)
    settle(sensor, fake)
    assert counters(sensor) == expect(malformed=4)


def test_silent_sensor_times_out_reconnects_and_resumes(sensor, fake) -> None:
    """The link goes quiet (the fixture's first read may have seen a single record, so the driver may not have
    learnt the ft_sequence step yet); the driver times out and re-sends its start, the box restarts its sequence
    into the quiet link; when the link is back, every record the fake withheld counts as lost, in one gap."""
    fake.go_silent()
    silent_since = len(fake.commands)
    fake.wait_for_command(0x0002, since=silent_since)  # the driver's re-sent start, heard during the silence
    fake.wait_until(lambda f: f.records_silenced > 0, what="a record withheld")
    fake.resume()
    settle(sensor, fake)
    health = sensor.health()
    assert health.timeouts >= 1 and health.reconnects >= 1
    # the box streamed on into the quiet link: exactly those records are lost (one gap); our own re-started
    # stream is not a device restart and nothing is a duplicate
    assert counters(sensor) == expect(lost=fake.records_silenced)
    assert health.gaps == 1


def test_device_restart_resets_sequences_and_is_counted(sensor, fake) -> None:
    fake.wait_until(lambda f: f.stats()["rdt_sequence"] > 200)  # a restart is a jump back from a large sequence
    sensor.read(timeout_s=READ_TIMEOUT_S)
    fake.restart()
    batches = settle(sensor, fake)
    assert counters(sensor) == expect(restarts=1)
    assert 1 in np.concatenate([b.sequence for b in batches]).tolist()


def test_stalled_ft_sequence_is_counted_and_samples_kept(sensor, fake) -> None:
    fake.stall_ft_sequence(4)
    settle(sensor, fake)
    assert counters(sensor) == expect(stalled=4)


def test_saturated_samples_are_flagged_and_never_averaged(sensor, fake) -> None:
    fake.saturate(10)
    batches = settle(sensor, fake)
    assert counters(sensor) == expect(saturated=10, status_errors=10)
    flagged = np.concatenate([b.saturated for b in batches])
    status = np.concatenate([b.status for b in batches])
    assert flagged.sum() == 10 and np.all(status[flagged] == 0x8002_0000)
    fake.saturate(None)
    while not sensor.read(timeout_s=READ_TIMEOUT_S).saturated[-1]:  # until saturated records arrive
        pass
    average_before = sensor.health().saturated
    with pytest.raises(SensorFaultError, match="error status"):
        sensor.average(0.05)
    assert sensor.health().saturated > average_before
    fake.clear_status()
    fake.wait_until(lambda f: f.status_word() == 0)
    sensor.read(timeout_s=READ_TIMEOUT_S)
    average = sensor.average(0.05)
    assert average.count > 0 and np.all(np.isfinite(average.mean))


def test_other_error_bits_are_status_errors_not_saturation(sensor, fake) -> None:
    fake.set_status(0x0000_0100, records=3)  # strain-gage excitation current too low
    batches = settle(sensor, fake)
    assert counters(sensor) == expect(status_errors=3)
    assert np.concatenate([b.saturated for b in batches]).sum() == 3


def test_monitor_latch_is_informational_until_reset(sensor, fake) -> None:
    fake.latch()
    batches = settle(sensor, fake)
    assert counters(sensor) == expect()
    assert sensor.health().last_status == 0x8001_0000
    assert not np.concatenate([b.saturated for b in batches]).any()
    sensor.reset_latch()
    fake.wait_for_command(0x0041)
    settle(sensor, fake)
    assert sensor.health().last_status == 0


def test_axia_status_map_busy_is_fine_saturation_is_not() -> None:
    physics = SensorPhysics(CellTruth(), SettablePose(), seed=2)
    with FakeNetFT(physics, rate_hz=RATE_HZ, prodname="Axia80-M20") as device, \
            NetFTSensor.from_url(device.url, timeout_s=STREAM_TIMEOUT_S) as sensor:
        assert sensor.status_map == "axia"
        sensor.read(timeout_s=READ_TIMEOUT_S)
        device.set_axia_status(0x0000_0008, records=5)  # busy: informational
        batches = settle(sensor, device)
        assert not np.concatenate([b.saturated for b in batches]).any()
        device.set_axia_status(1 << 30, records=5)  # F/T saturated
        batches = settle(sensor, device)
        assert counters(sensor) == expect(saturated=5, status_errors=5)
        assert np.concatenate([b.saturated for b in batches]).sum() == 5
