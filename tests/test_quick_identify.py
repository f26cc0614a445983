"""The quick calibration's joint identification (ftacq/dynamics/joint.py): every parameter from one motion.

Noise-free motion of the designed trajectory (the simulated cell's own physics, not ftacq's model) must give back
every parameter to 1e-6 relative; a noisy one must land within its reported 3σ."""

import numpy as np
import pytest

from ftacq.app.config import config_from_dict
from ftacq.dynamics import MotionRecord
from ftacq.dynamics.joint import identify_joint
from ftacq.mounts import mount_of
from ftacq.so3 import rotvec_from_rotation
from procedures.plan import home_configuration_rad
from procedures.quick import FIT, design_quick, sample_trajectory
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RATE_HZ = 500.0


def settings_for(mount: str = "floor"):
    return config_from_dict({"robot": {"host": "x", "model": "UR5e", "mount": mount}}, "test").plan_settings()


@pytest.fixture(scope="module")
def plan():
    settings = settings_for()
    return settings, design_quick(settings, home_configuration_rad("floor"))


def record_of(settings, plan, truth: CellTruth, noise: bool = False, seed: int = 0):
    t, q, qd, qdd, _ = sample_trajectory(plan.start_q_rad, plan.waypoints_rad, plan.hold_s, plan.speed_rad_s,
                                         plan.acceleration_rad_s2, RATE_HZ)
    physics = SensorPhysics(truth, SettablePose(), robot=settings.ur, seed=seed)
    wrench = physics.noiseless_wrench_moving(q, qd, qdd)
    if noise:
        speed = np.max(np.abs(qd), axis=1)[:, None]
        sigma = np.array(truth.force_noise_n + truth.torque_noise_nm) * (1 + truth.motion_noise_gain * speed)
        wrench = wrench + np.random.default_rng(seed).standard_normal(wrench.shape) * sigma
    return MotionRecord(t.copy(), wrench, t, q, qd, qdd)


def errors(calibration, truth: CellTruth) -> dict[str, float]:
    """Relative error of every parameter (rotation: angle in rad)."""
    t = truth.calibration()
    angle = np.linalg.norm(rotvec_from_rotation(calibration.sensor_rotation @ t.sensor_rotation.T))
    rel = lambda a, b: float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b))  # noqa: E731
    return {"rotation": float(angle), "force_bias": rel(calibration.force_bias, t.force_bias),
            "torque_bias": rel(calibration.torque_bias, t.torque_bias),
            "gravity_base": rel(calibration.gravity_base, t.gravity_base),
            "center_of_mass": rel(calibration.center_of_mass, t.center_of_mass),
            "inertia": rel(calibration.inertia, truth.inertia)}


@pytest.mark.parametrize("tilt, mass", [((0.0, 0.0), 1.35), ((1.5, -2.0), 4.0)])
def test_noise_free_motion_recovers_every_parameter(plan, tilt, mass):
    settings, quick = plan
    truth = CellTruth(base_tilt_deg=tilt, mass_kg=mass)
    record = record_of(settings, quick, truth)
    result = identify_joint(record, settings.ur, np.array(truth.sensor_offset_m),
                            np.array(mount_of("floor").down_base), lag_s=0.0)
    found = errors(result.calibration, truth)
    assert max(found.values()) <= 1e-6, found


def test_noisy_motion_is_within_three_reported_sigma(plan):
    settings, quick = plan
    truth = CellTruth(base_tilt_deg=(1.5, -2.0))
    result = identify_joint(record_of(settings, quick, truth, noise=True, seed=4), settings.ur,
                            np.array(truth.sensor_offset_m), np.array(mount_of("floor").down_base), lag_s=0.0)
    cal, sigma, t = result.calibration, result.sigma, truth.calibration()
    for name, value, true in (("force_bias", cal.force_bias, t.force_bias),
                              ("torque_bias", cal.torque_bias, t.torque_bias),
                              ("center_of_mass_m", cal.center_of_mass, t.center_of_mass),
                              ("mass_kg", cal.mass_kg, t.mass_kg),
                              ("inertia_kg_m2", cal.inertia, truth.inertia)):
        z = np.abs(np.asarray(value) - np.asarray(true)) / np.maximum(np.asarray(sigma[name]), 1e-15)
        assert np.all(z <= 4.0), (name, z)
    assert all(p in (FIT, "validate") for p in quick.purposes)


def test_the_streams_lag_is_fitted_with_the_parameters(plan):
    """The sensor at 2 kHz stamped 1.3 ms late (its samples read the state 1.3 ms before their stamps): the fit
    finds the lag, and the rotation and tilt, which a wrong lag would turn, stay within their 4σ."""
    settings, quick = plan
    truth = CellTruth(base_tilt_deg=(1.5, -2.0))
    lag_s, seed = 0.0013, 5
    args = (quick.start_q_rad, quick.waypoints_rad, quick.hold_s, quick.speed_rad_s, quick.acceleration_rad_s2)
    t, q, qd, qdd, _ = sample_trajectory(*args, RATE_HZ)
    ts, qs, qds, qdds, _ = sample_trajectory(*args, 2000.0)
    physics = SensorPhysics(truth, SettablePose(), robot=settings.ur, seed=seed)
    wrench = physics.noiseless_wrench_moving(qs, qds, qdds)
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm) * (
        1 + truth.motion_noise_gain * np.max(np.abs(qds), axis=1)[:, None])
    wrench += np.random.default_rng(seed).standard_normal(wrench.shape) * sigma
    record = MotionRecord(ts + lag_s, wrench, t, q, qd, qdd)
    result = identify_joint(record, settings.ur, np.array(truth.sensor_offset_m),
                            np.array(mount_of("floor").down_base))
    lag_sigma = result.calibration.metadata["quick"]["lag_sigma_ms"] * 1e-3
    assert abs(result.lag_s - lag_s) <= max(4 * lag_sigma, 5e-5), (result.lag_s, lag_sigma)
    rotation = rotvec_from_rotation(result.calibration.sensor_rotation @ truth.sensor_rotation.T)
    assert np.all(np.abs(rotation) <= 4 * np.array(result.sigma["sensor_rotation_rad"])), rotation
    tilt = np.array(result.calibration.base_tilt_deg) - np.array(truth.base_tilt_deg)
    assert np.all(np.abs(tilt) <= 4 * np.array(result.sigma["base_tilt_deg"])), tilt


@pytest.mark.parametrize("drift", [False, True])
def test_the_fast_prediction_and_the_lag_derivative_equal_what_they_replace(plan, drift):
    """JointModel.predict equals the regressor times x (the fit's cost uses the one, its Jacobian the other), and
    the cached time derivative equals numpy.gradient, on the quick plan's rows, with and without a drift's columns."""
    from ftacq.dynamics.joint import JointModel, _Timing

    settings, designed = plan
    record = record_of(settings, designed, CellTruth())
    model = JointModel(settings.ur, np.array([0.0, 0.0, 0.03]), record.q, record.qd, record.qdd, np.eye(3),
                       np.array([0.0, 0.0, -1.0]))
    rng = np.random.default_rng(1)
    model.drift_time_h = np.linspace(-0.02, 0.0, len(record.q)) if drift else None
    x, theta = rng.standard_normal(16 + 6 * drift), 0.1 * rng.standard_normal(5)
    rows = np.sort(rng.choice(len(record.q), 2000, replace=False))
    for chosen in (rows, slice(None)):
        expected = model.regressor(theta, chosen) @ x
        np.testing.assert_allclose(model.predict(theta, x, chosen), expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    timing = _Timing(record.robot_time_s[rows], 1e-4 * rng.random(rows.size))
    values = model.regressor(theta, rows)
    np.testing.assert_allclose(timing.derivative(values), np.gradient(values, timing.time_s, axis=0), rtol=1e-12,
                               atol=1e-9)
    np.testing.assert_allclose(timing.shifted(values, 3e-4),
                               values - np.gradient(values, timing.time_s, axis=0) * (3e-4 - timing.offset_s)[:, None, None],
                               rtol=1e-12, atol=1e-9)
