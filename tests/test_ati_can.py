"""The ATI NETCANOEM driver against the fake board on python-can's in-process ``virtual`` bus.

Every test uses its own channel name (uuid), so xdist workers and concurrent runs never share a bus.

Over 500 lines: one driver's tests against one fake board, sharing its fixtures (bus channel, physics, fake);
splitting them would only repeat the fixtures.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import struct
import time
import uuid

import can
import numpy as np
import pytest

from drivers.ati_can import AtiCanSensor, decode_status, parse_can_url
from drivers.ati_can.protocol import (
    HOST_STATUS_GAGE_SATURATED,
    OP_COUNTS_PER_UNIT,
    OP_FIRMWARE,
    OP_GAGES,
    OP_MATRIX,
    OP_SELECT_CALIBRATION,
    OP_SERIAL,
    OP_UNIT_CODES,
)
from drivers.sensor import ForceTorqueSensor, open_sensor
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError, InputError, SensorFaultError
from tests.fakes.netcanoem import FakeCanCalibration, FakeNetCanOem, FakeSlcanAdapter, default_calibration_matrix
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose, SharedPose
from tests.conftest import wait_until

WAIT_TIMEOUT_S = 10.0
"""Deadline of every condition a test waits for, seconds (generous: CI machines are loaded)."""
POLL_RATE_HZ = 1000.0
POLL_TIMEOUT_S = 1.0
"""Reply timeout of the shared fixture's polls: long, so a loaded CI machine causes no spurious timeouts."""
FRESH_SAMPLES = 20

NOISELESS = CellTruth(force_noise_n=(0.0, 0.0, 0.0), torque_noise_nm=(0.0, 0.0, 0.0))

POSES = [
    np.array([0.4, 0.0, 0.4, np.pi, 0.0, 0.0]),  # tool down
    np.array([0.3, 0.2, 0.5, 0.0, 0.0, 0.0]),  # tool up
    np.array([0.4, -0.1, 0.3, 0.0, np.pi / 2, 0.0]),
    np.array([0.4, 0.1, 0.3, 1.2, -0.7, 0.4]),
]


def fresh_samples(sensor: AtiCanSensor, count: int = FRESH_SAMPLES):
    """Return ``count`` samples whose requests were all sent after this call (see the sequence argument)."""
    last = int(sensor.read(timeout_s=WAIT_TIMEOUT_S).sequence.max())
    batches, total = [], 0
    deadline = time.monotonic() + WAIT_TIMEOUT_S
    while total < count:
        assert time.monotonic() < deadline, "fresh samples did not arrive"
        batch = sensor.read(timeout_s=WAIT_TIMEOUT_S)
        keep = batch.sequence >= last + 2  # request last+1 may have been answered before the call
        batches.append((batch, keep))
        total += int(keep.sum())
    from drivers.sensor import WrenchBatch

    kept = [WrenchBatch(b.time_s[k], b.wrench[k], b.counts[k], b.status[k], b.sequence[k], b.saturated[k])
            for b, k in batches]
    return WrenchBatch.concatenate(kept)


@pytest.fixture
def channel() -> str:
    return f"ftacq-test-{uuid.uuid4()}"


@pytest.fixture
def pose() -> SettablePose:
    return SettablePose(POSES[0])


@pytest.fixture
def physics(pose) -> SensorPhysics:
    return SensorPhysics(NOISELESS, pose, seed=3)


def make_fake(channel, physics, **options) -> FakeNetCanOem:
    return FakeNetCanOem(channel, physics, **options)


@pytest.fixture
def fake(channel, physics):
    board = make_fake(channel, physics, counts_per_force=816_326, counts_per_torque=1_234, torque_unit_code=4)
    yield board
    board.close()


@pytest.fixture
def sensor(channel, fake):
    driver = AtiCanSensor.from_url(f"can://virtual/{channel}?rate_hz={POLL_RATE_HZ}&timeout_s={POLL_TIMEOUT_S}")
    driver.start()
    yield driver
    driver.close()


def assert_within_one_count(batch, expected: np.ndarray, calibration: FakeCanCalibration) -> None:
    tolerance = calibration.quantisation_tolerance()
    error = np.abs(batch.wrench - expected)
    assert np.all(error <= tolerance), f"max error {error.max(axis=0)} exceeds one count {tolerance}"


# ---------------------------------------------------------------------------- wrench and units


@pytest.mark.parametrize(
    "cpf, cpt, torque_code",
    [(816_326, 1_234, 4), (1_000_000, 1_500_000, 3), (420_000, 97, 4)],
    ids=["N,N-mm", "N,N-m", "N,N-mm-coarse"],
)
def test_reproduces_simulated_wrench_within_one_count_at_every_pose(channel, physics, pose, cpf, cpt, torque_code):
    with make_fake(channel, physics, counts_per_force=cpf, counts_per_torque=cpt, torque_unit_code=torque_code) as board:
        with AtiCanSensor.from_url(f"can://virtual/{channel}?rate_hz={POLL_RATE_HZ}") as sensor:
            assert isinstance(sensor, ForceTorqueSensor)
            assert (sensor.info.counts_per_force, sensor.info.counts_per_torque) == (cpf, cpt)
            assert sensor.info.torque_unit == {3: "N-m", 4: "N-mm"}[torque_code]
            assert sensor.info.force_unit == "N"
            for flange_pose in POSES:
                pose.set(flange_pose)
                batch = fresh_samples(sensor)
                assert_within_one_count(batch, physics.noiseless_wrench(flange_pose), board.active_calibration)
                assert not batch.saturated.any()
                assert np.all(batch.status == 0)


def test_reading_changes_with_pose(sensor, pose, physics):
    pose.set(POSES[0])
    down = fresh_samples(sensor).wrench.mean(axis=0)
    pose.set(POSES[1])
    up = fresh_samples(sensor).wrench.mean(axis=0)
    weight_n = NOISELESS.mass_kg * 9.80665
    # turning the tool over swaps the sign of the weight in the sensor frame: the difference is 2 m g
    assert np.linalg.norm(down[:3] - up[:3]) == pytest.approx(2 * weight_n, rel=1e-3)


def test_low_latency_hint_is_kept_and_reported(sensor):
    # every polled sample is readable at once: nothing to shorten, but the hold asked for is reported and given back
    assert sensor.max_hold_s is None
    assert sensor.prefer_low_latency(0.0003) is None and sensor.max_hold_s == 0.0003
    assert sensor.prefer_low_latency(None) == 0.0003 and sensor.max_hold_s is None
    assert len(fresh_samples(sensor, 3)) >= 3


def test_batch_columns_counts_and_sequence(sensor, fake):
    batch = fresh_samples(sensor, 50)
    assert batch.wrench.shape == (len(batch), 6) and batch.counts.shape == (len(batch), 6)
    assert batch.counts.dtype == np.int64 and batch.status.dtype == np.uint32
    assert np.all(np.diff(batch.sequence) == 1)
    assert np.all(np.diff(batch.time_s) >= 0)
    np.testing.assert_allclose(batch.wrench, fake.active_calibration.wrench_from_gages(batch.counts), atol=1e-9)


def test_follows_a_pose_written_by_another_process(channel):
    """The simulated UR controller runs in another process; its SharedPose drives the CAN fake here."""
    shared = SharedPose(create=True)
    try:
        context = multiprocessing.get_context("spawn")
        writer = context.Process(target=_write_shared_pose, args=(shared.name, list(POSES[3])), name="pose-writer")
        writer.start()
        writer.join(WAIT_TIMEOUT_S * 3)
        assert writer.exitcode == 0
        physics = SensorPhysics(NOISELESS, shared, seed=1)
        with make_fake(channel, physics) as board, AtiCanSensor.from_url(f"can://virtual/{channel}") as sensor:
            assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[3]), board.active_calibration)
    finally:
        shared.close()


def _write_shared_pose(name: str, flange_pose: list[float]) -> None:
    shared = SharedPose(name=name)
    shared.set(np.array(flange_pose))
    shared.close()


def test_legacy_firmware_assumes_a_million_counts(channel, physics, pose):
    with make_fake(channel, physics, firmware=(3, 6, 2)) as board:
        with AtiCanSensor.from_url(f"can://virtual/{channel}?rate_hz={POLL_RATE_HZ}") as sensor:
            assert sensor.info.firmware == "3.6.2"
            assert sensor.info.counts_per_force == sensor.info.counts_per_torque == 1_000_000
            assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), board.active_calibration)
        assert not board.requests(OP_COUNTS_PER_UNIT) and not board.requests(OP_UNIT_CODES)


def test_start_up_sequence_on_the_wire(sensor, fake):
    fresh_samples(sensor)
    opcodes = [frame.opcode for frame in fake.requests()]
    first_poll = opcodes.index(OP_GAGES)
    assert opcodes[:first_poll] == [OP_FIRMWARE, OP_SELECT_CALIBRATION] + [OP_MATRIX] * 6 + [
        OP_COUNTS_PER_UNIT, OP_UNIT_CODES, OP_SERIAL]
    assert [frame.data for frame in fake.requests(OP_MATRIX)] == [bytes([row]) for row in range(6)]
    assert fake.requests(OP_SELECT_CALIBRATION)[0].data == b"\x00"
    assert sensor.info.serial == "FT23456"
    np.testing.assert_array_equal(np.array(sensor.info.extra["calibration_matrix"]), fake.active_calibration.matrix)


def test_selects_another_calibration_slot(channel, physics):
    slot1 = FakeCanCalibration(default_calibration_matrix(500_000, 2_000, 2, 4, seed=11), 500_000, 2_000, 2, 4)
    with make_fake(channel, physics, extra_calibrations=[slot1]) as board:
        with AtiCanSensor.from_url(f"can://virtual/{channel}?calibration=1&rate_hz={POLL_RATE_HZ}") as sensor:
            assert board.active_calibration_index == 1
            assert (sensor.info.counts_per_force, sensor.info.torque_unit) == (500_000, "N-mm")
            assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), slot1)


# ---------------------------------------------------------------------------- status and saturation


def test_critical_status_is_flagged_and_never_averaged(sensor, fake):
    fake.status = 0x8000 | 0x0010  # any error + supply too high
    wait_until(lambda: sensor.health().status_errors >= 5, "status errors to be counted")
    batch = fresh_samples(sensor)
    assert np.all(batch.saturated)
    assert np.all(batch.status & 0xFFFF == 0x8010)
    assert decode_status(0x8010) == ["supply too high", "any error"]
    with pytest.raises(SensorFaultError, match="supply too high"):
        sensor.average(0.05)
    with pytest.raises(SensorFaultError):
        sensor.bias(timeout_s=0.3)


def test_informational_status_is_reported_not_flagged(sensor, fake):
    fake.status = 0x0100  # configuration invalid (defaults used), no error bit
    batch = fresh_samples(sensor)
    assert np.all(batch.status == 0x0100)
    assert not batch.saturated.any()
    assert sensor.health().last_status == 0x0100


@pytest.mark.parametrize("high, value", [(True, 32767), (False, -32768)])
def test_saturated_gage_is_flagged(sensor, fake, high, value):
    fake.saturate_gage(2, high=high)
    batch = fresh_samples(sensor)
    assert np.all(batch.counts[:, 2] == value)
    assert np.all(batch.saturated)
    assert np.all(batch.status == HOST_STATUS_GAGE_SATURATED)
    assert sensor.health().saturated >= len(batch)
    with pytest.raises(SensorFaultError):
        sensor.average(0.05)


def test_average_excludes_saturated_samples_and_counts_them(sensor, fake, physics):
    fake.saturate_gage(4)
    saturated_before = sensor.health().saturated
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        future = pool.submit(sensor.average, 0.4)
        wait_until(lambda: sensor.health().saturated >= saturated_before + 10, "saturated samples in the window")
        fake.clear_saturation()
        result = future.result(WAIT_TIMEOUT_S)
    assert result.saturated >= 1 and result.count >= 1
    tolerance = fake.active_calibration.quantisation_tolerance()
    assert np.all(np.abs(result.mean - physics.noiseless_wrench(POSES[0])) <= tolerance)


def test_watchdog_reset_bit_counts_a_restart(sensor, fake):
    fake.status = 0x0001
    wait_until(lambda: sensor.health().restarts == 1, "a restart to be counted")
    fresh_samples(sensor)
    assert sensor.health().restarts == 1  # counted on the rising edge only


def test_watchdog_reset_reselects_the_calibration_slot(channel, physics):
    slot1 = FakeCanCalibration(default_calibration_matrix(500_000, 2_000, 2, 4, seed=11), 500_000, 2_000, 2, 4)
    with make_fake(channel, physics, extra_calibrations=[slot1]) as board:
        with AtiCanSensor.from_url(f"can://virtual/{channel}?calibration=1&rate_hz={POLL_RATE_HZ}") as sensor:
            fresh_samples(sensor)
            board.watchdog_reset()
            wait_until(lambda: len(board.requests(OP_SELECT_CALIBRATION)) == 2, "the slot to be selected again")
            assert board.active_calibration_index == 1 and sensor.health().restarts == 1
            board.status = 0
            assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), slot1)


# ---------------------------------------------------------------------------- bias and averaging


def test_bias_is_host_side_in_gage_space(sensor, fake, physics):
    fake.gage_offset = np.array([120.0, -340.0, 55.0, 800.0, -20.0, 9.0])
    fresh_samples(sensor)
    sensor.bias()
    tolerance = fake.active_calibration.quantisation_tolerance()
    assert np.all(np.abs(fresh_samples(sensor).wrench) <= tolerance)
    contact = np.array([5.0, -2.0, 10.0, 0.2, 0.1, -0.05])
    physics.contact_wrench = contact
    average = sensor.average(0.05)
    assert np.all(np.abs(average.mean - contact) <= tolerance)
    assert average.count >= 1 and average.saturated == 0
    opcodes = {frame.opcode for frame in fake.requests()}
    assert opcodes <= {OP_GAGES, OP_MATRIX, OP_SERIAL, OP_SELECT_CALIBRATION, OP_COUNTS_PER_UNIT, OP_UNIT_CODES,
                       OP_FIRMWARE}  # the board computes no bias: nothing but reads on the wire
    sensor.clear_bias()
    assert np.all(sensor.gage_bias == 0)


def test_average_reports_mean_std_and_count(channel, pose):
    noisy = SensorPhysics(CellTruth(), pose, seed=5)
    with make_fake(channel, noisy), AtiCanSensor.from_url(f"can://virtual/{channel}?rate_hz={POLL_RATE_HZ}") as sensor:
        average = sensor.average(0.3)
    assert average.count >= 20 and average.lost == 0
    expected_sigma = np.array(CellTruth().force_noise_n + CellTruth().torque_noise_nm)
    assert np.all(average.std > 0.3 * expected_sigma) and np.all(average.std < 3 * expected_sigma)
    assert np.all(np.abs(average.mean - noisy.noiseless_wrench(POSES[0])) < 5 * expected_sigma)


# ---------------------------------------------------------------------------- faults


def test_board_silent_mid_stream_is_counted_and_loop_recovers(channel, fake):
    with AtiCanSensor.from_url(f"can://virtual/{channel}?rate_hz={POLL_RATE_HZ}&timeout_s=0.05") as sensor:
        fresh_samples(sensor)
        fake.silent = True
        wait_until(lambda: sensor.health().timeouts >= 3, "unanswered polls to be counted")
        with pytest.raises(DeviceTimeoutError, match="no sample"):
            while True:  # drain what arrived before the board went silent, then time out
                sensor.read(timeout_s=0.3)
        fake.silent = False
        batch = fresh_samples(sensor)
        assert len(batch) >= FRESH_SAMPLES
        health = sensor.health()
        assert health.timeouts >= 3 and health.received > FRESH_SAMPLES
        assert health.gaps >= 1 and health.longest_gap_s >= 3 * 0.05  # runs of unanswered polls
        assert sensor._thread.is_alive()


def test_missing_second_frame_counts_lost(sensor, fake):
    fresh_samples(sensor)
    fake.drop_reply_frames(1, opcode=0x1)
    wait_until(lambda: sensor.health().lost == 1, "a partial reply to be counted as lost")
    batch = fresh_samples(sensor)
    assert len(batch) >= FRESH_SAMPLES and sensor.health().lost == 1


def test_foreign_and_malformed_frames_are_counted_and_ignored(fake, channel, physics):
    bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)  # handed in: no ID filters
    other = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        with AtiCanSensor(bus, rate_hz=POLL_RATE_HZ) as sensor:
            fresh_samples(sensor)
            other.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
            other.send(can.Message(arbitration_id=0x201, data=b"\x01\x02\x03", is_extended_id=False))  # bad length
            wait_until(lambda: sensor.health().foreign >= 1 and sensor.health().malformed >= 1, "frames counted")
            assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), fake.active_calibration)
    finally:
        other.shutdown()
        bus.shutdown()


def test_own_bus_filters_other_ids_and_counts_malformed(sensor, fake, channel, physics):
    fresh_samples(sensor)
    other = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        other.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        other.send(can.Message(arbitration_id=0x201, data=b"\x01\x02\x03", is_extended_id=False))
        wait_until(lambda: sensor.health().malformed >= 1, "the malformed frame to be counted")
    finally:
        other.shutdown()
    assert sensor.health().foreign == 0  # the bus this driver opened filters on the board's 16 IDs
    assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), fake.active_calibration)


def test_board_that_does_not_answer_times_out_with_a_clear_message(channel):
    sensor = AtiCanSensor.from_url(f"can://virtual/{channel}", startup_timeout_s=0.02)
    with pytest.raises(DeviceTimeoutError, match=r"base 0x20 on virtual channel .* did not answer the firmware"):
        sensor.start()
    sensor.close()


def test_wrong_base_times_out(channel, physics):
    with make_fake(channel, physics, base=0x21):
        with pytest.raises(DeviceTimeoutError, match="base 0x20"):
            AtiCanSensor.from_url(f"can://virtual/{channel}", startup_timeout_s=0.02).start()
        with AtiCanSensor.from_url(f"can://virtual/{channel}?base=0x21") as sensor:
            assert sensor.info.serial == "FT23456"


def test_unopenable_interface_is_a_connection_error():
    sensor = AtiCanSensor.from_url("can://socketcan/ftacq-no-such-if0")
    with pytest.raises(DeviceConnectionError, match="cannot open CAN interface 'socketcan'"):
        sensor.start()


def test_read_before_start_is_an_error(channel):
    from ftacq.errors import DeviceError

    with pytest.raises(DeviceError, match="start"):
        AtiCanSensor.from_url(f"can://virtual/{channel}").read(0.0)


# ---------------------------------------------------------------------------- URLs and life cycle


def test_url_parsing():
    assert parse_can_url("can://virtual/bench?base=0x21&bitrate=500000&rate_hz=250&calibration=3&timeout_s=0.05") == {
        "interface": "virtual", "channel": "bench", "base": 0x21, "bitrate": 500_000, "rate_hz": 250.0,
        "calibration_index": 3, "reply_timeout_s": 0.05}
    assert parse_can_url("can://slcan//dev/ttyACM0@115200")["channel"] == "/dev/ttyACM0@115200"
    assert parse_can_url("can://slcan/%2Fdev%2FttyUSB0")["channel"] == "/dev/ttyUSB0"
    assert parse_can_url("can://socketcan/can0?base=32")["base"] == 32


@pytest.mark.parametrize(
    "url, message",
    [
        ("can://nosuchbus/can0", "unknown python-can interface 'nosuchbus'"),
        ("can://socketcan", "missing CHANNEL"),
        ("can:///can0", "missing INTERFACE"),
        ("can://socketcan/can0?base=0x80", r"base=128 is out of range 0\.\.127"),
        ("can://socketcan/can0?base=zz", "base='zz' is not a number"),
        ("can://socketcan/can0?bitrate=-5", "bitrate=-5 is out of range"),
        ("can://socketcan/can0?rate_hz=0", "rate_hz=0.0 is out of range"),
        ("can://socketcan/can0?calibration=16", "calibration=16 is out of range"),
        ("can://socketcan/can0?speed=1", "unknown query key 'speed'"),
        ("can://socketcan/can0?base=1&base=2", "given twice"),
        ("netcan://socketcan/can0", "unknown scheme"),
    ],
)
def test_bad_url_gets_one_clear_input_error(url, message):
    with pytest.raises(InputError, match=message):
        open_sensor(url)


def test_takes_a_bus_handed_in_and_leaves_it_open(channel, physics):
    bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        with make_fake(channel, physics):
            sensor = AtiCanSensor(bus, rate_hz=POLL_RATE_HZ)
            with sensor:
                assert len(fresh_samples(sensor)) >= FRESH_SAMPLES
        bus.send(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False))  # still usable
    finally:
        bus.shutdown()


def test_threads_are_named_joined_and_close_is_idempotent(channel, physics):
    board = make_fake(channel, physics)
    sensor = AtiCanSensor.from_url(f"can://virtual/{channel}")
    sensor.start()
    assert sensor._thread.name.startswith("AtiCanSensor-virtual-") and board._thread.name.startswith("FakeNetCanOem-")
    sensor.close()
    sensor.close()
    board.close()
    board.close()
    assert not sensor._thread.is_alive() and not board._thread.is_alive()


# ---------------------------------------------------------------------------- the fake board itself


def _ask(bus: can.BusABC, request_id: int, data: bytes, frames: int) -> list[can.Message]:
    bus.send(can.Message(arbitration_id=request_id, data=data, is_extended_id=False))
    replies = []
    deadline = time.monotonic() + WAIT_TIMEOUT_S
    while len(replies) < frames and time.monotonic() < deadline:
        message = bus.recv(timeout=0.5)
        if message is not None:
            replies.append(message)
    return replies


def test_fake_ignores_request_dlc_and_replies_in_frame_order(channel, physics):
    with make_fake(channel, physics, serial="SN777") as board:
        bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)
        try:
            (serial,) = _ask(bus, 0x205, b"\x00", 1)  # DLC 1 [0] for a "none" request, as one python-can HAL does
            assert (serial.arbitration_id, bytes(serial.data)) == (0x205, b"SN777\x00\x00\x00")
            first, second = _ask(bus, 0x200, b"", 2)
            assert (first.arbitration_id, first.dlc, second.arbitration_id, second.dlc) == (0x200, 8, 0x201, 6)
            rows = _ask(bus, 0x202, b"\x05", 3)
            assert [m.arbitration_id for m in rows] == [0x202, 0x203, 0x204]
            coefficients = struct.unpack(">6f", b"".join(bytes(m.data) for m in rows))
            np.testing.assert_array_equal(coefficients, board.active_calibration.matrix[5])
            (echo,) = _ask(bus, 0x206, b"\x0c", 1)
            assert bytes(echo.data) == b"\x0c" and board.active_calibration_index == 12
            first, _ = _ask(bus, 0x200, b"", 2)
            assert struct.unpack(">H", bytes(first.data[:2]))[0] & 0x0040  # empty slot: bad active calibration
            bus.send(can.Message(arbitration_id=0x20C, data=b"", is_extended_id=False))  # reset: no reply
            (after_reset,) = _ask(bus, 0x20F, b"", 1)  # the board answers in order: the next frame is 0xF's
            assert after_reset.arbitration_id == 0x20F and board.active_calibration_index == 0 and board.reset_count == 1
            (base_ack,) = _ask(bus, 0x20D, b"\x33", 1)
            (rate_ack,) = _ask(bus, 0x20E, b"\x03", 1)
            assert (base_ack.dlc, rate_ack.dlc, board.base, board.bitrate) == (0, 0, 0x20, 250_000)
            board.power_cycle()
            assert (board.base, board.bitrate) == (0x33, 500_000)
            (firmware,) = _ask(bus, 0x33F, b"", 1)
            assert struct.unpack(">BBH", bytes(firmware.data)) == (3, 8, 0)
        finally:
            bus.shutdown()
        assert [f.arbitration_id for f in board.received][:3] == [0x205, 0x200, 0x202]


def test_fake_gages_invert_the_matrix(physics):
    calibration = FakeCanCalibration(default_calibration_matrix(816_326, 1_234, 2, 4), 816_326, 1_234, 2, 4)
    wrench = physics.noiseless_wrench(POSES[2])
    gages = calibration.gages_from_wrench(wrench, np.zeros(6))
    assert np.all(np.abs(gages) < 32767) and gages.dtype == np.int64
    assert np.all(np.abs(calibration.wrench_from_gages(gages) - wrench) <= calibration.quantisation_tolerance())
    huge = calibration.gages_from_wrench(np.array([1e5, 0, 0, 0, 0, 0]), np.zeros(6))
    assert 32767 in huge or -32768 in huge  # over range saturates, never wraps


def test_fake_enforces_board_rules(channel, physics):
    with pytest.raises(ValueError, match="base"):
        FakeNetCanOem(channel, physics, base=0x80, start=False)
    with pytest.raises(ValueError, match="1 000 000"):
        FakeNetCanOem(channel, physics, firmware=(3, 6, 0), counts_per_force=5, start=False)
    with pytest.raises(ValueError, match="8 ASCII"):
        FakeNetCanOem(channel, physics, serial="TOO-LONG-SERIAL", start=False)


# ---------------------------------------------------------------------------- the CLI


def test_ftacq_sensor_info_reads_a_fake_board_in_process(channel, fake, capsys):
    from ftacq.app.cli import main

    assert main(["sensor", "info", f"can://virtual/{channel}"]) == 0
    output = capsys.readouterr().out
    assert "FT23456" in output and "N-mm" in output


# ---------------------------------------------------------------------------- slcan through pyserial


def test_driver_over_slcan_through_pyserial(channel, fake, physics):
    """python-can's slcan interface on a real pseudo-terminal (pyserial), bridged to the board's virtual bus."""
    with FakeSlcanAdapter(channel) as adapter:
        url = f"can://slcan/{adapter.port}?bitrate=250000&rate_hz=200"
        with AtiCanSensor.from_url(url, bus_options={"sleep_after_open": 0.0}) as sensor:
            assert sensor.info.serial == "FT23456" and sensor.info.torque_unit == "N-mm"
            assert_within_one_count(fresh_samples(sensor, 10), physics.noiseless_wrench(POSES[0]),
                                    fake.active_calibration)
        assert adapter.commands[:3] == ["C", "S5", "O"]
        frames = [command for command in adapter.commands if command.startswith("t")]
        assert frames[0] == "t20F0" and "t2000" in frames  # firmware request (DLC 0) first; gage polls later


def test_slcan_at_the_wrong_bit_rate_times_out(channel, fake):
    with FakeSlcanAdapter(channel, bus_bitrate=250_000) as adapter:
        sensor = AtiCanSensor.from_url(f"can://slcan/{adapter.port}?bitrate=500000",
                                       bus_options={"sleep_after_open": 0.0}, startup_timeout_s=0.05)
        with pytest.raises(DeviceTimeoutError, match=r"bit rate \(500000 bit/s\)"):
            sensor.start()
        assert adapter.commands[:3] == ["C", "S6", "O"]
    assert not fake.requests()  # nothing reached the board


class _BrokenPhysics:
    """A wrench source that fails, to show the fake's thread error surfaces at close."""

    def sample(self, n: int) -> np.ndarray:
        raise ValueError("simulated physics failure")


def test_fake_thread_error_is_reraised_at_close_and_driver_keeps_polling(channel):
    board = make_fake(channel, _BrokenPhysics())
    with AtiCanSensor.from_url(f"can://virtual/{channel}?timeout_s=0.02&rate_hz={POLL_RATE_HZ}") as sensor:
        wait_until(lambda: sensor.health().timeouts >= 2, "polls of a dead board to time out")
        assert sensor._thread.is_alive()
    with pytest.raises(RuntimeError, match="simulated physics failure"):
        board.close()


@pytest.mark.skipif(not os.environ.get("FTACQ_CAN_SENSOR_URL"), reason="set FTACQ_CAN_SENSOR_URL to test a real board")
def test_real_board():
    """Opt-in hardware check (reads only; the bias is host-side, nothing is written to the board)."""
    with open_sensor(os.environ["FTACQ_CAN_SENSOR_URL"]) as sensor:
        assert sensor.info.serial and sensor.info.counts_per_force > 0
        average = sensor.average(1.0)
        assert average.count > 0 and np.all(np.isfinite(average.mean))


def test_open_sensor_routes_a_virtual_can_url_to_the_fake(channel, fake, physics):
    """The path ``ftacq sensor info can://virtual/<channel>`` takes: drivers.sensor.open_sensor → AtiCanSensor."""
    sensor = open_sensor(f"can://virtual/{channel}?base=0x20&bitrate=250000&rate_hz={POLL_RATE_HZ}")
    assert isinstance(sensor, AtiCanSensor)
    with sensor:
        assert (sensor.info.transport, sensor.info.serial, sensor.info.firmware) == ("can", "FT23456", "3.8.0")
        assert (sensor.info.force_unit, sensor.info.torque_unit) == ("N", "N-mm")
        assert (sensor.info.counts_per_force, sensor.info.counts_per_torque, sensor.info.rate_hz) == (
            816_326, 1_234, POLL_RATE_HZ)
        assert_within_one_count(fresh_samples(sensor), physics.noiseless_wrench(POSES[0]), fake.active_calibration)
