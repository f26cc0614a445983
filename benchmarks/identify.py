"""Benchmark the calibration core: identification time and compensation throughput / latency.

Prints (targets in brackets):
- identify (incl. robust refinement) on 48 poses [≤ 50 ms], 1 000 and 100 000 poses;
- identify on 10 000 real-like poses (heavy-tailed noise, no std/count, orientation error, an unmodelled force)
  [≤ 5 s], with its convergence;
- held-out error against an independent plain least-squares fit of the same model (scipy.optimize.least_squares,
  each channel weighted by its residual RMS) on the same splits, for 6 to 10⁴ synthetic poses [ratio ≤ 1.10] and,
  with ``--yumi FOLDER``, on the real ABB YuMi recording (gravitylog.csv + flange_pose.csv; torques in N·mm);
- batch compensation, one flange orientation per sample (N readings × N orientations) [≥ 20 M samples/s];
- batch compensation, one orientation for the whole batch;
- single-sample compensation latency, ``Calibration.compensate_sample`` and ``compensate`` [≤ 10 µs].

Usage: ``python benchmarks/identify.py [--quick] [--yumi FOLDER]`` (quick: fewer repetitions, smaller batches,
fewer splits).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from scipy.optimize import least_squares  # noqa: E402

from ftacq.identification import identify  # noqa: E402
from ftacq.identification.refine import ModelParameters, predict  # noqa: E402
from ftacq.posefile import PoseRecord  # noqa: E402
from ftacq.so3 import rotation_from_rotvec, rotvec_from_rotation  # noqa: E402
from ftacq.verdict import held_out_errors  # noqa: E402
from tests.fakes.pose_records import (  # noqa: E402
    cone_orientations,
    random_orientations,
    real_like_record,
    simulate_record,
    special_orientations,
)
from tests.fakes.world import CellTruth  # noqa: E402


def best_time_s(function, repeats: int) -> float:
    """Return the best wall time in seconds of ``repeats`` calls."""
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def plain_least_squares(record: PoseRecord) -> ModelParameters:
    """The same model (eqs 10-11) fitted independently: scipy's least_squares over the 15 parameters (sensor
    rotation as a rotation vector), each channel weighted by its residual RMS from a first unweighted pass
    (two-step feasible weighted LS), started from the paper's closed form without refinement."""
    rotations = record.flange_R_base
    start = ModelParameters.from_calibration(identify(record, refine=False, drift="none").calibration)
    x0 = np.concatenate([rotvec_from_rotation(start.sensor_rotation).reshape(3), start.gravity_base,
                         start.force_bias, start.center_of_mass, start.torque_bias])

    def params_of(x: np.ndarray) -> ModelParameters:
        return ModelParameters(rotation_from_rotvec(x[0:3]), x[3:6], x[6:9], x[9:12], x[12:15])

    def residual(x: np.ndarray, scale: np.ndarray) -> np.ndarray:
        return ((record.wrench - predict(params_of(x), rotations)) / scale).ravel()

    scale = np.ones(6)
    x = x0
    for _ in range(2):
        x = least_squares(residual, x, args=(scale,), method="lm").x
        scale = np.sqrt(np.mean((record.wrench - predict(params_of(x), rotations)) ** 2, axis=0))
        scale = np.maximum(scale, 1e-12)
    return params_of(x)


def held_out_rms(errors: np.ndarray) -> tuple[float, float]:
    """RMS of |F| and |T| over held-out poses (N, N·m)."""
    return (float(np.sqrt(np.mean(np.sum(errors[:, :3] ** 2, axis=1)))),
            float(np.sqrt(np.mean(np.sum(errors[:, 3:] ** 2, axis=1)))))


def compare_on_splits(record: PoseRecord, splits: list[np.ndarray], label: str) -> None:
    """Print ftacq's and the plain fit's held-out RMS |F|, |T| summed over the splits (a mask of held-out rows
    each), and their ratio; the folds' worst ratio too."""
    ours, plain, worst = np.zeros(2), np.zeros(2), np.zeros(2)
    refused, drift, elapsed = 0, 0, 0.0
    for held in splits:
        fit, out = record.select(~held), record.select(held)
        start = time.perf_counter()
        try:
            result = identify(fit)
        except Exception as error:  # noqa: BLE001 — a refusal is a figure here
            refused += 1
            print(f"    refused: {error}")
            continue
        elapsed += time.perf_counter() - start
        drift += result.calibration.metadata["drift_model"]["model"] == "linear"
        a = np.array(held_out_rms(held_out_errors(result, out)))
        b_params = plain_least_squares(fit)
        b = np.array(held_out_rms(out.wrench - predict(b_params, out.flange_R_base)))
        ours, plain = ours + a**2, plain + b**2
        worst = np.maximum(worst, a / b)
    ratio = np.sqrt(ours / np.maximum(plain, 1e-300))
    print(f"  {label:<44} held-out RMS |F| {np.sqrt(ours.sum() and ours[0] / len(splits)):.4g} N vs "
          f"{np.sqrt(plain[0] / len(splits)):.4g} N, |T| {np.sqrt(ours[1] / len(splits)):.4g} vs "
          f"{np.sqrt(plain[1] / len(splits)):.4g} N·m; ratio F {ratio[0]:.3f} T {ratio[1]:.3f} (worst fold "
          f"{worst[0]:.2f}/{worst[1]:.2f}); refused {refused}/{len(splits)}, drift modelled {drift}; "
          f"ftacq {elapsed / max(len(splits) - refused, 1):.2f} s per fit   [ratio ≤ 1.10]")


def random_splits(n: int, folds: int, seed: int) -> list[np.ndarray]:
    """``folds`` masks holding out a random 1/folds of the rows each (k-fold)."""
    order = np.random.default_rng(seed).permutation(n)
    return [np.isin(np.arange(n), part) for part in np.array_split(order, folds)]


def block_splits(n: int, folds: int) -> list[np.ndarray]:
    """``folds`` masks holding out one contiguous block of rows each (a later part of a recording)."""
    return [np.isin(np.arange(n), part) for part in np.array_split(np.arange(n), folds)]


def small_set_splits(n: int, fit_poses: int, count: int, seed: int) -> list[np.ndarray]:
    """``count`` masks that keep ``fit_poses`` random rows for the fit and hold out the rest."""
    rng = np.random.default_rng(seed)
    masks = []
    for _ in range(count):
        held = np.ones(n, dtype=bool)
        held[rng.choice(n, fit_poses, replace=False)] = False
        masks.append(held)
    return masks


def read_yumi(folder: Path) -> PoseRecord:
    """The YuMi recording as a pose record: flange poses from flange_pose.csv (rotation matrices), wrenches from
    gravitylog.csv with the torques converted from N·mm; rows in recording order (no times)."""
    log = np.genfromtxt(folder / "gravitylog.csv", delimiter=",", names=True)
    flange = np.genfromtxt(folder / "flange_pose.csv", delimiter=",", names=True)
    base_R_flange = np.stack([[flange[f"r{i}{j}"] for j in (1, 2, 3)] for i in (1, 2, 3)]).transpose(2, 0, 1)
    pose = np.hstack([np.column_stack([flange["px"], flange["py"], flange["pz"]]),
                      rotvec_from_rotation(base_R_flange).reshape(-1, 3)])
    wrench = np.column_stack([log["fx"], log["fy"], log["fz"], log["tx"] / 1e3, log["ty"] / 1e3, log["tz"] / 1e3])
    return PoseRecord(pose=pose, wrench=wrench, extra={"row_index": np.arange(len(pose), dtype=float)})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions and smaller batches (CI)")
    parser.add_argument("--yumi", type=Path, metavar="FOLDER",
                        help="folder of the YuMi recording (gravitylog.csv, flange_pose.csv): held-out comparison")
    parser.add_argument("--only-comparison", action="store_true", help="skip the timing of compensation")
    args = parser.parse_args(argv)
    repeats = 3 if args.quick else 10
    truth = CellTruth()

    print("identification (closed form + robust joint refinement, 1σ, diagnostics)")
    record48 = simulate_record(
        truth, np.concatenate([special_orientations(0.2, seed=1), cone_orientations(24, 40.0, seed=2)]), seed=3
    )
    identify(record48)  # warm-up (imports, caches)
    print(f"  48 poses (24 special + 24 in a 40° cone): {1e3 * best_time_s(lambda: identify(record48), repeats):8.1f} ms   [target ≤ 50 ms]")
    for n, reps in ((1_000, repeats), (100_000, 1)):
        record = simulate_record(truth, random_orientations(n, seed=n), seed=4)
        elapsed = best_time_s(lambda record=record: identify(record), reps)
        print(f"  {n:>7,} random poses:                     {1e3 * elapsed:8.1f} ms")
    real_like = real_like_record(truth, 10_000, seed=8)
    start = time.perf_counter()
    result = identify(real_like)
    elapsed = time.perf_counter() - start
    print(f"   10,000 real-like poses (t noise, no std):  {elapsed:8.2f} s    [target ≤ 5 s]; converged "
          f"{result.converged} after {result.diagnostics['reweightings']} re-weightings, {result.iterations} "
          "iterations")

    print("held-out error: ftacq against a plain least-squares fit of the same model (same splits)")
    folds = 3 if args.quick else 5
    for poses, count in ((6, 10 if args.quick else 30), (12, 10 if args.quick else 20)):
        record = simulate_record(truth, random_orientations(poses + 200, seed=poses), seed=poses,
                                 samples_per_pose=100)
        record = PoseRecord(pose=record.pose, wrench=record.wrench)  # means only, as most files
        compare_on_splits(record, small_set_splits(len(record), poses, count, seed=1),
                          f"{poses} random poses, {count} draws, no std")
    compare_on_splits(record48, random_splits(len(record48), folds, seed=2), f"48 poses (A+E), {folds}-fold")
    for n in (1_000, 10_000):
        record = real_like_record(truth, n, seed=n)
        compare_on_splits(record, random_splits(n, folds, seed=3), f"{n:,} real-like poses, {folds}-fold")
    if args.yumi is not None:
        yumi = read_yumi(args.yumi)
        n = len(yumi)
        compare_on_splits(yumi, random_splits(n, folds, seed=4), f"YuMi {n:,} rows, random {folds}-fold")
        compare_on_splits(yumi, block_splits(n, folds), f"YuMi {n:,} rows, contiguous {folds}-fold")
        for poses in (6, 12, 100):
            compare_on_splits(yumi, small_set_splits(n, poses, 10 if args.quick else 20, seed=poses),
                              f"YuMi: {poses} random rows fitted, rest held out")
    if args.only_comparison:
        return 0

    print("compensation (float64)")
    calibration = truth.calibration()
    n = 200_000 if args.quick else 1_000_000
    rotations = random_orientations(n, seed=5)
    wrench = np.random.default_rng(6).normal(size=(n, 6))
    out = np.empty((n, 6))
    elapsed = best_time_s(lambda: calibration.compensate(wrench, rotations, out=out), repeats)
    print(f"  batch, one orientation per sample ({n:,}): {n / elapsed / 1e6:8.1f} M samples/s   [target ≥ 20 M/s]")
    elapsed = best_time_s(lambda: calibration.compensate(wrench, rotations[0], out=out), repeats)
    print(f"  batch, one orientation per batch  ({n:,}): {n / elapsed / 1e6:8.1f} M samples/s")
    one_wrench, one_rotation = wrench[0], rotations[0]
    calls = 20_000 if args.quick else 100_000
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate_sample(one_wrench, one_rotation)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate_sample (numpy in):  {1e6 * per_call:6.2f} µs   [target ≤ 10 µs]")
    wrench_list, rotation_list = one_wrench.tolist(), one_rotation.tolist()
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate_sample(wrench_list, rotation_list)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate_sample (lists in):  {1e6 * per_call:6.2f} µs")
    start = time.perf_counter()
    for _ in range(calls):
        calibration.compensate(one_wrench, one_rotation)
    per_call = (time.perf_counter() - start) / calls
    print(f"  single sample, compensate (numpy path):       {1e6 * per_call:6.2f} µs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
