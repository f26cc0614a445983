"""Read a recording back with Rerun's own reader (:class:`rerun.chunk.RrdReader`): what the tests and benchmarks
check a dashboard recording against.

The ``sensor_time`` timeline holds seconds since the run's start; the readers return times on the host monotonic
clock (the timeline plus the recording's ``ftacq_time`` origin), as the data was logged, unless ``absolute=False``.
"""

from __future__ import annotations

import os

import numpy as np
from rerun.chunk import RrdReader

from ftacq.app.dashboard.layout import SENSOR_TIMELINE


def _chunks(rrd_path: str | os.PathLike):
    return RrdReader(rrd_path).stream().to_chunks()


def time_origin_s(rrd_path: str | os.PathLike) -> float:
    """Return the host monotonic time (s) of the ``sensor_time`` timeline's zero (the ``ftacq_time`` property)."""
    for chunk in _chunks(rrd_path):
        if chunk.entity_path == "/__properties/ftacq_time":
            return float(chunk.to_record_batch().column("origin_monotonic_s").to_pylist()[0][0])
    raise AssertionError(f"{rrd_path}: no ftacq_time property (not written by ftacq's Dashboard)")


def _seconds(rrd_path, time_ns: np.ndarray, absolute: bool) -> np.ndarray:
    return time_ns * 1e-9 + (time_origin_s(rrd_path) if absolute else 0.0)


def read_scalars(rrd_path: str | os.PathLike, entity_path: str, *,
                 absolute: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(time_s, values)`` of a Scalars entity: (N,) seconds (see the module) and (N, k) values, in time
    order."""
    wanted = "/" + entity_path.strip("/")
    times, values = [], []
    for chunk in _chunks(rrd_path):
        if chunk.entity_path != wanted or chunk.is_static or chunk.num_rows == 0:
            continue
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if SENSOR_TIMELINE not in names or "Scalars:scalars" not in names:
            continue
        times.append(batch.column(SENSOR_TIMELINE).cast("int64").to_numpy())
        column = batch.column("Scalars:scalars")
        values.append(column.flatten().to_numpy().reshape(len(column), -1))
    if not times:
        return np.empty(0), np.empty((0, 0))
    time_ns = np.concatenate(times)
    order = np.argsort(time_ns, kind="stable")
    return _seconds(rrd_path, time_ns[order], absolute), np.concatenate(values)[order]


def entity_paths(rrd_path: str | os.PathLike) -> set[str]:
    """Return the entity paths (without the leading "/") that hold data in an .rrd file's recording."""
    return {chunk.entity_path.lstrip("/") for chunk in _chunks(rrd_path)}


def static_paths(rrd_path: str | os.PathLike, component: str) -> set[str]:
    """Return the entity paths holding ``component`` (e.g. "LineStrips3D:strips") as static data."""
    found = set()
    for chunk in _chunks(rrd_path):
        if chunk.is_static and component in chunk.to_record_batch().schema.names:
            found.add(chunk.entity_path.lstrip("/"))
    return found


def read_column(rrd_path: str | os.PathLike, entity_path: str, component: str, *,
                absolute: bool = True) -> tuple[np.ndarray, list]:
    """Return ``(time_s, rows)`` of a temporal component: (N,) s (see the module) and N Python rows, time order."""
    wanted = "/" + entity_path.strip("/")
    times, rows = [], []
    for chunk in _chunks(rrd_path):
        if chunk.entity_path != wanted or chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if SENSOR_TIMELINE not in batch.schema.names or component not in batch.schema.names:
            continue
        times.append(batch.column(SENSOR_TIMELINE).cast("int64").to_numpy())
        rows += batch.column(component).to_pylist()
    if not times:
        return np.empty(0), []
    time_ns = np.concatenate(times)
    order = np.argsort(time_ns, kind="stable")
    return _seconds(rrd_path, time_ns[order], absolute), [rows[i] for i in order]


def read_texts(rrd_path: str | os.PathLike, entity_path: str) -> list[str]:
    """Return the TextLog lines logged to ``entity_path``."""
    texts: list[str] = []
    for chunk in _chunks(rrd_path):
        batch = chunk.to_record_batch()
        if chunk.entity_path == "/" + entity_path and "TextLog:text" in batch.schema.names:
            texts += [row[0] for row in batch.column("TextLog:text").to_pylist()]
    return texts


def count_chunks(rrd_path: str | os.PathLike, entity_path: str) -> int:
    """Return how many chunks hold data of ``entity_path``."""
    return sum(chunk.entity_path == "/" + entity_path.strip("/") for chunk in _chunks(rrd_path))


def mixed_static_and_temporal(rrd_path: str | os.PathLike, under: str = "world") -> set[str]:
    """Return the entity paths under ``under`` holding both static and temporal data (the viewer showed such
    entities of a file written live only after ``rerun rrd optimize``)."""
    kinds: dict[str, set[bool]] = {}
    for chunk in _chunks(rrd_path):
        path = chunk.entity_path.lstrip("/")
        if path == under or path.startswith(under + "/"):
            kinds.setdefault(path, set()).add(bool(chunk.is_static))
    return {path for path, seen in kinds.items() if len(seen) == 2}


def blueprint_views(rrd_path: str | os.PathLike) -> dict[str, tuple[str, str]]:
    """Return the views of the recording's blueprint: display name → (view class, origin entity path)."""
    reader = RrdReader(rrd_path)
    views = {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            batch = chunk.to_record_batch()
            if "ViewBlueprint:space_origin" not in batch.schema.names:
                continue
            for kind, name, origin in zip(*(batch.column(f"ViewBlueprint:{c}").to_pylist()
                                            for c in ("class_identifier", "display_name", "space_origin"))):
                views[name[0]] = (kind[0], origin[0])
    return views
