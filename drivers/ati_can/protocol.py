"""ATI NETCANOEM wire protocol (docs/protocols-ati.md, "CAN"): request and reply opcodes, reply lengths, gage
limits, status bits, and the board's calibration as it reports it. Tables and pure functions, no I/O.

The host sends ``ID = (base << 4) | opcode`` and the board replies on the IDs of the reply opcodes, big-endian.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sensor import STATUS_SATURATION, STATUS_SUMMARY

OP_GAGES = 0x0
"""Request gages; replies op 0x0 (u16 status, i16 sg0, sg2, sg4) then op 0x1 (i16 sg1, sg3, sg5)."""
OP_GAGES_SECOND = 0x1
OP_MATRIX = 0x2
"""Request one matrix row (1 byte, 0 Fx … 5 Tz); replies ops 0x2, 0x3, 0x4 with two f32 each."""
OP_SERIAL = 0x5
OP_SELECT_CALIBRATION = 0x6
OP_COUNTS_PER_UNIT = 0x7
OP_UNIT_CODES = 0x8
OP_DIAGNOSTIC_ADC = 0x9
OP_RESET = 0xC
OP_FIRMWARE = 0xF

REPLY_LENGTHS = {
    OP_GAGES: 8,
    OP_GAGES_SECOND: 6,
    OP_MATRIX: 8,
    OP_MATRIX + 1: 8,
    OP_MATRIX + 2: 8,
    OP_SERIAL: 8,
    OP_SELECT_CALIBRATION: 1,
    OP_COUNTS_PER_UNIT: 8,
    OP_UNIT_CODES: 2,
    OP_DIAGNOSTIC_ADC: 2,
    OP_FIRMWARE: 4,
}
"""Data length of every reply opcode; a frame on our IDs with another length is malformed."""

GAGE_MAX = 32767
GAGE_MIN = -32768
FIRMWARE_WITH_COUNTS = (3, 7)
"""Opcodes 0x7 (counts per unit) and 0x8 (unit codes) exist from firmware 3.7."""
LEGACY_COUNTS_PER_UNIT = 1_000_000.0
"""Counts per unit of boards older than firmware 3.7 (and of every MINI45 calibration)."""

STATUS_BIT_NAMES = {
    0: "watchdog reset",
    1: "DAC/ADC check too high",
    2: "DAC/ADC check too low",
    3: "artificial ground out of range",
    4: "supply too high",
    5: "supply too low",
    6: "bad active calibration",
    7: "EEPROM failure",
    8: "configuration invalid (defaults used)",
    11: "sensor temperature too high",
    12: "sensor temperature too low",
    14: "CAN bus error",
    15: "any error",
}
"""NETCANOEM u16 status bits."""
STATUS_CRITICAL_MASK = sum(1 << b for b in (1, 2, 3, 4, 5, 6, 7, 11, 12))
"""Bits the manual calls critical: the board keeps sending data, so the host must act on them."""
STATUS_ERROR_MASK = STATUS_CRITICAL_MASK | (1 << 15)
"""A sample whose status has any of these bits is flagged (``WrenchBatch.saturated``) and never averaged."""
STATUS_WATCHDOG_RESET = 1 << 0
HOST_STATUS_GAGE_SATURATED = STATUS_SUMMARY | STATUS_SATURATION
"""Set by this driver in bits 31 and 17 of ``WrenchBatch.status`` when a gage reads +32767 or −32768 (the
board's own u16 status is in bits 0–15); the same bits as the Net F/T saturation status."""



def decode_status(status: int) -> list[str]:
    """Return the names of the NETCANOEM status bits set in ``status`` (bits 0–15), low bit first."""
    return [STATUS_BIT_NAMES.get(bit, f"reserved bit {bit}") for bit in range(16) if status >> bit & 1]


@dataclass(frozen=True)
class CanCalibration:
    """What the board reports about its active calibration.

    Attributes:
        matrix: (6, 6) counts = matrix @ (gages − bias), rows Fx … Tz (as sent, float32 values).
        counts_per_force, counts_per_torque: counts per device unit.
        force_unit, torque_unit: unit names (``N``, ``N-m``, ``N-mm`` …).
        force_si_per_unit, torque_si_per_unit: N per force unit, N·m per torque unit.
    """

    matrix: np.ndarray
    counts_per_force: float
    counts_per_torque: float
    force_unit: str
    torque_unit: str
    force_si_per_unit: float
    torque_si_per_unit: float

    @property
    def gages_to_si(self) -> np.ndarray:
        """(6, 6) K with wrench_si = K @ (gages − bias): rows scaled by SI-per-unit / counts-per-unit."""
        scale = np.array([self.force_si_per_unit / self.counts_per_force] * 3
                         + [self.torque_si_per_unit / self.counts_per_torque] * 3)
        return scale[:, np.newaxis] * self.matrix


__all__ = ["OP_GAGES", "OP_GAGES_SECOND", "OP_MATRIX", "OP_SERIAL", "OP_SELECT_CALIBRATION", "OP_COUNTS_PER_UNIT",
           "OP_UNIT_CODES", "OP_DIAGNOSTIC_ADC", "OP_RESET", "OP_FIRMWARE", "REPLY_LENGTHS", "GAGE_MAX", "GAGE_MIN",
           "FIRMWARE_WITH_COUNTS", "LEGACY_COUNTS_PER_UNIT", "STATUS_BIT_NAMES", "STATUS_CRITICAL_MASK",
           "STATUS_ERROR_MASK", "STATUS_WATCHDOG_RESET", "HOST_STATUS_GAGE_SATURATED", "decode_status",
           "CanCalibration"]
