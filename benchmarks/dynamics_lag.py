"""Benchmark: ``calibrate --dynamic``'s inertia and the live compensation with the arm behind its target (issue 37).

    .venv/bin/python benchmarks/dynamics_lag.py [--seeds 3] [--lags-ms 0,4,8] [--moves 10] [--robot-rate-hz 125]

Each run synthesises the excitation ``--dynamic`` plans (procedures/excitation.py at CELL.toml's defaults,
0.5 rad/s and 1 rad/s², 10 moveJs) as the simulated cell records it (tests/fakes/lagging_motion.py: the physical
arm ``lag`` behind its target, a 4.2 kg tool, 7 kHz samples whose noise grows with the arm's speed, 1 ms
transport lag, 1e-6 rad encoder jitter), offline: a record takes seconds, not its duration in real time. The
static calibration it starts from is the truth with its mass and centre of mass drawn off by their stated 1σ
(2e-4 kg, 2e-5 m). Per run:

- the servo lag and the sensor's lag as identified (truth: ``lag``, 1 ms);
- the inertia's error (Frobenius, % of the true inertia) and that of an efficient estimator on the same motion
  (weighted least squares with the true kinematics, lag, noise level per sample, mass, centre of mass and biases:
  what no real identification knows; the rows straddling a step of q̈ left out, as ftacq does);
- max over the six elements of |error| / 1σ;
- the live compensation (procedures/dynamic_compensation.py fed the recording as the monitor reads it, with the
  true inertia and the identified lags): RMS of the compensated wrench over the motion / RMS of the sensor noise,
  force and torque.

Goals (issue 37): error ≤ 2× the efficient estimator's, |error|/σ ≤ 3, live ≤ 1.5× the noise, at lags of 2-8 ms.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftacq.dynamics import identify_dynamics  # noqa: E402
from ftacq.dynamics.identify import _steiner, _vech_to_matrix, acceleration_steps  # noqa: E402
from ftacq.dynamics.model import SensorDynamics, gravity_vector, inertial_parameters  # noqa: E402
from ftacq.dynamics.timing import box_average  # noqa: E402
from ftacq.kinematics import ur_model  # noqa: E402
from procedures.excitation import plan_excitation  # noqa: E402
from procedures.plan import PlanSettings, home_configuration_rad  # noqa: E402
from tests.fakes.lagging_motion import chain_of_moves, heavy_truth, record_excitation_offline, replay_live  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

MODEL = ur_model("UR5e")
MASS_SIGMA_KG, COM_SIGMA_M = 2e-4, 2e-5


def efficient_inertia(truth: CellTruth, recording) -> np.ndarray:
    """The inertia by weighted least squares with everything but the inertia known (see the module docstring)."""
    calibration = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))
    dynamics = SensorDynamics.for_calibration(MODEL, calibration)
    regressor = dynamics.regressor(recording.physical_q, recording.physical_qd, recording.physical_qdd,
                                   gravity_vector(calibration))
    record = recording.record
    mean, count = box_average(record.sensor_time_s, record.wrench, record.robot_time_s + recording.transport_lag_s,
                              record.robot_period_s)
    keep = (count > 0) & ~acceleration_steps(recording.physical_qdd)
    parameters = inertial_parameters(truth.mass_kg, truth.center_of_mass_m, truth.inertia)
    bias = np.array(truth.force_bias_n + truth.torque_bias_nm)
    target = mean[keep] - bias - regressor[keep][:, :, :4] @ parameters[:4]
    speed = np.linalg.norm(recording.physical_qd[keep], axis=1)
    sigma = (np.array(truth.force_noise_n + truth.torque_noise_nm)[None, :]
             * (1.0 + truth.motion_noise_gain * speed)[:, None] / np.sqrt(count[keep])[:, None])
    design = (regressor[keep][:, :, 4:] / sigma[:, :, None]).reshape(-1, 6)
    solution, *_ = np.linalg.lstsq(design, (target / sigma).reshape(-1), rcond=None)
    return _vech_to_matrix(solution) - _steiner(truth.mass_kg, np.array(truth.center_of_mass_m))


def run(seed: int, lag_s: float, moves: int, robot_rate_hz: float = 500.0) -> dict:
    truth = heavy_truth()
    settings = PlanSettings(joint_speed_rad_s=0.5, joint_acceleration_rad_s2=1.0)
    start = home_configuration_rad("floor")
    plan = plan_excitation(settings, start, moves=moves, seed=seed)
    chain = chain_of_moves(MODEL, start, plan.targets_rad, settings.joint_speed_rad_s,
                           settings.joint_acceleration_rad_s2)
    recording = record_excitation_offline(truth, MODEL, chain, servo_lag_s=lag_s, seed=seed,
                                          robot_rate_hz=robot_rate_hz)
    rng = np.random.default_rng(1000 + seed)
    static = replace(truth.calibration(), sensor_offset=np.array(truth.sensor_offset_m))
    mass = truth.mass_kg + rng.normal(0.0, MASS_SIGMA_KG)
    static = replace(static, gravity_base=static.gravity_base * mass / truth.mass_kg,
                     center_of_mass=np.array(truth.center_of_mass_m) + rng.normal(0.0, COM_SIGMA_M, 3),
                     uncertainty={"mass_kg": MASS_SIGMA_KG, "center_of_mass_m": [COM_SIGMA_M] * 3})
    started = time.perf_counter()
    result = identify_dynamics(static, recording.record, MODEL)
    identify_s = time.perf_counter() - started
    norm = np.linalg.norm(truth.inertia)
    upper = np.triu_indices(3)
    normalised = np.abs(result.inertia - truth.inertia)[upper] / result.inertia_sigma[upper]
    efficient = efficient_inertia(truth, recording)
    live = replay_live(recording, replace(static, inertia=truth.inertia), result.servo_lag_s or 0.0, result.lag_s)
    used = np.isfinite(live[:, 0])
    rms = np.sqrt(np.mean(live[used] ** 2, axis=0))
    floor = np.sqrt(np.mean(recording.sensor_noise[used] ** 2, axis=0))
    return {"seed": seed, "lag_ms": 1e3 * lag_s, "servo_ms": 1e3 * (result.servo_lag_s or 0.0),
            "sensor_ms": 1e3 * result.lag_s, "error_pct": 100 * np.linalg.norm(result.inertia - truth.inertia) / norm,
            "efficient_pct": 100 * np.linalg.norm(efficient - truth.inertia) / norm, "z_max": float(normalised.max()),
            "live_f": float(np.linalg.norm(rms[:3]) / np.linalg.norm(floor[:3])),
            "live_t": float(np.linalg.norm(rms[3:]) / np.linalg.norm(floor[3:])), "identify_s": identify_s,
            "motion_s": float(np.ptp(recording.record.robot_time_s))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--lags-ms", default="0,4,8")
    parser.add_argument("--moves", type=int, default=10)
    parser.add_argument("--robot-rate-hz", type=float, default=500.0, help="robot states per s (125: a CB3)")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; robot states at {args.robot_rate_hz:g} Hz",
          flush=True)
    print("lag ms | seed | servo ms | sensor ms | inertia err % | efficient % | |err|/σ max | live F/noise | "
          "live T/noise | identify s", flush=True)
    rows = []
    for lag_ms in (float(v) for v in args.lags_ms.split(",")):
        for seed in range(args.seeds):
            r = run(seed, lag_ms / 1e3, args.moves, args.robot_rate_hz)
            rows.append(r)
            print(f"{r['lag_ms']:6.1f} | {seed:4d} | {r['servo_ms']:8.3f} | {r['sensor_ms']:9.3f} | "
                  f"{r['error_pct']:13.3f} | {r['efficient_pct']:11.3f} | {r['z_max']:11.2f} | {r['live_f']:12.2f} | "
                  f"{r['live_t']:12.2f} | {r['identify_s']:10.1f}", flush=True)
    errors = np.array([r["error_pct"] for r in rows])
    efficient = np.array([r["efficient_pct"] for r in rows])
    print(f"RMS inertia error {np.sqrt(np.mean(errors ** 2)):.3f} % vs efficient {np.sqrt(np.mean(efficient ** 2)):.3f} % "
          f"(ratio {np.sqrt(np.mean(errors ** 2) / np.mean(efficient ** 2)):.2f}); max |err|/σ "
          f"{max(r['z_max'] for r in rows):.2f}; live max F {max(r['live_f'] for r in rows):.2f}, "
          f"T {max(r['live_t'] for r in rows):.2f} × noise; load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
