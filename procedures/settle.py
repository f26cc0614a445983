"""Settling and averaging at a still pose.

Theory of operation (as ophyd's ``StatusBase``: always under a finite timeout):

1. Settle: read the sensor continuously (so the driver's buffer never holds stale samples). The pose counts as
   settled when the robot reports steady for at least ``settle_time_s`` seconds AND the sample standard
   deviation of every channel over the last ``window_s`` seconds is below its threshold (force in N, torque
   in N·m). A pose that does not settle within ``timeout_s`` seconds raises :class:`PoseNotSettledError`
   naming the channel that kept moving; a sensor that delivers nothing for ``sensor_timeout_s`` seconds
   raises the driver's :class:`~ftacq.errors.DeviceTimeoutError`.
2. Average: collect fresh samples for ``average_time_s`` seconds with the driver's ``average`` (mean, std,
   count; saturated samples excluded and counted, lost samples counted).

A silence of the sensor shorter than ``sensor_timeout_s`` never aborts a pose: settling keeps reading through it,
and an averaging window it spoils (fewer than half the samples the rate promises over ``average_time_s``) is taken
again over twice the previous window (the arm is still: a longer window is as good, and a link that delivers in
bursts, such as a shared CAN bus or a starved host, fills it), up to ``MAX_AVERAGE_ATTEMPTS`` times; each window may
wait its length ``+ sensor_timeout_s`` for its samples, and the fullest window is kept.

Both check a stop flag between reads, so a requested stop lands within one read.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from drivers.robot import Robot
from drivers.sensor import ForceTorqueSensor, WrenchAverage
from ftacq.channels import AXES
from ftacq.errors import DeviceTimeoutError, FtacqError, SensorFaultError
from ftacq.settings import from_setting, values_from

log = logging.getLogger(__name__)

READ_TIMEOUT_CAP_S = 0.25
"""Longest single ``sensor.read`` wait, so the stop flag is checked at least this often (s)."""
SETTLE_POLL_PERIOD_S = 0.005
"""The settle loop checks the robot and the sensor at most this often (no busy loop on a fast sensor)."""
MIN_SAMPLE_FRACTION = 0.5
"""An averaging window with fewer than this fraction of the samples the sensor's rate promises is taken again."""
MAX_AVERAGE_ATTEMPTS = 5
"""Averaging windows tried at one pose before accepting a short one (with a warning) or failing."""
MIN_SAMPLES = 2
"""Fewest samples of an accepted average (a standard deviation needs two)."""
MIN_SETTLE_SAMPLES = 8
"""Fewest samples in the settle window before its std may declare the sensor still: the std of two or three
samples of a shaking tool is below the threshold far too often (3 samples of σ = 6× threshold pass 1 % of the
time; 8 samples, one in a million)."""


class PoseNotSettledError(DeviceTimeoutError):
    """The robot or the sensor did not become still within the settle timeout (a fault, data kept)."""


class StopRequested(FtacqError):
    """A planned stop was requested while settling or averaging (the procedure stops cleanly)."""


@dataclass(frozen=True)
class SettleSettings:
    """Settling and averaging parameters (the ``[sampling]`` keys of CELL.toml named below; SI units)."""

    settle_time_s: float = from_setting("sampling.settle_time_s")
    window_s: float = from_setting("sampling.settle_window_s")
    force_std_n: float = from_setting("sampling.settle_force_std_n")
    torque_std_nm: float = from_setting("sampling.settle_torque_std_nm")
    timeout_s: float = from_setting("sampling.settle_timeout_s")
    average_time_s: float = from_setting("sampling.average_time_s")
    sensor_timeout_s: float = from_setting("sampling.sensor_timeout_s")

    @classmethod
    def from_config(cls, config) -> "SettleSettings":
        """Build from a configuration with a ``sampling`` section (:class:`ftacq.app.config.CellConfig`)."""
        return cls(**values_from(config, cls))

    @property
    def thresholds(self) -> np.ndarray:
        """(6,) per-channel std thresholds [N, N, N, N·m, N·m, N·m]."""
        return np.array([self.force_std_n] * 3 + [self.torque_std_nm] * 3)


@dataclass(frozen=True)
class SettleResult:
    """How settling went: ``elapsed_s`` until settled, the window's per-channel std (6,) and sample count."""

    elapsed_s: float
    window_std: np.ndarray
    window_count: int


def _never() -> bool:
    return False


def wait_until_settled(robot: Robot, sensor: ForceTorqueSensor, settings: SettleSettings,
                       should_stop: Callable[[], bool] = _never,
                       clock_s: Callable[[], float] = time.monotonic) -> SettleResult:
    """Block until the robot is steady and the sensor is still (see the module docstring). Returns how long it took.

    Raises:
        PoseNotSettledError: not settled within ``settings.timeout_s`` seconds.
        DeviceTimeoutError: no sample for ``settings.sensor_timeout_s`` seconds (from the driver).
        StopRequested: ``should_stop()`` became true.
    """
    start = clock_s()
    deadline = start + settings.timeout_s
    steady_since: float | None = None
    times: list[np.ndarray] = []
    wrenches: list[np.ndarray] = []
    thresholds = settings.thresholds
    window_std = np.full(6, np.inf)
    count = 0
    last_sample = start
    while True:
        loop_start = time.monotonic()
        if should_stop():
            raise StopRequested("stop requested while settling")
        try:
            batch = sensor.read(timeout_s=min(settings.sensor_timeout_s, READ_TIMEOUT_CAP_S))
        except DeviceTimeoutError:
            batch = None  # silence shorter than sensor_timeout_s is tolerated (checked below)
        now = clock_s()
        if batch is not None and len(batch):
            last_sample = now
            good = ~batch.saturated
            times.append(batch.time_s[good])
            wrenches.append(batch.wrench[good])
        elif now - last_sample > settings.sensor_timeout_s:
            raise DeviceTimeoutError(f"the sensor went silent: no sample for {settings.sensor_timeout_s:g} s "
                                     "while settling")
        if robot.is_steady():
            steady_since = now if steady_since is None else steady_since
        else:
            steady_since = None
            times.clear()
            wrenches.clear()
        if times:
            all_t = np.concatenate(times)
            keep_from = int(np.searchsorted(all_t, all_t[-1] - settings.window_s))
            all_w = np.concatenate(wrenches)[keep_from:]
            all_t = all_t[keep_from:]
            times[:] = [all_t]
            wrenches[:] = [all_w]
            count = len(all_t)
            spans_window = steady_since is not None and now - steady_since >= settings.window_s
            if count >= MIN_SETTLE_SAMPLES and spans_window:
                window_std = all_w.std(axis=0, ddof=1)
                if steady_since is not None and now - steady_since >= settings.settle_time_s \
                        and np.all(window_std <= thresholds):
                    return SettleResult(now - start, window_std, count)
        if now >= deadline:
            if steady_since is None:
                why = "the robot never reported steady"
            elif not np.all(np.isfinite(window_std)):
                why = "too few sensor samples in the settle window"
            else:
                worst = int(np.argmax(window_std / thresholds))
                unit = "N" if worst < 3 else "N·m"
                why = (f"{AXES[worst]} std {window_std[worst]:.4g} {unit} stayed above "
                       f"{thresholds[worst]:g} {unit}")
            raise PoseNotSettledError(f"the pose did not settle within {settings.timeout_s:g} s: {why}")
        pause = SETTLE_POLL_PERIOD_S - (time.monotonic() - loop_start)
        if pause > 0:
            time.sleep(pause)


def average_at_pose(sensor: ForceTorqueSensor, settings: SettleSettings,
                    should_stop: Callable[[], bool] = _never) -> tuple[WrenchAverage, float, float]:
    """Average fresh samples for ``settings.average_time_s`` seconds; return (average, t_start, t_end) in UNIX s.

    Raises SensorFaultError when every sample was saturated, DeviceTimeoutError when the sensor is silent,
    StopRequested when a stop was requested before averaging began.
    """
    info = getattr(sensor, "info", None)
    rate_hz = float(getattr(info, "rate_hz", 0.0) or 0.0)
    minimum = max(MIN_SAMPLES, int(MIN_SAMPLE_FRACTION * rate_hz * settings.average_time_s))
    best: tuple[WrenchAverage, float, float] | None = None
    window_s = settings.average_time_s
    for attempt in range(MAX_AVERAGE_ATTEMPTS):
        if should_stop():
            raise StopRequested("stop requested before averaging")
        t_start = time.time()
        average = sensor.average(window_s, timeout_s=window_s + settings.sensor_timeout_s)
        t_end = time.time()
        if best is None or average.count > best[0].count:
            best = (average, t_start, t_end)
        if average.count >= minimum:
            break
        last = attempt + 1 == MAX_AVERAGE_ATTEMPTS
        log.warning("averaging window %d/%d: %d samples in %.3g s, expected at least %d (%.0f Hz); %s",
                    attempt + 1, MAX_AVERAGE_ATTEMPTS, average.count, window_s, minimum, rate_hz,
                    f"keeping the fullest ({best[0].count} samples)" if last else
                    f"averaging again over {2 * window_s:.3g} s")
        window_s *= 2.0
    assert best is not None
    average, t_start, t_end = best
    if average.count < MIN_SAMPLES:
        raise SensorFaultError(f"only {average.count} usable sample(s) in the fullest of {MAX_AVERAGE_ATTEMPTS} "
                               f"averaging windows ({settings.average_time_s:g} s, doubled after each short one; "
                               f"{average.saturated} saturated, {average.lost} lost)")
    if not np.all(np.isfinite(average.mean)):
        raise SensorFaultError("the averaged wrench is not finite")
    return average, t_start, t_end


__all__ = ["SettleSettings", "SettleResult", "PoseNotSettledError", "StopRequested", "wait_until_settled",
           "average_at_pose"]
