"""Live static compensation with the pose at the samples' time: :class:`StaticCompensator`, the monitor's
:class:`~procedures.monitor.Compensator` for a calibration without inertia.

Per sensor batch: the samples are put on the host clock through the device's own sample times
(:class:`ftacq.timebase.SampleClock`, shared with the monitor's record: docs/dynamics.md, "How the clocks are
aligned"), the flange orientation is interpolated at each sample's time from the RTDE state stream's rows
(:class:`procedures.flange_orientation.FlangeOrientations`: slerp between the states around it) and the calibration
subtracts the biases and the tool's weight at that orientation (:meth:`ftacq.calibration.Calibration.compensate`,
the paper's static model). The newest pose is never used for older samples: a monitor that falls behind (a loaded
host, a stalled viewer thread) reads samples taken up to hundreds of ms before, while the arm moved.

When a sample has no robot state within :data:`~procedures.flange_orientation.MAX_STATE_GAP_S` (the stream is lost,
late, or has a gap) the batch is left uncompensated: :meth:`StaticCompensator.compensate` returns None, the monitor
publishes it without a contact wrench (the readout shows no compensated value, the record leaves the ``contact_*``
columns empty) and it is counted in :attr:`StaticCompensator.uncompensated_batches`.

The static model is exact only while the arm is still (no inertial wrench); in motion it still leaves the tool's
inertial forces (docs/dynamics.md). The orientation's time matters all the same: the weight's direction in the
sensor frame is the largest term it subtracts.
"""

from __future__ import annotations

import numpy as np

from ftacq.calibration import Calibration
from ftacq.timebase import SampleClock
from ftacq.kinematics import URModel
from procedures.flange_orientation import FlangeOrientations, pose_rows, still_over


class StaticCompensator:
    """Static gravity compensation with the flange orientation at each sample's time (module docstring).

    Args: calibration, robot (the arm's model), stream (a started :class:`drivers.ur_stream.URStateStream`, or
    anything with its ``window(last=…)``), clock (the samples' :class:`~ftacq.timebase.SampleClock`, shared
    with the monitor so that each batch is observed once; default its own), lag_s (the sensor's lag behind the
    robot stream, s: the one the identification measured when the calibration says it, else 0 — a millisecond
    moves the orientation by a milliradian at 1 rad/s).
    """

    def __init__(self, calibration: Calibration, robot: URModel, stream, clock: SampleClock | None = None,
                 lag_s: float | None = None) -> None:
        self.calibration = calibration
        self.orientations = FlangeOrientations(robot, stream)
        self.clock = clock if clock is not None else SampleClock()
        dynamics = calibration.metadata.get("dynamics")
        measured = dynamics.get("lag_ms") if isinstance(dynamics, dict) else None
        self.lag_s = float(lag_s if lag_s is not None else (measured or 0.0) / 1e3)
        self.compensated_batches = 0
        self.uncompensated_batches = 0
        """Batches with no robot state within MAX_STATE_GAP_S of a sample: compensate() returned None."""
        self.flange_R_base: np.ndarray | None = None
        """The orientations (N, 3, 3) the last batch was compensated with (None when it was not)."""
        self._times = np.empty(0)
        """The last batch's sample times on the host clock, lag taken off, s."""

    def compensate(self, batch, robot=None) -> np.ndarray | None:
        """Return the contact wrench (N, 6) of ``batch`` (N, N·m, sensor frame), or None (uncompensated: no robot
        state near its samples). ``robot`` (the newest state from another source) is not used: its pose is from
        another time."""
        times = self._times = self.clock.host_times(batch.time_s, batch.device_time_s) - self.lag_s
        self.flange_R_base = self.orientations.flange_R_base_at(times)
        if self.flange_R_base is None:
            self.uncompensated_batches += 1
            return None
        self.compensated_batches += 1
        return self.calibration.compensate(batch.wrench, self.flange_R_base)

    def still_over(self, window_s: float, tolerance_rad: float) -> bool:
        """:func:`procedures.flange_orientation.still_over` for the last batch's sample times."""
        return still_over(self.orientations, self._times, window_s, tolerance_rad)

    def sample_flange_pose(self) -> np.ndarray | None:
        """The flange pose (N, 6) (m, rad: a UR pose, base frame) at each sample of the last batch, as it was
        compensated with; None when it was left uncompensated. For the record: each sample beside its pose."""
        if self.flange_R_base is None:
            return None
        return pose_rows(self.orientations.position_m, self.flange_R_base)


__all__ = ["StaticCompensator"]
