"""The dynamic model (Pinocchio) against the simulated cell's physics, the identification's exactness on noise-free
synthetic motion, the live predictor (RNEA) against the regressor, physical consistency, the lag estimate, compensation while moving, and calibration files."""

import json
from dataclasses import replace

import numpy as np
import pytest

from ftacq.calfile import calibration_to_dict, load_calibration, save_calibration
from ftacq.dynamics import (MotionRecord, SensorDynamics, WrenchPredictor, compensate_moving, identify_dynamics,
                            predict_moving, pseudo_inertia)
from ftacq.dynamics.model import calibration_parameters, gravity_vector
from ftacq.dynamics.timing import interpolate_rows
from ftacq.errors import InputError
from ftacq.kinematics import ur_model
from tests.fakes.ur_motion import JointMove
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

MODEL = ur_model("UR5e")
HOME = np.array([0.3, -1.4, 1.6, -1.9, -1.5, 0.4])
RATE_HZ = 500.0


def excitation_plan(seed: int = 3, moves: int = 8) -> list[tuple[float, JointMove]]:
    """A chain of brisk moveJs in random directions (every joint, wrist included): [(start time s, move)]."""
    rng = np.random.default_rng(seed)
    q_now, plan, start = HOME.copy(), [], 0.0
    for _ in range(moves):
        target = HOME + rng.uniform(-0.6, 0.6, 6) * np.array([0.6, 0.5, 0.5, 1.5, 1.5, 2.0])
        move = JointMove(MODEL, q_now, target, 1.0, 2.0)
        plan.append((start, move))
        start += move.duration_s
        q_now = target
    return plan


def states_at(plan: list[tuple[float, JointMove]], times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, q̈) (N, 6) of the plan at ``times``, exactly (the moves' own profiles, each move's times at once)."""
    starts = np.array([start for start, _ in plan])
    which = np.maximum(np.searchsorted(starts, times, side="right") - 1, 0)
    out = np.empty((3, len(times), 6))
    for k, (start, move) in enumerate(plan):
        rows = np.flatnonzero(which == k)
        tau = np.asarray(times, dtype=float)[rows] - start
        position = np.asarray(move.profile.position(tau))
        q = move.q_start + np.outer(position, move.direction)
        q[position >= move.length] = move.q_target  # JointMove.at_distance: the target once the path is done
        out[0, rows], out[1, rows] = q, np.outer(move.profile.speed_at(tau), move.direction)
        out[2, rows] = np.outer(move.profile.acceleration_at(tau), move.direction)
    return out[0], out[1], out[2]


def excitation_states(seed: int = 3, moves: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, q, q̇, q̈) at 500 Hz along :func:`excitation_plan`."""
    plan = excitation_plan(seed, moves)
    t = np.arange(0.0, plan[-1][0] + plan[-1][1].duration_s, 1.0 / RATE_HZ)
    return (t, *states_at(plan, t))


def record_for(truth: CellTruth, noise: bool = False, lag_s: float = 0.0, seed: int = 0,
               sensor_rate_hz: float | None = None) -> MotionRecord:
    """Robot states at 500 Hz; sensor samples at the robot's times, or at ``sensor_rate_hz`` from the exact motion,
    stamped ``lag_s`` late."""
    t, q, qd, qdd = excitation_states()
    physics = SensorPhysics(truth, SettablePose(), robot=MODEL, seed=seed)
    if sensor_rate_hz is None:
        sensor_t, wrench = t.copy(), physics.noiseless_wrench_moving(q, qd, qdd)
    else:
        sensor_t = np.arange(t[0], t[-1], 1.0 / sensor_rate_hz)
        wrench = physics.noiseless_wrench_moving(*states_at(excitation_plan(), sensor_t))
    if noise:
        sigma = np.array(truth.force_noise_n + truth.torque_noise_nm)
        wrench = wrench + np.random.default_rng(seed).standard_normal(wrench.shape) * sigma
    return MotionRecord(sensor_t + lag_s, wrench, t, q, qd, qdd)


def static_calibration(truth: CellTruth):
    return replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))


def test_pinocchio_model_predicts_the_simulated_wrench():
    truth = CellTruth(base_tilt_deg=(1.5, -2.0))
    _, q, qd, qdd = excitation_states(moves=2)
    calibration = replace(static_calibration(truth), inertia=truth.inertia)
    dynamics = SensorDynamics.for_calibration(MODEL, calibration)
    expected = SensorPhysics(truth, SettablePose(), robot=MODEL).noiseless_wrench_moving(q, qd, qdd)
    np.testing.assert_allclose(predict_moving(dynamics, calibration, q, qd, qdd), expected, atol=1e-9, rtol=0)


def test_wrench_predictor_equals_the_regressor_times_the_parameters():
    truth = CellTruth(base_tilt_deg=(1.5, -2.0))
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    dynamics = SensorDynamics.for_calibration(MODEL, calibration)
    rng = np.random.default_rng(5)
    q, qd, qdd = rng.uniform(-3, 3, (200, 6)), rng.uniform(-2, 2, (200, 6)), rng.uniform(-5, 5, (200, 6))
    bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
    expected = dynamics.regressor(q, qd, qdd, gravity_vector(calibration)) @ calibration_parameters(calibration) + bias
    np.testing.assert_allclose(WrenchPredictor(dynamics, calibration)(q, qd, qdd), expected, rtol=0, atol=1e-12)



def test_noise_free_identification_is_exact():
    truth = CellTruth()
    result = identify_dynamics(static_calibration(truth), record_for(truth), MODEL, lag_s=0.0)
    assert np.abs(result.inertia - truth.inertia).max() <= 1e-9
    assert abs(result.calibration.mass_kg - truth.mass_kg) <= 1e-9
    np.testing.assert_allclose(result.calibration.center_of_mass, truth.center_of_mass_m, atol=1e-9)
    assert not result.constrained and result.condition_number < 1e4
    assert result.held_out_rms_dynamic.max() <= 1e-9 < 0.05 < result.held_out_rms_static[:3].max()
    assert result.calibration.has_dynamics
    np.testing.assert_array_equal(result.calibration.sensor_offset, truth.sensor_offset_m)


def test_lag_between_streams_is_measured():
    truth = CellTruth()
    record = record_for(truth, lag_s=0.0043, sensor_rate_hz=7000.0)
    result = identify_dynamics(static_calibration(truth), record, MODEL)
    assert result.lag_s == pytest.approx(0.0043, abs=0.0004)
    assert np.linalg.norm(result.inertia - truth.inertia) <= 0.01 * np.linalg.norm(truth.inertia)


def test_noisy_identification_is_within_its_sigma():
    truth = CellTruth()
    result = identify_dynamics(static_calibration(truth), record_for(truth, noise=True, seed=4), MODEL, lag_s=0.0)
    error = result.inertia - truth.inertia
    assert np.all(np.abs(error) <= 4.0 * result.inertia_sigma + 1e-12), (error, result.inertia_sigma)
    assert not result.mass_from_motion  # the static estimate (its 1σ default 1e-6 relative here) is better


def test_an_unphysical_fit_is_made_physical():
    # data from a "tool" whose principal moments break the triangle inequality: the best physical body is kept
    bad = CellTruth(inertia_kg_m2=((0.001, 0.0, 0.0), (0.0, 0.001, 0.0), (0.0, 0.0, 0.005)))
    result = identify_dynamics(static_calibration(bad), record_for(bad), MODEL, lag_s=0.0)
    assert result.constrained
    moments = np.linalg.eigvalsh(result.inertia)
    assert moments.min() > 0 and moments[2] <= moments[0] + moments[1] + 1e-12
    parameters = np.concatenate([[result.calibration.mass_kg],
                                 result.calibration.mass_kg * result.calibration.center_of_mass, np.zeros(6)])
    assert np.linalg.eigvalsh(pseudo_inertia(parameters))[-1] > 0


def test_compensate_moving_interpolates_robot_states_onto_sensor_samples():
    truth = CellTruth()
    record = record_for(truth, sensor_rate_hz=7000.0)
    calibration = replace(static_calibration(truth), inertia=truth.inertia)
    contact = compensate_moving(calibration, record.wrench, record.q, record.qd, record.qdd, robot=MODEL,
                                sensor_time_s=record.sensor_time_s, robot_time_s=record.robot_time_s)
    static = calibration.compensate(record.wrench, np.zeros((len(record.wrench), 3, 3)) + np.eye(3))
    assert contact.shape == record.wrench.shape
    # interpolating between 2 ms states costs little (most of it where q̈ steps between two robot samples)
    assert np.sqrt(np.mean(contact[:, :3] ** 2)) < 0.04 and np.sqrt(np.mean(contact[:, 3:] ** 2)) < 0.002
    assert np.abs(static).max() > 1.0
    with pytest.raises(ValueError, match="static only"):
        compensate_moving(truth.calibration(), record.wrench, record.q, record.qd, record.qdd, robot=MODEL)


def test_interpolate_rows_is_linear_interpolation_held_at_the_ends():
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.001, 0.003, 40))
    times[7] = times[6]  # a repeated time (zero span)
    values = rng.normal(size=(40, 6))
    at = np.sort(rng.uniform(times[0] - 0.01, times[-1] + 0.01, 300))
    at[:3] = times[6], times[0], times[-1]
    got = interpolate_rows(at, times, values)
    index = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    span = times[index + 1] - times[index]
    fraction = np.clip((at - times[index]) / np.where(span > 0, span, 1.0), 0.0, 1.0)[:, None]
    np.testing.assert_array_equal(got, values[index] + fraction * (values[index + 1] - values[index]))
    keep = np.abs(at[:, None] - times[[6, 7]]).min(axis=1) > 0
    for column in range(6):
        np.testing.assert_allclose(got[keep, column], np.interp(at[keep], times, values[:, column]), atol=1e-12)



def test_calibration_file_version_2_keeps_the_inertia_and_version_1_loads_as_static(tmp_path):
    truth = CellTruth()
    calibration = replace(static_calibration(truth), inertia=truth.inertia,
                          uncertainty={"inertia_kg_m2": (np.full((3, 3), 1e-5)).tolist()})
    path = tmp_path / "calibration.json"
    save_calibration(path, calibration)
    loaded = load_calibration(path)
    assert loaded.has_dynamics
    np.testing.assert_array_equal(loaded.inertia, truth.inertia)
    np.testing.assert_array_equal(loaded.sensor_offset, truth.sensor_offset_m)
    assert json.loads(path.read_text())["version"] == 2
    # a version-1 file (no dynamics keys) loads and is static only
    document = calibration_to_dict(truth.calibration())
    document["version"] = 1
    for key in ("sensor_offset_m", "inertia_kg_m2"):
        document.pop(key, None)
    v1 = tmp_path / "v1.json"
    v1.write_text(json.dumps(document))
    old = load_calibration(v1)
    assert not old.has_dynamics and old.sensor_offset is None
    # an inertia that is no rigid body is refused with the file and key named
    document = calibration_to_dict(calibration)
    document["inertia_kg_m2"] = [[0.001, 0, 0], [0, 0.001, 0], [0, 0, 0.005]]
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(document))
    with pytest.raises(InputError, match=r"broken.json: key 'inertia_kg_m2'"):
        load_calibration(broken)
