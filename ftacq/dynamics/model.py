"""The tool as a rigid body on the sensor: Pinocchio's sensor-frame motion and body regressor, and the predicted
wrench while the arm moves.

Frames: B base, E flange, S sensor. The sensor frame S is placed in the flange frame by ``flange_R_sensor =
sensor_rotationᵀ`` (the calibration's ``sensor_R_flange``) and the sensor origin ``sensor_offset`` (m). Pinocchio
gives S's spatial velocity v_S and spatial acceleration a_S in S (``pin.LOCAL``) from (q, q̇, q̈) on UR's DH chain
(:func:`ftacq.kinematics.pinocchio_model`).

The sensor reads what the tool exerts on it: the opposite of the wrench that holds the tool against gravity and
accelerates it. With Pinocchio's body regressor Y(v, a) (``I a + v ×* I v = Y π``, π the ten inertial parameters
[m, m c, I_S] about the sensor origin, ``pin.Inertia.toDynamicParameters``) and gravity entering as an upward
acceleration of the base (as in RNEA):

    wrench_S = −Y(v_S, a_S − g_S) π + bias        g_S = base_R_Sᵀ g_B,   g_B = gravity_base / m

At rest this is exactly the static model of the paper (F = m g_S, T = c × m g_S). :func:`regressor` returns
R = −Y, so that ``wrench_S = R π + bias`` is linear in π: the identification's least squares
(:mod:`ftacq.dynamics.identify`) uses it.

Predicting (:class:`WrenchPredictor`, :func:`predict_moving`): the same Newton–Euler equation,
``I (a_S − g_S) + v_S ×* I v_S = Y(v_S, a_S − g_S) π``, evaluated by Pinocchio's RNEA on a copy of the arm that
carries only the tool (π placed at the sensor frame on the last joint, every link massless, the calibration's
gravity as the model's): the force the last joint transmits, expressed in the sensor frame, is the wrench that
holds and accelerates the tool. One C++ call per robot state (~5 µs with Python's overhead, against ~35 µs for the
motion, the regressor and the product with π; equal to R π + bias to 1e-14 N, tests/test_dynamics_identify.py).

Cost: the robot's states come at 500 Hz, so the live path evaluates the model once per robot state and interpolates
the predicted wrench onto the 7 kHz sensor samples (:func:`ftacq.dynamics.compensate_moving`,
procedures/dynamic_compensation.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftacq.calibration import Calibration
from ftacq.kinematics import FLANGE_FRAME, URModel, pinocchio_model

SENSOR_FRAME = "sensor"
"""Name of the sensor frame added to the Pinocchio model."""


def inertial_parameters(mass_kg: float, center_of_mass_m: np.ndarray, inertia_kg_m2: np.ndarray) -> np.ndarray:
    """Return π (10,) = [m, m c (3), I about the sensor origin (xx, xy, yy, xz, yz, zz)] (Pinocchio's order) from
    the mass, the centre of mass and the inertia about the centre of mass (sensor frame)."""
    import pinocchio as pin

    return np.array(pin.Inertia(float(mass_kg), np.asarray(center_of_mass_m, dtype=float),
                                np.asarray(inertia_kg_m2, dtype=float)).toDynamicParameters())


def body_from_parameters(parameters: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Return (mass kg, centre of mass m, inertia about the centre of mass kg·m²) of π (10,) (sensor frame)."""
    import pinocchio as pin

    body = pin.Inertia.FromDynamicParameters(np.asarray(parameters, dtype=float))
    return float(body.mass), np.array(body.lever), np.array(body.inertia)


def pseudo_inertia(parameters: np.ndarray) -> np.ndarray:
    """Return the 4×4 pseudo-inertia J(π) = [[Σ, m c], [m cᵀ, m]], Σ = ½ tr(I_S) 𝟙 − I_S (Wensing, Kim & Slotine
    2017): π belongs to a physical body (positive mass, positive-definite inertia about the centre of mass, triangle
    inequalities on its principal moments) exactly when J(π) ≻ 0."""
    m, hx, hy, hz, ixx, ixy, iyy, ixz, iyz, izz = np.asarray(parameters, dtype=float)
    inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    sigma = 0.5 * np.trace(inertia) * np.eye(3) - inertia
    return np.block([[sigma, np.array([[hx], [hy], [hz]])], [np.array([[hx, hy, hz]]), np.array([[m]])]])


def parameters_from_pseudo_inertia(matrix: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pseudo_inertia`: π (10,) from a symmetric 4×4 J."""
    sigma = matrix[:3, :3]
    inertia = np.trace(sigma) * np.eye(3) - sigma
    h = matrix[:3, 3]
    return np.array([matrix[3, 3], h[0], h[1], h[2], inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2],
                     inertia[1, 2], inertia[2, 2]])


@dataclass(frozen=True)
class SensorMotion:
    """The sensor frame's motion for N robot states.

    Attributes:
        base_R_sensor (N, 3, 3); velocity (N, 6) [linear m/s, angular rad/s] and acceleration (N, 6) [m/s², rad/s²]
        (spatial, as Pinocchio's ``getFrameAcceleration``), both in the sensor frame.
    """

    base_R_sensor: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class SensorDynamics:
    """Pinocchio model of the arm carrying the sensor frame: motion of S and the tool's regressor.

    Args:
        robot: the arm (UR DH parameters). sensor_R_flange: the calibration's ``sensor_rotation``.
        sensor_offset_m: the sensor origin in the flange frame (None = at the flange origin).
    """

    def __init__(self, robot: URModel, sensor_R_flange: np.ndarray, sensor_offset_m: np.ndarray | None) -> None:
        import pinocchio as pin

        self._pin = pin
        self.robot = robot
        self.model = pinocchio_model(robot)
        flange_id = self.model.getFrameId(FLANGE_FRAME)
        flange = self.model.frames[flange_id]
        offset = np.zeros(3) if sensor_offset_m is None else np.asarray(sensor_offset_m, dtype=float)
        flange_M_sensor = pin.SE3(np.asarray(sensor_R_flange, dtype=float).T.copy(), offset)
        self.frame_id = self.model.addFrame(pin.Frame(SENSOR_FRAME, flange.parentJoint, flange_id,
                                                      flange.placement * flange_M_sensor, pin.FrameType.OP_FRAME))
        self.data = self.model.createData()

    @classmethod
    def for_calibration(cls, robot: URModel, calibration: Calibration) -> "SensorDynamics":
        return cls(robot, calibration.sensor_rotation, calibration.sensor_offset)

    def motion(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> SensorMotion:
        """Return the sensor frame's motion for joint states (N, 6) each (rad, rad/s, rad/s²)."""
        pin, model, data, frame = self._pin, self.model, self.data, self.frame_id
        q, qd, qdd = (np.ascontiguousarray(np.asarray(x, dtype=float).reshape(-1, 6)) for x in (q, qd, qdd))
        n = q.shape[0]
        rotations, velocity, acceleration = np.empty((n, 3, 3)), np.empty((n, 6)), np.empty((n, 6))
        for k in range(n):
            pin.forwardKinematics(model, data, q[k], qd[k], qdd[k])
            pin.updateFramePlacement(model, data, frame)
            rotations[k] = data.oMf[frame].rotation
            velocity[k] = pin.getFrameVelocity(model, data, frame, pin.LOCAL).vector
            acceleration[k] = pin.getFrameAcceleration(model, data, frame, pin.LOCAL).vector
        return SensorMotion(rotations, velocity, acceleration)

    def regressor(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, gravity_base_m_s2: np.ndarray,
                  motion: SensorMotion | None = None) -> np.ndarray:
        """Return R (N, 6, 10): the wrench the tool exerts on the sensor is R π (+ biases), sensor frame.
        ``motion``: :meth:`motion` of these states when the caller has it already (one pass of Pinocchio)."""
        pin = self._pin
        motion = self.motion(q, qd, qdd) if motion is None else motion
        gravity_sensor = np.einsum("nji,j->ni", motion.base_R_sensor, np.asarray(gravity_base_m_s2, dtype=float))
        out = np.empty((motion.velocity.shape[0], 6, 10))
        for k in range(out.shape[0]):
            a = motion.acceleration[k]
            out[k] = pin.bodyRegressor(pin.Motion(motion.velocity[k]),
                                       pin.Motion(np.concatenate([a[:3] - gravity_sensor[k], a[3:]])))
        np.negative(out, out=out)
        return out


def gravity_vector(calibration: Calibration) -> np.ndarray:
    """The gravity vector in the base frame, m/s², from the calibration (gravity_base / mass: includes the tilt)."""
    return np.asarray(calibration.gravity_base) / calibration.mass_kg


def calibration_parameters(calibration: Calibration) -> np.ndarray:
    """π (10,) of a calibration with inertia (mass from gravity_base, centre of mass, inertia)."""
    if calibration.inertia is None:
        raise ValueError("the calibration has no inertia (static only): identify it from motion first")
    return inertial_parameters(calibration.mass_kg, calibration.center_of_mass, calibration.inertia)


class WrenchPredictor:
    """The contact-free wrench (N, 6) [N, N·m] the sensor reads at joint states: R π + biases, by RNEA (module
    docstring). Build it once per calibration (it copies the Pinocchio model); calls are not thread-safe (one
    ``pin.Data``).

    Args: dynamics (the arm carrying the sensor frame), calibration (with inertia: ``has_dynamics``).
    """

    def __init__(self, dynamics: SensorDynamics, calibration: Calibration) -> None:
        import pinocchio as pin

        self._pin = pin
        model = pin.Model(dynamics.model)
        frame = model.frames[dynamics.frame_id]
        self._joint = frame.parentJoint
        self._joint_M_sensor = frame.placement
        for joint in range(len(model.inertias)):
            model.inertias[joint] = pin.Inertia.Zero()
        tool = pin.Inertia.FromDynamicParameters(calibration_parameters(calibration))
        model.inertias[self._joint] = self._joint_M_sensor.act(tool)
        model.gravity = pin.Motion(gravity_vector(calibration), np.zeros(3))
        self.model = model
        self.data = model.createData()
        self.bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
        """Force and torque biases (6,), N and N·m."""

    def predict_one(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Write the wrench at one joint state (6,) each (rad, rad/s, rad/s², float64) into ``out`` (6,)."""
        pin = self._pin
        pin.rnea(self.model, self.data, q, qd, qdd)
        return np.subtract(self.bias, self._joint_M_sensor.actInv(self.data.f[self._joint]).vector, out=out)

    def __call__(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """Return the wrench (N, 6) at joint states (N, 6) each (rad, rad/s, rad/s²)."""
        q, qd, qdd = (np.ascontiguousarray(np.asarray(x, dtype=float).reshape(-1, 6)) for x in (q, qd, qdd))
        out = np.empty((q.shape[0], 6))
        for k in range(q.shape[0]):
            self.predict_one(q[k], qd[k], qdd[k], out[k])
        return out


def predict_moving(dynamics: SensorDynamics, calibration: Calibration, q: np.ndarray, qd: np.ndarray,
                   qdd: np.ndarray) -> np.ndarray:
    """Return the contact-free wrench (N, 6) [N, N·m] the sensor reads at joint states (N, 6): R π + biases
    (:class:`WrenchPredictor`; a stream builds that once and calls it per state)."""
    return WrenchPredictor(dynamics, calibration)(q, qd, qdd)
