"""A tap on a sensor: every batch it delivers becomes a :class:`procedures.events.WrenchSamples` event.

The calibration procedure taps its sensor while it runs, so its listeners (the dashboard's wrench plots) see
the raw stream of every settle and averaging window without the procedure knowing who listens. The tap
shadows the sensor object's ``read`` with an instance attribute for as long as it is attached: the driver's own
``average`` calls ``self.read`` and is therefore tapped too, with its device-specific semantics intact (fresh
samples, lost counts). Detaching removes the attribute.
"""

from __future__ import annotations

from drivers.sensor import ForceTorqueSensor, WrenchBatch
from procedures import events


class SensorTap:
    """Attach to a sensor (``with SensorTap(sensor, publish):``); ``publish`` gets a WrenchSamples per read.

    The events carry no robot state: the procedure's PoseMeasured says where the arm was.
    """

    def __init__(self, sensor: ForceTorqueSensor, publish: events.Listener) -> None:
        self.sensor = sensor
        self.publish = publish
        self._attached = False
        self._original = sensor.read
        self._had_own_read = False

    def _read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        batch = self._original(timeout_s=timeout_s)
        if len(batch):
            self.publish(events.WrenchSamples(batch))
        return batch

    def attach(self) -> "SensorTap":
        if not self._attached:
            self._had_own_read = "read" in vars(self.sensor)
            self._original = self.sensor.read
            self.sensor.read = self._read  # type: ignore[method-assign]  # instance attribute, see module doc
            self._attached = True
        return self

    def detach(self) -> None:
        """Restore the sensor's own ``read`` (safe twice)."""
        if self._attached:
            if self._had_own_read:
                self.sensor.read = self._original  # type: ignore[method-assign]
            else:
                del self.sensor.read
            self._attached = False

    def __enter__(self) -> "SensorTap":
        return self.attach()

    def __exit__(self, *exc_info) -> None:
        self.detach()


__all__ = ["SensorTap"]
