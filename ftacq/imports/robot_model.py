"""Joint angles → flange pose through Pinocchio, for any serial arm: a UR model ftacq knows, a DH table, or a URDF.

- UR models: :func:`ftacq.kinematics.pinocchio_model` (UR's published DH table); the flange is DH frame 6, as the
  controller's ``actual_TCP_pose`` with a zero TCP offset.
- A DH table (CSV, one row per joint, base to flange): columns ``alpha`` (rad), ``a`` (m), ``d`` (m) and optional
  ``offset`` (rad; ``alpha_deg`` / ``offset_deg`` in degrees instead), standard (distal) convention
  ``T_j = Rz(q_j + offset_j) · Tz(d_j) · Tx(a_j) · Rx(alpha_j)``, flange = T_1 ⋯ T_n. Built as a Pinocchio model
  of revolute-z joints: joint j sits at DH frame j−1 rotated by Rz(offset_j); the fixed step
  Tz(d_j) Tx(a_j) Rx(alpha_j) places the next (:func:`ftacq.kinematics.dh_chain_model`, the builder of the UR
  models too). Prismatic joints are not supported.
- A URDF: :func:`ftacq.kinematics.pinocchio_model_from_urdf`, the flange being a frame of the URDF (``tool0``,
  ``flange``, or the one named); the joint angles fill the model's configuration in the URDF's joint order
  (a continuous joint takes cos q, sin q).

:class:`ArmModel` maps (N, n) joint angles to (N, 4, 4) ``base_T_flange``, one Pinocchio forward-kinematics pass
per row (~10 µs; an import of 10⁴ rows takes a fraction of a second).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ftacq.errors import InputError
from ftacq.kinematics import FLANGE_FRAME, dh_chain_model, pinocchio_model, pinocchio_model_from_urdf, ur_model

URDF_FLANGE_FRAMES = ("tool0", "flange", "ee_link")
"""Frames tried, in order, as the flange of a URDF when none is named."""
MAX_DH_JOINTS = 12


@dataclass
class ArmModel:
    """A Pinocchio model and its flange frame: ``flange_transforms(q)`` gives base_T_flange for joint angles.

    Attributes:
        name: what the model is (``UR5e``, ``dh:yumi-dh.csv``, ``urdf:arm.urdf#tool0``), for messages.
        joints: joint angles per configuration (columns a recording must give).
    """

    name: str
    joints: int
    pin_model: Any
    frame_id: int

    def flange_transforms(self, q_rad: np.ndarray) -> np.ndarray:
        """Return base_T_flange (N, 4, 4) for joint angles ``q_rad`` (N, joints), rad."""
        import pinocchio as pin

        q_rad = np.asarray(q_rad, dtype=float).reshape(-1, self.joints)
        data = self.pin_model.createData()
        out = np.empty((len(q_rad), 4, 4))
        configuration = pin.neutral(self.pin_model)
        slots = [(j.idx_q, j.nq) for j in list(self.pin_model.joints)[1:]]
        for k, q in enumerate(q_rad):
            for angle, (start, size) in zip(q, slots):
                if size == 1:
                    configuration[start] = angle
                else:  # continuous joint: (cos q, sin q)
                    configuration[start:start + 2] = (np.cos(angle), np.sin(angle))
            pin.framesForwardKinematics(self.pin_model, data, configuration)
            out[k] = data.oMf[self.frame_id].homogeneous
        return out


def ur_arm_model(name: str) -> ArmModel:
    """The ArmModel of a UR arm ftacq knows (``UR5e`` …); ValueError lists the known ones."""
    model = pinocchio_model(ur_model(name))
    return ArmModel(ur_model(name).name, 6, model, model.getFrameId(FLANGE_FRAME))


def read_dh_table(path: str | os.PathLike) -> np.ndarray:
    """Read a DH table CSV (see the module docstring); return (n, 4) [alpha, a, d, offset] in rad and m."""
    from ftacq.posefile import numeric_column, read_csv_table

    path = Path(path)
    header, rows, lines = read_csv_table(path, ())
    if not rows:
        raise InputError(f"{path}: no joints in the DH table")
    if len(rows) > MAX_DH_JOINTS:
        raise InputError(f"{path}: {len(rows)} joints: at most {MAX_DH_JOINTS}")

    def column(name: str, default: float | None = None) -> np.ndarray:
        for unit_name, scale in ((name, 1.0), (f"{name}_deg", np.pi / 180.0)):
            if unit_name in header:
                return numeric_column(path, header, rows, lines, unit_name) * scale
        if default is None:
            raise InputError(f"{path}: the DH table needs a column {name!r} (or {name}_deg); header: "
                             f"{','.join(header)}")
        return np.full(len(rows), default)

    table = np.column_stack([column("alpha"), column("a"), column("d"), column("offset", 0.0)])
    if np.any(np.abs(table[:, 1:3]) > 10.0):
        raise InputError(f"{path}: a DH length beyond 10 m: a and d are in metres")
    return table


def dh_arm_model(table: np.ndarray, name: str = "dh") -> ArmModel:
    """Build the ArmModel of a standard DH table (n, 4) [alpha, a, d, offset] (rad, m)."""
    table = np.asarray(table, dtype=float).reshape(-1, 4)
    model = dh_chain_model(name, table[:, 0], table[:, 1], table[:, 2], offset_rad=table[:, 3])
    return ArmModel(name, len(table), model, model.getFrameId(FLANGE_FRAME))


def urdf_arm_model(path: str | os.PathLike, frame: str | None = None) -> ArmModel:
    """Build the ArmModel of a URDF file whose flange is ``frame`` (default the first of URDF_FLANGE_FRAMES)."""
    model = pinocchio_model_from_urdf(str(path))
    names = [f.name for f in model.frames]
    wanted = [frame] if frame else [name for name in URDF_FLANGE_FRAMES if name in names]
    if not wanted or wanted[0] not in names:
        raise InputError(f"{path}: no frame {frame or ' or '.join(URDF_FLANGE_FRAMES)!r} to use as the flange "
                         f"(give one of: {', '.join(names[1:20])}{' …' if len(names) > 20 else ''})")
    kinds = {j.shortname() for j in list(model.joints)[1:]}
    if not kinds <= {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
                     "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned"}:
        raise InputError(f"{path}: only revolute joints are supported (found {', '.join(sorted(kinds))})")
    return ArmModel(f"urdf:{Path(path).name}#{wanted[0]}", model.njoints - 1, model, model.getFrameId(wanted[0]))


__all__ = ["ArmModel", "dh_arm_model", "read_dh_table", "ur_arm_model", "urdf_arm_model"]
