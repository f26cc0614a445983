"""Compensating the tool's gravity and inertial wrench while the arm moves (batch, numpy).

:func:`compensate_moving` is the one entry point for every compensated stream (the live monitor, the controller
bridge): raw sensor samples (N, 6) and the robot's states (M, 6 each) in, contact wrench (N, 6) out. The rigid-body
model is evaluated once per robot state (Pinocchio, :mod:`ftacq.dynamics.model`) and the predicted wrench is
interpolated linearly onto the sensor samples' times: between two 2 ms RTDE states the predicted wrench changes
smoothly (gravity turns, velocities change), so interpolating it equals interpolating the state to second order,
at 1/14 of the cost of a Pinocchio pass per 7 kHz sample.
"""

from __future__ import annotations

import numpy as np

from ftacq.calibration import Calibration
from ftacq.dynamics.model import SensorDynamics, predict_moving
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import URModel


def compensate_moving(calibration: Calibration, wrench: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray,
                      *, robot: URModel | None = None, dynamics: SensorDynamics | None = None,
                      sensor_time_s: np.ndarray | None = None, robot_time_s: np.ndarray | None = None,
                      out: np.ndarray | None = None) -> np.ndarray:
    """Return the contact wrench (N, 6) [N, N·m], sensor frame: raw − biases − the tool's gravity and inertial wrench.

    Args:
        calibration: a calibration with inertia (``calibration.has_dynamics``; otherwise ValueError: use
            :meth:`Calibration.compensate`, the static model).
        wrench: raw samples (N, 6), sensor frame.
        q, qd, qdd: joint positions (rad), speeds (rad/s), accelerations (rad/s²), (M, 6) each.
        robot: the arm's model (or ``dynamics``, a prepared :class:`SensorDynamics`: build it once for a stream).
        sensor_time_s (N,), robot_time_s (M,): when both are given, the prediction at the M states is interpolated
            onto the N sensor times (one host clock, :mod:`ftacq.dynamics.timing`); otherwise M must equal N.
        out: optional (N, 6) output array (may be ``wrench``).
    """
    if not calibration.has_dynamics:
        raise ValueError("this calibration has no inertia (static only); compensate with Calibration.compensate")
    if dynamics is None:
        if robot is None:
            raise ValueError("compensate_moving needs the robot model (robot=) or a SensorDynamics (dynamics=)")
        dynamics = SensorDynamics.for_calibration(robot, calibration)
    wrench = np.asarray(wrench, dtype=float).reshape(-1, 6)
    predicted = predict_moving(dynamics, calibration, q, qd, qdd)
    if sensor_time_s is not None and robot_time_s is not None:
        predicted = interpolate_rows(sensor_time_s, robot_time_s, predicted)
    elif predicted.shape[0] != wrench.shape[0]:
        raise ValueError(f"{wrench.shape[0]} samples and {predicted.shape[0]} robot states: give sensor_time_s and "
                         "robot_time_s to interpolate, or one state per sample")
    return np.subtract(wrench, predicted, out=out)
