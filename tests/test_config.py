"""CELL.toml: every key validated with a message naming the key, the value and the allowed range."""

from __future__ import annotations

import re
import sys

import pytest

from ftacq.app.cli import EXIT_BAD_INPUT, main
from ftacq.app.config import EDIT_MARK, SCHEMA, CellConfig, config_from_dict, example_config_text, load_config
from ftacq.errors import ConfigError
from procedures.calibration_procedure import ProcedureOptions
from procedures.plan_settings import PlanSettings
from procedures.settle import SettleSettings

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def write(tmp_path, text: str):
    path = tmp_path / "CELL.toml"
    path.write_text(text, encoding="utf-8")
    return path


def test_example_parses_to_the_defaults_and_covers_every_key():
    text = example_config_text()
    config = config_from_dict(tomllib.loads(text))
    assert config.to_dict() == CellConfig().to_dict()
    for section, keys in SCHEMA.items():
        assert f"[{section}]" in text
        for name in keys:
            assert f"{name} = " in text, f"{section}.{name} missing from the example"


def _template_entries(text: str) -> dict[str, tuple[str, str]]:
    """Return {section.key: (comment line, value line)} of the template (value commented out when optional)."""
    lines, section, out = text.splitlines(), "", {}
    for comment, value in zip(lines, lines[1:]):
        match = re.match(r"^(# )?([a-z0-9_]+) = ", value)
        if comment.startswith("[") and comment.endswith("]"):
            section = comment[1:-1]
        elif comment.startswith("# ") and match and section:
            out[f"{section}.{match.group(2)}"] = (comment, value)
    return out


def test_template_writes_the_ranges_the_checker_enforces():
    entries = _template_entries(example_config_text())
    assert set(entries) == {f"{s}.{k}" for s, keys in SCHEMA.items() for k in keys}
    numeric = 0
    for key, (comment, _) in entries.items():
        section, name = key.split(".")
        declared = SCHEMA[section][name]
        if declared.kind not in ("float", "int"):
            continue
        numeric += 1
        low_text, high_text = comment.split(" in [")[1].split("]")[0].split(", ")
        if declared.kind == "int":
            low, high = int(low_text), int(high_text)
            cases = ((low, True), (high, True), (low - 1, False), (high + 1, False))
        else:
            low, high = float(low_text), float(high_text)
            cases = ((low, True), (high, True), (low - 1e-3 * max(1.0, abs(low)), False),
                     (high + 1e-3 * max(1.0, abs(high)), False))
        for value, accepted in cases:
            data = {section: {name: value}}
            if (section, name) == ("poses", "min_identification_poses"):
                data["poses"]["random_count"] = 1000  # the plan needs that many identification poses
            if (section, name) == ("sampling", "settle_window_s"):
                data["sampling"]["settle_timeout_s"] = 600.0  # the window must fit in the timeout
            if (section, name) == ("sampling", "settle_timeout_s"):
                data["sampling"]["settle_window_s"] = 0.001
            if accepted:
                config_from_dict(data)
            else:
                with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
                    config_from_dict(data)
    assert numeric >= 20
    speed = entries["robot.joint_speed_rad_s"][0]
    assert "for the UR5e" in speed and "3.2" not in speed  # the model's own bound, as checked


def test_template_marks_the_keys_a_user_must_edit():
    entries = _template_entries(example_config_text())
    marked = {key for key, (comment, _) in entries.items() if comment.startswith(f"# {EDIT_MARK}: ")}
    assert marked == {"robot.host", "robot.model", "robot.mount", "sensor.url", "tool.radius_m", "tool.length_m",
                      "tool.sensor_offset_m"}


def test_every_consumer_takes_the_declared_defaults():
    config = CellConfig()
    assert PlanSettings() == config.plan_settings()
    assert (PlanSettings().joint_speed_rad_s, PlanSettings().settle_time_s, PlanSettings().tool_radius_m) == (
        0.5, 0.5, 0.05)
    assert SettleSettings() == SettleSettings.from_config(config)
    assert ProcedureOptions(mount="floor") == ProcedureOptions.from_config(config)


def test_model_names_are_case_insensitive():
    assert config_from_dict({"robot": {"model": "ur10e"}}).robot.model == "UR10e"


def test_values_reach_the_plan_settings(tmp_path):
    path = write(tmp_path, """
[robot]
model = "UR10e"
mount = "wall"
joint_speed_rad_s = 0.3
joint_acceleration_rad_s2 = 0.8
[tool]
radius_m = 0.07
length_m = 0.2
[poses]
random_count = 10
validation_count = 5
cone_half_angle_deg = 30.0
center_m = [-0.3, -0.5, 0.4]
seed = 7
explicit = [[-0.3, -0.5, 0.4, 3.14159, 0.0, 0.0]]
[sampling]
average_time_s = 0.25
settle_time_s = 0.1
[output]
folder = "elsewhere"
""")
    config = load_config(path)
    settings = config.plan_settings()
    assert (settings.model, settings.mount) == ("UR10e", "wall")
    assert settings.joint_speed_rad_s == 0.3 and settings.joint_acceleration_rad_s2 == 0.8
    assert (settings.tool_radius_m, settings.tool_length_m) == (0.07, 0.2)
    assert (settings.random_count, settings.validation_count, settings.seed) == (10, 5, 7)
    assert settings.center_m == (-0.3, -0.5, 0.4)
    assert settings.explicit_poses == ((-0.3, -0.5, 0.4, 3.14159, 0.0, 0.0),)
    assert settings.average_time_s == 0.25 and settings.settle_time_s == 0.1
    assert config.output.folder == "elsewhere"
    assert config_from_dict(config.to_dict()).to_dict() == config.to_dict()  # run.json round trip


@pytest.mark.parametrize("text, expected", [
    ("[robot]\njoint_speed_rad_s = 5.0", ["robot.joint_speed_rad_s", "5.0", "[0.001, 3.14159] for the UR5e"]),
    ("[robot]\njoint_speed_rad_s = 3.15", ["robot.joint_speed_rad_s", "3.15"]),  # above the UR5e rating (π)
    ("[robot]\nmodel = \"UR10e\"\njoint_speed_rad_s = 2.5", ["robot.joint_speed_rad_s", "2.5",
                                                            "[0.001, 2.09439] for the UR10e"]),
    ("[robot]\njoint_acceleration_rad_s2 = -1", ["robot.joint_acceleration_rad_s2", "-1", "[0.001, 10]"]),
    ("[robot]\nmount = \"roof\"", ["robot.mount", "'roof'", "floor, wall, ceiling"]),
    ("[robot]\nmodel = \"UR99\"", ["robot.model", "'UR99'", "UR5e"]),
    ("[robot]\nspeed = 1.0", ["unknown key robot.speed", "joint_speed_rad_s"]),
    ("[robots]\nhost = \"x\"", ["unknown section [robots]"]),
    ("[poses]\nrandom_count = 2.5", ["poses.random_count", "2.5", "an integer in [0, 1000]"]),
    ("[poses]\nrandom_count = true", ["poses.random_count", "True"]),
    ("[poses]\ncone_half_angle_deg = 120", ["poses.cone_half_angle_deg", "120", "[0, 90]"]),
    ("[poses]\ncenter_m = [1.0, 2.0]", ["poses.center_m", "[1.0, 2.0]", "3 numbers"]),
    ("[poses]\ncenter_m = [1.0, 2.0, 9.0]", ["poses.center_m[2]", "9.0", "[-5, 5]"]),
    ("[poses]\nexplicit = [[1.0, 2.0, 3.0]]", ["poses.explicit[0]", "6 numbers"]),
    ("[poses]\nspecial = \"yes\"", ["poses.special", "'yes'", "true or false"]),
    ("[poses]\nspecial = false\nrandom_count = 0", ["no identification poses"]),
    ("[sampling]\naverage_time_s = 0", ["sampling.average_time_s", "0", "[0.001, 600]"]),
    ("[sampling]\nsettle_timeout_s = nan", ["sampling.settle_timeout_s", "nan"]),
    ("[sampling]\nsettle_window_s = 5.0\nsettle_timeout_s = 1.0", ["sampling.settle_window_s", "settle_timeout_s"]),
    ("[tool]\nradius_m = 0.9", ["tool.radius_m", "0.9", "[0, 0.5]"]),
    ("[sensor]\nurl = \"\"", ["sensor.url", "''"]),
    ("[output]\nfolder = 3", ["output.folder", "3"]),
    ("robot = 3", ["robot = 3", "must be a table"]),
])
def test_bad_values_name_the_key_the_value_and_the_range(tmp_path, text, expected):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert str(path) in message
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


def test_toml_syntax_error_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[robot\nhost = 1"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.toml")


def test_config_init_writes_the_example_and_refuses_to_overwrite(tmp_path, capsys):
    path = tmp_path / "CELL.toml"
    assert main(["config", "init", str(path)]) == 0
    assert path.read_text(encoding="utf-8") == example_config_text()
    assert load_config(path).to_dict() == CellConfig().to_dict()
    path.write_text("# mine\n", encoding="utf-8")
    assert main(["config", "init", str(path)]) == EXIT_BAD_INPUT
    assert "already exists" in capsys.readouterr().err
    assert path.read_text(encoding="utf-8") == "# mine\n"
    assert main(["config", "init", str(path), "--force"]) == 0
    assert path.read_text(encoding="utf-8") == example_config_text()


def test_config_check_reports_a_bad_key_with_exit_2(tmp_path, capsys):
    bad = write(tmp_path, "[robot]\njoint_speed_rad_s = 9")
    assert main(["config", "check", str(bad)]) == EXIT_BAD_INPUT
    assert "robot.joint_speed_rad_s = 9" in capsys.readouterr().err


def test_config_check_warns_about_the_unedited_template_and_strict_fails(tmp_path, capsys):
    """Issue 38, item 3: the template as written passes no longer: every key marked EDIT left at its value, and
    the sensor offset not set, are named (WARN, exit 0; --strict: FAIL, exit 1)."""
    path = tmp_path / "CELL.toml"
    assert main(["config", "init", str(path)]) == 0
    assert "tool.sensor_offset_m" in capsys.readouterr().err  # asked for up front
    assert main(["config", "check", str(path)]) == 0
    err = capsys.readouterr().err
    assert f"{path}: WARN: robot.host = \"192.168.1.10\" is still the template's value" in err
    assert f"{path}: WARN: tool.sensor_offset_m is not set" in err and f"{path}: OK" not in err
    assert main(["config", "check", "--strict", str(path)]) == 1
    assert f"{path}: FAIL (7 keys marked {EDIT_MARK}" in capsys.readouterr().err
    edited = write(tmp_path, '[robot]\nhost = "10.0.0.5"\nmodel = "UR10e"\nmount = "wall"\n[sensor]\n'
                   'url = "netft://10.0.0.6"\n[tool]\nradius_m = 0.07\nlength_m = 0.2\nsensor_offset_m = [0, 0, 0.03]\n')
    assert main(["config", "check", "--strict", str(edited)]) == 0
    assert capsys.readouterr().err.strip() == f"{edited}: OK"
