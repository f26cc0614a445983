"""Force and torque units of ATI devices, from the one table in :mod:`ftacq.units`; an unknown unit a device
reports is a DeviceError here (see docs/protocols-ati.md, "Units")."""

from __future__ import annotations

from ftacq import units as _units
from ftacq.errors import DeviceError
from ftacq.units import FORCE_UNIT_CODES, FORCE_UNITS, TORQUE_UNIT_CODES, TORQUE_UNITS


def canonical_unit(text: str | int, kind: str) -> str:
    """Return the unit name ("N", "N-mm", …) of a device unit string or code; raise DeviceError if unknown."""
    try:
        return _units.canonical_unit(text, kind)
    except ValueError as error:
        if kind not in ("force", "torque"):
            raise
        raise DeviceError(str(error)) from None


def si_per_unit(unit: str, kind: str) -> float:
    """Return newtons (force) or newton-metres (torque) per ``unit`` (any spelling or code)."""
    table = FORCE_UNITS if kind == "force" else TORQUE_UNITS
    return table[canonical_unit(unit, kind)]


__all__ = ["FORCE_UNITS", "TORQUE_UNITS", "FORCE_UNIT_CODES", "TORQUE_UNIT_CODES", "canonical_unit", "si_per_unit"]
