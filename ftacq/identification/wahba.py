"""The sensor rotation and force bias given the weight in the base frame: Wahba / Umeyama (eqs 35-42).

With g = gravity_base fixed, F_i = S R_i g + F0 is a rigid fit of the flange-frame vectors a_i = R_i g to
the sensor-frame forces. Centring removes F0 (eqs 37-38); with D = Σ w_i (F_i − F̄)(a_i − ā)ᵀ = U Σ Vᵀ the
rotation is S = U diag(1, 1, det U det V) Vᵀ (eqs 40-42) and F0 = F̄ − S ā (eq. 39).

The solution is unique only when rank D ≥ 2 and, if a reflection must be flipped (det U det V < 0), the
smallest singular value is not repeated (method.md: the paper's remark after eq. 42 is garbled).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.errors import IdentificationError

RANK_TOLERANCE = 1e-9
"""σ₂/σ₁ of D below this: gravity seen from the flange spans fewer than two directions (rank D < 2)."""
REPEATED_SINGULAR_TOLERANCE = 1e-6
"""Relative gap (σ₂ − σ₃)/σ₁ below this with a flipped reflection: the rotation is not unique."""


@dataclass(frozen=True)
class WahbaResult:
    """The rotation fit. ``singular_values`` of D descending (N²); ``unique`` False if the fit is ambiguous."""

    sensor_rotation: np.ndarray  # (3, 3) sensor_R_flange
    force_bias: np.ndarray  # (3,) N, sensor frame
    singular_values: np.ndarray  # (3,)
    reflection_flipped: bool
    unique: bool


def wahba(
    flange_R_base: np.ndarray, forces: np.ndarray, gravity_base: np.ndarray, weights: np.ndarray | None = None
) -> WahbaResult:
    """Return sensor_R_flange and the force bias (eqs 37-42) given gravity_base (3,) N.

    Raises IdentificationError when rank D < 2 (gravity seen from the flange does not span two directions:
    one orientation, or rotations about the vertical only).
    """
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    forces = np.asarray(forces, dtype=float).reshape(-1, 3)
    w = np.ones(len(rotations)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    gravity_flange = rotations @ np.asarray(gravity_base, dtype=float)  # a_i, flange frame (N, 3)
    mean_force = w @ forces
    mean_gravity_flange = w @ gravity_flange
    d = np.einsum("i,ij,ik->jk", w, forces - mean_force, gravity_flange - mean_gravity_flange)
    if not np.all(np.isfinite(d)):
        raise IdentificationError("Wahba step (eq. 40): the correlation matrix D is not finite")
    try:
        u, sigma, vt = np.linalg.svd(d)
    except np.linalg.LinAlgError as error:
        raise IdentificationError(f"Wahba step (eq. 40): the SVD of D did not converge ({error})") from None
    if sigma[0] <= 0.0 or sigma[1] < RANK_TOLERANCE * sigma[0]:
        raise IdentificationError(
            "the tool's weight seen from the flange spans fewer than two directions (rank D < 2, eq. 42): "
            "the poses share one orientation or turn about the vertical only; tilt the tool in two directions"
        )
    sign = float(np.sign(np.linalg.det(u) * np.linalg.det(vt)))
    flipped = sign < 0
    unique = not (flipped and (sigma[1] - sigma[2]) < REPEATED_SINGULAR_TOLERANCE * sigma[0])
    rotation = u @ np.diag([1.0, 1.0, sign]) @ vt
    force_bias = mean_force - rotation @ mean_gravity_flange
    return WahbaResult(
        sensor_rotation=rotation,
        force_bias=force_bias,
        singular_values=sigma,
        reflection_flipped=flipped,
        unique=unique,
    )
