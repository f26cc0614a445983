"""The cell's settings (the keys of ``CELL.toml``), each declared once: type, unit, range, default, help.

As PyMeasure declares a procedure's parameters, each ``[section]`` of CELL.toml is a frozen dataclass below
whose fields are declared with :func:`setting`. Everything else is derived from these declarations:

- :mod:`ftacq.app.config` reads and checks a file against them and writes the commented template
  (``ftacq config init``) with each key's unit, range and help, marking the keys a user must edit;
- ``procedures.plan_settings.PlanSettings``, ``procedures.settle.SettleSettings`` and
  ``procedures.calibration_procedure.ProcedureOptions`` take their defaults and checks from them
  (:func:`from_setting`), so a default or a range is written in one place only.

Adding a key is one :func:`setting` line in its section (an optional key with no default:
``setting(None, help, kind="str", optional=True)``; it is absent, None, unless the file sets it). A bound that depends on the robot model (the joint
speed) is a function of the :class:`ftacq.kinematics.URModel` (``model_high``), checked and shown for the
configured model. Units are SI (m, rad, s, N, N·m; degrees only in keys ending ``_deg``).
"""

from __future__ import annotations

import math
from dataclasses import Field, dataclass, field, fields, replace
from typing import Any, Callable, TypeVar

import numpy as np

from ftacq.errors import ConfigError
from ftacq.kinematics import UR_MODELS, URModel, ur_model
from ftacq.mounts import MOUNT_FORMS, check_mount
from ftacq.ros2_names import FRAME_FORMS, NAMESPACE_FORMS, ROS2_DISTROS, check_frame_id, check_namespace
from ftacq.validation import shown

KINDS = ("float", "int", "bool", "str", "vec3", "poses")
"""Value shapes: a number, an integer, true/false, a string, 3 numbers (or absent), a list of 6-number poses."""
SETTING = "ftacq.setting"
"""Key of a dataclass field's metadata holding its :class:`Setting`."""
KEY = "ftacq.key"
"""Key of a dataclass field's metadata holding the CELL.toml key it takes (``"robot.model"``)."""
POSE_COORDINATE_BOUND = 10.0
"""|x|, |y|, |z| (m) and |rx|, |ry|, |rz| (rad) of an explicit pose are at most this."""

T = TypeVar("T")


@dataclass(frozen=True)
class Setting:
    """One CELL.toml key (``section.name``).

    Attributes:
        kind: one of :data:`KINDS`. default: its value when the file leaves it out (None: absent, for an
            ``optional`` key). help: one line for people (the unit is added from ``unit``).
        unit: SI unit as written ("m", "rad/s", "N·m"), "" when none. low, high: inclusive bounds of a number
            (of each number of a vec3). choices: the allowed strings. optional: may be absent (no default).
        edit: a user must set it for their cell (robot address, model, mount, sensor URL, tool size).
        example: shown, commented out, in the template for an optional key.
        model_high: an upper bound depending on the robot model (used instead of ``high`` when the model is
            known), with ``model_high_why`` saying where it comes from.
        parse: for a str key without fixed choices: returns the value normalised or raises ValueError;
            ``forms`` says in words what it accepts.
    """

    kind: str
    default: Any
    help: str
    unit: str = ""
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    optional: bool = False
    edit: bool = False
    example: Any = None
    model_high: Callable[[URModel], float] | None = None
    model_high_why: str = ""
    parse: Callable[[str], str] | None = None
    forms: str = ""
    section: str = ""
    name: str = ""

    @property
    def key(self) -> str:
        """``section.name`` as written in messages."""
        return f"{self.section}.{self.name}"

    def high_for(self, model: str | None) -> float | None:
        """The upper bound for robot model ``model`` (the model-independent ``high`` when unknown)."""
        if self.model_high is not None and model is not None:
            try:
                return float(self.model_high(ur_model(model)))
            except ValueError:
                pass
        return self.high

    def range_text(self, model: str | None = None) -> str:
        """The allowed values in words, e.g. ``a number in [0.001, 3.14159] for the UR5e (…)``."""
        if self.choices:
            return "one of " + ", ".join(self.choices)
        if self.forms:
            return self.forms
        kind = {"float": "a number", "int": "an integer", "vec3": "3 numbers each"}.get(self.kind, "a value")
        high = self.high_for(model)
        if self.low is None or high is None:
            return kind
        text = f"{kind} in [{_number_text(self.low, up=True)}, {_number_text(high)}]"
        if self.model_high is not None and model is not None:
            text += f" for the {ur_model(model).name} ({self.model_high_why})"
        return text

    def check(self, value: Any, where: str | None = None, model: str | None = None) -> Any:
        """Return ``value`` checked and normalised (float, int, stripped str, tuple for vec3 and poses; None for
        an absent optional key). Raises ConfigError naming ``where`` (default the key), the value and the range.
        """
        where = where or self.key
        if value is None and self.optional:
            return None
        if self.kind in ("float", "int"):
            return self._number(where, value, self.kind == "int", model)
        if self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise ConfigError(f"{where} = {shown(value)}: must be true or false")
            return bool(value)
        if self.kind == "str":
            if not isinstance(value, str) or not value.strip():
                raise ConfigError(f"{where} = {shown(value)}: must be a non-empty string ({self.help})")
            if self.choices:  # case-insensitive, returned as declared ("ur5e" → "UR5e")
                for choice in self.choices:
                    if choice.lower() == value.strip().lower():
                        return choice
                raise ConfigError(f"{where} = {shown(value)}: must be {self.range_text()}")
            if self.parse is not None:
                try:
                    return self.parse(value)
                except ValueError as error:
                    raise ConfigError(f"{where} = {shown(value)}: must be {self.range_text()} ({error})") from None
            return value.strip()
        if self.kind == "vec3":
            items = _as_list(value)
            if items is None or len(items) != 3:
                raise ConfigError(f"{where} = {_shown(value)}: must be a list of 3 numbers in "
                                  f"[{_number_text(self.low)}, {_number_text(self.high)}]")
            return tuple(self._number(f"{where}[{i}]", v, False, model) for i, v in enumerate(items))
        if self.kind == "poses":
            rows = _as_list(value)
            if rows is None:
                raise ConfigError(f"{where} = {_shown(value)}: must be a list of poses [x, y, z, rx, ry, rz] (m, rad)")
            coordinate = Setting("float", 0.0, "", low=-POSE_COORDINATE_BOUND, high=POSE_COORDINATE_BOUND)
            out = []
            for i, row in enumerate(rows):
                items = _as_list(row)
                if items is None or len(items) != 6:
                    raise ConfigError(f"{where}[{i}] = {_shown(row)}: must be a pose [x, y, z, rx, ry, rz] of "
                                      "6 numbers")
                out.append(tuple(coordinate._number(f"{where}[{i}][{j}]", v, False, None)
                                 for j, v in enumerate(items)))
            return tuple(out) if out else None
        raise AssertionError(self.kind)  # pragma: no cover - kinds are checked at declaration

    def _number(self, where: str, value: Any, integer: bool, model: str | None) -> float | int:
        high = self.high_for(model)
        number_types = (int, float, np.integer, np.floating)
        bad_type = isinstance(value, (bool, np.bool_)) or not isinstance(value, number_types) \
            or (integer and not isinstance(value, (int, np.integer)))
        # an int is compared exactly (math.isfinite would overflow on one too large for a float)
        if bad_type or (not isinstance(value, (int, np.integer)) and not math.isfinite(value)) \
                or (self.low is not None and value < self.low) or (high is not None and value > high):
            raise ConfigError(f"{where} = {shown(value)}: must be {self.range_text(model)}")
        return int(value) if integer else float(value)


def _as_list(value: Any) -> list | None:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return list(value)
    return None


def _shown(value: Any) -> str:
    """:func:`ftacq.validation.shown` of a value, with arrays and tuples shown as the lists a file would hold."""
    return shown(value.tolist() if isinstance(value, np.ndarray) else list(value) if isinstance(value, tuple)
                 else value)


def _number_text(value: float | None, up: bool = False) -> str:
    """A bound in 6 significant digits, rounded inwards (down for an upper bound, ``up`` for a lower one), so
    that the number shown is itself accepted."""
    if value is None:
        return "?"
    if float(value).is_integer() and abs(value) >= 1e4:
        return str(int(value))
    text = f"{value:g}"
    if (float(text) > value and not up) or (float(text) < value and up):
        step = 10.0 ** (math.floor(math.log10(abs(value))) - 5)
        text = f"{(math.ceil(value / step) if up else math.floor(value / step)) * step:g}"
    return text


def setting(default: T, help: str, *, kind: str | None = None, unit: str = "", low: float | None = None,
            high: float | None = None, choices: tuple[str, ...] | None = None, optional: bool = False,
            edit: bool = False, example: Any = None, model_high: Callable[[URModel], float] | None = None,
            model_high_why: str = "", parse: Callable[[str], str] | None = None, forms: str = "") -> T:
    """Declare one key of a section class (a dataclass field carrying its :class:`Setting`).

    ``kind`` defaults from the default's type (bool, int, float, str); give it for vec3 and poses keys.
    """
    if kind is None:
        kind = {bool: "bool", int: "int", float: "float", str: "str"}.get(type(default), "")
    if kind not in KINDS:
        raise TypeError(f"setting {help!r}: kind {kind!r} is not one of {KINDS}")
    declared = Setting(kind, default, help, unit, low, high, choices, optional, edit, example, model_high,
                       model_high_why, parse, forms)
    return field(default=default, metadata={SETTING: declared})


CELL_SETTINGS: dict[str, dict[str, Setting]] = {}
"""Every CELL.toml key, by section then name, in file order (filled by :func:`cell_section`)."""
SECTION_TYPES: dict[str, type] = {}
"""The dataclass of each section, in file order."""


def cell_section(name: str) -> Callable[[type[T]], type[T]]:
    """Class decorator: make a frozen dataclass of ``setting`` fields and register it as ``[name]``."""
    def register(cls: type[T]) -> type[T]:
        data_class = dataclass(frozen=True)(cls)
        declared: dict[str, Setting] = {}
        for f in fields(data_class):  # type: ignore[arg-type]
            if SETTING not in f.metadata:
                raise TypeError(f"[{name}] {f.name}: declare it with setting(...)")
            declared[f.name] = replace(f.metadata[SETTING], section=name, name=f.name)
            declared[f.name].check(f.default)  # a default outside its own range is a declaration bug
        CELL_SETTINGS[name] = declared
        SECTION_TYPES[name] = data_class
        return data_class
    return register


def setting_of(key: str) -> Setting:
    """Return the declaration of ``"section.name"``. Raises KeyError for an unknown key."""
    section, _, name = key.partition(".")
    return CELL_SETTINGS[section][name]


def from_setting(key: str) -> Any:
    """A dataclass field (outside CELL.toml's sections) that takes the key ``"section.name"``: its default is the
    declared one and :func:`check_fields` checks it against the declaration."""
    declared = setting_of(key)
    return field(default=declared.default, metadata={KEY: key})


def keyed_fields(cls_or_instance: Any) -> list[tuple[Field, Setting]]:
    """Return (field, declaration) of every field made with :func:`from_setting`."""
    return [(f, setting_of(f.metadata[KEY])) for f in fields(cls_or_instance) if KEY in f.metadata]


def check_fields(instance: Any, model: str | None = None) -> dict[str, Any]:
    """Check every :func:`from_setting` field of a dataclass instance against its declaration (the range for robot
    ``model`` where it depends on it); return the normalised values by field name (ConfigError names the key)."""
    return {f.name: declared.check(getattr(instance, f.name), declared.key, model)
            for f, declared in keyed_fields(instance)}


def values_from(config: Any, cls: type) -> dict[str, Any]:
    """Return the keyword arguments of dataclass ``cls`` taken from a configuration with one attribute per section
    (``config.robot.model`` for a field made with ``from_setting("robot.model")``)."""
    out = {}
    for f, declared in keyed_fields(cls):
        out[f.name] = getattr(getattr(config, declared.section), declared.name)
    return out


def _slowest_joint_speed(model: URModel) -> float:
    return min(model.max_joint_speed_rad_s)


MAX_JOINT_SPEED_RAD_S = max(_slowest_joint_speed(m) for m in UR_MODELS.values())
"""The largest joint speed any model accepts (each model's own bound is its slowest joint's rated speed)."""


# ------------------------------------------------------------------------------------------------- the sections


@cell_section("robot")
class RobotConfig:
    """``[robot]``: the UR arm, its mounting and its motion limits."""

    host: str = setting("192.168.1.10", "IP address or host name of the UR controller (RTDE)", edit=True)
    model: str = setting("UR5e", "UR model", choices=tuple(UR_MODELS), edit=True)
    mount: str = setting("floor", "mounting of the robot base: a nominal mount, a tilt (α about base x, then β about "
                         "base y, degrees, paper eq. 47) or the gravity direction in the base frame", edit=True,
                         parse=check_mount, forms=MOUNT_FORMS)
    joint_speed_rad_s: float = setting(
        0.5, "moveJ joint speed", unit="rad/s", low=1e-3, high=MAX_JOINT_SPEED_RAD_S,
        model_high=_slowest_joint_speed, model_high_why="its slowest joint's rated speed")
    joint_acceleration_rad_s2: float = setting(1.0, "moveJ joint acceleration", unit="rad/s²", low=1e-3, high=10.0)
    table_margin_m: float = setting(0.02, "clearance kept above the mounting surface", unit="m", low=0.0, high=0.5)
    clearance_m: float = setting(0.01, "link-link and tool-link clearance beyond the capsule radii", unit="m",
                                 low=0.0, high=0.5)
    move_timeout_s: float = setting(60.0, "longest time one moveJ may take before it is a fault", unit="s",
                                    low=1.0, high=600.0)


@cell_section("sensor")
class SensorConfig:
    """``[sensor]``: the force/torque sensor."""

    url: str = setting("netft://192.168.1.1", "netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N] or "
                       "can://INTERFACE/CHANNEL[?base=0x20]", edit=True)
    frame: str = setting("ft_sensor", "name of the sensor frame (header.frame_id of the ROS 2 wrench topics and "
                         "the MCAP record: docs/ros2.md)", parse=check_frame_id, forms=FRAME_FORMS)
    ros2_namespace: str = setting("/ftacq", "ROS 2 namespace of ftacq monitor --ros2's topics and service (and of "
                                  "the MCAP record's topics)", parse=check_namespace, forms=NAMESPACE_FORMS)
    ros2_distro: str = setting("jazzy", "ROS 2 release of the nodes that should list ftacq's node (ros2 node list; "
                               "its discovery message differs up to Humble: docs/ros2.md)", choices=ROS2_DISTROS)
    check: bool = setting(True, "fit the sensor's force gains and cross-talk beside every calibration (the verdict's "
                          "sensor line; docs/verdict.md)")
    accuracy_percent: float = setting(1.25, "the sensor's stated accuracy (its calibration certificate), per axis: the "
                                      "sensor line warns beyond it and fails beyond twice it", unit="%", low=0.01,
                                      high=50.0)


@cell_section("tool")
class ToolConfig:
    """``[tool]``: a cylinder along the flange z axis enclosing the sensor and the tool (collision checks); where the
    sensor measures and what it cannot weigh (ftacq bridge)."""

    radius_m: float = setting(0.05, "radius of a cylinder along the flange z axis enclosing sensor and tool",
                              unit="m", low=0.0, high=0.5, edit=True)
    length_m: float = setting(0.1, "length of that cylinder from the flange", unit="m", low=0.0, high=1.0,
                              edit=True)
    sensor_offset_m: tuple[float, float, float] | None = setting(
        None, "sensor origin in the flange frame [x, y, z], from the adapter drawing (compensation while the arm "
        "moves, the UR payload export, the measuring point ftacq bridge declares; absent = at the flange)",
        kind="vec3", unit="m", low=-0.5, high=0.5, optional=True, example=[0.0, 0.0, 0.035], edit=True)
    sensor_body_mass_kg: float = setting(0.0, "mass between the flange and the sensor's measuring plane (adapter and "
                                         "sensor body, which the sensor cannot weigh); part of the payload ftacq "
                                         "bridge sets", unit="kg", low=0.0, high=20.0)
    reference_mass_kg: float | None = setting(
        None, "the tool's mass weighed on a scale (or a calibrated weight on the flange): fixes the sensor check's "
        "absolute gain scale (absent = only the gains' ratios are checked)", kind="float", unit="kg", low=0.001,
        high=100.0, optional=True, example=1.35)
    name: str | None = setting(None, "the tool's name, recorded in calibration.json (provenance; see "
                               "docs/drift-and-tare.md)", kind="str", optional=True, example="gripper-A")


@cell_section("poses")
class PosesConfig:
    """``[poses]``: the pose sets of a calibration run (see :mod:`ftacq.posesets`)."""

    special: bool = setting(True, "include the 24 special orientations (set A; SROM needs all 24)")
    random_count: int = setting(24, "random orientations within the cone used for identification (set E)",
                                low=0, high=1000)
    validation_count: int = setting(12, "held-out validation orientations, never identified on (set V)",
                                    low=0, high=1000)
    cone_half_angle_deg: float = setting(40.0, "half-angle of the cone of E and V tool axes", unit="degrees",
                                         low=0.0, high=90.0)
    center_m: tuple[float, float, float] | None = setting(
        None, "centre of the pose sets in the base frame [x, y, z] (absent = default for the model and mount)",
        kind="vec3", unit="m", low=-5.0, high=5.0, optional=True, example=[-0.245, -0.368, 0.368])
    nominal_rotvec: tuple[float, float, float] | None = setting(
        None, "cone axis orientation, rotation vector of base_R_flange [rx, ry, rz] (absent = tool pointing down)",
        kind="vec3", unit="rad", low=-7.0, high=7.0, optional=True, example=[3.14159, 0.0, 0.0])
    position_jitter_m: float = setting(0.0, "E/V positions vary uniformly by ± this per axis", unit="m",
                                       low=0.0, high=0.5)
    seed: int = setting(0, "random seed of the E and V sets", low=0, high=2**32 - 1)
    explicit: tuple[tuple[float, ...], ...] | None = setting(
        None, "extra identification poses [[x, y, z, rx, ry, rz], ...]", kind="poses", unit="m, rad",
        optional=True, example=[[-0.25, -0.35, 0.40, 3.14159, 0.0, 0.0]])
    require_srom: bool = setting(False, "refuse the plan unless all 24 special poses are reachable")
    min_identification_poses: int = setting(12, "fewest A + E poses the plan may proceed with", low=1, high=10000)


@cell_section("sampling")
class SamplingConfig:
    """``[sampling]``: settling, averaging and the drift check at each pose."""

    settle_time_s: float = setting(0.5, "wait at least this long after the robot reports steady", unit="s",
                                   low=0.0, high=60.0)
    settle_window_s: float = setting(0.2, "window over which the sensor's std is checked for stillness", unit="s",
                                     low=0.001, high=10.0)
    settle_force_std_n: float = setting(0.5, "settled when every force channel's std over the window is below",
                                        unit="N", low=1e-6, high=100.0)
    settle_torque_std_nm: float = setting(0.03, "... and every torque channel's std is below", unit="N·m",
                                          low=1e-6, high=10.0)
    settle_timeout_s: float = setting(10.0, "a pose that does not settle within this is a fault", unit="s",
                                      low=0.01, high=600.0)
    average_time_s: float = setting(0.5, "averaging time per pose", unit="s", low=0.001, high=600.0)
    drift_check: bool = setting(True, "revisit the first pose at the end and report the bias drift")
    drift_warn_force_n: float = setting(0.5, "warn when the force drift (norm) exceeds this", unit="N",
                                        low=0.0, high=1000.0)
    drift_warn_torque_nm: float = setting(0.02, "warn when the torque drift (norm) exceeds this", unit="N·m",
                                          low=0.0, high=100.0)
    mismatch_tolerance_force_n: float = setting(
        0.1, "model mismatch (held-out error beyond the noise, RMS per axis) accepted with a WARN", unit="N",
        low=0.0, high=1000.0)
    mismatch_tolerance_torque_nm: float = setting(0.005, "... and for the torques", unit="N·m", low=0.0, high=100.0)
    sensor_timeout_s: float = setting(2.0, "no sample for this long means the sensor went silent (fault)",
                                      unit="s", low=0.05, high=60.0)


@cell_section("output")
class OutputConfig:
    """``[output]``: where results go."""

    folder: str = setting("runs", "where run folders are created (one per run, named by date and time)")


__all__ = ["Setting", "setting", "cell_section", "CELL_SETTINGS", "SECTION_TYPES", "setting_of", "from_setting",
           "keyed_fields", "check_fields", "values_from", "RobotConfig", "SensorConfig", "ToolConfig",
           "PosesConfig", "SamplingConfig", "OutputConfig"]
