"""The live part of ``benchmarks/dynamics.py --live-minutes M`` (issue 27): minutes of ``ftacq monitor`` with dynamic
compensation on a simulated cell whose devices keep their own clocks, while a separate process jogs the arm.

The cell: UR5e (``--model``; a CB3 such as UR5 streams its states at 125 Hz) in real time, the Net F/T at 7 kHz in
its own process, its sample clock ``--sensor-rate-error`` off the host's (150 ppm by default), sending in bursts with
jitter and skipping what its sender cannot send within ``--sensor-backlog-s`` (the simulated box's process
descheduled: ``ft_sequence`` jumps); the controller stamps on its own clock with send jitter (tests/fakes/cell.py
``SimClocks``). A 4.2 kg tool (the default inertia scaled by
its mass), no contact, ``motion_noise_gain`` 0.

Steps: the static calibration (controller at time scale 0), the excitation stage in real time and the inertia
identified from it (with ``--burners N`` CPU-burning processes already running: the sensor skips samples under
that load), then ``ftacq monitor --record`` as its own process with the identified calibration for M minutes while
``python -m tests.fakes.jog`` (its own ur-rtde client) makes a moveJ at 1 rad/s, 2 rad/s² every ``--every-s``
(wrist included). Per minute of the record: the compensated wrench's error while moving (the truth is zero) with
the dynamic model (what the monitor wrote) and with the static model (the same samples compensated offline with
the static part of the calibration), beside the at-rest per-sample noise of that minute. The monitor's losses and
its CPU share of one core.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

TOOL_MASS_KG = 4.2
REST_MARGIN_S = 1.0
"""At-rest noise: the samples from this long after a move ends to this long before the next starts, s."""
READY_TIMEOUT_S = 90.0
"""The monitor's start-up (imports, connections, viewer) within this, s."""
BURNER = "while True: pass"
STOP_TIMEOUT_S = 120.0
"""The monitor stops (record written) within this after SIGINT, s; else its stacks are dumped and it is killed."""


@contextlib.contextmanager
def burners(count: int):
    """Run ``count`` CPU-burning Python processes for the block (stopped by their pids at the end)."""
    processes = [subprocess.Popen([sys.executable, "-c", BURNER]) for _ in range(count)]
    try:
        yield processes
    finally:
        for process in processes:
            process.kill()
            process.wait(timeout=10)


def heavy_truth():
    """The benchmark's truth: a 4.2 kg tool, the default inertia scaled by the mass, no motion noise."""
    from tests.fakes.world import CellTruth

    base = CellTruth()
    scale = TOOL_MASS_KG / base.mass_kg
    inertia = tuple(tuple(scale * v for v in row) for row in base.inertia_kg_m2)
    return CellTruth(mass_kg=TOOL_MASS_KG, inertia_kg_m2=inertia, motion_noise_gain=0.0)


def wait_for_text(path: Path, text: str, timeout_s: float) -> None:
    """Wait until the file holds ``text`` (the monitor's stderr, written by that process), at most ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if text in path.read_text(encoding="utf-8", errors="replace"):
            return
        time.sleep(0.2)  # a benchmark polling another process's log; tests use events
    raise TimeoutError(f"{text!r} not in {path.name} within {timeout_s} s: "
                       f"{path.read_text(encoding='utf-8', errors='replace')[-2000:]}")


def read_record(path: Path) -> dict[str, np.ndarray]:
    """The monitor's ``--record`` CSV as columns (comment lines skipped)."""
    with path.open(encoding="utf-8") as handle:
        for line in handle:
            if not line.startswith("#"):
                columns = line.strip().split(",")
                break
        from ftacq.channels import CONTACT_COLUMNS
        from ftacq.posefile import POSE_COLUMNS

        wanted = ["time_s", *POSE_COLUMNS, *CONTACT_COLUMNS]
        wanted += [name for name in ("sample_time_s",) if name in columns]  # the sample's host time, if recorded
        rows = (_filled(line) for line in handle)  # empty fields (an uncompensated batch) read as NaN
        values = np.loadtxt(rows, delimiter=",", usecols=[columns.index(name) for name in wanted], ndmin=2)
    return {name: values[:, i] for i, name in enumerate(wanted)}


def _filled(line: str) -> str:
    """A CSV line with its empty fields written as nan."""
    line = line.rstrip("\n")
    while ",," in line:
        line = line.replace(",,", ",nan,")
    if line.endswith(","):
        line += "nan"
    return "nan" + line if line.startswith(",") else line


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def live_run(cell, calibration_path: Path, minutes: float, every_s: float, folder: Path, seed: int,
             keep: Path | None = None, model: str = "UR5e") -> dict:
    """Run the monitor and the jog for ``minutes``; return the record, the moves and the monitor's figures."""
    import psutil

    cell_toml = folder / "CELL.toml"
    cell_toml.write_text(f'[robot]\nhost = "{cell.robot_host}"\nmodel = "{model}"\n[sensor]\nurl = "{cell.sensor_url}"\n',
                         encoding="utf-8")
    record_path, err_path = folder / "record.csv", folder / "monitor.err"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    moves = max(2, int(round(minutes * 60.0 / every_s)))
    with err_path.open("w", encoding="utf-8") as err:
        monitor = subprocess.Popen([sys.executable, "-m", "ftacq.app.cli", "monitor", "--config", str(cell_toml),
                                    "--calibration", str(calibration_path), "--record", str(record_path),
                                    "--record-rate", "0",  # every sample: the noise figures need them all
                                    "--seconds", str(minutes * 60.0 + 120.0)],
                                   stdout=subprocess.PIPE, stderr=err, text=True, env=env, cwd=folder)
    try:
        wait_for_text(err_path, "dynamic compensation", READY_TIMEOUT_S)
        process = psutil.Process(monitor.pid)
        before = cell.netft.stats()
        cpu_start = (sum(process.cpu_times()[:2]), time.monotonic())
        jog = subprocess.run([sys.executable, "-m", "tests.fakes.jog", "--host", cell.robot_host, "--moves",
                              str(moves), "--every-s", str(every_s), "--speed", "1.0", "--acc", "2.0", "--seed",
                              str(seed)], capture_output=True, text=True, env=env, cwd=ROOT,
                             timeout=minutes * 60.0 + 300.0)
        cpu_end = (sum(process.cpu_times()[:2]), time.monotonic())
        after = cell.netft.stats()
        skipped = after["skipped_backlog"] - before["skipped_backlog"]
        send_errors = after["send_errors"] - before["send_errors"]
    finally:
        monitor.send_signal(signal.SIGINT)
        try:
            out, _ = monitor.communicate(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:  # it did not stop: where its threads wait (ftacq's SIGUSR1 stack dump)
            monitor.send_signal(signal.SIGUSR1)
            time.sleep(2.0)  # the dump is written by the monitor's own process; nothing to wait on from here
            monitor.kill()
            monitor.communicate(timeout=30)
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
                shutil.copy(err_path, keep / "monitor.err")
            raise RuntimeError(f"the monitor did not stop within {STOP_TIMEOUT_S:g} s of SIGINT; its threads' stacks "
                               f"(SIGUSR1): {err_path.read_text(encoding='utf-8', errors='replace')[-6000:]}") from None
    if jog.returncode != 0:
        raise RuntimeError(f"jog failed: {jog.stderr[-2000:]}")
    (folder / "jog.jsonl").write_text(jog.stdout, encoding="utf-8")
    if keep is not None:  # the record and the jog's moves, to look into a run afterwards
        keep.mkdir(parents=True, exist_ok=True)
        for name in ("record.csv", "jog.jsonl", "monitor.err"):
            shutil.copy(folder / name, keep / name)
    lines = [json.loads(line) for line in jog.stdout.splitlines() if line.startswith("{")]
    return {"record": read_record(record_path), "moves": [line for line in lines if "move" in line],
            "summary": [line for line in out.splitlines() if line.startswith(("ftacq monitor:", "dynamic"))],
            "stderr": err_path.read_text(encoding="utf-8", errors="replace"),
            "cpu_fraction": (cpu_end[0] - cpu_start[0]) / (cpu_end[1] - cpu_start[1]),
            "skipped_live": skipped, "send_errors_live": send_errors}


def per_minute(run: dict, static) -> list[str]:
    """Lines of the per-minute table: error while moving (dynamic, static) beside the at-rest noise."""
    from ftacq.channels import CONTACT_COLUMNS, WRENCH_COLUMNS
    from ftacq.so3 import rotation_from_rotvec

    record, moves = run["record"], run["moves"]
    t = record.get("sample_time_s", record["time_s"])  # when the sample was taken, else when it was received
    contact = np.column_stack([record[c] for c in CONTACT_COLUMNS])
    raw = np.column_stack([record[c] for c in WRENCH_COLUMNS])
    moving = np.zeros(t.size, dtype=bool)
    rest = np.zeros(t.size, dtype=bool)
    for index, move in enumerate(moves):
        moving |= (t >= move["start_s"]) & (t <= move["end_s"])
        following = moves[index + 1]["start_s"] if index + 1 < len(moves) else move["end_s"] + 10.0
        rest |= (t >= move["end_s"] + REST_MARGIN_S) & (t <= following - REST_MARGIN_S)
    valid = np.all(np.isfinite(contact), axis=1) & np.all(np.isfinite(raw), axis=1) & np.isfinite(t)
    first = moves[0]["start_s"]
    minute = np.floor((t - first) / 60.0).astype(int)
    lines = [f"{'minute':>6} {'moving':>7} {'uncomp.':>7} {'noise F N':>10} {'noise T N·m':>12} {'dynamic F RMS (max)':>22} "
             f"{'dynamic T RMS (max)':>22} {'×F':>5} {'×T':>5} {'static F RMS':>13} {'static T RMS':>13} "
             f"{'×F':>5} {'×T':>5}"]
    worst = [0.0, 0.0, np.inf, np.inf]
    for m in range(int(minute[moving].max()) + 1 if moving.any() else 0):
        here = valid & (minute == m)
        on, still = here & moving, here & rest
        uncompensated = int(np.count_nonzero(~valid & (minute == m) & moving))
        if not on.any() or still.sum() < 100:
            continue
        noise = contact[still].std(axis=0)
        noise_f, noise_t = rms(noise[:3]), rms(noise[3:])
        dyn = contact[on]
        pose = np.column_stack([record[c][on] for c in ("rx", "ry", "rz")])
        stat = static.compensate(raw[on], np.swapaxes(rotation_from_rotvec(pose), -1, -2))
        dyn_f, dyn_t, st_f, st_t = rms(dyn[:, :3]), rms(dyn[:, 3:]), rms(stat[:, :3]), rms(stat[:, 3:])
        worst = [max(worst[0], dyn_f / noise_f), max(worst[1], dyn_t / noise_t), min(worst[2], st_f / noise_f),
                 min(worst[3], st_t / noise_t)]
        lines.append(f"{m + 1:>6} {on.sum():>7} {uncompensated:>7} {noise_f:>10.4f} {noise_t:>12.5f} "
                     f"{f'{dyn_f:.4f} ({np.abs(dyn[:, :3]).max():.3f})':>22} "
                     f"{f'{dyn_t:.5f} ({np.abs(dyn[:, 3:]).max():.4f})':>22} {dyn_f / noise_f:>5.2f} "
                     f"{dyn_t / noise_t:>5.2f} {st_f:>13.4f} {st_t:>13.5f} {st_f / noise_f:>5.1f} {st_t / noise_t:>5.1f}")
    lines.append(f"worst minute: dynamic {worst[0]:.2f}× / {worst[1]:.2f}× the noise (F / T; goal ≤ 1.5) -> "
                 f"{'met' if max(worst[:2]) <= 1.5 else 'NOT met'}; static at least {worst[2]:.1f}× / {worst[3]:.1f}× "
                 f"(goal ≥ 5) -> {'met' if min(worst[2:]) >= 5 else 'NOT met'}")
    return lines


def main(minutes: float, every_s: float, burner_count: int, sensor_rate_error: float, backlog_s: float,
         seed: int, keep: Path | None = None, sim_priority: int = 0, model: str = "UR5e",
         version: str | None = None) -> int:
    from drivers.robot import MotionLimits
    from drivers.sensor import open_sensor
    from drivers.ur import URRobot
    from drivers.ur_stream import URStateStream
    from ftacq.calfile import save_calibration
    from ftacq.dynamics import identify_dynamics
    from ftacq.kinematics import ur_model
    from procedures.excitation import plan_excitation, record_excitation
    from procedures.plan import PlanSettings
    from tests.fakes.cell import SimClocks, SimulatedCell, fast_config, run_calibration

    # The benchmark stands for a user at a terminal: its SIGINT is the user's Ctrl-C. Started in the background
    # (`cmd &` in a shell without job control, nohup) it inherits SIGINT ignored and so would the monitor, which
    # then rightly keeps it ignored and never stops (the "monitor did not stop on SIGINT" runs of issue 27).
    signal.signal(signal.SIGINT, signal.default_int_handler)  # children start with SIGINT at its default
    truth = heavy_truth()
    clocks = replace(SimClocks(), sensor_rate_error=sensor_rate_error, sensor_max_backlog_s=backlog_s)
    settings = PlanSettings(joint_speed_rad_s=1.0, joint_acceleration_rad_s2=2.0)
    started = time.monotonic()
    lines = [f"live run: {model}{f' at {version}' if version else ''}, {minutes:g} min, jog every {every_s:g} s (1 rad/s, 2 rad/s², wrist included, separate "
             f"ur-rtde process), {burner_count} CPU burners, {TOOL_MASS_KG} kg tool, sensor clock "
             f"{sensor_rate_error * 1e6:+.0f} ppm, bursts {clocks.sensor_burst_interval_s * 1e3:g} ms "
             f"(jitter {clocks.sensor_burst_jitter_s * 1e3:g} ms), sensor backlog {backlog_s * 1e3:g} ms, controller "
             f"{clocks.controller_rate_error * 1e6:+.0f} ppm, send jitter {clocks.controller_send_jitter_s * 1e3:g} ms; "
             f"simulated devices at {f'SCHED_FIFO {sim_priority}' if sim_priority else 'normal priority'}; "
             f"load average at start {os.getloadavg()[0]:.1f}"]
    with SimulatedCell(truth=truth, time_scale=0.0, rate_hz=7000.0, clocks=clocks, sensor_process=True,
                       realtime_priority=sim_priority, model=model, version=version) as cell, \
            tempfile.TemporaryDirectory() as folder_name:
        folder = Path(folder_name)
        config = fast_config(cell, random_count=12, validation_count=4, average_time_s=0.3)
        _, result = run_calibration(cell, config)
        static = replace(result.identification.calibration, sensor_offset=np.array(truth.sensor_offset_m))
        cell.controller.set_time_scale(1.0)
        with burners(burner_count):
            with URRobot(cell.robot_host, MotionLimits(1.0, 2.0), model=model) as robot, \
                    URStateStream(cell.robot_host) as stream:
                sensor = open_sensor(cell.sensor_url)
                sensor.start()
                try:
                    skipped_before = cell.netft.stats()["skipped_backlog"]
                    record = record_excitation(plan_excitation(settings, robot.joint_positions()), robot, sensor,
                                               stream)
                    skipped_excitation = cell.netft.stats()["skipped_backlog"] - skipped_before
                finally:
                    sensor.close()
            identified = identify_dynamics(static, record, ur_model(model))
            dynamic = identified.calibration
            error = np.linalg.norm(dynamic.inertia - truth.inertia) / np.linalg.norm(truth.inertia)
            lines.append(f"identified (excitation under the same load, {len(record.sensor_time_s)} sensor samples, "
                         f"{skipped_excitation} skipped by the sensor): inertia error {100 * error:.2f} % (Frobenius, "
                         f"about the COM; goal ≤ 2 %), mass {1e3 * (dynamic.mass_kg - truth.mass_kg):+.2f} g, lag "
                         f"{1e3 * identified.lag_s:.2f} ms")
            save_calibration(folder / "calibration.json", dynamic)
            run = live_run(cell, folder / "calibration.json", minutes, every_s, folder, seed, keep, model)
        lines += per_minute(run, static)
        lines.append(f"monitor (own process, dynamic, --record at 7 kHz): CPU {100 * run['cpu_fraction']:.1f} % of one "
                     f"core (goal < 50 %); the simulated sensor's sender skipped {run['skipped_live']} samples meanwhile "
                     f"(at the source: ft_sequence jumps, not the monitor's losses; its 'lost' below counts RDT "
                     f"sequence gaps, split into the kernel's drops at the monitor's socket, the reader's ring "
                     f"overflows, and the rest: never reached the socket); the sender's sendto failed for "
                     f"{run['send_errors_live']} datagrams (on loopback a datagram stays charged to the sender's "
                     f"buffer until the receiver reads it: a monitor not draining its socket fills it)")
        lines += ["  " + line for line in run["summary"]]
        lines += ["  " + line.strip() for line in run["stderr"].splitlines() if "compensation" in line or "receive" in line][:5]
    lines.append(f"wall time {time.monotonic() - started:.0f} s, load average at end {os.getloadavg()[0]:.1f}")
    print("\n".join(lines))
    return 0
