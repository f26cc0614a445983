"""The simulated controller's encoder jitter: reported joint angles (actual_q) scatter as a real UR's do.

A real UR5e reports its joint angles with about 1e-6 rad of noise at rest; a fake that reports them exactly hid a
run that died at its last pose (issue 26, item 1).
"""

from __future__ import annotations

import numpy as np
import pytest

from ftacq.kinematics import ur_model
from tests.fakes.ur_simulator import ENCODER_NOISE_RAD, URSimulator

MODEL = ur_model("UR5e")
HOME = np.array([np.pi / 2, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
TICKS = 2000


def _fields(sim: URSimulator, ticks: int = TICKS) -> list[dict]:
    start = sim._last_step_s
    return [sim.step(start + 0.002 * (k + 1))["fields"] for k in range(ticks)]


def test_reported_angles_jitter_by_the_encoder_noise_and_the_motion_stays_exact():
    sim = URSimulator(MODEL, time_scale=1.0, initial_q=HOME, encoder_noise_rad=ENCODER_NOISE_RAD, seed=1)
    fields = _fields(sim)
    actual = np.array([f["actual_q"] for f in fields])
    target = np.array([f["target_q"] for f in fields])
    np.testing.assert_array_equal(target, np.tile(HOME, (TICKS, 1)))  # the commanded (true) angles are exact
    np.testing.assert_array_equal(sim.q, HOME)
    error = actual - HOME
    # 12 000 draws: the sample σ's own relative scatter is 0.65 %, so 5 % is about 8 of it
    assert np.std(error) == pytest.approx(ENCODER_NOISE_RAD, rel=0.05)
    assert abs(np.mean(error)) < 5 * ENCODER_NOISE_RAD / np.sqrt(error.size)
    assert np.all(np.std(error, axis=0) > 0.8 * ENCODER_NOISE_RAD)  # every joint, independently
    assert abs(np.corrcoef(error[:-1, 5], error[1:, 5])[0, 1]) < 0.1  # a fresh draw every cycle


def test_the_jitter_is_configurable_and_can_be_switched_off():
    loud = np.array([f["actual_q"] for f in _fields(URSimulator(MODEL, initial_q=HOME, encoder_noise_rad=1e-4,
                                                                seed=2), 500)])
    assert np.std(loud - HOME) == pytest.approx(1e-4, rel=0.1)
    exact = np.array([f["actual_q"] for f in _fields(URSimulator(MODEL, initial_q=HOME), 50)])  # a bare controller
    np.testing.assert_array_equal(exact, np.tile(HOME, (50, 1)))
    with pytest.raises(ValueError, match="encoder_noise_rad"):
        URSimulator(MODEL, initial_q=HOME, encoder_noise_rad=-1e-6)


def test_the_simulated_cell_reports_jittered_angles_through_ur_rtde():
    """The cell (the procedure's tests, ``--sim``) has the jitter on: angles read with the real client scatter
    around the controller's exact ones by about the encoder noise, never more than a few σ."""
    from drivers.robot import MotionLimits
    from drivers.ur import URRobot
    from tests.conftest import wait_until
    from tests.fakes.cell import SimulatedCell

    pytest.importorskip("rtde_control")
    with SimulatedCell(sensor="can", time_scale=0.0) as cell, \
            URRobot(cell.robot_host, MotionLimits(), model=cell.model_name) as robot:
        exact = np.asarray(cell.controller.state()["q"])
        readings: list[np.ndarray] = []

        def enough_distinct() -> bool:
            q = np.asarray(robot.joint_positions(), dtype=float)
            if not readings or np.any(q != readings[-1]):
                readings.append(q)
            return len(readings) >= 20

        wait_until(enough_distinct, "20 distinct joint readings")
    error = np.array(readings) - exact
    assert np.all(np.abs(error) < 8 * ENCODER_NOISE_RAD)
    assert np.std(error) > 0.5 * ENCODER_NOISE_RAD
