"""The cell configuration file ``CELL.toml``: robot, sensor, tool, poses, sampling, output.

Every key is declared once, in :mod:`ftacq.settings` (type, unit, range, default, help), as PyMeasure declares
procedure parameters; this module reads a file against those declarations and writes the commented template.
:func:`load_config` rejects an unknown key, a wrong type or a value out of range with one message naming the
file, the key, the value and the allowed range (:class:`ftacq.errors.ConfigError`); a range that depends on the
robot model (the joint speed) is checked for the configured model. Missing keys take the defaults shown by
:func:`example_config_text` (``ftacq config init`` writes it).

Precedence: the file's values, then the declared defaults; nothing is read from the environment or the home
directory. The command line may override the output folder (``--out``).
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from ftacq.errors import ConfigError, InputError
from ftacq.settings import (
    CELL_SETTINGS,
    SECTION_TYPES,
    OutputConfig,
    PosesConfig,
    RobotConfig,
    SamplingConfig,
    SensorConfig,
    Setting,
    ToolConfig,
)
from ftacq.validation import shown

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

SCHEMA = CELL_SETTINGS
"""Every key by section (declared in :mod:`ftacq.settings`)."""


@dataclass(frozen=True)
class CellConfig:
    """The whole cell configuration (SI units; :mod:`ftacq.settings` declares every key's meaning and range)."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    tool: ToolConfig = field(default_factory=ToolConfig)
    poses: PosesConfig = field(default_factory=PosesConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    source: str = "<defaults>"

    def plan_settings(self):
        """Return the :class:`procedures.plan_settings.PlanSettings` these values describe (raises ConfigError)."""
        from procedures.plan_settings import PlanSettings

        return PlanSettings.from_config(self)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Return the configuration as nested plain dicts (JSON-ready; absent optional keys are left out)."""
        out: dict[str, dict[str, Any]] = {}
        for section in SECTION_TYPES:
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


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> CellConfig:
    """Validate nested dicts (as parsed from TOML) and return a :class:`CellConfig`.

    Raises ConfigError naming ``source``, the key, the value and the allowed range; unknown sections and keys
    are rejected with the list of known ones.
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a table of sections, got {type(data).__name__}")
    for section, table in data.items():
        if section not in SCHEMA:
            raise ConfigError(f"{source}: unknown section [{section}] (known: {', '.join(SCHEMA)})")
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {section} = {shown(table)}: must be a table [{section}]")
        for name in table:
            if name not in SCHEMA[section]:
                raise ConfigError(f"{source}: unknown key {section}.{name} (known in [{section}]: "
                                  f"{', '.join(SCHEMA[section])})")
    robot = data.get("robot", {})
    model_key = SCHEMA["robot"]["model"]
    model = model_key.check(robot["model"], f"{source}: robot.model") if "model" in robot else model_key.default
    sections: dict[str, Any] = {}
    for section, table in data.items():
        values = {name: SCHEMA[section][name].check(value, f"{source}: {section}.{name}", model)
                  for name, value in table.items()}
        sections[section] = SECTION_TYPES[section](**values)
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


def check_robot_host(host: str, where: str) -> None:
    """Refuse a robot.host that is not an IP address or host name (no network): ConfigError naming ``where``."""
    from drivers.hosts import host_problem

    problem = host_problem(host)
    if problem is not None:
        raise ConfigError(f"{where} = {shown(host)}: not an IP address or host name ({problem})")


def check_sensor_url(url: str, where: str) -> None:
    """Parse the sensor URL as its driver will (scheme, host, port, query keys) without touching the network.

    Uses the driver's own URL parser (:func:`drivers.sensor.parse_sensor_url`, no I/O); raises ConfigError naming
    ``where`` and the URL, so ``ftacq config check`` and ``--dry-run`` refuse what the run would refuse.
    """
    from drivers.sensor import parse_sensor_url

    try:
        parse_sensor_url(url)
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
    config = config_from_dict(data, str(path))
    check_robot_host(config.robot.host, f"{path}: robot.host")
    return config


def unedited_keys(config: CellConfig) -> list[str]:
    """Return, one line each, the keys marked ``edit`` (:mod:`ftacq.settings`) that ``config`` leaves at the
    template's value or, for an optional one, does not set: what ``ftacq config check`` warns about."""
    lines = []
    for section, keys in SCHEMA.items():
        for name, key in keys.items():
            if not key.edit:
                continue
            value = _plain(getattr(getattr(config, section), name))
            if key.optional and value is None:
                lines.append(f"{key.key} is not set ({key.help})")
            elif not key.optional and value == _plain(key.default):
                lines.append(f"{key.key} = {_toml_value(value)} is still the template's value")
    return lines


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


EDIT_MARK = "EDIT"
"""Marks, in the template, the keys a user must set for their cell."""


def _comment(key: Setting, model: str) -> str:
    unit = f" [{key.unit}]" if key.unit else ""
    edit = f"{EDIT_MARK}: " if key.edit else ""
    shown_range = key.kind in ("float", "int", "vec3") or key.choices or key.forms
    return f"# {edit}{key.help}{unit}" + (f"; {key.range_text(model)}" if shown_range else "")


def example_config_text() -> str:
    """Return a commented CELL.toml with every key at its default (optional keys commented out), each with its
    unit, its allowed range (for the default robot model where the range depends on it) and its help."""
    model = SCHEMA["robot"]["model"].default
    lines = [
        "# ftacq cell configuration (CELL.toml). SI units: m, rad, s, N, N·m (degrees only where a key says _deg).",
        f"# Keys marked {EDIT_MARK} describe your cell: set them before the first run; the others have working "
        "defaults.",
        "# Check it with: ftacq calibrate --config CELL.toml --dry-run   (prints the plan, moves nothing)",
        "",
    ]
    for section, keys in SCHEMA.items():
        lines.append(f"[{section}]")
        for name, key in keys.items():
            lines.append(_comment(key, model))
            if key.optional:
                lines.append(f"# {name} = {_toml_value(key.example if key.example is not None else key.default)}")
            else:
                lines.append(f"{name} = {_toml_value(key.default)}")
        lines.append("")
    return "\n".join(lines)


__all__ = ["CellConfig", "RobotConfig", "SensorConfig", "ToolConfig", "PosesConfig", "SamplingConfig",
           "OutputConfig", "SCHEMA", "EDIT_MARK", "load_config", "config_from_dict", "example_config_text",
           "unedited_keys"]
