"""A fake ATI NETCANOEM board on a python-can bus (docs/protocols-ati.md, "CAN").

The board answers requests only. Every request and its reply use 11-bit IDs ``(base << 4) | opcode``, big-endian
data. Raw strain gages come from the simulated cell's physics through the calibration matrix::

    sg = M⁻¹ · (FT_device · Cp) + gage_offset          (rounded, saturated to int16)

where ``FT_device`` is the physics' wrench in the board's units (force unit code, torque unit code), ``Cp`` the
counts per force (rows 0–2) or torque (rows 3–5) and ``M`` the float32 matrix the board sends on opcode 0x2, so
a host that computes ``M · (sg − bias) / Cp`` gets the wrench back within one gage count.

python-can's ``virtual`` interface links every bus on one channel name *in one process*, and a bus does not
receive its own frames; pass a channel name (the fake opens its own virtual bus) or any ``can.BusABC``. The
reading follows the robot because ``physics`` reads its pose source (a ``SettablePose`` in tests, or a
``SharedPose`` written by the simulated UR controller in another process).

Knobs (thread-safe, usable while a driver polls): ``status`` (u16 status word), ``saturate_gage`` /
``clear_saturation``, ``silent``, ``drop_reply_frames``, ``gage_offset``, ``power_cycle``,
``watchdog_reset``. Observables:
``received`` (every frame the board saw), ``requests(op)``, ``active_calibration_index``, ``reset_count``.

Over 600 lines: the board's request/reply codec and its gage physics in one file, because every opcode reads the
same calibration state; the codec is the next candidate to move apart.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import Protocol

import can
import numpy as np

logger = logging.getLogger(__name__)

DEFAULT_BASE = 0x20
DEFAULT_BITRATE = 250_000
RECV_POLL_S = 0.05
"""How long the reader thread blocks in ``bus.recv`` before checking its stop flag, seconds."""
CLOSE_JOIN_TIMEOUT_S = 2.0

OP_GAGES = 0x0
OP_GAGES_SECOND = 0x1
OP_MATRIX = 0x2
OP_SERIAL = 0x5
OP_SELECT_CALIBRATION = 0x6
OP_COUNTS_PER_UNIT = 0x7
OP_UNIT_CODES = 0x8
OP_DIAGNOSTIC_ADC = 0x9
OP_RESET = 0xC
OP_SET_BASE = 0xD
OP_SET_BITRATE = 0xE
OP_FIRMWARE = 0xF

GAGE_MAX = 32767
GAGE_MIN = -32768
CALIBRATION_SLOTS = 16
STATUS_ANY_ERROR = 0x8000
STATUS_BAD_CALIBRATION = 0x0040
STATUS_CAN_BUS_ERROR = 0x4000
FIRMWARE_WITH_COUNTS = (3, 7)
"""Opcodes 0x7 and 0x8 exist from firmware 3.7; older boards imply 1 000 000 counts per unit."""
FIRMWARE_WITH_DIAGNOSTICS = (3, 8)
LEGACY_COUNTS_PER_UNIT = 1_000_000

FORCE_UNIT_TO_SI = {1: 4.4482216152605, 2: 1.0, 3: 4448.2216152605, 4: 1000.0, 5: 9.80665, 6: 0.00980665}
"""Force unit code → newtons per unit (docs/protocols-ati.md, "Units": lbf, N, klbf, kN, kgf, gf)."""
TORQUE_UNIT_TO_SI = {1: 0.112984829027617, 2: 1.3558179483314, 3: 1.0, 4: 0.001, 5: 0.0980665, 6: 1000.0}
"""Torque unit code → N·m per unit (lbf-in, lbf-ft, N-m, N-mm, kgf-cm, kN-m)."""

DIAGNOSTIC_READINGS = {0: 2048, 1: 0, 2: 1650, 3: 3100, 4: 2048, 5: 3}
"""Fixed raw readings of the diagnostic ADC channels (MID_VSG, unused, thermistor, power, DAC, ground)."""

FULL_SCALE_GAGE_COUNTS = 20_000.0
"""Gage reading of the default matrix at the default full-scale load (leaves head-room to ±32767)."""


class WrenchPhysics(Protocol):
    """Anything that returns noisy wrench samples (n, 6) in N and N·m: tests/fakes/world.SensorPhysics."""

    def sample(self, n: int) -> np.ndarray: ...


@dataclass(frozen=True)
class FakeCanCalibration:
    """One calibration slot of the board.

    Attributes:
        matrix: (6, 6) float32 calibration matrix, counts = matrix @ (gages − bias) (row 0 Fx … 5 Tz).
        counts_per_force, counts_per_torque: integer counts per force / torque unit (opcode 0x7).
        force_unit_code, torque_unit_code: unit codes (docs/protocols-ati.md, "Units"), e.g. 2 = N, 3 = N-m, 4 = N-mm.
    """

    matrix: np.ndarray
    counts_per_force: int
    counts_per_torque: int
    force_unit_code: int = 2
    torque_unit_code: int = 3
    _poll_arrays: tuple = field(init=False, repr=False, compare=False)
    """(SI per unit, counts per unit, the matrix as float64): what every gage poll needs, computed once."""

    def __post_init__(self) -> None:
        matrix = np.asarray(self.matrix, dtype=np.float32)
        if matrix.shape != (6, 6) or not np.all(np.isfinite(matrix)):
            raise ValueError(f"calibration matrix must be a finite 6×6 array, got shape {matrix.shape}")
        object.__setattr__(self, "matrix", matrix)
        for name in ("counts_per_force", "counts_per_torque"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and 0 < value < 2**32):
                raise ValueError(f"{name} must be an integer in 1..2**32-1 (sent as u32), got {value!r}")
        if self.force_unit_code not in FORCE_UNIT_TO_SI:
            raise ValueError(f"force_unit_code {self.force_unit_code} not in {sorted(FORCE_UNIT_TO_SI)}")
        if self.torque_unit_code not in TORQUE_UNIT_TO_SI:
            raise ValueError(f"torque_unit_code {self.torque_unit_code} not in {sorted(TORQUE_UNIT_TO_SI)}")
        object.__setattr__(self, "_poll_arrays", (self.si_per_unit, self.counts_per_unit, matrix.astype(np.float64)))

    @property
    def counts_per_unit(self) -> np.ndarray:
        """(6,) Cp per row: CpF for Fx–Fz, CpT for Tx–Tz."""
        return np.array([self.counts_per_force] * 3 + [self.counts_per_torque] * 3, dtype=float)

    @property
    def si_per_unit(self) -> np.ndarray:
        """(6,) SI value (N or N·m) of one device unit per row."""
        return np.array(
            [FORCE_UNIT_TO_SI[self.force_unit_code]] * 3 + [TORQUE_UNIT_TO_SI[self.torque_unit_code]] * 3
        )

    def gages_from_wrench(self, wrench_si: np.ndarray, gage_offset: np.ndarray) -> np.ndarray:
        """Return int16-saturated gages (6,) int64 for a wrench in N and N·m: sg = M⁻¹·(FT·Cp) + offset."""
        si_per_unit, counts_per_unit, matrix = self._poll_arrays
        counts = np.asarray(wrench_si, dtype=float) / si_per_unit * counts_per_unit
        gages = np.linalg.solve(matrix, counts) + gage_offset
        return np.minimum(np.maximum(np.rint(gages), GAGE_MIN), GAGE_MAX).astype(np.int64)

    def wrench_from_gages(self, gages: np.ndarray, gage_bias: np.ndarray | None = None) -> np.ndarray:
        """Return the wrench (…, 6) in N and N·m a correct host computes from gages (for tests)."""
        raw = np.asarray(gages, dtype=float) - (0.0 if gage_bias is None else gage_bias)
        return raw @ self.matrix.astype(np.float64).T / self.counts_per_unit * self.si_per_unit

    def quantisation_tolerance(self) -> np.ndarray:
        """(6,) N and N·m: the wrench change of one gage count on every gage, through the matrix."""
        return np.abs(self.matrix.astype(np.float64)).sum(axis=1) / self.counts_per_unit * self.si_per_unit


def default_calibration_matrix(
    counts_per_force: int,
    counts_per_torque: int,
    force_unit_code: int = 2,
    torque_unit_code: int = 3,
    force_range_n: float = 500.0,
    torque_range_nm: float = 15.0,
    seed: int = 7,
) -> np.ndarray:
    """Return a plausible coupled float32 matrix whose full-scale load reads about 20 000 gage counts.

    The gage response to a unit load is a diagonal gain with ±15 % cross-coupling (seeded), as in a real
    six-gage structure; the returned matrix is ``diag(Cp) · G⁻¹`` so that counts = M · gages.
    """
    rng = np.random.default_rng(seed)
    device_range = np.array(
        [force_range_n / FORCE_UNIT_TO_SI[force_unit_code]] * 3 + [torque_range_nm / TORQUE_UNIT_TO_SI[torque_unit_code]] * 3
    )
    gages_per_unit = FULL_SCALE_GAGE_COUNTS / device_range
    coupling = np.eye(6) + rng.uniform(-0.15, 0.15, (6, 6)) * (1 - np.eye(6))
    gage_response = coupling * gages_per_unit[np.newaxis, :]  # gages = G @ FT_device
    counts_per_unit = np.array([counts_per_force] * 3 + [counts_per_torque] * 3, dtype=float)
    return (counts_per_unit[:, np.newaxis] * np.linalg.inv(gage_response)).astype(np.float32)


@dataclass(frozen=True)
class ReceivedFrame:
    """A frame the board saw: host monotonic receive time (s), 11-bit ID, data bytes."""

    time_s: float
    arbitration_id: int
    data: bytes

    @property
    def opcode(self) -> int:
        return self.arbitration_id & 0xF


class FakeNetCanOem:
    """A simulated NETCANOEM board that answers on a python-can bus from its own reader thread.

    Args:
        bus_or_channel: a ``can.BusABC`` (not shut down on close), or a ``virtual`` channel name (the fake
            opens and owns its bus). Use one unique channel name per test.
        physics: the wrench source (N, N·m), e.g. ``SensorPhysics``; sampled once per gage request.
        base: 7-bit base ID (IDs 0x200–0x20F for 0x20).
        calibration_matrix: (6, 6) counts = M · gages, or None for ``default_calibration_matrix``.
        counts_per_force, counts_per_torque: integer Cp of slot 0.
        force_unit_code, torque_unit_code: slot 0 units (2 = N; 3 = N-m, 4 = N-mm).
        serial: up to 8 ASCII characters. firmware: (major, minor, build); below 3.7 the board does not answer
            0x7/0x8 and its Cp must be 1 000 000; below 3.8 it does not answer 0x9.
        extra_calibrations: further slots 1, 2, … (slot 0 is built from the arguments above).
        gage_offset: (6,) unloaded gage reading in counts (what a host bias removes).
        start: start the reader thread now (default); otherwise call ``start()``.
    """

    def __init__(
        self,
        bus_or_channel: can.BusABC | str,
        physics: WrenchPhysics,
        base: int = DEFAULT_BASE,
        calibration_matrix: np.ndarray | None = None,
        counts_per_force: int = 1_000_000,
        counts_per_torque: int = 1_000_000,
        force_unit_code: int = 2,
        torque_unit_code: int = 3,
        serial: str = "FT23456",
        firmware: tuple[int, int, int] = (3, 8, 0),
        extra_calibrations: list[FakeCanCalibration] | None = None,
        gage_offset: np.ndarray | None = None,
        bitrate: int = DEFAULT_BITRATE,
        start: bool = True,
    ) -> None:
        if not 0 <= base <= 0x7F:
            raise ValueError(f"base {base:#x} out of range 0x00..0x7F (7 bits)")
        if len(serial.encode("ascii")) > 8:
            raise ValueError(f"serial {serial!r} longer than 8 ASCII characters")
        if len(firmware) != 3 or not (0 <= firmware[0] < 256 and 0 <= firmware[1] < 256 and 0 <= firmware[2] < 65536):
            raise ValueError(f"firmware {firmware!r} must be (u8 major, u8 minor, u16 build)")
        legacy = tuple(firmware[:2]) < FIRMWARE_WITH_COUNTS
        if legacy and (counts_per_force, counts_per_torque) != (LEGACY_COUNTS_PER_UNIT, LEGACY_COUNTS_PER_UNIT):
            raise ValueError(f"firmware {firmware} < 3.7 has no counts-per-unit opcode: Cp must be 1 000 000")
        if calibration_matrix is None:
            calibration_matrix = default_calibration_matrix(
                counts_per_force, counts_per_torque, force_unit_code, torque_unit_code
            )
        slot0 = FakeCanCalibration(
            calibration_matrix, counts_per_force, counts_per_torque, force_unit_code, torque_unit_code
        )
        self.calibrations: list[FakeCanCalibration] = [slot0, *(extra_calibrations or [])]
        if len(self.calibrations) > CALIBRATION_SLOTS:
            raise ValueError(f"at most {CALIBRATION_SLOTS} calibration slots, got {len(self.calibrations)}")
        self.physics = physics
        self.serial = serial
        self.firmware = tuple(firmware)
        self._lock = threading.Lock()
        self._base = base
        self._bitrate = bitrate
        self._pending_base: int | None = None
        self._pending_bitrate: int | None = None
        self._active_index = 0
        self._status = 0
        self._saturated: dict[int, int] = {}
        self._silent = False
        self._drop_frames = 0
        self._drop_opcode: int | None = None
        self._gage_offset = np.zeros(6) if gage_offset is None else np.asarray(gage_offset, dtype=float)
        self.received: list[ReceivedFrame] = []
        self.reset_count = 0
        self.replies_sent = 0
        self.error: BaseException | None = None
        if isinstance(bus_or_channel, str):
            self._bus = can.Bus(interface="virtual", channel=bus_or_channel, ignore_config=True)
            self._owns_bus = True
            self.channel_name = bus_or_channel
        else:
            self._bus = bus_or_channel
            self._owns_bus = False
            self.channel_name = str(getattr(bus_or_channel, "channel_info", bus_or_channel))
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False
        if start:
            self.start()

    # ----------------------------------------------------------------- lifecycle

    def start(self) -> None:
        """Start the reader thread (named after the channel and base)."""
        if self._thread is not None:
            return
        self._thread = threading.Thread(
            target=self._run, name=f"FakeNetCanOem-{self.channel_name}-{self._base:#04x}", daemon=False
        )
        self._thread.start()

    def close(self) -> None:
        """Stop and join the reader thread, shut down an owned bus, and re-raise the thread's error. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(CLOSE_JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                raise RuntimeError(f"{self._thread.name} did not stop within {CLOSE_JOIN_TIMEOUT_S} s")
        if self._owns_bus:
            self._bus.shutdown()
        if self.error is not None:
            raise RuntimeError(f"FakeNetCanOem reader thread failed: {self.error!r}") from self.error

    def __enter__(self) -> "FakeNetCanOem":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"FakeNetCanOem(channel={self.channel_name!r}, base={self._base:#04x}, serial={self.serial!r}, "
            f"firmware={self.firmware}, slot={self._active_index}, status={self._status:#06x})"
        )

    # ----------------------------------------------------------------- knobs

    @property
    def base(self) -> int:
        """The base ID in use (a set-base request takes effect at ``power_cycle``)."""
        return self._base

    @property
    def bitrate(self) -> int:
        """The bit rate in use, bit/s (informational on a virtual bus)."""
        return self._bitrate

    @property
    def active_calibration_index(self) -> int:
        return self._active_index

    @property
    def active_calibration(self) -> FakeCanCalibration:
        """The calibration of the active slot (slot 0 if the selected slot is empty)."""
        with self._lock:
            return self._calibration_locked()

    @property
    def status(self) -> int:
        """The u16 status word the board sends with every gage reply (bit 6 is added for an empty slot)."""
        return self._status

    @status.setter
    def status(self, value: int) -> None:
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"status {value:#x} out of range 0..0xFFFF (u16)")
        with self._lock:
            self._status = value

    @property
    def silent(self) -> bool:
        """While True the board answers nothing (cable pulled, board off)."""
        return self._silent

    @silent.setter
    def silent(self, value: bool) -> None:
        with self._lock:
            self._silent = bool(value)

    @property
    def gage_offset(self) -> np.ndarray:
        return self._gage_offset.copy()

    @gage_offset.setter
    def gage_offset(self, value: np.ndarray) -> None:
        with self._lock:
            self._gage_offset = np.asarray(value, dtype=float).reshape(6)

    def saturate_gage(self, index: int, high: bool = True) -> None:
        """Force gage ``index`` (0–5) to read +32767 (high) or −32768 (low), as with a broken cable."""
        if not 0 <= index < 6:
            raise ValueError(f"gage index {index} out of range 0..5")
        with self._lock:
            self._saturated[index] = GAGE_MAX if high else GAGE_MIN

    def clear_saturation(self) -> None:
        with self._lock:
            self._saturated.clear()

    def drop_reply_frames(self, count: int, opcode: int | None = None) -> None:
        """Do not send the next ``count`` reply frames (only those of ``opcode``, if given)."""
        with self._lock:
            self._drop_frames = count
            self._drop_opcode = opcode

    def power_cycle(self) -> None:
        """Simulate a power cycle: apply a pending base ID / bit rate, return to calibration slot 0."""
        with self._lock:
            if self._pending_base is not None:
                self._base, self._pending_base = self._pending_base, None
            if self._pending_bitrate is not None:
                self._bitrate, self._pending_bitrate = self._pending_bitrate, None
            self._active_index = 0

    def watchdog_reset(self) -> None:
        """Simulate a watchdog reset: back to calibration slot 0, status bit 0 (watchdog reset) set."""
        with self._lock:
            self._active_index = 0
            self._status |= 0x0001
            self.reset_count += 1

    def requests(self, opcode: int | None = None) -> list[ReceivedFrame]:
        """Frames received on this board's IDs (optionally one opcode), oldest first."""
        with self._lock:
            frames = list(self.received)
            base = self._base
        return [f for f in frames if f.arbitration_id >> 4 == base and (opcode is None or f.opcode == opcode)]

    def gages_now(self) -> np.ndarray:
        """The gages (6,) the board would send now (samples the physics once)."""
        with self._lock:
            return self._gages_locked()

    # ----------------------------------------------------------------- protocol

    def _calibration_locked(self) -> FakeCanCalibration:
        if self._active_index < len(self.calibrations):
            return self.calibrations[self._active_index]
        return self.calibrations[0]

    def _gages_locked(self) -> np.ndarray:
        wrench = np.asarray(self.physics.sample(1), dtype=float).reshape(6)
        gages = self._calibration_locked().gages_from_wrench(wrench, self._gage_offset)
        for index, value in self._saturated.items():
            gages[index] = value
        return gages

    def _status_locked(self) -> int:
        status = self._status
        if self._active_index >= len(self.calibrations):
            status |= STATUS_BAD_CALIBRATION | STATUS_ANY_ERROR
        return status

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                message = self._bus.recv(timeout=RECV_POLL_S)
                if message is None or self._stop.is_set():
                    continue
                if message.is_error_frame or message.is_remote_frame or message.is_extended_id:
                    continue
                if not getattr(message, "is_rx", True):
                    continue  # our own frame echoed back (socketcan with receive_own_messages)
                self._handle(message)
        except BaseException as error:  # kept and re-raised by close()
            if not self._stop.is_set():
                self.error = error
                logger.exception("FakeNetCanOem reader thread failed")

    def _handle(self, message: can.Message) -> None:
        data = bytes(message.data)
        with self._lock:
            self.received.append(ReceivedFrame(time.monotonic(), message.arbitration_id, data))
            if message.arbitration_id >> 4 != self._base or self._silent:
                return
            replies = self._replies_locked(message.arbitration_id & 0xF, data)
            replies = [r for r in replies if not self._drop_locked(r[0])]
            base = self._base
        for opcode, payload in replies:
            self._bus.send(can.Message(arbitration_id=(base << 4) | opcode, data=payload, is_extended_id=False))
            self.replies_sent += 1

    def _drop_locked(self, opcode: int) -> bool:
        if self._drop_frames > 0 and (self._drop_opcode is None or self._drop_opcode == opcode):
            self._drop_frames -= 1
            return True
        return False

    def _replies_locked(self, opcode: int, data: bytes) -> list[tuple[int, bytes]]:
        """Return the (opcode, payload) frames that answer a request; the request DLC is never checked."""
        firmware = tuple(self.firmware[:2])
        if opcode == OP_GAGES:
            sg = self._gages_locked().tolist()
            status = self._status_locked()
            return [
                (OP_GAGES, struct.pack(">Hhhh", status, sg[0], sg[2], sg[4])),
                (OP_GAGES_SECOND, struct.pack(">hhh", sg[1], sg[3], sg[5])),
            ]
        if opcode == OP_MATRIX:
            if not data or data[0] > 5:
                return []
            row = self._calibration_locked().matrix[data[0]].astype(">f4")
            return [(OP_MATRIX + k, row[2 * k : 2 * k + 2].tobytes()) for k in range(3)]
        if opcode == OP_SERIAL:
            return [(OP_SERIAL, self.serial.encode("ascii").ljust(8, b"\x00"))]
        if opcode == OP_SELECT_CALIBRATION:
            if not data or data[0] >= CALIBRATION_SLOTS:
                return []
            self._active_index = data[0]
            return [(OP_SELECT_CALIBRATION, bytes([data[0]]))]
        if opcode == OP_COUNTS_PER_UNIT and firmware >= FIRMWARE_WITH_COUNTS:
            calibration = self._calibration_locked()
            return [(OP_COUNTS_PER_UNIT, struct.pack(">II", calibration.counts_per_force, calibration.counts_per_torque))]
        if opcode == OP_UNIT_CODES and firmware >= FIRMWARE_WITH_COUNTS:
            calibration = self._calibration_locked()
            return [(OP_UNIT_CODES, bytes([calibration.force_unit_code, calibration.torque_unit_code]))]
        if opcode == OP_DIAGNOSTIC_ADC and firmware >= FIRMWARE_WITH_DIAGNOSTICS:
            if not data or data[0] not in DIAGNOSTIC_READINGS:
                return []
            return [(OP_DIAGNOSTIC_ADC, struct.pack(">H", DIAGNOSTIC_READINGS[data[0]]))]
        if opcode == OP_RESET:
            self._active_index = 0
            self.reset_count += 1
            return []
        if opcode == OP_SET_BASE:
            if data:
                self._pending_base = data[0] & 0x7F
            return [(OP_SET_BASE, b"")]
        if opcode == OP_SET_BITRATE:
            if data:
                self._pending_bitrate = 2_000_000 // (data[0] + 1)
            return [(OP_SET_BITRATE, b"")]
        if opcode == OP_FIRMWARE:
            major, minor, build = self.firmware
            return [(OP_FIRMWARE, struct.pack(">BBH", major, minor, build))]
        return []  # 0x1, 0x3, 0x4 are reply-only; 0xA, 0xB undocumented; old firmware lacks 0x7–0x9


SLCAN_BITRATE_COMMANDS = {
    "S0": 10_000, "S1": 20_000, "S2": 50_000, "S3": 100_000, "S4": 125_000,
    "S5": 250_000, "S6": 500_000, "S7": 750_000, "S8": 1_000_000,
}
"""Lawicel slcan set-bit-rate commands → bit/s (the ones python-can's slcan interface sends)."""
SLCAN_OK = b"\r"
SLCAN_ERROR = b"\a"
PTY_READ_SIZE = 4096


class FakeSlcanAdapter:
    """A simulated slcan (Lawicel ASCII) USB-CAN adapter on a pseudo-terminal, bridged to a virtual CAN channel.

    python-can's ``slcan`` interface opens ``port`` through pyserial exactly as it opens ``/dev/ttyACM0``; this
    adapter answers its ASCII commands (``C``, ``O``, ``Sn`` …) with ``\\r``, turns ``tIIIL<data>`` lines into frames
    on the virtual channel (where a :class:`FakeNetCanOem` listens) and frames from the channel into ``t`` lines.
    Frames pass only while the adapter is open (``O``) and its bit rate equals ``bus_bitrate``, as on a real bus
    where a node at the wrong bit rate decodes nothing. ``commands`` records every ASCII command received.
    """

    def __init__(self, channel: str, bus_bitrate: int = DEFAULT_BITRATE) -> None:
        import os
        import tty

        self.bus_bitrate = bus_bitrate
        self.bitrate: int | None = None
        self.is_open = False
        self.commands: list[str] = []
        self.error: BaseException | None = None
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.port = os.ttyname(self._slave)
        self._bus = can.Bus(interface="virtual", channel=channel, ignore_config=True)
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads = [
            threading.Thread(target=self._guard, args=(self._serial_loop,), name=f"FakeSlcan-serial-{self.port}"),
            threading.Thread(target=self._guard, args=(self._bus_loop,), name=f"FakeSlcan-bus-{channel}"),
        ]
        for thread in self._threads:
            thread.start()
        self._closed = False

    def close(self) -> None:
        """Stop and join both threads, close the pty and the virtual bus, re-raise a thread's error. Idempotent."""
        import os

        if self._closed:
            return
        self._closed = True
        self._stop.set()
        for thread in self._threads:
            thread.join(CLOSE_JOIN_TIMEOUT_S)
        self._bus.shutdown()
        os.close(self._master)
        os.close(self._slave)
        if self.error is not None:
            raise RuntimeError(f"FakeSlcanAdapter thread failed: {self.error!r}") from self.error

    def __enter__(self) -> "FakeSlcanAdapter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def passes_frames(self) -> bool:
        return self.is_open and self.bitrate == self.bus_bitrate

    def _guard(self, loop) -> None:
        try:
            loop()
        except BaseException as error:  # kept and re-raised by close()
            if not self._stop.is_set():
                self.error = error
                logger.exception("FakeSlcanAdapter thread failed")

    def _write(self, data: bytes) -> None:
        import os

        with self._write_lock:
            os.write(self._master, data)

    def _serial_loop(self) -> None:
        import os
        import select

        buffer = b""
        while not self._stop.is_set():
            readable, _, _ = select.select([self._master], [], [], RECV_POLL_S)
            if not readable:
                continue
            try:
                buffer += os.read(self._master, PTY_READ_SIZE)
            except OSError:  # the serial side was closed and nobody holds it: nothing more to read
                continue
            while b"\r" in buffer:
                line, buffer = buffer.split(b"\r", 1)
                self._command(line.decode("ascii", "replace"))

    def _command(self, line: str) -> None:
        if line:  # python-can sends an empty line for "no data bit rate"; answered OK, not recorded
            self.commands.append(line)
        if line in ("O", "L"):
            self.is_open = True
        elif line == "C":
            self.is_open = False
        elif line in SLCAN_BITRATE_COMMANDS:
            self.bitrate = SLCAN_BITRATE_COMMANDS[line]
        elif line.startswith("t") and len(line) >= 5:
            dlc = int(line[4])
            data = bytes.fromhex(line[5 : 5 + 2 * dlc])
            if self.passes_frames:
                self._bus.send(can.Message(arbitration_id=int(line[1:4], 16), data=data, is_extended_id=False))
            self._write(b"z\r")
            return
        elif not (line.startswith(("s", "Y", "V", "N", "F", "Z", "X")) or line == ""):
            self._write(SLCAN_ERROR)
            return
        self._write(SLCAN_OK)

    def _bus_loop(self) -> None:
        while not self._stop.is_set():
            message = self._bus.recv(timeout=RECV_POLL_S)
            if message is None or message.is_extended_id or message.is_remote_frame or not self.passes_frames:
                continue
            self._write(f"t{message.arbitration_id:03X}{message.dlc:d}{bytes(message.data).hex().upper()}\r".encode())
