"""The exception tree of ftacq. Library code raises these; only the CLI turns them into exit codes.

::

    FtacqError
     ├── InputError (ValueError)            bad file, column, value or configuration key
     │    └── ConfigError                    a CELL.toml key out of range, unknown key
     ├── IdentificationError (ValueError)    a pose set that cannot identify the parameters
     ├── DeviceError                         anything a sensor or robot did wrong
     │    ├── DeviceConnectionError (ConnectionError)   unreachable, refused, dropped
     │    ├── DeviceTimeoutError (TimeoutError)         no data / no reply within the deadline
     │    ├── SensorFaultError                          status error bits, saturation
     │    └── RobotError                                robot-side faults
     │         ├── ProtectiveStopError                  the controller is protective-stopped
     │         ├── EmergencyStopError                   an emergency stop is active
     │         ├── ProgramStoppedError                  the control script is not running
     │         └── MotionLimitError (ValueError)        a command above the configured limits
     ├── PlanError (ValueError)              a pose plan that fails reachability / collision checks
     └── AbortedError                        a fault stopped the procedure, or the user declined the plan
          └── InterruptedByUser                  Ctrl-C / SIGTERM stopped it (exit status 130)
"""

from __future__ import annotations


class FtacqError(Exception):
    """Root of every error ftacq raises on purpose."""


class InputError(FtacqError, ValueError):
    """Bad user input. Example: a pose CSV missing column ``fz``; a NaN in row 12; an unknown URL scheme.

    The message names the file, row, column and value, and says why.
    """


class ConfigError(InputError):
    """A configuration key with a wrong type or out-of-range value. Example: ``robot.speed_rad_s = 5``."""


class IdentificationError(FtacqError, ValueError):
    """The pose set cannot identify the calibration. Example: all poses share one orientation."""


class DeviceError(FtacqError):
    """A device (sensor or robot) failed."""


class DeviceConnectionError(DeviceError, ConnectionError):
    """Cannot reach a device, or the connection dropped. Example: wrong IP, cable pulled."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """A device did not answer within the deadline. Example: the sensor went silent for 1 s."""


class SensorFaultError(DeviceError):
    """The sensor reports an error status or saturation. Example: status 0x80020000 (gage saturated)."""


class RobotError(DeviceError):
    """The robot refused or failed a command."""


class ProtectiveStopError(RobotError):
    """The controller is in a protective stop. Example: the arm hit something mid-move."""


class EmergencyStopError(RobotError):
    """An emergency stop button is pressed."""


class ProgramStoppedError(RobotError):
    """The control script on the controller is not running. Example: someone pressed Stop on the pendant."""


class MotionLimitError(RobotError, ValueError):
    """A motion command exceeds the configured speed, acceleration or joint limits (refused, not clamped)."""


class PlanError(FtacqError, ValueError):
    """The pose plan failed its checks. Example: fewer reachable poses than the identification needs."""


class AbortedError(FtacqError):
    """The procedure was stopped by a fault or not started (plan not confirmed); recorded data are kept."""


class InterruptedByUser(AbortedError):
    """The user interrupted the procedure (Ctrl-C, SIGTERM); recorded data are kept. The CLI exits 130."""
