"""Units of a CSV's wrench columns (the pose record, a recording to import): declared per kind (force, torque) by
a column suffix (``tx_Nmm``, ``std_tx_Nmm``), a comment line before the header (``# torque_unit: N-mm``) or an
option; two declarations that disagree are refused, none means SI. Unit names: the one table of
:mod:`ftacq.units`. :func:`unit_header_map` plugs into :func:`ftacq.posefile.read_csv_table`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

from ftacq.channels import WRENCH_COLUMNS
from ftacq.errors import InputError
from ftacq.units import FORCE_UNITS, TORQUE_UNITS, canonical_unit

_UNIT_COLUMN = re.compile(r"^(std_)?([ft][xyz])_(.+)$")
"""A wrench or std column with a unit suffix: ``tx_nmm``, ``std_fx_n`` (header already in lower case)."""
_UNIT_COMMENT = re.compile(r"^#\s*(force|torque)[\s_-]*unit\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)
"""A header comment declaring a unit: ``# torque_unit: N-mm``."""
SI_UNITS = {"force": "N", "torque": "N-m"}


def _kind(channel: str) -> str:
    return "force" if channel.startswith("f") else "torque"


def _unit_name(text: str, kind: str, where: str) -> str:
    try:
        return canonical_unit(text, kind)
    except ValueError:
        names = ", ".join(FORCE_UNITS if kind == "force" else TORQUE_UNITS)
        raise InputError(f"{where}: unknown {kind} unit {text!r} (known: {names})") from None


def declared_units(path: Path) -> dict[str, tuple[str, str]]:
    """Return the units the comment lines before the header declare: kind → (unit name, where it was said)."""
    out: dict[str, tuple[str, str]] = {}
    try:
        with open(path, encoding="utf-8-sig") as handle:
            for number, line in enumerate(handle, start=1):
                text = line.strip()
                if not text:
                    continue
                if not text.startswith("#"):
                    break
                match = _UNIT_COMMENT.match(text)
                if match:
                    kind = match.group(1).lower()
                    where = f"{path}: line {number}"
                    out[kind] = (_unit_name(match.group(2), kind, where), where)
    except (OSError, UnicodeDecodeError):
        return out  # read_csv_table names the problem
    return out


def _resolve_units(path: Path, header: list[str], header_line: int, options: dict[str, str | None]
                   ) -> tuple[list[str], dict[str, float], dict[str, str], set[str]]:
    """Strip the unit suffixes of the header; return (header, SI factor per wrench column, unit per kind, the
    kinds whose unit was declared).

    Per kind (force, torque) the unit is the columns' suffix, else the option, else the header comment, else
    SI; two of them that disagree, or columns of one kind in different units, are refused.
    """
    declared = declared_units(path)
    suffix_units: dict[str, dict[str, str]] = {"force": {}, "torque": {}}
    renamed = []
    for name in header:
        match = _UNIT_COLUMN.match(name)
        if match:
            kind = _kind(match.group(2))
            unit = _unit_name(match.group(3), kind, f"{path}: line {header_line}, column {name!r}")
            suffix_units[kind][name] = unit
            name = (match.group(1) or "") + match.group(2)
        renamed.append(name)
    units: dict[str, str] = {}
    declared_kinds: set[str] = set()
    for kind in ("force", "torque"):
        sources: list[tuple[str, str]] = []
        if suffix_units[kind]:
            by_unit = sorted(set(suffix_units[kind].values()))
            if len(by_unit) > 1:
                raise InputError(f"{path}: line {header_line}: {kind} columns in different units "
                                 f"({', '.join(f'{c} in {u}' for c, u in suffix_units[kind].items())})")
            suffixed = {(_UNIT_COLUMN.match(c).group(1) or "") + _UNIT_COLUMN.match(c).group(2)  # type: ignore[union-attr]
                        for c in suffix_units[kind]}
            plain = [n for n in renamed if n not in suffixed and n.removeprefix("std_") in WRENCH_COLUMNS
                     and _kind(n.removeprefix("std_")) == kind]
            if plain:
                raise InputError(f"{path}: line {header_line}: column {plain[0]!r} has no unit suffix while "
                                 f"{next(iter(suffix_units[kind]))!r} has one: give every {kind} column its unit")
            sources.append((by_unit[0], f"column {next(iter(suffix_units[kind]))!r}"))
        option = options.get(kind)
        if option is not None:
            sources.append((_unit_name(option, kind, f"--{kind}-unit"), f"--{kind}-unit {option}"))
        if kind in declared:
            sources.append((declared[kind][0], declared[kind][1].removeprefix(f"{path}: ")))
        if len({unit for unit, _ in sources}) > 1:
            raise InputError(f"{path}: the {kind} unit is declared twice and differently: "
                             + "; ".join(f"{unit} ({where})" for unit, where in sources))
        units[kind] = sources[0][0] if sources else SI_UNITS[kind]
        if sources:
            declared_kinds.add(kind)
    factor = {}
    for channel in WRENCH_COLUMNS:
        kind = _kind(channel)
        factor[channel] = (FORCE_UNITS if kind == "force" else TORQUE_UNITS)[units[kind]]
    return renamed, factor, units, declared_kinds


def unit_header_map(path: Path, force_unit: str | None, torque_unit: str | None,
                    rename: Callable[[list[str]], list[str]] | None = None
                    ) -> tuple[Callable[[list[str], int], list[str]], dict]:
    """Return a ``header_map`` for :func:`read_csv_table` that strips the wrench columns' unit suffixes (after
    ``rename``), and the dict it fills once the header is read: ``factor`` (SI per file unit of each wrench column
    fx … tz), ``units`` (kind → unit name) and ``declared`` (the kinds whose unit the file or an option named;
    the others are SI by default)."""
    resolved: dict = {}

    def strip_units(header: list[str], line: int) -> list[str]:
        if rename is not None:
            header = rename(header)
        renamed, resolved["factor"], resolved["units"], resolved["declared"] = _resolve_units(
            path, header, line, {"force": force_unit, "torque": torque_unit})
        return renamed

    return strip_units, resolved


def adopt_identified_units(path: Path, resolved: dict, identified: dict | None) -> str:
    """Check a file's wrench units (``resolved`` by :func:`unit_header_map`, updated in place) against the units
    the calibration was identified in (``identified``: its ``input`` record, whose ``units`` say what the pose
    record was in), for a kind the file and the options leave undeclared: the very file identified (same SHA-256)
    is read in the recorded unit (the returned note says so); another file is refused (InputError, one line), since
    SI is then a guess. Return '' when nothing needed saying."""
    import hashlib

    recorded = (identified or {}).get("units") or {}
    undeclared = {kind: str(recorded[kind]) for kind in ("force", "torque")
                  if kind not in resolved["declared"] and recorded.get(kind, SI_UNITS[kind]) != SI_UNITS[kind]}
    if not undeclared:
        return ""
    said = ", ".join(f"{kind} in {unit}" for kind, unit in undeclared.items())
    source = (identified or {}).get("file", "its pose record")
    try:
        same = hashlib.sha256(path.read_bytes()).hexdigest() == (identified or {}).get("sha256")
    except OSError:
        same = False
    if not same:
        options = " ".join(f"--{kind}-unit {unit}" for kind, unit in undeclared.items())
        raise InputError(f"{path}: declares no unit for {' and '.join(undeclared)}, but the calibration was identified "
                         f"from {said} ({source}): pass {options} (or --{next(iter(undeclared))}-unit "
                         f"{SI_UNITS[next(iter(undeclared))]} if this file is in SI)")
    for kind, unit in undeclared.items():
        resolved["units"][kind] = canonical_unit(unit, kind)
        for channel in WRENCH_COLUMNS:
            if _kind(channel) == kind:
                resolved["factor"][channel] = (FORCE_UNITS if kind == "force" else TORQUE_UNITS)[resolved["units"][kind]]
    return f"{path} is the file the calibration was identified from: read with {said}, as identify read it"


__all__ = ["SI_UNITS", "WRENCH_COLUMNS", "adopt_identified_units", "declared_units", "unit_header_map"]
