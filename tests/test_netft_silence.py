"""Lose nothing: the Net F/T driver against a box whose link goes quiet, reorders, or power-cycles, at 7 kHz.

The fake box logs every record it puts on the wire (:meth:`tests.fakes.netft_box.NetFTBox.sent_records`); each test
checks that every one of them reached the client exactly once, in order. A record is identified by its
``rdt_sequence`` and its six counts (the counts carry the simulated noise, so two records never share them).
A silence is a stretch of host time during which the test keeps reading (the fault itself, not a
synchronisation); what the box produced meanwhile is ``records_silenced``, and exactly that is lost. Under load the
fake may run behind its schedule, so the tests assert counts (exact) rather than durations.
"""

from __future__ import annotations

import csv
import threading
import time

import numpy as np
import pytest

from drivers.netft import NetFTSensor
from drivers.sensor import WrenchBatch
from ftacq.app.cli import main
from ftacq.errors import DeviceTimeoutError
from procedures.settle import SettleSettings, average_at_pose, wait_until_settled
from tests.fakes.netft import FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RATE_HZ = 7000.0
READ_TIMEOUT_S = 2.0
DRAIN_TIMEOUT_S = 20.0
"""Longest a test waits for the client to deliver what the box sent (a loaded machine is slow), seconds."""
BEFORE_SILENCE_RECORDS = 7000
"""Records streamed before the silence (1 s at 7 kHz), so the restarted stream's sequences are below the last
one seen: the case that used to be discarded as duplicates."""


@pytest.fixture
def fake():
    physics = SensorPhysics(CellTruth(), SettablePose(), seed=21)
    with FakeNetFT(physics, rate_hz=RATE_HZ) as device:
        yield device


def identities(rdt: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """One row per record: rdt_sequence and the six counts (int64), for exact comparison."""
    return np.column_stack([np.asarray(rdt, dtype=np.int64), np.asarray(counts, dtype=np.int64)])


def sent_identities(fake: FakeNetFT) -> np.ndarray:
    sent = fake.sent_records()
    return identities(sent["rdt_sequence"], sent["counts"])


def assert_received_exactly_once(sent: np.ndarray, received: np.ndarray) -> None:
    """Every sent record is received once, and in the order sent (sent has no copies in these tests)."""
    assert len(np.unique(sent, axis=0)) == len(sent), "the box sent a record twice (test set-up)"
    assert len(received) == len(sent), f"{len(received)} received, {len(sent)} sent"
    np.testing.assert_array_equal(received, sent)


def read_until_sent_delivered(sensor: NetFTSensor, fake: FakeNetFT, batches: list[WrenchBatch],
                              copies: int = 0) -> np.ndarray:
    """Read until the client delivered as many records as the box sent (stream stopped first) less the
    ``copies`` it sent twice on purpose (the client drops a second copy); return them."""
    deadline = time.monotonic() + DRAIN_TIMEOUT_S
    target = fake.records_sent - copies
    while sum(len(b) for b in batches) < target and time.monotonic() < deadline:
        try:
            batches.append(sensor.read(timeout_s=0.2))
        except DeviceTimeoutError:
            pass
    batch = WrenchBatch.concatenate(batches)
    return identities(batch.sequence, batch.counts)


def stream_through(fake: FakeNetFT, sensor: NetFTSensor, silence_s: float, batches: list[WrenchBatch],
                   before: int = BEFORE_SILENCE_RECORDS, after: int = 3500) -> None:
    """Stream ``before`` records, go silent for ``silence_s`` of host time (the box streams into the quiet link),
    resume, stream ``after`` more; the test thread keeps reading meanwhile."""
    def read_until(predicate) -> None:
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while not predicate(fake):
            assert time.monotonic() < deadline, f"fake did not reach its state: {fake.stats()}"
            try:
                batches.append(sensor.read(timeout_s=0.05))
            except DeviceTimeoutError:
                pass

    read_until(lambda f: f.records_sent >= before)
    silent_at = time.monotonic()
    fake.go_silent()
    read_until(lambda f: time.monotonic() - silent_at >= silence_s and f.records_silenced > 0)
    fake.resume()
    sent_at_resume = fake.records_sent
    read_until(lambda f: f.records_sent >= sent_at_resume + after)


@pytest.mark.parametrize("silence_s", [0.3, 1.0, 3.0])
def test_every_record_sent_after_a_silence_is_received(fake, silence_s) -> None:
    batches: list[WrenchBatch] = []
    with NetFTSensor.from_url(fake.url) as sensor:
        stream_through(fake, sensor, silence_s, batches)
        fake.power_off()  # stop the stream so that "everything sent" is final
        received = read_until_sent_delivered(sensor, fake, batches)
        health = sensor.health()
    assert_received_exactly_once(sent_identities(fake), received)
    assert health.duplicate == 0 and health.restarts == 0, (health, fake.stats())
    # the box streamed on into the quiet link: exactly those records are lost, in one gap
    assert health.lost == fake.records_silenced and health.gaps == 1, (health, fake.stats())
    if silence_s >= 1.0:  # four times the driver's silence timeout: it re-sent its start, the box restarted
        assert health.reconnects >= 1 and fake.stats()["streams_started"] >= 2, (health, fake.stats())


@pytest.mark.parametrize("faults", ["drop", "reorder", "duplicate"])
def test_fault_matrix_with_a_one_second_silence(fake, faults) -> None:
    """A lossy, reordering or duplicating link around a 1 s silence: what was sent arrives once and in order."""
    batches: list[WrenchBatch] = []
    with NetFTSensor.from_url(fake.url) as sensor:
        inject = {"drop": lambda: fake.drop(1), "reorder": fake.reorder, "duplicate": lambda: fake.duplicate(1)}[faults]
        for _ in range(20):
            inject()
        stream_through(fake, sensor, 1.0, batches, before=3000)
        for _ in range(20):
            inject()
        fake.wait_until(lambda f: not f.faults_pending, what="faults applied")
        sent_at = fake.records_sent
        fake.wait_for_records(sent_at + 700)
        fake.power_off()
        # the 40 duplicated records went out twice: waiting for records_sent would wait out DRAIN_TIMEOUT_S
        received = read_until_sent_delivered(sensor, fake, batches, copies=40 if faults == "duplicate" else 0)
        health = sensor.health()
    sent = fake.sent_records()
    if faults == "duplicate":
        _, first = np.unique(identities(sent["rdt_sequence"], sent["counts"]), axis=0, return_index=True)
        sent = sent[np.sort(first)]
        assert health.duplicate == 40
    expected = identities(sent["rdt_sequence"], sent["counts"])
    if faults == "reorder":  # the box swapped pairs; the client puts them back in sequence order
        assert health.out_of_order == 40
        assert len(received) == len(expected)  # same records (as a set), then in order within each stream
        assert len(np.unique(np.concatenate([expected, received]), axis=0)) == len(expected)
        restart = np.flatnonzero(np.diff(received[:, 0]) < 0)
        for stream in np.split(received[:, 0], restart + 1):
            assert np.all(np.diff(stream) >= 1)
    else:
        assert_received_exactly_once(expected, received)
    if faults == "drop":
        assert health.lost == 40 + fake.records_silenced


@pytest.mark.slow(seconds=7)
def test_record_through_a_two_second_silence_keeps_every_record_sent(fake, tmp_path, capsys) -> None:
    """Acceptance: ``ftacq sensor record`` at 7 kHz through a 2 s silence: every record the box sent is in the
    CSV exactly once; the summary reports the gap and the command exits 1 (lost beyond the threshold)."""
    output = tmp_path / "wrench.csv"
    errors: list[BaseException] = []

    def silence() -> None:
        try:
            fake.wait_until(lambda f: f.records_sent >= BEFORE_SILENCE_RECORDS, timeout_s=DRAIN_TIMEOUT_S)
            silent_at = time.monotonic()
            fake.go_silent()
            fake.wait_until(lambda f: time.monotonic() - silent_at >= 2.0, timeout_s=DRAIN_TIMEOUT_S)
            fake.resume()
        except BaseException as error:  # noqa: BLE001 (reported by the test)
            errors.append(error)

    thread = threading.Thread(target=silence, name="silence")
    thread.start()
    status = main(["sensor", "record", fake.url, "--seconds", "6", "-o", str(output)])
    thread.join()
    assert not errors, errors
    out = capsys.readouterr()
    with output.open() as handle:
        rows = list(csv.DictReader(handle))
    received = np.array([[int(r["seq"])] + [int(r[f"count_{a}"]) for a in ("fx", "fy", "fz", "tx", "ty", "tz")]
                         for r in rows], dtype=np.int64)
    sent = sent_identities(fake)
    # the CSV ends where the recording stopped: every record sent up to its last row is in it, once, in order
    last = np.flatnonzero((sent == received[-1]).all(axis=1))
    assert len(last) == 1
    assert_received_exactly_once(sent[:last[0] + 1], received)
    assert fake.records_silenced > 0
    assert "gaps 1" in out.out and f"lost {fake.records_silenced}" in out.out
    assert status == 1 and "lost beyond" in out.err


class SteadyRobot:
    """A robot that is always steady (settling depends only on the sensor)."""

    def is_steady(self) -> bool:
        return True


@pytest.mark.parametrize("phase", ["settling", "averaging"])
def test_a_silence_shorter_than_sensor_timeout_never_aborts_a_pose(fake, phase) -> None:
    """A 1 s silence (sensor_timeout_s = 2 s) while a pose settles or averages: the pose waits or averages again."""
    settings = SettleSettings(settle_time_s=0.2, window_s=0.1, force_std_n=10.0, torque_std_nm=10.0, timeout_s=10.0,
                              average_time_s=0.3, sensor_timeout_s=2.0)
    with NetFTSensor.from_url(fake.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        # 4 s before the silence: a driver that took the restarted stream for old records would discard ~3.5 s
        fake.wait_until(lambda f: f.records_sent >= 4 * BEFORE_SILENCE_RECORDS, timeout_s=DRAIN_TIMEOUT_S)
        sensor.read(timeout_s=READ_TIMEOUT_S)
        done = threading.Event()

        def silence() -> None:
            if phase == "averaging":
                fake.wait_until(lambda f: done.is_set(), timeout_s=DRAIN_TIMEOUT_S)
            silent_at = time.monotonic()
            fake.go_silent()
            fake.wait_until(lambda f: time.monotonic() - silent_at >= 1.0, timeout_s=DRAIN_TIMEOUT_S)
            fake.resume()

        thread = threading.Thread(target=silence, name="silence")
        thread.start()
        try:
            if phase == "settling":
                fake.wait_until(lambda f: f.records_silenced > 0)
            wait_until_settled(SteadyRobot(), sensor, settings)
            done.set()
            average, _, _ = average_at_pose(sensor, settings)
        finally:
            done.set()
            thread.join()
    assert average.count >= 0.5 * RATE_HZ * settings.average_time_s


def test_data_resume_promptly_after_a_power_cycle(fake) -> None:
    """While the box is off the driver keeps re-sending its start at most every 0.5 s (not a back-off to seconds),
    so the box streams again soon after it is back; its fresh stream is accepted (a counted restart).

    "Soon" is checked on the driver's schedule (the interval it set after its latest re-send), not on host time,
    which a loaded machine stretches; the box hearing a start after power-on and streaming is waited for."""
    from drivers.netft.receiver import BACKOFF_RESTARTING_MAX_S

    with NetFTSensor.from_url(fake.url) as sensor:
        fake.wait_until(lambda f: f.records_sent >= BEFORE_SILENCE_RECORDS)
        sensor.read(timeout_s=READ_TIMEOUT_S)
        fake.power_off()
        before = sensor.health().reconnects
        while sensor.health().reconnects < before + 5:  # off for ~2 s: re-sends at 0.25, 0.5, 1.0, 1.5, 2.0 s
            try:
                sensor.read(timeout_s=0.1)
            except DeviceTimeoutError:
                pass
        # a doubling back-off would be at 4 s or more after five re-sends
        assert 0 < sensor._receiver.last_retry_interval_s <= BACKOFF_RESTARTING_MAX_S
        since = len(fake.commands)
        fake.power_on()
        fake.wait_for_command(0x0002, since=since, timeout_s=DRAIN_TIMEOUT_S)  # a re-send reached the box
        batch = sensor.read(timeout_s=READ_TIMEOUT_S)
        while batch.sequence[0] != 1:
            batch = sensor.read(timeout_s=READ_TIMEOUT_S)
        health = sensor.health()
    assert health.restarts == 1 and health.duplicate == 0
