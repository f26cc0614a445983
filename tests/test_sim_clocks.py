"""The simulated devices keep their own clocks, as real ones do (issue 27): the Net F/T samples on its own crystal
(ft_sequence counts its samples, a rate error off the host's), sends in bursts, skips samples when its sender falls
behind (ft_sequence jumps, rdt_sequence does not); the controller stamps RTDE packages on its own clock.

No timing asserts: the sensor's sample times are read back from the physics (a bias drifting at a known rate
encodes the host time of each sample in its value), the controller's from its own clock report."""

from __future__ import annotations

import socket
import struct
import time

import numpy as np
import pytest

from tests.fakes.netft import RECORD_DTYPE, FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RECEIVE_TIMEOUT_S = 2.0
COUNTS_PER_FORCE = 1_000_000
DRIFT_N_PER_S = 1.0
"""Fx drifts by this much per host second with no noise: Fx − bias = drift × (sample's host time − start)."""
RATE_ERROR = 150e-6
BURSTS_S = 0.02


def drifting_physics() -> SensorPhysics:
    truth = CellTruth(force_noise_n=(0.0, 0.0, 0.0), torque_noise_nm=(0.0, 0.0, 0.0),
                      drift_n_per_s=(DRIFT_N_PER_S, 0.0, 0.0))
    return SensorPhysics(truth, SettablePose(), seed=0, rate_hz=7000.0)


SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
BURST_GAP_S = 0.0005
"""Datagrams the kernel received less than this apart belong to one burst (1 kHz: 1 ms apart when sent as due)."""


def receive_records(sock: socket.socket, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Receive until ``n`` records arrived; return them and the kernel's arrival stamp of each datagram (s)."""
    chunks, stamps, total = [], [], 0
    while total < n:
        data, ancillary, _flags, _address = sock.recvmsg(65536, socket.CMSG_SPACE(16))
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                seconds, nanoseconds = struct.unpack("qq", value[:16])
                stamps.append(seconds + nanoseconds * 1e-9)
        chunks.append(np.frombuffer(data, dtype=RECORD_DTYPE))
        total += len(chunks[-1])
    return np.concatenate(chunks), np.array(stamps)


def stream(fake: FakeNetFT, n: int) -> tuple[np.ndarray, list[int]]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(("127.0.0.1", fake.rdt_port))
    sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    sock.settimeout(RECEIVE_TIMEOUT_S)
    try:
        sock.send(struct.pack(">HHI", 0x1234, 0x0002, 0))
        return receive_records(sock, n)
    finally:
        sock.send(struct.pack(">HHI", 0x1234, 0x0000, 0))
        sock.close()


@pytest.mark.parametrize("rate_error", [RATE_ERROR, -RATE_ERROR])
def test_the_sensor_samples_on_its_own_clock(rate_error):
    """ft_sequence / 7000 is the box's time; the host time of each sample (from the drift) advances 1 / (1 + e)
    as fast: a clock estimator fitted on these records must find the configured rate error."""
    physics = drifting_physics()
    with FakeNetFT(physics, rate_hz=7000.0, counts_per_force=COUNTS_PER_FORCE, clock_rate_error=rate_error,
                   burst_interval_s=0.002, burst_jitter_s=0.001) as fake:
        records, _ = stream(fake, 3500)
    ft = records["ft_sequence"].astype(np.int64)
    assert np.all(np.diff(ft) > 0)
    device_s = ft / 7000.0
    host_s = (records["counts"][:, 0] / COUNTS_PER_FORCE - physics.truth.force_bias_n[0]) / DRIFT_N_PER_S
    slope = np.polyfit(device_s - device_s[0], host_s - host_s[0], 1)[0]
    assert slope * (1.0 + rate_error) == pytest.approx(1.0, abs=10e-6)  # 150 ppm off the host's, within 10 ppm


def test_the_sensor_sends_in_bursts():
    with FakeNetFT(drifting_physics(), rate_hz=1000.0, burst_interval_s=BURSTS_S, burst_jitter_s=0.005) as fake:
        records, arrivals = stream(fake, 400)
    assert np.all(np.diff(records["rdt_sequence"].astype(np.int64)) == 1)
    bursts = np.split(arrivals, np.flatnonzero(np.diff(arrivals) > BURST_GAP_S) + 1)
    assert len(arrivals) == 400 and np.median([len(b) for b in bursts]) >= 5  # ~20 records every 10-30 ms


def test_a_descheduled_sender_skips_samples_seen_in_ft_sequence_not_rdt_sequence():
    with FakeNetFT(drifting_physics(), rate_hz=1000.0, max_backlog_s=0.01) as fake:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect(("127.0.0.1", fake.rdt_port))
        sock.settimeout(RECEIVE_TIMEOUT_S)
        try:
            sock.send(struct.pack(">HHI", 0x1234, 0x0002, 0))
            before, _ = receive_records(sock, 50)
            fake.deschedule(0.1)
            after, _ = receive_records(sock, 200)
        finally:
            sock.send(struct.pack(">HHI", 0x1234, 0x0000, 0))
            sock.close()
        skipped = fake.skipped_backlog
    records = np.concatenate([before, after])
    assert np.all(np.diff(records["rdt_sequence"].astype(np.int64)) == 1)  # every record sent arrived, in order
    steps = np.diff(records["ft_sequence"].astype(np.int64))
    assert skipped > 0
    assert np.sum(steps // 7 - 1) == skipped  # the box's samples the sender skipped, and only those


def test_a_start_heard_mid_burst_loses_none_of_the_samples_taken_before_it():
    """A real box sends each record as it samples it, so a start re-sent by the client (a driver that thinks the
    link went quiet) restarts rdt_sequence with nothing missing on the box's clock: the old stream's last record
    and the new stream's first are one sample period apart in ft_sequence. This fake produces in bursts, so the
    records due when it hears the command go out first (before, up to a burst of them was dropped unseen:
    counted as lost by a client, a loss no box makes)."""
    with FakeNetFT(drifting_physics(), rate_hz=1000.0, burst_interval_s=0.2, burst_jitter_s=0.0) as fake:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.connect(("127.0.0.1", fake.rdt_port))
        sock.settimeout(RECEIVE_TIMEOUT_S)
        try:
            sock.send(struct.pack(">HHI", 0x1234, 0x0002, 0))
            records, _ = receive_records(sock, 2)  # the start's first record, then the first burst
            sock.send(struct.pack(">HHI", 0x1234, 0x0002, 0))  # re-sent between bursts
            fake.wait_until(lambda f: f.streams_started >= 2)
            records = np.concatenate([records, receive_records(sock, 300)[0]])
        finally:
            sock.send(struct.pack(">HHI", 0x1234, 0x0000, 0))
            sock.close()
    rdt = records["rdt_sequence"].astype(np.int64)
    ft = records["ft_sequence"].astype(np.int64)
    restart = np.flatnonzero(np.diff(rdt) != 1)
    assert len(restart) == 1 and rdt[restart[0] + 1] == 1  # one restart, at the re-sent start
    assert np.all(np.diff(ft) == 7)  # 1 kHz: every 7th of the box's 7 kHz samples, none missing across it


def test_the_controller_stamps_rtde_packages_on_its_own_clock():
    rtde_receive = pytest.importorskip("rtde_receive")
    from tests.fakes.ur_process import URControllerProcess

    rate_error = -2000e-6  # large, so that a stamp on the host's clock would overtake the bound below
    with URControllerProcess(time_scale=0.0, extra_args=[f"--clock-rate-error={rate_error!r}",
                                                         "--send-jitter-s=0.0005"]) as controller:
        first = controller.control("clock")
        receiver = rtde_receive.RTDEReceiveInterface(controller.host, 500.0, ["timestamp"])
        try:
            stamps, hosts = [], []
            deadline = time.monotonic() + 10.0
            while len(stamps) < 200 and time.monotonic() < deadline:
                stamp = receiver.getTimestamp()
                hosts.append(time.monotonic())
                stamps.append(stamp)
                receiver.waitPeriod(receiver.initPeriod())
        finally:
            receiver.disconnect()
        last = controller.control("clock")
    assert len(stamps) == 200
    ratio = (last["controller_s"] - first["controller_s"]) / (last["host_s"] - first["host_s"])
    assert ratio == pytest.approx(1.0 + rate_error, abs=1e-9)
    # each package was stamped before it was read, on the controller's clock
    bound = (np.array(hosts) - first["start_host_s"]) * (1.0 + rate_error)
    assert np.all(np.array(stamps) <= bound)
    assert np.all(np.diff(stamps) >= 0) and stamps[-1] > stamps[0]
