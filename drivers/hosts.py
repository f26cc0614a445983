"""A host as a user types it (``robot.host``, ``ftacq robot info HOST``, a sensor URL's host), checked before any
socket sees it: an IP address or a host name of dot-separated labels (RFC 1123: letters, digits and hyphens, 1-63
characters each, 253 in all). Python's resolver turns a malformed name (``not..a..host``) into a UnicodeError from
its IDNA codec, not a socket error, so the name is checked here and refused in one line that says why.
"""

from __future__ import annotations

import ipaddress
import re

from ftacq.errors import InputError

_LABEL = re.compile(r"^[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?$")
MAX_NAME_CHARS = 253


def host_problem(host: str) -> str | None:
    """Why ``host`` is neither an IP address nor a host name (None when it is one)."""
    if not host:
        return "empty"
    try:
        ipaddress.ip_address(host.strip("[]"))
        return None
    except ValueError:
        pass
    if re.fullmatch(r"[^:]+:\d+", host):
        return "a port is not part of the host (give the address alone)"
    if len(host) > MAX_NAME_CHARS:
        return f"longer than {MAX_NAME_CHARS} characters"
    labels = host[:-1].split(".") if host.endswith(".") else host.split(".")
    for label in labels:
        if not label:
            return "an empty part between two dots"
        if not _LABEL.match(label):
            return (f"part {label!r} is not a host name part (letters, digits and inner hyphens, 1-63 characters)"
                    if len(label) <= 63 or not label.isascii() else f"part {label[:20]!r}… is longer than 63 characters")
    return None


def check_host(host: str, what: str) -> str:
    """Return ``host`` if it is an IP address or a host name; raise InputError naming ``what`` and why not."""
    problem = host_problem(host)
    if problem is not None:
        raise InputError(f"{what} {host!r}: not an IP address or host name ({problem})")
    return host
