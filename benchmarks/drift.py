"""Benchmark: one hour of bias drift at rest — no tare, a periodic `ftacq tare`, the live tracker — plus pushes on
the tool and tool swaps.

    .venv/bin/python benchmarks/drift.py            # one simulated hour + 10 tool swaps
    .venv/bin/python benchmarks/drift.py --minutes 20 --swaps 3
    .venv/bin/python benchmarks/drift.py --rates-only --seeds 8 --rate-minutes 10   # the 1σ over 8 calibrations

Time-scaled, without sockets: the simulated sensor's physics (tests/fakes/world.py SensorPhysics, the same code
the simulated Net F/T serves) is sampled directly at 7 kHz in 0.1 s batches along a schedule, and the batches go
through exactly what `ftacq monitor` runs (Calibration.compensate, then ftacq.drift_health.BiasHealth). Moving periods
are not sampled (the tracker ignores them; it only learns they happened). Wall time is a few seconds.

Cell: the default simulated truth with a drift of +0.5, −0.5, +0.5 N/h (force) and ±0.01 N·m/h (torque), plus a
thermal-like exponential step (0.15, −0.10, 0.20 N; 0.004, −0.003, 0.002 N·m; τ = 10 min) 15 min in. The
calibration is identified from a simulated record of that cell at time zero (24 special + 24 cone poses, 500
samples per pose: tests/fakes/pose_records.example_record). The arm alternates still (15-45 s, random orientation
in a 40° cone) and moving (5-20 s). In 40 % of still periods a push (2-15 N, 0.05-0.5 N·m, sensor frame) is held
1-4 s after a 0.15 s ramp; half trembles (5 % at 3-8 Hz), half is perfectly steady.

Printed: the compensated error at rest (mean of each push-free rest window, force channels, in N and in units of
the calibration's force-bias 1σ) every 5 min and over the hour, for (a) no tare, (b) `ftacq tare` at the current
pose every 10 min (one 0.5 s average, at the first push-free still moment), (c) the live tracker with --auto-tare,
and for reference (d) the calibration's own error at the same poses without any drift (the floor no bias
estimate can go below: the model's orientation-dependent error);
the tracker's absorbed pushes (rest windows overlapping a push that updated the estimate), its rejections, the
warnings; then, per tool swap (another mass and centre of mass put on during a move), the time from the arm's
next stillness to the at-rest warning.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from ftacq.bias_estimate import estimate_biases  # noqa: E402
from ftacq.calibration import Calibration  # noqa: E402
from ftacq.drift import DriftSettings  # noqa: E402
from ftacq.drift_health import BiasHealth  # noqa: E402
from ftacq.identification import identify  # noqa: E402
from ftacq.so3 import rotation_from_rotvec  # noqa: E402
from tests.fakes.pose_records import cone_orientations, example_record, poses_from_orientations  # noqa: E402
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose  # noqa: E402

RATE_HZ = 7000.0
BATCH_S = 0.1
TARE_EVERY_S = 600.0
DRIFT_N_PER_H = np.array([0.5, -0.5, 0.5])
DRIFT_NM_PER_H = np.array([0.01, -0.01, 0.01])


@dataclass
class Period:
    start_s: float
    end_s: float
    still: bool
    pose: np.ndarray
    push: tuple | None = None  # (start_s, end_s, wrench (6,), tremble: bool)


def cell_truth(thermal: bool = True) -> CellTruth:
    truth = replace(CellTruth(), drift_n_per_s=tuple(DRIFT_N_PER_H / 3600.0),
                    drift_nm_per_s=tuple(DRIFT_NM_PER_H / 3600.0))
    if thermal:
        truth = replace(truth, thermal_step_n=(0.15, -0.10, 0.20), thermal_step_nm=(0.004, -0.003, 0.002),
                        thermal_step_at_s=900.0, thermal_time_constant_s=600.0)
    return truth


def schedule(duration_s: float, rng: np.random.Generator, push_fraction: float = 0.4) -> list[Period]:
    poses = poses_from_orientations(cone_orientations(400, 40.0, seed=int(rng.integers(1 << 30))))
    periods, t, k = [], 0.0, 0
    while t < duration_s:
        still_s = rng.uniform(15.0, 45.0)
        pose = poses[k % len(poses)]
        k += 1
        push = None
        if rng.random() < push_fraction:
            start = t + rng.uniform(1.0, 5.0)
            hold = rng.uniform(1.0, 4.0)
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            moment = rng.normal(size=3)
            moment /= np.linalg.norm(moment)
            wrench = np.concatenate([direction * rng.uniform(2.0, 15.0), moment * rng.uniform(0.05, 0.5)])
            push = (start, min(start + hold + 0.3, t + still_s), wrench, bool(rng.random() < 0.5))
        periods.append(Period(t, min(t + still_s, duration_s), True, pose, push))
        t += still_s
        move_s = rng.uniform(5.0, 20.0)
        periods.append(Period(t, min(t + move_s, duration_s), False, pose))
        t += move_s
    return [p for p in periods if p.end_s > p.start_s]


def still_batches(physics: SensorPhysics, period: Period, rng: np.random.Generator):
    """Yield (t (N,), wrench (N, 6)) batches of BATCH_S over a still period: the noiseless wrench at the batch's
    first sample, the bias drift within the batch (linear), the sensor's white noise (what the simulated Net F/T
    serves, sampled directly)."""
    n_batch = int(RATE_HZ * BATCH_S)
    t0 = period.start_s
    while t0 < period.end_s - 1e-9:
        t = t0 + np.arange(n_batch) / RATE_HZ
        t = t[t < period.end_s]
        t0 += BATCH_S
        if len(t) == 0:
            return
        mean = physics.noiseless_wrench(period.pose, float(t[0]))
        drift_in_batch = physics.bias_at(float(t[-1])) - physics.bias_at(float(t[0]))
        frac = (t - t[0]) / max(t[-1] - t[0], 1e-9)
        yield t, mean + frac[:, None] * drift_in_batch + rng.standard_normal((len(t), 6)) * physics._noise_sigma


def push_wrench(push, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, 6) the push at sample times ``t`` (0.15 s ramps; trembling pushes wobble 5 %)."""
    start, end, wrench, tremble = push
    ramp = 0.15
    envelope = np.clip(np.minimum((t - start) / ramp, (end - t) / ramp), 0.0, 1.0)
    out = envelope[:, None] * wrench
    if tremble:
        frequency = 3.0 + 5.0 * ((hash(float(start)) % 1000) / 1000.0)
        out *= 1.0 + 0.05 * np.sin(2 * np.pi * frequency * t)[:, None]
    return out


class Strategy:
    """Tracks the error at rest of one way of keeping the biases (per push-free rest window)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.times: list[float] = []
        self.errors: list[np.ndarray] = []

    def record(self, time_s: float, error: np.ndarray) -> None:
        self.times.append(time_s)
        self.errors.append(error)


def run_hour(duration_s: float, seed: int, calibration, settings: DriftSettings, thermal: bool = True) -> dict:
    rng = np.random.default_rng(seed)
    truth = cell_truth(thermal)
    source = SettablePose()
    physics = SensorPhysics(truth, source, seed=seed + 1)
    health = BiasHealth(calibration, settings, auto_tare=True)
    none, periodic, tracker = Strategy("no tare"), Strategy(f"tare every {TARE_EVERY_S / 60:.0f} min"), \
        Strategy("live tracker")
    baseline = Strategy("no drift (calibration)")
    tare_offset = np.zeros(6)
    next_tare_s = TARE_EVERY_S
    absorbed = pushes_seen = contact_rejects = gate_rejects = warnings_in_push = warnings_clean = 0
    tares_done = suspended = 0
    still_rest = []  # (window start, end) of push-free windows: error measured there
    for period in schedule(duration_s, rng):
        flange_R_base = rotation_from_rotvec(period.pose[3:6]).T
        if not period.still:
            health.feed(np.array([period.start_s]), np.zeros((1, 6)), False)
            continue
        if period.push is not None:
            pushes_seen += 1
        for t, wrench in still_batches(physics, period, rng):
            in_push = False
            if period.push is not None:
                contact = push_wrench(period.push, t, rng)
                wrench += contact
                in_push = bool(np.any(np.abs(contact) > 0))
            residual = calibration.compensate(wrench, flange_R_base)
            observations_before, windows_before = health.tracker.accepted, health.observations
            was_applied = health.applied  # --auto-tare withdraws the offset while a step stands (after a push)
            notices = health.feed(t, residual, True, flange_R_base)
            for notice in notices:
                if notice.level == "WARN":
                    push = period.push
                    if push is not None and push[0] - 0.5 <= notice.time_s <= push[1] + 1.0:
                        warnings_in_push += 1
                    else:
                        warnings_clean += 1
            if in_push and health.tracker.accepted > observations_before and health.last is not None:
                w = health.last.window
                start, end = period.push[0], period.push[1]
                if w.end_s >= start and w.start_s <= end:
                    absorbed += 1
            # error at rest: push-free windows after the settle time, same windows as the tracker
            obs = health.last
            if obs is not None and health.observations > windows_before:
                w = obs.window
                push = period.push
                clear = push is None or w.end_s < push[0] - 0.05 or w.start_s > push[1] + 0.05
                if clear:
                    # the systematic error at rest: the noiseless compensated wrench at this pose and time (what a
                    # long average would show), minus what each strategy subtracts
                    true_contact_free = calibration.compensate(physics.noiseless_wrench(period.pose, w.mid_s)
                                                               - physics.contact_wrench, flange_R_base)
                    none.record(w.mid_s, true_contact_free)
                    if was_applied:
                        tracker.record(w.mid_s, true_contact_free - health.last_applied)
                    else:
                        suspended += 1
                    baseline.record(w.mid_s, calibration.compensate(
                        physics.noiseless_wrench(period.pose, 0.0) - physics.contact_wrench, flange_R_base))
                    if w.mid_s >= next_tare_s:  # the technician tares now (arm still, nobody touching)
                        # ftacq tare at one pose: the bias seen there over a 0.5 s average (this window)
                        estimate = estimate_biases(calibration, flange_R_base[None],  # noisy, as measured
                                                   (w.mean + calibration.predict(flange_R_base[None])[0])[None],
                                                   std=w.std[None], count=np.array([w.count]))
                        tare_offset = estimate.change
                        next_tare_s += TARE_EVERY_S
                        tares_done += 1
                    periodic.record(w.mid_s, true_contact_free - tare_offset)
                    still_rest.append(w.mid_s)
    contact_rejects, gate_rejects = health.tracker.rejected_contact, health.tracker.rejected_gate
    return {"strategies": (none, periodic, tracker, baseline), "absorbed": absorbed, "pushes": pushes_seen,
            "contact_rejects": contact_rejects, "gate_rejects": gate_rejects, "accepted": health.tracker.accepted,
            "warnings_in_push": warnings_in_push, "warnings_clean": warnings_clean, "tares": tares_done,
            "suspended": suspended,
            "final_offset": health.tracker.offset(), "true_change": physics.bias_at(duration_s) - physics._bias}


def run_swaps(count: int, seed: int, calibration, settings: DriftSettings) -> tuple[list[float], list[float]]:
    """Per trial: a few still/move periods, then a tool swap during a move; return seconds from the next
    stillness to the warning and to the notice calling it a step (inf when none within that still period)."""
    rng = np.random.default_rng(seed)
    truth = cell_truth()
    out, steps = [], []
    for trial in range(count):
        source = SettablePose()
        physics = SensorPhysics(truth, source, seed=seed + 100 + trial)
        health = BiasHealth(calibration, settings, auto_tare=True)
        periods = schedule(240.0, rng, push_fraction=0.0)
        swapped_at = None
        still_after_swap = None
        warned = stepped = None
        for period in periods:
            flange_R_base = rotation_from_rotvec(period.pose[3:6]).T
            if not period.still:
                health.feed(np.array([period.start_s]), np.zeros((1, 6)), False)
                if swapped_at is None and period.start_s > 120.0:
                    mass = truth.mass_kg * rng.uniform(0.6, 1.4)
                    com = np.array(truth.center_of_mass_m) + rng.normal(scale=0.02, size=3)
                    physics.set_tool(mass, com)
                    swapped_at = period.start_s
                continue
            if swapped_at is not None and still_after_swap is None:
                still_after_swap = period.start_s
            for t, wrench in still_batches(physics, period, rng):
                notices = health.feed(t, calibration.compensate(wrench, flange_R_base), True, flange_R_base)
                if still_after_swap is not None and warned is None and any(n.level == "WARN" for n in notices):
                    warned = next(n.time_s for n in notices if n.level == "WARN")
                if still_after_swap is not None and any("a step, not drift" in n.text for n in notices):
                    stepped = next(n.time_s for n in notices if "a step, not drift" in n.text)
                    break
            if stepped is not None or still_after_swap is not None:
                break
        out.append(float("inf") if warned is None else warned - still_after_swap)
        steps.append(float("inf") if stepped is None else stepped - still_after_swap)
    return out, steps


RATE_ROWS = (("force", 1.0), ("force", 10.0), ("force", 30.0), ("force", 60.0), ("torque", 0.5), ("torque", 2.0))
"""The drift-rate table's rows: channel group and rate (N/h or N·m/h) on each of its three channels (+, −, +)."""
WARMUP_TAU_S = 600.0
STEP_CASE = (np.array([0.5, 0.0, -0.3, 0.0, 0.0, 0.0]), 10.0)
"""The step case: this bias step (N, N·m), half-way through, on a warm-up starting at this rate (N/h)."""


def drift_truth(group: str, rate_per_h: float, shape: str) -> CellTruth:
    """The cell with drift on one group of channels: a linear ramp at ``rate_per_h``, or a warm-up A (1 − e^(−t/τ))
    starting at that rate (A = rate × τ)."""
    zero, signs = (0.0, 0.0, 0.0), np.array([1.0, -1.0, 1.0])
    rate = tuple(float(v) for v in signs * rate_per_h / 3600.0)
    if shape == "ramp":
        return replace(CellTruth(), drift_n_per_s=rate if group == "force" else zero,
                       drift_nm_per_s=rate if group == "torque" else zero)
    amplitude = tuple(float(v) * WARMUP_TAU_S for v in rate)
    return replace(CellTruth(), thermal_step_n=amplitude if group == "force" else zero,
                   thermal_step_nm=amplitude if group == "torque" else zero, thermal_step_at_s=0.0,
                   thermal_time_constant_s=WARMUP_TAU_S)


def run_rate(duration_s: float, seed: int, calibration, settings: DriftSettings, truth: CellTruth,
             group: str, step: np.ndarray | None = None) -> dict:
    """Drive the live tracker (with --auto-tare, biases of unknown age) through a push-free schedule on ``truth``;
    per rest window after the first still period: (offset − true offset) / the tracker's printed 1σ on the group's
    channels (``ratios``), and the calibration's own model error at the window's orientation (the noiseless
    compensated wrench minus the true offset) over the model 1σ the tracker uses there (``model_ratios``). ``step``
    is added to the biases half-way through (during a move or a still period, as it falls)."""
    rng = np.random.default_rng(seed)
    physics = SensorPhysics(truth, SettablePose(), seed=seed + 1)
    health = BiasHealth(calibration, settings, age_s=3600.0, auto_tare=True)
    file_bias = np.concatenate([calibration.force_bias, calibration.torque_bias])
    channels = slice(0, 3) if group == "force" else slice(3, 6)
    ratios, errors, model_ratios, gated, windows, notices = [], [], [], 0, 0, []
    first_still_end = None
    stepped = False
    for period in schedule(duration_s, rng, push_fraction=0.0):
        flange_R_base = rotation_from_rotvec(period.pose[3:6]).T
        if step is not None and not stepped and period.start_s >= duration_s / 2:
            physics._bias = physics._bias + step
            stepped = True
        if not period.still:
            health.feed(np.array([period.start_s]), np.zeros((1, 6)), False)
            continue
        first_still_end = period.end_s if first_still_end is None else first_still_end
        for t, wrench in still_batches(physics, period, rng):
            before = health.observations
            notices += health.feed(t, calibration.compensate(wrench, flange_R_base), True, flange_R_base)
            if health.observations == before or health.last is None:
                continue
            window = health.last.window
            windows += 1
            gated += int(health.last.reason.startswith("gate"))
            if window.mid_s <= first_still_end:
                continue
            true_offset = physics.bias_at(window.mid_s) - file_bias
            error = health.tracker.offset(window.mid_s) - true_offset
            errors.append(error[channels])
            ratios.append(error[channels] / health.tracker.sigma(window.mid_s)[channels])
            model_error = calibration.compensate(physics.noiseless_wrench(period.pose, window.mid_s)
                                                 - physics.contact_wrench, flange_R_base) - true_offset
            model_ratios.append(model_error[channels] / health.tracker.model_sigma(flange_R_base)[channels])
    ratios_a = np.abs(np.array(ratios))
    return {"ratios": np.array(ratios), "model_ratios": np.array(model_ratios),
            "max": float(ratios_a.max()), "rms": float(np.sqrt(np.mean(ratios_a**2))),
            "beyond3": float(np.mean(ratios_a > 3.0) * 100), "gated": gated / max(windows, 1) * 100,
            "windows": windows, "reacquired": health.tracker.reacquired,
            "steps": sum("a step, not drift" in n.text for n in notices),
            "suspended": sum("auto-tare suspended" in n.text for n in notices),
            "max_error": float(np.abs(np.array(errors)).max()),
            "change": float(np.abs(physics.bias_at(duration_s) - physics.bias_at(0.0))[channels].max())}


def calibrate(seed: int, samples_per_pose: int) -> Calibration:
    """The calibration identified from the simulated 48-pose record of ``seed`` (``samples_per_pose`` per pose)."""
    return identify(example_record(seed=seed, samples_per_pose=samples_per_pose), mount="floor").calibration


def report_rates(minutes: float, seeds: list[int], settings: DriftSettings, samples_per_pose: int) -> None:
    """Print the drift-rate table (one row per rate and shape; with several seeds, each seed its own calibration
    and schedule, the figures pooled over them) and the step case (first seed)."""
    calibrations = {seed: calibrate(seed, samples_per_pose) for seed in seeds}
    print("")
    print(f"== drift rates: {minutes:g} simulated min each, push-free, --auto-tare, biases of unknown age, seed"
          + (f"s {seeds[0]}-{seeds[-1]} (a calibration and a schedule each; pooled)" if len(seeds) > 1
             else f" {seeds[0]}")
          + "; error = tracked offset − true offset, per rest window after the first still period, in the "
          "tracker's printed 1σ (the group's three channels); cal e/σ: the calibration's own model error at the "
          "windows' orientations over its model 1σ, RMS per channel")
    print(f"  {'drift':>16} {'shape':>8} {'change':>11} {'max e/σ':>8} {'RMS e/σ':>8} {'> 3σ':>7} {'> 3σ per ch':>12} "
          f"{'gated':>7} {'windows':>8} {'re-acq':>6} {'steps':>5} {'max |e|':>10} {'cal e/σ':>16}"
          + ("  per-seed RMS e/σ" if len(seeds) > 1 else ""))
    for group, rate in RATE_ROWS:
        unit = "N" if group == "force" else "N·m"
        for shape in ("ramp", "warm-up"):
            rows = [run_rate(minutes * 60.0, seed, calibrations[seed], settings, drift_truth(group, rate, shape),
                             group) for seed in seeds]
            ratios = np.abs(np.concatenate([row["ratios"] for row in rows]))
            model = np.concatenate([row["model_ratios"] for row in rows])
            windows = sum(row["windows"] for row in rows)
            gated = sum(row["gated"] * row["windows"] for row in rows) / max(windows, 1)
            per_seed = [row["rms"] for row in rows]
            print(f"  {rate:>9g} {unit + '/h':>6} {shape:>8} {rows[0]['change']:>7.3g} {unit:<3} "
                  f"{ratios.max():>8.2f} {np.sqrt(np.mean(ratios**2)):>8.2f} {np.mean(ratios > 3.0) * 100:>6.2f}% "
                  f"{' '.join(f'{v:d}' for v in (ratios > 3.0).sum(axis=0)):>12} {gated:>6.2f}% {windows:>8d} "
                  f"{sum(row['reacquired'] for row in rows):>6d} {sum(row['steps'] for row in rows):>5d} "
                  f"{max(row['max_error'] for row in rows) * 1e3:>7.2f} m{unit} "
                  f"{' '.join(f'{v:.2f}' for v in np.sqrt(np.mean(model**2, axis=0))):>16}"
                  + (f"  {min(per_seed):.2f}-{max(per_seed):.2f}" if len(seeds) > 1 else ""), flush=True)
    size, rate = STEP_CASE
    row = run_rate(minutes * 60.0, seeds[0], calibrations[seeds[0]], settings,
                   drift_truth("force", rate, "warm-up"), "force", step=size)
    print(f"  step case: warm-up from {rate:g} N/h and a bias step of {size[:3].tolist()} N half-way: called a step "
          f"{row['steps']} time(s), re-acquired {row['reacquired']}, auto-tare suspended {row['suspended']} time(s), "
          f"{row['gated']:.1f} % of {row['windows']} rest windows gated (every one after the step: tare)")


def report(result: dict, minutes: float, sigma_bias: np.ndarray, thermal: bool) -> None:
    """Print one scenario's table and counts."""
    print("")
    print(f"== drift {DRIFT_N_PER_H.tolist()} N/h" + (" + thermal step (0.15, -0.10, 0.20) N, τ 10 min, from "
                                                      "15 min" if thermal else " (linear only)")
          + "; true change over the run " + " ".join(f"{v:+.4f}" for v in result["true_change"][:3]) + " N")
    print("compensated force error at rest (systematic: noiseless compensated wrench minus the correction), max |e| "
          "over the push-free rest windows of each 5 min [mN] (in calibration force-bias 1σ)")
    print(f"  {'minutes':>9}" + "".join(f" {s.name:>24}" for s in result["strategies"]))
    bins = np.arange(0.0, minutes * 60.0 + 1e-9, 300.0)
    for a, b in zip(bins[:-1], bins[1:]):
        cells = []
        for strategy in result["strategies"]:
            times = np.array(strategy.times)
            errors = np.array(strategy.errors)[:, :3] if strategy.errors else np.zeros((0, 3))
            sel = (times >= a) & (times < b)
            if not sel.any():
                cells.append(f"{'-':>24}")
                continue
            worst = np.abs(errors[sel]).max()
            worst_sigma = (np.abs(errors[sel]) / sigma_bias).max()
            cells.append(f"{worst * 1000:>14.2f} ({worst_sigma:5.1f}σ)")
        print(f"  {a / 60:4.0f}-{b / 60:<4.0f}" + "".join(f" {c}" for c in cells))
    for strategy in result["strategies"]:
        errors = np.abs(np.array(strategy.errors)[:, :3]) / sigma_bias
        within = float(np.mean(np.all(errors <= 3.0, axis=1)) * 100)
        rms = np.sqrt(np.mean(np.array(strategy.errors)[:, :3] ** 2)) * 1000
        print(f"  {strategy.name:>22}: max {errors.max():6.1f}σ, p95 {np.percentile(errors.max(axis=1), 95):5.1f}σ, "
              f"RMS {rms:6.2f} mN, {within:5.1f} % of {len(errors)} rest windows within 3σ")
    print(f"  pushes: {result['pushes']} held while still; rest windows overlapping a push absorbed by the tracker: "
          f"{result['absorbed']}; windows rejected as contact {result['contact_rejects']}, by the innovation gate "
          f"{result['gate_rejects']}, accepted {result['accepted']}")
    print(f"  at-rest warnings: {result['warnings_in_push']} during pushes (held > 1 s), {result['warnings_clean']} "
          f"with nothing touching the tool; periodic tares done: {result['tares']}; push-free rest windows while "
          f"--auto-tare was suspended (a steady push called a step, until the next window on the track; left out of "
          f"the live tracker's column): {result['suspended']}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--swaps", type=int, default=10)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rate-walk", type=float, default=None, help="override DriftSettings.rate_walk_per_h (force)")
    parser.add_argument("--rate-minutes", type=float, default=30.0,
                        help="simulated minutes per row of the drift-rate table (0: skip it)")
    parser.add_argument("--rates-only", action="store_true", help="print only the drift-rate table")
    parser.add_argument("--samples-per-pose", type=int, default=500,
                        help="samples averaged per pose of the calibration's record (a default run: 0.5 s at 7 kHz = 3500)")
    parser.add_argument("--seeds", type=int, default=1,
                        help="drift-rate table over this many seeds from --seed on (a calibration and schedule each)")
    args = parser.parse_args()
    started = time.perf_counter()
    calibration = calibrate(args.seed, args.samples_per_pose)
    settings = DriftSettings()
    if args.rate_walk is not None:
        settings = replace(settings, rate_walk_per_h=(args.rate_walk,) * 3 + (args.rate_walk * 0.03,) * 3)
    sigma_bias = np.asarray(calibration.uncertainty["force_bias"])
    print(f"bias drift benchmark: {args.minutes:g} simulated minutes at {RATE_HZ:.0f} Hz (time-scaled, tracker fed "
          f"with simulated batches), calibration force-bias 1σ "
          + " ".join(f"{v * 1000:.2f}" for v in sigma_bias) + " mN")
    if args.rate_minutes > 0:
        report_rates(args.rate_minutes, list(range(args.seed, args.seed + args.seeds)), settings,
                     args.samples_per_pose)
    if args.rates_only:
        print(f"wall time {time.perf_counter() - started:.1f} s")
        return 0
    for thermal in (False, True):
        result = run_hour(args.minutes * 60.0, args.seed, calibration, settings, thermal)
        report(result, args.minutes, sigma_bias, thermal)
    if args.swaps:
        delays, steps = run_swaps(args.swaps, args.seed + 7, calibration, settings)
        finite = [d for d in delays if np.isfinite(d)]
        called = [d for d in steps if np.isfinite(d)]
        print("")
        print(f"tool swaps: {len(finite)}/{len(delays)} flagged; time from the next stillness to the warning: "
              + (f"median {np.median(finite):.2f} s, max {max(finite):.2f} s" if finite else "never")
              + f"; {len(called)}/{len(steps)} called a step, "
              + (f"median {np.median(called):.2f} s, max {max(called):.2f} s after the stillness" if called else ""))
    print(f"wall time {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
