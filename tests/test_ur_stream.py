"""drivers/ur_stream.py (every RTDE state sample, kept) against the simulated controller moving in real time:
no sample lost, host times free of receive jitter, and q, q̇, q̈ that agree with each other and with the move."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.robot import MotionLimits
from drivers.ur import URRobot
from drivers.ur_stream import URStateStream
from ftacq.timebase import MAX_RATE_ERROR
from ftacq.errors import DeviceConnectionError
from tests.conftest import wait_until
from tests.fakes.ur_process import URControllerProcess, random_loopback_address

pytest.importorskip("rtde_control")

HOME_Q = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
SPEED, ACCELERATION = 1.0, 2.0


def _arrived(stream: URStateStream, count: int, target: np.ndarray):
    """The stream's window once it holds more than ``count`` samples and its newest q is the target, else None."""
    if stream.count <= count:
        return None
    window = stream.window()
    return window if np.abs(window.q[-1] - target).max() <= 1e-9 else None


def test_stream_keeps_every_sample_of_a_real_time_move():
    target = HOME_Q + np.array([0.3, -0.2, 0.25, 0.4, -0.5, 0.6])
    with URControllerProcess(time_scale=1.0, initial_q=HOME_Q) as fake, \
            URStateStream(fake.host) as stream, URRobot(fake.host, MotionLimits(SPEED, ACCELERATION)) as robot:
        wait_until(lambda: stream.count > 50, what="state samples")
        start = stream.count
        robot.move_joints(target, SPEED, ACCELERATION)
        # the move ends when the controller says so; under load its last ticks may reach this client a little later
        window = wait_until(lambda: _arrived(stream, start + 50, target), what="samples after the move, at the target")
    # every package the controller sent is kept, once (its own ticks jitter under load: 2 ms nominal)
    # (a loaded machine ticks the simulated controller slower; its ticks, not this client, set the count)
    assert len(window) > 0.25 * (window.controller_time_s[-1] - window.controller_time_s[0]) / 0.002
    assert np.all(np.diff(window.controller_time_s) > 0)
    assert np.median(np.diff(window.controller_time_s)) == pytest.approx(0.002, abs=3e-4)
    # host times: controller time on the minimum-delay line of the receive delay, never later than arrival; within
    # the clock's window one line maps every row, its slope bounded (a loaded machine ticks the simulated controller
    # slower than the host's clock: a rate error), so the host times keep the controller's order
    assert np.all(window.time_s <= window.arrival_s + 1e-12)
    offset = window.time_s - window.controller_time_s
    # (1 ns for the rounding of host times of ~1e4 s)
    assert np.all(np.abs(np.diff(offset)) <= MAX_RATE_ERROR * np.diff(window.controller_time_s) + 1e-9)
    assert np.all(np.diff(window.time_s) > 0)
    moving = np.abs(window.qd).max(axis=1) > 0
    assert moving.sum() > 0.2 / 0.002  # the move lasts ≈ 1.1 s
    np.testing.assert_allclose(window.q[-1], target, atol=1e-9)
    lead = int(np.argmax(np.abs(target - HOME_Q)))
    assert np.abs(window.qdd[:, lead]).max() == pytest.approx(ACCELERATION)
    assert np.abs(window.qd[:, lead]).max() == pytest.approx(SPEED, abs=1e-9)
    # q̇ is the derivative of q and q̈ that of q̇ where q̈ is constant over two controller periods (uneven steps:
    # the three-point derivative of a parabola)
    t, q, qd, qdd = window.controller_time_s, window.q, window.qd, window.qdd
    inner = np.where(np.all(qdd[:-2] == qdd[2:], axis=1) & np.all(qdd[1:-1] == qdd[2:], axis=1) & moving[1:-1])[0] + 1
    assert inner.size > 50
    h1, h2 = (t[inner] - t[inner - 1])[:, None], (t[inner + 1] - t[inner])[:, None]
    derivative = (h1 ** 2 * (q[inner + 1] - q[inner]) + h2 ** 2 * (q[inner] - q[inner - 1])) / (h1 * h2 * (h1 + h2))
    np.testing.assert_allclose(derivative, qd[inner], atol=1e-6)
    np.testing.assert_allclose((qd[inner + 1] - qd[inner - 1]) / (h1 + h2), qdd[inner], atol=1e-6)


def test_no_controller_is_a_one_line_error_within_the_deadline():
    with pytest.raises(DeviceConnectionError, match=r"port 30004 \(RTDE\)"):
        URStateStream(random_loopback_address(), connect_timeout_s=1.0).start()


@pytest.mark.parametrize("model, rate_hz", [("UR5", 125.0), ("UR5e", 500.0)])
def test_the_stream_asks_the_controllers_rate_and_a_cb3_steps_whole_8_ms_cycles(model, rate_hz):
    """A CB3 (PolyScope 3) streams at most 125 Hz, an e-Series 500 Hz: the stream asks what the controller's version
    allows (it asked 500 of every controller), and a CB3 asked for more streams its 8 ms cycle, whose timestamps
    step whole cycles (the simulated CB3 streamed 500 Hz to whoever asked)."""
    with URControllerProcess(model=model, time_scale=0.0, initial_q=HOME_Q) as fake:
        with URStateStream(fake.host) as stream:
            wait_until(lambda: stream.count > 2, what="state samples")
        assert stream.frequency_hz == rate_hz and stream.version is not None
        with URStateStream(fake.host, frequency_hz=500.0) as fast:
            wait_until(lambda: fast.count > 40, what="state samples")
            steps = np.diff(fast.window().controller_time_s)
        setups = [(e["requested_hz"], e["streamed_hz"]) for e in fake.events() if e["event"] == "output_setup"]
    assert setups == [(rate_hz, rate_hz), (500.0, rate_hz)]
    if model == "UR5":  # every step whole cycles (more than one where a tick came late), most of them one
        cycles = np.round(steps / 0.008)
        np.testing.assert_allclose(steps, 0.008 * cycles, atol=1e-9)
        assert cycles.min() >= 1 and np.median(cycles) == 1
