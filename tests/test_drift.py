"""The live drift tracker (ftacq/drift.py) fed with simulated batches: it follows a slow drift, never absorbs a push
held while the arm is still (steady or trembling), and flags a swapped tool soon after the arm stops."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ftacq.drift import DriftSettings
from ftacq.drift_health import BiasHealth
from ftacq.rest_windows import RestWindows, summarise_window
from ftacq.identification import identify
from ftacq.so3 import rotation_from_rotvec
from tests.fakes.pose_records import cone_orientations, example_record, poses_from_orientations
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

RATE_HZ = 2000.0
BATCH_S = 0.05
POSE = np.array([0.4, 0.0, 0.4, np.pi, 0.0, 0.0])
FLANGE_R_BASE = rotation_from_rotvec(POSE[3:6]).T


@pytest.fixture(scope="module")
def calibration():
    return identify(example_record(seed=2), mount="floor").calibration


class Feeder:
    """Samples SensorPhysics at RATE_HZ in batches along a simulated clock and feeds a BiasHealth."""

    def __init__(self, calibration, truth: CellTruth, seed: int = 0, auto_tare: bool = True) -> None:
        self.physics = SensorPhysics(truth, SettablePose(POSE), seed=seed)
        self.rng = np.random.default_rng(seed + 1)
        self.calibration = calibration
        self.health = BiasHealth(calibration, DriftSettings(), auto_tare=auto_tare)
        self.t = 0.0
        self.notices = []

    def still(self, seconds: float, contact=None, pose=POSE) -> None:
        n = int(RATE_HZ * BATCH_S)
        flange_R_base = rotation_from_rotvec(pose[3:6]).T
        end = self.t + seconds
        # the still tool's load at this pose (SensorPhysics.noiseless_wrench less its biases), once per call
        load = self.physics.noiseless_wrench(pose, 0.0) - self.physics.bias_at(0.0)
        while self.t < end - 1e-9:
            t = self.t + np.arange(n) / RATE_HZ
            wrench = load + self.physics.bias_at(self.t) + self.rng.standard_normal((n, 6)) \
                * self.physics._noise_sigma
            if contact is not None:
                wrench = wrench + contact(t)
            residual = self.calibration.compensate(wrench, flange_R_base)
            self.notices += self.health.feed(t, residual, True, flange_R_base)
            self.t += BATCH_S

    def move(self, seconds: float) -> None:
        self.health.feed(np.array([self.t]), np.zeros((1, 6)), False)
        self.t += seconds


def test_rest_windows_start_after_settling_and_motion_discards_the_open_one() -> None:
    windows = RestWindows(window_s=0.5, settle_s=0.5)
    t = np.arange(0, 0.9, 0.001)
    assert windows.feed(t, np.zeros((len(t), 6)), True) == []  # 0.4 s of data after settling: not a window yet
    assert windows.feed(np.array([1.0]), np.zeros((1, 6)), False) == []
    t = 2.0 + np.arange(0, 1.6, 0.001)
    done = windows.feed(t, np.ones((len(t), 6)), True)
    assert len(done) == 2 and done[0].start_s == pytest.approx(2.5) and done[0].count == 500
    np.testing.assert_allclose(done[0].mean, 1.0)


def test_in_window_slope_is_measured_in_standard_errors() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(0, 0.5, 1e-3)
    flat = summarise_window(t, rng.normal(scale=0.05, size=(len(t), 6)), None)
    ramp = summarise_window(t, rng.normal(scale=0.05, size=(len(t), 6)) + np.outer(t, [2.0, 0, 0, 0, 0, 0]), None)
    assert np.all(np.abs(flat.slope_t) < 5)
    assert ramp.slope_t[0] > 20


def test_tracker_follows_a_slow_drift(calibration) -> None:
    drift = np.array([0.5, -0.5, 0.5, 0.01, -0.01, 0.01]) / 3600.0
    truth = replace(CellTruth(), drift_n_per_s=tuple(drift[:3]), drift_nm_per_s=tuple(drift[3:]))
    feeder = Feeder(calibration, truth)
    for _ in range(40):  # 40 × (20 s still + 10 s moving) = 20 min
        feeder.still(20.0)
        feeder.move(10.0)
    true_offset = feeder.physics.bias_at(feeder.t) - feeder.physics.bias_at(0.0)
    estimate = feeder.health.tracker.offset(feeder.t)
    assert np.abs(true_offset[:3]).min() > 0.15  # 0.5 N/h over 20 min: a drift the tracker must follow
    np.testing.assert_allclose(estimate[:3], true_offset[:3], atol=0.01)
    assert not any(n.level == "WARN" for n in feeder.notices)


def test_sigma_is_the_propagated_state_s_to_the_last_bit(calibration) -> None:
    feeder = Feeder(calibration, CellTruth())
    feeder.still(12.0)
    tracker = feeder.health.tracker
    assert tracker.accepted and tracker.time_s is not None
    for dt in (-1.0, 0.0, 1e-3, 0.37, 60.0, 3600.0):  # sigma() reproduces _propagate's operations on P[0, 0]
        propagated = np.sqrt(tracker._state_at(tracker.time_s + dt)[1][:, 0, 0])
        assert np.array_equal(tracker.sigma(tracker.time_s + dt), propagated)
    assert np.array_equal(tracker.sigma(), np.sqrt(tracker.P[:, 0, 0]))


@pytest.mark.parametrize("tremble", [False, True])
def test_a_push_while_still_is_not_absorbed(calibration, tremble) -> None:
    """A push of 4 N held 3 s on the still arm (steady, or trembling as a hand does) leaves the bias estimate where
    it was; the tracker keeps working after it."""
    feeder = Feeder(calibration, CellTruth(), seed=3)
    for _ in range(6):
        feeder.still(15.0)
        feeder.move(5.0)
    feeder.still(3.0)
    before = feeder.health.tracker.offset(feeder.t)
    accepted_before = feeder.health.tracker.accepted
    push = np.array([3.0, -2.0, 1.5, 0.05, 0.02, -0.04])
    start = feeder.t

    def contact(t):
        envelope = np.clip(np.minimum((t - (start + 0.2)) / 0.15, (start + 3.2 - t) / 0.15), 0.0, 1.0)
        wobble = 1.0 + (0.05 * np.sin(2 * np.pi * 5.0 * t) if tremble else 0.0)
        return (envelope * wobble)[:, None] * push

    feeder.still(4.0, contact)
    after = feeder.health.tracker.offset(feeder.t)
    assert np.all(np.abs(after - before) <= 0.002 * np.array([1, 1, 1, 0.05, 0.05, 0.05]) + 1e-4), after - before
    rejected = feeder.health.tracker.rejected_contact + feeder.health.tracker.rejected_gate
    assert rejected >= 5  # the push's windows were seen and refused
    feeder.still(5.0)
    assert feeder.health.tracker.accepted > accepted_before  # and the tracker goes on after the push
    if tremble:  # a trembling hand is contact, not "at rest": no at-rest warning
        assert not any(n.level == "WARN" for n in feeder.notices)


def test_a_swapped_tool_is_flagged_within_5_s_of_stillness(calibration) -> None:
    feeder = Feeder(calibration, CellTruth(), seed=5)
    for _ in range(4):
        feeder.still(10.0)
        feeder.move(5.0)
    feeder.physics.set_tool(1.0, (0.01, 0.0, 0.05))  # during the move, without telling the software
    still_from = feeder.t
    feeder.still(10.0)
    warnings = [n for n in feeder.notices if n.level == "WARN"]
    assert warnings, "the swapped tool was not flagged"
    assert warnings[0].time_s - still_from <= 5.0
    assert "not the tracked drift" in warnings[0].text and "tool" in warnings[0].text
    assert any("a step, not drift" in w.text and w.time_s - still_from <= 5.0 for w in warnings)
    assert feeder.health.tracker.rejected_gate > 0  # and it was not absorbed as a bias


# ------------------------------------------------------------------------------------ the monitor's seam

class _Batch:
    def __init__(self, time_s, wrench):
        self.time_s, self.wrench = time_s, wrench
        self.saturated = np.zeros(len(time_s), dtype=bool)


class _Robot:
    def __init__(self, time_s, q):
        self.time_s, self.joint_positions_rad, self.flange_pose = time_s, q, POSE


class _Samples:
    def __init__(self, batch):
        self.batch = batch


def test_still_detector_needs_the_joints_still_for_its_window() -> None:
    from procedures.bias_health import StillDetector

    detector = StillDetector(tolerance_rad=2e-4, window_s=0.25)
    q = np.zeros(6)
    assert not detector.update(0.0, q)
    assert not detector.update(0.1, q + 1e-5)
    assert detector.update(0.3, q - 1e-5)
    assert not detector.update(0.4, q + [0, 0, 0, 0, 0, 1e-3])  # the wrist turned
    assert not detector.update(0.6, q + [0, 0, 0, 0, 0, 1e-3])  # still inside the window of the motion
    assert detector.update(0.7, q + [0, 0, 0, 0, 0, 1e-3])
    assert not detector.update(0.8, None)  # no robot state: not known to be still


def test_drift_compensator_applies_the_tracked_offset_only_with_auto_tare(calibration) -> None:
    """With --auto-tare the compensated stream at rest loses a bias offset the tracker found; without it the
    stream is the calibration's compensation, unchanged, and the tracker still reports the offset."""
    from procedures.bias_health import DriftCheck, DriftCompensator
    from procedures.events import BiasDrift

    offset = np.array([0.03, -0.02, 0.025, 0.001, -0.0005, 0.0008])  # drifted since the file, within the gate
    truth = replace(CellTruth(), force_bias_n=tuple(np.add(CellTruth().force_bias_n, offset[:3])),
                    torque_bias_nm=tuple(np.add(CellTruth().torque_bias_nm, offset[3:])))
    physics = SensorPhysics(truth, SettablePose(POSE), seed=9)
    rng = np.random.default_rng(9)
    results = {}
    for auto_tare in (False, True):
        compensator = DriftCompensator(BiasHealth(calibration, DriftSettings(), age_s=3600.0, auto_tare=auto_tare))
        check = DriftCheck(compensator, period_s=1.0)
        drift_events, out = [], []
        for k in range(200):  # 10 s still at 2 kHz in 0.05 s batches
            t = k * BATCH_S + np.arange(int(RATE_HZ * BATCH_S)) / RATE_HZ
            wrench = physics.noiseless_wrench(POSE) + rng.standard_normal((len(t), 6)) * physics._noise_sigma
            batch = _Batch(t, wrench)
            out.append(compensator.compensate(batch, _Robot(t[-1], np.zeros(6))))
            drift_events += [e for e in check.check(_Samples(batch)) if isinstance(e, BiasDrift)]
        results[auto_tare] = np.concatenate(out[-40:]).mean(axis=0)
        assert drift_events and drift_events[-1].applied == auto_tare
        np.testing.assert_allclose(drift_events[-1].offset[:3], offset[:3], atol=0.003)
    np.testing.assert_allclose(results[False][:3], offset[:3], atol=0.003)  # untouched: the drift shows
    np.testing.assert_allclose(results[True][:3], 0.0, atol=0.003)  # auto-tare removed it


def test_the_tracker_learns_from_reads_after_they_are_published(calibration) -> None:
    """A rest window's update (1-2 ms) must not delay a read's messages, nor a feed's fixed cost weigh on every 2 ms
    read: compensate() leaves its batch to DriftCheck.check, which the monitor runs once the read is published and
    which feeds the tracker once the batches waiting span TRACK_PERIOD_S, one feed per run of batches alike still
    (or not); a batch no check took is fed before a later compensate(), and a tare (rebase) feeds what waits to the
    old biases' tracker first. Every sample once, in order."""
    from procedures.bias_health import TRACK_PERIOD_S, DriftCheck, DriftCompensator

    class Still:  # the stillness of each batch, as scripted
        window_s, tolerance_rad = 0.25, 1e-4

        def __init__(self, flags) -> None:
            self.flags = iter(flags)

        def update(self, time_s, q) -> bool:
            return next(self.flags)

    compensator = DriftCompensator(BiasHealth(calibration, DriftSettings(), age_s=3600.0),
                                   still=Still([False] + [True] * 6))  # type: ignore[arg-type]
    check = DriftCheck(compensator, period_s=1.0)
    fed: list[tuple[float, int, bool]] = []
    health = compensator.health
    feed = health.feed

    def counted(time_s, residual, still, *args):
        fed.append((float(time_s[0]), len(time_s), still))
        return feed(time_s, residual, still, *args)

    health.feed = counted  # type: ignore[method-assign]
    period_s = 0.4 * TRACK_PERIOD_S  # 8 samples per batch, batches back to back
    batches = [_Batch(k * period_s + np.arange(8) * period_s / 8, np.zeros((8, 6))) for k in range(7)]

    def read(k: int, checked: bool = True) -> None:
        compensator.compensate(batches[k], _Robot(batches[k].time_s[-1], np.zeros(6)))
        if checked:
            check.check(_Samples(batches[k]))

    read(0)
    read(1)
    assert fed == []  # compensated and published, 0.75 TRACK_PERIOD_S waiting: not yet learnt from
    read(2)
    assert fed == [(0.0, 8, False), (period_s, 16, True)]  # one feed per run of stillness
    for k in (3, 4, 5):
        read(k, checked=False)
    assert fed[2:] == []  # at batch 5's compensation, 0.75 TRACK_PERIOD_S were waiting
    read(6, checked=False)
    assert fed[2:] == [(3 * period_s, 24, True)]  # fed before batch 6 is compensated
    compensator.rebase(calibration)
    assert fed[3:] == [(6 * period_s, 8, True)] and compensator.health is not health  # to the old tracker


def test_the_monitors_drift_line_prints_each_sigma_with_two_significant_digits(calibration) -> None:
    """The summary line of `ftacq monitor` gives the tracked offset ± 1σ; 1σ of a few 10⁻⁴ N or 10⁻⁵ N·m printed
    with a fixed 4 or 5 decimals showed one significant digit."""
    import re
    from types import SimpleNamespace

    from ftacq.app.commands.monitor import format_drift

    feeder = Feeder(calibration, CellTruth(), seed=11)
    feeder.still(20.0)
    line = format_drift(SimpleNamespace(health=feeder.health))
    sigmas = re.findall(r"([+-]\d+\.\d+)±(\d+\.\d+)", line)
    assert len(sigmas) == 6, line
    for value, sigma in sigmas:
        digits = sigma.replace(".", "").lstrip("0")
        assert len(digits) == 2, f"1σ {sigma} in: {line}"
        assert len(value.partition(".")[2]) == len(sigma.partition(".")[2])  # the value to the same decimal


# ------------------------------------------------------------------ warm-up drift, steps, trust (issue 26 item 2)

def warmup_truth(force_n_per_h: float, torque_nm_per_h: float, tau_s: float = 600.0) -> CellTruth:
    """A sensor warming up: the biases move as A (1 − e^(−t/τ)), starting at the given rates (A = rate × τ)."""
    force, torque = force_n_per_h / 3600.0 * tau_s, torque_nm_per_h / 3600.0 * tau_s
    return replace(CellTruth(), thermal_step_n=(force, -force, force), thermal_step_nm=(torque, -torque, torque),
                   thermal_step_at_s=0.0, thermal_time_constant_s=tau_s)


def test_the_simulated_sensor_warms_up_by_several_newtons_in_half_an_hour() -> None:
    physics = SensorPhysics(warmup_truth(30.0, 1.0), SettablePose(POSE), seed=0)
    change = physics.bias_at(1800.0) - physics.bias_at(0.0)
    assert np.all(np.abs(change[:3]) > 4.5) and np.all(np.abs(change[3:]) > 0.15)  # 5 N, 0.17 N·m: mostly done
    early = (physics.bias_at(60.0) - physics.bias_at(0.0)) / 60.0 * 3600.0
    np.testing.assert_allclose(np.abs(early), [29, 29, 29, 0.95, 0.95, 0.95], rtol=0.05)  # starts at 30 N/h


def test_tracker_follows_warm_up_drift_at_60_n_per_h_within_3_sigma_and_is_not_gated(calibration) -> None:
    """A warm-up starting at 60 N/h (2 N·m/h), the arm still 15 s and moving 5 s in turn: the old tracker gated
    ~all rest windows after the first ones and was off by > 10 printed σ."""
    feeder = Feeder(calibration, warmup_truth(60.0, 2.0), seed=21)
    ratios = []
    for _ in range(15):  # 5 min
        feeder.still(15.0)
        true_offset = feeder.physics.bias_at(feeder.t) - np.concatenate([calibration.force_bias,
                                                                           calibration.torque_bias])
        tracker = feeder.health.tracker
        ratios.append((tracker.offset(feeder.t) - true_offset) / tracker.sigma(feeder.t))
        feeder.move(5.0)
    tracker = feeder.health.tracker
    windows = tracker.accepted + tracker.rejected_gate + tracker.rejected_contact
    assert tracker.rejected_gate <= 0.02 * windows, (tracker.rejected_gate, windows)
    ratios = np.array(ratios[1:])  # from the second still period on (the first one finds the rate)
    assert np.all(np.abs(ratios) <= 3.0), ratios
    assert not any(n.level == "WARN" for n in feeder.notices), [n.text for n in feeder.notices]
    true_rate = np.array([1, -1, 1]) * 60.0 * np.exp(-tracker.time_s / 600.0)  # N/h, the warm-up slowing down
    np.testing.assert_allclose(tracker.rate_per_h[:3], true_rate, rtol=0.1)


def test_a_bias_step_is_called_a_step_and_auto_tare_stops_applying_the_offset(calibration) -> None:
    """A 0.4 N bias step while the arm is still (a box bias): refused, called a step (not drift), and --auto-tare
    withdraws the tracked offset it no longer trusts, saying so; once the sensor reads as before, it resumes."""
    feeder = Feeder(calibration, warmup_truth(20.0, 0.5), seed=23)
    for _ in range(4):
        feeder.still(15.0)
        feeder.move(5.0)
    feeder.still(5.0)
    health = feeder.health
    assert health.trusted and np.abs(health.correction(feeder.t)[:3]).max() > 0.05  # 20 N/h for 80 s: applied
    step = np.array([0.4, 0.0, -0.3, 0.0, 0.0, 0.0])
    feeder.physics._bias = feeder.physics._bias + step
    feeder.still(5.0)
    assert health.tracker.step is not None
    np.testing.assert_allclose(health.tracker.step.size[[0, 2]], step[[0, 2]], atol=0.02)
    assert not health.trusted and np.all(health.correction(feeder.t) == 0.0)
    texts = [n.text for n in feeder.notices]
    assert any("auto-tare suspended" in t and "step" in t for t in texts), texts
    assert any("a step, not drift" in t for t in texts), texts
    assert not any("re-acquired" in t for t in texts), texts
    feeder.physics._bias = feeder.physics._bias - step  # the box's zero restored (as after a power cycle back)
    feeder.still(3.0)
    assert health.trusted and health.tracker.step is None
    assert any("applying the tracked offset again" in n.text for n in feeder.notices)


def test_drift_faster_than_tracked_is_reacquired_not_called_a_step(calibration) -> None:
    """During a 60 s move the drift rate climbs from 10 to 150 N/h (out of the tracker's model): the first windows
    after it are refused, then found to join the track smoothly and re-acquired; a jump of the same size with the
    rate unchanged is a step."""
    results = {}
    for kind in ("drift", "step"):
        feeder = Feeder(calibration, CellTruth(), seed=25)
        base = feeder.physics._bias.copy()
        direction = np.array([1.0, -1.0, 1.0, 0.03, -0.03, 0.03])
        r0, r1, t0, t1 = 10.0 / 3600.0, 150.0 / 3600.0, 60.0, 120.0

        def bias_at(t, base=base, direction=direction, kind=kind, r0=r0, r1=r1, t0=t0, t1=t1):
            t = np.asarray(t, dtype=float)
            if kind == "drift":  # the rate goes linearly from r0 to r1 over [t0, t1], then stays at r1
                inside = np.clip(t - t0, 0.0, t1 - t0)
                change = r0 * t + 0.5 * (r1 - r0) * inside**2 / (t1 - t0) + (r1 - r0) * np.maximum(t - t1, 0.0)
            else:  # the rate stays r0; the same offset as the drift's at t1 appears at once during the move
                change = r0 * t + np.where(t >= 90.0, 0.5 * (r1 - r0) * (t1 - t0), 0.0)
            return base + np.multiply.outer(change, direction) if np.ndim(change) else base + change * direction

        feeder.physics.bias_at = bias_at  # type: ignore[method-assign]
        for _ in range(3):
            feeder.still(15.0)
            feeder.move(5.0)
        assert feeder.t == pytest.approx(t0)
        feeder.move(t1 - t0)
        feeder.still(10.0)
        results[kind] = feeder
    drift, step = results["drift"].health.tracker, results["step"].health.tracker
    assert drift.reacquired >= 1 and drift.step is None
    true_offset = results["drift"].physics.bias_at(results["drift"].t) - np.concatenate(
        [calibration.force_bias, calibration.torque_bias])
    assert np.all(np.abs(drift.offset(results["drift"].t) - true_offset) <= 3.0 * drift.sigma(results["drift"].t))
    assert step.reacquired == 0 and step.step is not None
    assert any("a step, not drift" in n.text for n in results["step"].notices)


def test_a_push_held_into_a_move_does_not_lock_the_tracker_out(calibration) -> None:
    """A steady push still held when the arm moves off (called a step, --auto-tare suspended) is gone at the next
    stillness, at another orientation, after the drift moved on: the tracker takes up the track again and applies
    it (the benchmark found the offset withdrawn for the rest of the hour)."""
    feeder = Feeder(calibration, warmup_truth(20.0, 0.5), seed=27)
    for _ in range(3):
        feeder.still(15.0)
        feeder.move(5.0)
    start = feeder.t

    def push(t):
        return np.clip((t - (start + 2.0)) / 0.15, 0.0, 1.0)[:, None] * np.array([2.0, -1.0, 3.0, 0.05, 0.0, 0.02])

    feeder.still(8.0, push)  # held until the arm moves
    assert feeder.health.tracker.step is not None and not feeder.health.trusted
    feeder.move(15.0)
    other = np.array([0.45, 0.05, 0.35, np.pi - 0.3, 0.2, 0.1])
    feeder.still(10.0, pose=other)
    assert feeder.health.tracker.step is None and feeder.health.trusted
    true_offset = feeder.physics.bias_at(feeder.t) - np.concatenate([calibration.force_bias, calibration.torque_bias])
    np.testing.assert_allclose(feeder.health.correction(feeder.t)[:3], true_offset[:3], atol=0.01)


def normalised_errors(seed: int, model_terms: bool = True, samples_per_pose: int = 20) -> np.ndarray:
    """(periods, 6) tracked offset − true offset over the printed 1σ at the end of each still period after the first,
    for a calibration identified from its own simulated record (seed; ``samples_per_pose`` per pose: 20 makes its
    model error several times the tracker's own noise, so that the 1σ's model terms decide the result) and a warm-up from 20 N/h
    (0.7 N·m/h) over orientations in the calibration's 40° cone. ``model_terms=False`` drops the calibration's
    model error from the tracker (what the printed 1σ would be without it)."""
    calibration = identify(example_record(seed=seed, samples_per_pose=samples_per_pose), mount="floor").calibration
    feeder = Feeder(calibration, warmup_truth(20.0, 0.7), seed=100 + seed)
    if not model_terms:
        feeder.health.tracker.model_variance = lambda flange_R_base: (np.zeros(6), np.zeros(6))  # type: ignore
    poses = poses_from_orientations(cone_orientations(6, 40.0, seed=200 + seed))
    file_bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
    ratios = []
    for k, pose in enumerate(poses):
        feeder.still(12.0, pose=pose)
        if k:
            tracker = feeder.health.tracker
            ratios.append((tracker.offset(feeder.t) - (feeder.physics.bias_at(feeder.t) - file_bias))
                          / tracker.sigma(feeder.t))
        feeder.move(4.0)
    return np.array(ratios)


def test_the_printed_sigma_is_a_true_one_sigma_over_many_calibrations() -> None:
    """The printed offset's error comes mostly from the calibration's own model error at the orientations visited
    (one draw per calibration, the same for the whole run), so its 1σ is tested over many calibrations: the
    normalised errors have an RMS near 1 (0.90-0.96 over two sets of 12 seeds; 2.4 with a 1σ that leaves the model
    error out)."""
    ratios = np.concatenate([normalised_errors(seed) for seed in range(1, 13)])
    rms = np.sqrt(np.mean(ratios**2, axis=0))
    assert np.all((rms > 0.45) & (rms < 1.5)), rms
    assert 0.7 < float(np.sqrt(np.mean(ratios**2))) < 1.25, rms
    without = np.concatenate([normalised_errors(seed, model_terms=False) for seed in range(1, 4)])
    assert float(np.sqrt(np.mean(without**2))) > 1.6  # the test can fail: the model terms matter at this size
