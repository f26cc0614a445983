"""The identified calibration (a frozen value type) and gravity compensation with it.

Model (paper eqs 10-13, method.md), for a contact-free pose i:

    F_i = sensor_rotation @ flange_R_base_i @ gravity_base + force_bias
    T_i = center_of_mass × (sensor_rotation @ flange_R_base_i @ gravity_base) + torque_bias

Compensation subtracts the *predicted* gravity wrench and the biases (not eq. 13's P × (F − F0), which
would remove part of a contact torque):

    g_s = sensor_rotation @ flange_R_base @ gravity_base
    F_contact = F − g_s − force_bias,   T_contact = T − center_of_mass × g_s − torque_bias

``Calibration.compensate`` handles batches (one (N, 9) @ (9, 6) product per block of samples, in place when
given ``out``); ``Calibration.compensate_sample`` is the plain-Python path for one sample (a few µs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2


COMPENSATION_BLOCK = 8192
"""Samples per block in batch compensation (keeps each block in cache)."""


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
        sensor_offset: the sensor origin in the flange frame, m (CELL.toml ``tool.sensor_offset_m``), or None.
        inertia: the tool's inertia about its centre of mass, sensor frame (3×3, kg·m²), identified from motion
            (:mod:`ftacq.dynamics`), or None: then the calibration is static only.
    """

    sensor_rotation: np.ndarray
    force_bias: np.ndarray
    torque_bias: np.ndarray
    gravity_base: np.ndarray
    center_of_mass: np.ndarray
    uncertainty: Mapping[str, Any] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)
    sensor_offset: np.ndarray | None = None
    inertia: np.ndarray | None = None
    # Precomputed compensation operators, derived from the fields above in __post_init__ (not constructor
    # arguments, not compared, not shown): gain K (6, 3), lifted L (9, 6) and −L, bias (6,), and plain-float
    # copies of K's rows, gravity_base and bias for the single-sample path.
    _gain: np.ndarray = field(init=False, repr=False, compare=False)
    _lifted: np.ndarray = field(init=False, repr=False, compare=False)
    _lifted_negative: np.ndarray = field(init=False, repr=False, compare=False)
    _bias: np.ndarray = field(init=False, repr=False, compare=False)
    _gain_rows: tuple[tuple[float, ...], ...] = field(init=False, repr=False, compare=False)
    _gravity_tuple: tuple[float, ...] = field(init=False, repr=False, compare=False)
    _bias_tuple: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name, shape in (("sensor_offset", (3,)), ("inertia", (3, 3))):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _frozen_array(getattr(self, name), shape, name))
        for name, shape in (
            ("sensor_rotation", (3, 3)),
            ("force_bias", (3,)),
            ("torque_bias", (3,)),
            ("gravity_base", (3,)),
            ("center_of_mass", (3,)),
        ):
            object.__setattr__(self, name, _frozen_array(getattr(self, name), shape, name))
        # Precomputed compensation operators (derived from the fields above).
        # Predicted wrench = K @ (flange_R_base @ gravity_base) + bias with K = [S; [c]× S] (6×3), so for a
        # batch of rotations  pred = R.reshape(N, 9) @ L + bias  with  L[(j, k), :] = K[:, j] · gravity_base[k].
        c = self.center_of_mass
        skew = np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])
        gain = np.vstack([self.sensor_rotation, skew @ self.sensor_rotation])  # (6, 3)
        lifted = np.einsum("aj,k->jka", gain, self.gravity_base).reshape(9, 6)
        bias = np.concatenate([self.force_bias, self.torque_bias])
        lifted_negative = -lifted
        for array in (gain, lifted, lifted_negative, bias):
            array.setflags(write=False)
        object.__setattr__(self, "_gain", gain)
        object.__setattr__(self, "_lifted", lifted)
        object.__setattr__(self, "_lifted_negative", lifted_negative)
        object.__setattr__(self, "_bias", bias)
        # plain-float copies for the single-sample path (no numpy call overhead)
        object.__setattr__(self, "_gain_rows", tuple(tuple(float(v) for v in row) for row in gain))
        object.__setattr__(self, "_gravity_tuple", tuple(float(v) for v in self.gravity_base))
        object.__setattr__(self, "_bias_tuple", tuple(float(v) for v in bias))

    @property
    def has_dynamics(self) -> bool:
        """True when the tool's inertia is known: the wrench can be compensated while the arm moves."""
        return self.inertia is not None

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

    def compensate(self, wrench: np.ndarray, flange_R_base: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Return the contact wrench (…, 6) [N, N·m]: reading minus predicted gravity wrench and biases.

        ``wrench`` is (6,) or (N, 6) in the sensor frame; ``flange_R_base`` is (3, 3) (one orientation for
        the whole batch) or (N, 3, 3) (one per sample). ``out`` (N, 6) float64 may be given to avoid an
        allocation (it may be ``wrench`` itself). Vectorised: one (N, 9) @ (9, 6) product per batch.
        """
        wrench = np.asarray(wrench, dtype=float)
        rotations = np.asarray(flange_R_base, dtype=float)
        if rotations.shape == (3, 3):
            predicted = self._gain @ (rotations @ self.gravity_base) + self._bias
            return np.subtract(wrench, predicted, out=out)
        if rotations.shape[-2:] != (3, 3):
            raise ValueError(f"flange_R_base: expected (3, 3) or (N, 3, 3), got {rotations.shape}")
        lead = rotations.shape[:-2]
        flat = rotations.reshape(-1, 9)
        if wrench.shape != lead + (6,):  # broadcasting case: plain arithmetic
            predicted = (flat @ self._lifted + self._bias).reshape(lead + (6,))
            return np.subtract(wrench, predicted, out=out)
        if out is None:
            out = np.empty(lead + (6,))
        if np.shares_memory(out, wrench):
            predicted = flat @ self._lifted
            predicted += self._bias
            np.subtract(wrench, predicted.reshape(lead + (6,)), out=out)
            return out
        # fastest form: out = R·(−L) + wrench − bias, in place, in cache-sized blocks (small BLAS calls also
        # stay single-threaded, which matters on a loaded machine)
        out_2d = out.reshape(-1, 6)
        wrench_2d = wrench.reshape(-1, 6)
        for start in range(0, flat.shape[0], COMPENSATION_BLOCK):
            block = slice(start, start + COMPENSATION_BLOCK)
            target = out_2d[block]
            np.matmul(flat[block], self._lifted_negative, out=target)
            target += wrench_2d[block]
            target -= self._bias
        return out

    def compensate_sample(self, wrench: "Sequence[float]", flange_R_base: "Sequence[Sequence[float]]") -> list[float]:
        """Return the contact wrench of ONE sample as a list of 6 floats [N, N·m] (fast path, plain Python).

        Same result as :meth:`compensate` for a (6,) reading and a (3, 3) rotation, without numpy's per-call
        overhead (a few µs). ``flange_R_base`` may be a nested list or a (3, 3) array.
        """
        if isinstance(flange_R_base, np.ndarray):
            flange_R_base = flange_R_base.tolist()
        if isinstance(wrench, np.ndarray):
            wrench = wrench.tolist()
        gx, gy, gz = self._gravity_tuple
        r0, r1, r2 = flange_R_base
        u0 = r0[0] * gx + r0[1] * gy + r0[2] * gz
        u1 = r1[0] * gx + r1[1] * gy + r1[2] * gz
        u2 = r2[0] * gx + r2[1] * gy + r2[2] * gz
        return [
            w - (k[0] * u0 + k[1] * u1 + k[2] * u2) - b
            for w, k, b in zip(wrench, self._gain_rows, self._bias_tuple)
        ]
