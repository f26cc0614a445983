"""Simulated pose records: flange poses and noisy mean wrenches from a known :class:`CellTruth`.

The mean wrench at each pose is the truth's noiseless wrench plus the noise of a mean of ``count``
samples (σ/√count per channel, σ from the truth), plus any contact wrench given for that pose; the std
column is the sample standard deviation of those samples (drawn, so it scatters around σ like real data).

Pose sets (``flange_R_base`` orientations, converted to UR poses ``base_R_flange`` rotation vectors):

- :func:`special_orientations`: the 24 cube rotations (paper set A), optionally perturbed by a few tenths
  of a degree as a real robot would reach them;
- :func:`cone_orientations`: random orientations whose tool axis is within a cone about tool-down (set E),
  with a random spin about the tool axis;
- :func:`random_orientations`: uniformly random orientations (set D).

:func:`real_like_record` adds what real recordings show and the other records do not: heavy-tailed noise, no
std/count columns, a robot orientation error and a small force the model cannot represent.

``python -m tests.fakes.pose_records OUT.csv`` writes an example record (A + E poses, floor mount).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ftacq.posefile import PoseRecord, write_pose_csv
from ftacq.so3 import cube_rotations, rotation_from_rotvec, rotvec_from_rotation
from tests.fakes.world import CellTruth

TOOL_DOWN_BASE_R_FLANGE = np.diag([1.0, -1.0, -1.0])
"""base_R_flange with the flange z axis pointing down (rotation by π about base x), as UR's [π, 0, 0]."""
DEFAULT_SAMPLES_PER_POSE = 500
DEFAULT_POSITION_M = (0.4, -0.1, 0.35)


def special_orientations(perturbation_deg: float = 0.0, seed: int = 0) -> np.ndarray:
    """Return the 24 special ``flange_R_base`` (24, 3, 3) in the paper's order, each optionally rotated by
    a random small angle up to ``perturbation_deg``."""
    rotations = cube_rotations()
    if perturbation_deg <= 0.0:
        return rotations
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(24, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.radians(rng.uniform(0.0, perturbation_deg, size=24))
    return rotation_from_rotvec(axes * angles[:, None]) @ rotations


def cone_orientations(count: int, half_angle_deg: float = 40.0, seed: int = 0, axis_base_R_flange: np.ndarray = TOOL_DOWN_BASE_R_FLANGE) -> np.ndarray:
    """Return ``count`` random ``flange_R_base`` (count, 3, 3) with the tool axis within ``half_angle_deg``
    of the axis of ``axis_base_R_flange`` (tool-down by default), random spin about the tool axis."""
    rng = np.random.default_rng(seed)
    cos_max = np.cos(np.radians(half_angle_deg))
    cos_tilt = rng.uniform(cos_max, 1.0, size=count)  # uniform over the spherical cap
    tilt = np.arccos(cos_tilt)
    azimuth = rng.uniform(-np.pi, np.pi, size=count)
    spin = rng.uniform(-np.pi, np.pi, size=count)
    tilt_axis = np.column_stack([np.cos(azimuth), np.sin(azimuth), np.zeros(count)])
    base_R_flange = (
        axis_base_R_flange
        @ rotation_from_rotvec(tilt_axis * tilt[:, None])
        @ rotation_from_rotvec(np.column_stack([np.zeros(count), np.zeros(count), spin]))
    )
    return np.swapaxes(base_R_flange, -1, -2)


def gravity_down_base_R_flange(gravity_base: np.ndarray) -> np.ndarray:
    """Return a base_R_flange whose flange z axis points along gravity (the tool hanging down on any mount),
    to use as the cone axis of :func:`cone_orientations` for wall, ceiling and tilted mounts."""
    z = np.asarray(gravity_base, dtype=float) / np.linalg.norm(gravity_base)
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def random_orientations(count: int, seed: int = 0) -> np.ndarray:
    """Return ``count`` uniformly random ``flange_R_base`` (count, 3, 3) (random unit quaternions)."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
        ],
        axis=-2,
    )


def poses_from_orientations(flange_R_base: np.ndarray, position_m: tuple[float, float, float] = DEFAULT_POSITION_M) -> np.ndarray:
    """Return UR flange poses (N, 6) [x, y, z, rx, ry, rz] with the rotation vectors of base_R_flange."""
    rotvecs = rotvec_from_rotation(np.swapaxes(np.asarray(flange_R_base), -1, -2)).reshape(-1, 3)
    positions = np.broadcast_to(np.asarray(position_m, dtype=float), rotvecs.shape)
    return np.hstack([positions, rotvecs])


def simulate_record(
    truth: CellTruth,
    flange_R_base: np.ndarray,
    *,
    samples_per_pose: int = DEFAULT_SAMPLES_PER_POSE,
    seed: int = 0,
    noise: bool = True,
    contacts: dict[int, np.ndarray] | None = None,
    labels: tuple[str, ...] | None = None,
    sets: tuple[str, ...] | None = None,
    with_std: bool = True,
    orientation_error_deg: float = 0.0,
) -> PoseRecord:
    """Return a simulated pose record at the given orientations (see the module docstring).

    ``contacts`` maps a pose index to a contact wrench (6,) in the sensor frame [N, N·m] added to its mean.
    ``orientation_error_deg`` > 0: the record reports each flange orientation off by a random rotation (1σ per
    axis, flange frame) while the wrench follows the true one, as with a robot's kinematic error.
    """
    rotations = np.asarray(flange_R_base, dtype=float).reshape(-1, 3, 3)
    n = len(rotations)
    poses = poses_from_orientations(rotations)
    calibration = truth.calibration()
    exact_rotations = np.swapaxes(rotation_from_rotvec(poses[:, 3:]), -1, -2)  # as the reader will see them
    mean = truth.measured(calibration.predict(exact_rotations))  # through the sensor's own gains
    if orientation_error_deg > 0.0:
        error_rng = np.random.default_rng([seed, 7919])
        error = rotation_from_rotvec(error_rng.standard_normal((n, 3)) * np.radians(orientation_error_deg))
        reported = np.swapaxes(exact_rotations, -1, -2) @ error  # base_R_flange · exp([δ]×)
        poses = np.hstack([poses[:, :3], rotvec_from_rotation(reported).reshape(-1, 3)])
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm)
    rng = np.random.default_rng(seed)
    std = None
    count = None
    if noise:
        mean = mean + rng.standard_normal((n, 6)) * sigma / np.sqrt(samples_per_pose)
        if with_std:
            dof = samples_per_pose - 1
            std = sigma * np.sqrt(rng.chisquare(dof, size=(n, 6)) / dof)
            count = np.full(n, samples_per_pose)
    for index, contact in (contacts or {}).items():
        mean[index] += np.asarray(contact, dtype=float)
    return PoseRecord(
        pose=poses,
        wrench=mean,
        std=std,
        count=count,
        labels=labels or tuple(f"P{i + 1:02d}" for i in range(n)),
        sets=sets or ("",) * n,
    )


def real_like_record(truth: CellTruth, count: int, seed: int = 0) -> PoseRecord:
    """``count`` random poses as a real recording gives them: mean wrenches only (no std, no count), Student-t
    (3 dof) noise at the truth's per-sample σ, a 0.05° robot orientation error, and a cable-like force along
    (0.3, −0.2, 1) growing with the tool's tilt (up to 0.1 N): a residual excess no fit of the model removes."""
    rotations = random_orientations(count, seed=seed)
    exact = simulate_record(truth, rotations, seed=seed, orientation_error_deg=0.05, noise=False)
    rng = np.random.default_rng(seed)
    sigma = np.array(truth.force_noise_n + truth.torque_noise_nm)
    wrench = exact.wrench + rng.standard_t(3, size=(count, 6)) * sigma
    wrench[:, :3] += 0.05 * (1.0 - rotations[:, 2, 2])[:, None] * np.array([0.3, -0.2, 1.0])
    return PoseRecord(pose=exact.pose, wrench=wrench, labels=exact.labels)


def example_record(truth: CellTruth | None = None, seed: int = 0, cone_poses: int = 24,
                   samples_per_pose: int = DEFAULT_SAMPLES_PER_POSE) -> PoseRecord:
    """Return the example record: the 24 special poses (A, reached to ±0.2°) + ``cone_poses`` in a 40° cone (E),
    each averaged over ``samples_per_pose``."""
    truth = truth or CellTruth()
    rotations = np.concatenate(
        [special_orientations(0.2, seed), cone_orientations(cone_poses, 40.0, seed + 1)]
    )
    labels = tuple(f"A{i + 1:02d}" for i in range(24)) + tuple(f"E{i + 1:02d}" for i in range(cone_poses))
    sets = ("A",) * 24 + ("E",) * cone_poses
    return simulate_record(truth, rotations, samples_per_pose=samples_per_pose, seed=seed, labels=labels, sets=sets)


def write_example_csv(path: str | Path, truth: CellTruth | None = None, seed: int = 0) -> PoseRecord:
    """Write :func:`example_record` to ``path`` (atomic) and return it."""
    record = example_record(truth, seed)
    write_pose_csv(path, record)
    return record


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "example_poses.csv")
    write_example_csv(target)
    print(f"wrote {target}")
