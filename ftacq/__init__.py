"""ftacq: calibrate a wrist-mounted ATI force/torque sensor on a UR arm and watch compensated wrenches.

Method: Yu, Shi & Lou, "Bias Estimation and Gravity Compensation for Wrist-Mounted Force/Torque Sensor",
IEEE Sensors J. 22(18), 2022 (doi 10.1109/JSEN.2021.3056943). Frame conventions: see docs/formats.md.

The core's public names (:data:`__all__`) are loaded lazily: ``import ftacq`` imports nothing heavy; the first
use of a name imports its module. The devices are in the ``drivers`` package, the steps (plan, calibration
procedure, monitor) in ``procedures``. ``open_cell`` (the live stream in Python: docs/python-api.md) is the
application's (:mod:`ftacq.app.session`, which reads CELL.toml and starts the simulated cell), named here for users.
"""

from __future__ import annotations

from ftacq.lazy import lazy_names

__version__ = "0.1.0"

STANDARD_GRAVITY_M_S2 = 9.80665
"""Standard gravity g in m/s², used to turn the identified weight ‖gravity_base‖ (N) into a mass (kg)."""

_LAZY = {
    "Calibration": "ftacq.calibration",
    "load_calibration": "ftacq.calfile",
    "save_calibration": "ftacq.calfile",
    "write_calibration": "ftacq.calfile",
    "WRITERS": "ftacq.calfile",
    "identify": "ftacq.identification",
    "IdentificationResult": "ftacq.identification",
    "PoseRecord": "ftacq.posefile",
    "read_pose_csv": "ftacq.posefile",
    "write_pose_csv": "ftacq.posefile",
    "MOUNTS": "ftacq.mounts",
    "POSE_SETS": "ftacq.posesets",
    "FtacqError": "ftacq.errors",
    "open_cell": "ftacq.app.session",
    "SimOptions": "ftacq.app.session",
    "Cell": "ftacq.app.session",
    "Batch": "ftacq.app.session",
}
"""Public name → the module defining it."""

__all__ = ["__version__", "STANDARD_GRAVITY_M_S2", *_LAZY]


__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
