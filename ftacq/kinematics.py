"""Universal Robots kinematics from UR's published DH parameters.

Standard (distal) DH: ``T_i = Rz(q_i + θ_i) Tz(d_i) Tx(a_i) Rx(α_i)``; the product of the six is
``base_T_flange`` (the tool flange, TCP offset zero), which is what a UR controller reports as
``actual_TCP_pose`` when its TCP offset is zero. A Pinocchio model of the same chain is built by
:func:`pinocchio_model` for IK and collision checking in the planner, and for the flange orientation of a caller
that needs it every controller cycle (:class:`FlangeRotation`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.so3 import rotvec_from_rotation

_HALF_PI = np.pi / 2


@dataclass(frozen=True)
class URModel:
    """A UR arm: DH parameters (m, rad) and joint limits (rad).

    Attributes:
        name: e.g. ``"UR5e"``. d, a, alpha: the six DH d_i, a_i (m) and α_i (rad).
        joint_min_rad, joint_max_rad: position limits (elbow restricted to ±π as in UR's URDFs).
        max_joint_speed_rad_s: the arm's rated joint speeds.
        link_radius_m: approximate radius of each link for collision checks.
        payload_kg: rated payload.
    """

    name: str
    d: tuple[float, ...]
    a: tuple[float, ...]
    alpha: tuple[float, ...]
    joint_min_rad: tuple[float, ...]
    joint_max_rad: tuple[float, ...]
    max_joint_speed_rad_s: tuple[float, ...]
    link_radius_m: float
    payload_kg: float


def _model(name, d, a, speed, radius, payload) -> URModel:
    two_pi = 2 * np.pi
    return URModel(
        name=name,
        d=tuple(d),
        a=tuple(a),
        alpha=(_HALF_PI, 0.0, 0.0, _HALF_PI, -_HALF_PI, 0.0),
        joint_min_rad=(-two_pi, -two_pi, -np.pi, -two_pi, -two_pi, -two_pi),
        joint_max_rad=(two_pi, two_pi, np.pi, two_pi, two_pi, two_pi),
        max_joint_speed_rad_s=tuple(speed),
        link_radius_m=radius,
        payload_kg=payload,
    )


_PI = np.pi
UR_MODELS: dict[str, URModel] = {
    # UR's published DH tables ("DH parameters for calculations of kinematics and dynamics").
    "UR3": _model("UR3", (0.1519, 0, 0, 0.11235, 0.08535, 0.0819), (0, -0.24365, -0.21325, 0, 0, 0),
                  (_PI, _PI, _PI, 2 * _PI, 2 * _PI, 2 * _PI), 0.045, 3.0),
    "UR5": _model("UR5", (0.089159, 0, 0, 0.10915, 0.09465, 0.0823), (0, -0.425, -0.39225, 0, 0, 0),
                  (_PI, _PI, _PI, _PI, _PI, _PI), 0.06, 5.0),
    "UR10": _model("UR10", (0.1273, 0, 0, 0.163941, 0.1157, 0.0922), (0, -0.612, -0.5723, 0, 0, 0),
                   (2 * _PI / 3, 2 * _PI / 3, _PI, _PI, _PI, _PI), 0.075, 10.0),
    "UR3e": _model("UR3e", (0.15185, 0, 0, 0.13105, 0.08535, 0.0921), (0, -0.24355, -0.2132, 0, 0, 0),
                   (_PI, _PI, _PI, 2 * _PI, 2 * _PI, 2 * _PI), 0.045, 3.0),
    "UR5e": _model("UR5e", (0.1625, 0, 0, 0.1333, 0.0997, 0.0996), (0, -0.425, -0.3922, 0, 0, 0),
                   (_PI, _PI, _PI, _PI, _PI, _PI), 0.06, 5.0),
    "UR10e": _model("UR10e", (0.1807, 0, 0, 0.17415, 0.11985, 0.11655), (0, -0.6127, -0.57155, 0, 0, 0),
                    (2 * _PI / 3, 2 * _PI / 3, _PI, _PI, _PI, _PI), 0.075, 12.5),
    "UR16e": _model("UR16e", (0.1807, 0, 0, 0.17415, 0.11985, 0.11655), (0, -0.4784, -0.36, 0, 0, 0),
                    (2 * _PI / 3, 2 * _PI / 3, _PI, _PI, _PI, _PI), 0.075, 16.0),
    "UR20": _model("UR20", (0.2363, 0, 0, 0.2010, 0.1593, 0.1543), (0, -0.8620, -0.7287, 0, 0, 0),
                   (2 * _PI / 3, 2 * _PI / 3, _PI, 2 * _PI / 3, 2 * _PI / 3, 2 * _PI / 3), 0.1, 20.0),
    "UR30": _model("UR30", (0.2363, 0, 0, 0.2010, 0.1593, 0.1543), (0, -0.6370, -0.5037, 0, 0, 0),
                   (2 * _PI / 3, 2 * _PI / 3, _PI, 2 * _PI / 3, 2 * _PI / 3, 2 * _PI / 3), 0.1, 30.0),
}


JOINT_LIMIT_MARGIN_RAD = float(np.radians(5.0))
"""Every planned joint target stays this far inside each joint limit (5°). It covers what the arm adds to a
target: the executor accepts a pose reached within ``TARGET_TOLERANCE_RAD`` (0.01 rad, 0.6°) of it, the encoders'
jitter (:data:`MEASURED_ANGLE_TOLERANCE_RAD`), and the next move starting from that measured configuration. It
costs no reach on a ±360° joint (every angle has an equivalent within ±355°); on the ±180° elbow it leaves out
175-180°, which the elbow-singularity margin already mostly excludes (|sin q3| < 0.05: beyond 177.1°)."""
MEASURED_ANGLE_TOLERANCE_RAD = 1e-4
"""A *measured* joint angle (what the controller reports) may lie this far outside a joint limit and still count as
inside it. A UR's reported angles jitter by about 1e-6 rad at rest (encoder noise; the simulated controller's
``encoder_noise_rad``): 1e-4 rad (0.006°) is 100 times that, so noise never refuses a move that starts at a limit,
while an arm truly beyond its limit is still caught. Planned targets get no tolerance: they are checked against
the limits less :data:`JOINT_LIMIT_MARGIN_RAD`."""


def planning_limits_rad(model: "URModel", margin_rad: float = JOINT_LIMIT_MARGIN_RAD) -> tuple[np.ndarray, np.ndarray]:
    """Return (lower, upper) (6,) joint limits less ``margin_rad`` on each side: the range planned targets keep to."""
    lower, upper = np.array(model.joint_min_rad, dtype=float), np.array(model.joint_max_rad, dtype=float)
    return lower + margin_rad, upper - margin_rad


def middle_equivalent(q_rad: np.ndarray, lower_rad: np.ndarray, upper_rad: np.ndarray) -> np.ndarray:
    """Return each joint's 2π-equivalent nearest the middle of its range [lower, upper] (rad).

    The planner takes it when the equivalent nearest the previous target would leave the range: it leaves the
    most room on both sides for the moves that follow.
    """
    q = np.asarray(q_rad, dtype=float)
    middle = (np.asarray(lower_rad, dtype=float) + np.asarray(upper_rad, dtype=float)) / 2.0
    return q + 2.0 * np.pi * np.round((middle - q) / (2.0 * np.pi))


def ur_model(name: str) -> URModel:
    """Return the model called ``name`` (case-insensitive, e.g. ``"ur5e"``). Raises ValueError listing the known ones."""
    for key, model in UR_MODELS.items():
        if key.lower() == name.lower():
            return model
    raise ValueError(f"unknown UR model {name!r}; known: {', '.join(UR_MODELS)}")


def dh_transforms(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the cumulative transforms base_T_link_i (6, 4, 4) for joint angles ``q_rad`` (6,)."""
    q_rad = np.asarray(q_rad, dtype=float)
    out = np.empty((6, 4, 4))
    current = np.eye(4)
    for i in range(6):
        ct, st = np.cos(q_rad[i]), np.sin(q_rad[i])
        ca, sa = np.cos(model.alpha[i]), np.sin(model.alpha[i])
        step = np.array([
            [ct, -st * ca, st * sa, model.a[i] * ct],
            [st, ct * ca, -ct * sa, model.a[i] * st],
            [0.0, sa, ca, model.d[i]],
            [0.0, 0.0, 0.0, 1.0],
        ])
        current = current @ step
        out[i] = current
    return out


def forward_kinematics(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return base_T_flange (4, 4) for joint angles ``q_rad`` (6,) in rad."""
    return dh_transforms(model, q_rad)[-1]


def flange_pose(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the flange pose [x, y, z (m), rx, ry, rz (rad)] as a UR controller reports it (TCP offset zero)."""
    base_T_flange = forward_kinematics(model, q_rad)
    return np.concatenate([base_T_flange[:3, 3], rotvec_from_rotation(base_T_flange[:3, :3])])


# ----------------------------------------------------------------------------------------------------------------
# Pinocchio model of the same chain
# ----------------------------------------------------------------------------------------------------------------

FLANGE_FRAME = "flange"
"""Name of the flange frame (DH frame 6, TCP offset zero) in the models built by :func:`pinocchio_model`."""

_LINK_MASS_PER_PAYLOAD = 4.0  # rough arm mass / rated payload; inertias only matter for dynamics, unused here


def dh_frame_name(i: int) -> str:
    """Return the Pinocchio frame name of DH frame ``i`` (1..6), the frame at the end of link ``i``."""
    return f"dh_{i}"


def dh_step(model: URModel, i: int) -> np.ndarray:
    """Return the fixed part ``Tz(d_i) Tx(a_i) Rx(α_i)`` (4, 4) of DH step ``i`` (0-based) after ``Rz(q_i)``."""
    ca, sa = np.cos(model.alpha[i]), np.sin(model.alpha[i])
    return np.array([
        [1.0, 0.0, 0.0, model.a[i]],
        [0.0, ca, -sa, 0.0],
        [0.0, sa, ca, model.d[i]],
        [0.0, 0.0, 0.0, 1.0],
    ])


def pinocchio_model(model: URModel):
    """Build a ``pin.Model`` of ``model``: six revolute-z joints whose flange FK equals :func:`forward_kinematics`.

    Joint ``i`` sits at DH frame ``i-1`` and turns about its z axis (``Rz(q_i)``); the placement of joint ``i+1``
    in joint ``i`` is the fixed DH step ``Tz(d_i) Tx(a_i) Rx(α_i)``. Operational frames ``dh_1`` … ``dh_6`` are the
    DH frames (``dh_6`` = :data:`FLANGE_FRAME`, also added under that name). Position and velocity limits come from
    the model; the inertias are rough placeholders (the planner uses kinematics only).
    """
    import pinocchio as pin

    pin_model = pin.Model()
    pin_model.name = model.name
    link_mass_kg = _LINK_MASS_PER_PAYLOAD * model.payload_kg / 6.0
    parent_joint = 0
    placement = pin.SE3.Identity()
    for i in range(6):
        joint_id = pin_model.addJoint(
            parent_joint, pin.JointModelRZ(), placement, f"joint_{i + 1}",
            np.array([1000.0]), np.array([model.max_joint_speed_rad_s[i]]),
            np.array([model.joint_min_rad[i]]), np.array([model.joint_max_rad[i]]),
        )
        step = dh_step(model, i)
        step_se3 = pin.SE3(step[:3, :3].copy(), step[:3, 3].copy())
        com = step[:3, 3] / 2.0
        pin_model.appendBodyToJoint(
            joint_id, pin.Inertia(link_mass_kg, com, np.eye(3) * link_mass_kg * 0.01), pin.SE3.Identity())
        pin_model.addFrame(pin.Frame(dh_frame_name(i + 1), joint_id, 0, step_se3, pin.FrameType.OP_FRAME))
        parent_joint, placement = joint_id, step_se3
    pin_model.addFrame(pin.Frame(FLANGE_FRAME, parent_joint, 0, placement, pin.FrameType.OP_FRAME))
    return pin_model


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


def dh_transforms_batch(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return base_T_link_i (S, 6, 4, 4) for configurations ``q_rad`` (S, 6), vectorised over S.

    Same chain as :func:`dh_transforms` and Pinocchio's model (tested equal to 1e-12); used where many
    configurations are needed at once (sampling a joint move for collision checks), where one Pinocchio call
    per configuration would cost ~30 µs of Python overhead each.
    """
    q = np.asarray(q_rad, dtype=float).reshape(-1, 6)
    n = q.shape[0]
    out = np.empty((n, 6, 4, 4))
    current = np.broadcast_to(np.eye(4), (n, 4, 4))
    for i in range(6):
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        ca, sa = np.cos(model.alpha[i]), np.sin(model.alpha[i])
        step = np.zeros((n, 4, 4))
        step[:, 0, 0], step[:, 0, 1], step[:, 0, 2], step[:, 0, 3] = ct, -st * ca, st * sa, model.a[i] * ct
        step[:, 1, 0], step[:, 1, 1], step[:, 1, 2], step[:, 1, 3] = st, ct * ca, -ct * sa, model.a[i] * st
        step[:, 2, 1], step[:, 2, 2], step[:, 2, 3] = sa, ca, model.d[i]
        step[:, 3, 3] = 1.0
        current = current @ step
        out[:, i] = current
    return out
