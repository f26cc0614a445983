"""``ftacq monitor --sim`` compensates with the simulated tool's true calibration (inertia included) and prints
no note that does not apply; ``--record`` and ``--save`` keep every k-th sample so that an hour fits 1 GB, and say
so (issue 38, item 6)."""

from __future__ import annotations

import re

import numpy as np

from ftacq.decimation import CSV_BYTES_PER_SAMPLE, DEFAULT_BUDGET_BYTES_PER_H, RRD_BYTES_PER_SAMPLE, Decimator, every_for
from ftacq.app.dashboard import layout
from tests.rrd_reader import read_scalars
from tests.scripted import read_record


def test_the_decimator_keeps_every_kth_sample_across_batches():
    decimator = Decimator(8)
    sizes = [5, 3, 17, 1, 0, 9, 40]
    kept = np.concatenate([offset + decimator.keep(n) for offset, n in zip(np.cumsum([0] + sizes[:-1]), sizes)])
    np.testing.assert_array_equal(kept, np.arange(0, sum(sizes), 8))
    np.testing.assert_array_equal(Decimator(1).keep(4), np.arange(4))


def test_the_default_rates_fit_the_budget_at_7_khz():
    for size in (CSV_BYTES_PER_SAMPLE, RRD_BYTES_PER_SAMPLE):
        every = every_for(7000.0, size)
        assert 7000.0 / every * size * 3600.0 <= DEFAULT_BUDGET_BYTES_PER_H < 7000.0 / (every - 1) * size * 3600.0
    assert every_for(7000.0, CSV_BYTES_PER_SAMPLE, rate_hz=0.0) == 1
    assert every_for(7000.0, CSV_BYTES_PER_SAMPLE, rate_hz=1000.0) == 7


def test_monitor_sim_is_dynamic_says_nothing_that_does_not_apply_and_thins_its_files(tmp_path, capsys):
    from ftacq.app.cli import main

    record, rrd = tmp_path / "m.csv", tmp_path / "m.rrd"
    assert main(["monitor", "--sim", "--seconds", "2", "--record", str(record), "--save", str(rrd)]) == 0
    captured = capsys.readouterr()
    err, out = captured.err, captured.out
    assert "dynamic compensation (tool inertia from the calibration" in err
    assert "static compensation" not in err and "no inertia" not in err
    assert "sensor match not checked" not in err and "records no sensor" not in err
    assert re.search(rf"--record {re.escape(str(record))}: every 8th sample \(875 of 7000 per s\), about 0\.9\d? GB/h",
                     err), err
    assert re.search(r"--save .*: every 5th sample \(1400 of 7000 per s\), about 0\.8\d? GB/h", err), err
    samples = int(re.search(r"(\d+) samples received", out).group(1))
    rows = read_record(record)
    assert rows.size == -(-samples // 8)  # the first sample and every 8th after it
    assert "# rows: every 8th sample (--record-rate)" in record.read_text()
    dropped = int(re.search(r"(\d+) dropped for the viewer", out).group(1))  # whole batches, before thinning
    time_s, _ = read_scalars(rrd, layout.RAW_FORCE)
    assert time_s.size == -(-(samples - dropped) // 5)


def test_tare_sim_says_nothing_about_an_unrecorded_sensor(tmp_path, capsys):
    from ftacq.app.cli import main

    assert main(["tare", "--sim", "-o", str(tmp_path / "tared.json")]) == 0
    captured = capsys.readouterr()
    assert "sensor match not checked" not in captured.err + captured.out
    assert "true biases" in captured.out
