"""``ftacq sensor info | record | bias`` against the fake Net F/T (and the error paths a technician meets)."""

from __future__ import annotations

import csv
import json
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ftacq.app.cli import main
from tests.conftest import wait_until
from tests.fakes.netft import FakeNetFT
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

ROOT = Path(__file__).resolve().parents[1]
POSE = np.array([0.4, 0.1, 0.3, 2.0, -1.0, 0.5])
RATE_HZ = 1000.0
NOISE_SIGMAS = 6.0
SUBPROCESS_TIMEOUT_S = 60.0


@pytest.fixture
def physics() -> SensorPhysics:
    return SensorPhysics(CellTruth(), SettablePose(POSE), seed=7)


@pytest.fixture
def fake(physics):
    with FakeNetFT(physics, rate_hz=RATE_HZ, torque_unit="N-mm", counts_per_torque=1_000,
                   counts_per_force=2_000_000, serial="FT98765") as device:
        yield device


def test_info_prints_identity_units_rate_and_status(fake, capsys) -> None:
    assert main(["sensor", "info", fake.url, "--seconds", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "FT98765" in out and "2.2.59" in out
    assert "force N, torque N-mm" in out
    assert "2000000 per N, 1000 per N-mm" in out
    assert "1000 Hz configured" in out
    assert "0x00000000 (ok)" in out
    assert "lost 0" in out


def test_record_writes_si_csv_and_prints_health(fake, physics, tmp_path, capsys) -> None:
    path = tmp_path / "wrench.csv"
    assert main(["sensor", "record", fake.url, "--seconds", "0.4", "-o", str(path)]) == 0
    with path.open() as handle:
        rows = list(csv.reader(handle))
    assert rows[0][:8] == ["t", "fx", "fy", "fz", "tx", "ty", "tz", "status"]
    table = np.array(rows[1:], dtype=float)
    assert len(table) > 100
    assert table[0, 0] == 0.0 and np.all(np.diff(table[:, 0]) >= 0)
    sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
    np.testing.assert_array_less(np.abs(table[:, 1:7].mean(axis=0) - physics.noiseless_wrench(POSE)),
                                 NOISE_SIGMAS * sigma / np.sqrt(len(table)))  # torque in N·m, not N-mm
    assert np.all(table[:, 7] == 0)
    # each sample's time on the box's own clock (its ft_sequence: one sample period apart), and that time on the
    # host clock (the minimum-delay line): in order, never later than the sample was received
    assert rows[0][-2:] == ["device_time_s", "sample_time_s"]
    device, sample = table[:, -2], table[:, -1]
    np.testing.assert_allclose(np.median(np.diff(device)), 1.0 / RATE_HZ, rtol=1e-6)
    assert np.all(np.diff(device) > 0) and np.all(np.diff(sample) > 0)
    assert np.all(sample <= table[:, 0] + 1e-6)
    out = capsys.readouterr().out
    assert f"{len(table)} samples" in out and "health: received" in out and "lost 0" in out


def test_record_saturated_samples_are_marked(fake, tmp_path, capsys) -> None:
    fake.saturate(None)
    path = tmp_path / "saturated.csv"
    assert main(["sensor", "record", fake.url, "--seconds", "0.2", "-o", str(path)]) == 0
    with path.open() as handle:
        rows = list(csv.DictReader(handle))
    assert rows and all(int(row["status"]) == 0x8002_0000 and row["saturated"] == "1" for row in rows)
    saturated = int(re.search(r"saturated (\d+)", capsys.readouterr().out).group(1))
    assert saturated >= len(rows)  # the summary counts every flagged record the stream delivered


def test_bias_tares_the_device(fake, capsys) -> None:
    assert main(["sensor", "bias", fake.url]) == 0
    captured = capsys.readouterr()
    assert "biased" in captured.out and "residual mean" in captured.out
    assert "no longer fits" in captured.err and "ftacq tare" in captured.err  # a box bias invalidates calibrations
    assert 0x0042 in [c.code for c in fake.commands if c.source == "udp"]
    assert np.abs(fake.bias_counts).max() > 0


def test_bad_url_is_one_message_and_exit_2(tmp_path, capsys) -> None:
    assert main(["sensor", "info", "netft://127.0.0.1:notaport"]) == 2
    assert main(["sensor", "info", "ftp://somewhere"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(line.startswith("ftacq: error: sensor URL") for line in err)


def test_unreachable_sensor_is_one_message_and_exit_1(capsys) -> None:
    with socket.socket() as tcp, socket.socket() as http:
        tcp.bind(("127.0.0.1", 0))
        http.bind(("127.0.0.1", 0))  # bound but not listening: refused
        url = f"netft://127.0.0.1:9?tcp_port={tcp.getsockname()[1]}&http_port={http.getsockname()[1]}"
        assert main(["sensor", "info", url]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach the Net F/T at 127.0.0.1" in err[0]


def test_record_rejects_bad_seconds_without_writing(fake, tmp_path, capsys) -> None:
    path = tmp_path / "never.csv"
    assert main(["sensor", "record", fake.url, "--seconds", "-1", "-o", str(path)]) == 2
    assert not path.exists()
    assert "--seconds -1" in capsys.readouterr().err


def test_ctrl_c_keeps_what_was_recorded(tmp_path) -> None:
    """Run the real ``ftacq`` entry point against the fake in its own process; interrupt it mid-recording."""
    fake_process = subprocess.Popen([sys.executable, "-m", "tests.fakes.netft", "--rate-hz", "500"], cwd=ROOT,
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        url = json.loads(fake_process.stdout.readline())["url"]
        path = tmp_path / "interrupted.csv"
        recorder = subprocess.Popen([sys.executable, "-m", "ftacq.app.cli", "sensor", "record", url, "--seconds", "60",
                                     "-o", str(path)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True)
        wait_until(lambda: recorder.poll() is not None
                   or any(p.stat().st_size > 4096 for p in tmp_path.glob(".interrupted.csv.*")),
                   "the recorder writing samples", timeout_s=SUBPROCESS_TIMEOUT_S)
        assert recorder.poll() is None, recorder.communicate()
        recorder.send_signal(signal.SIGINT)
        out, err = recorder.communicate(timeout=SUBPROCESS_TIMEOUT_S)
        assert recorder.returncode == 130, err
        assert "stopped by Ctrl-C" in out
        with path.open() as handle:
            rows = list(csv.reader(handle))
        assert rows[0][0] == "t" and len(rows) > 50
        assert all(len(row) == len(rows[0]) for row in rows)  # no half-written row
        assert not list(tmp_path.glob(".interrupted.csv.*"))
    finally:
        fake_process.stdin.close()
        fake_process.wait(timeout=SUBPROCESS_TIMEOUT_S)


def test_sensor_without_action_prints_help(capsys) -> None:
    assert main(["sensor"]) == 2
    assert "info" in capsys.readouterr().out


def test_the_same_commands_work_for_a_can_sensor(physics, tmp_path, capsys) -> None:
    """``ftacq sensor`` goes through drivers.sensor.open_sensor: a NETCANOEM board on a virtual CAN bus works too."""
    import uuid

    from tests.fakes.netcanoem import FakeNetCanOem

    channel = f"cli-{uuid.uuid4()}"
    board = FakeNetCanOem(channel, physics, serial="FT23456", torque_unit_code=4, counts_per_torque=1_000)
    try:
        url = f"can://virtual/{channel}?rate_hz=200"
        assert main(["sensor", "info", url, "--seconds", "0.2"]) == 0
        out = capsys.readouterr().out
        assert "FT23456" in out and "torque N-mm" in out
        path = tmp_path / "can.csv"
        assert main(["sensor", "record", url, "--seconds", "0.3", "-o", str(path)]) == 0
        table = np.genfromtxt(path, delimiter=",", skip_header=1)  # empty cells: NaN
        sigma = np.array(physics.truth.force_noise_n + physics.truth.torque_noise_nm)
        np.testing.assert_array_less(np.abs(table[:, 1:7].mean(axis=0) - physics.noiseless_wrench(POSE)),
                                     NOISE_SIGMAS * sigma / np.sqrt(len(table)) + 0.02)  # + gage quantisation
        # a polled CAN sensor has no sample clock: device_time_s empty, sample_time_s the receive time
        assert np.all(np.isnan(table[:, -2]))
        np.testing.assert_allclose(table[:, -1], table[:, 0], atol=1e-6)
    finally:
        board.close()
