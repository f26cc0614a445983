"""Device drivers: ATI force/torque sensors (Net F/T, CAN) and Universal Robots arms (ur-rtde).

The public names (:data:`__all__`) are loaded lazily: ``import drivers`` imports no driver (nor ur-rtde or
python-can); the first use of a name imports its module.
"""

from __future__ import annotations

from ftacq.lazy import lazy_names

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


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
