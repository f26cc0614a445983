"""The live dynamic compensation: its per-batch shortcuts give what the straightforward computation gives, and a
batch the predictions do not cover is compensated with the pose *at its samples' time*, or not at all.

procedures/dynamic_compensation.py reads only the newest robot states, runs the model only for the new ones (RNEA,
ftacq.dynamics.model.WrenchPredictor) and keeps the predictions in a ring; ftacq.dynamics.timing.interpolate_rows
avoids temporaries. Compared here with a plain version of what it replaced, to 1e-12 N (the predictor itself
against the regressor: tests/test_dynamics_identify.py; the sensor clock: tests/test_device_clock.py).
"""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from drivers.ur_ft_input import ControllerCycle
from ftacq.dynamics.acceleration import acceleration_steps, joint_acceleration
from ftacq.dynamics.timing import interpolate_rows
from ftacq.kinematics import ur_model
from procedures.bridge import CycleStates
from ftacq.kinematics import FlangeRotation
from procedures.dynamic_compensation import MAX_STATE_GAP_S, PREDICTION_WINDOW_S, DynamicCompensator
from tests.fakes.world import CellTruth

pytest.importorskip("pinocchio")
MODEL = ur_model("UR5e")


def cycles(count: int, seed: int, departs: bool = True):
    """Controller cycles of a smooth motion; target q̇ leaves actual q̇ (the derivative path) now and then (when
    ``departs``; else the arm tracks throughout and q̈ is target q̈)."""
    rng = np.random.default_rng(seed)
    t = np.arange(count) * 0.002
    phase = 2 * np.pi * t[:, None] / np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1])
    q = np.array([0.1, -1.2, 1.0, -1.4, -1.6, 0.2]) + 0.6 * np.sin(phase)
    qd = 0.6 * np.cos(phase) * 2 * np.pi / np.array([1.7, 1.3, 1.9, 0.9, 0.7, 1.1]) + rng.normal(0, 1e-4, (count, 6))
    off = (np.mod(t, 0.5) < 0.05)[:, None] & departs
    received = 80.0 + t + rng.uniform(1e-4, 4e-4, count)
    for k in range(count):
        yield ControllerCycle(timestamp_s=float(t[k]), q=q[k], qd=qd[k], tcp_force=np.zeros(6), runtime_state=2,
                              safety_status_bits=1, received_s=float(received[k]), tcp_pose=np.zeros(6),
                              target_qd=qd[k] + 0.05 * off[k], target_qdd=-q[k] * 0.3)


def plain_compensation(compensator: DynamicCompensator, states: CycleStates, batch, kept: dict) -> np.ndarray | None:
    """What the compensator computed before: the whole window's q̈ each batch, the model for the new states,
    the newest window_rows predictions kept by concatenation."""
    rows = compensator.window_rows
    window = states.window(last=rows)
    new = window.controller_time_s > kept["last"]
    if np.any(new):
        qdd, _ = joint_acceleration(window.time_s, window.qd, window.target_qd, window.qdd)
        predicted = compensator.predictor(window.q[new], window.qd[new], qdd[new])
        kept["times"] = np.concatenate([kept["times"], window.time_s[new]])[-rows:]
        kept["predicted"] = np.vstack([kept["predicted"], predicted])[-rows:]
        kept["last"] = float(window.controller_time_s[-1])
    times = batch.time_s - compensator.lag_s
    if kept["times"].size >= 2 and times[0] >= kept["times"][0] and times[-1] <= kept["times"][-1] + 0.05:
        return batch.wrench - interpolate_rows(times, kept["times"], kept["predicted"])
    return None


def test_dynamic_compensator_gives_the_whole_window_evaluation():
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states = CycleStates()
    # a sensor without a sample clock (NaN device times): the batch keeps its receive times
    compensator = DynamicCompensator(calibration, MODEL, states, lag_s=0.0012, window_s=0.128)
    kept = {"times": np.empty(0), "predicted": np.empty((0, 6)), "last": -np.inf}
    rng = np.random.default_rng(6)
    compared = held = 0
    farthest = 0.0
    for k, cycle in enumerate(cycles(1400, seed=7)):
        states.append(cycle)
        if 300 <= k < 340 or k % 97 == 5:
            continue  # a stall (many new states at the next batch), and batches skipped now and then
        newest_state_s = float(states.window(last=1).time_s[-1])
        offsets = np.sort(rng.uniform(-0.003, 0.0008, int(rng.integers(8, 20))))
        batch = SimpleNamespace(time_s=newest_state_s + compensator.lag_s + offsets,
                                device_time_s=np.full(len(offsets), np.nan),
                                wrench=rng.normal(size=(len(offsets), 6)))
        if k == 700:
            batch.time_s = batch.time_s - 1.0  # older than every state kept: left uncompensated
        got = compensator.compensate(batch, None)
        expected = plain_compensation(compensator, states, batch, kept)
        if expected is None:  # the first cycles (fewer than two states): static, with the pose at the samples' time,
            # or none for samples older than the first state
            first_state_s = float(states.window(last=compensator.window_rows).time_s[0])
            assert (got is None) == (k == 700 or batch.time_s[0] - compensator.lag_s < first_state_s)
            continue
        compared += 1
        ahead = batch.time_s - compensator.lag_s - kept["times"][-1]  # samples newer than the newest state
        held += int(np.count_nonzero(ahead > 0))
        farthest = max(farthest, float(ahead.max()))
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert compared > 1000
    assert compensator.held_samples == held > 0 and compensator.held_max_s == pytest.approx(farthest, abs=1e-12)
    assert compensator.uncompensated_batches >= 1 and compensator.derivative_states > 0  # both paths ran



def test_a_batch_older_than_the_predictions_is_predicted_from_the_states_of_its_time():
    """A batch older than the kept predictions (the monitor's first read after a slow start; a reader that fell
    behind) is predicted from the stream's states of its own span, not compensated statically with the newest or
    its own pose: on issue 27's live run a 2 s first read that began 50 ms before the oldest kept prediction was
    compensated statically throughout a jog move (1.1 N RMS of inertial wrench left in)."""
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states = CycleStates()  # 0.5 s of controller cycles kept
    compensator = DynamicCompensator(calibration, MODEL, states, lag_s=0.0, window_s=0.128)
    flange = FlangeRotation(MODEL)
    all_cycles = list(cycles(200, seed=3))
    for cycle in all_cycles:
        states.append(cycle)
    window = states.window(last=200)
    wrench = np.random.default_rng(1).normal(size=(14, 6))
    # the reader fell behind: a batch 0.3 s old, older than the predictions kept (window_s 0.128 s) but within
    # the states kept, while the arm moves fast (the newest pose would be off by tenths of a radian)
    at = np.sort(window.time_s[40] + np.random.default_rng(2).uniform(0.0, 0.003, 14))
    batch = SimpleNamespace(time_s=at, device_time_s=np.full(14, np.nan), wrench=wrench)
    got = compensator.compensate(batch, None)
    assert got is not None and compensator.catch_up_batches == 1 and compensator.dynamic_batches == 1
    assert compensator.static_batches == 0
    # the expected: the model over every state, interpolated at the samples (the whole-window evaluation)
    qdd, _ = joint_acceleration(window.time_s, window.qd, window.target_qd, window.qdd)
    expected = wrench - interpolate_rows(at, window.time_s, compensator.predictor(window.q, window.qd, qdd))
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    # what the static fallback gave: the pose at the samples' time (slerp), without the inertial wrench
    slerp = Slerp(window.time_s, Rotation.from_matrix(np.array([flange(q) for q in window.q])))
    static = calibration.compensate(wrench, slerp(at).as_matrix().transpose(0, 2, 1))
    assert np.abs(static - expected).max() > 0.05
    newest = calibration.compensate(wrench, flange(window.q[-1]).T)
    assert np.abs(newest - expected).max() > 1.0  # the newest pose would have been wrong by more than a newton
    # the state stream is late (no state within MAX_STATE_GAP_S of the samples): uncompensated, said by None
    late = SimpleNamespace(time_s=window.time_s[-1] + MAX_STATE_GAP_S + 0.01 + np.arange(14) / 7000.0,
                           device_time_s=np.full(14, np.nan), wrench=wrench)
    assert compensator.compensate(late, None) is None and compensator.uncompensated_batches == 1
    # a gap in the stream inside the batch's span counts too
    assert compensator.compensate(SimpleNamespace(time_s=window.time_s[0] - 0.2 + np.arange(3) * 0.1,
                                                  device_time_s=np.full(3, np.nan), wrench=wrench[:3]), None) is None


def test_a_batch_straddling_the_first_robot_state_is_compensated_statically_where_states_are():
    """Samples from before the state stream's first package (the sensor started first): the static fallback with
    the pose at the samples' time when states are near them all, else uncompensated; never a pose from another
    time."""
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states = CycleStates()
    compensator = DynamicCompensator(calibration, MODEL, states, lag_s=0.0, window_s=0.128)
    for cycle in cycles(100, seed=3):
        states.append(cycle)
    window = states.window(last=100)
    wrench = np.random.default_rng(1).normal(size=(14, 6))
    at = window.time_s[0] - 0.004 + np.arange(14) / 7000.0  # 4 ms before the first state, to 2 ms after it
    got = compensator.compensate(SimpleNamespace(time_s=at, device_time_s=np.full(14, np.nan), wrench=wrench), None)
    assert compensator.catch_up_batches == 0 and compensator.dynamic_batches == 0
    assert (got is None) == (compensator.uncompensated_batches == 1) and compensator.static_batches + \
        compensator.uncompensated_batches == 1


def test_a_reader_a_second_behind_the_states_is_still_compensated_dynamically():
    """The monitor descheduled for ~1 s on a loaded machine: its batches are that old when it reads them. With the
    default ring (PREDICTION_WINDOW_S) they still find the predictions of their samples' time, and get what a reader
    on time got; with the old 128 ms ring they fell back to the static model."""
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    states, prompt_states = CycleStates(capacity=2048), CycleStates(capacity=2048)
    lagging = DynamicCompensator(calibration, MODEL, states, lag_s=0.0)
    prompt = DynamicCompensator(calibration, MODEL, prompt_states, lag_s=0.0)
    assert lagging.window_rows * 0.002 >= PREDICTION_WINDOW_S - 0.002
    rng = np.random.default_rng(4)
    batches = []
    for k, cycle in enumerate(cycles(1200, seed=5, departs=False)):
        states.append(cycle)
        prompt_states.append(cycle)
        if k >= 20 and k % 5 == 0:  # a 10 ms batch of samples up to the newest state, read at once by `prompt`
            newest_s = float(states.window(last=1).time_s[-1])
            batch = SimpleNamespace(time_s=newest_s - np.sort(rng.uniform(0.0, 0.009, 70)),
                                    device_time_s=np.full(70, np.nan), wrench=rng.normal(size=(70, 6)))
            batch.time_s.sort()
            batches.append((batch, prompt.compensate(batch, None)))
    # `lagging` read nothing for the last 1.0 s (500 states): it reads those batches now, in order
    late = [(batch, expected) for batch, expected in batches if batch.time_s[0] > states.window(last=500).time_s[0]]
    assert len(late) >= 90
    for batch, expected in late:
        got = lagging.compensate(batch, None)
        assert got is not None and expected is not None
        # (to 1 mN, not 1e-12: read at once, the newest states' q̈ had fewer newer neighbours than read late)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-3)
    assert lagging.static_batches == 0 and lagging.uncompensated_batches == 0
    assert lagging.dynamic_batches == len(late) and prompt.static_batches <= 1



class _ArrivingStates(CycleStates):
    """A state stream whose next states arrive while the compensator waits for them (the RTDE reader thread, held
    off, delivering once the monitor sleeps): ``wait_for_samples`` appends the pending cycles, or none (a silent
    controller: False at once, standing for the deadline)."""

    def __init__(self) -> None:
        super().__init__(capacity=2048)
        self.pending: list[ControllerCycle] = []
        self.waited = 0
        self.stale = False

    @property
    def count(self) -> int:
        return self._count

    def wait_for_samples(self, count: int, timeout_s: float) -> bool:
        self.waited += 1
        assert 0.0 < timeout_s <= 0.1
        if not self.pending:
            return False
        self.append(self.pending.pop(0))
        return self._count >= count


def test_a_batch_ahead_of_the_newest_state_waits_for_the_states_of_its_time():
    """The monitor under load: its batch's newest samples are 12 ms newer than the newest robot state (the RTDE reader
    thread was held off). With state_wait_s it waits for those states and gives what a reader with every state in
    hand gives (nothing held); without, the newest prediction is held over the 12 ms. A silent stream is waited for
    once, not at every batch."""
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    all_cycles = list(cycles(400, seed=9, departs=False))
    waiting_states, holding_states, full_states = _ArrivingStates(), CycleStates(2048), CycleStates(2048)
    for cycle in all_cycles[:300]:
        for states in (waiting_states, holding_states):
            states.append(cycle)
    for cycle in all_cycles:
        full_states.append(cycle)
    waiting_states.pending = all_cycles[300:310]
    waiting = DynamicCompensator(calibration, MODEL, waiting_states, lag_s=0.0, state_wait_s=0.1)
    holding = DynamicCompensator(calibration, MODEL, holding_states, lag_s=0.0)
    reference = DynamicCompensator(calibration, MODEL, full_states, lag_s=0.0)
    newest_s = float(holding_states.window(last=1).time_s[-1])
    rng = np.random.default_rng(8)
    batch = SimpleNamespace(time_s=newest_s - 0.008 + np.arange(140) / 7000.0, device_time_s=np.full(140, np.nan),
                            wrench=rng.normal(size=(140, 6)))
    assert batch.time_s[-1] - newest_s > 0.011
    expected = reference.compensate(batch, None)
    got, held = waiting.compensate(batch, None), holding.compensate(batch, None)
    assert got is not None and held is not None and expected is not None
    # (to 1 mN: the reference's newest states had their later neighbours in hand, as in the test above)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-3)
    assert waiting.held_samples == 0 and waiting.waits == 1 and waiting.wait_timeouts == 0
    assert 0 < waiting_states.waited <= 10 and waiting_states.pending  # it stopped once the states covered the batch
    assert holding.held_samples > 80 and np.abs(held - expected).max() > 0.1  # held: off by dW/dt × up to 12 ms
    # the controller falls silent: the next batch waits in vain once; later ones do not wait until a state comes
    waiting_states.pending = []
    for shift in (0.02, 0.03):
        late = SimpleNamespace(time_s=batch.time_s + shift, device_time_s=batch.device_time_s, wrench=batch.wrench)
        assert waiting.compensate(late, None) is not None  # the newest prediction held, within MAX_STATE_GAP_S
    assert waiting.waits == 2 and waiting.wait_timeouts == 1 and waiting.held_samples > 0


def test_a_live_publisher_holds_the_newest_few_ms_and_waits_only_beyond():
    """``monitor --ros2`` (hold_s 5 ms): a read at most 5 ms ahead of the newest robot state takes that state's
    prediction held, without waiting; one 12 ms ahead waits, but only until the states are within 5 ms of it."""
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    all_cycles = list(cycles(400, seed=9, departs=False))
    states = _ArrivingStates()
    for cycle in all_cycles[:300]:
        states.append(cycle)
    states.pending = all_cycles[300:310]
    live = DynamicCompensator(calibration, MODEL, states, lag_s=0.0, state_wait_s=0.1, hold_s=0.005)
    newest_s = float(states.window(last=1).time_s[-1])
    rng = np.random.default_rng(8)
    near = SimpleNamespace(time_s=newest_s - 0.017 + np.arange(140) / 7000.0, device_time_s=np.full(140, np.nan),
                           wrench=rng.normal(size=(140, 6)))
    assert 0.0 < near.time_s[-1] - newest_s < 0.005
    assert live.compensate(near, None) is not None
    assert live.waits == 0 and states.waited == 0 and live.held_samples > 0  # held, not waited for
    far = SimpleNamespace(time_s=near.time_s + 0.009, device_time_s=near.device_time_s, wrench=near.wrench)
    assert far.time_s[-1] - newest_s > 0.011
    assert live.compensate(far, None) is not None
    assert live.waits == 1 and live.wait_timeouts == 0 and states.pending  # waited for a few states, not all
    assert live.held_max_s <= 0.005  # never held further than hold_s ahead



def _joints(move, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q, q̇, q̈) (N, 6) of a moveJ (tests/fakes/ur_motion.py) at its times ``t`` (N,), s: its trapezoid."""
    profile, direction = move.profile, move.direction
    return (move.q_start + np.outer(profile.position(t), direction), np.outer(profile.speed_at(t), direction),
            np.outer(profile.acceleration_at(t), direction))


@pytest.mark.parametrize("period_s, servo_lag_s, ahead_s", [(0.008, 0.004, 0.0), (0.008, 0.004, 0.003),
                                                            (0.008, 0.0, 0.0), (0.002, 0.004, 0.0)])
def test_a_moves_acceleration_steps_are_located_inside_the_state_interval(period_s, servo_lag_s, ahead_s):
    """A moveJ's trapezoid switches q̈ at any instant; a CB3 reports its states every 8 ms. The prediction at the
    states interpolated linearly smears each step over the period (and the servo lag): up to 0.8 N off at the 7 kHz
    samples of an exact sensor. With the steps located from the change of the target's speed
    (ftacq.dynamics.acceleration) the compensated wrench is 50× closer to zero; for samples up to 3 ms ahead of the
    newest state (held: the step is then known from the target, the servo lag ahead of the arm) 5× at the worst
    sample (the rest is the hold's own error, dW/dt × 3 ms)."""
    from procedures.plan import home_configuration_rad
    from tests.fakes.ur_motion import JointMove
    truth = CellTruth()
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m), inertia=truth.inertia)
    start = home_configuration_rad("floor")
    move = JointMove(MODEL, start, start + np.array([0.5, -0.3, 0.4, 0.4, -0.5, 0.6]), 1.0, 2.0)
    start_s = 80.05021  # the move's start on the host clock (the states arrive 80 s after their timestamp)
    state_s = np.arange(0.0013, move.duration_s + 0.15, period_s)  # controller time
    target = _joints(move, state_s + 80.0 - start_s)
    arm = _joints(move, state_s + 80.0 - start_s - servo_lag_s)
    cycles = [ControllerCycle(timestamp_s=float(t), q=arm[0][k], qd=arm[1][k], tcp_force=np.zeros(6), runtime_state=2,
                              safety_status_bits=1, received_s=80.0 + float(t), tcp_pose=np.zeros(6),
                              target_qd=target[1][k], target_qdd=target[2][k]) for k, t in enumerate(state_s)]
    sample_s = np.arange(np.ceil(80.0 * 7000.0), np.floor((80.0 + state_s[-1] + ahead_s) * 7000.0) + 1) / 7000.0
    errors = {}
    for located in (True, False):
        states = CycleStates(4096, frequency_hz=1.0 / period_s)
        compensator = DynamicCompensator(calibration, MODEL, states, lag_s=0.0, servo_lag_s=servo_lag_s,
                                         window_s=4.0)
        if not located:
            compensator._locate_steps = lambda *args: None  # the linear interpolation alone, as before
        truth_wrench = compensator.predictor(*_joints(move, sample_s - start_s - servo_lag_s))  # the arm's
        residuals = []
        for k, cycle in enumerate(cycles):
            states.append(cycle)
            if k == 0:
                continue
            batch = (sample_s > cycles[k - 1].received_s + ahead_s) & (sample_s <= cycle.received_s + ahead_s)
            contact = compensator.compensate(SimpleNamespace(time_s=sample_s[batch], wrench=truth_wrench[batch],
                                                             device_time_s=np.full(np.count_nonzero(batch), np.nan)))
            assert contact is not None
            residuals.append(contact)
        errors[located] = np.abs(np.vstack(residuals))
        assert compensator.located_steps == (4 if located else 0)  # accelerate, cruise, decelerate, stop
    rms = {located: np.sqrt(np.mean(error ** 2, axis=0)) for located, error in errors.items()}
    assert np.all(errors[True].max(axis=0) <= (0.2 if ahead_s else 0.05) * errors[False].max(axis=0))
    assert np.all(rms[True] <= (0.4 if ahead_s else 0.02) * rms[False])


def test_a_step_of_the_targets_acceleration_is_located_where_it_is_and_a_ramp_is_none():
    """acceleration_steps: a q̈ that switches from a to b at a random instant between two 8 ms states is found at that
    instant (from the speeds: exact for a piecewise-constant q̈); a q̈ that changes at every state (a moveL, a blend)
    has no step, nor has a steady one."""
    rng = np.random.default_rng(3)
    t = 0.0017 + 0.008 * np.arange(12)
    for _ in range(5):
        a, b, step_s = rng.normal(size=6), rng.normal(size=6), float(rng.uniform(t[5], t[6]))
        qdd = np.where((t < step_s)[:, None], a, b)
        qd = np.where((t < step_s)[:, None], a * t[:, None], a * step_s + b * (t[:, None] - step_s))
        rows, at_s, change = acceleration_steps(t, qd, qdd)
        assert rows.tolist() == [5]
        assert at_s[0] == pytest.approx(step_s, abs=1e-12) and np.allclose(change[0], b - a)
    ramp = np.outer(t, np.ones(6))
    assert acceleration_steps(t, 0.5 * ramp ** 2, ramp)[0].size == 0
    assert acceleration_steps(t, ramp, np.ones((12, 6)))[0].size == 0
