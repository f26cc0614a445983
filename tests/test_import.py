"""``ftacq import`` (issue 28 item 5): recordings as quaternions, rotation matrices or joint angles, wrenches in
the sensor or the base frame, each back to the same pose record; a wrong frame named by the verdict."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ftacq.app.cli import main
from ftacq.calfile import load_calibration
from ftacq.errors import InputError
from ftacq.imports import ImportOptions, import_recording
from ftacq.imports.robot_model import dh_arm_model, ur_arm_model, urdf_arm_model
from ftacq.imports.wrench_frame import base_from_sensor
from ftacq.kinematics import flange_pose, ur_model
from ftacq.posefile import read_pose_csv, write_pose_csv
from tests.fakes.pose_records import random_orientations, simulate_record
from tests.fakes.world import CellTruth

TRUTH = CellTruth(mass_kg=1.3, center_of_mass_m=(0.01, -0.004, 0.06))
WRENCH = ("fx", "fy", "fz", "tx", "ty", "tz")


@pytest.fixture(scope="module")
def record():
    return simulate_record(TRUTH, random_orientations(24, seed=11), seed=11, with_std=False)


def _write_table(path, names, values):
    lines = [",".join(names)] + [",".join(repr(float(v)) for v in row) for row in values]
    path.write_text("\n".join(lines) + "\n")
    return path


def _same_rotations(pose_a, pose_b, atol=1e-12):
    a = Rotation.from_rotvec(pose_a[:, 3:]).as_matrix()
    b = Rotation.from_rotvec(pose_b[:, 3:]).as_matrix()
    np.testing.assert_allclose(a, b, atol=atol)


@pytest.mark.parametrize("order", ["xyzw", "wxyz"])
def test_quaternions_round_trip_to_the_same_pose_record(tmp_path, record, order):
    quaternion = Rotation.from_rotvec(record.pose[:, 3:]).as_quat()  # x, y, z, w
    quaternion[::2] *= -1.0  # q and −q are the same rotation
    if order == "wxyz":
        quaternion = quaternion[:, [3, 0, 1, 2]]
    names = ["px", "py", "pz", "a", "b", "c", "d", *WRENCH]
    source = _write_table(tmp_path / "quat.csv", names, np.hstack([record.pose[:, :3], quaternion, record.wrench]))
    out = tmp_path / "poses.csv"
    assert main(["import", str(source), "-o", str(out), "--orientation", "quaternion", "--quaternion-order", order,
                 "--orientation-columns", "a,b,c,d", "--position-columns", "px,py,pz"]) == 0
    imported = read_pose_csv(out)
    _same_rotations(imported.pose, record.pose)
    np.testing.assert_allclose(imported.pose[:, :3], record.pose[:, :3], atol=0)
    np.testing.assert_allclose(imported.wrench, record.wrench, atol=0)


def test_the_wrong_quaternion_order_is_not_the_same_record(tmp_path, record):
    quaternion = Rotation.from_rotvec(record.pose[:, 3:]).as_quat()
    source = _write_table(tmp_path / "q.csv", ["a", "b", "c", "d", *WRENCH], np.hstack([quaternion, record.wrench]))
    wrong = import_recording(source, ImportOptions(orientation="quaternion", quaternion_order="wxyz",
                                                   orientation_columns=("a", "b", "c", "d"))).record
    with pytest.raises(AssertionError):
        _same_rotations(wrong.pose, record.pose, atol=1e-6)


def test_rotation_matrices_round_trip_and_positions_default_to_zero(tmp_path, record):
    matrix = Rotation.from_rotvec(record.pose[:, 3:]).as_matrix().reshape(-1, 9)
    names = [f"r{i}{j}" for i in "123" for j in "123"] + list(WRENCH)
    source = _write_table(tmp_path / "m.csv", names, np.hstack([np.round(matrix, 7), record.wrench]))
    result = import_recording(source, ImportOptions(orientation="matrix"))
    _same_rotations(result.record.pose, record.pose, atol=1e-6)
    assert np.all(result.record.pose[:, :3] == 0.0)
    assert any("positions written as 0" in note for note in result.notes)


def test_joint_angles_of_a_ur_arm_give_the_controllers_flange_pose(tmp_path):
    rng = np.random.default_rng(3)
    q = rng.uniform(-np.pi, np.pi, size=(30, 6))
    poses = np.array([flange_pose(ur_model("UR10e"), row) for row in q])
    truth_record = simulate_record(TRUTH, Rotation.from_rotvec(poses[:, 3:]).inv().as_matrix(), seed=2,
                                   with_std=False)
    names = [f"q{i}" for i in range(1, 7)] + list(WRENCH)
    source = _write_table(tmp_path / "joints.csv", names, np.hstack([q, truth_record.wrench]))
    out = tmp_path / "poses.csv"
    assert main(["import", str(source), "-o", str(out), "--robot", "UR10e"]) == 0
    imported = read_pose_csv(out)
    np.testing.assert_allclose(imported.pose[:, :3], poses[:, :3], atol=1e-12)
    _same_rotations(imported.pose, poses)
    np.testing.assert_allclose(np.column_stack([imported.extra[f"q{i}"] for i in range(6)]), q, atol=0)
    # and it identifies the truth
    out_cal = tmp_path / "cal.json"
    assert main(["identify", str(out), "-o", str(out_cal)]) in (0, 1)
    assert load_calibration(out_cal).mass_kg == pytest.approx(TRUTH.mass_kg, rel=0.01)


def test_a_dh_table_through_pinocchio_equals_the_ur_kinematics():
    model = ur_model("UR5e")
    table = np.column_stack([model.alpha, model.a, model.d, np.zeros(6)])
    q = np.random.default_rng(5).uniform(-3.0, 3.0, size=(20, 6))
    np.testing.assert_allclose(dh_arm_model(table).flange_transforms(q),
                               ur_arm_model("UR5e").flange_transforms(q), atol=1e-12)


URDF = """<?xml version="1.0"?>
<robot name="two_joints">
  <link name="base_link"/><link name="upper"/><link name="lower"/><link name="tool0"/>
  <joint name="shoulder" type="revolute"><parent link="base_link"/><child link="upper"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3.2" upper="3.2" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="continuous"><parent link="upper"/><child link="lower"/>
    <origin xyz="0.3 0 0"/><axis xyz="0 1 0"/></joint>
  <joint name="flange" type="fixed"><parent link="lower"/><child link="tool0"/>
    <origin xyz="0.2 0 0" rpy="0 0 0.5"/></joint>
</robot>
"""


def test_a_urdf_arm_with_a_continuous_joint(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text(URDF)
    model = urdf_arm_model(path)
    q = np.array([[0.3, -0.7], [-2.0, 1.2]])
    for angles, transform in zip(q, model.flange_transforms(q)):
        rz, ry = Rotation.from_euler("z", angles[0]), Rotation.from_euler("y", angles[1])
        expected_position = np.array([0, 0, 0.1]) + rz.apply([0.3, 0, 0]) + (rz * ry).apply([0.2, 0, 0])
        np.testing.assert_allclose(transform[:3, 3], expected_position, atol=1e-12)
        np.testing.assert_allclose(transform[:3, :3], (rz * ry * Rotation.from_euler("z", 0.5)).as_matrix(),
                                   atol=1e-12)
    with pytest.raises(InputError, match="no frame 'wrist'"):
        urdf_arm_model(path, "wrist")


def test_base_frame_wrenches_are_named_by_the_verdict_and_converted_on_request(tmp_path, record, capsys):
    base = base_from_sensor(record)
    source = tmp_path / "base.csv"
    write_pose_csv(source, base)
    out = tmp_path / "cal.json"
    assert main(["identify", str(source), "-o", str(out)]) == 1  # FAIL
    text = capsys.readouterr().out
    assert "the wrenches look like base-frame: use --wrench-frame base" in text
    assert load_calibration(out).metadata["verdict"]["status"] == "FAIL"
    assert main(["identify", str(source), "-o", str(out), "--wrench-frame", "base"]) == 0
    calibration = load_calibration(out)
    assert calibration.mass_kg == pytest.approx(TRUTH.mass_kg, rel=0.01)
    np.testing.assert_allclose(calibration.center_of_mass, TRUTH.center_of_mass_m, atol=2e-3)
    # the import converts too, and warns when the frame given looks wrong
    poses = tmp_path / "poses.csv"
    assert main(["import", str(source), "-o", str(poses)]) == 0
    assert "look like base-frame" in capsys.readouterr().err
    assert main(["import", str(source), "-o", str(poses), "--wrench-frame", "base"]) == 0
    np.testing.assert_allclose(read_pose_csv(poses).wrench, record.wrench, atol=1e-12)


@pytest.mark.parametrize("args, message", [
    (["--orientation", "quaternion", "--orientation-columns", "fx,fy,fz,tx"], "quaternion of norm"),
    (["--orientation", "joints"], "joint angles need a robot model"),
    (["--robot", "UR99"], "--robot UR99: unknown UR model"),
    (["--rename", "nothere=x"], "cannot rename column"),
    ([], "cannot tell the orientation"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, record, capsys, args, message):
    source = _write_table(tmp_path / "w.csv", list(WRENCH), record.wrench)
    out = tmp_path / "poses.csv"
    assert main(["import", str(source), "-o", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
