"""The Python API (``ftacq.open_cell``, ftacq/app/session.py) against the simulated cell: the documented example as
written, the batches' shapes and values (compensated = raw − the calibration's model, the record's values row for
row), the live tare, listeners, and a close that leaves no thread and no child process, however the block is left."""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import ftacq
from ftacq.errors import InputError
from ftacq.so3 import rotation_from_rotvec
from procedures import events
from tests.fakes.world import CellTruth
from tests.scripted import read_record

pytest.importorskip("rtde_control")

ROOT = Path(__file__).resolve().parents[1]
SECONDS = 1.0
TARE_SHIFT = np.array([0.35, -0.25, 0.6, 0.012, -0.008, 0.005])
"""The calibration handed to the cell has biases off the simulated sensor's by this much (N, N·m): a tare finds it."""


def child_processes() -> dict[int, str]:
    """The live processes whose parent is this one (from /proc): pid → command line. Python's multiprocessing
    resource tracker is left out: one per process, started with the first shared-memory block (the simulated
    cell's) and kept until the process exits, by design."""
    children = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, IndexError):
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                if int(fields[1]) == os.getpid() and fields[0] != "Z" and "resource_tracker" not in command:
                    children[int(entry.name)] = command
    return children


@pytest.fixture
def nothing_left_running():
    """Fail when a thread or a child process started during the test is still there at its end."""
    threads_before = set(threading.enumerate())
    children_before = child_processes()
    yield
    left = [t.name for t in threading.enumerate() if t not in threads_before and t.is_alive()]
    assert not left, f"threads left running: {left}"
    children = child_processes()
    assert set(children) <= set(children_before), f"child processes left running: {children}"


def documented_example() -> str:
    text = (ROOT / "docs" / "python-api.md").read_text(encoding="utf-8")
    return re.search(r"```python\n(.*?)```", text, re.S).group(1)


def test_the_documented_example_runs_and_leaves_nothing_running(nothing_left_running):
    code = documented_example()
    assert len(code.strip().splitlines()) <= 10  # the goal: compensated batches in ≤ 10 lines
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "docs/python-api.md", "exec"), {})  # noqa: S102 - the page's own example, as written
    lines = out.getvalue().splitlines()
    readings = [line for line in lines if "contact force" in line]
    assert len(readings) >= 2
    # the simulated cell compensated with its true calibration, arm still, nothing on the tool: ≈ 0 N of contact
    # (nan: a first read older than the robot's first state, left uncompensated)
    forces = np.array([[float(v) for v in re.search(r"\[(.*)\]", line).group(1).split()] for line in readings])
    assert np.isfinite(forces[-1]).all() and np.nanmax(np.abs(forces)) < 1.0
    assert lines[-1].startswith("biases changed by")


def test_batches_have_fixed_shapes_and_compensated_is_raw_minus_the_model(nothing_left_running):
    with ftacq.open_cell(sim=True) as cell:
        calibration = cell.calibration
        batches = list(cell.batches(seconds=SECONDS))
    assert len(batches) > 20
    for batch in batches:
        n = len(batch)
        assert n > 0
        for name in ("time_s", "receive_time_s"):
            assert getattr(batch, name).shape == (n,) and getattr(batch, name).dtype == np.float64
        for name in ("raw", "compensated", "flange_pose"):
            assert getattr(batch, name).shape == (n, 6) and getattr(batch, name).dtype == np.float64
        assert batch.saturated.dtype == np.bool_ and batch.sequence.dtype == np.int64
        assert batch.compensation in ("dynamic", "static", "none") and not batch.drift_corrected
    # a read with no robot state near its samples (a loaded host stalls the state stream) is flagged and stays raw
    for batch in batches:
        assert batch.uncompensated == (batch.compensation == "none") == bool(np.isnan(batch.compensated).all())
    compensated = [b for b in batches if not b.uncompensated]
    # the simulated tool's true calibration has its inertia: dynamic (static only for a read the states fell behind)
    assert compensated and any(b.compensation == "dynamic" for b in compensated)
    # within a read the samples are 1/rate apart on the sensor's clock (between reads the clock's mapping may move a
    # few µs as it learns: docs/dynamics.md)
    assert all(np.all(np.diff(b.time_s) > 0) for b in batches)
    assert np.all(np.diff(np.concatenate([b.sequence for b in batches])) > 0)
    # compensated = raw − (biases + the tool's weight at each sample's orientation): the calibration's own model.
    # (A rotation vector near π, the tool pointing down, holds the orientation to ~1e-6 rad: up to 1e-5 N here.)
    for batch in compensated:
        flange_R_base = np.array([rotation_from_rotvec(p[3:]).T for p in batch.flange_pose])
        np.testing.assert_allclose(batch.compensated, calibration.compensate(batch.raw, flange_R_base), atol=1e-4)
        np.testing.assert_allclose(batch.model, batch.raw - batch.compensated)


def test_a_cell_from_cell_toml_without_a_calibration_streams_raw(tmp_path, nothing_left_running):
    from tests.fakes.cell import SimulatedCell

    with SimulatedCell(sensor="netft", rate_hz=2000.0) as sim:
        config = tmp_path / "CELL.toml"
        config.write_text(f'[robot]\nhost = "{sim.robot_host}"\nmodel = "{sim.model_name}"\n\n'
                          f'[sensor]\nurl = "{sim.sensor_url}"\n', encoding="utf-8")
        with ftacq.open_cell(config) as cell:
            batches = list(cell.batches(seconds=0.5))
            assert cell.bias is None and cell.source == str(config)
            with pytest.raises(InputError, match="no calibration"):
                cell.tare()
    assert batches and all(b.compensation == "none" and np.isnan(b.compensated).all() for b in batches)
    assert all(np.isfinite(b.flange_pose).all() for b in batches)


def test_bad_input_is_one_line_and_opens_nothing(tmp_path, nothing_left_running):
    with pytest.raises(InputError, match="CELL.toml path or sim=True"):
        ftacq.open_cell()
    with pytest.raises(InputError, match="missing.json"):
        ftacq.open_cell(sim=True, calibration=tmp_path / "missing.json")
    with pytest.raises(InputError, match="missing.toml"):
        ftacq.open_cell(tmp_path / "missing.toml")


def test_a_record_holds_the_values_of_the_batches_row_for_row(tmp_path, nothing_left_running):
    path = tmp_path / "run.csv"
    with ftacq.open_cell(sim=True, record=path) as cell:
        batches = list(cell.batches(seconds=SECONDS))
    record = read_record(path)
    joined = {name: np.concatenate([getattr(b, name) for b in batches])
              for name in ("time_s", "receive_time_s", "raw", "compensated", "flange_pose", "sequence")}
    assert record.size == joined["time_s"].size
    np.testing.assert_allclose(record["sample_time_s"], joined["time_s"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(record["time_s"], joined["receive_time_s"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(record["sequence"], joined["sequence"])
    for columns, key in ((("fx", "fy", "fz", "tx", "ty", "tz"), "raw"), (("x", "y", "z", "rx", "ry", "rz"), "flange_pose"),
                         (tuple(f"contact_{c}" for c in ("fx", "fy", "fz", "tx", "ty", "tz")), "compensated")):
        from_file = np.column_stack([record[c] for c in columns])
        np.testing.assert_allclose(from_file, joined[key], rtol=1e-8, atol=1e-12, equal_nan=True)


def test_tare_changes_the_bias_and_the_stream(nothing_left_running):
    truth = CellTruth()
    off = truth.calibration()
    off = replace(off, force_bias=off.force_bias - TARE_SHIFT[:3], torque_bias=off.torque_bias - TARE_SHIFT[3:])
    with ftacq.open_cell(sim=True, calibration=off) as cell:
        before = np.vstack([b.compensated for b in cell.batches(seconds=0.5)])
        bias_before = cell.bias
        result = cell.tare()
        after = np.vstack([b.compensated for b in cell.batches(seconds=0.5)])
        bias_after = cell.bias
        history = cell.calibration.metadata["bias_history"]
    true_bias = np.concatenate([truth.force_bias_n, truth.torque_bias_nm])
    # before: the contact wrench at rest is the biases' error; after: ≈ 0
    np.testing.assert_allclose(np.nanmean(before, axis=0), TARE_SHIFT, atol=0.05)
    assert np.all(np.abs(result.estimate.change - TARE_SHIFT) <= 5 * result.estimate.sigma + 1e-3)
    assert np.all(np.abs(np.nanmean(after, axis=0)) < np.abs(TARE_SHIFT) / 4)
    assert np.all(np.abs(bias_after.bias - true_bias) <= 5 * bias_after.sigma + 1e-3)
    assert np.abs(bias_after.bias - bias_before.bias).max() > 0.2
    assert history[-1]["method"].startswith("tare")
    np.testing.assert_allclose(cell.calibration.force_bias, result.estimate.force_bias)


def test_a_tare_from_another_thread_is_served_by_the_reading_loop(nothing_left_running):
    """As a ROS service callback would: the thread reading batches serves the tare; every read reaches it."""
    results = []
    with ftacq.open_cell(sim=True) as cell:
        asker = threading.Thread(target=lambda: results.append(cell.tare(seconds=0.2)), name="test-tare")
        batches = []
        for batch in cell.batches(seconds=3 * SECONDS):
            batches.append(batch)
            if len(batches) == 5:
                asker.start()
        asker.join()
    assert results and np.all(np.abs(results[0].estimate.change) < 0.05)  # the true calibration: nothing to change
    assert np.all(np.diff(np.concatenate([b.sequence for b in batches])) > 0)


def test_a_listener_gets_every_read_and_is_closed_once(nothing_left_running):
    seen: list[events.WrenchSamples] = []
    closed = []
    with ftacq.open_cell(sim=True) as cell:
        cell.add_listener(lambda e: seen.append(e) if isinstance(e, events.WrenchSamples) else None,
                          close=lambda: closed.append(len(seen)))
        batches = list(cell.batches(seconds=SECONDS))
    assert closed == [len(seen)]
    # (the listeners' thread joins consecutive reads; a read left uncompensated has no compensated wrench)
    np.testing.assert_array_equal(np.vstack([e.batch.wrench for e in seen]), np.vstack([b.raw for b in batches]))
    np.testing.assert_array_equal(np.concatenate([e.sample_time_s for e in seen]),
                                  np.concatenate([b.time_s for b in batches]))
    compensated = np.vstack([e.compensated if e.compensated is not None else np.full((len(e), 6), np.nan)
                             for e in seen])
    np.testing.assert_array_equal(compensated, np.vstack([b.compensated for b in batches]))


class Boom(Exception):
    pass


def sigint_now() -> None:
    """Ctrl-C: SIGINT to this process (delivered to the main thread), from a thread of its own, joined."""
    sender = threading.Thread(target=os.kill, args=(os.getpid(), signal.SIGINT), name="test-sigint")
    sender.start()
    sender.join()


@pytest.mark.parametrize("how", ["normally", "exception", "keyboard-interrupt", "sigint"])
def test_leaving_the_block_leaves_nothing_running(tmp_path, how, nothing_left_running):
    if how == "sigint" and signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT does not have Python's handler here")
    expected = {"normally": contextlib.nullcontext(), "exception": pytest.raises(Boom),
                "keyboard-interrupt": pytest.raises(KeyboardInterrupt), "sigint": pytest.raises(KeyboardInterrupt)}[how]
    path = tmp_path / "run.csv"
    rows = 0
    with expected:
        with ftacq.open_cell(sim=ftacq.SimOptions(jog=True), record=path) as cell:
            for batch in cell.batches(seconds=20):
                rows += len(batch)
                if rows > 2000:
                    if how == "normally":
                        break
                    if how == "exception":
                        raise Boom
                    if how == "keyboard-interrupt":
                        raise KeyboardInterrupt
                    sigint_now()
    assert cell.summary is not None and cell.summary.samples >= rows
    assert read_record(path).size == cell.summary.samples  # the record finished with every read


def test_while_run_streams_another_thread_reads_the_bias_and_tares(nothing_left_running):
    """``ftacq monitor``'s way (``cell.run`` reads until stopped) with a service thread beside it, as a ROS 2 tare
    service would be: the bias reads without waiting for the run, the run's reads serve the tare, a notice says it."""
    notices: list[events.Notice] = []
    found = {}
    stop = threading.Event()

    def service(cell) -> None:
        try:
            found["bias"] = cell.bias
            found["tare"] = cell.tare(seconds=0.2)
        finally:
            stop.set()

    with ftacq.open_cell(sim=True) as cell:
        cell.add_listener(lambda e: notices.append(e) if isinstance(e, events.Notice) else None)
        thread = threading.Thread(target=service, args=(cell,), name="test-service")
        thread.start()
        summary = cell.run(stop=stop)
        thread.join()
    assert found["bias"].bias.shape == (6,) and np.all(found["bias"].sigma > 0)
    assert np.all(np.abs(found["tare"].estimate.change) < 0.05)  # the true calibration: nothing to change
    assert any(n.source == "tare" and n.text.startswith("tared at the current pose") for n in notices)
    assert summary.samples > 0 and not summary.warnings


def test_a_tare_while_the_arm_moves_fails_and_changes_nothing(nothing_left_running):
    from procedures.live_tare import TareError

    with ftacq.open_cell(sim=ftacq.SimOptions(jog=True)) as cell:
        before = cell.calibration
        with pytest.raises(TareError, match="not still"):
            cell.tare(timeout_s=1.5)  # the simulated technician jogs for its first 8 s
        assert cell.calibration is before and np.all(cell.drift.bias_offset == 0)
        assert sum(len(b) for b in cell.batches(seconds=0.2)) > 0  # the stream goes on


def test_ftacq_monitor_is_a_client_of_the_session(tmp_path, monkeypatch, nothing_left_running):
    """Not a second path: the command opens its cell with open_cell, and its record is that cell's."""
    import ftacq.app.session as session
    from ftacq.app.cli import main as ftacq_main

    opened = []

    def spy(*args, **kwargs):
        opened.append(session_open(*args, **kwargs))
        return opened[-1]

    session_open = session.open_cell
    monkeypatch.setattr(session, "open_cell", spy)
    record = tmp_path / "monitor.csv"
    assert ftacq_main(["monitor", "--sim", "--sim-still", "--seconds", "1", "--record", str(record),
                       "--record-rate", "0", "--save", str(tmp_path / "monitor.rrd")]) == 0
    assert len(opened) == 1 and opened[0].summary.samples == read_record(record).size > 0


def test_a_tare_inside_the_loop_hands_the_loop_every_read_it_made(tmp_path, nothing_left_running):
    path = tmp_path / "run.csv"
    yielded = tared = 0
    with ftacq.open_cell(sim=True, record=path) as cell:
        for batch in cell.batches(seconds=2 * SECONDS):
            yielded += len(batch)
            if not tared and yielded > 1000:
                tared = cell.summary.samples
                cell.tare(seconds=0.2)
                assert cell.summary.samples > tared  # the tare read on its own
    assert yielded == read_record(path).size
