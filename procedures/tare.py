"""Tare with the tool on: re-estimate the biases at the current pose or at N planned poses.

The estimate itself is :func:`ftacq.bias_estimate.estimate_biases` (rotation, weight, centre of mass kept). Two
ways to feed it still, contact-free poses:

- :func:`tare_here`: nothing moves. Wait until the robot is steady and the sensor still (the calibration's
  settle rule, :mod:`procedures.settle`), average, read the flange orientation, estimate.
- :class:`TareProcedure`: N poses planned and checked like a calibration (:func:`tare_plan_settings` asks the
  planner for N random orientations in the configured cone, no special set, no validation, no revisit). It is
  the calibration procedure (same moves, path re-checks, settling, averaging, stop/abort and events) whose
  identification step is the bias estimate, so everything the calibration guarantees about motion holds.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from drivers.robot import Robot
from drivers.sensor import ForceTorqueSensor
from ftacq.bias_estimate import BiasEstimate, estimate_biases
from ftacq.calibration import Calibration
from ftacq.errors import IdentificationError
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation
from procedures import events
from procedures.calibration_procedure import CalibrationProcedure, ProcedureOptions
from procedures.settle import SettleSettings, average_at_pose, wait_until_settled

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TareResult:
    """A tare's estimate and the poses it used (flange poses [x, y, z, rx, ry, rz], mean wrenches, std, counts)."""

    estimate: BiasEstimate
    poses: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray
    labels: tuple[str, ...]


def _never() -> bool:
    return False


def flange_R_base_of(poses: np.ndarray) -> np.ndarray:
    """Return flange_R_base (N, 3, 3) = base_R_flangeᵀ of UR flange poses (N, 6) (rotation vectors)."""
    return np.array([rotation_from_rotvec(p[3:6]).T for p in np.asarray(poses, dtype=float).reshape(-1, 6)])


def estimate_from_poses(calibration: Calibration, poses: np.ndarray, mean: np.ndarray, std: np.ndarray,
                        count: np.ndarray, labels: Sequence[str]) -> TareResult:
    """Estimate the biases from measured still poses (rows of ``poses``, ``mean``, ``std``, ``count``)."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 6)
    estimate = estimate_biases(calibration, flange_R_base_of(poses), mean, std=std, count=count)
    return TareResult(estimate, poses, np.asarray(mean, dtype=float).reshape(-1, 6),
                      np.asarray(std, dtype=float).reshape(-1, 6), np.asarray(count, dtype=float).reshape(-1),
                      tuple(labels))


def tare_here(robot: Robot, sensor: ForceTorqueSensor, calibration: Calibration, settle: SettleSettings,
              should_stop: Callable[[], bool] = _never) -> TareResult:
    """Tare at the current pose: settle, average, estimate. The robot is only read, never moved.

    Raises the settle errors (PoseNotSettledError when the arm or the tool does not become still — a hand on
    the tool keeps the sensor's std up), DeviceTimeoutError, StopRequested.
    """
    wait_until_settled(robot, sensor, settle, should_stop)
    before = np.asarray(robot.flange_pose(), dtype=float)
    average, _, _ = average_at_pose(sensor, settle, should_stop)
    after = np.asarray(robot.flange_pose(), dtype=float)
    # the turn between the two poses, not the difference of their rotation vectors: near an angle of π (the tool
    # pointing down) the encoders' jitter flips a rotation vector's sign
    turned_rad = float(np.linalg.norm(rotvec_from_rotation(rotation_from_rotvec(before[3:]).T
                                                           @ rotation_from_rotvec(after[3:]))))
    if not robot.is_steady() or max(float(np.max(np.abs(after[:3] - before[:3]))), turned_rad) > 1e-4:
        from procedures.settle import PoseNotSettledError

        raise PoseNotSettledError("the arm moved while the tare was averaging: keep it still and tare again")
    return estimate_from_poses(calibration, after[None], average.mean[None], average.std[None],
                               np.array([average.count]), ("here",))


def tare_plan_settings(settings, poses: int):
    """Return plan settings for an N-pose tare: N random orientations (set E) in the configured cone, nothing
    else (no special set, no validation, no drift revisit), at least one pose kept."""
    if not isinstance(poses, (int, np.integer)) or poses < 1:
        raise ValueError(f"poses {poses!r}: must be an integer ≥ 1")
    return replace(settings, special=False, random_count=int(poses), validation_count=0, explicit_poses=None,
                   require_srom=False, drift_check=False, min_identification_poses=1)


class TareProcedure(CalibrationProcedure):
    """The calibration procedure over a tare plan, whose identification step re-estimates the biases.

    After :meth:`run`, ``result`` is the :class:`TareResult` (None when the run did not reach the estimate).
    """

    def __init__(self, plan, robot: Robot, sensor: ForceTorqueSensor, calibration: Calibration,
                 options: ProcedureOptions | None = None, listeners: Sequence[events.Listener] = ()) -> None:
        options = replace(options or ProcedureOptions(), drift_check=False)
        super().__init__(plan, robot, sensor, options, listeners)
        self.calibration = calibration
        self.result: TareResult | None = None

    def _identify(self) -> None:
        self._enter("identifying", message="re-estimating the biases")
        rows = [self.measured[label] for label in self.plan.labels if label in self.measured]
        if not rows:
            raise IdentificationError("no tare pose was measured")
        self.result = estimate_from_poses(
            self.calibration, np.array([r.pose for r in rows]), np.array([r.mean for r in rows]),
            np.array([r.std if r.std is not None else np.zeros(6) for r in rows]),
            np.array([max(r.count, 1) for r in rows]), [r.label for r in rows])

    def _validate(self) -> None:
        """Nothing is held out in a tare."""


__all__ = ["TareResult", "TareProcedure", "tare_here", "tare_plan_settings", "estimate_from_poses",
           "flange_R_base_of"]
