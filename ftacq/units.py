"""Force and torque units: one table for every driver and every file (see docs/protocols-ati.md, "Units").

ATI boxes report their configured units either as a name (``N``, ``Nm``, ``N-mm``, ``lbf-in`` …, spelled in several
ways by different firmware) or as a unit code (1-6, the same codes on the Net F/T TCP port, its HTTP pages and the
CAN board). A driver converts counts to SI once::

    wrench_si = counts × (SI per unit) / (counts per unit)

with :func:`si_per_unit`. Torque is often configured in N-mm (÷ 1000). Pose files declare their units with the
same names (``tx_Nmm``, ``# torque_unit: N-mm``, ``--torque-unit``: docs/formats.md). The drivers' wrapper
:mod:`drivers.units` turns an unknown unit into a DeviceError; here it is a ValueError.
"""

from __future__ import annotations

import re


FORCE_UNITS: dict[str, float] = {"lbf": 4.4482216152605, "N": 1.0, "klbf": 4448.2216152605, "kN": 1000.0,
                                 "kgf": 9.80665, "gf": 0.00980665}
"""Force unit name → newtons per unit."""
TORQUE_UNITS: dict[str, float] = {"lbf-in": 0.112984829027617, "lbf-ft": 1.3558179483314, "N-m": 1.0,
                                  "N-mm": 0.001, "kgf-cm": 0.0980665, "kN-m": 1000.0}
"""Torque unit name → newton-metres per unit."""
FORCE_UNIT_CODES: dict[int, str] = {1: "lbf", 2: "N", 3: "klbf", 4: "kN", 5: "kgf", 6: "gf"}
"""ATI force unit code → unit name."""
TORQUE_UNIT_CODES: dict[int, str] = {1: "lbf-in", 2: "lbf-ft", 3: "N-m", 4: "N-mm", 5: "kgf-cm", 6: "kN-m"}
"""ATI torque unit code → unit name."""

_ALIASES = {"nm": "N-m", "n-m": "N-m", "newtonmeter": "N-m", "nmm": "N-mm", "n-mm": "N-mm", "kg-cm": "kgf-cm",
            "kgcm": "kgf-cm", "kgf-cm": "kgf-cm", "knm": "kN-m", "kn-m": "kN-m", "lbfin": "lbf-in",
            "lbf-in": "lbf-in", "in-lb": "lbf-in", "inlb": "lbf-in", "in-lbf": "lbf-in", "lbfft": "lbf-ft",
            "lbf-ft": "lbf-ft", "ft-lb": "lbf-ft", "ftlb": "lbf-ft", "ft-lbf": "lbf-ft", "n": "N",
            "newton": "N", "lbf": "lbf", "lb": "lbf", "lbs": "lbf", "klbf": "klbf", "kn": "kN", "kgf": "kgf",
            "kg": "kgf", "gf": "gf", "g": "gf"}
"""Spellings seen in device pages (lower case, spaces removed) → unit name."""


def _tables(kind: str) -> tuple[dict[str, float], dict[int, str]]:
    if kind == "force":
        return FORCE_UNITS, FORCE_UNIT_CODES
    if kind == "torque":
        return TORQUE_UNITS, TORQUE_UNIT_CODES
    raise ValueError(f"unit kind {kind!r}: must be 'force' or 'torque'")


def canonical_unit(text: str | int, kind: str) -> str:
    """Return the unit name ("N", "N-mm", …) of a unit string or code; raise ValueError if unknown."""
    table, codes = _tables(kind)
    raw = str(text).strip()
    if raw.isdigit() and int(raw) in codes:
        return codes[int(raw)]
    if raw in table:
        return raw
    key = re.sub(r"[\s·.*_]", "", raw).lower().replace("–", "-")
    name = _ALIASES.get(key) or _ALIASES.get(key.replace("-", ""))
    if name in table:
        return name
    raise ValueError(f"unknown {kind} unit {text!r}: expected one of {', '.join(table)}")


def si_per_unit(unit: str, kind: str) -> float:
    """Return newtons (force) or newton-metres (torque) per ``unit`` (any spelling or code)."""
    table, _ = _tables(kind)
    return table[canonical_unit(unit, kind)]


__all__ = ["FORCE_UNITS", "TORQUE_UNITS", "FORCE_UNIT_CODES", "TORQUE_UNIT_CODES", "canonical_unit", "si_per_unit"]
