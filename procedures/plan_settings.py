"""The settings a pose plan depends on: the ``[robot]``, ``[tool]``, ``[poses]`` and part of the ``[sampling]`` keys
of CELL.toml, flattened into one value that the plan JSON stores (``--resume`` re-plans nothing).

Every field takes one declared key (:func:`ftacq.settings.from_setting`): its default and its range come from
:mod:`ftacq.settings`, so they cannot disagree with ``CELL.toml``'s. The one rule across keys checked here: the
settings must ask for at least one identification pose.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any

from ftacq.errors import ConfigError
from ftacq.kinematics import URModel, ur_model
from ftacq.settings import check_fields, from_setting, setting_of, values_from


@dataclass(frozen=True)
class PlanSettings:
    """Everything the plan depends on (SI units; each field is the CELL.toml key named in its declaration).

    Attributes:
        model: UR model name ("UR5e"…) (robot.model). mount: "floor", "wall" or "ceiling" (robot.mount).
        center_m: centre of the pose sets in the base frame (3,), m; None = the model's and mount's default
            (``procedures.plan.default_center_m``, and alternatives if that does not reach every pose).
        special: include the 24 special orientations (A set). random_count: size of the E set.
        validation_count: size of the V set. cone_half_angle_deg: cone of the E and V tool axes, degrees.
        nominal_rotvec: nominal orientation of the cone (rotation vector of base_R_flange, rad); None = tool down.
        position_jitter_m: E/V positions move uniformly within ± this per axis, m. seed: random seed.
        tool_radius_m, tool_length_m: bounding cylinder of sensor + tool along the flange z axis, m.
        table_margin_m: clearance above the mounting surface, m.
        joint_speed_rad_s, joint_acceleration_rad_s2: moveJ speed and acceleration.
        settle_time_s: expected settle time per pose (estimate only). average_time_s: averaging time per pose.
        explicit_poses: extra user poses (N, 6) [x, y, z, rx, ry, rz] used for identification, or None.
        min_identification_poses: fewest A + E poses to proceed. require_srom: refuse unless all 24 A remain.
        drift_check: the executor revisits the first pose at the end (counted in the duration estimate).
        clearance_m: link-link and tool-link clearance beyond the capsule radii, m.
    """

    model: str = from_setting("robot.model")
    mount: str = from_setting("robot.mount")
    center_m: tuple[float, float, float] | None = from_setting("poses.center_m")
    special: bool = from_setting("poses.special")
    random_count: int = from_setting("poses.random_count")
    validation_count: int = from_setting("poses.validation_count")
    cone_half_angle_deg: float = from_setting("poses.cone_half_angle_deg")
    nominal_rotvec: tuple[float, float, float] | None = from_setting("poses.nominal_rotvec")
    position_jitter_m: float = from_setting("poses.position_jitter_m")
    seed: int = from_setting("poses.seed")
    tool_radius_m: float = from_setting("tool.radius_m")
    tool_length_m: float = from_setting("tool.length_m")
    table_margin_m: float = from_setting("robot.table_margin_m")
    joint_speed_rad_s: float = from_setting("robot.joint_speed_rad_s")
    joint_acceleration_rad_s2: float = from_setting("robot.joint_acceleration_rad_s2")
    settle_time_s: float = from_setting("sampling.settle_time_s")
    average_time_s: float = from_setting("sampling.average_time_s")
    explicit_poses: tuple[tuple[float, ...], ...] | None = from_setting("poses.explicit")
    min_identification_poses: int = from_setting("poses.min_identification_poses")
    require_srom: bool = from_setting("poses.require_srom")
    drift_check: bool = from_setting("sampling.drift_check")
    clearance_m: float = from_setting("robot.clearance_m")

    def __post_init__(self) -> None:
        model = setting_of("robot.model").check(self.model)
        for name, value in check_fields(self, model).items():  # normalised: floats, ints, tuples
            object.__setattr__(self, name, value)
        if not (self.special or self.random_count or self.explicit_poses):
            raise ConfigError("poses: no identification poses (special = false, random_count = 0, no explicit poses)")

    @property
    def ur(self) -> URModel:
        """The UR model these settings name."""
        return ur_model(self.model)

    @classmethod
    def from_config(cls, config: Any) -> "PlanSettings":
        """Build from a configuration with one attribute per CELL.toml section (:class:`ftacq.app.config.CellConfig`)."""
        return cls(**values_from(config, cls))

    def to_dict(self) -> dict:
        """Return a JSON-ready dict of the settings."""
        out = asdict(self)
        for key, value in out.items():
            if isinstance(value, tuple):
                out[key] = json.loads(json.dumps(value))
        return out

    @staticmethod
    def from_dict(data: dict) -> "PlanSettings":
        """Rebuild settings from :meth:`to_dict`; unknown keys raise ConfigError naming them."""
        known = {f.name for f in fields(PlanSettings)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"plan settings: unknown key(s) {', '.join(unknown)}")
        return PlanSettings(**data)


__all__ = ["PlanSettings"]
