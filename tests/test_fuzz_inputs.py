"""Fuzz the pose CSV, the calibration JSON, CELL.toml and sensor URLs: only ftacq's own errors may escape.

Bounded for the suite (a fixed, derandomised set of examples per input kind, a few seconds in all); longer
randomised runs: ``python benchmarks/fuzz.py``. Strategies and targets: tests/fuzz_inputs.py.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings

from ftacq.errors import FtacqError
from tests.fuzz_inputs import Targets, calibration_json, cell_toml, pose_csv, robot_host, sensor_url

SUITE_SETTINGS = settings(max_examples=120, deadline=None, derandomize=True, database=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def targets():
    shared = Targets()
    yield shared
    shared.close()


def _only_ftacq_errors(target, text: str) -> None:
    try:
        target(text)
    except FtacqError:
        pass  # a one-line message for the user: what the fuzz wants


@SUITE_SETTINGS
@given(text=pose_csv())
def test_pose_csv_reader(targets, text):
    _only_ftacq_errors(targets.pose_csv, text)


@SUITE_SETTINGS
@given(text=calibration_json())
def test_calibration_json_reader(targets, text):
    _only_ftacq_errors(targets.calibration_json, text)


@SUITE_SETTINGS
@given(text=cell_toml())
def test_cell_toml_reader(targets, text):
    _only_ftacq_errors(targets.cell_toml, text)


@SUITE_SETTINGS
@given(url=sensor_url())
def test_sensor_url_parser(targets, url):
    _only_ftacq_errors(targets.sensor_url, url)


@SUITE_SETTINGS
@given(text=robot_host())
def test_robot_host_check(targets, text):
    _only_ftacq_errors(targets.robot_host, text)
