"""The tool in motion: its inertia identified from a recorded motion, and its inertial wrench removed live.

- :mod:`ftacq.dynamics.model`: Pinocchio's sensor-frame motion and body regressor; the predicted wrench (RNEA).
- :mod:`ftacq.dynamics.identify`: physically consistent least squares, 1σ, conditioning, held-out error, lag.
- :mod:`ftacq.dynamics.joint`: every calibration parameter (rotation, biases, mass, centre of mass, tilt,
  inertia, and the lag) from one motion: ``ftacq calibrate --quick``.
- :mod:`ftacq.dynamics.timing`: resampling between the sensor's and the robot's rates.
- :mod:`ftacq.dynamics.compensate`: :func:`compensate_moving`, the batch compensation every stream uses.

The host clock every stream uses is :mod:`ftacq.timebase`. The names below load on first use (Pinocchio takes
a while to import): ``import ftacq.dynamics`` imports none of these modules.
"""

from ftacq.lazy import lazy_names

_HOMES = {"compensate_moving": "compensate", "DynamicsResult": "identify", "MotionRecord": "identify",
          "estimate_lag": "identify", "identify_dynamics": "identify", "SensorDynamics": "model",
          "WrenchPredictor": "model", "inertial_parameters": "model", "predict_moving": "model",
          "pseudo_inertia": "model", "box_average": "timing", "interpolate_rows": "timing"}

__getattr__, __dir__ = lazy_names(__name__, {name: f"{__name__}.{home}" for name, home in _HOMES.items()},
                                  globals())

__all__ = list(_HOMES)
