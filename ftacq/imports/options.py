"""What ``ftacq import`` can be told about a recording: the choices and defaults, declared once (the CLI's options
are built from them) and light to import (the standard library only), so that ``ftacq --help`` stays fast."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ftacq.imports.robot_model import ArmModel

ORIENTATIONS = ("auto", "rotvec", "quaternion", "matrix", "joints")
"""How a recording gives the flange orientation (``auto``: joints when a robot model is given, else the form whose
default column names the header holds)."""
DEFAULT_COLUMNS = {
    "rotvec": ("rx", "ry", "rz"),
    "quaternion": ("qx", "qy", "qz", "qw"),
    "matrix": tuple(f"r{i}{j}" for i in range(1, 4) for j in range(1, 4)),
}
"""Orientation columns read when none are named (a quaternion's are put in ``quaternion_order`` by name)."""
POSITION_COLUMNS = ("x", "y", "z")
"""The flange position's columns, m, when none are named."""
QUATERNION_ORDERS = ("xyzw", "wxyz")
"""A quaternion's component order: scalar last (ROS, scipy) or first (ABB, MATLAB)."""
WRENCH_FRAMES = ("sensor", "base")
"""Frames a recording's wrenches can be in: the sensor's own (the pose record's), or the robot base frame."""


@dataclass(frozen=True)
class ImportOptions:
    """What a recording holds (see the :mod:`ftacq.imports` docstring).

    Attributes:
        orientation: one of :data:`ORIENTATIONS`.
        quaternion_order: ``xyzw`` (scalar last) or ``wxyz`` (scalar first), for the order of
            ``orientation_columns`` when they are given; with the default names (qx, qy, qz, qw) the order is
            read from the names.
        orientation_columns: the orientation's columns (default :data:`DEFAULT_COLUMNS`, or every ``q<n>`` column in
            number order for joints).
        position_columns: the flange position's columns, m (ignored with joints).
        robot: the joint model (required with ``orientation="joints"``).
        wrench_frame: ``sensor`` or ``base`` (:data:`WRENCH_FRAMES`).
        force_unit, torque_unit: the wrench units when neither a column suffix nor a header comment says.
        time_column: a column of time stamps (s), kept as the pose's averaging window.
        rename: source column name → pose-record name, applied first (names compared in lower case).
    """

    orientation: str = "auto"
    quaternion_order: str = "xyzw"
    orientation_columns: tuple[str, ...] | None = None
    position_columns: tuple[str, str, str] = POSITION_COLUMNS
    robot: ArmModel | None = None
    wrench_frame: str = "sensor"
    force_unit: str | None = None
    torque_unit: str | None = None
    time_column: str | None = None
    rename: dict[str, str] = field(default_factory=dict)


__all__ = ["DEFAULT_COLUMNS", "ImportOptions", "ORIENTATIONS", "POSITION_COLUMNS", "QUATERNION_ORDERS",
           "WRENCH_FRAMES"]
