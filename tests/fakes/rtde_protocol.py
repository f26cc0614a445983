"""RTDE wire format (UR port 30004) for the simulated controller: framing, type table, packing.

Everything is big-endian. A package is ``uint16 size (incl. header) | uint8 type | payload``
(docs/protocols-ur.md, "RTDE framing"). This module is pure: no sockets, no threads.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

# Package types (docs/protocols-ur.md).
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
CONTROL_PACKAGE_START = ord("S")
CONTROL_PACKAGE_PAUSE = ord("P")
DATA_PACKAGE = ord("U")

HEADER = struct.Struct(">HB")
HEADER_SIZE = HEADER.size
MAX_PACKAGE_SIZE = 0xFFFF

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

# struct codes and element counts of each RTDE type (big-endian).
TYPE_FORMATS: dict[str, tuple[str, int]] = {
    "BOOL": ("?", 1),
    "UINT8": ("B", 1),
    "UINT32": ("I", 1),
    "INT32": ("i", 1),
    "UINT64": ("Q", 1),
    "DOUBLE": ("d", 1),
    "VECTOR3D": ("d", 3),
    "VECTOR6D": ("d", 6),
    "VECTOR6INT32": ("i", 6),
    "VECTOR6UINT32": ("I", 6),
}

_VECTOR6D_OUTPUTS = (
    "target_q target_qd target_qdd target_current target_moment actual_q actual_qd actual_current "
    "actual_current_window actual_current_as_torque joint_control_output actual_joint_voltage actual_TCP_pose "
    "actual_TCP_speed actual_TCP_force target_TCP_pose target_TCP_speed actual_TCP_acceleration "
    "target_TCP_acceleration tcp_offset wrench_calc_from_currents target_base_acceleration target_base_wrench "
    "joint_temperatures ft_raw_wrench payload_inertia"
).split()
_DOUBLE_OUTPUTS = (
    "timestamp actual_execution_time target_execution_time speed_scaling target_speed_fraction actual_momentum "
    "actual_main_voltage actual_robot_voltage actual_robot_current standard_analog_input0 standard_analog_input1 "
    "standard_analog_output0 standard_analog_output1 io_current tool_analog_input0 tool_analog_input1 "
    "tool_output_current tool_temperature tcp_force_scalar actual_robot_energy_consumed "
    "actual_robot_braking_energy_dissipated euromap67_24V_voltage euromap67_24V_current "
    "joint_position_deviation_ratio collision_detection_ratio payload speed_scaling_combined"
).split()
_VECTOR3D_OUTPUTS = "actual_tool_accelerometer elbow_position elbow_velocity target_gravity payload_cog".split()
_UINT32_OUTPUTS = (
    "robot_status_bits safety_status_bits runtime_state analog_io_types tool_mode tool_analog_input_types "
    "euromap67_input_bits euromap67_output_bits script_control_line output_bit_registers0_to_31 "
    "output_bit_registers32_to_63 input_bit_registers0_to_31 input_bit_registers32_to_63"
).split()
_INT32_OUTPUTS = "robot_mode safety_mode safety_status encoder0_raw encoder1_raw tool_output_voltage time_scale_source".split()
_UINT64_OUTPUTS = (
    "actual_digital_input_bits actual_digital_output_bits actual_configurable_digital_input_bits "
    "actual_configurable_digital_output_bits control_step"
).split()
_UINT8_OUTPUTS = "tool_output_mode tool_digital_output0_mode tool_digital_output1_mode".split()

REGISTER_COUNT = 48


def _build_output_types() -> dict[str, str]:
    table: dict[str, str] = {}
    for names, type_name in ((_VECTOR6D_OUTPUTS, "VECTOR6D"), (_DOUBLE_OUTPUTS, "DOUBLE"),
                             (_VECTOR3D_OUTPUTS, "VECTOR3D"), (_UINT32_OUTPUTS, "UINT32"),
                             (_INT32_OUTPUTS, "INT32"), (_UINT64_OUTPUTS, "UINT64"), (_UINT8_OUTPUTS, "UINT8")):
        for name in names:
            table[name] = type_name
    table["joint_mode"] = "VECTOR6INT32"
    for n in range(REGISTER_COUNT):
        for prefix in ("output", "input"):
            table[f"{prefix}_int_register_{n}"] = "INT32"
            table[f"{prefix}_double_register_{n}"] = "DOUBLE"
    for n in range(64, 128):
        table[f"output_bit_register_{n}"] = "BOOL"
        table[f"input_bit_register_{n}"] = "BOOL"
    return table


def _build_input_types() -> dict[str, str]:
    table: dict[str, str] = {}
    for n in range(REGISTER_COUNT):
        table[f"input_int_register_{n}"] = "INT32"
        table[f"input_double_register_{n}"] = "DOUBLE"
    for n in range(64, 128):
        table[f"input_bit_register_{n}"] = "BOOL"
    table.update({
        "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32",
        "speed_slider_mask": "UINT32", "speed_slider_fraction": "DOUBLE",
        "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
        "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
        "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8",
        "standard_analog_output_mask": "UINT8", "standard_analog_output_type": "UINT8",
        "standard_analog_output_0": "DOUBLE", "standard_analog_output_1": "DOUBLE",
        "external_force_torque": "VECTOR6D",
    })
    return table


OUTPUT_TYPES: dict[str, str] = _build_output_types()
"""Output variable name → RTDE type name (the names and types UR controllers publish)."""

INPUT_TYPES: dict[str, str] = _build_input_types()
"""Input variable name → RTDE type name (the controller's input fields)."""


def frame(package_type: int, payload: bytes = b"") -> bytes:
    """Return one package: size header, type byte, payload."""
    size = HEADER_SIZE + len(payload)
    if size > MAX_PACKAGE_SIZE:
        raise ValueError(f"RTDE package too large: {size} bytes")
    return HEADER.pack(size, package_type) + payload


def split_names(payload: bytes) -> list[str]:
    """Return the variable names of an O/I request's comma-separated list, dropping empty ones (ur_rtde
    appends a trailing comma)."""
    return [name.strip() for name in payload.decode("ascii", "replace").split(",") if name.strip()]


@dataclass(frozen=True)
class Recipe:
    """An output or input recipe: names, their RTDE types, and the struct that packs them in order.

    ``known`` is False when a name is not in the table (the reply then holds NOT_FOUND and the recipe is unusable).
    """

    recipe_id: int
    names: tuple[str, ...]
    types: tuple[str, ...]
    codec: struct.Struct
    counts: tuple[int, ...]
    known: bool

    @classmethod
    def build(cls, recipe_id: int, names: list[str], table: dict[str, str]) -> "Recipe":
        types = tuple(table.get(name, NOT_FOUND) for name in names)
        known = NOT_FOUND not in types
        fmt, counts = ">", []
        for type_name in types:
            code, count = TYPE_FORMATS.get(type_name, ("", 0))
            fmt += code * count
            counts.append(count)
        return cls(recipe_id, tuple(names), types, struct.Struct(fmt), tuple(counts), known)

    def setup_reply(self) -> bytes:
        """Payload of the O/I reply: recipe id then the comma-separated types."""
        return bytes([self.recipe_id & 0xFF]) + ",".join(self.types).encode("ascii")

    def pack(self, flat_values: list) -> bytes:
        """Return a DATA_PACKAGE payload: recipe id then ``flat_values`` packed in recipe order."""
        return bytes([self.recipe_id & 0xFF]) + self.codec.pack(*flat_values)

    def unpack_partial(self, body: bytes) -> dict[str, object]:
        """Decode a client data package body (after the recipe id) into name → value.

        Fields that are not complete in a short package are left out (ur_rtde sends short packages for
        wrong-length vectors); scalars come back as Python numbers, vectors as tuples.
        """
        out: dict[str, object] = {}
        offset = 0
        for name, type_name, count in zip(self.names, self.types, self.counts):
            code = TYPE_FORMATS[type_name][0]
            item = struct.Struct(">" + code * count)
            if offset + item.size > len(body):
                break
            values = item.unpack_from(body, offset)
            offset += item.size
            out[name] = values[0] if count == 1 and type_name not in ("VECTOR3D", "VECTOR6D") else values
        return out


def pack_version(major: int, minor: int, bugfix: int, build: int) -> bytes:
    """Payload of the GET_URCONTROL_VERSION reply (4 × uint32)."""
    return struct.pack(">IIII", major, minor, bugfix, build)


def text_message(message: str, source: str = "ftacq-fake", level: int = 3) -> bytes:
    """Payload of a protocol-v2 TEXT_MESSAGE (level 3 = info)."""
    msg, src = message.encode()[:255], source.encode()[:255]
    return bytes([len(msg)]) + msg + bytes([len(src)]) + src + bytes([level])
