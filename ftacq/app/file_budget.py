"""What a long ``ftacq monitor`` writes to disk: ``--record`` (CSV) and ``--save`` (.rrd) keep every k-th sample so
that an hour fits :data:`ftacq.decimation.DEFAULT_BUDGET_BYTES_PER_H` (1 GB/h each), unless ``--record-rate`` /
``--save-rate`` name a rate (0: every sample). A live viewer (``--spawn``, ``--connect``, ``--serve``) still gets
every sample. The command prints what each file keeps and its size per hour."""

from __future__ import annotations

import argparse
from typing import Any

from ftacq.decimation import (CSV_BYTES_PER_SAMPLE, DEFAULT_BUDGET_BYTES_PER_H, RRD_BYTES_PER_SAMPLE, every_for,
                              size_text)


def _rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value >= 0.0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text}: must be a rate ≥ 0 Hz (0 = every sample)")
    return value


def add_budget_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--record-rate`` and ``--save-rate``."""
    budget = f"{DEFAULT_BUDGET_BYTES_PER_H / 1e9:g} GB per hour"
    parser.add_argument("--record-rate", type=_rate, metavar="HZ",
                        help=f"samples per second written to --record (default: as many as fit {budget}, about "
                             "1 in 8 at 7 kHz; 0 = every sample, about 7 GB/h)")
    parser.add_argument("--save-rate", type=_rate, metavar="HZ",
                        help=f"wrench samples per second written to --save (default: as many as fit {budget}, about "
                             "1 in 5 at 7 kHz; 0 = every sample, about 4 GB/h); a live viewer gets every sample")


def record_budget(sensor_rate_hz: float, record_rate_hz: float | None) -> tuple[int, str]:
    """Return (k: keep every k-th sample of the CSV record, the line saying what it keeps and its size per hour)
    for ``record_rate_hz`` (None: as many as fit the budget; 0: every sample)."""
    every = every_for(sensor_rate_hz, CSV_BYTES_PER_SAMPLE, record_rate_hz)
    return every, (size_text(sensor_rate_hz, every, CSV_BYTES_PER_SAMPLE)
                   + ("" if record_rate_hz is not None else " (--record-rate to change)"))


def apply_save_budget(args: argparse.Namespace, sensor_rate_hz: float, dashboard: Any, saved: bool) -> list[str]:
    """Thin the saved dashboard recording (``saved``: ``dashboard`` writes to a file); return the line saying what
    it keeps and its size per hour (none when nothing is saved)."""
    if not saved:
        return []
    save_every = every_for(sensor_rate_hz, RRD_BYTES_PER_SAMPLE, getattr(args, "save_rate", None))
    dashboard.thin_wrenches(save_every)
    return [f"--save {getattr(args, 'save', None) or '(the saved recording)'}: "
            f"{size_text(sensor_rate_hz, save_every, RRD_BYTES_PER_SAMPLE)}"
            + ("" if getattr(args, "save_rate", None) is not None else " (--save-rate to change)")]


__all__ = ["add_budget_args", "record_budget", "apply_save_budget"]
