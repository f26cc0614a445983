"""The simulated cell's rigid-tool physics (tests/fakes/rigid_body.py, hand-written Newton-Euler) against Pinocchio,
its reduction to the static model at rest, and the simulated controller's RTDE motion outputs against its own
motion profiles."""


import numpy as np
import pinocchio as pin
import pytest

from ftacq.kinematics import FLANGE_FRAME, flange_pose, pinocchio_model, ur_model
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.ur_motion import JointMove
from tests.fakes.ur_simulator import MOUNT_GRAVITY_M_S2, URSimulator
from tests.fakes.world import CellTruth, JointState, SensorPhysics, SettablePose, SharedPose

MODEL = ur_model("UR5e")
HOME = np.array([0.3, -1.4, 1.6, -1.9, -1.5, 0.4])


def moving_states(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint states along a brisk moveJ (every joint, wrist included) plus random states with large rates."""
    move = JointMove(MODEL, HOME, HOME + np.array([0.8, -0.5, 0.6, 1.0, -1.2, 1.5]), 1.0, 2.0)
    times = np.linspace(0.0, move.duration_s, 23)
    q = np.array([move.sample(t)[0] for t in times])
    qd = np.array([move.sample(t)[1] for t in times])
    qdd = np.array([move.acceleration(t)[0] for t in times])
    rng = np.random.default_rng(seed)
    q = np.vstack([q, HOME + rng.uniform(-1.5, 1.5, (10, 6))])
    qd = np.vstack([qd, rng.uniform(-2.0, 2.0, (10, 6))])
    qdd = np.vstack([qdd, rng.uniform(-4.0, 4.0, (10, 6))])
    assert np.abs(qdd[:23]).max() == pytest.approx(2.0) and np.abs(qd[:23]).max() == pytest.approx(1.0)
    return q, qd, qdd


def pinocchio_with_sensor(truth: CellTruth):
    """Pinocchio's UR model with a frame 'sensor' at flange_T_sensor (rotation sensor_R_flangeᵀ, sensor offset)."""
    model = pinocchio_model(MODEL)
    flange = model.frames[model.getFrameId(FLANGE_FRAME)]
    flange_M_sensor = pin.SE3(truth.sensor_rotation.T, np.array(truth.sensor_offset_m))
    model.addFrame(pin.Frame("sensor", flange.parentJoint, model.getFrameId(FLANGE_FRAME),
                             flange.placement * flange_M_sensor, pin.FrameType.OP_FRAME))
    return model, flange.placement * flange_M_sensor


@pytest.mark.parametrize("mount", ["floor", "wall"])
def test_moving_tool_wrench_matches_pinocchio_body_regressor_and_rnea(mount):
    truth = CellTruth().with_mount(mount) if mount != "floor" else CellTruth(base_tilt_deg=(2.0, -3.0))
    physics = SensorPhysics(truth, SettablePose(), robot=MODEL)
    q, qd, qdd = moving_states()
    simulated = physics.tool_wrench(q, qd, qdd)

    model, joint_M_sensor = pinocchio_with_sensor(truth)
    data = model.createData()
    sensor = model.getFrameId("sensor")
    tool = pin.Inertia(truth.mass_kg, np.array(truth.center_of_mass_m), truth.inertia)
    # RNEA on the same chain with massless links and the tool as the last body: τ = J_Sᵀ f_S
    rnea_model = pinocchio_model(MODEL)
    for i in range(1, rnea_model.njoints):
        rnea_model.inertias[i] = pin.Inertia.Zero()
    rnea_model.appendBodyToJoint(rnea_model.njoints - 1, tool, joint_M_sensor)
    rnea_model.gravity.linear = truth.gravity_base_m_s2
    rnea_data = rnea_model.createData()
    for k in range(q.shape[0]):
        pin.forwardKinematics(model, data, q[k], qd[k], qdd[k])
        pin.updateFramePlacements(model, data)
        velocity = pin.getFrameVelocity(model, data, sensor, pin.LOCAL)
        acceleration = pin.getFrameAcceleration(model, data, sensor, pin.LOCAL)
        gravity_sensor = data.oMf[sensor].rotation.T @ truth.gravity_base_m_s2
        # a body accelerating against gravity: RNEA's convention a_0 = −g
        regressor = pin.bodyRegressor(velocity, pin.Motion(acceleration.linear - gravity_sensor, acceleration.angular))
        on_tool = regressor @ tool.toDynamicParameters()  # wrench the sensor applies to the tool
        np.testing.assert_allclose(simulated[k], -on_tool, atol=1e-9, rtol=0)
        torques = pin.rnea(rnea_model, rnea_data, q[k], qd[k], qdd[k])
        jacobian = pin.computeFrameJacobian(model, data, q[k], sensor, pin.LOCAL)
        np.testing.assert_allclose(torques, jacobian.T @ -simulated[k], atol=1e-9, rtol=0)
    inertial = simulated - physics.tool_wrench(q, np.zeros_like(qd), np.zeros_like(qdd))
    assert np.abs(inertial[:23, :3]).max() > 0.5  # the motion is brisk enough for the check to mean something


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.0, 90.0), (0.0, 180.0), (4.0, -7.0)])
def test_at_rest_the_moving_model_is_the_static_model(tilt):
    truth = CellTruth(base_tilt_deg=tilt)
    physics = SensorPhysics(truth, SettablePose(), robot=MODEL)
    rng = np.random.default_rng(1)
    q = HOME + rng.uniform(-2.0, 2.0, (20, 6))
    zeros = np.zeros_like(q)
    moving = physics.noiseless_wrench_moving(q, zeros, zeros)
    static = np.array([physics.noiseless_wrench(flange_pose(MODEL, qk)) for qk in q])
    np.testing.assert_allclose(moving, static, atol=1e-10, rtol=0)  # rounding of the rotation vector
    calibration = truth.calibration()
    predicted = np.array([calibration.predict(rotation_from_rotvec(flange_pose(MODEL, qk)[3:]).T) for qk in q])
    np.testing.assert_allclose(moving, predicted, atol=1e-10, rtol=0)


def test_joint_state_extrapolates_exactly_across_a_change_of_acceleration():
    move = JointMove(MODEL, HOME, HOME + np.array([0.0, 0.3, -0.2, 0.9, 0.1, 0.0]), 1.0, 2.0)
    profile = move.profile
    t0 = profile.accelerate_s - 0.0013  # 1.3 ms before the cruise starts
    q0, qd0 = move.sample(t0)
    qdd0, switch, qdd_next = move.acceleration(t0)
    assert switch[0] == pytest.approx(0.0013) and np.any(qdd0) and not np.any(qdd_next[0])
    assert np.all(np.isfinite(switch[:2])) and np.any(qdd_next[1])  # then the deceleration, then rest
    stamp, scale = 100.0, 1.0
    state = JointState(stamp, scale, q0, qd0, qdd0, switch, qdd_next)
    offsets = np.linspace(0.0, 0.004, 9)
    q, qd, qdd = state.at(stamp + offsets)
    for k, dt in enumerate(offsets):
        q_true, qd_true = move.sample(t0 + dt)
        np.testing.assert_allclose(q[k], q_true, atol=1e-12)
        np.testing.assert_allclose(qd[k], qd_true, atol=1e-12)
        np.testing.assert_allclose(qdd[k], move.acceleration(t0 + dt)[0], atol=1e-12)
    # a time-lapse controller: motion time runs `scale` times as fast as the clock
    fast = JointState(stamp, 4.0, q0, qd0, qdd0, switch, qdd_next)
    np.testing.assert_allclose(fast.at(np.array([stamp + 0.001]))[0][0], move.sample(t0 + 0.004)[0], atol=1e-12)
    # a stalled controller (no tick for most of the move): the sensor still follows the whole profile, to rest
    early = 0.05
    q1, qd1 = move.sample(early)
    qdd1, switch1, after1 = move.acceleration(early)
    far = JointState(stamp, 1.0, q1, qd1, qdd1, switch1, after1)
    offsets = np.linspace(-0.02, move.duration_s - early + 0.3, 50)
    q, qd, qdd = far.at(stamp + offsets)
    for k, dt in enumerate(offsets):
        np.testing.assert_allclose(q[k], move.sample(early + dt)[0], atol=1e-9)
        np.testing.assert_allclose(qd[k], move.sample(early + dt)[1], atol=1e-9)
    assert not np.any(qdd[-1]) and np.abs(qd[-1]).max() < 1e-12


def test_shared_pose_carries_the_joint_state():
    writer = SharedPose(create=True)
    try:
        reader = SharedPose(writer.name)
        assert reader.read_state()[2] is None
        switches, after = np.array([0.25, 0.5, np.inf]), np.vstack([np.ones(6), -np.ones(6), np.zeros(6)])
        state = JointState(12.5, 1.0, HOME, np.arange(6.0), -np.arange(6.0), switches, after)
        writer.set(flange_pose(MODEL, HOME), 0.5, state)
        pose, speed, got = reader.read_state()
        np.testing.assert_array_equal(pose, flange_pose(MODEL, HOME))
        assert speed == 0.5 and got.stamp_s == 12.5 and not got.at_rest
        np.testing.assert_array_equal(got.switch_in_s, switches)
        np.testing.assert_array_equal(np.vstack([got.q, got.qd, got.qdd, got.qdd_next]),
                                      np.vstack([HOME, np.arange(6.0), -np.arange(6.0), after]))
        reader.close()
    finally:
        writer.close()


def test_simulated_sensor_follows_the_moving_arm_sample_by_sample():
    """The sensor reads the published state and evaluates each sample at its own time (rate_hz apart)."""
    move = JointMove(MODEL, HOME, HOME + np.array([0.5, 0.0, 0.0, 0.0, -0.8, 1.2]), 1.0, 2.0)
    t0 = 0.3 * move.duration_s
    shared = SharedPose(create=True)
    try:
        q0, qd0 = move.sample(t0)
        qdd0, switch, after = move.acceleration(t0)
        truth = CellTruth(force_noise_n=(0.0, 0.0, 0.0), torque_noise_nm=(0.0, 0.0, 0.0), motion_noise_gain=0.0)
        physics = SensorPhysics(truth, shared, robot=MODEL, rate_hz=7000.0)
        import time
        stamp = time.monotonic()
        shared.set(flange_pose(MODEL, q0), float(np.linalg.norm(qd0)), JointState(stamp, 1.0, q0, qd0, qdd0, switch, after))
        got = physics.sample(14)
        # the samples start no earlier than the stamp and are 1/7000 s apart: bracket them by motion time
        first = got[0]
        candidates = np.array([physics.noiseless_wrench_moving(*[x[None] for x in (move.sample(t0 + dt)[0],
                                                                                     move.sample(t0 + dt)[1], qdd0)])[0]
                               for dt in np.linspace(0.0, 0.05, 501)])
        best = np.argmin(np.abs(candidates - first).max(axis=1))
        assert np.abs(candidates[best] - first).max() < 5e-3
        assert np.abs(got[-1] - got[0]).max() > 1e-4  # samples of one call differ: the arm moved between them
    finally:
        shared.close()


def test_simulated_controller_outputs_agree_with_its_motion():
    """actual_q/qd, target_qdd, actual_TCP_speed and actual_tool_accelerometer from the simulator's ticks agree
    with finite differences of its own poses (a 2 ms tick, like the real controller's 500 Hz)."""
    sim = URSimulator(MODEL, time_scale=1.0, initial_q=HOME)
    tcp = np.array([0.01, -0.02, 0.15, 0.0, 0.0, 0.3])
    sim.tcp_offset = tcp
    start = sim._last_step_s
    with sim.lock:
        assert sim._start_move("movej", HOME + np.array([0.4, -0.3, 0.5, 0.7, -0.9, 1.1]), 1.0, 2.0, True)
    dt = 0.002
    snaps = [sim.step(start + dt * (k + 1))["fields"] for k in range(int(sim.motion.duration_s / dt) + 20)]
    assert sim.motion is None
    q = np.array([s["actual_q"] for s in snaps])
    qd = np.array([s["actual_qd"] for s in snaps])
    qdd = np.array([s["target_qdd"] for s in snaps])
    tcp_pose = np.array([s["actual_TCP_pose"] for s in snaps])
    tcp_speed = np.array([s["actual_TCP_speed"] for s in snaps])
    accelerometer = np.array([s["actual_tool_accelerometer"] for s in snaps])
    np.testing.assert_allclose(np.array([s["target_qd"] for s in snaps]), qd)
    assert np.abs(qdd).max() == pytest.approx(2.0) and np.abs(qd).max() == pytest.approx(1.0, abs=1e-9)
    # central differences inside the constant-acceleration stretches (away from the profile's switches)
    inner = np.where(np.all(qdd[:-2] == qdd[2:], axis=1) & np.all(qdd[1:-1] == qdd[2:], axis=1))[0] + 1
    assert inner.size > 0.8 * len(snaps) - 20
    np.testing.assert_allclose(((q[2:] - q[:-2]) / (2 * dt))[inner - 1], qd[inner], atol=1e-9)
    np.testing.assert_allclose(((qd[2:] - qd[:-2]) / (2 * dt))[inner - 1], qdd[inner], atol=1e-9)
    position_rate = (tcp_pose[2:, :3] - tcp_pose[:-2, :3]) / (2 * dt)
    np.testing.assert_allclose(position_rate[inner - 1], tcp_speed[inner, :3], atol=2e-5)
    rotations = [rotation_from_rotvec(p[3:]) for p in tcp_pose]
    for k in inner[::10]:
        turn = rotations[k + 1] @ rotations[k - 1].T
        omega = np.array([turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1]]) / 2 / (2 * dt)
        np.testing.assert_allclose(omega, tcp_speed[k, 3:], atol=2e-4)
    # the accelerometer reads R_flangeᵀ (a − g) at the flange origin
    flange = np.array([flange_pose(MODEL, qk) for qk in q])
    acceleration = (flange[2:, :3] - 2 * flange[1:-1, :3] + flange[:-2, :3]) / dt ** 2
    gravity = np.array(MOUNT_GRAVITY_M_S2["floor"])
    for k in inner[::10]:
        expected = rotation_from_rotvec(flange[k, 3:]).T @ (acceleration[k - 1] - gravity)
        np.testing.assert_allclose(accelerometer[k], expected, atol=2e-3)
    at_rest = snaps[-1]
    assert not np.any(at_rest["target_qdd"]) and not np.any(at_rest["actual_TCP_speed"])
    np.testing.assert_allclose(np.linalg.norm(at_rest["actual_tool_accelerometer"]), 9.81, rtol=1e-12)
    assert np.all(np.isinf(sim.joint_state(start).switch_in_s))


def test_joint_state_goes_back_through_the_previous_phase():
    """A sensor that generates its samples late gets those from before the last change of q̈ from the phase
    before it (switched_ago_s, qdd_before), not from the current phase extrapolated backwards."""
    q_switch, qd_switch = np.array([0.1, -1.2, 1.3, -1.5, -1.6, 0.2]), np.array([0.3, 0.0, -0.2, 0.1, 0.0, 0.5])
    qdd_before, qdd_now, since_s = np.array([2.0, 0.0, 1.0, 0.0, 0.0, -1.0]), np.zeros(6), 0.1
    state = JointState(50.0, 1.0, q_switch + qd_switch * since_s + 0.5 * qdd_now * since_s ** 2,
                       qd_switch + qdd_now * since_s, qdd_now, switched_ago_s=since_s, qdd_before=qdd_before)
    back_s = 0.2  # before the switch
    q, qd, qdd = state.at(np.array([50.0 - since_s - back_s, 50.0 - since_s / 2]))
    np.testing.assert_allclose(q[0], q_switch - qd_switch * back_s + 0.5 * qdd_before * back_s ** 2, atol=1e-12)
    np.testing.assert_allclose(qd[0], qd_switch - qdd_before * back_s, atol=1e-12)
    np.testing.assert_allclose(qdd[0], qdd_before)
    np.testing.assert_allclose(qdd[1], qdd_now)
    assert not JointState(50.0, 1.0, q_switch, np.zeros(6), np.zeros(6), switched_ago_s=0.01,
                          qdd_before=qdd_before).at_rest  # just stopped: samples from before still move
