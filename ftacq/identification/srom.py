"""SROM: the tool's weight in the base frame from the 24 special orientations (paper eqs 14-23).

The 24 special orientations are the proper rotations of the cube (:func:`ftacq.so3.cube_rotations`). We use
the order-free form of eqs 17-23 (method.md): over the cube group Σ_i R_i = 0 and
(1/8) Σ_i R_i[a, b] R_i[c, d] = δ_ac δ_bd, so with F_i = S R_i g + F0 (eq. 14)

    Q[a, b] = (1/8) Σ_i R_i[a, b] F_i = S[:, a] g[b]        (the bias cancels; eqs 17-19)
    g[b]    = cbrt(det[Q[0, b], Q[1, b], Q[2, b]])            (eqs 20-23, det S = 1)

with a real cube root (``np.cbrt``): ``x ** (1/3)`` is NaN for the negative g_z of a floor mount.
"""

from __future__ import annotations

import numpy as np

from ftacq.errors import IdentificationError
from ftacq.so3 import cube_rotations

CUBE_ROTATIONS = cube_rotations()
"""(24, 3, 3) the special ``flange_R_base`` in the paper's order (index 0 is the paper's i = 1)."""

DEFAULT_SPECIAL_TOLERANCE_DEG = 3.0
"""A pose within this geodesic angle of a cube rotation counts as that special orientation."""


def match_special(flange_R_base: np.ndarray, tolerance_deg: float = DEFAULT_SPECIAL_TOLERANCE_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Return (index (N,) of the nearest cube rotation or −1 when farther than ``tolerance_deg``, angle (N,) deg)."""
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    # trace(R_iᵀ C_k) = Σ_ab R_i[a,b] C_k[a,b]; the nearest cube rotation has the largest trace
    traces = rotations.reshape(-1, 9) @ CUBE_ROTATIONS.reshape(24, 9).T
    nearest = np.argmax(traces, axis=1)
    cos_angle = np.clip((traces[np.arange(len(rotations)), nearest] - 1.0) / 2.0, -1.0, 1.0)
    angle_deg = np.degrees(np.arccos(cos_angle))
    index = np.where(angle_deg <= tolerance_deg, nearest, -1)
    return index, angle_deg


def missing_special(index: np.ndarray) -> list[int]:
    """Return the paper's numbers (1-24) of the special orientations absent from ``index``."""
    present = set(int(i) for i in np.asarray(index) if i >= 0)
    return [k + 1 for k in range(24) if k not in present]


def srom_gravity_base(
    flange_R_base: np.ndarray,
    forces: np.ndarray,
    special_index: np.ndarray,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Return gravity_base (3,) N by SROM (eqs 17-23, order-free form) from the poses matched to cube rotations.

    Several poses matched to one cube rotation are averaged (weighted by ``weights``), so each of the 24
    orientations counts once, as the cube-group identities require. The measured rotations are used (not
    the nominal cube rotations), so poses a little off the ideal orientation bias the result less.
    Raises IdentificationError if a special orientation is missing.
    """
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    forces = np.asarray(forces, dtype=float).reshape(-1, 3)
    special_index = np.asarray(special_index)
    missing = missing_special(special_index)
    if missing:
        raise IdentificationError(
            f"SROM needs all 24 special orientations; missing paper number(s) {', '.join(map(str, missing))}"
        )
    w = np.ones(len(rotations)) if weights is None else np.asarray(weights, dtype=float)
    member = special_index >= 0
    # per pose: R_i[a, b] F_i  →  (N, 3, 3, 3) indexed [i, a, b, :]
    products = rotations[member][:, :, :, None] * forces[member][:, None, None, :]
    group = special_index[member]
    group_weight = np.bincount(group, weights=w[member] + 1e-300, minlength=24)
    summed = np.zeros((24, 3, 3, 3))
    np.add.at(summed, group, products * (w[member] + 1e-300)[:, None, None, None])
    q = (summed / group_weight[:, None, None, None]).sum(axis=0) / 8.0  # Q[a, b, :] = S[:, a] g[b]
    # for each b: matrix with columns Q[a, b, :] (a = 0, 1, 2) = g[b] S  →  det = g[b]^3
    determinants = np.linalg.det(np.transpose(q, (1, 2, 0)))  # [b] → matrix [:, a]
    return np.cbrt(determinants)
