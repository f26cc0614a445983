"""The simulated arm follows its target a few ms late, as a real UR's servos do (issue 37): ``actual_q``,
``actual_qd``, the actual TCP pose and the tool's physics the simulated sensor feels are the target's of
``servo_lag_s`` ago; ``target_*`` are the profile's now."""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.kinematics import flange_pose, ur_model
from tests.fakes.ur_simulator import SERVO_LAG_S, URSimulator

MODEL = ur_model("UR5e")
HOME = np.array([0.3, -1.4, 1.6, -1.9, -1.5, 0.4])
DT = 0.002


def _run(servo_lag_s: float, time_scale: float = 1.0):
    sim = URSimulator(MODEL, time_scale=time_scale, initial_q=HOME, servo_lag_s=servo_lag_s)
    start = sim._last_step_s
    with sim.lock:
        assert sim._start_move("movej", HOME + np.array([0.4, -0.3, 0.5, 0.7, -0.9, 1.1]), 1.0, 2.0, True)
    ticks = int(sim.motion.duration_s / time_scale / DT) + 20
    snaps = [sim.step(start + DT * (k + 1)) for k in range(ticks)]
    return sim, start + DT * (np.arange(ticks) + 1), snaps


@pytest.mark.parametrize("lag_s", [0.002, SERVO_LAG_S, 0.008])
def test_the_actual_joints_are_the_target_of_servo_lag_ago(lag_s):
    sim, times, snaps = _run(lag_s)
    fields = [s["fields"] for s in snaps]
    target_q = np.array([f["target_q"] for f in fields])
    target_qd = np.array([f["target_qd"] for f in fields])
    actual_q = np.array([f["actual_q"] for f in fields])
    actual_qd = np.array([f["actual_qd"] for f in fields])
    assert np.abs(actual_q - target_q).max() > 0.5 * lag_s  # the arm lags (≥ 1 rad/s on the leading joint)
    # the target's own profile at t − lag: the target positions interpolated (piecewise quadratic, exact at ticks
    # for lags that are whole ticks; within the interpolation's error otherwise)
    back = np.array([np.interp(times - lag_s, times, target_q[:, j]) for j in range(6)]).T
    back_qd = np.array([np.interp(times - lag_s, times, target_qd[:, j]) for j in range(6)]).T
    inner = times - lag_s >= times[0]
    np.testing.assert_allclose(actual_q[inner], back[inner], atol=2e-6)
    np.testing.assert_allclose(actual_qd[inner], back_qd[inner], atol=5e-3)
    # at rest after the move both agree, and the actual TCP pose is the actual angles' flange pose
    np.testing.assert_allclose(actual_q[-1], target_q[-1], atol=1e-12)
    k = len(fields) // 2
    np.testing.assert_allclose(fields[k]["actual_TCP_pose"], flange_pose(MODEL, actual_q[k]), atol=1e-9)
    np.testing.assert_allclose(fields[k]["target_TCP_pose"], flange_pose(MODEL, target_q[k]), atol=1e-9)


def test_the_sensor_feels_the_lagging_arm():
    """The joint state published for the simulated sensor gives, at each tick's time, the actual joints."""
    sim, times, snaps = _run(SERVO_LAG_S)
    for k in range(10, len(snaps) - 10, 37):
        state = snaps[k]["joint_state"]
        q, qd, _ = state.at(np.array([times[k]]))
        np.testing.assert_allclose(q[0], snaps[k]["fields"]["actual_q"], atol=1e-12)
        np.testing.assert_allclose(qd[0], snaps[k]["fields"]["actual_qd"], atol=1e-12)


def test_no_lag_by_default_on_a_bare_controller_and_the_lag_scales_with_a_time_lapse():
    sim, _times, snaps = _run(0.0)
    for s in snaps:
        assert s["fields"]["actual_q"] == s["fields"]["target_q"]
    _sim, times, snaps = _run(SERVO_LAG_S, time_scale=4.0)
    q = np.array([s["fields"]["target_q"] for s in snaps])
    actual = np.array([s["fields"]["actual_q"] for s in snaps])
    back = np.array([np.interp(times - SERVO_LAG_S / 4.0, times, q[:, j]) for j in range(6)]).T
    np.testing.assert_allclose(actual[5:], back[5:], atol=2e-5)
    with pytest.raises(ValueError):
        URSimulator(MODEL, initial_q=HOME, servo_lag_s=-0.001)
