"""The tool in motion: its inertia identified from a recorded motion, and its inertial wrench removed live.

- :mod:`ftacq.dynamics.model`: Pinocchio's sensor-frame motion and body regressor; the predicted wrench (RNEA).
- :mod:`ftacq.dynamics.identify`: physically consistent least squares, 1σ, conditioning, held-out error, lag.
- :mod:`ftacq.dynamics.clock`: one host clock for sensor and robot samples (the minimum-delay line).
- :mod:`ftacq.dynamics.joint`: every calibration parameter (rotation, biases, mass, centre of mass, tilt,
  inertia, and the lag) from one motion: ``ftacq calibrate --quick``.
- :mod:`ftacq.dynamics.timing`: resampling between the sensor's and the robot's rates.
- :mod:`ftacq.dynamics.compensate`: :func:`compensate_moving`, the batch compensation every stream uses.
"""

from ftacq.dynamics.compensate import compensate_moving
from ftacq.dynamics.identify import DynamicsResult, MotionRecord, estimate_lag, identify_dynamics
from ftacq.dynamics.model import SensorDynamics, WrenchPredictor, inertial_parameters, predict_moving, pseudo_inertia
from ftacq.dynamics.clock import DeviceClock, device_to_host_clock
from ftacq.dynamics.timing import box_average, interpolate_rows

__all__ = ["compensate_moving", "DynamicsResult", "MotionRecord", "estimate_lag", "identify_dynamics",
           "SensorDynamics", "WrenchPredictor", "inertial_parameters", "predict_moving", "pseudo_inertia", "box_average",
           "device_to_host_clock", "DeviceClock", "interpolate_rows"]
