"""Moved to :mod:`ftacq.timebase` (issue 40: one time base for every stream). This alias stays only until
procedures/monitor.py and procedures/dynamic_compensation.py import from there; new code imports ftacq.timebase."""

from ftacq.timebase import CLOCK_WINDOW_S, DeviceClock, SampleClock, device_to_host_clock

__all__ = ["CLOCK_WINDOW_S", "DeviceClock", "SampleClock", "device_to_host_clock"]
