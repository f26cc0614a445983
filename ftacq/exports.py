"""Calibration exports the next system takes: the UR controller's payload and a ROS 2 parameters file.

Frames (docs/exports.md): the calibration's vectors are in the sensor frame; ``sensor_rotation`` is
``sensor_R_flange``; ``sensor_offset_m`` (optional key, CELL.toml ``tool.sensor_offset_m``, from the adapter
drawing) is the sensor origin in the flange frame, ``flange_p_sensor``; ``inertia_kg_m2`` (optional) is the
tool's 3×3 inertia about its centre of mass in the sensor axes.

- **UR payload** (``ur``): the controller wants the mass, the centre of gravity in the tool-flange frame (metres from
  the tool mount) and, since PolyScope 5.10, the inertia matrix about the centre of gravity with the axes of the
  tool flange, as [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] (the entries of that 3×3 matrix). So
  ``cog_flange = flange_p_sensor + flange_R_sensor @ center_of_mass`` and
  ``I_flange = flange_R_sensor @ I_sensor @ flange_R_sensorᵀ`` (flange_R_sensor = sensor_rotationᵀ).
- **ROS 2** (``ros2``): parameters for ros2_controllers' force_torque_sensor_broadcaster with a filter chain whose
  one filter is control_toolbox's GravityCompensation (``control_filters/GravityCompensationWrench``): the
  broadcaster adds ``offset`` (so offset = −bias), the filter subtracts ``tool.mass · tool.gravity_field`` turned
  into the sensor frame by TF and ``tool.CoG`` × that force. Together: raw − bias − gravity wrench, this
  package's compensation (ftacq.calibration).

Each writer maps a :class:`ftacq.calibration.Calibration` to the file's text; they are rows of the writer
table, :data:`ftacq.calfile.WRITERS`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftacq.calibration import Calibration
from ftacq.errors import InputError

UR_FORMAT = "ftacq-ur-payload"
UR_FORMAT_VERSION = 1
UR_MAX_INERTIA_KG_M2 = 133.0
"""The controller refuses inertia entries beyond ± this (its script manual); Ixx, Iyy, Izz must not be negative."""
ROS2_SENSOR_FRAME = "ft_sensor"
ROS2_FLANGE_FRAME = "tool0"
"""ur_description's frame of the tool flange as the controller reports it (z out of the flange)."""
ROS2_BASE_FRAME = "base"
"""ur_description's frame of the controller's base (the frame of the RTDE poses and of ``gravity_base``)."""
ROS2_BROADCASTER = "force_torque_sensor_broadcaster"
ROS2_FILTER_TYPE = "control_filters/GravityCompensationWrench"
ROS2_VERSIONS_FOLLOWED = ("control_toolbox 5.2+ (GravityCompensation filter: tool.CoG, tool.mass, tool.gravity_field)"
                          "; ros2_controllers force_torque_sensor_broadcaster with offset.* and sensor_filter_chain "
                          "(Jazzy/Kilted releases)")


def sensor_offset_m(calibration: Calibration) -> np.ndarray | None:
    """Return the sensor origin in the flange frame, m (3,), or None when the calibration does not know it."""
    value = getattr(calibration, "sensor_offset", None)  # the model field (calibration.json version 2)
    if value is None:
        value = calibration.metadata.get("sensor_offset_m")
    return None if value is None else np.asarray(value, dtype=float).reshape(3)


def inertia_kg_m2(calibration: Calibration) -> np.ndarray | None:
    """Return the tool's inertia about its centre of mass in the sensor axes (3, 3) kg·m², or None."""
    value = getattr(calibration, "inertia", None)  # the model field (calibration.json version 2)
    if value is None:
        value = calibration.metadata.get("inertia_kg_m2")
    return None if value is None else np.asarray(value, dtype=float).reshape(3, 3)


@dataclass(frozen=True)
class URPayload:
    """The payload as the UR controller takes it (tool-flange frame, SI units).

    Attributes:
        mass_kg: the tool's mass.
        cog_flange_m: centre of gravity from the tool mount, flange axes, m.
        inertia_flange_kg_m2: [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the centre of gravity, flange axes, or None.
    """

    mass_kg: float
    cog_flange_m: np.ndarray
    inertia_flange_kg_m2: np.ndarray | None = None

    def urscript(self) -> str:
        """Return the URScript line that sets this payload (``set_target_payload``, PolyScope 5.10+)."""
        cog = ", ".join(f"{v:.5f}" for v in self.cog_flange_m)
        line = f"set_target_payload({self.mass_kg:.4f}, [{cog}]"
        if self.inertia_flange_kg_m2 is not None:
            line += ", [" + ", ".join(f"{v:.6g}" for v in self.inertia_flange_kg_m2) + "]"
        return line + ")"


def ur_payload(calibration: Calibration) -> URPayload:
    """Return the calibration's payload in the UR flange frame (module docstring).

    Raises InputError without ``sensor_offset_m``: the centre of gravity is known only in the sensor frame until
    the sensor's place on the flange is given (:func:`with_sensor_offset`).
    """
    offset = sensor_offset_m(calibration)
    if offset is None:
        raise InputError("the calibration has no sensor_offset_m (the sensor origin in the flange frame, from the "
                         "adapter drawing): set tool.sensor_offset_m in CELL.toml and calibrate again, or give "
                         "--sensor-offset-m X Y Z (metres)")
    flange_R_sensor = np.asarray(calibration.sensor_rotation).T
    cog = offset + flange_R_sensor @ np.asarray(calibration.center_of_mass)
    inertia = inertia_kg_m2(calibration)
    flat = None
    if inertia is not None:
        matrix = flange_R_sensor @ inertia @ flange_R_sensor.T
        flat = np.array([matrix[0, 0], matrix[1, 1], matrix[2, 2], matrix[0, 1], matrix[0, 2], matrix[1, 2]])
        if np.any(flat[:3] < 0) or np.any(np.abs(flat) > UR_MAX_INERTIA_KG_M2):
            raise InputError(f"inertia_kg_m2: {np.round(flat, 6).tolist()} kg·m² in the flange axes is outside what "
                             f"the controller accepts (Ixx, Iyy, Izz ≥ 0, every entry within ±{UR_MAX_INERTIA_KG_M2:g})")
    return URPayload(calibration.mass_kg, cog, flat)


def _source(calibration: Calibration) -> dict[str, Any]:
    meta = calibration.metadata
    verdict = meta.get("verdict") or {}
    return {"created_utc": meta.get("created_utc"), "run_folder": meta.get("run_folder"),
            "verdict": verdict.get("status"), "software_version": meta.get("software_version")}


def ur_payload_text(calibration: Calibration) -> str:
    """The ``ur`` export: JSON with the URScript line and the values, frames stated."""
    payload = ur_payload(calibration)  # InputError without the sensor offset
    offset = sensor_offset_m(calibration)
    assert offset is not None, "ur_payload refuses a calibration without sensor_offset_m"
    document = {
        "format": UR_FORMAT,
        "version": UR_FORMAT_VERSION,
        "urscript": payload.urscript(),
        "mass_kg": round(payload.mass_kg, 6),
        "cog_flange_m": [round(float(v), 7) for v in payload.cog_flange_m],
        "inertia_kg_m2": None if payload.inertia_flange_kg_m2 is None
        else [float(f"{v:.6g}") for v in payload.inertia_flange_kg_m2],
        "convention": "cog_flange_m: centre of gravity from the tool mount, tool-flange axes; inertia_kg_m2: "
                      "[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the centre of gravity, tool-flange axes (null: the "
                      "calibration has no inertia and the controller uses zeros)",
        "sensor_offset_m": [float(v) for v in offset],
        "mass_sigma_kg": calibration.uncertainty.get("mass_kg"),
        "source": _source(calibration),
    }
    return json.dumps(document, indent=2) + "\n"


def _quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(rotation, dtype=float)).as_quat()


def _yaml_list(values) -> str:
    return "[" + ", ".join(f"{float(v) + 0.0:.7g}" for v in values) + "]"  # + 0.0: no "-0"


def ros2_parameters_text(calibration: Calibration) -> str:
    """The ``ros2`` export: a parameters YAML for the broadcaster and its gravity-compensation filter."""
    mass = calibration.mass_kg
    gravity_field = np.asarray(calibration.gravity_base) / max(mass, 1e-12)  # m/s², base frame
    bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
    offset = sensor_offset_m(calibration)
    flange_R_sensor = np.asarray(calibration.sensor_rotation).T
    q = _quaternion_xyzw(flange_R_sensor)
    source = _source(calibration)
    translation = offset if offset is not None else np.zeros(3)
    lines = [
        "# ftacq calibration for ROS 2: force_torque_sensor_broadcaster + control_toolbox GravityCompensation.",
        f"# Parameter names as in {ROS2_VERSIONS_FOLLOWED}.",
        f"# From the calibration created {source['created_utc']} (verdict {source['verdict']}).",
        "# Rename the top-level key to your controller's name in the controller_manager configuration, and set",
        f"# sensor_name to your hardware's sensor. The filter needs the TF frame '{ROS2_SENSOR_FRAME}' (the sensor axes):",
        f"#   ros2 run tf2_ros static_transform_publisher --x {translation[0]:.6g} --y {translation[1]:.6g} "
        f"--z {translation[2]:.6g} --qx {q[0]:.9f} --qy {q[1]:.9f} --qz {q[2]:.9f} --qw {q[3]:.9f} "
        f"--frame-id {ROS2_FLANGE_FRAME} --child-frame-id {ROS2_SENSOR_FRAME}",
    ]
    if offset is None:
        lines.append("#   (translation unknown: the calibration has no sensor_offset_m; the rotation is exact and the "
                     "gravity compensation does not depend on the translation)")
    lines += [
        f"{ROS2_BROADCASTER}:",
        "  ros__parameters:",
        f"    sensor_name: {ROS2_SENSOR_FRAME}",
        f"    frame_id: {ROS2_SENSOR_FRAME}",
        "    offset:  # added to every reading: minus the identified biases (N, N·m, sensor frame)",
        "      force: {" + ", ".join(f"{a}: {-b:.7g}" for a, b in zip("xyz", bias[:3])) + "}",
        "      torque: {" + ", ".join(f"{a}: {-b:.7g}" for a, b in zip("xyz", bias[3:])) + "}",
        "    sensor_filter_chain:",
        "      filter1:",
        "        name: gravity_compensation",
        f"        type: {ROS2_FILTER_TYPE}",
        "        params:",
        f"          world_frame: {ROS2_BASE_FRAME}",
        f"          sensor_frame: {ROS2_SENSOR_FRAME}",
        "          tool:",
        f"            CoG: {_yaml_list(calibration.center_of_mass)}  # centre of mass, sensor frame, m",
        f"            mass: {mass:.7g}  # kg",
        f"            gravity_field: {_yaml_list(gravity_field)}  # m/s², {ROS2_BASE_FRAME} frame (identified base tilt)",
    ]
    return "\n".join(lines) + "\n"


def with_sensor_offset(calibration: Calibration, offset_m) -> Calibration:
    """Return the calibration with ``sensor_offset_m`` (3,) m set (e.g. from the command line)."""
    from dataclasses import fields, replace

    offset = [float(v) for v in np.asarray(offset_m, dtype=float).reshape(3)]
    if any(f.name == "sensor_offset" for f in fields(calibration)):
        return replace(calibration, sensor_offset=np.array(offset))
    metadata = dict(calibration.metadata)
    metadata["sensor_offset_m"] = offset
    return replace(calibration, metadata=metadata)


__all__ = ["URPayload", "ur_payload", "ur_payload_text", "ros2_parameters_text", "sensor_offset_m", "inertia_kg_m2",
           "with_sensor_offset", "ROS2_VERSIONS_FOLLOWED"]
