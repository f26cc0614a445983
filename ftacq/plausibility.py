"""Is an identified tool physically plausible? A mass or centre of mass beyond what a wrist-mounted tool has is a
unit mistake far more often than a tool: refuse it at identification and name the likely cause.

The bounds are deliberately wide (a long pole on a heavy arm passes): PLAUSIBLE_CENTER_OF_MASS_M from the sensor,
PLAUSIBLE_MASS_KG. The usual mistakes scale the centre of mass c = T/F by a factor far outside them:

- torque in N·mm read as N·m: c × 1000 (a 28 mm offset reads as 28 m);
- torque in lbf·in read as N·m: c × 8.85; in kgf·cm: c × 10.2;
- force in kN read as N: mass ÷ 1000 and c × 1000; force in lbf or kgf: mass × 0.22 or 0.10.

:func:`check_tool` is called by ``ftacq.identification.identify`` after the fit; the calibration writer and
reader share the looser file bounds of :mod:`ftacq.calfile` (a file ``identify`` writes always loads).
"""

from __future__ import annotations

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2
from ftacq.errors import IdentificationError
from ftacq.units import FORCE_UNITS, TORQUE_UNITS

PLAUSIBLE_CENTER_OF_MASS_M = 3.0
"""No wrist-mounted tool has its centre of mass further than this from the sensor (the paper's own numerical
examples, Table I, go to 2 m; a real tool's 10-300 mm read in N·mm as N·m lands at 10-300 m)."""
PLAUSIBLE_MASS_KG = 500.0
"""No wrist sensor carries a tool heavier than this (the heaviest arms' payloads are a few hundred kg)."""

_TORQUE_SUSPECTS = ("N-mm", "kgf-cm", "lbf-in")
"""Torque units that read as N·m give a centre of mass too far out, most likely first."""


def tool_problem(mass_kg: float, center_of_mass_m: np.ndarray) -> str | None:
    """Return why a tool of this mass and centre of mass (sensor frame, m) is implausible, with the likely unit
    mistake and the way to declare the right unit; None when it is plausible."""
    distance = float(np.linalg.norm(center_of_mass_m))
    if distance > PLAUSIBLE_CENTER_OF_MASS_M:
        causes = []
        for unit in _TORQUE_SUSPECTS:
            if distance * TORQUE_UNITS[unit] <= PLAUSIBLE_CENTER_OF_MASS_M:
                causes.append(f"torque in {unit}? ({distance * TORQUE_UNITS[unit] * 1000:.1f} mm if so; declare it "
                              f"with --torque-unit {unit} or columns tx_{unit.replace('-', '')}…)")
                break
        if mass_kg < 0.05 and distance / FORCE_UNITS["kN"] <= PLAUSIBLE_CENTER_OF_MASS_M:
            causes.append("force in kN? (declare it with --force-unit kN)")
        cause = "; ".join(causes) if causes else "torque or force columns in another unit, or swapped columns?"
        return (f"the tool's centre of mass is {distance:.3g} m from the sensor (mass {mass_kg:.4g} kg), beyond the "
                f"{PLAUSIBLE_CENTER_OF_MASS_M:g} m of any wrist-mounted tool: {cause}")
    if mass_kg > PLAUSIBLE_MASS_KG:
        return (f"the tool's mass is {mass_kg:.4g} kg (weight {mass_kg * STANDARD_GRAVITY_M_S2:.4g} N), beyond the "
                f"{PLAUSIBLE_MASS_KG:g} kg a wrist sensor carries: force in another unit (mN, gf) or raw counts?")
    return None


def check_tool(mass_kg: float, center_of_mass_m: np.ndarray) -> None:
    """Raise IdentificationError naming the likely cause when the tool is implausible (:func:`tool_problem`)."""
    problem = tool_problem(mass_kg, center_of_mass_m)
    if problem is not None:
        raise IdentificationError(problem)


__all__ = ["PLAUSIBLE_CENTER_OF_MASS_M", "PLAUSIBLE_MASS_KG", "check_tool", "tool_problem"]
