"""The fake Net F/T speaks the real bytes (docs/protocols-ati.md), checked with raw sockets and independent clients.

Force and torque use different counts per unit and the torque is served in N-mm, so a scale or unit mix-up fails.
"""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest

from tests.fakes.netft import (
    RECORD_DTYPE,
    FakeNetFT,
    quantise_rate_hz,
)
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose, SharedPose

ROOT = Path(__file__).resolve().parents[1]
COUNTS_PER_FORCE = 1_000_000
COUNTS_PER_TORQUE_NMM = 1_000
"""Counts per N-mm: 1000 counts per N-mm = 10⁶ counts per N·m, different from the force's per N."""
RATE_HZ = 1000.0
RECEIVE_TIMEOUT_S = 2.0
NOISE_SIGMAS = 6.0
"""A mean of n noisy samples lies within this many standard errors of the truth."""
POSE = np.array([0.4, 0.1, 0.3, 2.0, -1.0, 0.5])


@pytest.fixture
def pose() -> SettablePose:
    return SettablePose(POSE)


@pytest.fixture
def physics(pose) -> SensorPhysics:
    return SensorPhysics(CellTruth(), pose, seed=3)


@pytest.fixture
def fake(physics):
    with FakeNetFT(physics, rate_hz=RATE_HZ, force_unit="N", torque_unit="N-mm",
                   counts_per_force=COUNTS_PER_FORCE, counts_per_torque=COUNTS_PER_TORQUE_NMM) as device:
        yield device


@pytest.fixture
def client(fake):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(("127.0.0.1", fake.rdt_port))
    sock.settimeout(RECEIVE_TIMEOUT_S)
    yield sock
    sock.send(struct.pack(">HHI", 0x1234, 0x0000, 0))
    sock.close()


def command(code: int, count: int = 0) -> bytes:
    return struct.pack(">HHI", 0x1234, code, count)


def receive_records(sock: socket.socket, n: int) -> np.ndarray:
    """Receive datagrams until n records arrived; return them as a structured array."""
    chunks = []
    total = 0
    while total < n:
        data = sock.recv(65536)
        assert len(data) % 36 == 0, f"datagram of {len(data)} bytes"
        chunks.append(np.frombuffer(data, dtype=RECORD_DTYPE))
        total += len(chunks[-1])
    return np.concatenate(chunks)[:n]


def expected_counts(physics: SensorPhysics) -> np.ndarray:
    wrench = physics.noiseless_wrench(POSE)
    return np.concatenate([wrench[:3] * COUNTS_PER_FORCE, wrench[3:] * 1000.0 * COUNTS_PER_TORQUE_NMM])


def noise_counts(physics: SensorPhysics, n: int) -> np.ndarray:
    sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
    return NOISE_SIGMAS * sigma * np.array([COUNTS_PER_FORCE] * 3 + [1000.0 * COUNTS_PER_TORQUE_NMM] * 3) / np.sqrt(n)


def test_stream_records_carry_device_counts_of_the_physics(fake, client, physics) -> None:
    client.send(command(0x0002))
    records = receive_records(client, 200)
    assert records["rdt_sequence"].tolist() == list(range(1, 201))
    assert np.all(np.diff(records["ft_sequence"].astype(np.int64)) == 7)  # 7000 Hz internal / 1000 Hz
    assert np.all(records["status"] == 0)
    mean = records["counts"].astype(float).mean(axis=0)
    np.testing.assert_array_less(np.abs(mean - expected_counts(physics)), noise_counts(physics, 200))


def test_count_n_sends_exactly_n_records_then_stops(fake, client) -> None:
    client.send(command(0x0002, 5))
    records = receive_records(client, 5)
    assert records["rdt_sequence"].tolist() == [1, 2, 3, 4, 5]
    fake.wait_for_records(5)
    assert not fake.stats()["streaming"]
    assert fake.records_sent == 5
    client.settimeout(0.05)
    with pytest.raises(socket.timeout):
        client.recv(100)


def test_each_start_resets_rdt_sequence_but_not_ft_sequence(fake, client) -> None:
    client.send(command(0x0002, 3))
    first = receive_records(client, 3)
    client.send(command(0x0002, 1))
    second = receive_records(client, 1)
    assert second["rdt_sequence"][0] == 1
    assert second["ft_sequence"][0] > first["ft_sequence"][-1]


def test_buffered_mode_sends_comrdtbsiz_records_per_datagram(fake, client) -> None:
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/comm.cgi?comrdtbsiz=50").read()
    assert fake.buffer_size == 40  # clamped to 1..40
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/comm.cgi?comrdtbsiz=8").read()
    client.send(command(0x0003, 24))
    sizes = [len(client.recv(65536)) for _ in range(3)]
    assert sizes == [8 * 36] * 3


def test_bias_subtracts_current_load_and_latch_is_informational(fake, client, physics) -> None:
    client.send(command(0x0002))
    receive_records(client, 5)
    client.send(command(0x0042))
    fake.wait_for_command(0x0042)
    fake.wait_until(lambda f: f.records_sent > 20)
    records = receive_records(client, 400)[-200:]
    # the bias is one noisy sample: the mean afterwards is within that sample's noise of zero
    np.testing.assert_array_less(np.abs(records["counts"].astype(float).mean(axis=0)), noise_counts(physics, 1))
    fake.latch()
    assert fake.status_word() == 0x8001_0000
    client.send(command(0x0041))
    fake.wait_for_command(0x0041)
    assert fake.status_word() == 0


def test_a_start_from_another_address_takes_the_stream_over(fake, client) -> None:
    client.send(command(0x0002))
    receive_records(client, 2)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.connect(("127.0.0.1", fake.rdt_port))
    other.settimeout(RECEIVE_TIMEOUT_S)
    try:
        other.send(command(0x0002))
        assert receive_records(other, 3)["rdt_sequence"].tolist() == [1, 2, 3]
    finally:
        other.send(command(0x0000))
        other.close()


def test_extended_command_streams_to_the_embedded_address(fake) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as target:
        target.bind(("127.0.0.1", 0))
        target.settimeout(RECEIVE_TIMEOUT_S)
        port = target.getsockname()[1]
        sender.sendto(struct.pack(">HHI4sH", 0x1234, 0x8002, 3, socket.inet_aton("127.0.0.1"), port),
                      ("127.0.0.1", fake.rdt_port))
        data, source = target.recvfrom(100)
        assert len(data) == 36 and source == ("127.0.0.1", fake.rdt_port)


def test_malformed_commands_are_ignored_and_recorded(fake, client) -> None:
    client.send(struct.pack(">HHI", 0x4321, 0x0002, 0))
    client.send(b"\x12\x34\x00\x02")
    client.send(command(0x0002, 1))  # a good one afterwards still works
    assert receive_records(client, 1)["rdt_sequence"][0] == 1
    codes = [c.code for c in fake.wait_for_command(None, count=3)]
    assert codes == [-1, -1, 0x0002]


def tcp_exchange(sock: socket.socket, request: bytes, reply_size: int) -> bytes:
    sock.sendall(request)
    reply = b""
    while len(reply) < reply_size:
        chunk = sock.recv(reply_size - len(reply))
        assert chunk, "connection closed"
        reply += chunk
    return reply


def test_tcp_readcalinfo_readft_and_writes_on_one_connection(fake, physics) -> None:
    with socket.create_connection(("127.0.0.1", fake.tcp_port), timeout=RECEIVE_TIMEOUT_S) as sock:
        sock.sendall(bytes([1]) + bytes(9))  # half a command: nothing happens until the rest arrives
        reply = tcp_exchange(sock, bytes(10), 24)
        header, force_code, torque_code, cpf, cpt, *scales = struct.unpack(">HBBII6H", reply)
        assert (header, force_code, torque_code, cpf, cpt) == (0x1234, 2, 4, COUNTS_PER_FORCE, COUNTS_PER_TORQUE_NMM)
        reply = tcp_exchange(sock, bytes(20), 16)
        header, status, *values = struct.unpack(">HH6h", reply)
        assert header == 0x1234 and status == 0
        value_si = np.array(values, dtype=float) * np.array(scales) / np.array(
            [COUNTS_PER_FORCE] * 3 + [COUNTS_PER_TORQUE_NMM * 1000.0] * 3)
        resolution = np.array(scales) / np.array([COUNTS_PER_FORCE] * 3 + [COUNTS_PER_TORQUE_NMM * 1000.0] * 3)
        sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
        np.testing.assert_array_less(np.abs(value_si - physics.noiseless_wrench(POSE)),
                                     resolution + NOISE_SIGMAS * sigma)
        assert tcp_exchange(sock, bytes([2]) + bytes(19), 4) == b"\x12\x34\x02\x00"
        assert tcp_exchange(sock, bytes([3]) + bytes(19), 4) == b"\x12\x34\x03\x00"
        fake.latch()
        reply = tcp_exchange(sock, bytes(18) + struct.pack(">H", 0x3), 16)  # bias + clear latch
        header, status, *values = struct.unpack(">HH6h", reply)
        assert status == 0
        # raw − bias: the difference of two noisy samples
        np.testing.assert_array_less(np.abs(values) * resolution, resolution + NOISE_SIGMAS * np.sqrt(2) * sigma)
    assert [c.code for c in fake.commands if c.source == "tcp"] == [1, 0, 2, 3, 0]


def test_http_pages_and_cgi_settings(fake) -> None:
    body = urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/netftapi2.xml?index=3").read().decode()
    for element in ("prodname", "cfgcpf", "cfgcpt", "scfgfu", "scfgtu", "setcfgsel", "cfgcalsel", "cfgcalsn",
                    "cfgnam", "cfgmr", "comrdtrate", "comrdtbsiz", "comrdte", "runstat", "runrate",
                    "setuserfilter", "setbias"):
        assert body.count(f"<{element}>") == 1, element
    assert "<scfgtu>N-mm</scfgtu>" in body and "<cfgcpt>1000</cfgcpt>" in body
    calibration = urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/netftcalapi.xml").read().decode()
    assert "<netftCalibration>" in calibration and "<calcpf>1000000</calcpf>" in calibration
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/comm.cgi?comrdtrate=150").read()
    assert fake.rate_hz == pytest.approx(7000 / 46)  # rounded up to 7000/n
    body = urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/netftapi2.xml").read().decode()
    assert "<comrdtrate>152.174</comrdtrate>" in body
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/setting.cgi?setuserfilter=3").read()
    assert "<setuserfilter>3</setuserfilter>" in urllib.request.urlopen(
        f"http://127.0.0.1:{fake.http_port}/netftapi2.xml").read().decode()


def test_rate_quantisation_matches_the_box() -> None:
    assert quantise_rate_hz(150) == (7000 / 46, 46)
    assert quantise_rate_hz(7000) == (7000.0, 1)
    assert quantise_rate_hz(20000) == (7000.0, 1)  # a real box cannot go faster
    assert quantise_rate_hz(20000, max_rate_hz=50000) == (20000.0, 1)


def test_pynetft_reads_correct_newtons_and_newton_metres(fake, physics) -> None:
    pynetft = pytest.importorskip("pynetft")
    config = pynetft.Config(sensor_host="127.0.0.1", rdt_port=fake.rdt_port, http_port=fake.http_port,
                            receive_timeout=0.5)
    with pynetft.Client(config, queue_size=4096) as client:
        samples = client.samples(timeout=RECEIVE_TIMEOUT_S)
        batch = [next(samples) for _ in range(300)]
        assert batch[-1].force_unit == pynetft.ForceUnit.NEWTON
        assert batch[-1].torque_unit == pynetft.TorqueUnit.NEWTON_MILLIMETER
        force = np.array([s.force for s in batch]).mean(axis=0)
        torque_nm = np.array([s.torque for s in batch]).mean(axis=0) / 1000.0  # N-mm → N·m
        truth = physics.noiseless_wrench(POSE)
        sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
        np.testing.assert_array_less(np.abs(np.concatenate([force, torque_nm]) - truth),
                                     NOISE_SIGMAS * sigma / np.sqrt(len(batch)))
        raw = np.array([s.raw_wrench for s in batch], dtype=float).mean(axis=0)
        np.testing.assert_allclose(raw[:3] / COUNTS_PER_FORCE, force, rtol=1e-9)
        health = client.health()
        assert health.lost_count == 0 and health.malformed_count == 0
    fake.wait_for_command(0x0000)  # pynetft stops the stream on stop()
    assert fake.commands[[c.source for c in fake.commands].index("udp")].code == 0x0002


def test_legacy_netft_client_reads_raw_counts(fake, physics) -> None:
    NetFT = pytest.importorskip("NetFT")
    sensor = NetFT.Sensor("127.0.0.1")
    sensor.sock.connect(("127.0.0.1", fake.rdt_port))  # its port is hard-coded to 49152
    sensor.sock.settimeout(RECEIVE_TIMEOUT_S)
    try:
        readings = np.array([sensor.getMeasurement() for _ in range(50)], dtype=float)
    finally:
        sensor.sock.close()
    np.testing.assert_array_less(np.abs(readings.mean(axis=0) - expected_counts(physics)), noise_counts(physics, 50))


def test_runs_as_its_own_process_and_follows_a_shared_pose(physics) -> None:
    shared = SharedPose(create=True)
    try:
        shared.set(POSE)
        process = subprocess.Popen(
            [sys.executable, "-m", "tests.fakes.netft", "--rate-hz", "500", "--torque-unit", "N-mm",
             "--counts-per-torque", str(COUNTS_PER_TORQUE_NMM), "--pose-shm", shared.name],
            cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        try:
            ports = json.loads(process.stdout.readline())
            assert ports["url"].startswith(f"netft://127.0.0.1:{ports['rdt_port']}?")
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
                sock.connect(("127.0.0.1", ports["rdt_port"]))
                sock.settimeout(RECEIVE_TIMEOUT_S)
                sock.send(command(0x0002, 100))
                records = receive_records(sock, 100)
            # same ground truth (default CellTruth) at the shared pose
            mean = records["counts"].astype(float).mean(axis=0)
            np.testing.assert_array_less(np.abs(mean - expected_counts(physics)), noise_counts(physics, 100))
            process.stdin.write("stats\n")
            process.stdin.flush()
            stats = json.loads(process.stdout.readline())
            assert stats["records_sent"] == 100
        finally:
            process.stdin.close()
            assert process.wait(timeout=10) == 0
    finally:
        shared.close()


def test_close_joins_threads_and_reraises_their_errors(physics) -> None:
    class Broken:
        def sample(self, n):
            raise RuntimeError("physics exploded")

    device = FakeNetFT(Broken(), rate_hz=RATE_HZ).start()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.sendto(command(0x0002), ("127.0.0.1", device.rdt_port))
        device.wait_for_command(0x0002)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(RuntimeError, match="physics exploded"):
            device.close()


def test_monitor_condition_latches_until_reset(fake, client) -> None:
    # condition 0: Fz counts > 0 (the default pose's Fz is ≈ +11 N); enable monitoring
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/moncon.cgi?mce0=1&mcx0=2&mcc0=1&mcv0=0&setmce=1").read()
    client.send(command(0x0002))
    fake.wait_until(lambda f: f.status_word() == 0x8001_0000, what="latch")
    records = receive_records(client, 50)
    assert records["status"][-1] == 0x8001_0000
    urllib.request.urlopen(f"http://127.0.0.1:{fake.http_port}/moncon.cgi?setmce=0").read()
    client.send(command(0x0041))
    fake.wait_for_command(0x0041)
    assert fake.status_word() == 0


def test_a_quiet_link_hides_records_while_the_box_streams_on_and_hears_a_start(fake, client) -> None:
    """go_silent() is the link, not the box: sequences advance meanwhile, a start restarts rdt_sequence only."""
    client.send(command(0x0002))
    before = receive_records(client, 50)
    fake.go_silent()
    fake.wait_until(lambda f: f.records_silenced >= 100)
    client.send(command(0x0002))  # a re-sent start reaches the box during the silence
    fake.wait_until(lambda f: f.stats()["streams_started"] == 2 and f.records_silenced >= 300)
    silenced_so_far = fake.records_silenced
    fake.resume()
    records = np.concatenate([before, receive_records(client, 400)])  # what was queued, then after the silence
    ft = records["ft_sequence"].astype(np.int64)
    jump = np.flatnonzero(np.diff(ft) != 7)
    assert len(jump) == 1  # one hole: the silence
    produced_meanwhile = (ft[jump[0] + 1] - ft[jump[0]]) // 7 - 1
    assert produced_meanwhile >= silenced_so_far  # ft_sequence ran on through the silence
    first_after = int(records["rdt_sequence"][jump[0] + 1])
    assert 1 < first_after < produced_meanwhile  # the restarted stream went on into the quiet link
    fake.power_off()  # stops the stream: the log and the count are final
    sent = fake.sent_records()
    assert len(sent) == fake.records_sent and sent["ft_sequence"][0] == before["ft_sequence"][0]


def test_power_cycle_silences_the_box_and_restarts_both_sequences(fake, client) -> None:
    client.send(command(0x0002))
    receive_records(client, 20)
    fake.power_off()
    powered_on_s = fake.power_on()
    client.settimeout(0.3)
    with pytest.raises(socket.timeout):
        for _ in range(1000):  # drain what was in flight; then nothing comes until a start
            client.recv(100)
    client.settimeout(RECEIVE_TIMEOUT_S)
    client.send(command(0x0002))
    records = receive_records(client, 3)
    on_for_s = time.monotonic() - powered_on_s
    assert records["rdt_sequence"].tolist() == [1, 2, 3]
    ft = records["ft_sequence"].astype(np.int64)
    assert np.all(np.diff(ft) == 7) and 0 <= ft[0] <= 7000 * on_for_s + 7  # counted from power-up, not before
