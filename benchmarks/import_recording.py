"""Benchmark ``ftacq import``: a recording of joint angles of a 7-joint arm (the DH table of tests/data/
yumi-gravitylog) → pose record, and the verdict's wrench-frame check.

Prints the wall time of: reading the CSV and computing the flange poses through Pinocchio (``import_recording``),
writing the pose record, and ``frame_mismatch`` (two closed-form fits on at most 500 rows), best of a few runs.

Usage: ``python benchmarks/import_recording.py [--quick]`` (quick: 2 000 rows instead of 10 000).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ftacq.imports import ImportOptions, import_recording  # noqa: E402
from ftacq.imports.robot_model import dh_arm_model, read_dh_table  # noqa: E402
from ftacq.imports.wrench_frame import frame_mismatch  # noqa: E402
from ftacq.posefile import write_pose_csv  # noqa: E402
from tests.fakes.world import CellTruth  # noqa: E402

DH_TABLE = ROOT / "tests" / "data" / "yumi-gravitylog" / "yumi-dh.csv"


def best_time_s(function, repeats: int) -> tuple[float, object]:
    best, value = float("inf"), None
    for _ in range(repeats):
        start = time.perf_counter()
        value = function()
        best = min(best, time.perf_counter() - start)
    return best, value


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 000 rows, fewer repetitions")
    args = parser.parse_args(argv)
    rows = 2_000 if args.quick else 10_000
    repeats = 2 if args.quick else 3
    model = dh_arm_model(read_dh_table(DH_TABLE))
    rng = np.random.default_rng(1)
    q = rng.uniform(-2.0, 2.0, size=(rows, model.joints))
    flange_R_base = np.swapaxes(model.flange_transforms(q)[:, :3, :3], -1, -2)
    wrench = CellTruth(mass_kg=0.3, center_of_mass_m=(0.0, 0.0, 0.03)).calibration().predict(flange_R_base)
    wrench += rng.normal(scale=[0.05] * 3 + [0.002] * 3, size=wrench.shape)
    with tempfile.TemporaryDirectory() as folder:
        source = Path(folder) / "recording.csv"
        header = [f"q{i + 1}" for i in range(model.joints)] + ["fx", "fy", "fz", "tx_Nmm", "ty_Nmm", "tz_Nmm"]
        values = np.hstack([q, wrench * np.r_[np.ones(3), np.full(3, 1000.0)]])
        source.write_text(",".join(header) + "\n" + "\n".join(",".join(f"{v:.10g}" for v in row) for row in values)
                          + "\n")
        options = ImportOptions(orientation="joints", robot=model)
        import_s, result = best_time_s(lambda: import_recording(source, options), repeats)
        record = result.record  # type: ignore[attr-defined]
        fk_s, _ = best_time_s(lambda: model.flange_transforms(q), repeats)
        write_s, _ = best_time_s(lambda: write_pose_csv(Path(folder) / "poses.csv", record), repeats)
        frame_s, (hint, figures) = best_time_s(lambda: frame_mismatch(record, "sensor"), repeats)
    print(f"import of {rows} rows, 7 joints, DH table through Pinocchio (best of {repeats})")
    print(f"  read CSV + flange poses + units: {import_s:.3f} s ({import_s / rows * 1e6:.0f} µs/row)")
    print(f"    of which forward kinematics:  {fk_s:.3f} s ({fk_s / rows * 1e6:.1f} µs/row)")
    print(f"  write the pose record:           {write_s:.3f} s")
    print(f"  wrench-frame check:              {frame_s:.3f} s (force RMS {figures['force_rms_n']:.3g} N as given, "
          f"{figures['other_force_rms_n']:.3g} N as base-frame; hint: {hint})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
