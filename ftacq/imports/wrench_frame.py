"""Wrenches recorded in the robot base frame, and the check that names that mistake.

Some recorders store the wrench rotated into the base frame (``base_R_sensor · F``, torques about the sensor origin
in base axes). The identification needs sensor-frame readings; with the flange pose known, ``flange_R_base · w``
is the reading of a sensor aligned with the flange, and any fixed rotation between the flange and the real sensor
is absorbed by the identified ``sensor_R_flange`` (method: a constant rotation of the data is a change of sensor
frame, the biases stay constant).

Fed the wrong way, the fit cannot work: base-frame forces hardly change with the orientation (gravity points
down whatever the tool does) while the model rotates the weight with the flange. :func:`wrench_frame_finding`
fits the paper's closed form to the other frame's wrenches too and names the frame that fits
:data:`FRAME_RATIO`× better (a verdict finding, check ``frame``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ftacq.posefile import PoseRecord

FRAME_RATIO = 3.0
"""The other frame's closed-form force RMS this many times smaller than the frame given: the frame is wrong."""
MAX_CHECKED_POSES = 500
"""A larger record is checked on this many of its rows, evenly spaced (two closed-form fits of 10⁴ rows cost
seconds; a few hundred poses tell the frames apart as well)."""


def rotate_wrench(rotation: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """Return ``wrench`` (N, 6) with force and torque rotated by ``rotation`` (N, 3, 3)."""
    wrench = np.asarray(wrench, dtype=float).reshape(-1, 6)
    force = np.einsum("nij,nj->ni", rotation, wrench[:, :3])
    torque = np.einsum("nij,nj->ni", rotation, wrench[:, 3:])
    return np.hstack([force, torque])


def sensor_from_base(record: PoseRecord) -> PoseRecord:
    """Return the record with base-frame wrenches (and std) expressed in the flange frame: ``flange_R_base · w``."""
    return _rotated(record, record.flange_R_base)


def base_from_sensor(record: PoseRecord) -> PoseRecord:
    """The inverse of :func:`sensor_from_base`: ``base_R_flange · w``."""
    return _rotated(record, np.swapaxes(record.flange_R_base, -1, -2))


def _rotated(record: PoseRecord, rotation: np.ndarray) -> PoseRecord:
    from dataclasses import replace

    std = None
    if record.std is not None:  # the variance of a rotated channel mixes the others': keep the largest as its σ
        std = np.repeat(np.maximum(record.std[:, :3].max(axis=1, keepdims=True), 0.0), 3, axis=1)
        std = np.hstack([std, np.repeat(record.std[:, 3:].max(axis=1, keepdims=True), 3, axis=1)])
    return replace(record, wrench=rotate_wrench(rotation, record.wrench), std=std)


def _closed_form_force_rms(record: PoseRecord) -> float | None:
    from ftacq.errors import IdentificationError
    from ftacq.identification import identify

    try:
        result = identify(record, refine=False, orientation_error=False)
    except IdentificationError:
        return None
    return float(np.sqrt(np.mean(result.closed_form_residuals[:, :3] ** 2)))


def frame_mismatch(record: PoseRecord, frame: str = "sensor", given_rms: float | None = None
                   ) -> tuple[str | None, dict]:
    """Return (the hint when the other frame fits :data:`FRAME_RATIO`× better, else None; the figures).

    ``record`` holds the wrenches as fitted (after any conversion from ``frame``); ``given_rms`` its closed-form
    force RMS when already known (else fitted here). Records over :data:`MAX_CHECKED_POSES` rows are judged on
    that many rows, evenly spaced.
    """
    if len(record) > MAX_CHECKED_POSES:
        record = record.select(np.linspace(0, len(record) - 1, MAX_CHECKED_POSES).round().astype(int))
        given_rms = None  # both frames judged on the same rows
    given = _closed_form_force_rms(record) if given_rms is None else given_rms
    other = "base" if frame == "sensor" else "sensor"
    alternative = sensor_from_base(record) if frame == "sensor" else base_from_sensor(record)
    other_rms = _closed_form_force_rms(alternative)
    figures = {"frame": frame, "force_rms_n": given, "other_frame": other, "other_force_rms_n": other_rms,
               "ratio_limit": FRAME_RATIO}
    if other_rms is None or (given is not None and other_rms * FRAME_RATIO >= given):
        return None, figures
    option = "--wrench-frame base" if other == "base" else "--wrench-frame sensor (the default)"
    shown = "no fit" if given is None else f"{given:.3g} N"
    return (f"the wrenches look like {other}-frame: use {option} (the fit leaves {other_rms:.3g} N RMS that way, "
            f"{shown} as given)"), figures


def wrench_frame_finding(record: PoseRecord, result: Any, frame: str = "sensor") -> Any:
    """Judge whether the record's wrenches were given in the right frame (a :class:`ftacq.verdict.Finding`,
    check ``frame``): FAIL with the option to use when the other frame fits :data:`FRAME_RATIO`× better.

    ``record`` is what was fitted (wrenches after any conversion from ``frame``), ``result`` its
    IdentificationResult.
    """
    from ftacq.verdict import FAIL, PASS, Finding

    given = float(np.sqrt(np.mean(result.closed_form_residuals[:, :3] ** 2)))
    hint, figures = frame_mismatch(record, frame, given)
    other_rms = figures["other_force_rms_n"]
    details = (f"closed-form force RMS with the wrenches in the {frame} frame {given:.3g} N; with them taken as "
               f"{figures['other_frame']}-frame " + ("(no fit)" if other_rms is None else f"{other_rms:.3g} N")
               + f"; the frame is named wrong when the other fits {FRAME_RATIO:g}× better")
    if hint is not None:
        return Finding("frame", FAIL, hint, details, figures)
    return Finding("frame", PASS, f"the wrenches fit in the {frame} frame they were given in", details, figures)


__all__ = ["FRAME_RATIO", "base_from_sensor", "frame_mismatch", "rotate_wrench", "sensor_from_base",
           "wrench_frame_finding"]
