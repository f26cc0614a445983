"""Procedures: pose sets and planning, the calibration procedure, the live monitor.

The public names (:data:`__all__`) are loaded lazily: ``import procedures`` imports no procedure (nor Pinocchio);
the first use of a name imports its module.
"""

from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "PlanSettings": "procedures.plan_settings",
    "Plan": "procedures.plan",
    "make_plan": "procedures.plan",
    "format_plan": "procedures.plan",
    "home_configuration_rad": "procedures.plan",
    "CalibrationProcedure": "procedures.calibration_procedure",
    "ProcedureOptions": "procedures.calibration_procedure",
    "ProcedureResult": "procedures.calibration_procedure",
    "RunFolder": "procedures.run_folder",
    "RunFolderWriter": "procedures.run_folder",
    "LiveMonitor": "procedures.monitor",
}
"""Public name → the module defining it."""

__all__ = list(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'procedures' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
