"""Rotations: UR rotation vectors <-> rotation matrices, batched in numpy.

A UR controller reports a pose as ``[x, y, z, rx, ry, rz]`` (m, rad): the rotation vector (axis × angle)
of ``base_R_flange``. These helpers are vectorised over a leading axis; single rotations may also use
Pinocchio's ``pin.exp3`` / ``pin.log3``, which agree with them (tested).
"""

from __future__ import annotations

import numpy as np

_SMALL_ANGLE_RAD = 1e-8


def rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Return the rotation matrices (…, 3, 3) of rotation vectors (…, 3) in radians (Rodrigues)."""
    rotvec = np.asarray(rotvec, dtype=float)
    theta = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    k = np.zeros(rotvec.shape[:-1] + (3, 3))
    x, y, z = rotvec[..., 0], rotvec[..., 1], rotvec[..., 2]
    k[..., 0, 1], k[..., 0, 2] = -z, y
    k[..., 1, 0], k[..., 1, 2] = z, -x
    k[..., 2, 0], k[..., 2, 1] = -y, x
    small = theta < _SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * k + b * (k @ k)


def rotation_of_rotvec(rotvec) -> np.ndarray:
    """The rotation matrix (3, 3) of one rotation vector (3,), rad: Pinocchio's ``exp3`` (equal to
    :func:`rotation_from_rotvec` to 1e-15, tests/test_so3.py), ~0.5 µs against ~70 µs of numpy calls: once per live
    monitor read."""
    import pinocchio as pin

    return pin.exp3(np.ascontiguousarray(rotvec, dtype=float))


def rotvec_of_rotation(rotation) -> np.ndarray:
    """The rotation vector (3,), rad, angle in [0, π], of one rotation matrix (3, 3): Pinocchio's ``log3`` (equal to
    :func:`rotvec_from_rotation`, tests/test_so3.py), ~1 µs against ~100 µs of numpy calls: once per pose read."""
    import pinocchio as pin

    return pin.log3(np.ascontiguousarray(rotation, dtype=float))


def rotvec_from_rotation(rotation: np.ndarray) -> np.ndarray:
    """Return rotation vectors (…, 3), angle in [0, π], of rotation matrices (…, 3, 3): vectorised (axis·sin θ from
    the skew part, scaled by θ / sin θ); the angles within 1e-4 rad of π (where sin θ vanishes: a tool pointing down)
    take their axis from the symmetric part, also batched."""
    rotation = np.asarray(rotation, dtype=float)
    r = rotation.reshape(-1, 3, 3)
    cos_theta = np.clip((np.trace(r, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_theta)
    axis_sin = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1) / 2.0
    sin_theta = np.sin(theta)
    scale = np.divide(theta, sin_theta, out=np.ones_like(theta), where=theta >= 1e-6)
    out = axis_sin * scale[:, None]
    near = np.flatnonzero(theta >= np.pi - 1e-4)
    if near.size:  # near π: axis from the symmetric part (its largest diagonal's column), sign from the skew part
        m = r[near]
        c = cos_theta[near][:, None, None]
        outer = ((m + np.swapaxes(m, 1, 2)) / 2.0 - c * np.eye(3)) / (1.0 - c)  # axis axisᵀ
        diagonal = np.diagonal(outer, axis1=1, axis2=2)
        j = np.argmax(diagonal, axis=1)
        rows = np.arange(near.size)
        axis = outer[rows, :, j] / np.sqrt(np.maximum(diagonal[rows, j], 1e-300))[:, None]
        flip = np.einsum("ij,ij->i", axis, axis_sin[near]) < 0
        axis[flip] *= -1.0
        out[near] = axis * theta[near][:, None]
    return out.reshape(rotation.shape[:-2] + (3,))


def angle_between_deg(rotation_a: np.ndarray, rotation_b: np.ndarray) -> np.ndarray:
    """Return the geodesic angle in degrees between rotation matrices (…, 3, 3)."""
    rel = np.swapaxes(np.asarray(rotation_a), -1, -2) @ np.asarray(rotation_b)
    cos_theta = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos_theta))


def rotation_zyx_deg(yaw_z_deg: float, pitch_y_deg: float, roll_x_deg: float) -> np.ndarray:
    """Return Rz(yaw) @ Ry(pitch) @ Rx(roll): the Z-Y-X Euler convention of the paper's Table I."""
    cz, sz = np.cos(np.radians(yaw_z_deg)), np.sin(np.radians(yaw_z_deg))
    cy, sy = np.cos(np.radians(pitch_y_deg)), np.sin(np.radians(pitch_y_deg))
    cx, sx = np.cos(np.radians(roll_x_deg)), np.sin(np.radians(roll_x_deg))
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return rz @ ry @ rx


def cube_rotations() -> np.ndarray:
    """Return the 24 proper rotations of the cube as ``flange_R_base`` (24, 3, 3), in the paper's order.

    Blocks of four (i = 1-4, 5-8, …, 21-24): the first column is +x, −x, +y, −y, +z, −z; inside a block the
    second column runs (+a, −a, +b, −b) over the two remaining axes in x<y<z order; the third column is the
    cross product (method.md, "The 24 special orientations"; eqs 14-23).
    """
    axes = np.eye(3)
    out = []
    for first_axis in range(3):
        for first_sign in (1.0, -1.0):
            c1 = first_sign * axes[first_axis]
            others = [a for a in range(3) if a != first_axis]
            for second_axis in others:
                for second_sign in (1.0, -1.0):
                    c2 = second_sign * axes[second_axis]
                    out.append(np.column_stack([c1, c2, np.cross(c1, c2)]))
    # order inside a block: (+a, -a, +b, -b)
    return np.array(out)
