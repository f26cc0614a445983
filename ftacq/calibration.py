"""The identified calibration (a frozen value type) and gravity compensation with it.

Model (paper eqs 10-13, method.md), for a contact-free pose i:

    F_i = sensor_rotation @ flange_R_base_i @ gravity_base + force_bias
    T_i = center_of_mass × (sensor_rotation @ flange_R_base_i @ gravity_base) + torque_bias

Compensation subtracts the *predicted* gravity wrench and the biases (not eq. 13's P × (F − F0), which
would remove part of a contact torque):

    g_s = sensor_rotation @ flange_R_base @ gravity_base
    F_contact = F − g_s − force_bias,   T_contact = T − center_of_mass × g_s − torque_bias
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2


def _frozen_array(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    array = np.array(value, dtype=float)
    if array.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
    array.setflags(write=False)
    return array


@dataclass(frozen=True)
class Calibration:
    """Sensor-to-flange rotation, biases and tool gravity parameters, all SI, sensor frame unless stated.

    Attributes:
        sensor_rotation: ``sensor_R_flange`` (3×3): maps flange-frame vectors into the sensor frame (paper sR).
        force_bias: sensor force bias sF0 in N (sensor frame).
        torque_bias: sensor torque bias sT0 in N·m (sensor frame).
        gravity_base: the tool's weight as a force in the robot base frame, N (paper F_b, eq. 11).
        center_of_mass: the tool's centre of mass sP in the sensor frame, m.
        uncertainty: 1σ per parameter (same keys as the JSON file, e.g. ``force_bias``), or empty.
        metadata: method, residuals, outliers, software version, … (free-form, JSON-serialisable).
    """

    sensor_rotation: np.ndarray
    force_bias: np.ndarray
    torque_bias: np.ndarray
    gravity_base: np.ndarray
    center_of_mass: np.ndarray
    uncertainty: Mapping[str, Any] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, shape in (
            ("sensor_rotation", (3, 3)),
            ("force_bias", (3,)),
            ("torque_bias", (3,)),
            ("gravity_base", (3,)),
            ("center_of_mass", (3,)),
        ):
            object.__setattr__(self, name, _frozen_array(getattr(self, name), shape, name))

    @property
    def mass_kg(self) -> float:
        """Tool mass in kg: ‖gravity_base‖ / g (corrected eq. 46: the paper squares the norm)."""
        return float(np.linalg.norm(self.gravity_base) / STANDARD_GRAVITY_M_S2)

    @property
    def base_tilt_deg(self) -> tuple[float, float]:
        """Base tilt (α, β) in degrees from gravity_base = −m g [cos α sin β, −sin α, cos α cos β].

        Corrected eqs 46-48 (method.md): β = atan2(−f_x, −f_z), α = atan2(f_y, √(f_x² + f_z²));
        branch cos α ≥ 0, β in (−180°, 180°]. A level floor robot gives (0, 0).
        """
        fx, fy, fz = self.gravity_base
        beta = float(np.degrees(np.arctan2(-fx, -fz)))
        if beta <= -180.0:
            beta += 360.0
        alpha = float(np.degrees(np.arctan2(fy, np.hypot(fx, fz))))
        return alpha, beta

    def gravity_in_sensor(self, flange_R_base: np.ndarray) -> np.ndarray:
        """Return g_s = sensor_rotation @ flange_R_base @ gravity_base, N, for one (3, 3) or many (N, 3, 3)."""
        gravity_flange = np.asarray(flange_R_base) @ self.gravity_base
        return gravity_flange @ self.sensor_rotation.T

    def predict(self, flange_R_base: np.ndarray) -> np.ndarray:
        """Return the contact-free wrench (…, 6) [N, N·m] the sensor reads at the given orientation(s)."""
        gravity_sensor = self.gravity_in_sensor(flange_R_base)
        force = gravity_sensor + self.force_bias
        torque = np.cross(self.center_of_mass, gravity_sensor) + self.torque_bias
        return np.concatenate([force, torque], axis=-1)

    def compensate(self, wrench: np.ndarray, flange_R_base: np.ndarray) -> np.ndarray:
        """Return the contact wrench (…, 6) [N, N·m]: reading minus predicted gravity wrench and biases.

        ``wrench`` is (6,) or (N, 6) in the sensor frame; ``flange_R_base`` is (3, 3) (one orientation for
        the whole batch) or (N, 3, 3) (one per sample).
        """
        return np.asarray(wrench, dtype=float) - self.predict(flange_R_base)
