"""Pinocchio models of serial arms: the one builder of a standard DH chain (a UR model ftacq knows, or any DH
table: :func:`dh_chain_model`), the loader of a URDF, and the flange's placement from them (for IK and collision
checks in the planner, for the flange orientation of a caller that needs it every controller cycle:
:class:`FlangeRotation`, and for the tool's dynamics).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ftacq.kinematics.ur import URModel, dh_matrix

Floats = Sequence[float] | np.ndarray
"""One value per joint: a tuple (a :class:`URModel`'s fields) or an array (a DH table's column)."""
FLANGE_FRAME = "flange"
"""Name of the flange frame (DH frame 6, TCP offset zero) in the models built by :func:`pinocchio_model`."""

_LINK_MASS_PER_PAYLOAD = 4.0  # rough arm mass / rated payload; inertias only matter for dynamics, unused here


def dh_frame_name(i: int) -> str:
    """Return the Pinocchio frame name of DH frame ``i`` (1..6), the frame at the end of link ``i``."""
    return f"dh_{i}"


def dh_chain_model(name: str, alpha_rad: Floats, a_m: Floats, d_m: Floats, offset_rad: Floats | None = None,
                   lower_rad: Floats | None = None, upper_rad: Floats | None = None, speed_rad_s: Floats | None = None,
                   link_mass_kg: float = 1.0):
    """Build a ``pin.Model`` of a standard DH chain (one joint per entry of ``alpha_rad``, ``a_m``, ``d_m``): revolute-z
    joints whose flange FK equals the product of the DH steps (:func:`ftacq.kinematics.ur.dh_matrix`).

    Joint ``j`` sits at DH frame ``j-1`` rotated by ``Rz(offset_j)`` and turns about its z axis; the placement of
    joint ``j+1`` in joint ``j`` is the fixed DH step ``Tz(d_j) Tx(a_j) Rx(α_j)``. Operational frames ``dh_1`` …
    ``dh_n`` are the DH frames (``dh_n`` = :data:`FLANGE_FRAME`, also added under that name). Position limits
    default to ±4π, speeds to 1000 rad/s; the link inertias are placeholders (``link_mass_kg`` at the middle of
    each step: the planner and the imports use kinematics only).
    """
    import pinocchio as pin

    n = len(alpha_rad)
    lower = np.full(n, -4 * np.pi) if lower_rad is None else np.asarray(lower_rad, dtype=float)
    upper = np.full(n, 4 * np.pi) if upper_rad is None else np.asarray(upper_rad, dtype=float)
    speed = np.full(n, 1e3) if speed_rad_s is None else np.asarray(speed_rad_s, dtype=float)
    pin_model = pin.Model()
    pin_model.name = name
    parent_joint = 0
    placement = pin.SE3.Identity()
    for i in range(n):
        if offset_rad is not None:
            placement = placement * pin.SE3(pin.utils.rotate("z", float(offset_rad[i])), np.zeros(3))
        joint_id = pin_model.addJoint(
            parent_joint, pin.JointModelRZ(), placement, f"joint_{i + 1}",
            np.array([1000.0]), np.array([speed[i]]), np.array([lower[i]]), np.array([upper[i]]),
        )
        step = dh_matrix(alpha_rad[i], a_m[i], d_m[i])
        step_se3 = pin.SE3(step[:3, :3].copy(), step[:3, 3].copy())
        com = step[:3, 3] / 2.0
        pin_model.appendBodyToJoint(
            joint_id, pin.Inertia(link_mass_kg, com, np.eye(3) * link_mass_kg * 0.01), pin.SE3.Identity())
        pin_model.addFrame(pin.Frame(dh_frame_name(i + 1), joint_id, 0, step_se3, pin.FrameType.OP_FRAME))
        parent_joint, placement = joint_id, step_se3
    pin_model.addFrame(pin.Frame(FLANGE_FRAME, parent_joint, 0, placement, pin.FrameType.OP_FRAME))
    return pin_model


def pinocchio_model(model: URModel):
    """The ``pin.Model`` of a UR arm (:func:`dh_chain_model` of its DH table, its joint and speed limits): flange FK
    equal to :func:`ftacq.kinematics.ur.forward_kinematics`; frames ``dh_1`` … ``dh_6`` and :data:`FLANGE_FRAME`."""
    return dh_chain_model(model.name, model.alpha, model.a, model.d, lower_rad=model.joint_min_rad,
                          upper_rad=model.joint_max_rad, speed_rad_s=model.max_joint_speed_rad_s,
                          link_mass_kg=_LINK_MASS_PER_PAYLOAD * model.payload_kg / 6.0)


class FlangeRotation:
    """base_R_flange (3, 3) of joint angles (6,) in rad, by Pinocchio's forward kinematics on :func:`pinocchio_model`:
    one C++ pass (~3 µs) where :func:`forward_kinematics` multiplies six numpy DH matrices (~45 µs), for a caller
    that needs the flange orientation every controller cycle (the bridge's static compensation). Equal to
    ``forward_kinematics(model, q)[:3, :3]`` to 1e-15. Not thread-safe (one ``pin.Data``)."""

    def __init__(self, model: URModel) -> None:
        import pinocchio as pin

        self._pin = pin
        self.model = pinocchio_model(model)
        self.data = self.model.createData()
        self._frame = self.model.getFrameId(FLANGE_FRAME)

    def __call__(self, q_rad: np.ndarray) -> np.ndarray:
        pin = self._pin
        pin.forwardKinematics(self.model, self.data, np.asarray(q_rad, dtype=float))
        pin.updateFramePlacement(self.model, self.data, self._frame)
        return self.data.oMf[self._frame].rotation.copy()  # a view into data otherwise

    def placement(self, q_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(base_R_flange (3, 3), the flange's position (3,) in m, base frame) of joint angles (6,) in rad."""
        pin = self._pin
        pin.forwardKinematics(self.model, self.data, np.asarray(q_rad, dtype=float))
        pin.updateFramePlacement(self.model, self.data, self._frame)
        frame = self.data.oMf[self._frame]
        return frame.rotation.copy(), frame.translation.copy()


def pinocchio_model_from_urdf(path: str):
    """Load a ``pin.Model`` from a URDF file at ``path`` (e.g. the ``ur_description`` package's generated URDF).

    Raises :class:`ftacq.errors.InputError` naming the file if it cannot be read or parsed. Note that UR's URDFs
    put ``base_link`` rotated by π about z relative to the controller's ``base`` frame, and name the flange
    ``tool0``/``flange``; the planner itself uses :func:`pinocchio_model` (UR's DH table), so a URDF is a
    cross-check, not a requirement.
    """
    import pinocchio as pin

    from ftacq.errors import InputError

    try:
        return pin.buildModelFromUrdf(str(path))
    except (OSError, ValueError, RuntimeError) as exc:  # pinocchio raises ValueError/RuntimeError on bad XML
        raise InputError(f"{path}: cannot load URDF: {exc}") from exc


def pinocchio_dh_frames(pin_model, pin_data, q_rad: np.ndarray) -> np.ndarray:
    """Return the DH frames base_T_dh_i (6, 4, 4) from Pinocchio FK (``forwardKinematics`` + ``updateFramePlacements``)."""
    import pinocchio as pin

    pin.forwardKinematics(pin_model, pin_data, np.asarray(q_rad, dtype=float))
    pin.updateFramePlacements(pin_model, pin_data)
    out = np.empty((6, 4, 4))
    for i in range(6):
        out[i] = pin_data.oMf[pin_model.getFrameId(dh_frame_name(i + 1))].homogeneous
    return out


__all__ = ["FLANGE_FRAME", "dh_frame_name", "dh_chain_model", "pinocchio_model", "FlangeRotation",
           "pinocchio_model_from_urdf", "pinocchio_dh_frames"]
