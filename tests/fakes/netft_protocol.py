"""Net F/T wire format for the simulated box: RDT commands and records, TCP replies, units, rate quantisation.

Pure: no sockets, no threads, no state (the box is tests/fakes/netft_box.py, its servers tests/fakes/netft.py).
The facts are those of docs/protocols-ati.md ("Net F/T").
"""

from __future__ import annotations

import socket
import struct
from dataclasses import dataclass, field

import numpy as np

RDT_HEADER = 0x1234
RDT_STOP, RDT_START_SINGLE_BLOCK, RDT_START, RDT_START_BUFFERED, RDT_START_MULTI_UNIT = 0x0000, 0x0001, 0x0002, 0x0003, 0x0004
RDT_RESET_LATCH, RDT_BIAS = 0x0041, 0x0042
RDT_EXTENDED_FLAG = 0x8000
RECORD_SIZE = 36
RECORD_DTYPE = np.dtype([("rdt_sequence", ">u4"), ("ft_sequence", ">u4"), ("status", ">u4"), ("counts", ">i4", (6,))])
UINT32_MASK = 0xFFFF_FFFF
INT32_MAX, INT32_MIN = 2**31 - 1, -(2**31)

INTERNAL_RATE_HZ = 7000.0
"""The Net F/T's internal sample rate; ``comrdtrate`` is quantised to INTERNAL_RATE_HZ / n."""
MIN_BUFFER_SIZE, MAX_BUFFER_SIZE = 1, 40

TCP_COMMAND_SIZE = 20
TCP_READFT, TCP_READCALINFO, TCP_WRITETRANSFORM, TCP_WRITETHRESHOLD = 0, 1, 2, 3
INT16_MAX = 32767

STATUS_SUMMARY = 0x8000_0000
STATUS_SATURATION = 0x0002_0000
STATUS_LATCH = 0x0001_0000

FORCE_UNIT_CODES = {"lbf": 1, "N": 2, "klbf": 3, "kN": 4, "kgf": 5, "gf": 6}
TORQUE_UNIT_CODES = {"lbf-in": 1, "lbf-ft": 2, "N-m": 3, "Nm": 3, "N-mm": 4, "Nmm": 4, "kgf-cm": 5, "kN-m": 6}
NEWTONS_PER_FORCE_UNIT = {"lbf": 4.4482216152605, "N": 1.0, "klbf": 4448.2216152605, "kN": 1000.0,
                          "kgf": 9.80665, "gf": 0.00980665}
NEWTON_METRES_PER_TORQUE_UNIT = {"lbf-in": 0.112984829027617, "lbf-ft": 1.3558179483314, "N-m": 1.0, "Nm": 1.0,
                                 "N-mm": 0.001, "Nmm": 0.001, "kgf-cm": 0.0980665, "kN-m": 1000.0}

RDT_STARTS = (RDT_START_SINGLE_BLOCK, RDT_START, RDT_START_BUFFERED, RDT_START_MULTI_UNIT)


@dataclass(frozen=True)
class ReceivedCommand:
    """One thing the fake received. ``source`` is "udp", "tcp" or "http".

    udp: ``code`` = RDT command, ``count`` = sample count, ``raw`` = the datagram. tcp: ``code`` = command byte,
    ``raw`` = the 20 bytes. http: ``code`` = the path (e.g. "/comm.cgi"), ``params`` = the query.
    """

    source: str
    code: int | str
    count: int = 0
    address: tuple = ()
    time_s: float = 0.0
    raw: bytes = b""
    params: dict = field(default_factory=dict)


def quantise_rate_hz(requested_hz: float, max_rate_hz: float = INTERNAL_RATE_HZ) -> tuple[float, int]:
    """Return (rate Hz, ft_sequence step) the box streams at for a requested ``comrdtrate``.

    Up to the internal rate: INTERNAL_RATE_HZ / n with n = floor(7000 / requested), i.e. rounded **up**
    (150 → 7000/46 ≈ 152.2). Above it (only when ``max_rate_hz`` allows): the requested rate, step 1.
    """
    requested_hz = max(float(requested_hz), 1.0)
    if requested_hz > INTERNAL_RATE_HZ and max_rate_hz > INTERNAL_RATE_HZ:
        return min(requested_hz, max_rate_hz), 1
    divisor = max(1, int(INTERNAL_RATE_HZ // min(requested_hz, INTERNAL_RATE_HZ)))
    return INTERNAL_RATE_HZ / divisor, divisor


def parse_rdt_command(data: bytes) -> tuple[int, int, tuple | None] | None:
    """Return (command, sample count, embedded target address or None) of an RDT request, or None if malformed.

    The 8-byte form is ``>HHI`` (header 0x1234, command, count); the 14-byte extended form sets bit 15 of the
    command and appends an IPv4 address and port to stream to."""
    if len(data) not in (8, 14):
        return None
    header, command, count = struct.unpack(">HHI", data[:8])
    if header != RDT_HEADER:
        return None
    if command & RDT_EXTENDED_FLAG:
        if len(data) != 14:
            return None
        ip, port = struct.unpack(">4sH", data[8:14])
        return command & ~RDT_EXTENDED_FLAG, count, (socket.inet_ntoa(ip), port)
    if len(data) != 8:
        return None
    return command, count, None


def xml_text(value) -> str:
    """Escape a value for an XML element's text."""
    return str(value).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")

