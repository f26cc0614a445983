"""The Net F/T driver against the fake: discovery and its cross-check, SI conversion, streaming, bias, URLs."""

from __future__ import annotations

import logging
import socket
import struct

import numpy as np
import pytest

from drivers.netft import NetFTSensor, canonical_unit, parse_flat_xml, parse_netft_url, status_text
from drivers.sensor import ForceTorqueSensor, open_sensor
from ftacq.errors import DeviceConnectionError, DeviceError, InputError
from tests.fakes.netft import FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RATE_HZ = 1000.0
POSE = np.array([0.4, 0.1, 0.3, 2.0, -1.0, 0.5])
NOISE_SIGMAS = 6.0
"""A mean of n noisy samples lies within this many standard errors of the truth."""
READ_TIMEOUT_S = 2.0


@pytest.fixture
def physics() -> SensorPhysics:
    return SensorPhysics(CellTruth(), SettablePose(POSE), seed=5)


def make_fake(physics, **options) -> FakeNetFT:
    settings = dict(rate_hz=RATE_HZ, force_unit="N", torque_unit="N-mm", counts_per_force=1_000_000,
                    counts_per_torque=1_000)
    settings.update(options)
    return FakeNetFT(physics, **settings)


@pytest.fixture
def fake(physics):
    with make_fake(physics) as device:
        yield device


def tolerance(physics, n: int) -> np.ndarray:
    sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
    return NOISE_SIGMAS * sigma / np.sqrt(n)


def test_driver_reads_si_from_a_box_serving_torque_in_newton_millimetres(fake, physics) -> None:
    with NetFTSensor.from_url(fake.url) as sensor:
        assert isinstance(sensor, ForceTorqueSensor)
        info = sensor.info
        assert (info.transport, info.serial, info.force_unit, info.torque_unit) == ("netft", "FT12345", "N", "N-mm")
        assert (info.counts_per_force, info.counts_per_torque, info.rate_hz) == (1e6, 1e3, RATE_HZ)
        batch = sensor.read(timeout_s=READ_TIMEOUT_S)
        assert batch.wrench.shape == (len(batch), 6) and batch.counts.dtype == np.int64
        np.testing.assert_allclose(batch.wrench[:, 3:], batch.counts[:, 3:] / 1e6)  # N-mm counts → N·m
        np.testing.assert_allclose(batch.wrench[:, :3], batch.counts[:, :3] / 1e6)
        average = sensor.average(0.2)
        np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                     tolerance(physics, average.count))
        assert average.count >= 100 and average.saturated == 0 and average.lost == 0
        np.testing.assert_allclose(average.std, np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm),
                                   rtol=0.35)
        health = sensor.health()
        assert health.received > 0 and health.lost == health.duplicate == health.malformed == 0
        assert np.all(np.diff(batch.sequence) == 1) and np.all(np.diff(batch.time_s) >= 0)
    fake.wait_for_command(0x0000)  # stop on close


def test_imperial_units_are_converted_once(physics) -> None:
    with make_fake(physics, force_unit="lbf", torque_unit="lbf-in", counts_per_force=200_000,
                   counts_per_torque=30_000) as device, NetFTSensor.from_url(device.url) as sensor:
        average = sensor.average(0.2)
        np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                     tolerance(physics, average.count) + 1.0 / 30_000)


def test_http_and_tcp_disagreeing_is_a_clear_error(physics) -> None:
    with make_fake(physics) as device:
        device.calinfo_override = (2, 3, 1_000_000, 1_000)  # TCP says N-m, HTTP says N-mm
        with pytest.raises(DeviceError, match=r"disagree.*N-mm.*TCP READCALINFO.*N-m"):
            NetFTSensor.from_url(device.url).start()
        assert not any(c.source == "udp" for c in device.commands)  # never started streaming


@pytest.mark.parametrize("missing", ["calibration_page", "tcp", "prodname"])
def test_liberal_about_what_the_box_serves(physics, caplog, missing) -> None:
    options = {"calibration_page": dict(serve_calibration_page=False), "tcp": dict(serve_tcp=False),
               "prodname": dict(prodname=None)}[missing]
    caplog.set_level(logging.WARNING, logger="drivers.netft")
    with make_fake(physics, **options) as device:
        url = device.url if missing != "tcp" else device.url.replace("tcp_port=0", f"tcp_port={unused_tcp_port()}")
        with NetFTSensor.from_url(url) as sensor:
            average = sensor.average(0.1)
            np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                         tolerance(physics, average.count))
    if missing != "prodname":
        assert any(("netftcalapi" in r.message or "only" in r.message) for r in caplog.records)


def unused_tcp_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_url_overrides_scaling_when_the_box_offers_none(physics) -> None:
    with make_fake(physics, serve_tcp=False) as device:
        device.serve_calibration_page = False
        url = (f"netft://127.0.0.1:{device.rdt_port}?tcp_port={unused_tcp_port()}&http_port={unused_tcp_port()}"
               "&counts_per_force=1000000&counts_per_torque=1000&force_unit=N&torque_unit=N-mm")
        with NetFTSensor.from_url(url) as sensor:
            assert sensor.info.extra["scaling_source"] == "URL"
            average = sensor.average(0.1)
            np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                         tolerance(physics, average.count))


def test_rate_and_buffered_mode_from_the_url(physics) -> None:
    with make_fake(physics) as device:
        with NetFTSensor.from_url(device.url + "&rate_hz=500&buffered=1&buffer_size=10") as sensor:
            assert sensor.info.rate_hz == 500.0 and device.rate_hz == 500.0 and device.buffer_size == 10
            device.wait_until(lambda f: f.records_sent >= 200)
            batch = sensor.read(timeout_s=READ_TIMEOUT_S)
            assert len(batch) % 10 == 0
            health = sensor.health()
            assert health.lost == 0 and health.malformed == 0
        starts = [c for c in device.commands if c.source == "udp" and c.code == 0x0003]
        assert starts, "buffered mode streams with 0x0003"
        cgi = [c for c in device.commands if c.source == "http" and c.code == "/comm.cgi"]
        assert cgi and cgi[0].params == {"comrdtrate": "500", "comrdtbsiz": "10"}


def test_bias_tares_on_the_device_and_later_samples_read_zero(fake, physics) -> None:
    with NetFTSensor.from_url(fake.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        sensor.bias()
        batch = sensor.read(timeout_s=READ_TIMEOUT_S)
        assert batch.sequence[0] <= 16  # only records from the restarted (biased) stream
        average = sensor.average(0.2)
        sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
        np.testing.assert_array_less(np.abs(average.mean), NOISE_SIGMAS * sigma)  # one noisy sample is the bias
        assert sensor.health().restarts == 0  # our own restart is not a fault
    codes = [c.code for c in fake.commands if c.source == "udp"]
    assert codes[:3] == [0x0002, 0x0042, 0x0002]


def test_datagrams_from_other_senders_are_rejected_and_counted(fake) -> None:
    with NetFTSensor.from_url(fake.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        record = struct.pack(">III6i", 999_999, 0, 0, *([123_456_789] * 6))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as intruder:
            for _ in range(3):
                intruder.sendto(record, sensor.local_address)
        deadline_batches = [sensor.read(timeout_s=READ_TIMEOUT_S) for _ in range(3)]
        while sensor.health().foreign < 3:
            deadline_batches.append(sensor.read(timeout_s=READ_TIMEOUT_S))
        assert all(not np.any(b.counts == 123_456_789) for b in deadline_batches)
        health = sensor.health()
        assert health.foreign == 3 and health.lost == 0


def test_unreachable_sensor_is_one_connection_error() -> None:
    with socket.socket() as tcp, socket.socket() as http:
        tcp.bind(("127.0.0.1", 0))
        http.bind(("127.0.0.1", 0))  # bound, not listening: connections are refused
        url = f"netft://127.0.0.1:9?tcp_port={tcp.getsockname()[1]}&http_port={http.getsockname()[1]}"
        with pytest.raises(DeviceConnectionError, match="cannot reach the Net F/T at 127.0.0.1"):
            NetFTSensor.from_url(url).start()


def test_open_sensor_builds_the_driver_from_the_url() -> None:
    sensor = open_sensor("netft://192.0.2.7:4000?tcp_port=4001&http_port=8080&rate_hz=1000")
    assert isinstance(sensor, NetFTSensor)
    assert (sensor.host, sensor.rdt_port, sensor.tcp_port, sensor.http_port) == ("192.0.2.7", 4000, 4001, 8080)
    defaults = open_sensor("netft://192.0.2.7")
    assert (defaults.rdt_port, defaults.tcp_port, defaults.http_port) == (49152, 49151, 80)


@pytest.mark.parametrize("url, message", [
    ("netft://127.0.0.1:abc", "Port could not be cast"),
    ("netft://", "no host"),
    ("netft://127.0.0.1?colour=red", "unknown query key 'colour'"),
    ("netft://127.0.0.1?rate_hz=100&rate_hz=200", "given twice"),
    ("netft://127.0.0.1?rate_hz=fast", "rate_hz='fast'"),
    ("netft://127.0.0.1?buffered=maybe", "buffered='maybe'"),
    ("netft://127.0.0.1?counts_per_force=1000", "only all together"),
    ("netft://127.0.0.1?buffer_size=99", "buffer_size = 99"),
    ("netft://127.0.0.1/path", "unexpected path"),
])
def test_bad_urls_name_the_problem(url, message) -> None:
    with pytest.raises(InputError, match=message):
        open_sensor(url)


def test_unit_strings_and_codes() -> None:
    assert canonical_unit("Nm", "torque") == "N-m"
    assert canonical_unit("Nmm", "torque") == "N-mm"
    assert canonical_unit("4", "torque") == "N-mm"
    assert canonical_unit("kg-cm", "torque") == "kgf-cm"
    assert canonical_unit("lbf", "force") == "lbf"
    with pytest.raises(DeviceError, match="unknown torque unit 'furlong'"):
        canonical_unit("furlong", "torque")


def test_flat_xml_parser_is_liberal() -> None:
    assert parse_flat_xml("<netft><cfgcpf>100</cfgcpf><scfgfu>N</scfgfu></netft>") == {"cfgcpf": "100", "scfgfu": "N"}
    assert parse_flat_xml("<netft><cfgcpf>100</cfgcpf><broken>")["cfgcpf"] == "100"  # tag scan fallback


def test_status_text_names_bits_of_both_maps() -> None:
    assert status_text(0x8002_0000) == "error summary, transducer saturation or A/D error"
    assert status_text(0x0000_0008, "axia") == "busy"
    assert status_text(0) == "ok"


def test_units_changed_on_the_box_are_followed(physics) -> None:
    """config.cgi cfgfu=1 (lbf), cfgtu=2 (lbf-ft): counts per unit change with them; the driver still gives SI."""
    with make_fake(physics) as device:
        import urllib.request

        urllib.request.urlopen(f"http://127.0.0.1:{device.http_port}/config.cgi?cfgid=0&cfgfu=1&cfgtu=2").read()
        assert (device.force_unit, device.torque_unit) == ("lbf", "lbf-ft")
        assert device.counts_per_force == round(1e6 * 4.4482216152605)
        with NetFTSensor.from_url(device.url) as sensor:
            assert (sensor.info.force_unit, sensor.info.torque_unit) == ("lbf", "lbf-ft")
            average = sensor.average(0.2)
            np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                         tolerance(physics, average.count))


@pytest.fixture
def small_ring(monkeypatch):
    """A 512-record receive ring with room for 64-record datagrams, so a short stream wraps it many times."""
    import drivers.netft.receiver as receiver

    monkeypatch.setattr(receiver, "RING_RECORDS", 512)
    monkeypatch.setattr(receiver, "SLACK_RECORDS", 64)
    monkeypatch.setattr(receiver, "MAX_DATAGRAM_BYTES", 64 * 36)


def test_ring_wraps_with_datagrams_straddling_its_end(physics, small_ring) -> None:
    with make_fake(physics, rate_hz=2000) as device, \
            NetFTSensor.from_url(device.url + "&buffered=1&buffer_size=7") as sensor:  # 512 % 7 ≠ 0
        batches = []
        while sum(len(b) for b in batches) < 3000:
            batches.append(sensor.read(timeout_s=READ_TIMEOUT_S))
        batch = type(batches[0]).concatenate(batches)
        health = sensor.health()
        steps = np.diff(batch.sequence)
        # a loaded machine may stall this reader past the small ring: then whole datagrams are dropped, and
        # exactly those records are counted lost; everything delivered is intact and in order
        assert np.all(steps >= 1) and int((steps - 1).sum()) == health.lost == 7 * sensor.overflowed
        assert np.count_nonzero(steps > 1) <= sensor.overflowed
        np.testing.assert_allclose(batch.wrench, batch.counts * sensor.scaling.counts_to_si)
        assert np.all(np.diff(batch.time_s) >= 0)
        assert health.duplicate == health.out_of_order == health.malformed == 0


def test_a_reader_that_stops_reading_loses_records_counted_as_lost(physics, small_ring) -> None:
    with make_fake(physics, rate_hz=2000) as device, NetFTSensor.from_url(device.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        sent = device.records_sent
        device.wait_until(lambda f: f.records_sent > sent + 1500)  # ring holds 512: the rest must be dropped
        while sensor.overflowed == 0:
            now_sent = device.records_sent
            device.wait_until(lambda f, now_sent=now_sent: f.records_sent > now_sent + 10)
        target = device.stats()["rdt_sequence"] + 20
        while sensor.read(timeout_s=READ_TIMEOUT_S).sequence[-1] < target:
            pass
        health = sensor.health()
        assert sensor.overflowed > 0 and health.lost == sensor.overflowed  # each dropped datagram is one lost record
        assert health.duplicate == health.out_of_order == health.restarts == 0


def test_url_keys_become_constructor_arguments() -> None:
    assert parse_netft_url("netft://box.local:5000?tcp_port=5001&http_port=8080&rate_hz=500&buffered=yes"
                           "&buffer_size=20&timeout_s=0.5&status_map=axia") == {
        "host": "box.local", "rdt_port": 5000, "tcp_port": 5001, "http_port": 8080, "rate_hz": 500.0,
        "buffered": True, "buffer_size": 20, "timeout_s": 0.5, "status_map": "axia"}


def test_the_kernels_drops_at_the_socket_are_read_from_its_table() -> None:
    """Datagrams sent into a socket nobody drains: what its (small) buffer cannot hold the kernel drops and counts;
    received + dropped = sent (loopback delivers in the sender's call)."""
    import socket

    from drivers.netft.receiver import socket_drops

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as receiving, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sending:
        receiving.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        receiving.bind(("127.0.0.1", 0))
        if socket_drops(receiving) is None:
            pytest.skip("this system does not report per-socket drops (/proc/self/net/udp)")
        assert socket_drops(receiving) == 0
        sent = 500
        for k in range(sent):
            sending.sendto(k.to_bytes(4, "little") * 9, receiving.getsockname())
        receiving.setblocking(False)
        received = 0
        while True:
            try:
                receiving.recv(64)
            except BlockingIOError:
                break
            received += 1
        dropped = socket_drops(receiving)
        assert dropped is not None and dropped > 0 and received + dropped == sent
        assert socket_drops(receiving, tables=()) is None  # no table: not known, not zero


def test_records_from_another_port_are_rejected_unless_allowed(physics) -> None:
    with make_fake(physics, send_from_other_socket=True) as device:
        with pytest.raises(DeviceError, match=r"foreign.*accept_any_port=1"):
            NetFTSensor.from_url(device.url).start()
        with NetFTSensor.from_url(device.url + "&accept_any_port=1") as sensor:
            average = sensor.average(0.1)
            np.testing.assert_array_less(np.abs(average.mean - physics.noiseless_wrench(POSE)),
                                         tolerance(physics, average.count))
            assert sensor.health().foreign == 0


def test_the_contract_imports_no_driver_and_the_registry_loads_one_lazily() -> None:
    import subprocess
    import sys

    code = ("import sys, drivers.sensor as s; assert 'drivers.netft' not in sys.modules, 'netft imported'; "
            "assert 'drivers.ati_can' not in sys.modules, 'ati_can imported'; "
            "print(s.sensor_class('netft://192.0.2.1').__name__, sorted(s.SENSOR_TYPES))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split()[0] == "NetFTSensor"
    with pytest.raises(InputError, match="unknown scheme 'ftp'.*netft://.*can://"):
        open_sensor("ftp://x")
    from drivers.sensor import parse_sensor_url

    assert parse_sensor_url("netft://192.0.2.7?rate_hz=500") == {"host": "192.0.2.7", "rate_hz": 500.0}
    with pytest.raises(InputError, match="Invalid IPv6 URL"):
        parse_sensor_url("netft://[::1")


def test_driver_state_is_set_in_the_constructor() -> None:
    sensor = NetFTSensor("192.0.2.7")
    assert sensor._family == socket.AF_INET and sensor.local_address is None


def test_receive_socket_is_bound_to_the_interface_that_routes_to_the_box(fake) -> None:
    with NetFTSensor.from_url(fake.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        address, port = sensor.local_address
        assert address == "127.0.0.1" and port != 0  # not the wildcard 0.0.0.0


def test_resend_schedule_is_short_while_a_box_restarts_and_backs_off_when_it_is_gone() -> None:
    from drivers.netft.receiver import (
        BACKOFF_MAX_S,
        BACKOFF_RESTARTING_MAX_S,
        UNREACHABLE_AFTER_S,
        next_retry_interval_s,
    )

    intervals, silent_s, interval = [], 0.25, 0.0
    while silent_s < 2 * UNREACHABLE_AFTER_S:
        interval = next_retry_interval_s(interval, silent_s)
        intervals.append((silent_s, interval))
        silent_s += interval
    assert intervals[0][1] == 0.25 and intervals[1][1] == 0.5
    assert max(i for s, i in intervals if s < UNREACHABLE_AFTER_S) == BACKOFF_RESTARTING_MAX_S
    assert intervals[-1][1] == BACKOFF_MAX_S


def test_benchmark_figures_are_available_from_the_driver(fake) -> None:
    """benchmarks/stream.py reads these: they must exist on the driver."""
    with NetFTSensor.from_url(fake.url) as sensor:
        sensor.read(timeout_s=READ_TIMEOUT_S)
        assert sensor.receive_buffer_bytes > 0 and sensor.delivered > 0 and sensor.overflowed == 0
        health = sensor.health()
        assert health.socket_drops == health.ring_overflows == 0


def test_sensor_urls_from_random_pieces_raise_only_input_errors() -> None:
    """Fuzz (seeded): any string made of URL pieces is accepted or refused with InputError, never a traceback."""
    import random

    from drivers.sensor import parse_sensor_url

    pieces = ["netft://", "can://", "virtual/", "socketcan/can0", "127.0.0.1", "[::1", "[::1]", ":", "?", "&", "=",
              "rate_hz", "tcp_port", "base", "0x", "nan", "inf", "-1", "1e400", "99999999999", "buffered", "yes",
              "timeout_s", "%", "%zz", "/", "#", "@", "\x00", "é", "calibration", "bitrate", "status_map", "axia",
              "force_unit", "N-mm", "counts_per_force", "counts_per_torque", "torque_unit", "lbf", "ftp://"]
    rng = random.Random(15)
    accepted = 0
    for _ in range(3000):
        url = "".join(rng.choice(pieces) for _ in range(rng.randint(1, 8)))
        try:
            parse_sensor_url(url)
            accepted += 1
        except InputError:
            pass
    assert accepted > 0
    for bad in (None, 42, b"netft://x"):
        with pytest.raises(InputError):
            parse_sensor_url(bad)


def test_a_low_latency_hold_applies_on_open_and_is_given_back(fake) -> None:
    from drivers.netft.receiver import COALESCE_S

    sensor = NetFTSensor.from_url(fake.url)
    assert sensor.max_hold_s is None
    assert sensor.prefer_low_latency(0.0003) is None  # asked before the start: applied when the receiver opens
    with sensor:
        receiver = sensor._receiver
        assert receiver is not None and receiver.coalesce_s == 0.0003
        assert sensor.prefer_low_latency(0.0001) == 0.0003 and receiver.coalesce_s == 0.0001
        assert sensor.prefer_low_latency(0.0003) == 0.0001 and receiver.coalesce_s == 0.0003  # longer again
        assert sensor.prefer_low_latency(None) == 0.0003  # the driver's own hold back: one wake-up a millisecond
        assert receiver.coalesce_s == COALESCE_S and sensor.max_hold_s is None
        assert sensor.prefer_low_latency(0.5) is None and receiver.coalesce_s == COALESCE_S  # never longer
        assert sensor.prefer_low_latency(-1.0) == 0.5 and receiver.coalesce_s == 0.0
        assert len(sensor.read(timeout_s=READ_TIMEOUT_S)) > 0
