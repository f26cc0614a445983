"""Calibration JSON: exact round trip, required keys with SI units, and clear errors for bad files."""

import json

import numpy as np
import pytest

from ftacq.calfile import (
    FORMAT_VERSION,
    MODEL_CORRELATION_PARAMETERS,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from ftacq.errors import InputError
from ftacq.identification import identify
from tests.fakes.pose_records import example_record
from tests.fakes.world import CellTruth


@pytest.fixture(scope="module")
def identified():
    return identify(example_record(seed=2), mount="floor").calibration


def test_round_trip_is_exact(tmp_path, identified):
    path = tmp_path / "cal.json"
    save_calibration(path, identified)
    back = load_calibration(path)
    for name in ("sensor_rotation", "force_bias", "torque_bias", "gravity_base", "center_of_mass"):
        np.testing.assert_array_equal(getattr(back, name), getattr(identified, name))
    assert back.mass_kg == identified.mass_kg
    assert back.uncertainty["mass_kg"] == identified.uncertainty["mass_kg"]
    assert back.metadata["method"] == "srom+refine"
    assert back.metadata["residuals"]["labels"] == list(identified.metadata["residuals"]["labels"])
    assert back.metadata["model_correlation"] == identified.metadata["model_correlation"]


def test_the_identification_writes_the_model_parameters_correlations(identified):
    """The kept parameters' errors are correlated (the rotation with the centre of mass, the weight with the
    rotation): the file says how, so their 1σ propagate correctly (ftacq.bias_estimate)."""
    entry = identified.metadata["model_correlation"]
    assert entry["parameters"] == list(MODEL_CORRELATION_PARAMETERS)
    matrix = np.array(entry["matrix"])
    np.testing.assert_allclose(np.diag(matrix), 1.0)
    np.testing.assert_allclose(matrix, matrix.T)
    assert np.all(np.linalg.eigvalsh(matrix) > -1e-9)
    assert np.abs(matrix - np.eye(9)).max() > 0.3  # strongly correlated somewhere: the diagonal alone is not it


def test_document_has_the_required_keys_and_shapes(identified):
    document = calibration_to_dict(identified)
    assert document["format"] == "ftacq-calibration" and document["version"] == FORMAT_VERSION
    assert np.array(document["sensor_rotation"]).shape == (3, 3)
    for key in ("force_bias", "torque_bias", "gravity_base", "center_of_mass_m"):
        assert len(document[key]) == 3
    assert document["mass_kg"] == pytest.approx(identified.mass_kg)
    assert document["base_tilt_deg"] == pytest.approx(list(identified.base_tilt_deg))
    for key in ("uncertainty", "residuals", "outliers", "method", "software_version", "created_utc", "mount",
                "base_tilt_relative_deg", "warnings", "diagnostics"):
        assert key in document, key
    json.dumps(document, allow_nan=False)


def write(tmp_path, document) -> str:
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(document))
    return str(path)


def good_document():
    return calibration_to_dict(CellTruth().calibration())


@pytest.mark.parametrize(
    "change, expected",
    [
        (lambda d: d.update(version=3), "reads calibration versions 1, 2, the file has 3"),
        (lambda d: d.pop("version"), "the file has None"),
        (lambda d: d.update(format="other"), "key 'format'"),
        (lambda d: d.pop("torque_bias"), "missing required key 'torque_bias'"),
        (lambda d: d.update(force_bias=[1, 2]), "key 'force_bias': expected shape \\[3\\], got \\[2\\]"),
        (lambda d: d.update(center_of_mass_m=["a", 0, 0]), "key 'center_of_mass_m'"),
        (lambda d: d.update(sensor_rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), "not a rotation matrix"),
        (lambda d: d.update(mass_kg=d["mass_kg"] * 1.01), "disagrees with"),
        (lambda d: d.update(model_correlation={"parameters": ["gravity_base"], "matrix": [[1]]}),
         "key 'model_correlation': expected"),
        (lambda d: d.update(model_correlation={"parameters": list(MODEL_CORRELATION_PARAMETERS),
                                               "matrix": np.eye(8).tolist()}), "expected a 9×9 array"),
        (lambda d: d.update(model_correlation={"parameters": list(MODEL_CORRELATION_PARAMETERS),
                                               "matrix": (np.eye(9) * 2).tolist()}), "not a correlation matrix"),
    ],
)
def test_bad_calibration_files_are_refused_with_the_key(tmp_path, change, expected):
    document = good_document()
    change(document)
    with pytest.raises(InputError, match=expected):
        load_calibration(write(tmp_path, document))


def test_unreadable_and_invalid_json(tmp_path):
    with pytest.raises(InputError, match="cannot read"):
        load_calibration(tmp_path / "missing.json")
    path = tmp_path / "broken.json"
    path.write_text('{"format": ')
    with pytest.raises(InputError, match="not valid JSON"):
        load_calibration(path)
    path.write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        load_calibration(path)


def test_save_is_atomic(tmp_path):
    path = tmp_path / "cal.json"
    path.write_text("previous")
    bad = CellTruth().calibration()
    object.__setattr__(bad, "metadata", {"not_serialisable": object()})
    with pytest.raises(TypeError):
        save_calibration(path, bad)
    assert path.read_text() == "previous"
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


def test_writer_table_writes_every_format_atomically(tmp_path, identified, monkeypatch):
    import os
    import stat

    from ftacq import calfile

    assert "json" in calfile.WRITERS
    path = tmp_path / "cal.json"
    calfile.write_calibration(path, identified, "json")
    assert load_calibration(path).mass_kg == identified.mass_kg
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o644
    # a new format is one function and one table row
    monkeypatch.setitem(calfile.WRITERS, "mass", lambda calibration: f"{calibration.mass_kg:.6f}\n")
    calfile.write_calibration(tmp_path / "mass.txt", identified, "mass")
    assert (tmp_path / "mass.txt").read_text() == f"{identified.mass_kg:.6f}\n"
    with pytest.raises(InputError, match="'urscript': unknown .*json"):
        calfile.write_calibration(tmp_path / "x", identified, "urscript")
    assert not (tmp_path / "x").exists()


def test_provenance_names_the_input_and_what_was_identified_on(tmp_path, identified):
    import hashlib

    from ftacq.provenance import input_record, with_provenance

    poses = tmp_path / "poses.csv"
    poses.write_text("label,set\nA01,A\n", encoding="utf-8")
    record = input_record(poses, ["A", "A", "E", "V"], ["A", "E"], has_std=True, has_count=False)
    assert record == {"file": str(poses), "sha256": hashlib.sha256(poses.read_bytes()).hexdigest(), "poses": 4,
                      "sets": {"A": 2, "E": 1, "V": 1}, "identified_on": ["A", "E"], "has_std": True,
                      "has_count": False, "units": {"force": "N", "torque": "N-m"}}
    calibration = with_provenance(identified, None, None, input=record, run_folder="runs/x", validation=None)
    assert calibration.metadata["input"] == record and calibration.metadata["run_folder"] == "runs/x"
    assert "validation" not in calibration.metadata and calibration.metadata["bias_history"]
    path = tmp_path / "cal.json"
    save_calibration(path, calibration)
    assert load_calibration(path).metadata["input"]["identified_on"] == ["A", "E"]


def test_a_broken_file_names_plain_numbers_not_numpy_reprs(tmp_path):
    document = good_document()
    document["mass_kg"] = 1.3499
    with pytest.raises(InputError) as caught:
        load_calibration(write(tmp_path, document))
    message = str(caught.value)
    assert "np.float64" not in message and "float64" not in message
    assert "1.3499 kg disagrees with ‖gravity_base‖/g = 1.35 kg" in message
