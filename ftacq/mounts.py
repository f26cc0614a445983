"""Robot mounts: the nominal ones (floor, wall, ceiling) and any tilt, the one table and parser every layer reads.

A mount fixes how the robot base frame sits in the world. The base tilt (α, β) follows the model's convention
(paper eqs 46-48, corrected): ``gravity_base = −m g [cos α sin β, −sin α, cos α cos β]``, i.e. the unit gravity
direction in the base frame is ``down_base = −R_y(β) R_x(α) e_z``. A level floor robot has (0, 0), a wall robot
(0, 90°) (gravity along base −x) and a ceiling robot (0, 180°). In every case the mounting surface is the
base-frame plane z = 0; ``surface`` names it in messages ("tool hits the table").

A mount is named by a spec string (CELL.toml ``robot.mount``, ``--mount``):

- ``floor``, ``wall``, ``ceiling``: the rows of :data:`MOUNT_TABLE`;
- ``tilted:ALPHA,BETA``: the tilt (α, β) in degrees in the convention above (α about base x first, then β
  about base y; |α| ≤ 90°); ``tilted:0,-90`` is a wall mount with gravity along base +x;
- ``gravity:X,Y,Z``: the gravity direction in the base frame (any length, normalised), e.g. the direction
  ``ftacq identify`` measured (``gravity:0.539,0.699,-0.470`` for a base tilted 62°).

A spec that is not nominal takes the surface name and the planner's default pose-set centre of the nominal mount
nearest its gravity direction (``nominal``). A new nominal mount is one row of :data:`MOUNT_TABLE` (plus its
default pose-set centre in ``procedures.plan.DEFAULT_CENTER_FRACTION``, which the planner checks at import).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mount:
    """One mount: ``name`` its spec, ``tilt_deg`` (α, β) in degrees, ``down_base`` (3,) unit gravity direction in
    the base frame, ``surface`` the mounting surface's name in messages, ``nominal`` the nominal mount (a row of
    :data:`MOUNT_TABLE`) whose defaults it takes (itself for a nominal mount)."""

    name: str
    tilt_deg: tuple[float, float]
    down_base: tuple[float, float, float]
    surface: str
    nominal: str = ""

    def __post_init__(self) -> None:
        if not self.nominal:
            object.__setattr__(self, "nominal", self.name)


MOUNT_TABLE: dict[str, Mount] = {m.name: m for m in (
    Mount("floor", (0.0, 0.0), (0.0, 0.0, -1.0), "table"),
    Mount("wall", (0.0, 90.0), (-1.0, 0.0, 0.0), "wall"),
    Mount("ceiling", (0.0, 180.0), (0.0, 0.0, 1.0), "ceiling"),
)}
"""Every nominal mount by name (the first is the default)."""

MOUNTS: tuple[str, ...] = tuple(MOUNT_TABLE)
"""The nominal mount names, for messages."""

MOUNT_FORMS = "floor, wall, ceiling, tilted:ALPHA,BETA (degrees) or gravity:X,Y,Z (base frame)"
"""Every form a mount spec takes, for help texts and messages."""

MIN_GRAVITY_DIRECTION_NORM = 1e-6
"""A ``gravity:X,Y,Z`` shorter than this has no direction."""


def down_from_tilt_deg(alpha_deg: float, beta_deg: float) -> np.ndarray:
    """Return the unit gravity direction in the base frame of a tilt (α, β) in degrees (eq. 47 divided by m g)."""
    alpha, beta = math.radians(alpha_deg), math.radians(beta_deg)
    return -np.array([math.cos(alpha) * math.sin(beta), -math.sin(alpha), math.cos(alpha) * math.cos(beta)])


def tilt_from_down_deg(down_base: np.ndarray) -> tuple[float, float]:
    """Return (α, β) in degrees of a gravity direction (corrected eq. 48: cos α ≥ 0, β in (−180°, 180°])."""
    fx, fy, fz = np.asarray(down_base, dtype=float)
    beta = math.degrees(math.atan2(-fx, -fz))
    beta = 180.0 if beta <= -180.0 else beta
    return math.degrees(math.atan2(fy, math.hypot(fx, fz))), beta


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(np.dot(a, b), -1.0, 1.0))))


def nearest_nominal(down_base: np.ndarray) -> str:
    """Return the name of the nominal mount whose gravity direction is nearest ``down_base`` (unit vector)."""
    return min(MOUNTS, key=lambda name: _angle_deg(np.array(MOUNT_TABLE[name].down_base), down_base))


def _numbers(text: str, count: int, spec: str, what: str) -> list[float]:
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"mount {spec!r}: {what}")
    return values


def mount_of(spec: str) -> Mount:
    """Return the mount a spec names (see the module docstring). Raises ValueError naming the forms."""
    text = str(spec).strip()
    key = text.lower()
    if key in MOUNT_TABLE:
        return MOUNT_TABLE[key]
    kind, sep, rest = key.partition(":")
    if sep and kind == "tilted":
        alpha, beta = _numbers(rest, 2, text, "tilted:ALPHA,BETA needs two finite angles in degrees")
        if abs(alpha) > 90.0 or abs(beta) > 360.0:
            raise ValueError(f"mount {text!r}: ALPHA must be in [-90, 90] and BETA in [-360, 360] degrees")
        down = down_from_tilt_deg(alpha, beta)
    elif sep and kind == "gravity":
        vector = np.array(_numbers(rest, 3, text, "gravity:X,Y,Z needs three finite numbers"))
        norm = float(np.linalg.norm(vector))
        if norm < MIN_GRAVITY_DIRECTION_NORM:
            raise ValueError(f"mount {text!r}: the gravity direction has no length")
        down = vector / norm
        alpha, beta = tilt_from_down_deg(down)
    else:
        raise ValueError(f"mount must be one of {MOUNT_FORMS}, got {text!r}")
    nominal = nearest_nominal(down)
    return Mount(text, (alpha, beta), (float(down[0]), float(down[1]), float(down[2])),
                 MOUNT_TABLE[nominal].surface, nominal)


def check_mount(spec: str) -> str:
    """Return the spec normalised (a nominal name in lower case, else as given) if it names a mount (ValueError)."""
    mount = mount_of(spec)
    return mount.name


def gravity_spec(vector: str) -> str:
    """The mount spec of a ``--gravity-direction X,Y,Z`` option value (checked: ValueError)."""
    spec = "gravity:" + str(vector).strip()
    return check_mount(spec)


__all__ = ["Mount", "MOUNT_TABLE", "MOUNTS", "MOUNT_FORMS", "check_mount", "down_from_tilt_deg", "gravity_spec",
           "mount_of", "nearest_nominal", "tilt_from_down_deg"]
