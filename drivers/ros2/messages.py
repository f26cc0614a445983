"""ROS 2 messages ftacq publishes, as Cyclone DDS types with ROS 2's own type names, and their ``.msg`` text.

ROS 2 maps a message ``pkg/msg/Type`` to the DDS type ``pkg::msg::dds_::Type_`` with the fields of the ``.msg`` in
its order, serialized as plain CDR (XCDR1, little endian); a service ``pkg/srv/Srv`` to the types
``pkg::srv::dds_::Srv_Request_`` and ``Srv_Response_``. The definitions below are ROS 2's (Humble and Jazzy:
common_interfaces, rcl_interfaces), field for field. :data:`DEFINITIONS` holds each message's definition as
rosbag2 writes it into an MCAP schema (``ros2msg``: the message's ``.msg``, then every nested type after a line of
80 ``=`` and ``MSG: pkg/Type``).

Services as rmw_cyclonedds_cpp puts them on the wire: the request and the reply samples start with a request
header, the client's request-writer instance handle (uint64) and a sequence number (int64), before the request's
or response's own fields; the reply repeats the request's header (``rmw_send_request``, ``rmw_send_response``).
An empty request (``std_srvs/srv/Trigger``) has ROS 2's one placeholder field ``uint8
structure_needs_at_least_one_member``.
"""

# (no `from __future__ import annotations`: Cyclone DDS reads the field types from the annotations)

from dataclasses import dataclass, field

import cyclonedds.idl as idl
import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types


def dds_type_name(ros_type: str) -> str:
    """``geometry_msgs/msg/WrenchStamped`` → ``geometry_msgs::msg::dds_::WrenchStamped_`` (ROS 2's DDS mapping)."""
    package, kind, name = ros_type.split("/")
    return f"{package}::{kind}::dds_::{name}_"


@dataclass
@annotate.final
class Time(idl.IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    """builtin_interfaces/msg/Time: seconds and nanoseconds since the UNIX epoch (ROS time = the system clock)."""

    sec: types.int32 = 0
    nanosec: types.uint32 = 0


@dataclass
@annotate.final
class Header(idl.IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
@annotate.final
class Vector3(idl.IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: types.float64 = 0.0
    y: types.float64 = 0.0
    z: types.float64 = 0.0


@dataclass
@annotate.final
class Wrench(idl.IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3 = field(default_factory=Vector3)
    torque: Vector3 = field(default_factory=Vector3)


@dataclass
@annotate.final
class WrenchStamped(idl.IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header = field(default_factory=Header)
    wrench: Wrench = field(default_factory=Wrench)


@dataclass
@annotate.final
class String(idl.IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
@annotate.final
class JointState(idl.IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: types.sequence[str] = field(default_factory=list)
    position: types.sequence[types.float64] = field(default_factory=list)
    velocity: types.sequence[types.float64] = field(default_factory=list)
    effort: types.sequence[types.float64] = field(default_factory=list)


@dataclass
@annotate.final
class TriggerRequest(idl.IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    """std_srvs/srv/Trigger's request as rmw_cyclonedds_cpp sends it (module docstring)."""

    guid: types.uint64 = 0  # the client's request writer (its instance handle)
    seq: types.int64 = 0  # the request's sequence number
    structure_needs_at_least_one_member: types.uint8 = 0


@dataclass
@annotate.final
class TriggerResponse(idl.IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    """std_srvs/srv/Trigger's response as rmw_cyclonedds_cpp sends it: the request's header, then the fields."""

    guid: types.uint64 = 0  # the client's request writer (its instance handle)
    seq: types.int64 = 0  # the request's sequence number
    success: bool = False
    message: str = ""


def discovery_types(gid_bytes: int) -> tuple[type, type, type]:
    """rmw_dds_common's ``Gid``, ``NodeEntitiesInfo`` and ``ParticipantEntitiesInfo`` with a ``Gid`` of
    ``gid_bytes`` (:data:`ftacq.ros2_names.GID_BYTES`: 24 up to Humble, 16 since Iron), the message every ROS 2 node
    sends on ``ros_discovery_info`` (:class:`drivers.ros2.node.NodeAnnouncer`)::

        Gid:                     char[24] data (Humble) | char[16] data (Iron, Jazzy)
        NodeEntitiesInfo:        string<=256 node_namespace, string<=256 node_name, Gid[] reader_gid_seq,
                                 Gid[] writer_gid_seq
        ParticipantEntitiesInfo: Gid gid, NodeEntitiesInfo[] node_entities_info_seq

    ``char`` is one byte on the wire (a ``uint8`` here)."""
    cached = _DISCOVERY_TYPES.get(gid_bytes)
    if cached is not None:
        return cached

    @dataclass
    @annotate.final
    class Gid(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: types.array[types.uint8, gid_bytes] = field(default_factory=lambda: [0] * gid_bytes)

    @dataclass
    @annotate.final
    class NodeEntitiesInfo(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: types.bounded_str[256] = ""
        node_name: types.bounded_str[256] = ""
        reader_gid_seq: types.sequence[Gid] = field(default_factory=list)
        writer_gid_seq: types.sequence[Gid] = field(default_factory=list)

    @dataclass
    @annotate.final
    class ParticipantEntitiesInfo(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid = field(default_factory=Gid)
        node_entities_info_seq: types.sequence[NodeEntitiesInfo] = field(default_factory=list)

    made = _DISCOVERY_TYPES[gid_bytes] = (Gid, NodeEntitiesInfo, ParticipantEntitiesInfo)
    return made


_DISCOVERY_TYPES: dict[int, tuple[type, type, type]] = {}


_SEPARATOR = "=" * 80
_TIME = "int32 sec\nuint32 nanosec\n"
_HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
_VECTOR3 = "float64 x\nfloat64 y\nfloat64 z\n"
_WRENCH = "Vector3  force\nVector3  torque\n"


def _definition(top: str, *nested: tuple[str, str]) -> str:
    return top + "".join(f"{_SEPARATOR}\nMSG: {name}\n{text}" for name, text in nested)


DEFINITIONS: dict[str, str] = {
    "geometry_msgs/msg/WrenchStamped": _definition(
        "std_msgs/Header header\nWrench wrench\n", ("std_msgs/Header", _HEADER),
        ("builtin_interfaces/Time", _TIME), ("geometry_msgs/Wrench", _WRENCH), ("geometry_msgs/Vector3", _VECTOR3)),
    "sensor_msgs/msg/JointState": _definition(
        "std_msgs/Header header\n\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
        ("std_msgs/Header", _HEADER), ("builtin_interfaces/Time", _TIME)),
    "std_msgs/msg/String": "string data\n",
}
"""ROS 2 type name → its full message definition (``ros2msg``, nested types concatenated) for MCAP schemas."""

MESSAGE_TYPES: dict[str, type] = {
    "geometry_msgs/msg/WrenchStamped": WrenchStamped,
    "sensor_msgs/msg/JointState": JointState,
    "std_msgs/msg/String": String,
}
"""ROS 2 type name → its Cyclone DDS type."""


__all__ = ["Time", "Header", "Vector3", "Wrench", "WrenchStamped", "String", "JointState", "TriggerRequest",
           "TriggerResponse", "DEFINITIONS", "MESSAGE_TYPES", "dds_type_name", "discovery_types"]
