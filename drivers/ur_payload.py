"""The payload and the gravity direction of a UR controller: set them through ur-rtde, read the payload back over RTDE.

Setting (ur-rtde 1.6.5's control script, command ids in docs/protocols-ur.md):

- ``setTargetPayload(mass, cog, inertia)`` (command 65) on PolyScope 5.10+ and PolyScope X: mass kg, centre of
  gravity [m] from the tool mount in tool-flange axes, inertia [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] kg·m² about the
  centre of gravity in tool-flange axes. Older controllers run the script without it (the ``$5.10`` lines are
  left out): they get ``setPayload(mass, cog)`` (command 17) instead, without inertia.
- Either script command keeps the current centre of gravity when all three of its coordinates are 0.
- ``setGravity(d)`` (command 59): d [m/s²] in the base frame, the acceleration *away from* the earth's centre
  (a level floor robot: [0, 0, 9.82]).

Reading back: the RTDE outputs ``payload`` (kg), ``payload_cog`` (m) and, from 5.11 / 3.15, ``payload_inertia``
(kg·m²). No RTDE output ftacq knows reports the gravity set by setGravity: it is reported as sent.
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass

import numpy as np

from drivers.ur_connection import PROBE_TIMEOUT_S, RTDE_PORT, call_with_deadline, probe_rtde
from ftacq.errors import DeviceConnectionError

log = logging.getLogger(__name__)

TARGET_PAYLOAD_SINCE = (5, 10)
"""Controllers from this PolyScope version (and PolyScope X, 10.x) take setTargetPayload."""
READBACK_VARIABLES = ["timestamp", "payload", "payload_cog", "payload_inertia"]
READBACK_VARIABLES_OLD = ["timestamp", "payload", "payload_cog"]
"""Before 5.11 / 3.15 the controller has no payload_inertia output."""
READBACK_TIMEOUT_S = 3.0


def parse_version(text: str | None) -> tuple[int, int] | None:
    """Return (major, minor) of a PolyScope version text ("5.11.1.108318", "URSoftware 5.11.1…"), or None."""
    match = re.search(r"(\d+)\.(\d+)", text or "")
    return (int(match.group(1)), int(match.group(2))) if match else None


def takes_target_payload(version_text: str | None) -> bool:
    """True when the controller's version takes setTargetPayload (5.10+ or PolyScope X); unknown: False."""
    version = parse_version(version_text)
    return version is not None and version >= TARGET_PAYLOAD_SINCE


def gravity_from_weight(gravity_base_n, mass_kg: float) -> np.ndarray:
    """Return setGravity's vector [m/s²] from the tool's weight in the base frame (``gravity_base``, N): the
    acceleration away from the earth's centre, −gravity_base / mass."""
    return -np.asarray(gravity_base_n, dtype=float) / float(mass_kg)


@dataclass(frozen=True)
class PayloadReadback:
    """What the controller reports over RTDE: mass kg, centre of gravity m (flange), inertia kg·m² (or None)."""

    mass_kg: float
    cog_m: np.ndarray
    inertia_kg_m2: np.ndarray | None


def read_payload(host: str, timeout_s: float = PROBE_TIMEOUT_S) -> PayloadReadback:
    """Open an RTDE receive connection for the payload outputs, read them once, close. Raises
    DeviceConnectionError naming host and port (the handshake is probed with a deadline first)."""
    import rtde_receive

    probe_rtde(host, timeout_s)
    receive = None
    with_inertia = True
    try:
        try:
            receive = rtde_receive.RTDEReceiveInterface(host, -1.0, READBACK_VARIABLES)
        except RuntimeError as error:
            if "not found" not in str(error).lower():
                raise
            with_inertia = False
            receive = rtde_receive.RTDEReceiveInterface(host, -1.0, READBACK_VARIABLES_OLD)
    except RuntimeError as error:
        raise DeviceConnectionError(f"robot controller {host} port {RTDE_PORT} (RTDE): {error}") from error
    try:
        deadline = time.monotonic() + READBACK_TIMEOUT_S
        first = receive.getTimestamp()
        while receive.getTimestamp() == first and time.monotonic() < deadline:  # one fresh package
            time.sleep(0.002)
        mass = float(call_with_deadline(receive.getPayload, timeout_s=timeout_s, what="getPayload"))
        cog = np.array(call_with_deadline(receive.getPayloadCog, timeout_s=timeout_s, what="getPayloadCog"))
        inertia = None
        if with_inertia:
            inertia = np.array(call_with_deadline(receive.getPayloadInertia, timeout_s=timeout_s,
                                                  what="getPayloadInertia"))
        return PayloadReadback(mass, cog, inertia)
    finally:
        try:
            call_with_deadline(receive.disconnect, timeout_s=timeout_s, what="receive-disconnect")
        except Exception as error:  # noqa: BLE001 - the values are read; a slow disconnect is only logged
            log.warning("RTDE receive disconnect from %s: %s", host, error)


__all__ = ["PayloadReadback", "read_payload", "takes_target_payload", "gravity_from_weight", "parse_version"]
