"""The calibration file: versioned JSON, SI units, written atomically.

Required keys (format ``ftacq-calibration``, ``version`` 2; version-1 files, which lack the optional provenance
keys below, load as they are):

- ``sensor_rotation`` 3×3 row-major: ``sensor_R_flange``, maps flange-frame vectors into the sensor frame;
- ``force_bias`` [3] N, ``torque_bias`` [3] N·m (sensor frame);
- ``gravity_base`` [3] N: the tool's weight as a force in the robot base frame;
- ``mass_kg``; ``center_of_mass_m`` [3] (sensor frame); ``base_tilt_deg`` [α, β] (corrected eqs 46-48).

Optional keys written from the identification: ``uncertainty`` (1σ per key above, plus
``sensor_rotation_rad`` as a small rotation about the sensor axes), ``mount`` and ``base_tilt_relative_deg``,
``method``, ``residuals`` (per pose labels and [fx..tz] residual), ``outliers``, ``warnings``,
``diagnostics``, ``input``, ``software_version``, ``created_utc``, and ``model_correlation``: the correlations
between the errors of ``sensor_rotation_rad``, ``gravity_base`` and ``center_of_mass_m`` (the parameters a tare
keeps), ``{"parameters": [names], "matrix": 9×9}``, so that their 1σ propagate with their correlations (checked on
load: symmetric, unit diagonal, |r| ≤ 1). Unknown keys are kept in ``Calibration.metadata`` on load.

Optional dynamics keys (version 2, :mod:`ftacq.dynamics`): ``sensor_offset_m`` [3] m, the sensor origin in the
flange frame (CELL.toml ``tool.sensor_offset_m``); ``inertia_kg_m2`` 3×3, the tool's inertia about its centre of
mass in the sensor frame, with its 1σ as ``uncertainty.inertia_kg_m2`` (3×3). A file without ``inertia_kg_m2``
(every version-1 file) is a static-only calibration.

Optional provenance keys (version 2, :mod:`ftacq.provenance`; their types are checked on load): ``sensor``
(serial, model, transport, counts per force and torque, units, firmware), ``tool`` (name) and ``bias_history``
(time, method, biases, 1σ of every bias estimate, oldest first). :func:`ftacq.provenance.with_provenance` builds
all of them, and the ``input`` record, for every command alike.

Other file formats: :data:`WRITERS` maps a format name to a function turning a calibration into the file's text;
:func:`write_calibration` writes any of them atomically (mode 0644). A new export format is one such function
and one row of the table.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ftacq import STANDARD_GRAVITY_M_S2, __version__
from ftacq.calibration import Calibration
from ftacq.errors import InputError
from ftacq.exports import ros2_parameters_text, ur_payload_text
from ftacq.fileio import atomic_write
from ftacq.validation import (
    MAX_CENTER_OF_MASS_M,
    MAX_FORCE_N,
    MAX_TORQUE_NM,
    check_number,
    load_json_text,
    shown,
)

FORMAT_NAME = "ftacq-calibration"
FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
"""Versions this ftacq reads: 2 adds optional keys only, so a version-1 file is a valid version-2 file."""
ROTATION_ORTHONORMAL_TOLERANCE = 1e-6
"""Max |RᵀR − I| element and |det R − 1| accepted for ``sensor_rotation`` on load."""
MASS_CONSISTENCY_TOLERANCE = 1e-6
"""Max relative difference accepted between ``mass_kg`` and ‖gravity_base‖ / g on load."""

REQUIRED_KEYS = {
    "sensor_rotation": (3, 3),
    "force_bias": (3,),
    "torque_bias": (3,),
    "gravity_base": (3,),
    "mass_kg": (),
    "center_of_mass_m": (3,),
    "base_tilt_deg": (2,),
}
OPTIONAL_ARRAY_KEYS = {"sensor_offset_m": ("sensor_offset", (3,)), "inertia_kg_m2": ("inertia", (3, 3))}
"""Optional model keys: file key → (Calibration field, shape)."""
INERTIA_SYMMETRY_TOLERANCE_KG_M2 = 1e-9
_FIELD_OF_KEY = {"center_of_mass_m": "center_of_mass"}
MAX_BASE_TILT_DEG = 180.0
MAX_SENSOR_OFFSET_M = 1.0
"""|element| bound of ``sensor_offset_m``: an adapter is centimetres thick, not metres (a unit mistake)."""
MAX_MASS_KG = MAX_FORCE_N / STANDARD_GRAVITY_M_S2
MAX_INERTIA_KG_M2 = MAX_MASS_KG * MAX_CENTER_OF_MASS_M ** 2
"""|element| bound of ``inertia_kg_m2``: the heaviest tool with all its mass at the farthest centre of mass."""
_LIMIT_OF_KEY = {
    "sensor_rotation": 1.0 + ROTATION_ORTHONORMAL_TOLERANCE,
    "force_bias": MAX_FORCE_N,
    "torque_bias": MAX_TORQUE_NM,
    "gravity_base": MAX_FORCE_N,
    "mass_kg": MAX_MASS_KG,
    "center_of_mass_m": MAX_CENTER_OF_MASS_M,
    "base_tilt_deg": MAX_BASE_TILT_DEG,
    "sensor_offset_m": MAX_SENSOR_OFFSET_M,
    "inertia_kg_m2": MAX_INERTIA_KG_M2,
}
"""|value| bound of every element of each required key (beyond a sensor's range: a unit or file mistake)."""
MODEL_CORRELATION_KEY = "model_correlation"
"""Optional key: correlations of the model parameters' errors (module docstring)."""
MODEL_CORRELATION_PARAMETERS = ("sensor_rotation_rad", "gravity_base", "center_of_mass_m")
"""The parameters ``model_correlation`` covers, three rows each, in this order."""
CORRELATION_TOLERANCE = 1e-6
"""Slack on |r| ≤ 1, symmetry and the unit diagonal of ``model_correlation`` (rounding in the file)."""
_MODEL_KEYS = set(REQUIRED_KEYS) | set(OPTIONAL_ARRAY_KEYS) | {"format", "version", "uncertainty"}


def _jsonable(value: Any) -> Any:
    """Return ``value`` with numpy arrays and scalars turned into lists and floats (NaN → None)."""
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return value


def calibration_to_dict(calibration: Calibration) -> dict[str, Any]:
    """Return the JSON document (a dict) of a calibration; metadata keys follow the model keys."""
    metadata = dict(calibration.metadata)
    document: dict[str, Any] = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "sensor_rotation": calibration.sensor_rotation,
        "force_bias": calibration.force_bias,
        "torque_bias": calibration.torque_bias,
        "gravity_base": calibration.gravity_base,
        "mass_kg": calibration.mass_kg,
        "center_of_mass_m": calibration.center_of_mass,
        "base_tilt_deg": list(calibration.base_tilt_deg),
        "uncertainty": dict(calibration.uncertainty),
    }
    for key, (name, _shape) in OPTIONAL_ARRAY_KEYS.items():
        if getattr(calibration, name) is not None:
            document[key] = getattr(calibration, name)
    metadata.setdefault("software_version", f"ftacq {__version__}")
    metadata.setdefault("created_utc", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    for key, value in metadata.items():
        if key not in document:
            document[key] = value
    return _jsonable(document)


def calibration_json_text(calibration: Calibration) -> str:
    """Return the calibration as the versioned JSON text of this module's format (the ``json`` writer)."""
    return json.dumps(calibration_to_dict(calibration), indent=2, allow_nan=False) + "\n"


CalibrationWriter = Callable[[Calibration], str]
"""A calibration file format: the file's whole text for one calibration."""

WRITERS: dict[str, CalibrationWriter] = {
    "json": calibration_json_text,
    "ur": ur_payload_text,
    "ros2": ros2_parameters_text,
}
"""Every calibration file format ftacq writes, by name (``json`` is the one it reads back; ``ur`` the UR payload
and ``ros2`` the ROS 2 parameters of :mod:`ftacq.exports`)."""


def write_calibration(path: str | os.PathLike, calibration: Calibration, format: str = "json") -> None:
    """Write ``calibration`` in ``format`` (a key of :data:`WRITERS`) atomically: never a half-written file.

    The calibration is first put through the reader's own checks (:func:`check_readable`): ftacq never writes a
    calibration that ``compensate``, ``monitor`` or ``tare`` would refuse.

    Raises InputError naming the format and the known ones, or what the reader would refuse (nothing written).
    """
    try:
        writer = WRITERS[format]
    except KeyError:
        raise InputError(f"calibration format {format!r}: unknown (known: {', '.join(WRITERS)})") from None
    check_readable(calibration, path)
    text = writer(calibration)
    with atomic_write(path) as handle:
        handle.write(text)


def check_readable(calibration: Calibration, path: str | os.PathLike = "<calibration>") -> None:
    """Raise InputError when :func:`load_calibration` would refuse this calibration once written to ``path``:
    the one validity check shared by the writer and the reader (:func:`calibration_from_dict`)."""
    try:
        calibration_from_dict(calibration_to_dict(calibration), path)
    except InputError as error:
        raise InputError(f"{path}: not written, ftacq would refuse to read it back: "
                         f"{str(error).removeprefix(f'{Path(path)}: ')}") from None


def save_calibration(path: str | os.PathLike, calibration: Calibration) -> None:
    """Write the calibration as versioned JSON, atomically (never a half-written file)."""
    write_calibration(path, calibration, "json")


def _shape_text(value: Any) -> str:
    """The shape of a nested list as ``[a, b]``, or what it is instead."""
    shape = []
    while isinstance(value, list):
        shape.append(len(value))
        if not value or any(not isinstance(v, list) or len(v) != len(value[0]) for v in value) and \
                any(isinstance(v, list) for v in value):
            break
        value = value[0]
    return str(shape) if shape else type(value).__name__


def _array(path: Path, document: dict, key: str, shape: tuple[int, ...]) -> np.ndarray:
    """The value of ``key`` as a float array of ``shape``; every element a finite number within its bound."""
    value = document[key]
    limit = _LIMIT_OF_KEY[key.rsplit(".", 1)[-1]]  # "bias_history[2].force_bias" is bounded as "force_bias"

    def elements(item: Any, depth: int) -> list:
        if depth == len(shape):
            return [check_number(item, f"{path}: key {key!r}", low=-limit, high=limit)]
        if not isinstance(item, list) or len(item) != shape[depth]:
            raise InputError(f"{path}: key {key!r}: expected shape {list(shape)}, got {_shape_text(value)} "
                             f"({shown(value)})")
        return [x for sub in item for x in elements(sub, depth + 1)]

    return np.array(elements(value, 0), dtype=float).reshape(shape)


def calibration_from_dict(document: Any, path: str | os.PathLike = "<calibration>") -> Calibration:
    """Check a parsed calibration document and return the Calibration (InputError naming the key on failure)."""
    path = Path(path)
    if not isinstance(document, dict):
        raise InputError(f"{path}: expected a JSON object at the top level, got {type(document).__name__}")
    if document.get("format") != FORMAT_NAME:
        raise InputError(f"{path}: key 'format': expected {FORMAT_NAME!r}, got {shown(document.get('format'))}")
    version = document.get("version")
    if type(version) is not int or version not in READABLE_VERSIONS:  # exact: true and 1.0 are not version 1
        raise InputError(
            f"{path}: key 'version': this ftacq reads calibration versions "
            f"{', '.join(str(v) for v in READABLE_VERSIONS)}, the file has {shown(version)} (an exact integer)"
        )
    for key in REQUIRED_KEYS:
        if key not in document:
            raise InputError(f"{path}: missing required key {key!r}")
    values = {key: _array(path, document, key, shape) for key, shape in REQUIRED_KEYS.items()}
    rotation = values["sensor_rotation"]
    orthonormal_error = np.abs(rotation.T @ rotation - np.eye(3)).max()
    if orthonormal_error > ROTATION_ORTHONORMAL_TOLERANCE or abs(np.linalg.det(rotation) - 1.0) > ROTATION_ORTHONORMAL_TOLERANCE:
        raise InputError(
            f"{path}: key 'sensor_rotation': not a rotation matrix (|RᵀR − I| = {float(orthonormal_error):.2e}, "
            f"det = {float(np.linalg.det(rotation)):.6f})"
        )
    mass_from_gravity = np.linalg.norm(values["gravity_base"]) / STANDARD_GRAVITY_M_S2
    mass = check_number(float(values["mass_kg"]), f"{path}: key 'mass_kg'", low=0.0, high=MAX_MASS_KG,
                        low_exclusive=True)
    if abs(mass - mass_from_gravity) > MASS_CONSISTENCY_TOLERANCE * max(mass_from_gravity, 1e-9):
        raise InputError(
            f"{path}: key 'mass_kg': {mass:.6g} kg disagrees with ‖gravity_base‖/g = {float(mass_from_gravity):.6g} kg"
        )
    optional = {}
    for key, (name, shape) in OPTIONAL_ARRAY_KEYS.items():
        if document.get(key) is not None:
            optional[name] = _array(path, document, key, shape)
    inertia = optional.get("inertia")
    if inertia is not None:
        asymmetry = float(np.abs(inertia - inertia.T).max())
        eigenvalues = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
        if asymmetry > INERTIA_SYMMETRY_TOLERANCE_KG_M2 or eigenvalues[0] <= 0.0 or \
                eigenvalues[2] > eigenvalues[0] + eigenvalues[1] + INERTIA_SYMMETRY_TOLERANCE_KG_M2:
            raise InputError(
                f"{path}: key 'inertia_kg_m2': not the inertia of a rigid body (asymmetry {asymmetry:.2e} kg·m², "
                f"principal moments {', '.join(f'{v:.6g}' for v in eigenvalues)} kg·m²: they must be > 0 and each "
                "at most the sum of the other two)")
    uncertainty = document.get("uncertainty", {})
    if not isinstance(uncertainty, dict):
        raise InputError(f"{path}: key 'uncertainty': expected an object, got {type(uncertainty).__name__}")
    for name, sigma in uncertainty.items():  # 1σ: a number or a (nested: 3×3) list of numbers, each ≥ 0 (null = unknown)
        if isinstance(sigma, list) and sigma and all(isinstance(row, list) for row in sigma):
            sigma = [item for row in sigma for item in row]
        for k, item in enumerate(sigma if isinstance(sigma, list) else [sigma]):
            if item is not None:
                check_number(item, f"{path}: key 'uncertainty.{name}'" + (f"[{k}]" if isinstance(sigma, list) else ""),
                             low=0.0)
    _check_provenance(path, document)
    _check_model_correlation(path, document.get(MODEL_CORRELATION_KEY))
    metadata = {key: value for key, value in document.items() if key not in _MODEL_KEYS}
    return Calibration(
        sensor_rotation=rotation,
        force_bias=values["force_bias"],
        torque_bias=values["torque_bias"],
        gravity_base=values["gravity_base"],
        center_of_mass=values["center_of_mass_m"],
        uncertainty=uncertainty,
        metadata=metadata,
        **optional,
    )


def _check_model_correlation(path: Path, entry: Any) -> None:
    """Check ``model_correlation`` (absent is fine): the parameters named, a symmetric 9×9 with unit diagonal."""
    if entry is None:
        return
    where = f"{path}: key '{MODEL_CORRELATION_KEY}'"
    if not isinstance(entry, dict) or list(entry.get("parameters") or []) != list(MODEL_CORRELATION_PARAMETERS):
        raise InputError(f"{where}: expected {{\"parameters\": {list(MODEL_CORRELATION_PARAMETERS)}, \"matrix\": "
                         "9×9}")
    try:
        matrix = np.asarray(entry.get("matrix"), dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}.matrix: expected a 9×9 array of numbers") from None
    size = 3 * len(MODEL_CORRELATION_PARAMETERS)
    if matrix.shape != (size, size) or not np.all(np.isfinite(matrix)):
        raise InputError(f"{where}.matrix: expected a {size}×{size} array of numbers, got shape {matrix.shape}")
    if np.abs(matrix - matrix.T).max() > CORRELATION_TOLERANCE or \
            np.abs(np.diag(matrix) - 1.0).max() > CORRELATION_TOLERANCE or \
            np.abs(matrix).max() > 1.0 + CORRELATION_TOLERANCE:
        raise InputError(f"{where}.matrix: not a correlation matrix (symmetric, unit diagonal, |r| ≤ 1)")


def _check_provenance(path: Path, document: dict) -> None:
    """Check the types of the optional provenance keys (``sensor``, ``tool``, ``bias_history``)."""
    sensor = document.get("sensor")
    if sensor is not None:
        if not isinstance(sensor, dict):
            raise InputError(f"{path}: key 'sensor': expected an object, got {type(sensor).__name__}")
        for key, value in sensor.items():
            if key in ("counts_per_force", "counts_per_torque"):
                check_number(value, f"{path}: key 'sensor.{key}'", low=0.0)
            elif not isinstance(value, str):
                raise InputError(f"{path}: key 'sensor.{key}': value {shown(value)} must be a string")
    tool = document.get("tool")
    if tool is not None and not (isinstance(tool, dict) and isinstance(tool.get("name", ""), str)):
        raise InputError(f"{path}: key 'tool': expected an object with a string 'name', got {shown(tool)}")
    history = document.get("bias_history")
    if history is None:
        return
    if not isinstance(history, list):
        raise InputError(f"{path}: key 'bias_history': expected a list, got {type(history).__name__}")
    for index, entry in enumerate(history):
        where = f"{path}: key 'bias_history[{index}]'"
        if not isinstance(entry, dict):
            raise InputError(f"{where}: expected an object, got {shown(entry)}")
        for key in ("force_bias", "torque_bias"):
            _array(path, {f"bias_history[{index}].{key}": entry.get(key)}, f"bias_history[{index}].{key}", (3,))
        if not isinstance(entry.get("time"), (str, type(None))) or not isinstance(entry.get("method", ""), str):
            raise InputError(f"{where}: 'time' and 'method' must be strings")
        for key in ("sensor", "previous_sensor"):
            if not isinstance(entry.get(key, ""), str):
                raise InputError(f"{where}: '{key}' must be a string (a serial number), got {shown(entry[key])}")


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration JSON file. Raises InputError (file, key, why) if unreadable or invalid."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(f"{path}: cannot read: {error}") from error
    return calibration_from_dict(load_json_text(text, str(path)), path)
