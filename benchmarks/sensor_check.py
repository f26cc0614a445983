"""Benchmark: the sensor check's detection power, false alarms and honesty of its 1σ (issue 41).

    .venv/bin/python benchmarks/sensor_check.py            # 20 seeds per case
    .venv/bin/python benchmarks/sensor_check.py --quick    # 5 seeds per case
    .venv/bin/python benchmarks/sensor_check.py --healthy 50   # false alarms only, 50 seeds

Offline: pose records synthesised as the default pose set measures them (tests/fakes/pose_records.py: the 24
special orientations as reached to ±0.2° and 24 poses in a 40° cone, each a mean of 500 samples at the simulated
sensor's noise, 1.35 kg tool), the robot's orientation error 0 or 0.02° (1σ per axis), identified with
``identify(sensor_check=True)`` without and with a reference weight (the true mass ± 1 g). Printed:

- the false-alarm rate on a healthy sensor: the sensor line not PASS, and the check "significant" (p < 0.001);
- the honesty of C's 1σ: over every run, |error| / σ of each of C's 6 entries (RMS; share within 3σ);
- detection power: the share of runs in which a single force axis's gain error (+e on Fx, Fy or Fz), a one-way
  cross-talk (e of one axis on another) or, with a reference, a gain error of all three axes alike, shows in its
  figure at ≥ 3σ; and the smallest e of those tried detected in ≥ 95 % of runs.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
from scipy.linalg import sqrtm  # noqa: E402

from ftacq.channels import FORCE_AXES as AXES  # noqa: E402
from ftacq.identification import identify  # noqa: E402
from ftacq.identification.sensor_gain import ReferenceWeight  # noqa: E402
from ftacq.verdict import PASS, identification_findings  # noqa: E402
from tests.fakes.pose_records import cone_orientations, simulate_record, special_orientations  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

SIZES = (0.001, 0.002, 0.003, 0.005)
"""Errors tried (fractions)."""
UNIFORM_SIZES = (0.005, 0.0075, 0.01)
"""... for a gain error of all three axes alike (only a reference weight sees it; its σ includes local gravity's)."""
PAIRS = ((0, 1), (0, 2), (1, 2))


def record_of(truth: CellTruth, seed: int, orientation_error_deg: float):
    rotations = np.concatenate([special_orientations(0.2, seed), cone_orientations(24, 40.0, seed + 1)])
    return simulate_record(truth, rotations, seed=seed, orientation_error_deg=orientation_error_deg)


def run(error: np.ndarray, seed: int, reference: bool, orientation_error_deg: float) -> tuple[dict, str, np.ndarray]:
    """Identify one record; return the check, the sensor line's status and the expected C."""
    truth = replace(CellTruth(), sensor_gain_error=tuple(map(tuple, error)))
    weight = ReferenceWeight(truth.mass_kg, 0.001) if reference else None
    result = identify(record_of(truth, seed, orientation_error_deg), sensor_check=True, reference=weight)
    check = result.calibration.metadata["sensor_check"]
    status = {f.check: f for f in identification_findings(result)}["sensor"].status
    gain = np.eye(3) + error[:3, :3]
    polar = np.real(sqrtm(gain @ gain.T))
    return check, status, polar if reference else 3.0 * polar / np.trace(polar)


def entries(matrix) -> np.ndarray:
    m = np.asarray(matrix, dtype=float)
    return np.array([m[0, 0], m[1, 1], m[2, 2], m[0, 1], m[0, 2], m[1, 2]])


def gain_z(check: dict, axis: int, reference: bool) -> float:
    """|figure| / σ of a gain error on ``axis``: its largest ratio to another axis, or its gain (reference)."""
    gain, cov = np.asarray(check["force_gain"]), np.asarray(check["force_gain_covariance"])
    out = abs(gain[axis, axis] - 1.0) / np.sqrt(cov[axis, axis]) if reference else 0.0
    for other in range(3):
        if other != axis:
            var = cov[axis, axis] + cov[other, other] - 2 * cov[axis, other]
            out = max(out, abs(gain[axis, axis] - gain[other, other]) / np.sqrt(var))
    return out


def crosstalk_z(check: dict, pair: tuple[int, int]) -> float:
    gain, cov = np.asarray(check["force_gain"]), np.asarray(check["force_gain_covariance"])
    index = 3 + PAIRS.index(pair)
    return abs(gain[pair]) / np.sqrt(cov[index, index])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="5 seeds per case instead of 20")
    parser.add_argument("--healthy", type=int, metavar="SEEDS",
                        help="only the healthy sensor (false alarms, 1σ), over this many seeds")
    args = parser.parse_args()
    seeds = range(args.healthy or (5 if args.quick else 20))
    start = time.perf_counter()
    for orientation_deg in (0.0, 0.02):
        for reference in (False, True):
            label = f"robot orientation error {orientation_deg:g}°, {'with' if reference else 'without'} a reference"
            alarms, significant, z_all = 0, 0, []
            for seed in seeds:
                check, status, expected = run(np.zeros((6, 6)), seed, reference, orientation_deg)
                alarms += status != PASS
                significant += bool(check["significant"])
                z_all.append((entries(check["force_gain"]) - entries(expected))
                             / np.sqrt(np.diag(np.asarray(check["force_gain_covariance"]))))
            lines = [f"{label}: healthy sensor: sensor line not PASS in {alarms}/{len(seeds)}, check significant "
                     f"in {significant}/{len(seeds)}"]
            detected: dict[str, list[float]] = {}
            for size in () if args.healthy else SIZES:
                for axis in range(3):
                    error = np.zeros((6, 6))
                    error[axis, axis] = size
                    shares = []
                    for seed in seeds:
                        check, _, expected = run(error, seed, reference, orientation_deg)
                        shares.append(gain_z(check, axis, reference) >= 3.0)
                        z_all.append((entries(check["force_gain"]) - entries(expected))
                                     / np.sqrt(np.diag(np.asarray(check["force_gain_covariance"]))))
                    detected.setdefault(f"{AXES[axis]} gain", []).append(float(np.mean(shares)))
                for pair in PAIRS:
                    error = np.zeros((6, 6))
                    error[pair[1], pair[0]] = size  # one way: size × the first axis appears on the second
                    shares = [crosstalk_z(run(error, seed, reference, orientation_deg)[0], pair) >= 3.0
                              for seed in seeds]
                    detected.setdefault(f"{AXES[pair[0]]}→{AXES[pair[1]]} cross-talk", []).append(
                        float(np.mean(shares)))
            sizes = {name: SIZES for name in detected}
            if reference and not args.healthy:
                for size in UNIFORM_SIZES:
                    error = np.zeros((6, 6))
                    error[0, 0] = error[1, 1] = error[2, 2] = size
                    shares = [gain_z(run(error, seed, True, orientation_deg)[0], 2, True) >= 3.0 for seed in seeds]
                    detected.setdefault("all three gains alike", []).append(float(np.mean(shares)))
                sizes["all three gains alike"] = UNIFORM_SIZES
            for name, shares in detected.items():
                smallest = next((f"{100 * s:g} %" for s, share in zip(sizes[name], shares) if share >= 0.95),
                                f"> {100 * sizes[name][-1]:g} %")
                lines.append(f"  {name:<26} detected at ≥3σ in " + ", ".join(
                    f"{100 * s:g} %: {100 * share:.0f} %" for s, share in zip(sizes[name], shares))
                    + f"; smallest detected in ≥ 95 %: {smallest}")
            z = np.concatenate(z_all)
            lines.append(f"  C's 1σ: |error|/σ RMS {np.sqrt(np.mean(z ** 2)):.2f}, within 3σ {100 * np.mean(np.abs(z) <= 3):.1f} "
                         f"% of {z.size} entries")
            print("\n".join(lines), flush=True)
    print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
