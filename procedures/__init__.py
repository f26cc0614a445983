"""Procedures: pose sets and planning, the calibration procedure, the live monitor.

The public names (:data:`__all__`) are loaded lazily: ``import procedures`` imports no procedure (nor Pinocchio);
the first use of a name imports its module.
"""

from __future__ import annotations

from ftacq.lazy import lazy_names

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


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
