"""Flange orientations as recorded (quaternion, rotation matrix, rotation vector) → ``base_R_flange`` (N, 3, 3).

Every form is the orientation of the flange in the robot base frame (``base_R_flange``, maps flange-frame vectors
into the base frame), the convention of UR's ``actual_TCP_pose`` and of the pose record. A recording that stores
the inverse (``flange_R_base``) gives its transpose with ``inverse=True``.

- quaternions: scalar last (``xyzw``: ROS, scipy, Eigen's coeffs) or scalar first (``wxyz``: ABB RAPID, MATLAB,
  Pinocchio's constructor). Their norm must be 1 within :data:`QUATERNION_NORM_TOLERANCE` (normalised after);
  q and −q are the same rotation.
- rotation matrices: nine columns, row-major (``r11 r12 r13 r21 … r33``), orthonormal within
  :data:`MATRIX_ORTHONORMAL_TOLERANCE` (a printed matrix with 6-digit cells passes) and det +1; projected onto
  SO(3) by SVD (the nearest rotation).
- rotation vectors (axis × angle, rad): as the pose record stores them.

Conversions are scipy's ``Rotation`` (batched). Bad rows raise InputError naming the row's line.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from ftacq.errors import InputError
from ftacq.imports.options import QUATERNION_ORDERS

QUATERNION_NORM_TOLERANCE = 1e-3
"""|‖q‖ − 1| above this is not a unit quaternion (a column mix-up or a scaled value): refused."""
MATRIX_ORTHONORMAL_TOLERANCE = 1e-3
"""max |RᵀR − I| and |det R − 1| above this is not a rotation matrix (transposed blocks, wrong columns): refused."""


def _refuse(where: str, lines: Sequence[int], bad: np.ndarray, why: str) -> None:
    index = int(np.flatnonzero(bad)[0])
    raise InputError(f"{where}: line {lines[index]}: {why} ({int(bad.sum())} row(s) like it)")


def from_quaternions(quaternions: np.ndarray, order: str, where: str = "<record>",
                     lines: Sequence[int] = ()) -> np.ndarray:
    """Return base_R_flange (N, 3, 3) of quaternions (N, 4) in ``order`` (``xyzw`` or ``wxyz``)."""
    if order not in QUATERNION_ORDERS:
        raise InputError(f"quaternion order {order!r}: must be one of {', '.join(QUATERNION_ORDERS)}")
    q = np.asarray(quaternions, dtype=float).reshape(-1, 4)
    lines = list(lines) or list(range(1, len(q) + 1))
    norm = np.linalg.norm(q, axis=1)
    bad = np.abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        _refuse(where, lines, bad, f"quaternion of norm {norm[k]:.6g}, not 1: the wrong columns?")
    if order == "wxyz":
        q = q[:, [1, 2, 3, 0]]
    return Rotation.from_quat(q / norm[:, None]).as_matrix()


def from_matrices(rows: np.ndarray, where: str = "<record>", lines: Sequence[int] = ()) -> np.ndarray:
    """Return base_R_flange (N, 3, 3) of row-major rotation matrices (N, 9), projected onto SO(3)."""
    m = np.asarray(rows, dtype=float).reshape(-1, 3, 3)
    lines = list(lines) or list(range(1, len(m) + 1))
    error = np.abs(np.swapaxes(m, -1, -2) @ m - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(m)
    bad = (error > MATRIX_ORTHONORMAL_TOLERANCE) | (np.abs(det - 1.0) > MATRIX_ORTHONORMAL_TOLERANCE)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        _refuse(where, lines, bad, f"not a rotation matrix (|RᵀR − I| = {error[k]:.2g}, det = {det[k]:.4f}): "
                                   "row-major r11 … r33 expected")
    u, _, vt = np.linalg.svd(m)
    return u @ vt  # det(u vt) = +1 here: det m ≈ 1


def from_rotation_vectors(rotvecs: np.ndarray) -> np.ndarray:
    """Return base_R_flange (N, 3, 3) of rotation vectors (N, 3), rad."""
    return Rotation.from_rotvec(np.asarray(rotvecs, dtype=float).reshape(-1, 3)).as_matrix()


def to_rotation_vectors(base_R_flange: np.ndarray) -> np.ndarray:
    """Return the rotation vectors (N, 3), rad, |r| ≤ π, of rotations (N, 3, 3) (the pose record's rx, ry, rz)."""
    return Rotation.from_matrix(np.asarray(base_R_flange, dtype=float).reshape(-1, 3, 3)).as_rotvec()


__all__ = ["from_matrices", "from_quaternions", "from_rotation_vectors", "to_rotation_vectors"]
