"""``ftacq identify`` and ``ftacq compensate`` in-process: report, files, and bad input → exit 2, no output."""

import csv

import numpy as np
import pytest

from ftacq.calfile import load_calibration
from ftacq.app.cli import main
from ftacq.posefile import POSE_COLUMNS, write_pose_csv
from tests.fakes.pose_records import cone_orientations, example_record, simulate_record, special_orientations
from tests.fakes.world import CellTruth


@pytest.fixture()
def poses_csv(tmp_path):
    path = tmp_path / "poses.csv"
    write_pose_csv(path, example_record(seed=1))
    return path


def test_identify_prints_the_report_and_writes_the_calibration(tmp_path, poses_csv, capsys):
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(out), "--mount", "floor"]) == 0
    text = capsys.readouterr().out
    for expected in ("srom+refine", "force_bias", "N·m", "mass", "± ", "center_of_mass    mm", "A01", "E24",
                     "Outliers: none", "nominal floor mount", f"wrote {out}"):
        assert expected in text, expected
    calibration = load_calibration(out)
    assert calibration.mass_kg == pytest.approx(CellTruth().mass_kg, abs=1e-3)
    assert calibration.metadata["input"]["poses"] == 48
    assert calibration.metadata["input"]["sets"] == {"A": 24, "E": 24}


def test_identify_options_method_and_no_refine(tmp_path, poses_csv, capsys):
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(out), "--method", "lrom", "--no-refine"]) == 0
    text = capsys.readouterr().out
    assert "method lrom\n" in text and "no refinement" in text
    assert load_calibration(out).metadata["method"] == "lrom"


def test_identify_names_an_outlier(tmp_path, capsys):
    rotations = np.concatenate([special_orientations(0.2, seed=1), cone_orientations(24, 40.0, seed=2)])
    record = simulate_record(CellTruth(), rotations, seed=3, contacts={30: np.array([20.0, 0, 0, 0, 0, 0])})
    path = tmp_path / "poses.csv"
    write_pose_csv(path, record)
    assert main(["identify", str(path), "-o", str(tmp_path / "cal.json")]) == 0
    text = capsys.readouterr().out
    assert "Outliers: P31" in text and "OUTLIER" in text and "looks disturbed" in text


def test_compensate_writes_the_contact_wrench_per_row(tmp_path, poses_csv, capsys):
    cal = tmp_path / "cal.json"
    assert main(["identify", str(poses_csv), "-o", str(cal)]) == 0
    capsys.readouterr()
    truth = CellTruth()
    record = simulate_record(truth, cone_orientations(5, 60.0, seed=4), noise=False,
                             contacts={2: np.array([0.0, 0.0, -5.0, 0.0, 0.1, 0.0])})
    sensor_record = tmp_path / "sensor.csv"
    with open(sensor_record, "w", newline="") as handle:  # a sensor-record-like file: time + pose + wrench
        writer = csv.writer(handle)
        writer.writerow(["time_s", *POSE_COLUMNS[3:]])
        for k in range(len(record)):
            writer.writerow([0.001 * k, *record.pose[k, 3:], *record.wrench[k]])
    out = tmp_path / "contact.csv"
    assert main(["compensate", str(cal), str(sensor_record), "-o", str(out)]) == 0
    rows = list(csv.DictReader(open(out)))
    assert len(rows) == 5 and rows[1]["time_s"] == "0.001"
    contact = np.array([[float(row[f"contact_{c}"]) for c in ("fx", "fy", "fz", "tx", "ty", "tz")] for row in rows])
    expected = np.zeros((5, 6))
    expected[2] = [0.0, 0.0, -5.0, 0.0, 0.1, 0.0]
    np.testing.assert_allclose(contact, expected, atol=5e-3)
    assert main(["compensate", str(cal), str(sensor_record)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].endswith("contact_tz") and len(printed) == 6


BAD_POSES = {
    "missing column": "x,y,z,rx,ry,rz,fx,fy,fz,tx,ty\n0,0,0,0,0,0,1,2,3,4,5\n",
    "duplicated column": "x,y,z,rx,ry,rz,fx,fy,fz,tx,ty,tz,fx\n" + "0,0,0,0,0,0,1,2,3,4,5,6,1\n",
    "non-numeric": "x,y,z,rx,ry,rz,fx,fy,fz,tx,ty,tz\n0,0,0,0,0,zero,1,2,3,4,5,6\n",
    "nan": "x,y,z,rx,ry,rz,fx,fy,fz,tx,ty,tz\n0,0,0,0,0,0,1,2,NaN,4,5,6\n",
}


@pytest.mark.parametrize("case", list(BAD_POSES))
def test_identify_bad_input_exit_2_and_no_output(tmp_path, capsys, case):
    path = tmp_path / "poses.csv"
    path.write_text(BAD_POSES[case])
    out = tmp_path / "cal.json"
    assert main(["identify", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "line" in err
    assert not out.exists()


@pytest.mark.parametrize("case", ["too few", "one orientation", "one axis"])
def test_identify_degenerate_pose_sets_exit_2(tmp_path, capsys, case):
    from ftacq.so3 import rotation_from_rotvec

    truth = CellTruth()
    if case == "too few":
        rotations = special_orientations()[:3]
    elif case == "one orientation":
        rotations = np.repeat(special_orientations()[:1], 8, axis=0)
    else:
        rotations = np.swapaxes(rotation_from_rotvec(np.column_stack([np.linspace(0, 2, 8), np.zeros(8), np.zeros(8)])), -1, -2)
    path = tmp_path / "poses.csv"
    write_pose_csv(path, simulate_record(truth, rotations, seed=1))
    out = tmp_path / "cal.json"
    assert main(["identify", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "cannot identify" in err and str(path) in err
    assert not out.exists()


def test_compensate_bad_calibration_exit_2(tmp_path, poses_csv, capsys):
    cal = tmp_path / "cal.json"
    cal.write_text('{"format": "ftacq-calibration", "version": 99}')
    out = tmp_path / "out.csv"
    assert main(["compensate", str(cal), str(poses_csv), "-o", str(out)]) == 2
    assert "version" in capsys.readouterr().err
    assert not out.exists()


def test_validation_poses_are_held_out_and_reported(tmp_path, capsys):
    truth = CellTruth()
    rotations = np.concatenate([special_orientations(0.2, seed=1), cone_orientations(30, 40.0, seed=2)])
    sets = ("A",) * 24 + ("E",) * 24 + ("V",) * 6
    record = simulate_record(truth, rotations, seed=5, sets=sets)
    path = tmp_path / "poses.csv"
    write_pose_csv(path, record)
    out = tmp_path / "cal.json"
    assert main(["identify", str(path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Validation: compensation error on 6 held-out poses" in text
    calibration = load_calibration(out)
    assert calibration.metadata["diagnostics"]["poses"] == 48
    validation = calibration.metadata["validation"]
    assert validation["labels"] == list(record.labels[48:])
    assert 0 < validation["max_force_norm"] < 0.05 and 0 < validation["max_torque_norm"] < 0.002
    assert main(["identify", str(path), "-o", str(out), "--use-validation"]) == 0
    assert load_calibration(out).metadata["diagnostics"]["poses"] == 54


def test_compensate_reads_a_monitor_style_record(tmp_path, capsys):
    truth = CellTruth()
    cal = tmp_path / "cal.json"
    from ftacq.calfile import save_calibration

    save_calibration(cal, truth.calibration())
    record = simulate_record(truth, cone_orientations(3, 30.0, seed=1), noise=False)
    lines = ["# ftacq monitor record", "time_s,x,y,z,rx,ry,rz,fx,fy,fz,tx,ty,tz,contact_fx,contact_fy,contact_fz,"
             "contact_tx,contact_ty,contact_tz,sequence"]
    for k in range(3):
        pose = ",".join(repr(float(v)) for v in record.pose[k])
        wrench = ",".join(repr(float(v)) for v in record.wrench[k] + [1.0, 0, 0, 0, 0, 0])
        lines.append(f"{k},{pose},{wrench},,,,,,,{k}")
    lines.append("3,,,,,,," + ",".join(repr(float(v)) for v in record.wrench[0]) + ",,,,,,,3")  # no robot pose
    path = tmp_path / "monitor.csv"
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    assert main(["compensate", str(cal), str(path), "-o", str(out)]) == 0
    assert "1 rows without a flange pose" in capsys.readouterr().err
    rows = list(csv.DictReader(open(out)))
    assert list(rows[0]).count("contact_fx") == 1 and len(rows) == 4
    for row in rows[:3]:
        assert float(row["contact_fx"]) == pytest.approx(1.0, abs=1e-9)
        assert float(row["contact_tz"]) == pytest.approx(0.0, abs=1e-9)
    assert rows[3]["contact_fx"] == "" and rows[3]["sequence"] == "3"


def test_compensate_bad_pose_file_exit_2_and_no_output(tmp_path, capsys):
    from ftacq.calfile import save_calibration

    cal = tmp_path / "cal.json"
    save_calibration(cal, CellTruth().calibration())
    path = tmp_path / "poses.csv"
    path.write_text("rx,ry,rz,fx,fy,fz,tx,ty,tz\n0,0,0,1,2,3,4,5,6\n0,0,0,1,2,inf,4,5,6\n")
    out = tmp_path / "out.csv"
    assert main(["compensate", str(cal), str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "line 3, column 'fz': value 'inf' is not finite" in err and str(path) in err
    assert not out.exists()


def test_a_reader_that_goes_away_stops_the_output_quietly_and_keeps_the_file(tmp_path, poses_csv, monkeypatch, capsys):
    class ClosedPipe:
        """Standard output whose reader has gone (`ftacq identify … | head -1`)."""

        def __init__(self, path):
            self._file = open(path, "w")

        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            pass

        def fileno(self):
            return self._file.fileno()

    out = tmp_path / "cal.json"
    monkeypatch.setattr("sys.stdout", ClosedPipe(tmp_path / "stdout"))
    assert main(["identify", str(poses_csv), "-o", str(out)]) == 141
    assert "Traceback" not in capsys.readouterr().err
    assert load_calibration(out).mass_kg == pytest.approx(CellTruth().mass_kg, abs=1e-3)


def test_identify_ends_with_the_verdict(tmp_path, capsys):
    """Held-out poses of the right tool: not FAIL; the same poses measured with a part in the gripper: FAIL, the
    reason in plain words, exit status 1, the calibration kept with its verdict; a D revisit is judged as drift."""
    import dataclasses

    truth = CellTruth()
    rotations = np.concatenate([special_orientations(0.2, seed=1), cone_orientations(30, 40.0, seed=2)])
    labels = tuple(f"A{i + 1:02d}" for i in range(24)) + tuple(f"E{i + 1:02d}" for i in range(24)) + tuple(
        f"V{i + 1:02d}" for i in range(6))
    sets = ("A",) * 24 + ("E",) * 24 + ("V",) * 6
    good = simulate_record(truth, rotations, seed=5, sets=sets, labels=labels)
    path, out = tmp_path / "poses.csv", tmp_path / "cal.json"
    write_pose_csv(path, good)
    assert main(["identify", str(path), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    verdict = text.rstrip().split("\n\nverdict: ")[1]
    assert verdict.split("\n")[0] in ("PASS", "WARN") and "validation   the 6 held-out poses" in verdict
    assert load_calibration(out).metadata["verdict"]["status"] == verdict.split("\n")[0]

    heavier = simulate_record(dataclasses.replace(truth, mass_kg=truth.mass_kg + 0.2), rotations[48:], seed=6,
                              sets=sets[48:], labels=labels[48:])
    bad = dataclasses.replace(good, wrench=np.vstack([good.wrench[:48], heavier.wrench]))
    write_pose_csv(path, bad)
    assert main(["identify", str(path), "-o", str(out)]) == 1
    verdict = capsys.readouterr().out.rstrip().split("\n\nverdict: ")[1]
    assert verdict.startswith("FAIL\n  FAIL  validation   the 6 held-out poses disagree with the calibration")
    assert load_calibration(out).metadata["verdict"]["status"] == "FAIL"

    drifted = simulate_record(truth, rotations[:1], seed=7, sets=("D",), labels=("A01-revisit",))
    drifted = dataclasses.replace(drifted, wrench=drifted.wrench + np.array([2.0, 0, 0, 0, 0, 0]))
    write_pose_csv(path, good.select(np.arange(54)).__class__(
        pose=np.vstack([good.pose, drifted.pose]), wrench=np.vstack([good.wrench, drifted.wrench]),
        std=np.vstack([good.std, drifted.std]), count=np.concatenate([good.count, drifted.count]),
        labels=good.labels + drifted.labels, sets=good.sets + drifted.sets))
    assert main(["identify", str(path), "-o", str(out)]) == 1
    text = capsys.readouterr().out
    assert "FAIL  drift        the sensor drifted 2" in text
