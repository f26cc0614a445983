"""``ftacq sensor``: look at, record and bias an ATI F/T sensor named by URL (any transport).

- ``ftacq sensor info URL [--seconds S]``: serial, firmware, units, counts per unit, configured and measured rate,
  status and the mean wrench over a short window.
- ``ftacq sensor record URL --seconds S -o FILE.csv``: one CSV row per sample (``t,fx,fy,fz,tx,ty,tz,status``
  then ``saturated,seq``, raw ``count_*`` columns, the sensor's own ``device_time_s`` and its ``sample_time_s`` on
  the host clock: :data:`CSV_COLUMNS`) in s, N and N·m; written atomically; Ctrl-C keeps what was
  recorded; prints a summary with the stream's health counters and its gaps (how many, the longest, samples
  lost). Exits 1 when the sensor lost more than ``--max-lost-fraction`` (default 0.1 %) of the samples it
  produced during the recording (the CSV still keeps every sample received).
- ``ftacq sensor bias URL``: tare the sensor and print the residual mean.

Sensors come from :func:`drivers.sensor.open_sensor` (``netft://…`` or ``can://…``).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from ftacq.app.helptext import examples
from ftacq.channels import WRENCH_COLUMNS
from ftacq.errors import DeviceError, InputError

INFO_WINDOW_S = 0.5
"""Default window over which ``info`` measures the rate, status and mean wrench, seconds."""
BIAS_CHECK_WINDOW_S = 0.2
"""Window averaged after a bias to show the residual, seconds."""
READ_TIMEOUT_S = 1.0
"""Longest single wait for samples while recording (the driver reconnects meanwhile), seconds."""
CSV_COLUMNS = ("t", *WRENCH_COLUMNS, "status", "saturated", "seq", *(f"count_{name}" for name in WRENCH_COLUMNS),
               "device_time_s", "sample_time_s")
"""The sensor record's columns (docs/formats.md, "Sensor record"): ``t`` the receive time (s since the first
sample's), ``device_time_s`` the sample's time on the sensor's own clock (s; empty for a sensor without one),
``sample_time_s`` that time on the host clock (s since the first sample's receive time, as ``t``: the minimum-delay
line, :class:`ftacq.timebase.SampleClock`; the receive time without a device clock)."""
CSV_FORMATS = ["%.6f"] + ["%.9g"] * 6 + ["%d"] * 9 + ["%.9f", "%.7f"]
MAX_LOST_FRACTION = 0.001
"""Default ``record --max-lost-fraction``: the recording fails (exit 1) when more than this fraction of the samples
the sensor produced (received + lost) were lost. 0.1 % is 7 samples a second at 7 kHz: more than a healthy link
loses, far less than any silence of the link."""
BIAS_WARNING = ("warning: this zero includes the tool's weight at the current orientation: every calibration made "
                "before it (and every one made after it, once the box is power-cycled or biased again) no longer "
                "fits its biases. Calibrate again, or to re-zero with the tool on while keeping a calibration "
                "valid use `ftacq tare --config CELL.toml --calibration CAL.json -o NEW.json` instead")
"""Printed after every ``ftacq sensor bias``."""
HEALTH_FIELDS = ("received", "lost", "duplicate", "out_of_order", "malformed", "foreign", "stalled", "saturated",
                 "status_errors", "timeouts", "restarts", "reconnects")


def register(subparsers) -> None:
    """Add ``ftacq sensor {info,record,bias}``."""
    parser = subparsers.add_parser("sensor", help="inspect, record or bias an ATI F/T sensor",
                                   description="Look at, record and bias an ATI F/T sensor named by URL "
                                               "(netft:// or can://).",
                                   **examples("ftacq sensor info netft://192.168.1.1",
                                              "ftacq sensor record can://pcan/PCAN_USBBUS1 --seconds 10 -o still.csv"))
    commands = parser.add_subparsers(dest="sensor_command", metavar="ACTION")
    url_help = ("sensor URL: netft://HOST[:RDT_PORT][?tcp_port=N&http_port=N&rate_hz=R] or "
                "can://INTERFACE/CHANNEL[?base=0x20&bitrate=250000]")

    info = commands.add_parser("info", help="serial, units, counts per unit, rate, status",
                               **examples("ftacq sensor info netft://192.168.1.1",
                                          "ftacq sensor info can://socketcan/can0 --seconds 5"))
    info.add_argument("url", nargs="?", help=url_help)
    info.add_argument("--sim", action="store_true", help=SIM_HELP)
    info.add_argument("--seconds", type=float, default=INFO_WINDOW_S, metavar="S",
                      help="measure rate and mean wrench over S seconds (default %(default)s)")
    info.set_defaults(func=run_info)

    record = commands.add_parser("record", help="record samples to CSV (s, N, N·m)",
                                 **examples("ftacq sensor record netft://192.168.1.1 --seconds 10 -o still.csv"))
    record.add_argument("url", nargs="?", help=url_help)
    record.add_argument("--sim", action="store_true", help=SIM_HELP)
    record.add_argument("--seconds", type=float, required=True, metavar="S", help="record for S seconds")
    record.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.csv", help="CSV file to write")
    record.add_argument("--max-lost-fraction", type=float, default=MAX_LOST_FRACTION, metavar="F",
                        help="exit 1 when more than this fraction of the samples the sensor produced were lost "
                             "(default %(default)g = 0.1 %%)")
    record.set_defaults(func=run_record)

    bias = commands.add_parser(
        "bias", help="zero the sensor at the current load (invalidates earlier calibrations; see ftacq tare)",
        description="Zero the sensor at the current load (the Net F/T box's own bias, RDT command 0x0042; on CAN a "
                    "host-side zero). The zero includes the tool's weight at this orientation, so every "
                    "calibration made before it no longer fits: calibrate again after a box bias. To re-zero "
                    "with the tool on and keep a calibration valid, use `ftacq tare` instead.",
        **examples("ftacq sensor bias netft://192.168.1.1"))
    bias.add_argument("url", help=url_help)
    bias.set_defaults(func=run_bias)

    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])


SIM_HELP = "use the simulated cell's Net F/T sensor (7 kHz on loopback) instead of URL"


@contextlib.contextmanager
def sensor_url(args: argparse.Namespace) -> Iterator[str]:
    """The URL to open: ``args.url``, or with ``--sim`` the simulated cell's sensor (started and stopped here)."""
    if args.sim:
        if args.url:
            raise InputError(f"give a sensor URL or --sim, not both (got {args.url!r} and --sim)")
        from ftacq.app.simcell import simulated_cell

        with simulated_cell(sensor="netft") as cell:
            yield cell.sensor_url
    else:
        if not args.url:
            raise InputError("give the sensor URL (e.g. netft://192.168.1.1), or --sim for the simulated sensor")
        yield args.url


def _with_sim_url(command: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Run ``command`` with ``args.url`` set by :func:`sensor_url` (the simulated sensor's with ``--sim``)."""
    @functools.wraps(command)
    def run(args: argparse.Namespace) -> int:
        with sensor_url(args) as url:
            args.url = url
            return command(args)

    return run


def _open(url: str):
    from drivers.sensor import open_sensor

    sensor = open_sensor(url)
    sensor.start()
    return sensor


def _positive_seconds(value: float, flag: str = "--seconds") -> float:
    if not value > 0 or value != value or value == float("inf"):
        raise InputError(f"{flag} {value}: must be a positive, finite number of seconds")
    return float(value)


def describe_status(sensor, status: int) -> str:
    """Return ``0x…: names`` for a status word of this sensor's transport."""
    return sensor.describe_status(status)


def health_line(health) -> str:
    """Return the health counters as ``name n`` pairs, comma-separated."""
    return ", ".join(f"{name} {getattr(health, name)}" for name in HEALTH_FIELDS)


@_with_sim_url
def run_info(args: argparse.Namespace) -> int:
    """Print what the sensor says about itself and a short look at its stream."""
    from drivers.sensor import WrenchBatch

    window_s = _positive_seconds(args.seconds)
    sensor = _open(args.url)
    try:
        info = sensor.info
        batches, deadline = [], time.monotonic() + window_s
        while time.monotonic() < deadline:
            batches.append(sensor.read(timeout_s=max(READ_TIMEOUT_S, window_s)))
        batch = WrenchBatch.concatenate(batches)
        health = sensor.health()
    finally:
        sensor.close()
    span_s = float(batch.time_s[-1] - batch.time_s[0]) if len(batch) > 1 else 0.0
    measured_hz = (len(batch) - 1) / span_s if span_s > 0 else 0.0
    lines = [
        ("sensor", args.url),
        ("transport", info.transport),
        ("product", info.extra.get("product", "") or "-"),
        ("serial", info.serial or "-"),
        ("firmware", info.firmware or "-"),
        ("units", f"force {info.force_unit}, torque {info.torque_unit} (reported here in N and N·m)"),
        ("counts per unit", f"{info.counts_per_force:.10g} per {info.force_unit}, "
                            f"{info.counts_per_torque:.10g} per {info.torque_unit}"),
        ("rate", f"{info.rate_hz:g} Hz configured, {measured_hz:.0f} Hz measured over {len(batch)} samples"),
        ("status", describe_status(sensor, int(batch.status[-1])) if len(batch) else "-"),
    ]
    if len(batch):
        good = ~batch.saturated
        mean = batch.wrench[good].mean(axis=0) if good.any() else batch.wrench.mean(axis=0)
        lines.append(("mean wrench", "F [" + ", ".join(f"{v:.4g}" for v in mean[:3]) + "] N, T ["
                      + ", ".join(f"{v:.4g}" for v in mean[3:]) + "] N·m"
                      + ("" if good.all() else f" ({int((~good).sum())} flagged samples excluded)")))
    lines.append(("health", health_line(health)))
    width = max(len(name) for name, _ in lines)
    for name, value in lines:
        print(f"{name + ':':<{width + 1}} {value}")
    return 0


@_with_sim_url
def run_record(args: argparse.Namespace) -> int:
    """Record ``--seconds`` of samples to a CSV; keep what was recorded on Ctrl-C."""
    import numpy as np

    from ftacq.timebase import SampleClock
    from ftacq.errors import DeviceTimeoutError
    from ftacq.fileio import atomic_write

    seconds = _positive_seconds(args.seconds)
    max_lost = args.max_lost_fraction
    if not 0.0 <= max_lost <= 1.0:
        raise InputError(f"--max-lost-fraction {max_lost}: must be a fraction between 0 and 1")
    if args.output.is_dir():
        raise InputError(f"-o {args.output}: is a folder; give a file name such as {args.output / 'wrench.csv'}")
    sensor = _open(args.url)
    samples = read_timeouts = 0
    interrupted = False
    fault: DeviceError | None = None
    first_time_s = None
    clock = SampleClock()
    started = time.monotonic()
    try:
        with atomic_write(args.output) as handle:
            handle.write(",".join(CSV_COLUMNS) + "\n")
            try:
                while time.monotonic() - started < seconds:
                    try:
                        batch = sensor.read(timeout_s=min(READ_TIMEOUT_S, max(seconds - (time.monotonic() - started), 0.01)))
                    except DeviceTimeoutError:
                        read_timeouts += 1
                        continue
                    if first_time_s is None:
                        first_time_s = float(batch.time_s[0])
                    sample_time_s = clock.host_times(batch.time_s, batch.device_time_s) - first_time_s
                    table = np.column_stack([batch.time_s - first_time_s, batch.wrench, batch.status.astype(np.int64),
                                             batch.saturated.astype(np.int64), batch.sequence, batch.counts,
                                             batch.device_time_s, sample_time_s])
                    cells = np.char.mod(CSV_FORMATS, table)
                    cells[cells == "nan"] = ""  # no device clock
                    # one write: Ctrl-C cannot leave half a row
                    handle.write("\n".join(",".join(row) for row in cells) + "\n")
                    samples += len(batch)
            except KeyboardInterrupt:
                interrupted = True
            except DeviceError as error:  # keep what was recorded; report the fault below
                fault = error
        health = sensor.health()
    finally:
        try:
            sensor.close()
        except DeviceError as error:
            print(f"ftacq sensor record: warning: {error}", file=sys.stderr)
    duration_s = time.monotonic() - started
    rate_hz = samples / duration_s if duration_s > 0 else 0.0
    print(f"ftacq sensor record: {samples} samples in {duration_s:.2f} s ({rate_hz:.0f} Hz) → {args.output}"
          + ("; stopped by Ctrl-C (kept what was recorded)" if interrupted else ""))
    print(f"health: {health_line(health)}" + (f", read timeouts {read_timeouts}" if read_timeouts else ""))
    produced = samples + health.lost
    lost_fraction = health.lost / produced if produced else 0.0
    print(f"gaps {health.gaps}, longest {health.longest_gap_s:.3f} s, lost {health.lost} samples "
          f"({lost_fraction:.3%} of the {produced} the sensor produced)")
    if fault is not None:
        print(f"ftacq sensor record: stopped by a sensor fault (kept what was recorded): {fault}", file=sys.stderr)
        return 1
    if interrupted:
        return 130
    if samples == 0:
        print(f"ftacq sensor record: no samples received from {args.url} in {seconds:g} s", file=sys.stderr)
        return 1
    if lost_fraction > max_lost:
        print(f"ftacq sensor record: {health.lost} samples lost beyond the threshold ({lost_fraction:.3%} > "
              f"{max_lost:.3%}, --max-lost-fraction) in {health.gaps} gap(s), the longest "
              f"{health.longest_gap_s:.3f} s; {args.output} keeps every sample received", file=sys.stderr)
        return 1
    return 0


def run_bias(args: argparse.Namespace) -> int:
    """Zero the sensor and print the residual mean over a short window; warn that earlier calibrations no longer fit."""
    sensor = _open(args.url)
    try:
        sensor.bias()
        average = sensor.average(BIAS_CHECK_WINDOW_S)
    finally:
        sensor.close()
    where = "on the device (kept until it is power-cycled or biased again)" if sensor.info.transport == "netft" \
        else "on the host (lasts only while this driver runs)"
    print(f"biased {args.url} {where}")
    print("residual mean: F [" + ", ".join(f"{v:.4g}" for v in average.mean[:3]) + "] N, T ["
          + ", ".join(f"{v:.4g}" for v in average.mean[3:]) + f"] N·m over {average.count} samples")
    print(BIAS_WARNING, file=sys.stderr)
    return 0
