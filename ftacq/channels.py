"""The six wrench channels, named once: forces then torques, x y z, in N and N·m (sensor frame unless said).

Every file column, table heading and message that names a channel takes its name from here.
"""

from __future__ import annotations

WRENCH_COLUMNS = ("fx", "fy", "fz", "tx", "ty", "tz")
"""The wrench's column names in files (pose records, sensor records, logs), N and N·m once converted."""
AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
"""The channels as shown to people (messages, tables, plots)."""
FORCE_AXES, TORQUE_AXES = AXES[:3], AXES[3:]
UNITS = ("N", "N", "N", "N·m", "N·m", "N·m")
"""Each channel's SI unit as shown."""
LABELS = tuple(f"{axis} [{unit}]" for axis, unit in zip(AXES, UNITS))
"""``Fx [N]`` … ``Tz [N·m]``: a channel with its unit, for table headings."""
CONTACT_COLUMNS = tuple(f"contact_{name}" for name in WRENCH_COLUMNS)
"""The compensated (contact) wrench's columns, N and N·m."""

__all__ = ["AXES", "CONTACT_COLUMNS", "FORCE_AXES", "LABELS", "TORQUE_AXES", "UNITS", "WRENCH_COLUMNS"]
