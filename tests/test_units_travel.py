"""Units travel with the data: the calibration records the units its pose record was identified in, and
``ftacq compensate`` reads the same file in them, refuses another file that declares none, and converts one that
declares its own (issue 38, item 1)."""

import csv

import numpy as np
import pytest

from ftacq.app.cli import main
from ftacq.calfile import load_calibration
from tests.fakes.pose_records import example_record
from tests.fakes.world import CellTruth

COLUMNS = ("label", "set", "x", "y", "z", "rx", "ry", "rz", "fx", "fy", "fz", "tx", "ty", "tz")


def _write(path, record, torque_scale=1.0, header_lines=(), torque_suffix=""):
    """Rotation and wrench columns of ``record``, torques multiplied by ``torque_scale`` (N·m → the file's unit)."""
    names = [f"{n}{torque_suffix}" if n.startswith("t") else n for n in COLUMNS]
    lines = list(header_lines) + [",".join(names)]
    for label, set_name, pose, wrench in zip(record.labels, record.sets, record.pose, record.wrench):
        values = list(pose) + list(wrench[:3]) + list(wrench[3:] * torque_scale)
        lines.append(",".join([label, set_name] + [repr(float(v)) for v in values]))
    path.write_text("\n".join(lines) + "\n")


def _contact(path):
    rows = list(csv.DictReader(open(path)))
    return np.array([[float(row[f"contact_{c}"]) for c in ("fx", "fy", "fz", "tx", "ty", "tz")] for row in rows])


@pytest.fixture()
def nmm(tmp_path, capsys):
    """A pose record in N·mm that says so nowhere, identified with --torque-unit N-mm."""
    record = example_record(seed=1)
    path = tmp_path / "poses_nmm.csv"
    _write(path, record, torque_scale=1000.0)
    cal = tmp_path / "cal.json"
    assert main(["identify", str(path), "-o", str(cal), "--torque-unit", "N-mm"]) == 0
    capsys.readouterr()
    return record, path, cal


def test_the_calibration_records_the_units_it_was_identified_in(nmm):
    _, _, cal = nmm
    assert load_calibration(cal).metadata["input"]["units"] == {"force": "N", "torque": "N-mm"}


def test_compensate_reads_the_identified_file_in_its_recorded_units(nmm, tmp_path, capsys):
    record, path, cal = nmm
    out = tmp_path / "contact.csv"
    assert main(["compensate", str(cal), str(path), "-o", str(out)]) == 0
    assert "read with torque in N-mm" in capsys.readouterr().err
    contact = _contact(out)
    # residuals of a good fit (0.22 kg-class noise), not the raw N·mm readings taken for N·m
    assert np.abs(contact[:, 3:]).max() < 0.05 and np.abs(contact[:, :3]).max() < 1.0


def test_compensate_refuses_another_undeclared_file_and_converts_a_declared_one(nmm, tmp_path, capsys):
    record, _, cal = nmm
    other = tmp_path / "other.csv"
    _write(other, record.select(np.arange(len(record)) < 5), torque_scale=1000.0)
    out = tmp_path / "contact.csv"
    assert main(["compensate", str(cal), str(other), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "declares no unit for torque" in err and "--torque-unit N-mm" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert main(["compensate", str(cal), str(other), "-o", str(out), "--torque-unit", "N-mm"]) == 0
    assert np.abs(_contact(out)[:, 3:]).max() < 0.05
    suffixed = tmp_path / "suffixed.csv"  # the unit in the column names, kept in the output's header
    _write(suffixed, record.select(np.arange(len(record)) < 5), torque_suffix="_Nm")
    assert main(["compensate", str(cal), str(suffixed), "-o", str(out)]) == 0
    assert "tx_nm" in open(out).readline() and np.abs(_contact(out)[:, 3:]).max() < 0.05
    declared = tmp_path / "declared.csv"  # a header comment, as the monitor's record writes it
    _write(declared, record.select(np.arange(len(record)) < 5), header_lines=["# force_unit: N", "# torque_unit: N-m"])
    assert main(["compensate", str(cal), str(declared), "-o", str(out)]) == 0
    assert np.abs(_contact(out)[:, 3:]).max() < 0.05


def test_an_si_calibration_reads_undeclared_files_as_si(tmp_path, capsys):
    from ftacq.calfile import save_calibration

    cal = tmp_path / "cal.json"
    save_calibration(cal, CellTruth().calibration())  # no input record: nothing to compare
    record = example_record(seed=2)
    path = tmp_path / "p.csv"
    _write(path, record)
    out = tmp_path / "c.csv"
    assert main(["compensate", str(cal), str(path), "-o", str(out)]) == 0
    assert np.abs(_contact(out)).max() < 1.0
