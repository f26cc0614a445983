"""CELL.toml: every key validated with a message naming the key, the value and the allowed range."""

from __future__ import annotations

import sys

import pytest

from ftacq.app.cli import EXIT_BAD_INPUT, main
from ftacq.app.config import SCHEMA, CellConfig, config_from_dict, example_config_text, load_config
from ftacq.errors import ConfigError

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
    ("[robot]\njoint_speed_rad_s = 5.0", ["robot.joint_speed_rad_s", "5.0", "[0.001, 3.2]"]),
    ("[robot]\njoint_speed_rad_s = 3.15", ["robot.joint_speed_rad_s", "3.15"]),  # above the UR5e rating (π)
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
