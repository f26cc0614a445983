"""Universal Robots arms from UR's published DH parameters, and the one DH step.

Standard (distal) DH: ``T_i = Rz(q_i + θ_i) Tz(d_i) Tx(a_i) Rx(α_i)`` (:func:`dh_matrix`, one configuration or a
batch); the product of the six is ``base_T_flange`` (the tool flange, TCP offset zero), which is what a UR
controller reports as ``actual_TCP_pose`` when its TCP offset is zero. The Pinocchio model of the same chain is
:mod:`ftacq.kinematics.pinocchio_models`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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


def dh_matrix(alpha_rad: float, a_m: float, d_m: float, q_rad=0.0) -> np.ndarray:
    """The one DH step ``Rz(q) Tz(d) Tx(a) Rx(α)``: (4, 4) for a joint angle ``q_rad`` (rad), (…, 4, 4) for an
    array of them; ``q_rad`` 0 gives the fixed part ``Tz(d) Tx(a) Rx(α)`` (a Pinocchio joint's placement)."""
    q = np.asarray(q_rad, dtype=float)
    ct, st = np.cos(q), np.sin(q)
    ca, sa = np.cos(alpha_rad), np.sin(alpha_rad)
    if q.ndim == 0:  # one matrix: a literal is 2.5 times faster than the batch's assignments (IK, FK per pose)
        return np.array([
            [ct, -st * ca, st * sa, a_m * ct],
            [st, ct * ca, -ct * sa, a_m * st],
            [0.0, sa, ca, d_m],
            [0.0, 0.0, 0.0, 1.0],
        ])
    step = np.zeros(q.shape + (4, 4))
    step[..., 0, 0], step[..., 0, 1], step[..., 0, 2], step[..., 0, 3] = ct, -st * ca, st * sa, a_m * ct
    step[..., 1, 0], step[..., 1, 1], step[..., 1, 2], step[..., 1, 3] = st, ct * ca, -ct * sa, a_m * st
    step[..., 2, 1], step[..., 2, 2], step[..., 2, 3] = sa, ca, d_m
    step[..., 3, 3] = 1.0
    return step


def dh_step(model: URModel, i: int, q_rad=0.0) -> np.ndarray:
    """:func:`dh_matrix` of joint ``i`` (0-based) of ``model``; ``q_rad`` 0: the fixed part after ``Rz(q_i)``."""
    return dh_matrix(model.alpha[i], model.a[i], model.d[i], q_rad)


def dh_transforms(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the cumulative transforms base_T_link_i (6, 4, 4) for joint angles ``q_rad`` (6,)."""
    q_rad = np.asarray(q_rad, dtype=float)
    out = np.empty((6, 4, 4))
    current = np.eye(4)
    for i in range(6):
        current = current @ dh_step(model, i, q_rad[i])
        out[i] = current
    return out


def forward_kinematics(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return base_T_flange (4, 4) for joint angles ``q_rad`` (6,) in rad."""
    return dh_transforms(model, q_rad)[-1]


def flange_pose(model: URModel, q_rad: np.ndarray) -> np.ndarray:
    """Return the flange pose [x, y, z (m), rx, ry, rz (rad)] as a UR controller reports it (TCP offset zero)."""
    return pose_of_transform(forward_kinematics(model, q_rad))


def pose_of_transform(base_T_frame: np.ndarray) -> np.ndarray:
    """Return [x, y, z (m), rx, ry, rz (rad)] of a (4, 4) transform: a pose as a UR controller reports one."""
    from ftacq.so3 import rotvec_of_rotation

    return np.concatenate([base_T_frame[:3, 3], rotvec_of_rotation(base_T_frame[:3, :3])])


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
        current = current @ dh_step(model, i, q[:, i])
        out[:, i] = current
    return out
