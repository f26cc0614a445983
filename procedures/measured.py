"""The value types of a measured pose, shared by the procedure (which makes them) and the run folder (which keeps
them): :class:`MeasuredPose` and the label of the drift-check revisit. The drift-check set itself is a row of the
pose-set table (:data:`ftacq.posesets.DRIFT_SET`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DRIFT_SUFFIX = "-revisit"
"""Appended to the first pose's label for its drift-check revisit (``A01-revisit``)."""


def drift_label(first_label: str) -> str:
    """Return the label of the drift-check revisit of pose ``first_label``."""
    return f"{first_label}{DRIFT_SUFFIX}"


@dataclass(frozen=True)
class MeasuredPose:
    """One measured pose as the procedure needs it back on resume (one row of ``poses.csv``; SI units).

    Attributes:
        label: the plan's label ("A07", "A01-revisit"). set_name: its pose set (:mod:`ftacq.posesets`).
        pose: flange pose (6,) in the base frame [x, y, z (m), rx, ry, rz (rad)] when averaging.
        mean, std: averaged wrench (6,) and its per-channel standard deviation (or None) [N, N·m], sensor frame.
        count: samples averaged. t_end_s: end of the averaging window, UNIX time, s (None when unknown).
    """

    label: str
    set_name: str
    pose: np.ndarray
    mean: np.ndarray
    std: np.ndarray | None
    count: int
    t_end_s: float | None


__all__ = ["MeasuredPose", "drift_label", "DRIFT_SUFFIX"]


def pose_record(rows: list[MeasuredPose]):
    """Return measured poses as one :class:`ftacq.posefile.PoseRecord` (in the order given), or None for none."""
    from ftacq.posefile import PoseRecord

    if not rows:
        return None
    std = None if any(r.std is None for r in rows) else np.array([r.std for r in rows])
    # the end of each averaging window: the time axis of a bias drift over the run (ftacq.identification.trend)
    extra = {} if any(r.t_end_s is None for r in rows) else {"t_end_s": np.array([r.t_end_s for r in rows], dtype=float)}
    return PoseRecord(pose=np.array([r.pose for r in rows]), wrench=np.array([r.mean for r in rows]), std=std,
                      count=np.array([max(r.count, 1) for r in rows], dtype=float),
                      labels=tuple(r.label for r in rows), sets=tuple(r.set_name for r in rows), extra=extra)
