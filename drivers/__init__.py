"""Device drivers: ATI force/torque sensors (Net F/T, CAN) and Universal Robots arms (ur-rtde).

The public names (:data:`__all__`) are loaded lazily: ``import drivers`` imports no driver (nor ur-rtde or
python-can); the first use of a name imports its module.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "open_sensor": "drivers.sensor",
    "ForceTorqueSensor": "drivers.sensor",
    "SensorInfo": "drivers.sensor",
    "WrenchBatch": "drivers.sensor",
    "WrenchAverage": "drivers.sensor",
    "Robot": "drivers.robot",
    "MotionLimits": "drivers.robot",
    "URRobot": "drivers.ur",
}
"""Public name → the module defining it."""

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'drivers' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
