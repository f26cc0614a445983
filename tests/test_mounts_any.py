"""Any mount (issue 28 item 6): a base tilt of any size, declared as angles or as the gravity direction, in the
identification, the report, the CLI, CELL.toml and the planner."""

import numpy as np
import pytest

from ftacq.app.cli import main
from ftacq.errors import ConfigError
from ftacq.identification import identify
from ftacq.mounts import down_from_tilt_deg, mount_of, tilt_from_down_deg
from ftacq.posefile import write_pose_csv
from ftacq.so3 import rotation_from_rotvec
from procedures.plan import make_plan
from procedures.plan_settings import PlanSettings
from tests.fakes.pose_records import cone_orientations, gravity_down_base_R_flange, simulate_record
from tests.fakes.world import CellTruth

YUMI_DOWN = np.array([0.539, 0.699, -0.470])
"""A real arm's base (ABB YuMi left arm): gravity about 62° away from base −z."""


def _record(down_base: np.ndarray, seed: int = 3):
    alpha, beta = tilt_from_down_deg(down_base / np.linalg.norm(down_base))
    truth = CellTruth(base_tilt_deg=(alpha, beta), mass_kg=1.5)
    axis = gravity_down_base_R_flange(truth.gravity_base)
    return truth, simulate_record(truth, cone_orientations(30, 60.0, seed=seed, axis_base_R_flange=axis), seed=seed)


@pytest.mark.parametrize("spec, down", [
    ("floor", (0, 0, -1)), ("wall", (-1, 0, 0)), ("ceiling", (0, 0, 1)), ("tilted:0,-90", (1, 0, 0)),
    ("gravity:2,0,0", (1, 0, 0)), ("tilted:90,0", (0, 1, 0)), ("gravity:0.539,0.699,-0.470", YUMI_DOWN),
])
def test_every_spec_names_its_gravity_direction(spec, down):
    down = np.asarray(down, dtype=float) / np.linalg.norm(down)
    mount = mount_of(spec)
    np.testing.assert_allclose(mount.down_base, down, atol=1e-12)
    np.testing.assert_allclose(down_from_tilt_deg(*mount.tilt_deg), down, atol=1e-12)


@pytest.mark.parametrize("spec", ["desk", "tilted:62", "tilted:a,b", "tilted:120,0", "gravity:0,0,0",
                                  "gravity:1,nan,0", "gravity:1,2"])
def test_a_malformed_spec_is_refused(spec):
    with pytest.raises(ValueError, match="mount"):
        mount_of(spec)


def test_a_62_degree_tilt_declared_as_gravity_direction_reads_as_level():
    truth, record = _record(YUMI_DOWN)
    declared = identify(record, mount="gravity:0.539,0.699,-0.470")
    meta = declared.calibration.metadata
    assert meta["tilt_from_mount_deg"] < 0.5  # the numbers are rounded to 3 digits
    assert not any("tilted" in w for w in declared.warnings)
    # the same tilt as angles: α, β of the direction
    alpha, beta = tilt_from_down_deg(YUMI_DOWN / np.linalg.norm(YUMI_DOWN))
    assert identify(record, mount=f"tilted:{alpha:.4f},{beta:.4f}").calibration.metadata["tilt_from_mount_deg"] < 0.5
    # no mount named: the report says how to declare the one measured
    from ftacq.report import format_identification_report

    report = format_identification_report(identify(record))
    assert "nearest nominal mount: floor (61.9" in report and "--gravity-direction 0.539,0.699,-0.470" in report
    # a nominal mount instead: the warning gives the measured direction to declare
    floor = identify(record, mount="floor")
    warning = next(w for w in floor.warnings if "nominal floor mount" in w)
    assert "--gravity-direction 0.539,0.699,-0.470" in warning.replace("-0.47,", "-0.470,")


def test_a_wall_mount_along_plus_x_does_not_read_as_tilted_from_a_wall(tmp_path):
    _, record = _record(np.array([1.0, 0.0, 0.0]))
    poses = tmp_path / "poses.csv"
    write_pose_csv(poses, record)
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses), "-o", str(out), "--gravity-direction", "1,0,0"]) == 0
    from ftacq.calfile import load_calibration

    meta = load_calibration(out).metadata
    assert meta["tilt_from_mount_deg"] < 0.2
    assert meta["mount"] == "gravity:1,0,0"
    assert abs(meta["base_tilt_relative_deg"][0]) < 0.2 and abs(meta["base_tilt_relative_deg"][1]) < 0.2
    assert main(["identify", str(poses), "-o", str(out), "--mount", "tilted:0,-90"]) == 0
    assert load_calibration(out).metadata["tilt_from_mount_deg"] < 0.2


def test_a_malformed_gravity_direction_is_one_line_exit_2(tmp_path, capsys):
    _, record = _record(np.array([0.0, 0.0, -1.0]))
    poses = tmp_path / "poses.csv"
    write_pose_csv(poses, record)
    assert main(["identify", str(poses), "-o", str(tmp_path / "c.json"), "--gravity-direction", "1,0"]) == 2
    err = capsys.readouterr().err
    assert "--gravity-direction" in err and "Traceback" not in err
    assert not (tmp_path / "c.json").exists()


def test_cell_toml_takes_a_tilted_mount_and_refuses_a_bad_one():
    from ftacq.app.config import config_from_dict

    config = config_from_dict({"robot": {"mount": "tilted:62,-37"}}, "CELL.toml")
    assert config.robot.mount == "tilted:62,-37"
    with pytest.raises(ConfigError, match="robot.mount.*tilted:ALPHA,BETA"):
        config_from_dict({"robot": {"mount": "tilted:62"}}, "CELL.toml")


def test_the_planner_points_the_tool_along_a_tilted_gravity():
    spec = "tilted:20,30"
    plan = make_plan(PlanSettings(mount=spec), np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]))
    down = np.array(mount_of(spec).down_base)
    axes = rotation_from_rotvec(plan.poses[plan.indices("E"), 3:])[:, :, 2]
    assert len(axes) > 0
    assert np.degrees(np.arccos(np.clip(axes @ down, -1, 1))).max() <= 40.0 + 1e-9
