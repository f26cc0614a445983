"""Benchmark: identification accuracy with the robot's orientation error modelled or not, side by side.

    .venv/bin/python benchmarks/identify_accuracy.py            # 20 seeds per case
    .venv/bin/python benchmarks/identify_accuracy.py --quick    # 5 seeds per case

Simulated pose records (tests/fakes/pose_records.py: 500 samples per pose, the default sensor noise) for a light
tool on a floor, a 15 kg tool on a ceiling (24 special + 24 cone poses) and an 8 kg tool on a wall (40 cone poses
only), with the flange orientation the record reports off by 0, 0.01 or 0.03° (1σ per axis; the wrench follows
the true orientation). Each record is identified twice: ``identify()`` (full 6×6 noise model when the residuals
show an orientation error, pose_error.py) and ``identify(orientation_error=False)`` (independent channels).
Printed per case, mean over seeds: the worst compensation error over 150 random orientations (|F| N, |T| N·m),
the RMS error of force bias and centre of mass, the largest z RMS over the 15 parameters (error / reported 1σ;
1 when the 1σ is honest) and the estimated σ_θ.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from ftacq.identification import identify  # noqa: E402
from tests.fakes.pose_records import (  # noqa: E402
    cone_orientations,
    gravity_down_base_R_flange,
    random_orientations,
    simulate_record,
    special_orientations,
)
from tests.fakes.world import CellTruth  # noqa: E402

VALIDATION = random_orientations(150, seed=999)


def special_and_cone(truth: CellTruth, seed: int) -> np.ndarray:
    hanging = gravity_down_base_R_flange(truth.gravity_base)
    return np.concatenate([special_orientations(0.2, seed), cone_orientations(24, 40.0, seed + 7, axis_base_R_flange=hanging)])


def cone_only(truth: CellTruth, seed: int) -> np.ndarray:
    return cone_orientations(40, 40.0, seed + 100, axis_base_R_flange=gravity_down_base_R_flange(truth.gravity_base))


CASES = (
    ("1.35 kg, floor, A+E", CellTruth(), special_and_cone),
    ("15 kg, ceiling, A+E", replace(CellTruth(), mass_kg=15.0, base_tilt_deg=(-0.3, 179.6)), special_and_cone),
    ("8 kg, wall, cone only", replace(CellTruth(), mass_kg=8.0, base_tilt_deg=(0.5, 90.3),
                                      center_of_mass_m=(0.01, -0.02, 0.12)), cone_only),
)


def parameters(calibration) -> np.ndarray:
    return np.concatenate([calibration.gravity_base, calibration.force_bias, calibration.center_of_mass,
                           calibration.torque_bias])


def sigmas(calibration) -> np.ndarray:
    u = calibration.uncertainty
    return np.concatenate([u["gravity_base"], u["force_bias"], u["center_of_mass_m"], u["torque_bias"]])


def figures(truth: CellTruth, rotations_for, error_deg: float, seeds: int, full: bool) -> dict:
    true = truth.calibration()
    worst, bias, com, z, sigma_deg = [], [], [], [], []
    for seed in range(seeds):
        record = simulate_record(truth, rotations_for(truth, seed), seed=seed, orientation_error_deg=error_deg)
        calibration = identify(record, orientation_error=full).calibration
        error = calibration.predict(VALIDATION) - true.predict(VALIDATION)
        worst.append([np.linalg.norm(error[:, :3], axis=1).max(), np.linalg.norm(error[:, 3:], axis=1).max()])
        bias.append(np.linalg.norm(calibration.force_bias - true.force_bias))
        com.append(np.linalg.norm(calibration.center_of_mass - true.center_of_mass))
        z.append((parameters(calibration) - parameters(true)) / sigmas(calibration))
        sigma_deg.append(calibration.metadata["noise"]["orientation_error_deg"])
    return {"worst": np.mean(worst, axis=0), "bias": float(np.sqrt(np.mean(np.square(bias)))),
            "com": float(np.sqrt(np.mean(np.square(com)))),
            "z": float(np.sqrt(np.mean(np.square(z), axis=0)).max()), "sigma_deg": float(np.median(sigma_deg))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5 seeds per case instead of 20")
    args = parser.parse_args()
    seeds = 5 if args.quick else 20
    print(f"{'case':<24} {'pose err':>8}  {'model':<9} {'max|F| N':>9} {'max|T| N·m':>10} {'|ΔF0| N':>8} "
          f"{'|Δc| mm':>8} {'max zRMS':>8} {'σθ est.':>8}")
    for name, truth, rotations_for in CASES:
        for error_deg in (0.0, 0.01, 0.03):
            for full in (True, False):
                f = figures(truth, rotations_for, error_deg, seeds, full)
                print(f"{name:<24} {error_deg:>7.2f}°  {'full' if full else 'channels':<9} {f['worst'][0]:>9.4f} "
                      f"{f['worst'][1]:>10.5f} {f['bias']:>8.4f} {1e3 * f['com']:>8.3f} {f['z']:>8.2f} "
                      f"{f['sigma_deg']:>7.4f}°", flush=True)
    print(f"({seeds} seeds per row; max|F|, max|T|: worst compensation error over 150 random orientations, mean over "
          "seeds; ΔF0, Δc: RMS error of force bias and centre of mass; zRMS: error / reported 1σ, worst parameter)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
