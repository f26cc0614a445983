"""Net F/T wire facts: RDT commands and the 36-byte record, the TCP calibration query, status bits, defaults.

Everything here is stated in docs/protocols-ati.md ("Net F/T"); nothing here does I/O.

- RDT (UDP, box port 49152): the host sends 8 bytes ``>HHI`` = header 0x1234, command, sample count (0 = stream
  until stopped). The box answers to the sender's address and port with 36-byte records ``>III6i`` =
  ``rdt_sequence`` (per stream, the first record of a stream is 1), ``ft_sequence`` (the box's internal sample
  counter: it runs on across streams and restarts only at power-up), ``status`` and six counts Fx, Fy, Fz, Tx,
  Ty, Tz. Buffered mode (0x0003) packs ``comrdtbsiz`` records into one datagram.
- TCP (box port 49151): 20-byte commands; READCALINFO (byte 0 = 1) answers 24 bytes ``>HBBII6H``: header 0x1234,
  force and torque unit codes, counts per force and per torque unit, six scale factors.
- Status: bit 31 summarises any error; the Net F/T and the Ethernet Axia use different maps below it.
"""

from __future__ import annotations

import struct

import numpy as np

from drivers.sensor import STATUS_HEALTHY_MASK, STATUS_SATURATION

DEFAULT_RDT_PORT, DEFAULT_TCP_PORT, DEFAULT_HTTP_PORT = 49152, 49151, 80
RDT_HEADER = 0x1234
RDT_STOP, RDT_START, RDT_START_BUFFERED, RDT_RESET_LATCH, RDT_BIAS = 0x0000, 0x0002, 0x0003, 0x0041, 0x0042
RDT_COMMAND_FORMAT = ">HHI"
RECORD_SIZE = 36
RECORD_DTYPE = np.dtype([("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
"""One RDT record, big-endian (decoded in whole batches with ``np.frombuffer``)."""
TCP_READCALINFO = 1
TCP_COMMAND_SIZE, TCP_CALINFO_REPLY_SIZE = 20, 24
TCP_CALINFO_FORMAT = ">HBBII6H"
UINT32_MASK = 0xFFFF_FFFF
HALF_RANGE = 1 << 31
"""Sequence differences (mod 2³²) at or above this are backward steps."""
INTERNAL_RATE_HZ = 7000.0
"""The box's internal sample rate (``runrate`` in netftapi2.xml), Hz: ``ft_sequence`` counts at this rate, so at
``comrdtrate`` = 7000/n Hz it advances by n per record."""

# Status maps: error bits (flag the sample, never average it) and saturation bits.
NETFT_ERROR_MASK = UINT32_MASK & ~STATUS_HEALTHY_MASK
NETFT_SATURATION_MASK = STATUS_SATURATION
AXIA_INFORMATIONAL = (1 << 31) | (1 << 28) | (1 << 16) | (1 << 3)
"""Axia bits that are not errors: summary, simulated error, monitor latch, busy."""
AXIA_ERROR_MASK = UINT32_MASK & ~AXIA_INFORMATIONAL
AXIA_SATURATION_MASK = (1 << 30) | (1 << 27) | (1 << 2)
"""Axia: F/T saturated, gage out of range, broken gage."""
STATUS_MAPS = {"netft": (NETFT_ERROR_MASK, NETFT_SATURATION_MASK), "axia": (AXIA_ERROR_MASK, AXIA_SATURATION_MASK)}
NETFT_STATUS_BITS = {31: "error summary", 30: "CPU/RAM error", 29: "digital board error", 28: "analog board error",
                     27: "serial link error", 26: "program memory error", 25: "halted: configuration errors",
                     24: "settings validation error", 23: "configuration incompatible with calibration",
                     22: "network failure", 21: "CAN error", 20: "RDT error", 19: "EtherNet/IP failure",
                     18: "DeviceNet failure", 17: "transducer saturation or A/D error",
                     16: "monitor condition latched", 14: "watchdog timeout", 13: "stack check error",
                     12: "EEPROM failure", 11: "flash failure", 10: "analog board watchdog",
                     9: "excitation current too high", 8: "excitation current too low",
                     7: "analog ground out of range", 6: "analog supply too high", 5: "analog supply too low",
                     4: "serial link data unavailable", 3: "reference voltage error", 2: "temperature error",
                     1: "HTTP protocol failure"}
AXIA_STATUS_BITS = {0: "temperature out of range", 1: "supply voltage out of range", 2: "broken gage",
                    3: "busy", 5: "common error", 16: "monitor condition latched", 27: "gage out of range",
                    28: "simulated error", 29: "calibration checksum error", 30: "F/T saturated",
                    31: "error summary"}


def rdt_command(command: int, count: int = 0) -> bytes:
    """Return the 8-byte RDT request for ``command`` (count 0: stream until stopped)."""
    return struct.pack(RDT_COMMAND_FORMAT, RDT_HEADER, command, count)


def status_text(status: int, status_map: str = "netft") -> str:
    """Return the names of the set bits of a status word, e.g. "error summary, transducer saturation or A/D error"."""
    names = AXIA_STATUS_BITS if status_map == "axia" else NETFT_STATUS_BITS
    return ", ".join(names.get(bit, f"bit {bit}") for bit in range(31, -1, -1) if status >> bit & 1) or "ok"
