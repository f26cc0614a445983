"""LROM: the tool's weight in the base frame from any orientations (paper eqs 24-34), mount-free sign rule.

From F_i = S R_i g + F0 (eq. 12), pre-multiplying by Sᵀ gives the linear homogeneous system (eq. 24, with
the paper's eR read as sR, method.md)

    Sᵀ F_i − R_i g − Sᵀ F0 = 0,    x = [rows of Sᵀ (9); g (3); Sᵀ F0 (3)]   (eq. 25)

minimised as ‖A x‖² subject to ‖x[0:9]‖² = 3 (eq. 26). Eliminating x[9:15] (eqs 30-31) leaves the
Schur complement H = N99 − N96 N66⁻¹ N69 of the normal matrix N = AᵀWA; x[0:9] is √3 times the
eigenvector of H with the smallest eigenvalue (eqs 32-33). Its sign: x[0:9] reshaped is ±Sᵀ and
det(−Sᵀ) = −1, so the sign that makes the determinant positive is right for every mount (this replaces
the paper's mount-dependent rule 34, method.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.errors import IdentificationError

SINGULAR_RCOND = 1e-12
"""Below this reciprocal condition number the bias block N66 counts as singular (one orientation only)."""


@dataclass(frozen=True)
class LromResult:
    """LROM estimate. ``rotation_raw`` is the unconstrained ±Sᵀ-derived S (not orthonormal under noise)."""

    gravity_base: np.ndarray  # (3,) N, base frame
    rotation_raw: np.ndarray  # (3, 3) approximately sensor_R_flange
    eigenvalues: np.ndarray  # (9,) ascending eigenvalues of H (N²); eigengap = eigenvalues[1] / eigenvalues[0]


def lrom(flange_R_base: np.ndarray, forces: np.ndarray, weights: np.ndarray | None = None) -> LromResult:
    """Return the LROM estimate of gravity_base (eqs 24-34) from (N, 3, 3) rotations and (N, 3) forces [N].

    ``weights`` (N,) ≥ 0 weight each pose's three equations (robust re-weighting). Raises
    IdentificationError when the orientations cannot separate the weight from the bias.
    """
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    forces = np.asarray(forces, dtype=float).reshape(-1, 3)
    n = len(rotations)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).reshape(n)
    # Normal matrix blocks of A_i = [kron(I3, F_iᵀ), −R_i, −I3] (eq. 26), summed with weights.
    sw = w.sum()
    ff = np.einsum("i,ij,ik->jk", w, forces, forces)  # Σ w F Fᵀ
    n99 = np.kron(np.eye(3), ff)
    # kron(I3, F_i) (9×3, row (c, k) = F_i[k] e_cᵀ) times −R_i → row (c, k): −F_i[k] R_i[c, :]
    n9g = -np.einsum("i,ik,icj->ckj", w, forces, rotations).reshape(9, 3)
    sum_f = w @ forces
    n9b = -np.kron(np.eye(3), sum_f[:, None])  # row (c, k), column c': −Σ F[k] δ_cc'
    sum_r = np.einsum("i,iab->ab", w, rotations)
    n66 = np.block([[sw * np.eye(3), sum_r.T], [sum_r, sw * np.eye(3)]])
    n96 = np.hstack([n9g, n9b])
    if not np.all(np.isfinite(n66)) or np.linalg.cond(n66) * SINGULAR_RCOND > 1.0:
        raise IdentificationError(
            "LROM: the orientations do not separate the tool's weight from the force bias "
            "(all poses share one orientation)"
        )
    try:
        h = n99 - n96 @ np.linalg.solve(n66, n96.T)
        h = 0.5 * (h + h.T)
        if not np.all(np.isfinite(h)):
            raise np.linalg.LinAlgError("non-finite normal matrix")
        eigenvalues, eigenvectors = np.linalg.eigh(h)
        x9 = np.sqrt(3.0) * eigenvectors[:, 0]
        x6 = -np.linalg.solve(n66, n96.T @ x9)
    except np.linalg.LinAlgError as error:
        raise IdentificationError(f"LROM: the linear system (eqs 30-33) cannot be solved ({error})") from None
    sensor_rotation_t = x9.reshape(3, 3)  # rows of Sᵀ
    if np.linalg.det(sensor_rotation_t) < 0.0:  # mount-free sign rule (replaces eq. 34)
        sensor_rotation_t = -sensor_rotation_t
        x6 = -x6
    return LromResult(gravity_base=x6[:3].copy(), rotation_raw=sensor_rotation_t.T.copy(), eigenvalues=eigenvalues)
