"""Units of a pose record and a physically plausible tool (issue 28 item 4): a torque recorded in N·mm is refused
at identification with the likely cause, accepted once the unit is declared (column suffix, header comment or
option), and ftacq never writes a calibration its own readers refuse."""

import json

import numpy as np
import pytest

from ftacq.app.cli import main
from ftacq.calfile import load_calibration, save_calibration
from ftacq.errors import IdentificationError, InputError
from ftacq.identification import identify
from ftacq.posefile import POSE_COLUMNS, read_pose_csv
from tests.fakes.pose_records import random_orientations, simulate_record
from tests.fakes.world import CellTruth

TRUTH = CellTruth(mass_kg=0.9, center_of_mass_m=(0.004, -0.006, 0.045))


@pytest.fixture(scope="module")
def si_record():
    return simulate_record(TRUTH, random_orientations(20, seed=4), seed=4)


def _write(path, record, header_names=POSE_COLUMNS, comment="", torque_scale=1.0, force_scale=1.0):
    scale = np.r_[np.ones(6), np.full(3, force_scale), np.full(3, torque_scale)]
    rows = np.hstack([record.pose, record.wrench]) * scale
    lines = [comment] if comment else []
    lines.append(",".join(header_names))
    lines += [",".join(repr(float(v)) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_torque_in_newton_millimetres_is_refused_with_the_likely_cause(tmp_path, si_record, capsys):
    poses = _write(tmp_path / "nmm.csv", si_record, torque_scale=1000.0)
    with pytest.raises(IdentificationError, match=r"torque in N-mm\?.*--torque-unit N-mm"):
        identify(read_pose_csv(poses))
    out = tmp_path / "cal.json"
    assert main(["identify", str(poses), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "torque in N-mm?" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


@pytest.mark.parametrize("how", ["suffix", "comment", "option"])
def test_torque_in_newton_millimetres_is_accepted_when_declared(tmp_path, si_record, how, capsys):
    names = [f"{n}_Nmm" if n.startswith("t") and how == "suffix" else n for n in POSE_COLUMNS]
    poses = _write(tmp_path / "nmm.csv", si_record, names, "# torque_unit: N·mm" if how == "comment" else "",
                   torque_scale=1000.0)
    out = tmp_path / "cal.json"
    options = ["--torque-unit", "Nmm"] if how == "option" else []
    assert main(["identify", str(poses), "-o", str(out), *options]) in (0, 1)
    assert "torque in N-mm (converted" in capsys.readouterr().out
    calibration = load_calibration(out)
    np.testing.assert_allclose(calibration.center_of_mass, TRUTH.center_of_mass_m, atol=2e-3)
    assert calibration.mass_kg == pytest.approx(TRUTH.mass_kg, rel=0.01)


def test_force_in_pound_force_and_std_columns_follow_their_channel(tmp_path, si_record):
    names = [f"{n}_lbf" if n.startswith("f") else n for n in POSE_COLUMNS]
    poses = _write(tmp_path / "lbf.csv", si_record, names, force_scale=1 / 4.4482216152605)
    record = read_pose_csv(poses)
    np.testing.assert_allclose(record.wrench, si_record.wrench, rtol=1e-12)
    assert record.units == {"force": "lbf", "torque": "N-m"}


@pytest.mark.parametrize("names, comment, option, message", [
    (["tx_Nmm", "ty_Nm", "tz_Nmm"], "", None, "torque columns in different units"),
    (["tx_Nmm", "ty", "tz"], "", None, "column 'ty' has no unit suffix"),
    (["tx_parsec", "ty", "tz"], "", None, "unknown torque unit 'parsec'"),
    (["tx", "ty", "tz"], "# torque_unit: N-mm", "N-m", "declared twice and differently"),
])
def test_contradictory_or_unknown_units_are_one_line_errors(tmp_path, si_record, names, comment, option, message):
    poses = _write(tmp_path / "bad.csv", si_record, [*POSE_COLUMNS[:9], *names], comment)
    with pytest.raises(InputError, match=message):
        read_pose_csv(poses, torque_unit=option)


def test_identify_never_writes_a_file_its_readers_refuse(tmp_path):
    calibration = identify(simulate_record(TRUTH, random_orientations(20, seed=4), seed=4)).calibration
    from dataclasses import replace

    far = replace(calibration, center_of_mass=np.array([27.8, 0.0, 0.0]))
    out = tmp_path / "far.json"
    with pytest.raises(InputError, match="not written.*center_of_mass_m"):
        save_calibration(out, far)
    assert not out.exists()
    save_calibration(out, calibration)
    assert json.loads(out.read_text())["format"] == "ftacq-calibration"
