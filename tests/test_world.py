"""The simulated cell's physics follows the model of ftacq.calibration exactly (without noise)."""

import numpy as np

from ftacq.so3 import rotation_from_rotvec
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose, SharedPose


def test_noiseless_wrench_equals_calibration_prediction():
    truth = CellTruth(base_tilt_deg=(3.0, -4.0))
    pose = SettablePose([0.3, -0.2, 0.5, 0.4, -1.2, 2.0])
    physics = SensorPhysics(truth, pose)
    expected = truth.calibration().predict(rotation_from_rotvec(pose.read()[0][3:]).T)
    np.testing.assert_allclose(physics.noiseless_wrench(pose.read()[0]), expected, atol=1e-12)
    assert abs(truth.calibration().mass_kg - truth.mass_kg) < 1e-12  # ‖gravity‖ / g: the last bit is the libm's


def test_noise_is_seeded_and_has_the_configured_spread():
    truth = CellTruth()
    a = SensorPhysics(truth, SettablePose(), seed=7).sample(20000)
    b = SensorPhysics(truth, SettablePose(), seed=7).sample(20000)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(a.std(axis=0), truth.force_noise_n + truth.torque_noise_nm, rtol=0.05)


def test_shared_pose_crosses_handles():
    writer = SharedPose(create=True)
    try:
        reader = SharedPose(writer.name)
        writer.set(np.array([0.1, 0.2, 0.3, 0.0, 3.0, 0.0]), joint_speed_rad_s=0.25)
        pose, speed = reader.read()
        np.testing.assert_array_equal(pose, [0.1, 0.2, 0.3, 0.0, 3.0, 0.0])
        assert speed == 0.25
        reader.close()
    finally:
        writer.close()


def test_mount_tilts():
    assert CellTruth().with_mount("wall").calibration().base_tilt_deg == (0.0, 90.0)
    alpha, beta = CellTruth().with_mount("ceiling").calibration().base_tilt_deg
    assert (alpha, beta) == (0.0, 180.0)
