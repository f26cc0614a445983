"""The centre of mass and torque bias by linear least squares (paper eqs 43-45).

T_i = c × g_s,i + T0 = −[g_s,i]× c + T0, with g_s,i the gravity force in the sensor frame. The paper uses
g_s,i = F_i − F0 (measured); we use the model value S R_i g from the force fit, which carries less noise
(no errors in the regressors); both are exact without noise. Solved as a (weighted) stacked least squares.
"""

from __future__ import annotations

import numpy as np

from ftacq.errors import IdentificationError


def skew(vectors: np.ndarray) -> np.ndarray:
    """Return [v]× (…, 3, 3) with [v]× u = v × u."""
    v = np.asarray(vectors, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def torque_least_squares(
    gravity_sensor: np.ndarray, torques: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Return (center_of_mass (3,) m, torque_bias (3,) N·m) minimising Σ w ‖T_i + [g_s,i]× c − T0‖² (eq. 44).

    ``gravity_sensor`` (N, 3) N, ``torques`` (N, 3) N·m, ``weights`` (N,) per pose or (N, 3) per channel.
    """
    g = np.asarray(gravity_sensor, dtype=float).reshape(-1, 3)
    t = np.asarray(torques, dtype=float).reshape(-1, 3)
    n = len(g)
    design = np.zeros((n, 3, 6))
    design[:, :, :3] = -skew(g)
    design[:, :, 3:] = np.eye(3)
    if weights is None:
        root = np.ones((n, 3))
    else:
        w = np.asarray(weights, dtype=float)
        root = np.sqrt(np.broadcast_to(w[:, None] if w.ndim == 1 else w, (n, 3)))
    a = (design * root[:, :, None]).reshape(-1, 6)
    b = (t * root).reshape(-1)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise IdentificationError("torque least squares (eq. 44): non-finite regressors or torques")
    try:
        solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    except np.linalg.LinAlgError as error:
        raise IdentificationError(f"torque least squares (eq. 44) did not converge ({error})") from None
    return solution[:3], solution[3:]
