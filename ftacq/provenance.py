"""Where a calibration comes from: the sensor it was made with, the tool, and the history of its biases.

Three optional keys of calibration.json (version 2; :mod:`ftacq.calfile` checks their types on load):

- ``sensor``: ``{serial, model, transport, counts_per_force, counts_per_torque, force_unit, torque_unit,
  firmware}`` as the device told the driver when the calibration was measured (``model`` and ``firmware`` are
  empty where the device does not tell; the CAN board reports no transducer model);
- ``tool``: ``{name}`` (CELL.toml ``tool.name``);
- ``bias_history``: a list, oldest first, of ``{time (UTC, ISO 8601), method, force_bias [3] N,
  torque_bias [3] N·m, uncertainty {force_bias [3], torque_bias [3]} (1σ)}``: the calibration's own biases,
  then every re-estimate (``ftacq tare``, an applied live tracker estimate).

:func:`sensor_mismatch` compares a calibration's ``sensor`` record with the sensor now connected: a different
serial number, different units or different counts per unit mean the calibration was made on another sensor (or
under another of the box's calibration matrices), so the monitor and ``ftacq tare`` refuse it unless forced.
Everything here is plain data (no device access): the drivers' :class:`drivers.sensor.SensorInfo` is read by
attribute.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import math
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

SENSOR_KEYS = ("serial", "model", "transport", "counts_per_force", "counts_per_torque", "force_unit", "torque_unit",
               "firmware")
"""Keys of the ``sensor`` record, in file order."""
COUNTS_RELATIVE_TOLERANCE = 1e-6
"""Counts per unit that differ by more than this (relative) are a different scaling."""
BIAS_HISTORY_LIMIT = 200
"""Entries kept in ``bias_history`` (the oldest — the calibration's own — is always kept)."""


def utc_now_iso() -> str:
    """Return the current UTC time as ISO 8601 with seconds (``2026-12-02T04:40:00+00:00``)."""
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def sensor_record(info: Any) -> dict[str, Any]:
    """Return the ``sensor`` record of a started sensor's :class:`drivers.sensor.SensorInfo` (read by attribute)."""
    return {
        "serial": str(getattr(info, "serial", "") or ""),
        "model": str(getattr(info, "model", "") or ""),
        "transport": str(getattr(info, "transport", "") or ""),
        "counts_per_force": float(getattr(info, "counts_per_force", 0.0) or 0.0),
        "counts_per_torque": float(getattr(info, "counts_per_torque", 0.0) or 0.0),
        "force_unit": str(getattr(info, "force_unit", "") or ""),
        "torque_unit": str(getattr(info, "torque_unit", "") or ""),
        "firmware": str(getattr(info, "firmware", "") or ""),
    }


def tool_record(name: str | None) -> dict[str, Any] | None:
    """Return the ``tool`` record for CELL.toml's ``tool.name`` (None when no name is configured)."""
    return {"name": str(name)} if name else None


def bias_entry(method: str, force_bias: Iterable[float], torque_bias: Iterable[float],
               force_sigma: Iterable[float] | None = None, torque_sigma: Iterable[float] | None = None,
               time: str | None = None, **extra: Any) -> dict[str, Any]:
    """Return one ``bias_history`` entry (N, N·m, sensor frame; 1σ where known; ``time`` UTC ISO, default now)."""
    entry: dict[str, Any] = {
        "time": time or utc_now_iso(),
        "method": str(method),
        "force_bias": [float(v) for v in force_bias],
        "torque_bias": [float(v) for v in torque_bias],
    }
    if force_sigma is not None and torque_sigma is not None:
        entry["uncertainty"] = {"force_bias": [float(v) for v in force_sigma],
                                "torque_bias": [float(v) for v in torque_sigma]}
    entry.update(extra)
    return entry


def calibration_bias_entry(calibration: Any) -> dict[str, Any]:
    """Return the history entry of a calibration's own biases (time = its ``created_utc`` when known)."""
    metadata = dict(getattr(calibration, "metadata", {}) or {})
    uncertainty = dict(getattr(calibration, "uncertainty", {}) or {})
    entry = bias_entry(f"calibration ({metadata.get('method', 'unknown method')})", calibration.force_bias,
                       calibration.torque_bias, uncertainty.get("force_bias"), uncertainty.get("torque_bias"))
    entry["time"] = metadata.get("created_utc")  # None when the calibration does not say when it was made
    return entry


def bias_history(calibration: Any) -> list[dict[str, Any]]:
    """Return the calibration's bias history; a file without one (version 1) gets its own biases as first entry."""
    history = list((getattr(calibration, "metadata", {}) or {}).get("bias_history") or [])
    return history or [calibration_bias_entry(calibration)]


def with_bias_entry(history: Sequence[Mapping[str, Any]], entry: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Return ``history`` with ``entry`` appended, keeping the first entry and the latest BIAS_HISTORY_LIMIT − 1."""
    out = [dict(item) for item in history] + [dict(entry)]
    if len(out) > BIAS_HISTORY_LIMIT:
        out = out[:1] + out[-(BIAS_HISTORY_LIMIT - 1):]
    return out


def last_tare(calibration: Any) -> dict[str, Any] | None:
    """Return the latest bias-history entry that is not the calibration itself (a tare), or None."""
    history = (getattr(calibration, "metadata", {}) or {}).get("bias_history") or []
    tares = [entry for entry in history if not str(entry.get("method", "")).startswith("calibration")]
    return dict(tares[-1]) if tares else None


def input_record(poses_file: str | os.PathLike, sets: Sequence[str], identified_on: Sequence[str], *,
                 has_std: bool, has_count: bool, units: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Return the ``input`` record: the pose record identified (path, SHA-256 taken now, pose count), the count of
    poses per set, the sets the fit used, whether the record had standard deviations and sample counts, and the
    ``units`` its wrench columns were in (``{"force": "N", "torque": "N-mm"}``; default SI), so that
    ``ftacq compensate`` reads the same file in the same units."""
    path = Path(poses_file)
    return {
        "file": str(path),
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "poses": len(sets),
        "sets": {name: list(sets).count(name) for name in sorted(set(sets))},
        "identified_on": list(identified_on),
        "has_std": bool(has_std),
        "has_count": bool(has_count),
        "units": dict(units or {"force": "N", "torque": "N-m"}),
    }


def with_provenance(calibration: Any, sensor_info: Any | None, tool_name: str | None, **keys: Any) -> Any:
    """Return a newly identified calibration with its provenance: creation time, ``sensor`` (from the started
    sensor's info, when given), ``tool`` (when named) and a ``bias_history`` starting with its own biases.

    ``keys``: further provenance stored as given where not None (``input`` from :func:`input_record`,
    ``validation``, ``run_folder``, ``drift_check``). Every command that saves a new calibration calls this.
    """
    from dataclasses import replace

    metadata = dict(calibration.metadata)
    metadata.update({key: value for key, value in keys.items() if value is not None})
    metadata.setdefault("created_utc", utc_now_iso())
    if sensor_info is not None:
        metadata["sensor"] = sensor_record(sensor_info)
    tool = tool_record(tool_name)
    if tool is not None:
        metadata["tool"] = tool
    calibration = replace(calibration, metadata=metadata)
    metadata["bias_history"] = bias_history(calibration)
    return replace(calibration, metadata=metadata)


def sensor_mismatch(recorded: Mapping[str, Any] | None, info: Any) -> list[str]:
    """Return why the sensor now connected (``info``) is not the one ``recorded`` in the calibration (empty: same).

    Compared: serial number (when both are known), force and torque units, counts per force and per torque (when
    both are known). A calibration without a ``sensor`` record gives no problems (nothing to compare: version-1
    files); :func:`unchecked_reason` says so.
    """
    if not recorded:
        return []
    now = sensor_record(info)
    problems = []
    serial_then, serial_now = str(recorded.get("serial", "") or ""), now["serial"]
    if serial_then and serial_now and serial_then != serial_now:
        problems.append(f"serial number: the calibration was made with sensor {serial_then}, the sensor connected "
                        f"is {serial_now}")
    for key in ("force_unit", "torque_unit"):
        then = str(recorded.get(key, "") or "")
        if then and now[key] and then != now[key]:
            problems.append(f"{key.replace('_', ' ')}: {then} in the calibration, {now[key]} on the sensor now")
    for key in ("counts_per_force", "counts_per_torque"):
        then_value = recorded.get(key)
        if isinstance(then_value, (int, float)) and then_value > 0 and now[key] > 0 and not math.isclose(
                float(then_value), now[key], rel_tol=COUNTS_RELATIVE_TOLERANCE):
            problems.append(f"{key.replace('_', ' ')}: {float(then_value):g} in the calibration, {now[key]:g} on "
                            "the sensor now (another calibration matrix selected on the box?)")
    return problems


def require_same_sensor(calibration: Any, info: Any, force: bool, command: str) -> str:
    """Refuse a calibration made with another sensor (InputError naming both values) unless ``force``; return a
    note to print ('' when the match was checked and holds)."""
    from ftacq.errors import InputError

    recorded = (getattr(calibration, "metadata", {}) or {}).get("sensor")
    problems = sensor_mismatch(recorded, info)
    if problems and not force:
        raise InputError("the calibration does not belong to the sensor connected: " + "; ".join(problems)
                         + f". Calibrate this sensor, or pass --force to {command} anyway")
    if problems:
        return "WARNING (--force): the calibration does not belong to this sensor: " + "; ".join(problems)
    reason = unchecked_reason(recorded, info)
    return f"note: sensor match not checked: {reason}" if reason else ""


def biases_measured_utc(calibration: Any) -> str | None:
    """Return when the calibration's current biases were measured (last bias-history entry, else created_utc)."""
    metadata = getattr(calibration, "metadata", {}) or {}
    history = metadata.get("bias_history") or []
    return (history[-1].get("time") if history else None) or metadata.get("created_utc")


def age_s(utc_iso: str | None) -> float | None:
    """Return seconds since an ISO 8601 UTC time (None when unknown or unparsable)."""
    if not utc_iso:
        return None
    try:
        then = _dt.datetime.fromisoformat(str(utc_iso))
    except ValueError:
        return None
    if then.tzinfo is None:
        then = then.replace(tzinfo=_dt.timezone.utc)
    return max((_dt.datetime.now(_dt.timezone.utc) - then).total_seconds(), 0.0)


def unchecked_reason(recorded: Mapping[str, Any] | None, info: Any) -> str:
    """Return why the match could not be checked fully ('' when serial numbers were compared)."""
    if not recorded:
        return "the calibration records no sensor (made before calibration files recorded it)"
    if not recorded.get("serial") or not getattr(info, "serial", ""):
        return "the sensor's serial number is unknown on one side"
    return ""


__all__ = ["SENSOR_KEYS", "sensor_record", "tool_record", "bias_entry", "calibration_bias_entry", "bias_history",
           "with_bias_entry", "last_tare", "with_provenance", "require_same_sensor", "biases_measured_utc", "age_s", "sensor_mismatch", "unchecked_reason", "utc_now_iso"]
