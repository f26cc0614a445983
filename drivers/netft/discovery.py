"""Net F/T discovery: what the box says about its scaling, asked twice (HTTP and TCP) and cross-checked.

HTTP ``/netftapi2.xml`` gives counts per unit (``cfgcpf``, ``cfgcpt``), unit names (``scfgfu``, ``scfgtu``) or codes
(``cfgfu``, ``cfgtu``), the product name, serial, firmware and RDT settings (``comrdtrate``, ``comrdtbsiz``); TCP
READCALINFO gives unit codes and counts per unit. Both describe the active configuration: if they disagree the box is
misconfigured (or someone changed it between the two questions) and :func:`discover` refuses to guess. One source
missing is a warning (older firmware serves no TCP or no ``/netftcalapi.xml``). Rates and buffer sizes are set over
``/comm.cgi`` and read back (the box quantises the rate to 7000/n Hz). Facts in docs/protocols-ati.md.
"""

from __future__ import annotations

import http.client
import logging
import math
import re
import socket
import struct
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from urllib.parse import urlencode

import numpy as np

from drivers.netft.protocol import TCP_CALINFO_FORMAT, TCP_CALINFO_REPLY_SIZE, TCP_COMMAND_SIZE, TCP_READCALINFO
from drivers.units import canonical_unit, si_per_unit
from ftacq.errors import DeviceConnectionError, DeviceError

logger = logging.getLogger("drivers.netft")

DEFAULT_HTTP_TIMEOUT_S = 2.0
DEFAULT_TCP_TIMEOUT_S = 2.0
MAX_PAGE_BYTES = 1 << 20


@dataclass(frozen=True)
class Scaling:
    """Counts per unit and units of the active configuration, and where they came from."""

    counts_per_force: float
    counts_per_torque: float
    force_unit: str
    torque_unit: str
    source: str

    @property
    def counts_to_si(self) -> np.ndarray:
        """(6,) multiply counts by this to get N (Fx-Fz) and N·m (Tx-Tz)."""
        return np.array([si_per_unit(self.force_unit, "force") / self.counts_per_force] * 3
                        + [si_per_unit(self.torque_unit, "torque") / self.counts_per_torque] * 3)

    def agrees_with(self, other: "Scaling") -> bool:
        return bool(np.allclose(self.counts_to_si, other.counts_to_si, rtol=1e-6, atol=0.0))

    def describe(self) -> str:
        return (f"{self.source}: {self.counts_per_force:g} counts/{self.force_unit}, "
                f"{self.counts_per_torque:g} counts/{self.torque_unit}")


@dataclass
class Discovered:
    """What :func:`discover` learnt: the scaling in use, the status map, the streaming rate and the pages read."""

    scaling: Scaling
    status_map: str
    rate_hz: float
    buffer_size: int
    api: dict = field(default_factory=dict)
    calibration_page: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)


def parse_flat_xml(text: str) -> dict[str, str]:
    """Return {element name (lower case): text} of a flat XML page; liberal (falls back to a tag scan)."""
    values: dict[str, str] = {}
    try:
        root = ElementTree.fromstring(text.strip().encode() if isinstance(text, str) else text)
        for element in root.iter():
            if element is not root and len(element) == 0:
                values.setdefault(element.tag.split("}")[-1].lower(), (element.text or "").strip())
        if values:
            return values
    except ElementTree.ParseError:
        pass
    for name, value in re.findall(r"<([A-Za-z_][\w.-]*)>([^<]*)</\1>", text):
        values.setdefault(name.lower(), value.strip())
    return values


def to_float(text) -> float | None:
    """A finite float from a page value (``"1000;2000"`` → 1000.0), or None."""
    try:
        value = float(str(text).strip().split(";")[0])
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) else None


@dataclass
class BoxAddress:
    """Where the box answers: ``host`` (as named, for messages and the HTTP Host header), ``ip`` (resolved)."""

    host: str
    ip: str
    http_port: int
    tcp_port: int
    http_timeout_s: float = DEFAULT_HTTP_TIMEOUT_S
    tcp_timeout_s: float = DEFAULT_TCP_TIMEOUT_S

    def http_get(self, path: str) -> str:
        """GET a page; return its text or raise DeviceConnectionError / DeviceError."""
        connection = http.client.HTTPConnection(self.ip, self.http_port, timeout=self.http_timeout_s)
        try:
            connection.request("GET", path, headers={"Host": self.host})
            response = connection.getresponse()
            body = response.read(MAX_PAGE_BYTES)
        except (OSError, http.client.HTTPException) as error:
            raise DeviceConnectionError(
                f"HTTP {self.host}:{self.http_port}{path}: {error or type(error).__name__}") from error
        finally:
            connection.close()
        if response.status != 200:
            raise DeviceError(f"HTTP {self.host}:{self.http_port}{path}: status {response.status} {response.reason}")
        return body.decode("utf-8", errors="replace")

    def read_calinfo(self) -> tuple[int, int, int, int, tuple[int, ...]]:
        """TCP READCALINFO → (force code, torque code, CpF, CpT, scale factors)."""
        try:
            with socket.create_connection((self.ip, self.tcp_port), timeout=self.tcp_timeout_s) as sock:
                sock.sendall(bytes([TCP_READCALINFO]) + bytes(TCP_COMMAND_SIZE - 1))
                reply = b""
                while len(reply) < TCP_CALINFO_REPLY_SIZE:
                    chunk = sock.recv(TCP_CALINFO_REPLY_SIZE - len(reply))
                    if not chunk:
                        break
                    reply += chunk
        except OSError as error:
            raise DeviceConnectionError(
                f"TCP {self.host}:{self.tcp_port} READCALINFO: {error or type(error).__name__}") from error
        if len(reply) != TCP_CALINFO_REPLY_SIZE or reply[:2] != b"\x12\x34":
            raise DeviceError(f"TCP {self.host}:{self.tcp_port} READCALINFO: bad reply {reply.hex()!r} "
                              f"(expected {TCP_CALINFO_REPLY_SIZE} bytes starting 1234)")
        _, force_code, torque_code, cpf, cpt, *scales = struct.unpack(TCP_CALINFO_FORMAT, reply)
        return force_code, torque_code, cpf, cpt, tuple(scales)


def scaling_from_xml(host: str, values: dict[str, str], keys: tuple[str, ...], source: str) -> Scaling | None:
    """The scaling a page states under ``keys`` (CpF, CpT, force unit, torque unit, force code, torque code)."""
    cpf_key, cpt_key, fu_key, tu_key, fu_code_key, tu_code_key = keys
    cpf, cpt = to_float(values.get(cpf_key)), to_float(values.get(cpt_key))
    force_text = values.get(fu_key) or values.get(fu_code_key)
    torque_text = values.get(tu_key) or values.get(tu_code_key)
    if not cpf or not cpt or cpf <= 0 or cpt <= 0 or not force_text or not torque_text:
        return None
    try:
        return Scaling(cpf, cpt, canonical_unit(force_text, "force"), canonical_unit(torque_text, "torque"), source)
    except DeviceError as error:
        raise DeviceError(f"Net F/T {host}: {source}: {error}") from None


def configure_rate(box: BoxAddress, api: dict[str, str], rate_hz: float | None,
                   buffer_size: int | None) -> dict[str, str]:
    """Set comrdtrate / comrdtbsiz over CGI, then re-read netftapi2.xml (the box quantises and clamps)."""
    params = {}
    if rate_hz is not None:
        params["comrdtrate"] = f"{rate_hz:g}"
    if buffer_size is not None:
        params["comrdtbsiz"] = str(int(buffer_size))
    try:
        box.http_get("/comm.cgi?" + urlencode(params))
        api = parse_flat_xml(box.http_get("/netftapi2.xml"))
    except DeviceError as error:
        logger.warning("Net F/T %s: could not set %s over HTTP (%s); streaming at the device's setting",
                       box.host, params, error)
    rate = to_float(api.get("comrdtrate"))
    if rate_hz is not None and rate and abs(rate - rate_hz) > 0.01 * rate_hz:
        logger.warning("Net F/T %s: asked for %g Hz, the device streams at %g Hz", box.host, rate_hz, rate)
    return api


def discover(box: BoxAddress, *, override: Scaling | None = None, rate_hz: float | None = None,
             buffer_size: int | None = None, status_map: str = "auto") -> Discovered:
    """Ask the box for its scaling over HTTP and TCP and cross-check; set the rate if asked.

    Raises DeviceConnectionError (neither answers), DeviceError (the two answers disagree, unknown units, no
    counts per unit anywhere).
    """
    problems: list[str] = []
    api: dict[str, str] = {}
    try:
        api = parse_flat_xml(box.http_get("/netftapi2.xml"))
    except DeviceError as error:
        problems.append(str(error))
    if api and (rate_hz is not None or buffer_size is not None):
        api = configure_rate(box, api, rate_hz, buffer_size)
    calibration_page: dict[str, str] = {}
    if api:
        try:
            calibration_page = parse_flat_xml(box.http_get("/netftcalapi.xml"))
        except DeviceError as error:
            logger.warning("Net F/T %s: /netftcalapi.xml unavailable (%s); using /netftapi2.xml only",
                           box.host, error)
    calinfo = None
    try:
        calinfo = box.read_calinfo()
    except DeviceError as error:
        problems.append(str(error))

    http_scaling = tcp_scaling = None
    if api:
        http_scaling = scaling_from_xml(box.host, api, ("cfgcpf", "cfgcpt", "scfgfu", "scfgtu", "cfgfu", "cfgtu"),
                                        "HTTP /netftapi2.xml")
    if http_scaling is None and calibration_page:
        http_scaling = scaling_from_xml(box.host, calibration_page,
                                        ("calcpf", "calcpt", "scalfu", "scaltu", "calfu", "caltu"),
                                        "HTTP /netftcalapi.xml")
    if calinfo is not None:
        force_code, torque_code, cpf, cpt, _ = calinfo
        try:
            tcp_scaling = Scaling(float(cpf), float(cpt), canonical_unit(str(force_code), "force"),
                                  canonical_unit(str(torque_code), "torque"), "TCP READCALINFO")
        except DeviceError as error:
            problems.append(f"TCP READCALINFO: {error}")
        if tcp_scaling is not None and (cpf <= 0 or cpt <= 0):
            problems.append(f"TCP READCALINFO: counts per unit {cpf}, {cpt} must be positive")
            tcp_scaling = None

    if override is not None:
        scaling = override
        for other in (http_scaling, tcp_scaling):
            if other is not None and not other.agrees_with(scaling):
                logger.warning("Net F/T %s: URL scaling (%s) differs from the device's (%s); using the URL's",
                               box.host, scaling.describe(), other.describe())
    elif http_scaling is not None and tcp_scaling is not None:
        if not http_scaling.agrees_with(tcp_scaling):
            raise DeviceError(
                f"Net F/T {box.host}: the device's two answers about scaling disagree — {http_scaling.describe()}; "
                f"{tcp_scaling.describe()}. Check the active configuration (setcfgsel) or pass "
                f"counts_per_force, counts_per_torque, force_unit and torque_unit in the URL")
        scaling = http_scaling
    elif (only := http_scaling or tcp_scaling) is not None:
        scaling = only
        logger.warning("Net F/T %s: scaling from %s only (%s)", box.host, scaling.source, "; ".join(problems))
    else:
        if not api and calinfo is None:
            raise DeviceConnectionError(f"cannot reach the Net F/T at {box.host}: " + "; ".join(problems))
        why = "; ".join(problems) or "netftapi2.xml has no cfgcpf/cfgcpt/scfgfu/scfgtu"
        raise DeviceError(f"Net F/T {box.host}: no counts per unit found ({why}); pass counts_per_force, "
                          f"counts_per_torque, force_unit and torque_unit in the URL")
    product = api.get("prodname", "")
    if status_map == "auto":
        status_map = "axia" if ("axia" in product.lower() or "setrate" in api) else "netft"
    rate = to_float(api.get("comrdtrate")) or float(rate_hz or 0.0)
    return Discovered(scaling=scaling, status_map=status_map, rate_hz=rate,
                      buffer_size=int(to_float(api.get("comrdtbsiz")) or 1), api=api,
                      calibration_page=calibration_page, problems=problems)
