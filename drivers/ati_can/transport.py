"""The ATI CAN board's bus: opening it, one request and its reply frames, and the frame classifier (our board's
valid replies, or why not, counted in :class:`drivers.sensor.SensorHealth`).

:class:`CanTransport` is a mixin of :class:`drivers.ati_can.driver.AtiCanSensor`: the start-up requests, the poll
loop and the host-side bias share one bus, one lock and one frame classifier (the board answers on the IDs the
host sends on), so these methods use the driver's attributes declared below rather than state of their own.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from drivers.ati_can.protocol import REPLY_LENGTHS
from drivers.sensor import SensorHealth
from ftacq.errors import DeviceConnectionError, DeviceTimeoutError

logger = logging.getLogger(__name__)

STARTUP_ATTEMPTS = 3
"""Tries per start-up request before the board is declared unreachable."""


class CanTransport:
    """The bus half of :class:`~drivers.ati_can.driver.AtiCanSensor` (module docstring)."""

    _bus: Any
    _owns_bus: bool
    interface: str
    channel: str
    bitrate: int
    base: int
    bus_options: dict
    startup_timeout_s: float
    _lock: threading.Condition
    _health: SensorHealth

    def _open_bus(self):
        import can

        filters = [{"can_id": self.base << 4, "can_mask": 0x7F0, "extended": False}]
        try:
            return can.Bus(**{"can_filters": filters, **self.bus_options, "interface": self.interface,
                              "channel": self.channel, "bitrate": self.bitrate, "ignore_config": True})
        except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as error:
            raise DeviceConnectionError(
                f"cannot open CAN interface {self.interface!r} channel {self.channel!r} at {self.bitrate} bit/s: "
                f"{error}") from error

    def _shutdown_owned_bus(self) -> None:
        if self._owns_bus and self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception:  # a failed shutdown must not hide the error that got us here
                logger.exception("shutting down CAN bus %r failed", self.channel)
            self._bus = None
    def _request(self, opcode: int, data: bytes, what: str, reply_ops: tuple[int, ...] | None = None) -> dict[int, bytes]:
        """Send one start-up request and return its reply frames by opcode; retry, then raise DeviceTimeoutError."""
        import can

        reply_ops = reply_ops or (opcode,)
        for _attempt in range(STARTUP_ATTEMPTS):
            tally = SensorHealth()
            self._drain(tally)
            try:
                self._bus.send(can.Message(arbitration_id=self.base << 4 | opcode, data=data, is_extended_id=False))
            except can.CanError as error:
                raise DeviceConnectionError(
                    f"cannot send the {what} request on CAN {self.interface!r} {self.channel!r}: {error}") from error
            replies = self._collect(reply_ops, time.monotonic() + self.startup_timeout_s, tally)
            self._merge(tally)
            if len(replies) == len(reply_ops):
                return replies
        raise DeviceTimeoutError(
            f"ATI CAN board at base {self.base:#04x} on {self.interface} channel {self.channel!r} did not answer "
            f"the {what} request (ID {self.base << 4 | opcode:#05x}) within {self.startup_timeout_s} s, "
            f"{STARTUP_ATTEMPTS} tries: check power, wiring and termination, the bit rate ({self.bitrate} bit/s) "
            f"and the base ID")

    def _collect(self, reply_ops: tuple[int, ...], deadline: float, tally: SensorHealth) -> dict[int, bytes]:
        """Receive frames until every opcode in ``reply_ops`` arrived or ``deadline`` (monotonic) passed.

        Frames that are not wanted replies are counted in ``tally`` (a scratch SensorHealth, merged later).
        """
        replies: dict[int, bytes] = {}
        while len(replies) < len(reply_ops):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            message = self._bus.recv(timeout=remaining)
            if message is None:
                break
            opcode = self._classify(message, tally)
            if opcode is None:
                continue
            if opcode in reply_ops:
                if opcode in replies:
                    tally.duplicate += 1
                else:
                    replies[opcode] = bytes(message.data)
            else:
                tally.out_of_order += 1  # a reply to another (earlier) request
        return replies

    def _classify(self, message, tally: SensorHealth) -> int | None:
        """Return the reply opcode of a valid frame from our board, or None (counting why in ``tally``)."""
        if not getattr(message, "is_rx", True):
            return None  # our own request, echoed back
        if message.is_error_frame or message.is_remote_frame or message.is_extended_id:
            tally.foreign += 1
            return None
        if message.arbitration_id >> 4 != self.base:
            tally.foreign += 1
            return None
        opcode = message.arbitration_id & 0xF
        if REPLY_LENGTHS.get(opcode) != message.dlc:
            tally.malformed += 1
            return None
        return opcode

    def _drain(self, tally: SensorHealth) -> None:
        """Discard frames already queued (late replies to a request that timed out), counting them."""
        while (message := self._bus.recv(timeout=0.0)) is not None:
            if self._classify(message, tally) is not None:
                tally.out_of_order += 1

    def _merge(self, tally: SensorHealth) -> None:
        """Add the frame counters of ``tally`` to the driver's health (under the lock)."""
        if tally.duplicate or tally.out_of_order or tally.malformed or tally.foreign:
            with self._lock:
                self._health.duplicate += tally.duplicate
                self._health.out_of_order += tally.out_of_order
                self._health.malformed += tally.malformed
                self._health.foreign += tally.foreign


__all__ = ["CanTransport", "STARTUP_ATTEMPTS"]
