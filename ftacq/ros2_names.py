"""ROS 2 names ftacq takes from CELL.toml and the command line: a namespace, a frame name and a ROS 2 release,
checked as ROS 2 does.

A namespace is absolute (``/ftacq``, ``/cell_3/ft``): parts of ASCII letters, digits and ``_``, none starting with a
digit (ROS 2's rules for names, rcl ``rmw_validate_namespace``). A frame name (tf2, ``header.frame_id``) has no
leading ``/`` and the same characters. The namespace is also the ROS 2 node's full name (:func:`node_of_namespace`),
so the topics are the node's private ones (``~/wrench_raw``).
"""

from __future__ import annotations

NAMESPACE_FORMS = "a ROS 2 namespace such as /ftacq or /cell_3/ft (letters, digits, _; parts not starting with a digit)"
FRAME_FORMS = "a tf2 frame name such as ft_sensor (letters, digits, _ and /, no leading /)"
GID_BYTES: dict[str, int] = {"humble": 24, "iron": 16, "jazzy": 16, "kilted": 16, "rolling": 16}
"""ROS 2 release → bytes of ``rmw_dds_common/msg/Gid`` (``char[24]`` up to Humble, ``char[16]`` since Iron): the one
message ftacq sends whose layout differs between releases (``ros_discovery_info``, docs/ros2.md)."""
ROS2_DISTROS = tuple(GID_BYTES)
"""The ROS 2 releases whose nodes see ftacq's node (CELL.toml ``sensor.ros2_distro``, ``--ros2-distro``)."""
ROOT_NODE_NAME = "ftacq"
"""The node's name when its namespace is the root (``/``): its topics stay ``/wrench_raw``, ... ."""


def _valid_part(part: str) -> bool:
    return bool(part) and part.isascii() and all(c.isalnum() or c == "_" for c in part) and not part[0].isdigit()


def normalize_namespace(namespace: str) -> str:
    """``"ur5e/ft"`` or ``"/ur5e/ft/"`` → ``"/ur5e/ft"``; ``""`` or ``"/"`` → ``""`` (the root). ValueError for a name
    ROS 2 refuses."""
    parts = [part for part in str(namespace).strip().split("/") if part]
    if not all(_valid_part(part) for part in parts):
        raise ValueError(f"{namespace!r} is not {NAMESPACE_FORMS}")
    return "".join("/" + part for part in parts)


def check_namespace(namespace: str) -> str:
    """The namespace as CELL.toml keeps it: normalised, ``/`` for the root (ValueError as above)."""
    return normalize_namespace(namespace) or "/"


def node_of_namespace(namespace: str) -> tuple[str, str]:
    """The ROS 2 node (namespace, name) whose private names are under ``namespace``: ``/cell_3/ft`` → (``/cell_3``,
    ``ft``), ``/ftacq`` → (``/``, ``ftacq``); the root → (``/``, :data:`ROOT_NODE_NAME`)."""
    parent, _, name = normalize_namespace(namespace).rpartition("/")
    return parent or "/", name or ROOT_NODE_NAME


def check_frame_id(frame_id: str) -> str:
    """Return ``frame_id`` stripped if tf2 accepts it (ValueError otherwise)."""
    frame_id = str(frame_id).strip()
    if frame_id.startswith("/") or not all(_valid_part(part) for part in frame_id.split("/")):
        raise ValueError(f"{frame_id!r} is not {FRAME_FORMS}")
    return frame_id


__all__ = ["normalize_namespace", "check_namespace", "check_frame_id", "node_of_namespace", "NAMESPACE_FORMS",
           "FRAME_FORMS", "GID_BYTES", "ROS2_DISTROS", "ROOT_NODE_NAME"]
