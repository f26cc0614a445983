"""The nominal robot mounts (floor, wall, ceiling): the one table every layer reads.

A mount fixes how the robot base frame sits in the world. The base tilt (α, β) follows the model's convention
(paper eqs 46-48, corrected): ``gravity_base = −m g [cos α sin β, −sin α, cos α cos β]``, so a level floor robot
has (0, 0), a wall robot (0, 90°) and a ceiling robot (0, 180°); ``down_base`` is the unit gravity direction in
the base frame that tilt gives. In every case the mounting surface is the base-frame plane z = 0; ``surface``
names it in messages ("tool hits the table").

A new mount is one row of :data:`MOUNT_TABLE` (plus its default pose-set centre in
``procedures.plan_settings.DEFAULT_CENTER_FRACTION``, which the planner checks at import).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mount:
    """One nominal mount: ``tilt_deg`` (α, β) in degrees, ``down_base`` (3,) unit gravity direction in the base
    frame, ``surface`` the mounting surface's name in messages."""

    name: str
    tilt_deg: tuple[float, float]
    down_base: tuple[float, float, float]
    surface: str


MOUNT_TABLE: dict[str, Mount] = {m.name: m for m in (
    Mount("floor", (0.0, 0.0), (0.0, 0.0, -1.0), "table"),
    Mount("wall", (0.0, 90.0), (-1.0, 0.0, 0.0), "wall"),
    Mount("ceiling", (0.0, 180.0), (0.0, 0.0, 1.0), "ceiling"),
)}
"""Every mount by name (the first is the default)."""

MOUNTS: tuple[str, ...] = tuple(MOUNT_TABLE)
"""The mount names, for choices and messages."""


def mount_of(name: str) -> Mount:
    """Return the mount called ``name``. Raises ValueError listing the known ones."""
    try:
        return MOUNT_TABLE[name]
    except KeyError:
        raise ValueError(f"mount must be one of {', '.join(MOUNTS)}, got {name!r}") from None


__all__ = ["Mount", "MOUNT_TABLE", "MOUNTS", "mount_of"]
