"""One validation layer (issue 15): every file, option and URL is checked before the work starts; bad input is one
line (file or option, field, value, why), exit status 2, no traceback, nothing written.

The identification of extreme values runs in a subprocess: on a build without the numeric guards it spins inside
LAPACK for minutes without answering Ctrl-C, and the test must be able to give up on it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ftacq.app.cli import main
from ftacq.calfile import calibration_to_dict, load_calibration
from ftacq.errors import IdentificationError, InputError
from ftacq.identification import identify
from ftacq.posefile import PoseRecord, write_pose_csv
from ftacq.validation import check_number, check_output_file, check_url, load_json_text
from tests.fakes.pose_records import example_record
from tests.fakes.world import CellTruth

REPO_ROOT = Path(__file__).resolve().parents[1]
EXTREME_KILL_AFTER_S = 60.0


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [line for line in err.strip().splitlines() if line]
    assert len(lines) == 1, err
    return lines[0]


# ------------------------------------------------------------------------------------------ calibration JSON


@pytest.fixture()
def good_calibration() -> dict:
    return calibration_to_dict(CellTruth().calibration())


@pytest.mark.parametrize("change, expected", [
    (lambda d: d.update(version=True), "the file has True"),
    (lambda d: d.update(version=1.0), "the file has 1.0"),
    (lambda d: d.update(mass_kg=0.0, gravity_base=[0.0, 0.0, 0.0]), "mass_kg' = 0.0: must be"),
    (lambda d: d.update(mass_kg=10**400), "an integer of"),
    (lambda d: d["force_bias"].__setitem__(0, 10**400), "key 'force_bias' = an integer of"),
    (lambda d: d["torque_bias"].__setitem__(1, 1e30), "torque_bias' = 1e+30: must be"),
    (lambda d: d["uncertainty"].update(mass_kg=-1.0), "uncertainty.mass_kg' = -1.0"),
])
def test_calibration_values_out_of_type_or_range_are_refused(tmp_path, good_calibration, change, expected):
    change(good_calibration)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(good_calibration), encoding="utf-8")
    with pytest.raises(InputError, match=expected.replace("(", r"\(").replace("+", r"\+")):
        load_calibration(path)


@pytest.mark.parametrize("text, expected", [
    ('{"version": ' + "7" * 5000 + "}", "cannot read a value"),
    ("[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ('{"mass_kg": NaN}', "NaN is not a number JSON allows"),
])
def test_calibration_text_python_cannot_parse_is_an_input_error(tmp_path, text, expected):
    path = tmp_path / "cal.json"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=expected):
        load_calibration(path)


# ------------------------------------------------------------------------------------------ CELL.toml and URLs


@pytest.mark.parametrize("toml, expected", [
    ("[robot]\njoint_speed_rad_s = 1" + "0" * 400 + "\n", "robot.joint_speed_rad_s = an integer of"),
    ("[poses]\nseed = " + "9" * 5000 + "\n", "cannot read a value"),
    ("[poses]\nexplicit = " + "[" * 5000 + "]" * 5000 + "\n", "not valid TOML"),
    ('[sensor]\nurl = "ftp://x"\n', "sensor.url: sensor URL 'ftp://x': unknown scheme 'ftp'"),
    ('[sensor]\nurl = "netft://[::1"\n', "sensor.url"),
    ('[sensor]\nurl = "netft://"\n', "no host"),
    ('[sensor]\nurl = "netft://10.0.0.1:99999"\n', "sensor.url"),
])
def test_config_check_refuses_bad_values_and_urls_in_one_line(tmp_path, capsys, toml, expected):
    path = tmp_path / "CELL.toml"
    path.write_text(toml, encoding="utf-8")
    assert main(["config", "check", str(path)]) == 2
    line = one_line_error(capsys)
    assert str(path) in line and expected in line


def never(what: str):
    def fail(*args, **kwargs):
        raise AssertionError(f"{what} was reached: the input should have been refused before")

    return fail


def test_dry_run_refuses_a_bad_sensor_url_before_connecting_the_robot(tmp_path, capsys, monkeypatch):
    import drivers.ur

    monkeypatch.setattr(drivers.ur.URRobot, "start", never("the robot connection"))
    path = tmp_path / "CELL.toml"
    path.write_text('[robot]\nhost = "127.0.0.9"\n[sensor]\nurl = "ftp://x"\n', encoding="utf-8")
    assert main(["calibrate", "--config", str(path), "--dry-run"]) == 2
    assert "unknown scheme 'ftp'" in one_line_error(capsys)


@pytest.mark.parametrize("url, ok", [
    ("netft://192.168.1.1", True), ("netft://[::1]:49152", True), ("netft://[::1", False),
    ("netft://h:0", False), ("netft://h:70000", False), ("ftp://x", False), ("netft:// h", False), (None, False),
])
def test_check_url_parses_scheme_host_and_port(url, ok):
    if ok:
        assert check_url(url, "sensor.url", ("netft", "can")).scheme == "netft"
    else:
        with pytest.raises(InputError, match="sensor.url"):
            check_url(url, "sensor.url", ("netft", "can"))


# ------------------------------------------------------------------------------------------ numbers


@pytest.mark.parametrize("value", [True, float("nan"), float("inf"), 10**400, "1", None, -1.0])
def test_check_number_refuses_non_numbers_non_finite_and_out_of_range(value):
    with pytest.raises(InputError, match="x = "):
        check_number(value, "x", low=0.0, high=10.0)


def test_check_number_integer_mode_refuses_whole_floats():
    assert check_number(3, "n", integer=True) == 3
    with pytest.raises(InputError):
        check_number(3.0, "n", integer=True)


def test_load_json_text_refuses_what_json_module_would_raise_on():
    for text in ("[" * 50_000, "1" * 5000, "NaN", "{"):
        with pytest.raises(InputError):
            load_json_text(text, "f.json")


# ------------------------------------------------------------------------------------------ identify, compensate


@pytest.fixture()
def poses_csv(tmp_path) -> Path:
    path = tmp_path / "poses.csv"
    write_pose_csv(path, example_record(seed=1))
    return path


@pytest.mark.parametrize("tolerance", ["nan", "-5", "0", "45", "inf"])
def test_identify_refuses_a_special_tolerance_that_is_not_an_angle_in_0_45(tmp_path, poses_csv, capsys, tolerance):
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(out), "--special-tolerance-deg", tolerance]) == 2
    assert "--special-tolerance-deg" in one_line_error(capsys)
    assert not out.exists()


def test_the_library_refuses_a_nan_tolerance_too():
    with pytest.raises(IdentificationError, match="tolerance"):
        identify(example_record(seed=1), special_tolerance_deg=float("nan"))


def test_identify_checks_the_output_path_before_reading_anything(tmp_path, capsys):
    folder = tmp_path / "a-folder"
    folder.mkdir()
    missing_input = tmp_path / "not-there.csv"  # never read: the -o check comes first
    assert main(["identify", str(missing_input), "-o", str(folder)]) == 2
    line = one_line_error(capsys)
    assert "-o/--output" in line and "is a folder" in line and "not-there" not in line
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    assert main(["identify", str(missing_input), "-o", str(blocker / "cal.json")]) == 2
    assert "is a file, not a folder" in one_line_error(capsys)


@pytest.mark.parametrize("scale", [1e30, 1e100, 1e300])
def test_identify_on_extreme_values_exits_2_at_once_in_a_subprocess(tmp_path, scale):
    record = example_record(seed=1)
    extreme = PoseRecord(pose=record.pose, wrench=record.wrench * scale, labels=record.labels, sets=record.sets)
    poses = tmp_path / "extreme.csv"
    write_pose_csv(poses, extreme)
    try:
        result = subprocess.run([sys.executable, "-m", "ftacq.app.cli", "identify", str(poses), "-o",
                                 str(tmp_path / "cal.json")], capture_output=True, text=True,
                                timeout=EXTREME_KILL_AFTER_S, env=dict(os.environ, PYTHONPATH=str(REPO_ROOT)),
                                cwd=REPO_ROOT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"identify on values scaled by {scale:g} still ran after {EXTREME_KILL_AFTER_S:g} s")
    assert result.returncode == 2, result.stderr
    assert "beyond what a robot or an F/T sensor reports" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "cal.json").exists()


def test_identify_refuses_a_record_whose_forces_never_change(tmp_path):
    record = example_record(seed=1)
    flat = PoseRecord(pose=record.pose, wrench=np.tile(record.wrench[0], (len(record), 1)), labels=record.labels)
    with pytest.raises(IdentificationError, match="the force readings are the same at every pose"):
        identify(flat)


def test_compensate_refuses_a_rotation_vector_of_1e300(tmp_path, capsys):
    calibration = tmp_path / "cal.json"
    calibration.write_text(json.dumps(calibration_to_dict(CellTruth().calibration())), encoding="utf-8")
    poses = tmp_path / "rows.csv"
    poses.write_text("rx,ry,rz,fx,fy,fz,tx,ty,tz\n0,0,0,1,2,3,0,0,0\n1e300,0,0,1,2,3,0,0,0\n", encoding="utf-8")
    out = tmp_path / "out.csv"
    assert main(["compensate", str(calibration), str(poses), "-o", str(out)]) == 2
    line = one_line_error(capsys)
    assert "line 3" in line and "'rx'" in line and "1e300" in line
    assert not out.exists()


# ------------------------------------------------------------------------------------------ other commands


def test_calibrate_sim_with_an_unknown_model_is_a_one_line_error(capsys):
    assert main(["calibrate", "--sim", "--model", "UR99", "--dry-run"]) == 2
    assert "UR99" in one_line_error(capsys)


def test_monitor_sim_with_an_unknown_model_or_a_model_without_sim_is_a_one_line_error(capsys, monkeypatch):
    import ftacq.app.simcell

    monkeypatch.setattr(ftacq.app.simcell, "simulated_cell", never("the simulated cell"))
    assert main(["monitor", "--sim", "--model", "UR99", "--seconds", "1"]) == 2
    assert "UR99" in one_line_error(capsys)
    assert main(["monitor", "--config", "CELL.toml", "--model", "UR5", "--seconds", "1"]) == 2
    assert "only with --sim" in one_line_error(capsys)


def test_output_paths_under_a_file_are_refused_before_any_device_starts(tmp_path, capsys, monkeypatch):
    import ftacq.app.simcell

    monkeypatch.setattr(ftacq.app.simcell, "simulated_cell", never("the simulated cell"))
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    assert main(["config", "init", str(blocker / "CELL.toml")]) == 2
    assert "is a file, not a folder" in one_line_error(capsys)
    assert main(["calibrate", "--sim", "--yes", "--save", str(blocker / "run.rrd")]) == 2
    assert "--save" in one_line_error(capsys)
    assert main(["monitor", "--sim", "--seconds", "1", "--record", str(blocker / "rec.csv")]) == 2
    assert "--record" in one_line_error(capsys)
    assert main(["calibrate", "--sim", "--yes", "--out", str(blocker)]) == 2
    assert "--out" in one_line_error(capsys)


def test_check_output_file_accepts_a_new_file_in_an_existing_folder(tmp_path):
    assert check_output_file(tmp_path / "cal.json") == tmp_path / "cal.json"


def test_an_output_file_in_a_missing_folder_is_refused_and_no_folder_created(tmp_path, poses_csv, capsys):
    out = tmp_path / "no" / "such" / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(out)]) == 2
    line = one_line_error(capsys)
    assert "-o/--output" in line and "does not exist" in line and str(tmp_path / "no" / "such") in line
    assert not (tmp_path / "no").exists()


@pytest.mark.parametrize("argv, what", [
    (["robot", "info", "not..a..host"], "an empty part between two dots"),
    (["robot", "info", "a" * 64 + ".example"], "longer than 63 characters"),
    (["robot", "info", "127.0.0.62:80"], "ports are fixed"),
    (["sensor", "info", "netft://not..a..host"], "an empty part between two dots"),
    (["sensor", "info", "netft://a_b.example"], "not a host name part"),
])
def test_a_malformed_host_is_a_one_line_error_before_any_socket(argv, what, capsys, monkeypatch):
    monkeypatch.setattr("socket.create_connection", never("a connection"))
    monkeypatch.setattr("socket.getaddrinfo", never("a name lookup"))
    assert main(argv) == 2
    assert what in one_line_error(capsys)


def test_a_robot_host_with_its_rtde_port_says_nothing_listens_there(capsys):
    # a loopback address where nothing listens on 30004: the connection is refused at once, no network involved
    assert main(["robot", "info", "127.0.0.62:30004"]) == 1
    line = one_line_error(capsys)
    assert "127.0.0.62" in line and "port 30004 (RTDE): nothing listens there" in line and "not known" not in line


def test_a_cell_toml_robot_host_that_is_no_host_is_refused(tmp_path, capsys):
    path = tmp_path / "CELL.toml"
    assert main(["config", "init", str(path)]) == 0
    path.write_text(path.read_text().replace('host = "192.168.1.10"', 'host = "ur..cell"'))
    capsys.readouterr()
    assert main(["config", "check", str(path)]) == 2
    line = one_line_error(capsys)
    assert "robot.host" in line and "'ur..cell'" in line


def test_written_files_are_mode_0644(tmp_path, poses_csv, capsys):
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(out)]) == 0
    assert (out.stat().st_mode & 0o777) == 0o644
