"""The Pinocchio model of each UR equals the DH forward kinematics."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ftacq.errors import InputError
from ftacq.kinematics import (
    FLANGE_FRAME, UR_MODELS, FlangeRotation, dh_transforms, forward_kinematics, pinocchio_dh_frames, pinocchio_model,
    pinocchio_model_from_urdf,
)

FK_TOLERANCE = 1e-12


@pytest.mark.parametrize("name", sorted(UR_MODELS))
def test_pinocchio_fk_equals_dh_fk(name):
    model = UR_MODELS[name]
    pin_model = pinocchio_model(model)
    data = pin_model.createData()
    flange_id = pin_model.getFrameId(FLANGE_FRAME)
    rng = np.random.default_rng(7)
    assert pin_model.nq == 6 and pin_model.nv == 6
    for _ in range(50):
        q = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        frames = pinocchio_dh_frames(pin_model, data, q)
        np.testing.assert_allclose(frames, dh_transforms(model, q), atol=FK_TOLERANCE, rtol=0)
        np.testing.assert_allclose(data.oMf[flange_id].homogeneous, forward_kinematics(model, q),
                                   atol=FK_TOLERANCE, rtol=0)


@pytest.mark.parametrize("name", ["UR5e", "UR10"])
def test_flange_rotation_equals_dh_fk_and_is_a_copy(name):
    model = UR_MODELS[name]
    flange_rotation = FlangeRotation(model)
    rng = np.random.default_rng(8)
    for _ in range(50):
        q = rng.uniform(-2 * np.pi, 2 * np.pi, 6)
        rotation = flange_rotation(q)
        np.testing.assert_allclose(rotation, forward_kinematics(model, q)[:3, :3], atol=1e-15, rtol=0)
        assert not np.shares_memory(rotation, flange_rotation(q + 0.1))


@pytest.mark.parametrize("name", ["UR5e", "UR20"])
def test_pinocchio_model_limits_and_joint_axes(name):
    model = UR_MODELS[name]
    pin_model = pinocchio_model(model)
    np.testing.assert_array_equal(pin_model.lowerPositionLimit, model.joint_min_rad)
    np.testing.assert_array_equal(pin_model.upperPositionLimit, model.joint_max_rad)
    np.testing.assert_array_equal(pin_model.velocityLimit, model.max_joint_speed_rad_s)
    # each joint turns about the z axis of the previous DH frame: a small q_i rotates the flange about it
    data = pin_model.createData()
    q = np.array([0.3, -1.1, 1.2, -0.4, 0.9, 0.2])
    pin.computeJointJacobians(pin_model, data, q)
    frames = dh_transforms(model, q)
    for i in range(6):
        axis = np.array([0.0, 0.0, 1.0]) if i == 0 else frames[i - 1, :3, 2]
        np.testing.assert_allclose(data.J[3:, i], axis, atol=1e-12)


def test_urdf_loader_reports_missing_file(tmp_path):
    missing = tmp_path / "nope.urdf"
    with pytest.raises(InputError, match="nope.urdf"):
        pinocchio_model_from_urdf(str(missing))


def test_urdf_loader_reads_a_simple_chain(tmp_path):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text("""<robot name="arm">
  <link name="base"/><link name="l1"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
</robot>""")
    model = pinocchio_model_from_urdf(str(urdf))
    assert model.nq == 1
    assert model.upperPositionLimit[0] == pytest.approx(3.0)


@pytest.mark.parametrize("name", ["UR3e", "UR10"])
def test_batched_dh_equals_pinocchio(name):
    from ftacq.kinematics import dh_transforms_batch

    model = UR_MODELS[name]
    pin_model = pinocchio_model(model)
    data = pin_model.createData()
    q = np.random.default_rng(5).uniform(-2 * np.pi, 2 * np.pi, (40, 6))
    batch = dh_transforms_batch(model, q)
    for k in range(len(q)):
        np.testing.assert_allclose(batch[k], pinocchio_dh_frames(pin_model, data, q[k]), atol=FK_TOLERANCE, rtol=0)
