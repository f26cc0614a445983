"""The static live compensation (a calibration without inertia) uses the flange orientation *at the samples' time*,
interpolated (slerp) from the robot state stream, never the newest pose; a batch with no robot state near its samples
is left uncompensated (None: empty contact columns in the monitor's record).

The scene: the arm turns (every joint, up to ~3 rad/s), the sensor reads the tool's weight at the orientation of each
sample's time plus a known contact wrench, and the monitor reads each batch when the robot state stream is already
100 ms further (a monitor that falls behind). The expected contact is known by construction, so the compensation
with the newest pose is measurably wrong (> 1 N) and the one at the samples' time right (to the slerp's error
between 2 ms states, well below the sensor's noise).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from drivers.sensor import WrenchBatch
from drivers.ur_ft_input import ControllerCycle
from ftacq.drift_health import BiasHealth
from ftacq.kinematics import FlangeRotation, flange_pose
from procedures.bias_health import DriftCompensator
from procedures.bridge import CycleStates
from procedures.flange_orientation import MAX_STATE_GAP_S, SLERP_ABOVE_RAD, FlangeOrientations
from procedures.monitor import LiveMonitor, flange_R_base_from_pose
from procedures.static_compensation import StaticCompensator
from tests.fakes.world import CellTruth
from tests.scripted import MODEL, ScriptedSensor, read_record, run_until_exhausted

pytest.importorskip("pinocchio")

RATE_HZ = 7000.0
BATCH = 70
BEHIND_S = 0.1
"""The monitor reads each batch when the robot state stream is this much further, s."""
HOST_OFFSET_S = 80.0
"""Host monotonic time of controller timestamp 0 (and of the sensor's device time 0), s."""
PERIODS_S = np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1])


def joint_angles(t: np.ndarray) -> np.ndarray:
    """q(t) (N, 6), rad: every joint swinging by 0.6 rad (up to 5 rad/s at the wrist)."""
    return np.array([0.1, -1.2, 1.0, -1.4, -1.6, 0.2]) + 0.6 * np.sin(2 * np.pi * t[:, None] / PERIODS_S)


def controller_cycle(t: float) -> ControllerCycle:
    q = joint_angles(np.array([t]))[0]
    return ControllerCycle(timestamp_s=t, q=q, qd=np.zeros(6), tcp_force=np.zeros(6), runtime_state=2,
                           safety_status_bits=1, received_s=HOST_OFFSET_S + t + 2e-4, tcp_pose=np.zeros(6),
                           target_qd=np.zeros(6), target_qdd=np.zeros(6))


def sensor_batches(calibration, count: int, contact: np.ndarray, start_s: float = 0.2) -> list[WrenchBatch]:
    """Batches of the sensor on the turning arm: each sample is the tool's weight at the true orientation of its own
    time (forward kinematics of q(t) at the sample), the biases and ``contact``; received 0.1 ms after it was taken."""
    flange = FlangeRotation(MODEL)
    batches = []
    for k in range(count):
        device = start_s + (k * BATCH + np.arange(BATCH)) / RATE_HZ
        flange_R_base = np.array([flange(q).T for q in joint_angles(device)])
        weight = -calibration.compensate(np.zeros((BATCH, 6)), flange_R_base)  # biases + weight in the sensor frame
        wrench = weight + contact
        batches.append(WrenchBatch(time_s=HOST_OFFSET_S + device + 2e-4, wrench=wrench,
                                   counts=np.round(wrench * 1e6).astype(np.int64),
                                   status=np.zeros(BATCH, dtype=np.uint32),
                                   sequence=k * BATCH + np.arange(BATCH, dtype=np.int64),
                                   saturated=np.zeros(BATCH, dtype=bool), device_time_s=device))
    return batches


class FallingBehindSensor(ScriptedSensor):
    """Hands out its batches when the robot state stream is already BEHIND_S past their newest sample (the controller
    cycles are appended on each read: a monitor that falls behind), except during ``silent_s`` (host times) when the
    controller sends nothing."""

    def __init__(self, batches, states: CycleStates, silent_s: tuple[float, float] = (np.inf, np.inf)) -> None:
        super().__init__(batches)
        self.states, self.silent_s, self._next_cycle = states, silent_s, 0

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        if self._batches:
            until = self._batches[0].time_s[-1] - HOST_OFFSET_S + BEHIND_S
            while self._next_cycle * 0.002 <= until:
                t = self._next_cycle * 0.002
                if not self.silent_s[0] <= HOST_OFFSET_S + t < self.silent_s[1]:
                    self.states.append(controller_cycle(t))
                self._next_cycle += 1
        return super().read(timeout_s)


class NewestState:
    """The robot's newest state (the monitor's RobotStateSource), from the same controller cycles."""

    def __init__(self, states: CycleStates) -> None:
        self.states = states

    def joint_positions(self) -> np.ndarray:
        return self.states.window(last=1).q[-1].copy()

    def flange_pose(self) -> np.ndarray:
        return flange_pose(MODEL, self.joint_positions())


def test_a_monitor_that_falls_behind_compensates_with_the_pose_at_the_samples_time(tmp_path):
    calibration = CellTruth().calibration()
    assert not calibration.has_dynamics
    contact = np.array([1.0, -2.0, 3.0, 0.1, -0.2, 0.05])
    states = CycleStates()
    batches = sensor_batches(calibration, 120, contact)
    # the controller is silent for 0.2 s in the middle: the batches then have no state near them
    silent = (HOST_OFFSET_S + 0.2 + 60 * BATCH / RATE_HZ, HOST_OFFSET_S + 0.4 + 60 * BATCH / RATE_HZ)
    sensor = FallingBehindSensor(batches, states, silent_s=silent)
    robot = NewestState(states)
    monitor = LiveMonitor(sensor, robot=robot, record_path=tmp_path / "run.csv", strict=True, batch_period_s=0.0)
    static = StaticCompensator(calibration, MODEL, states, clock=monitor.sample_clock)  # as ftacq monitor builds it
    monitor.compensator = DriftCompensator(BiasHealth(calibration), moving=static)
    summary = run_until_exhausted(monitor, sensor)

    record = read_record(tmp_path / "run.csv")
    assert record.size == summary.samples == 120 * BATCH
    got = np.column_stack([record[f"contact_{axis}"] for axis in ("fx", "fy", "fz", "tx", "ty", "tz")])
    sample_time = record["sample_time_s"]
    last_before_silence = silent[0] + 2e-4 - 0.002  # host time of the last state before the silence (about)
    # samples in the silence are left uncompensated (empty), except those at most MAX_STATE_GAP_S after the last
    # state, which the monitor read when that state was still the newest (the live edge: held at it)
    inside = (sample_time > last_before_silence + MAX_STATE_GAP_S + 0.002) & (sample_time < silent[1])
    assert inside.sum() > 5 * BATCH and np.all(np.isnan(got[inside]))
    assert static.uncompensated_batches >= 5 and static.compensated_batches >= 80
    compensated = ~np.isnan(got[:, 0])
    assert compensated.sum() == summary.compensated_samples >= 80 * BATCH
    # between two states: compensated with the orientation of each sample's own time, the contact wrench to far
    # below the sensor's noise (the slerp between 2 ms states)
    bracketed = compensated & ((sample_time < last_before_silence) | (sample_time > silent[1]))
    assert bracketed.sum() > 80 * BATCH
    np.testing.assert_allclose(got[bracketed], np.broadcast_to(contact, got[bracketed].shape), atol=1e-3)
    # the record pairs each sample with the pose of its time (so `ftacq compensate` of the record gives the same)
    pose = np.column_stack([record[name] for name in ("x", "y", "z", "rx", "ry", "rz")])
    true_pose = np.array([flange_pose(MODEL, q) for q in joint_angles(record["device_time_s"][bracketed])])
    np.testing.assert_allclose(pose[bracketed], true_pose, atol=1e-4)  # interpolation between 2 ms states: ~q̈ dt²/8
    raw = np.column_stack([record[name] for name in ("fx", "fy", "fz", "tx", "ty", "tz")])
    again = calibration.compensate(raw[bracketed], np.array([flange_R_base_from_pose(p) for p in pose[bracketed]]))
    np.testing.assert_allclose(again, got[bracketed], atol=1e-3)  # (the pose a rotation: entry-wise θ²/8 apart)
    # ... where the newest pose (the state 0.1 s later, as the monitor read it) would have been off by newtons
    newest = calibration.compensate(np.vstack([b.wrench for b in batches]),
                                    np.array([flange_R_base_from_pose(flange_pose(MODEL, q))
                                              for q in joint_angles(np.repeat([b.device_time_s[-1] + BEHIND_S
                                                                               for b in batches], BATCH))]))
    assert np.abs(newest[bracketed, :3] - contact[:3]).max() > 1.0


def test_flange_orientations_are_the_slerp_between_the_states_and_say_when_none_is_near():
    from scipy.spatial.transform import Rotation, Slerp

    states = CycleStates()
    for k in range(200):
        states.append(controller_cycle(k * 0.002))
    orientations = FlangeOrientations(MODEL, states)
    flange = FlangeRotation(MODEL)
    window = states.window(last=200)
    slerp = Slerp(window.time_s, Rotation.from_matrix(np.array([flange(q) for q in window.q])))
    at = np.sort(np.random.default_rng(4).uniform(window.time_s[5], window.time_s[-1], 70))
    got = orientations.flange_R_base_at(at)
    assert got is not None
    # the slerp, or entry-wise where the states are closer than SLERP_ABOVE_RAD (then within θ²/8 of it)
    np.testing.assert_allclose(got, np.swapaxes(slerp(at).as_matrix(), 1, 2), atol=SLERP_ABOVE_RAD**2 / 8)
    assert np.all(np.linalg.det(got) > 0)
    computed = orientations.computed
    again = orientations.flange_R_base_at(at[10:])  # the states it needs were computed already: none again
    assert again is not None and orientations.computed == computed
    # within MAX_STATE_GAP_S after the newest state: held at the newest; beyond it, or too old: None
    newest = window.time_s[-1]
    held = orientations.flange_R_base_at(np.array([newest + 0.5 * MAX_STATE_GAP_S]))
    assert held is not None
    np.testing.assert_allclose(held[0], flange(window.q[-1]).T, atol=1e-12)
    assert orientations.flange_R_base_at(np.array([newest + 2 * MAX_STATE_GAP_S])) is None
    assert orientations.flange_R_base_at(np.array([window.time_s[0] - 2 * MAX_STATE_GAP_S])) is None


def test_the_dashboard_leaves_a_batch_the_live_compensation_left_raw_uncompensated(tmp_path):
    from ftacq.app.dashboard import layout, sinks
    from procedures import events
    from tests.rrd_reader import read_scalars
    from tests.scripted import FixedRobotState, Q_HOME_RAD, dashboard_listener, new_recording, physics_batches

    robot = FixedRobotState(Q_HOME_RAD)
    first, second = physics_batches(robot.pose, 2)
    path = tmp_path / "monitor.rrd"
    recording = new_recording(path)
    listener = dashboard_listener(recording)
    listener.set_calibration(CellTruth().calibration())
    # no robot state of its time: raw only, although the event carries the newest pose (another time's)
    listener(events.WrenchSamples(first, None, flange_pose=robot.pose, joint_positions_rad=robot.q_rad,
                                  uncompensated=True))
    listener(events.WrenchSamples(second, None, flange_pose=robot.pose, joint_positions_rad=robot.q_rad))
    listener.flush()
    sinks.close_recording(recording)
    raw_time, _ = read_scalars(path, layout.RAW_FORCE)
    compensated_time, _ = read_scalars(path, layout.COMPENSATED_FORCE)
    assert raw_time.size == 2 * len(first)
    np.testing.assert_allclose(compensated_time, second.time_s, atol=1e-9)  # only the batch with no such flag


def test_stillness_is_judged_at_the_samples_time_not_when_they_are_read():
    from procedures.bias_health import STILL_TOLERANCE_RAD, STILL_WINDOW_S, StillDetector

    calibration = CellTruth().calibration()
    states = CycleStates(capacity=1024)
    stop_s = 0.3  # the arm moves until then, and stays still after

    for k in range(500):  # states up to 1.0 s: the monitor reads late
        t = k * 0.002
        states.append(replace(controller_cycle(min(t, stop_s)), timestamp_s=t, received_s=HOST_OFFSET_S + t + 2e-4))
    static = StaticCompensator(calibration, MODEL, states)
    newest_q = states.window(last=1).q[-1]
    detector = StillDetector()
    for t in np.arange(0.0, 1.0, 0.01):  # what the newest joint angles say: still for long
        detector.update(t, newest_q)

    def batch_at(start_s: float):
        device = start_s + np.arange(BATCH) / RATE_HZ
        return WrenchBatch(time_s=HOST_OFFSET_S + device + 2e-4, wrench=np.zeros((BATCH, 6)),
                           counts=np.zeros((BATCH, 6), dtype=np.int64), status=np.zeros(BATCH, dtype=np.uint32),
                           sequence=np.arange(BATCH, dtype=np.int64), saturated=np.zeros(BATCH, dtype=bool),
                           device_time_s=device)

    assert detector.update(1.0, newest_q)  # the newest state: still
    static.compensate(batch_at(0.4))  # samples taken 0.1 s after the stop: not yet still for STILL_WINDOW_S
    assert not static.still_over(STILL_WINDOW_S, STILL_TOLERANCE_RAD)
    static.compensate(batch_at(0.25))  # taken while the arm moved
    assert not static.still_over(STILL_WINDOW_S, STILL_TOLERANCE_RAD)
    static.compensate(batch_at(0.6))  # taken 0.3 s after the stop
    assert static.still_over(STILL_WINDOW_S, STILL_TOLERANCE_RAD)



class _CountedStates(CycleStates):
    """CycleStates that say their ``count`` (as drivers.ur_stream.URStateStream does) and count their reads."""

    reads = 0

    @property
    def count(self) -> int:
        return self._count

    def window(self, last: int):
        self.reads += 1
        return super().window(last)


def _still_stream():
    """(states, append_still, orientations): 300 still states every 2 ms; append_still(t, q_offset_rad) adds one
    at controller time t (s), joint 1 offset by q_offset_rad (rad)."""
    states = _CountedStates(capacity=1024)

    def append_still(t: float, q_offset_rad: float = 0.0) -> None:
        cycle = controller_cycle(0.0)
        states.append(replace(cycle, timestamp_s=t, received_s=HOST_OFFSET_S + t + 2e-4,
                              q=cycle.q + np.array([q_offset_rad, 0, 0, 0, 0, 0])))

    for k in range(300):
        append_still(k * 0.002)
    return states, append_still, FlangeOrientations(MODEL, states)


def test_a_stillness_query_before_the_next_robot_state_reads_nothing_and_one_after_it_sees_it():
    states, append_still, orientations = _still_stream()
    newest_s = float(states.window(last=1).time_s[-1])
    for _ in range(2):  # the first query sizes the reads of the next ones
        assert orientations.still_between(newest_s - 0.25, newest_s, 2e-4)
    reads = states.reads
    for start_s in (newest_s - 0.25, newest_s - 0.2):  # no state since: the rows read are kept
        assert orientations.still_between(start_s, newest_s, 2e-4)
    assert states.reads == reads
    append_still(0.6, q_offset_rad=1e-3)  # the arm moved in the next state: read, and seen
    newest_s = float(states.window(last=1).time_s[-1])
    reads = states.reads
    assert not orientations.still_between(newest_s - 0.25, newest_s, 2e-4)
    assert states.reads > reads


def test_the_newest_rows_and_the_stillness_query_of_one_state_share_one_read_of_the_stream():
    """The dynamic compensator's newest rows (FlangeOrientations.newest) are read as wide as the stillness check's
    next query, which then reads nothing; a new state (the stream's count) is read again, and seen by both."""
    states, append_still, orientations = _still_stream()
    newest_s = float(states.window(last=1).time_s[-1])
    assert orientations.still_between(newest_s - 0.25, newest_s, 2e-4)  # sizes the next queries
    for t, moved in ((0.6, False), (0.602, True)):  # a new state each time
        append_still(t, q_offset_rad=1e-3 if moved else 0.0)
        newest_s = float(states.window(last=1).time_s[-1])
        reads = states.reads
        tail = orientations.newest(16)
        assert states.reads == reads + 1 and len(tail) > 16  # one read, as wide as the stillness query's
        assert tail.controller_time_s[-1] == t  # the new state
        assert orientations.still_between(newest_s - 0.25, newest_s, 2e-4) is not moved
        assert states.reads == reads + 1  # the stillness query read nothing more
        expected = states.window(last=16)
        for name in ("time_s", "controller_time_s", "q", "qd", "qdd", "target_qd"):
            np.testing.assert_array_equal(getattr(tail, name)[-16:], getattr(expected, name))
