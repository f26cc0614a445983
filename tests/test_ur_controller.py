"""The simulated UR controller driven by the unmodified ur-rtde client (RTDE, UR Dashboard Server, script port, handshake).

One controller (time scale 0: moves complete at once) and one pair of ur-rtde clients are shared by the module
(ur-rtde's disconnect costs 0.5 s per interface); tests that break the connection start their own controller.
Every controller binds its own random 127.x.y.z, so the suite runs under ``pytest -n 2`` and twice at once.
"""

from __future__ import annotations

import contextlib
import random

import numpy as np
import pytest

from ftacq.errors import DeviceError
from ftacq.kinematics import flange_pose, forward_kinematics, ur_model
from ftacq.so3 import rotation_from_rotvec
from tests.fakes import ur_process
from tests.fakes.ur_process import URControllerProcess, random_loopback_address
from tests.conftest import wait_until

rtde_control = pytest.importorskip("rtde_control")
rtde_receive = pytest.importorskip("rtde_receive")
dashboard_client = pytest.importorskip("dashboard_client")

UR5E = ur_model("UR5e")
POSE_TOLERANCE = 1e-9
HOME_Q = [0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]
WAIT_S = 5.0


def assert_same_pose(actual, expected, tol: float = POSE_TOLERANCE) -> None:
    """Positions and rotations equal to ``tol`` (rotation matrices, so ±π rotation vectors compare equal)."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    np.testing.assert_allclose(actual[:3], expected[:3], atol=tol, rtol=0)
    np.testing.assert_allclose(rotation_from_rotvec(actual[3:6]), rotation_from_rotvec(expected[3:6]), atol=tol, rtol=0)


def wait_for_joints(receive, q, atol: float = 1e-12) -> None:
    """Wait (bounded) until the receive stream shows ``q``: it is a separate connection read by its own client
    thread, so on a loaded machine it may trail the control connection by a few packages."""
    wait_until(lambda: np.allclose(receive.getActualQ(), q, atol=atol, rtol=0), timeout_s=2.0,
               what=f"actual_q = {q}")


@pytest.fixture(scope="module")
def fake():
    with URControllerProcess(time_scale=0.0, initial_q=HOME_Q) as process:
        yield process


@pytest.fixture(scope="module")
def clients(fake):
    receive = rtde_receive.RTDEReceiveInterface(fake.host)
    control = rtde_control.RTDEControlInterface(fake.host)
    yield receive, control
    control.disconnect()
    receive.disconnect()


@pytest.fixture()
def at_home(fake, clients):
    """Start each test at HOME_Q with a normal safety state."""
    receive, control = clients
    if receive.isProtectiveStopped():
        server = dashboard_client.DashboardClient(fake.host)
        server.connect()
        server.unlockProtectiveStop()
        server.disconnect()
        wait_until(lambda: not receive.isProtectiveStopped(), what="unlock")
    # the control connection may still show the cleared stop for a few packages: retry until accepted
    wait_until(lambda: control.moveJ(HOME_Q, 1.0, 1.0), what="moveJ home accepted")
    wait_for_joints(receive, HOME_Q)
    return receive, control


def test_receive_reads_the_served_state(fake, clients, at_home):
    receive, _ = clients
    np.testing.assert_allclose(receive.getActualQ(), HOME_Q, atol=1e-12)
    assert_same_pose(receive.getActualTCPPose(), flange_pose(UR5E, np.array(HOME_Q)))
    assert receive.getRobotMode() == 7 and receive.getSafetyMode() == 1
    assert receive.getRuntimeState() == 2  # ur-rtde's control script runs
    first = receive.getTimestamp()
    wait_until(lambda: receive.getTimestamp() > first + 0.01, what="timestamps advancing")


def test_movej_reaches_target_and_pose_matches_forward_kinematics(fake, at_home):
    receive, control = at_home
    target = [0.3, -1.2, 1.3, -1.7, -1.4, 0.5]
    assert control.moveJ(target, 1.0, 1.2)
    wait_for_joints(receive, target)
    assert_same_pose(receive.getActualTCPPose(), flange_pose(UR5E, np.array(target)))
    assert_same_pose(receive.getTargetTCPPose(), flange_pose(UR5E, np.array(target)))
    last = fake.commands()[-1]
    assert (last["kind"], last["speed"], last["acceleration"], last["accepted"]) == ("movej", 1.0, 1.2, True)
    np.testing.assert_allclose(last["target"], target)


def test_movel_moves_the_flange_in_a_straight_line_to_the_pose(fake, at_home):
    receive, control = at_home
    start = np.array(receive.getActualTCPPose())
    goal = start + np.array([0.03, -0.02, -0.05, 0.0, 0.0, 0.0])
    assert control.moveL(list(goal), 0.2, 1.0)
    wait_until(lambda: np.allclose(receive.getActualTCPPose()[:3], goal[:3], atol=1e-9, rtol=0), timeout_s=2.0,
               what="the TCP at the goal")
    assert_same_pose(receive.getActualTCPPose(), goal)
    # the joint angles the controller reports put the flange exactly there (IK consistent with FK)
    assert_same_pose(flange_pose(UR5E, np.array(receive.getActualQ())), goal)
    last = fake.commands()[-1]
    assert (last["kind"], last["speed"], last["acceleration"]) == ("movel", 0.2, 1.0)


def test_controller_forward_kinematics_and_is_steady(at_home):
    receive, control = at_home
    q = [0.1, -1.4, 1.4, -1.5, -1.6, 0.3]
    assert_same_pose(control.getForwardKinematics(q, [0.0] * 6), flange_pose(UR5E, np.array(q)))
    assert_same_pose(control.getForwardKinematics(), flange_pose(UR5E, np.array(receive.getActualQ())))
    assert control.isSteady() is True


def test_tcp_offset_moves_the_reported_tcp_not_the_flange(fake, at_home):
    receive, control = at_home
    tcp = [0.0, 0.0, 0.12, 0.0, 0.0, 0.0]
    assert control.setTcp(tcp)
    try:
        base_T_flange = forward_kinematics(UR5E, np.array(receive.getActualQ()))
        expected_tcp_position = base_T_flange[:3, :3] @ np.array(tcp[:3]) + base_T_flange[:3, 3]
        wait_until(lambda: np.allclose(receive.getActualTCPPose()[:3], expected_tcp_position, atol=1e-9),
                   what="TCP pose with the offset")
        # ur-rtde 1.6.5 sends a zero tcp_offset as "not given": the controller applies its active TCP
        q = np.array(receive.getActualQ())
        assert_same_pose(control.getForwardKinematics(list(q), [0.0] * 6), receive.getActualTCPPose())
        probe = [0.0, 0.0, 0.2, 0.0, 0.0, 0.0]
        np.testing.assert_allclose(control.getForwardKinematics(list(q), probe)[:3],
                                   base_T_flange[:3, :3] @ np.array(probe[:3]) + base_T_flange[:3, 3], atol=1e-9)
    finally:
        assert control.setTcp([0.0] * 6)


def test_path_move_runs_every_waypoint_in_order(fake, at_home):
    receive, control = at_home
    first, second = [0.2, -1.5, 1.5, -1.5, -1.5, 0.1], [0.25, -1.45, 1.45, -1.6, -1.5, 0.2]
    before = len(fake.commands())
    assert control.moveJ([first + [0.8, 1.1, 0.0], second + [0.7, 1.0, 0.0]])
    wait_for_joints(receive, second, atol=1e-6)  # path lines carry 6 significant digits
    path = fake.commands()[before:]
    assert [c["source"] for c in path] == ["path", "path"]
    assert [(c["speed"], c["acceleration"]) for c in path] == [(0.8, 1.1), (0.7, 1.0)]


def test_dashboard_server_replies_are_the_documented_lines(fake, clients):
    server = dashboard_client.DashboardClient(fake.host)
    server.connect()
    try:
        assert server.polyscopeVersion() == "5.11.1.108318"
        assert server.getRobotModel() == "UR5"
        assert server.getSerialNumber() == "20235500123"
        assert server.isInRemoteControl() is True
        assert server.robotmode() == "Robotmode: RUNNING"
        assert server.safetymode() == "Safetymode: NORMAL"
        assert server.safetystatus() == "Safetystatus: NORMAL"
        assert server.programState() == "PLAYING rtde_control"
        assert server.running() is True
        assert server.getLoadedProgram() == "No program loaded"
        server.closeSafetyPopup()
        server.unlockProtectiveStop()  # raises unless the reply is exactly "Protective stop releasing"
        with pytest.raises(RuntimeError):
            server.loadURP("missing.txt")
    finally:
        server.disconnect()


def test_protective_stop_mid_move_refuses_commands_until_unlocked(fake, at_home):
    receive, control = at_home
    target = [0.4, -1.3, 1.4, -1.6, -1.5, 0.4]
    fake.inject("protective_stop", "move_fraction", 0.5)
    assert control.moveJ(target, 1.0, 1.0) is False
    wait_until(receive.isProtectiveStopped, what="the receive stream showing the stop")
    halfway = np.array(HOME_Q) + 0.5 * (np.array(target) - np.array(HOME_Q))
    np.testing.assert_allclose(receive.getActualQ(), halfway, atol=1e-9)  # stopped where the fault hit
    assert control.moveJ(target, 1.0, 1.0) is False  # refused while stopped
    server = dashboard_client.DashboardClient(fake.host)
    server.connect()
    server.unlockProtectiveStop()
    server.disconnect()
    wait_until(lambda: not receive.isProtectiveStopped(), what="protective stop cleared")
    # the control connection may trail the receive connection by a few packages (separate client threads)
    wait_until(lambda: control.moveJ(target, 1.0, 1.0), timeout_s=2.0, what="moveJ accepted after the unlock")
    wait_for_joints(receive, target)


def test_joint_limit_target_is_refused_with_a_protective_stop(fake, at_home):
    receive, control = at_home
    beyond_elbow_limit = [0.0, -1.5708, 3.3, -1.5708, -1.5708, 0.0]
    assert control.moveJ(beyond_elbow_limit, 1.0, 1.0) is False
    wait_until(receive.isProtectiveStopped, what="the receive stream showing the stop")
    rejected = fake.commands()[-1]
    assert rejected["accepted"] is False and "joint position limit" in rejected["reason"]
    np.testing.assert_allclose(receive.getActualQ(), HOME_Q, atol=1e-12)


def test_async_move_and_stop_at_real_time(fake, at_home):
    receive, control = at_home
    fake.set_time_scale(1.0)
    try:
        target = [1.2, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]  # ≈ 4.6 s: stopped long before
        assert control.moveJ(target, 0.3, 0.5, True)
        wait_until(lambda: abs(receive.getActualQ()[0]) > 0.02, what="the arm moving")
        assert not control.isSteady()
        control.stopJ(0.5, False)
        wait_until(lambda: np.max(np.abs(receive.getActualQd())) == 0.0, what="the arm at rest")
        stopped_at = receive.getActualQ()[0]
        assert 0.02 < stopped_at < 1.2  # decelerated along the path before the target
        assert control.isSteady()
        stop = fake.commands()[-1]
        assert (stop["kind"], stop["acceleration"]) == ("stopj", 0.5)
    finally:
        fake.set_time_scale(0.0)


def test_shared_pose_publishes_the_flange_pose():
    from tests.fakes.world import SharedPose

    shared = SharedPose(name=None, create=True)
    try:
        with URControllerProcess(time_scale=0.0, pose_shm=shared.name, initial_q=HOME_Q) as process:
            target = [0.2, -1.4, 1.5, -1.6, -1.5, 0.3]
            process.set_joint_positions(target)
            wait_until(lambda: np.allclose(shared.read()[0], flange_pose(UR5E, np.array(target)), atol=1e-12),
                       what="shared pose")
            assert shared.read()[1] == 0.0
    finally:
        shared.close()


@pytest.mark.parametrize("version, model", [("3.15.7.106331", "UR5"), ("5.23.0.0", "UR10e")])
def test_other_controller_versions_work_with_ur_rtde(version, model):
    with URControllerProcess(time_scale=0.0, version=version, model=model, initial_q=HOME_Q) as process:
        receive = rtde_receive.RTDEReceiveInterface(process.host)
        control = rtde_control.RTDEControlInterface(process.host)
        try:
            target = [0.1, -1.5, 1.5, -1.5, -1.5, 0.1]
            assert control.moveJ(target, 1.0, 1.0)
            wait_for_joints(receive, target)
            assert_same_pose(receive.getActualTCPPose(), flange_pose(ur_model(model), np.array(target)))
        finally:
            control.disconnect()
            receive.disconnect()


def test_random_loopback_addresses_avoid_127_0_0_1():
    rng = random.Random(7)
    addresses = {random_loopback_address(rng) for _ in range(500)}
    assert "127.0.0.1" not in addresses and len(addresses) > 490
    assert all(a.startswith("127.") and len(a.split(".")) == 4 for a in addresses)


def test_taken_address_is_reported_and_the_helper_retries_elsewhere(fake, monkeypatch):
    with pytest.raises(DeviceError, match="BIND_ERROR"):
        URControllerProcess(host=fake.host).start()
    fresh = random_loopback_address()
    candidates = iter([fake.host, fresh])
    monkeypatch.setattr(ur_process, "random_loopback_address", lambda rng=None: next(candidates))
    with URControllerProcess(time_scale=0.0) as second:
        assert second.host == fresh
        assert second.state()["q"] is not None


def test_pendant_jog_moves_with_the_motion_profile_not_a_jump():
    """``jog`` (the simulated technician's pendant moves): the arm moves through the controller's moveJ profile, so
    its joint state (and a simulated sensor's inertial wrench) changes smoothly; ``set q`` jumps."""
    from tests.fakes.world import SharedPose

    shared = SharedPose(name=None, create=True)
    try:
        with URControllerProcess(time_scale=1.0, pose_shm=shared.name, initial_q=HOME_Q) as process:
            target = np.array(HOME_Q) + np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.4])
            duration_s = process.jog(target, 1.0, 4.0)
            assert duration_s == pytest.approx(0.4 / 1.0 + 1.0 / 4.0)  # trapezoid: L/v + v/a
            moving = process.wait_for(lambda state: state["moving"], timeout_s=5.0)
            assert moving["move_count"] >= 1
            seen = []

            def in_motion() -> bool:
                state = shared.read_state()[2]
                seen.append(state)
                return state is not None and bool(np.any(state.qd))  # (a move's first cycle: q̈ only)

            wait_until(in_motion, what="the published joint state in motion (q̇ ≠ 0: not a jump)")
            assert 0 < np.abs(seen[-1].qd).max() <= 1.0 + 1e-9  # on the profile, within the jog's speed
            process.wait_for(lambda state: not state["moving"], timeout_s=10.0)
            np.testing.assert_allclose(process.state()["q"], target, atol=1e-9)
            assert process.commands()[-1]["source"] == "pendant"
    finally:
        shared.close()


def test_a_client_that_does_not_read_loses_whole_packages_and_never_holds_up_the_tick():
    """The controller drops data packages rather than queueing them: a client that stops reading (its buffers
    full) loses packages, the connection stays open and each send returns at once (the old blocking send closed
    the connection after its timeout, and held up every other client's stream meanwhile); what reaches the client
    is whole packages."""
    import socket

    from tests.fakes import rtde_protocol as rp
    from tests.fakes.ur_controller import RTDEConnection, _OutputPlan

    with socket.create_server(("127.0.0.1", 0)) as listener:
        client = socket.socket()
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        client.connect(listener.getsockname())
        server_side, _ = listener.accept()
    server_side.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    connection = RTDEConnection(server=None, sock=server_side)  # type: ignore[arg-type]
    try:
        plan = _OutputPlan(rp.Recipe.build(1, ["timestamp", "actual_q"], rp.OUTPUT_TYPES))
        connection.outputs, connection.streaming = plan, True
        for k in range(20_000):  # 40 s of packages at 500 Hz, ~1.3 MB: far beyond both buffers
            connection.send_data({"fields": {"timestamp": k * 0.002, "actual_q": [float(k)] * 6}})
        assert not connection.closed and connection.dropped_packages > 0
        client.setblocking(False)
        received = bytearray()
        with contextlib.suppress(BlockingIOError):
            while chunk := client.recv(1 << 16):
                received += chunk
        whole = len(received) // plan.package_size
        assert whole > 0
        packages = np.frombuffer(bytes(received[:whole * plan.package_size]), dtype=np.uint8).reshape(whole, -1)
        sizes = packages[:, 0].astype(int) << 8 | packages[:, 1]
        assert set(sizes.tolist()) == {plan.package_size} and set(packages[:, 2].tolist()) == {rp.DATA_PACKAGE}
    finally:
        connection.close()
        client.close()


def test_a_simulated_controller_takes_the_suites_realtime_priority(monkeypatch):
    """The suite's simulated controllers ask for SCHED_FIFO (tests/conftest.py), unless told otherwise; a value
    that is not a priority is ignored (normal scheduling)."""
    from tests.fakes.ur_process import REALTIME_PRIORITY_VARIABLE, default_realtime_priority

    for text, priority in (("5", 5), ("", 0), ("0", 0), ("100", 0), ("high", 0), (" 7 ", 7)):
        monkeypatch.setenv(REALTIME_PRIORITY_VARIABLE, text)
        assert default_realtime_priority() == priority, text
    monkeypatch.setenv(REALTIME_PRIORITY_VARIABLE, "5")
    assert "--realtime-priority" in URControllerProcess()._command("127.0.0.9")
    assert "--realtime-priority" not in URControllerProcess(realtime_priority=0)._command("127.0.0.9")


def test_a_simulated_cb3_arm_runs_polyscope_3_so_that_ftacq_names_it_right():
    """The Dashboard Server says "UR5" for a UR5 and a UR5e; the software version tells them apart. A simulated UR5
    reports PolyScope 3, and ftacq reads it as the CB3 arm it is (a 5.x version made it a UR5e)."""
    from drivers.ur_dashboard_server import read_controller_info
    from tests.fakes.ur_controller import default_version

    assert default_version("UR5")[0] == 3 and default_version("ur10")[0] == 3 and default_version("UR5e")[0] == 5
    with URControllerProcess(model="UR5", host=random_loopback_address()) as controller:
        info = read_controller_info(controller.host)
    assert info.model is not None and info.model.name == "UR5" and info.software_version.startswith("3.15")
