"""The cell configuration file ``CELL.toml``: robot, sensor, tool, poses, sampling, output.

Every key is declared once in :data:`SCHEMA` with its type, unit (in the name) and allowed range, as PyMeasure
declares procedure parameters. :func:`load_config` rejects an unknown key, a wrong type or a value out of range
with one message naming the file, the key, the value and the allowed range (:class:`ftacq.errors.ConfigError`).
Missing keys take the defaults shown by :func:`example_config_text` (``ftacq config init`` writes it).

Precedence: the file's values, then the defaults below; nothing is read from the environment or the home
directory. The command line may override the output folder (``--out``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from ftacq.errors import ConfigError, InputError
from ftacq.validation import shown

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

MOUNTS = ("floor", "wall", "ceiling")


@dataclass(frozen=True)
class Key:
    """One configuration key: its Python type, bounds (inclusive) or choices, and a help line with the unit."""

    kind: str  # "float", "int", "bool", "str", "vec3" (3 floats or absent), "poses" (list of 6-float lists)
    default: Any
    help: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    optional: bool = False  # may be absent (None) with no default value


SCHEMA: dict[str, dict[str, Key]] = {
    "robot": {
        "host": Key("str", "192.168.1.10", "IP address or host name of the UR controller (RTDE)"),
        "model": Key("str", "UR5e", "UR model: UR3e, UR5e, UR10e, UR16e, UR20, UR30, UR3, UR5, UR10"),
        "mount": Key("str", "floor", "nominal mounting of the robot base", choices=MOUNTS),
        "joint_speed_rad_s": Key("float", 0.5, "moveJ joint speed, rad/s (refused above the model's rating)",
                                 1e-3, 3.2),
        "joint_acceleration_rad_s2": Key("float", 1.0, "moveJ joint acceleration, rad/s²", 1e-3, 10.0),
        "table_margin_m": Key("float", 0.02, "clearance kept above the mounting surface, m", 0.0, 0.5),
        "clearance_m": Key("float", 0.01, "link-link and tool-link clearance beyond the capsule radii, m", 0.0, 0.5),
        "move_timeout_s": Key("float", 60.0, "longest time one moveJ may take before it is a fault, s", 1.0, 600.0),
    },
    "sensor": {
        "url": Key("str", "netft://192.168.1.1",
                   "netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N] or can://INTERFACE/CHANNEL[?base=0x20]"),
    },
    "tool": {
        "radius_m": Key("float", 0.05, "radius of a cylinder along the flange z axis enclosing sensor and tool, m",
                        0.0, 0.5),
        "length_m": Key("float", 0.1, "length of that cylinder from the flange, m", 0.0, 1.0),
    },
    "poses": {
        "special": Key("bool", True, "include the 24 special orientations (set A; SROM needs all 24)"),
        "random_count": Key("int", 24, "random orientations within the cone used for identification (set E)", 0, 1000),
        "validation_count": Key("int", 12, "held-out validation orientations, never identified on (set V)", 0, 1000),
        "cone_half_angle_deg": Key("float", 40.0, "half-angle of the cone of E and V tool axes, degrees", 0.0, 90.0),
        "center_m": Key("vec3", None, "centre of the pose sets in the base frame [x, y, z], m (absent = default "
                                      "for the model and mount)", -5.0, 5.0, optional=True),
        "nominal_rotvec": Key("vec3", None, "cone axis orientation, rotation vector of base_R_flange [rx, ry, rz], "
                                            "rad (absent = tool pointing down)", -7.0, 7.0, optional=True),
        "position_jitter_m": Key("float", 0.0, "E/V positions vary uniformly by ± this per axis, m", 0.0, 0.5),
        "seed": Key("int", 0, "random seed of the E and V sets", 0, 2**32 - 1),
        "explicit": Key("poses", None, "extra identification poses [[x, y, z, rx, ry, rz], ...] (m, rad)",
                        optional=True),
        "require_srom": Key("bool", False, "refuse the plan unless all 24 special poses are reachable"),
        "min_identification_poses": Key("int", 12, "fewest A + E poses the plan may proceed with", 1, 10000),
    },
    "sampling": {
        "settle_time_s": Key("float", 0.5, "wait at least this long after the robot reports steady, s", 0.0, 60.0),
        "settle_window_s": Key("float", 0.2, "window over which the sensor's std is checked for stillness, s",
                               0.001, 10.0),
        "settle_force_std_n": Key("float", 0.5, "settled when every force channel's std over the window is below, N",
                                  1e-6, 100.0),
        "settle_torque_std_nm": Key("float", 0.03, "... and every torque channel's std is below, N·m", 1e-6, 10.0),
        "settle_timeout_s": Key("float", 10.0, "a pose that does not settle within this is a fault, s", 0.01, 600.0),
        "average_time_s": Key("float", 0.5, "averaging time per pose, s", 0.001, 600.0),
        "drift_check": Key("bool", True, "revisit the first pose at the end and report the bias drift"),
        "drift_warn_force_n": Key("float", 0.5, "warn when the force drift (norm) exceeds this, N", 0.0, 1000.0),
        "drift_warn_torque_nm": Key("float", 0.02, "warn when the torque drift (norm) exceeds this, N·m", 0.0, 100.0),
        "sensor_timeout_s": Key("float", 2.0, "no sample for this long means the sensor went silent (fault), s",
                                0.05, 60.0),
    },
    "output": {
        "folder": Key("str", "runs", "where run folders are created (one per run, named by date and time)"),
    },
}


@dataclass(frozen=True)
class RobotConfig:
    host: str = "192.168.1.10"
    model: str = "UR5e"
    mount: str = "floor"
    joint_speed_rad_s: float = 0.5
    joint_acceleration_rad_s2: float = 1.0
    table_margin_m: float = 0.02
    clearance_m: float = 0.01
    move_timeout_s: float = 60.0


@dataclass(frozen=True)
class SensorConfig:
    url: str = "netft://192.168.1.1"


@dataclass(frozen=True)
class ToolConfig:
    radius_m: float = 0.05
    length_m: float = 0.1


@dataclass(frozen=True)
class PosesConfig:
    special: bool = True
    random_count: int = 24
    validation_count: int = 12
    cone_half_angle_deg: float = 40.0
    center_m: tuple[float, float, float] | None = None
    nominal_rotvec: tuple[float, float, float] | None = None
    position_jitter_m: float = 0.0
    seed: int = 0
    explicit: tuple[tuple[float, ...], ...] | None = None
    require_srom: bool = False
    min_identification_poses: int = 12


@dataclass(frozen=True)
class SamplingConfig:
    settle_time_s: float = 0.5
    settle_window_s: float = 0.2
    settle_force_std_n: float = 0.5
    settle_torque_std_nm: float = 0.03
    settle_timeout_s: float = 10.0
    average_time_s: float = 0.5
    drift_check: bool = True
    drift_warn_force_n: float = 0.5
    drift_warn_torque_nm: float = 0.02
    sensor_timeout_s: float = 2.0


@dataclass(frozen=True)
class OutputConfig:
    folder: str = "runs"


_SECTION_TYPES = {
    "robot": RobotConfig,
    "sensor": SensorConfig,
    "tool": ToolConfig,
    "poses": PosesConfig,
    "sampling": SamplingConfig,
    "output": OutputConfig,
}


@dataclass(frozen=True)
class CellConfig:
    """The whole cell configuration (SI units; see :data:`SCHEMA` for every key's meaning and range)."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    tool: ToolConfig = field(default_factory=ToolConfig)
    poses: PosesConfig = field(default_factory=PosesConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    source: str = "<defaults>"

    def plan_settings(self):
        """Return the :class:`procedures.plan.PlanSettings` these values describe (raises ConfigError)."""
        from procedures.plan import PlanSettings

        p = self.poses
        return PlanSettings(
            model=self.robot.model,
            mount=self.robot.mount,
            center_m=p.center_m,
            special=p.special,
            random_count=p.random_count,
            validation_count=p.validation_count,
            cone_half_angle_deg=p.cone_half_angle_deg,
            nominal_rotvec=p.nominal_rotvec,
            position_jitter_m=p.position_jitter_m,
            seed=p.seed,
            tool_radius_m=self.tool.radius_m,
            tool_length_m=self.tool.length_m,
            table_margin_m=self.robot.table_margin_m,
            joint_speed_rad_s=self.robot.joint_speed_rad_s,
            joint_acceleration_rad_s2=self.robot.joint_acceleration_rad_s2,
            settle_time_s=self.sampling.settle_time_s,
            average_time_s=self.sampling.average_time_s,
            explicit_poses=p.explicit,
            min_identification_poses=p.min_identification_poses,
            require_srom=p.require_srom,
            drift_check=self.sampling.drift_check,
            clearance_m=self.robot.clearance_m,
        )

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Return the configuration as nested plain dicts (JSON-ready; absent optional keys are left out)."""
        out: dict[str, dict[str, Any]] = {}
        for section in _SECTION_TYPES:
            values = asdict(getattr(self, section))
            out[section] = {k: _plain(v) for k, v in values.items() if v is not None}
        return out

    def replace_section(self, section: str, **changes) -> "CellConfig":
        """Return a copy with some keys of one section changed (validated like the file's values)."""
        data = self.to_dict()
        data[section].update(changes)
        return config_from_dict(data, self.source)


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def _number_text(value: float) -> str:
    return str(int(value)) if float(value).is_integer() and abs(value) >= 1e4 else f"{value:g}"


def _range_text(key: Key) -> str:
    if key.choices:
        return "one of " + ", ".join(key.choices)
    kind = {"float": "a number", "int": "an integer", "vec3": "3 numbers each"}.get(key.kind, "a value")
    if key.low is not None and key.high is not None:
        return f"{kind} in [{_number_text(key.low)}, {_number_text(key.high)}]"
    return kind


def _check_number(where: str, value: Any, key: Key, integer: bool) -> float | int:
    bad_type = isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int))
    # an int is compared exactly (math.isfinite would overflow on one too large for a float)
    if bad_type or (isinstance(value, float) and not math.isfinite(value)) \
            or (key.low is not None and value < key.low) or (key.high is not None and value > key.high):
        raise ConfigError(f"{where} = {shown(value)}: must be {_range_text(key)}")
    return int(value) if integer else float(value)


def _check_value(where: str, value: Any, key: Key) -> Any:
    if key.kind == "float":
        return _check_number(where, value, key, integer=False)
    if key.kind == "int":
        return _check_number(where, value, key, integer=True)
    if key.kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{where} = {shown(value)}: must be true or false")
        return value
    if key.kind == "str":
        if not isinstance(value, str) or not value.strip():
            raise ConfigError(f"{where} = {shown(value)}: must be a non-empty string ({key.help})")
        if key.choices and value not in key.choices:
            raise ConfigError(f"{where} = {shown(value)}: must be {_range_text(key)}")
        return value.strip()
    if key.kind == "vec3":
        if not isinstance(value, list) or len(value) != 3:
            raise ConfigError(f"{where} = {shown(value)}: must be a list of 3 numbers in [{key.low:g}, {key.high:g}]")
        return tuple(_check_number(f"{where}[{i}]", v, key, integer=False) for i, v in enumerate(value))
    if key.kind == "poses":
        if not isinstance(value, list):
            raise ConfigError(f"{where} = {shown(value)}: must be a list of poses [x, y, z, rx, ry, rz] (m, rad)")
        rows = []
        pose_key = Key("float", 0.0, "", -10.0, 10.0)
        for i, row in enumerate(value):
            if not isinstance(row, list) or len(row) != 6:
                raise ConfigError(f"{where}[{i}] = {shown(row)}: must be a pose [x, y, z, rx, ry, rz] of 6 numbers")
            rows.append(tuple(_check_number(f"{where}[{i}][{j}]", v, pose_key, integer=False)
                              for j, v in enumerate(row)))
        return tuple(rows) if rows else None
    raise AssertionError(key.kind)  # pragma: no cover


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> CellConfig:
    """Validate nested dicts (as parsed from TOML) and return a :class:`CellConfig`.

    Raises ConfigError naming ``source``, the key, the value and the allowed range; unknown sections and keys
    are rejected with the list of known ones.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a table of sections, got {type(data).__name__}")
    sections: dict[str, Any] = {}
    for section, table in data.items():
        if section not in SCHEMA:
            raise ConfigError(f"{source}: unknown section [{section}] (known: {', '.join(SCHEMA)})")
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {section} = {shown(table)}: must be a table [{section}]")
        values: dict[str, Any] = {}
        for name, value in table.items():
            if name not in SCHEMA[section]:
                raise ConfigError(f"{source}: unknown key {section}.{name} (known in [{section}]: "
                                  f"{', '.join(SCHEMA[section])})")
            values[name] = _check_value(f"{source}: {section}.{name}", value, SCHEMA[section][name])
        sections[section] = _SECTION_TYPES[section](**values)
    config = CellConfig(**sections, source=source)
    try:
        config.plan_settings()  # model name, speed within the model's rating, at least one pose set …
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from error
    if config.sampling.settle_window_s > config.sampling.settle_timeout_s:
        raise ConfigError(f"{source}: sampling.settle_window_s = {config.sampling.settle_window_s!r}: must not "
                          f"exceed sampling.settle_timeout_s = {config.sampling.settle_timeout_s!r}")
    check_sensor_url(config.sensor.url, f"{source}: sensor.url")
    return config


def check_sensor_url(url: str, where: str) -> None:
    """Parse the sensor URL as its driver will (scheme, host, port, query keys) without touching the network.

    Builds the driver from the URL and drops it (drivers do no I/O before ``start()``); raises ConfigError naming
    ``where`` and the URL, so ``ftacq config check`` and ``--dry-run`` refuse what the run would refuse.
    """
    from drivers.sensor import open_sensor

    try:
        open_sensor(url)
    except InputError as error:
        raise ConfigError(f"{where}: {error}") from None
    except (ValueError, TypeError) as error:  # urllib's own parse errors, e.g. "Invalid IPv6 URL"
        raise ConfigError(f"{where} = {shown(url)}: not a valid URL ({error})") from None


def load_config(path: str | Path) -> CellConfig:
    """Read and validate ``CELL.toml``. Raises ConfigError (file unreadable, TOML syntax, key, value, range)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: cannot read the configuration: {error}") from error
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from error
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: nested too deeply to read") from None
    except ValueError as error:  # e.g. an integer of more than 4300 digits
        raise ConfigError(f"{path}: cannot read a value: {error}") from None
    return config_from_dict(data, str(path))


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


def example_config_text() -> str:
    """Return a commented CELL.toml with every key at its default (optional keys commented out)."""
    lines = [
        "# ftacq cell configuration (CELL.toml). SI units: m, rad, s, N, N·m (degrees only where a key says _deg).",
        "# Check it with: ftacq calibrate --config CELL.toml --dry-run   (prints the plan, moves nothing)",
        "",
    ]
    examples = {"center_m": [-0.245, -0.368, 0.368], "nominal_rotvec": [3.14159, 0.0, 0.0],
                "explicit": [[-0.25, -0.35, 0.40, 3.14159, 0.0, 0.0]]}
    for section, keys in SCHEMA.items():
        lines.append(f"[{section}]")
        for name, key in keys.items():
            lines.append(f"# {key.help}" + (f" ({_range_text(key)})" if key.kind in ("float", "int") or key.choices
                                              else ""))
            if key.optional:
                lines.append(f"# {name} = {_toml_value(examples.get(name, key.default))}")
            else:
                lines.append(f"{name} = {_toml_value(key.default)}")
        lines.append("")
    return "\n".join(lines)


def _check_schema_defaults() -> None:
    """The dataclass defaults and the schema's must agree (import-time guard against drift)."""
    for section, cls in _SECTION_TYPES.items():
        for f in fields(cls):
            key = SCHEMA[section][f.name]
            if key.default != f.default:
                raise AssertionError(f"{section}.{f.name}: schema default {key.default!r} != {f.default!r}")
        if set(SCHEMA[section]) != {f.name for f in fields(cls)}:
            raise AssertionError(f"[{section}] schema and dataclass keys differ")


_check_schema_defaults()

__all__ = ["CellConfig", "RobotConfig", "SensorConfig", "ToolConfig", "PosesConfig", "SamplingConfig",
           "OutputConfig", "SCHEMA", "load_config", "config_from_dict", "example_config_text"]
