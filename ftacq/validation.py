"""One validation layer for every value that comes from a file, an option or a URL.

Each check returns the clean value or raises :class:`ftacq.errors.InputError` with one line naming where the
value came from (file and key, or option), the value, and why it is refused. Nothing here touches the network.

- Numbers: finite, in range; booleans are never numbers; integers too large for a float are refused by
  comparison (no ``OverflowError``); integers must be exact (a version ``1.0`` or ``true`` is not ``1``).
- Text that Python itself may refuse to parse (JSON or TOML with an integer of more than 4300 digits, nesting
  deep enough for a ``RecursionError``) becomes an InputError too: :func:`load_json_text`.
- Output paths are checked before the work starts (:func:`check_output_file`, :func:`check_output_folder`):
  not a folder where a file is wanted, a file's folder existing and writable (an output folder creatable).
- URLs are parsed (:func:`check_url`): scheme, host and port; a malformed one (``netft://[::1``) is an
  InputError, not a ``ValueError`` from :mod:`urllib`.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Iterable
from urllib.parse import SplitResult, urlsplit

from ftacq.errors import InputError

MAX_FORCE_N = 1e5
"""No F/T sensor reads a force beyond this (2.5× the rating of ATI's largest transducer, 40 kN): a larger
value in a file is a unit or parsing mistake, and refused before any arithmetic."""
MAX_TORQUE_NM = 1e4
"""The same for torques (ATI's largest transducer is rated 6 kN·m)."""
MAX_POSITION_M = 100.0
"""No robot places its flange further than this from its base."""
MAX_ROTATION_VECTOR_RAD = 4.0 * math.pi
"""A rotation vector longer than two turns is not an orientation a robot reports (UR keeps |r| ≤ π)."""
MAX_CENTER_OF_MASS_M = 10.0
"""A tool's centre of mass further than this from the sensor is not a wrist-mounted tool."""
MAX_TEXT_VALUE_CHARS = 60
"""Values quoted in a message are cut to this many characters."""


def shown(value: Any) -> str:
    """``repr(value)`` cut to :data:`MAX_TEXT_VALUE_CHARS` (a 5000-digit integer must not flood the terminal)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**30:
        return f"an integer of {len(str(abs(value))) if abs(value) < 10**4000 else 'over 4000'} digits"
    try:
        text = repr(value)
    except ValueError:  # holds an integer of more than 4300 digits
        return "a value holding an integer of over 4300 digits"
    except RecursionError:
        return "a value nested too deeply to show"
    return text if len(text) <= MAX_TEXT_VALUE_CHARS else text[: MAX_TEXT_VALUE_CHARS - 1] + "…"


def _range_text(low: float | None, high: float | None, integer: bool) -> str:
    kind = "an integer" if integer else "a finite number"
    if low is not None and high is not None:
        return f"{kind} in [{low:g}, {high:g}]"
    if low is not None:
        return f"{kind} ≥ {low:g}"
    if high is not None:
        return f"{kind} ≤ {high:g}"
    return kind


def check_number(value: Any, where: str, *, low: float | None = None, high: float | None = None,
                 integer: bool = False, low_exclusive: bool = False, high_exclusive: bool = False) -> float | int:
    """Return ``value`` as a float (or an int when ``integer``) if it is a finite number within [low, high].

    ``bool`` is refused (``true`` is not 1); with ``integer`` a float is refused even when whole (``1.0``). A
    Python integer too large for a float is compared exactly and refused as out of range (no OverflowError).
    ``low_exclusive`` / ``high_exclusive`` make a bound strict (e.g. a mass must be > 0).
    """
    expected = _range_text(low, high, integer)
    if low_exclusive or high_exclusive:
        expected = expected.replace("[", "(" if low_exclusive else "[").replace("]", ")" if high_exclusive else "]")
        expected = expected.replace("≥", ">" if low_exclusive else "≥").replace("≤", "<" if high_exclusive else "≤")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise InputError(f"{where} = {shown(value)}: must be {expected}")
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{where} = {shown(value)}: must be {expected}")
    if isinstance(value, int) and not integer and abs(value) > 2**1023:
        raise InputError(f"{where} = {shown(value)}: must be {expected}")
    if (low is not None and (value < low or (low_exclusive and value == low))) \
            or (high is not None and (value > high or (high_exclusive and value == high))):
        raise InputError(f"{where} = {shown(value)}: must be {expected}")
    return int(value) if integer else float(value)


def check_version(value: Any, where: str, supported: int) -> int:
    """An exact integer format version equal to ``supported`` (``true``, ``1.0`` and ``"1"`` are refused)."""
    if type(value) is not int:
        raise InputError(f"{where} = {shown(value)}: must be the integer {supported}")
    if value != supported:
        raise InputError(f"{where} = {shown(value)}: this ftacq reads version {supported}")
    return value


def parse_number_text(text: str, where: str, *, low: float | None = None, high: float | None = None,
                      integer: bool = False, low_exclusive: bool = False) -> float | int:
    """Parse a command-line or CSV number (``nan``, ``inf`` and ``1e999`` are refused) and range-check it."""
    try:
        value: float | int = int(text) if integer else float(text)
    except (ValueError, OverflowError):
        raise InputError(f"{where} = {shown(text)}: must be {_range_text(low, high, integer)}") from None
    return check_number(value, where, low=low, high=high, integer=integer, low_exclusive=low_exclusive)


def load_json_text(text: str, where: str) -> Any:
    """Parse JSON text; any failure (syntax, ``NaN``/``Infinity``, an integer over 4300 digits, nesting deep
    enough to exhaust the recursion limit) raises InputError naming ``where``."""
    def refuse_constant(name: str) -> Any:
        raise InputError(f"{where}: {name} is not a number JSON allows (write a finite number or null)")

    try:
        return json.loads(text, parse_constant=refuse_constant)
    except json.JSONDecodeError as error:
        raise InputError(f"{where}: not valid JSON: {error.msg} at line {error.lineno}, column {error.colno}") from None
    except RecursionError:
        raise InputError(f"{where}: JSON nested too deeply to read") from None
    except ValueError as error:  # e.g. "Exceeds the limit (4300 digits) for integer string conversion"
        raise InputError(f"{where}: cannot read a value: {error}") from None


def check_output_file(path: str | os.PathLike, what: str = "output file") -> Path:
    """Check, before any work, that a file can be written at ``path`` (atomically: temporary file + rename).

    Refused: an existing folder, a path below an existing file, a folder that does not exist (a mistyped path
    would otherwise create folders nobody asked for) or cannot be written.
    """
    target = Path(path)
    if str(path) == "" or target.name in ("", ".", ".."):
        raise InputError(f"{what} {str(path)!r}: not a file name")
    if target.is_dir():
        raise InputError(f"{what} {target}: is a folder; give a file name (e.g. {target / 'out'})")
    _check_writable_folder(target.parent, f"{what} {target}")
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{what} {target}: the folder {folder} does not exist (create it first)")
    return target


def check_output_folder(path: str | os.PathLike, what: str = "output folder") -> Path:
    """Check, before any work, that ``path`` is (or can be created as) a writable folder."""
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise InputError(f"{what} {target}: exists and is not a folder")
    _check_writable_folder(target, f"{what} {target}")
    return target


def _check_writable_folder(folder: Path, where: str) -> None:
    existing = folder if str(folder) else Path(".")
    while not existing.exists():
        if existing.is_symlink():
            raise InputError(f"{where}: {existing} is a dangling link")
        if existing.parent == existing:
            break
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{where}: {existing} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{where}: the folder {existing} is not writable")


def check_url(url: Any, where: str, schemes: Iterable[str], *, host_required: bool = True) -> SplitResult:
    """Parse a URL without any network access: a known scheme, a host (when required), a port in 1..65535.

    Returns the :class:`urllib.parse.SplitResult`. Raises InputError naming ``where``, the URL and the reason.
    """
    schemes = tuple(schemes)
    form = " or ".join(f"{s}://…" for s in schemes)
    if not isinstance(url, str) or not url.strip():
        raise InputError(f"{where} = {shown(url)}: must be a URL ({form})")
    if any(ord(c) < 32 or c.isspace() for c in url):
        raise InputError(f"{where} = {shown(url)}: a URL has no spaces or control characters")
    try:
        parts = urlsplit(url)
        port = parts.port
        hostname = parts.hostname
    except ValueError as error:
        raise InputError(f"{where} = {shown(url)}: not a valid URL ({error})") from None
    if parts.scheme not in schemes:
        raise InputError(f"{where} = {shown(url)}: unknown scheme {parts.scheme!r}; expected {form}")
    if host_required and not hostname:
        raise InputError(f"{where} = {shown(url)}: no host; expected {parts.scheme}://HOST[:PORT]")
    if port is not None and port == 0:
        raise InputError(f"{where} = {shown(url)}: port 0 is not a port (1-65535)")
    return parts


__all__ = ["MAX_FORCE_N", "MAX_TORQUE_NM", "MAX_POSITION_M", "MAX_ROTATION_VECTOR_RAD",
           "MAX_CENTER_OF_MASS_M", "check_number", "check_version", "parse_number_text", "load_json_text", "check_output_file",
           "check_output_folder", "check_url", "shown"]
