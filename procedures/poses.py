"""Pose sets for the calibration: A (24 special orientations), E (random in a cone), V (validation), explicit.

Every pose is a flange pose in the robot base frame, ``[x, y, z (m), rx, ry, rz (rad)]`` with the rotation
vector of ``base_R_flange`` (what a UR controller reports with a zero TCP offset).

- A: the 24 proper rotations of the cube (:func:`ftacq.so3.cube_rotations`, given as ``flange_R_base`` in the
  paper's order, eqs 14-23), all at one centre position; label ``A01`` is the paper's i = 1.
- E and V: random orientations whose tool axis (flange z) lies within a cone of half-angle θ about a nominal
  tool orientation (default: tool pointing down for the mount), drawn uniformly over the cone's solid angle;
  E and V come from independent streams of the same seed (same region, different poses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.mounts import mount_of
from ftacq.posesets import RANDOM_SET, SPECIAL_SET, VALIDATION_SET
from ftacq.so3 import cube_rotations, rotation_from_rotvec, rotvec_from_rotation

E_STREAM, V_STREAM = 0, 1
"""Sub-streams of the seed used for the E and V sets (``np.random.default_rng([seed, stream])``)."""


@dataclass(frozen=True)
class PoseSet:
    """Poses (N, 6) with their labels (e.g. ``"A07"``) and the set each belongs to (``"A"``, ``"E"``, ``"V"``)."""

    poses: np.ndarray
    labels: tuple[str, ...]
    set_names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.labels)

    def __add__(self, other: "PoseSet") -> "PoseSet":
        return PoseSet(np.vstack([self.poses.reshape(-1, 6), other.poses.reshape(-1, 6)]),
                       self.labels + other.labels, self.set_names + other.set_names)

    @staticmethod
    def empty() -> "PoseSet":
        """Return a set with no poses."""
        return PoseSet(np.empty((0, 6)), (), ())


def pose_from(base_R_flange: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """Return flange poses (…, 6) from rotations (…, 3, 3) and positions (…, 3)."""
    rotvec = rotvec_from_rotation(base_R_flange)
    position = np.broadcast_to(np.asarray(position_m, dtype=float), rotvec.shape)
    return np.concatenate([position, rotvec], axis=-1)


def tool_down_rotation(mount: str = "floor") -> np.ndarray:
    """Return the nominal ``base_R_flange`` with the tool (flange z) pointing down (along gravity) for ``mount``.

    Flange x is the base axis nearest the mounting surface's "forward": base x projected off gravity when gravity
    is nearer base z than the horizontal (floor: Rx(π); ceiling: the identity), else −z_base projected (wall,
    gravity along −x_base: flange z = −x_base, flange x = −z_base). Any tilt (``tilted:A,B``) gets the same rule.
    """
    z_axis = np.array(mount_of(mount).down_base)  # the tool points along gravity
    reference = np.array([1.0, 0.0, 0.0]) if abs(z_axis[2]) > 0.7 else np.array([0.0, 0.0, -1.0])
    x_axis = reference - (reference @ z_axis) * z_axis
    x_axis /= np.linalg.norm(x_axis)
    return np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])


def special_poses(center_m: np.ndarray, pivot_offset_m: float = 0.0) -> PoseSet:
    """Return the A set: the 24 cube rotations (paper's order) as flange poses about ``center_m`` (3,), m.

    ``pivot_offset_m``: the orientations turn about the point this far along the flange z axis (e.g. the
    middle of the tool), so the flange position is ``center − pivot_offset · z_flange``; 0 keeps the flange at the
    centre for all 24.
    """
    center = np.asarray(center_m, dtype=float).reshape(3)
    base_R_flange = np.swapaxes(cube_rotations(), -1, -2)  # cube_rotations() are flange_R_base
    positions = center - pivot_offset_m * base_R_flange[:, :, 2]
    poses = pose_from(base_R_flange, positions)
    return PoseSet(poses, tuple(f"{SPECIAL_SET}{i + 1:02d}" for i in range(24)), (SPECIAL_SET,) * 24)


def cone_rotations(n: int, cone_half_angle_deg: float, nominal_base_R_flange: np.ndarray,
                   rng: np.random.Generator) -> np.ndarray:
    """Return ``n`` rotations base_R_flange (n, 3, 3) whose flange z axis is within the cone about the nominal's.

    The tilt is drawn uniformly over the cap's solid angle (cos t uniform in [cos θ, 1], azimuth uniform) and
    applied as the smallest rotation taking the nominal tool axis there (no spin about the tool axis: spin does
    not change the gravity direction seen by the sensor, it only costs wrist travel).
    """
    if not 0.0 <= cone_half_angle_deg <= 180.0:
        raise ValueError(f"cone_half_angle_deg must be in [0, 180], got {cone_half_angle_deg}")
    nominal = np.asarray(nominal_base_R_flange, dtype=float)
    cos_t = rng.uniform(np.cos(np.radians(cone_half_angle_deg)), 1.0, n)
    tilt = np.arccos(np.clip(cos_t, -1.0, 1.0))
    azimuth = rng.uniform(-np.pi, np.pi, n)
    # tilt axis: perpendicular to the nominal tool axis, in the nominal flange frame (x, y plane)
    axis_flange = np.column_stack([-np.sin(azimuth), np.cos(azimuth), np.zeros(n)])
    axis_base = axis_flange @ nominal.T
    tilt_rotation = rotation_from_rotvec(axis_base * tilt[:, None])
    return tilt_rotation @ nominal


def random_cone_poses(n: int, cone_half_angle_deg: float = 40.0, nominal_base_R_flange: np.ndarray | None = None,
                      center_m: np.ndarray | tuple[float, float, float] = (0.0, -0.45, 0.45), position_jitter_m: float = 0.0, seed: int = 0,
                      set_name: str = RANDOM_SET, mount: str = "floor") -> PoseSet:
    """Return ``n`` random poses in a cone (the E or V set), labelled ``E01``… or ``V01``….

    Args:
        n: pose count. cone_half_angle_deg: half-angle θ of the cone of tool axes, degrees.
        nominal_base_R_flange: nominal orientation (3, 3); default the tool pointing down for ``mount``.
        center_m: position (3,), m. position_jitter_m: each coordinate moves uniformly within ± this, m.
        seed: random seed; E uses stream ``[seed, 0]`` and V ``[seed, 1]`` so they never coincide.
        set_name: "E" or "V".
    """
    if n < 0:
        raise ValueError(f"pose count must be ≥ 0, got {n}")
    if position_jitter_m < 0:
        raise ValueError(f"position_jitter_m must be ≥ 0, got {position_jitter_m}")
    stream = {RANDOM_SET: E_STREAM, VALIDATION_SET: V_STREAM}.get(set_name, 2)
    rng = np.random.default_rng([int(seed), stream])
    nominal = tool_down_rotation(mount) if nominal_base_R_flange is None else np.asarray(nominal_base_R_flange)
    rotations = cone_rotations(n, cone_half_angle_deg, nominal, rng)
    positions = np.asarray(center_m, dtype=float) + rng.uniform(-position_jitter_m, position_jitter_m, (n, 3))
    return PoseSet(pose_from(rotations, positions).reshape(n, 6), tuple(f"{set_name}{i + 1:02d}" for i in range(n)),
                   (set_name,) * n)


def explicit_poses(poses: np.ndarray, set_name: str = RANDOM_SET, prefix: str = "X") -> PoseSet:
    """Return user-given flange poses (N, 6) as a set (default: used for identification, labels ``X01``…).

    Raises ValueError naming the row and column of a non-finite value or a wrong shape.
    """
    arr = np.asarray(poses, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 6:
        raise ValueError(f"explicit poses must be an (N, 6) array of [x, y, z, rx, ry, rz], got shape {arr.shape}")
    bad = np.argwhere(~np.isfinite(arr))
    if len(bad):
        row, col = bad[0]
        raise ValueError(f"explicit pose row {row + 1}, column {'x y z rx ry rz'.split()[col]}: {arr[row, col]} is not finite")
    return PoseSet(arr.copy(), tuple(f"{prefix}{i + 1:02d}" for i in range(len(arr))), (set_name,) * len(arr))
