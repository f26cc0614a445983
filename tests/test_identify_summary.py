"""``ftacq identify`` on a long, disturbed record prints a summary (counts, the worst few, the verdict last), and
writes every pose to the report file beside the calibration (issue 38, item 4)."""

import numpy as np

from ftacq.app.cli import main
from ftacq.posefile import write_pose_csv
from ftacq.report import SUMMARY_ROWS
from tests.fakes.pose_records import cone_orientations, simulate_record, special_orientations
from tests.fakes.world import CellTruth

DISTURBED = 40


def test_a_long_disturbed_record_gets_a_summary_and_the_full_list_in_a_file(tmp_path, capsys):
    rotations = np.concatenate([special_orientations(0.2, seed=1), cone_orientations(276, 60.0, seed=2)])
    contacts = {30 + 6 * k: np.array([15.0 + k, 0, 0, 0, 0.2, 0]) for k in range(DISTURBED)}
    record = simulate_record(CellTruth(), rotations, seed=3, contacts=contacts)
    path = tmp_path / "poses.csv"
    write_pose_csv(path, record)
    out = tmp_path / "cal.json"
    status = main(["identify", str(path), "-o", str(out)])
    text = capsys.readouterr().out
    lines = text.strip().splitlines()
    assert text.count("looks disturbed") == SUMMARY_ROWS  # the worst ten, and a line counting the others
    assert f"… and {DISTURBED - SUMMARY_ROWS} more poses look disturbed" in text
    assert f"Outliers: {DISTURBED} of 300 poses; the {SUMMARY_ROWS} worst: " in text
    assert len(lines) < 100, len(lines)
    verdict_at = max(i for i, line in enumerate(lines) if line.startswith("verdict: "))
    assert status in (0, 1) and all(line.startswith("  ") for line in lines[verdict_at + 1:])  # the verdict is last
    full = tmp_path / "cal.report.txt"
    assert f"every pose: {full}" in text
    report = full.read_text()
    assert report.count("looks disturbed") == DISTURBED and "… and" not in report


def test_hold_out_lets_a_recording_without_sets_pass(tmp_path, capsys):
    """Issue 38, item 5: an imported recording has no V poses; --hold-out FRACTION holds some out, spread over the
    record, so the verdict can check (and pass) the calibration on poses it was not fitted to."""
    from dataclasses import replace

    from ftacq.calfile import load_calibration
    from tests.fakes.pose_records import example_record

    record = example_record(seed=4)
    record = replace(record, sets=("",) * len(record))  # as imported: no sets
    path = tmp_path / "imported.csv"
    write_pose_csv(path, record)
    out = tmp_path / "cal.json"
    assert main(["identify", str(path), "-o", str(out)]) == 0
    assert "no held-out poses" in capsys.readouterr().out
    assert load_calibration(out).metadata["verdict"]["status"] == "WARN"  # never PASS without --hold-out
    assert main(["identify", str(path), "-o", str(out), "--hold-out", "0.25"]) == 0
    text = capsys.readouterr().out
    calibration = load_calibration(out)
    verdict = calibration.metadata["verdict"]
    assert verdict["status"] == "PASS", text
    held = calibration.metadata["validation"]["labels"]
    assert len(held) == 12 and held[0] != record.labels[0] and held[-1] != record.labels[-1]
    assert calibration.metadata["input"]["sets"]["V"] == 12
    assert main(["identify", str(path), "-o", str(out), "--hold-out", "0.9"]) == 2
    assert "--hold-out" in capsys.readouterr().err
