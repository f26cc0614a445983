"""Test helpers for the live monitor and the dashboard: a scripted sensor (pre-computed batches of the simulated
cell's physics, no transport), an arm standing still, and recordings to read back."""

from __future__ import annotations

import socket
import threading
import uuid
from pathlib import Path

import numpy as np
import rerun as rr

from drivers.sensor import SensorHealth, WrenchBatch
from ftacq.app.dashboard import layout
from ftacq.app.dashboard.listener import DashboardListener
from ftacq.app.dashboard.recorder import Dashboard
from ftacq.errors import DeviceTimeoutError
from ftacq.kinematics import flange_pose, ur_model
from procedures.monitor import LiveMonitor
from tests.fakes.world import CellTruth, SensorPhysics, SettablePose

MODEL = ur_model("UR5e")
Q_HOME_RAD = np.array([0.3, -1.2, 1.4, -1.6, -1.5, 0.4])
RATE_HZ = 7000.0
BATCH_SAMPLES = 70
VALUE_TOLERANCE = 1e-9


def new_recording(path: Path):
    recording = rr.RecordingStream(layout.APP_ID, recording_id=uuid.uuid4())
    recording.save(path)
    return recording


class ScriptedSensor:
    """A ForceTorqueSensor that hands out pre-computed batches (no transport), then times out.

    ``delivered`` keeps every batch it returned, so a test can compare with what reached the recording.
    """

    def __init__(self, batches: list[WrenchBatch]) -> None:
        self._batches = list(batches)
        self.delivered: list[WrenchBatch] = []
        self.exhausted = threading.Event()
        self._health = SensorHealth(rate_hz=RATE_HZ)

    def read(self, timeout_s: float | None = 1.0) -> WrenchBatch:
        if not self._batches:
            self.exhausted.set()
            raise DeviceTimeoutError("scripted sensor: no more batches")
        batch = self._batches.pop(0)
        self.delivered.append(batch)
        self._health.received += len(batch)
        return batch

    def health(self) -> SensorHealth:
        return self._health.snapshot()


class FixedRobotState:
    """The latest robot state of an arm standing still at ``q_rad``."""

    def __init__(self, q_rad: np.ndarray) -> None:
        self.q_rad = np.asarray(q_rad, dtype=float)
        self.pose = flange_pose(MODEL, self.q_rad)

    def joint_positions(self) -> np.ndarray:
        return self.q_rad.copy()

    def flange_pose(self) -> np.ndarray:
        return self.pose.copy()


def physics_batches(pose: np.ndarray, count: int, seed: int = 1, contact_after: int | None = None) -> list[WrenchBatch]:
    """Return ``count`` batches of the simulated cell's sensor at ``pose``; a 5 N push from batch ``contact_after``."""
    truth = CellTruth()
    physics = SensorPhysics(truth, SettablePose(pose), seed=seed)
    batches = []
    for k in range(count):
        if contact_after is not None and k == contact_after:
            physics.contact_wrench = np.array([0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
        wrench = physics.sample(BATCH_SAMPLES)
        start = k * BATCH_SAMPLES
        batches.append(WrenchBatch(
            time_s=1000.0 + (start + np.arange(BATCH_SAMPLES)) / RATE_HZ,
            wrench=wrench,
            counts=np.round(wrench * 1e6).astype(np.int64),
            status=np.zeros(BATCH_SAMPLES, dtype=np.uint32),
            sequence=start + np.arange(BATCH_SAMPLES, dtype=np.int64),
            saturated=np.zeros(BATCH_SAMPLES, dtype=bool),
            device_time_s=5.0 + (start + np.arange(BATCH_SAMPLES)) / RATE_HZ,  # the sensor's own sample clock
        ))
    return batches


def dashboard_listener(recording, model=MODEL) -> DashboardListener:
    """The dashboard as the monitor's listener, strict (a Rerun misuse fails the test)."""
    return DashboardListener(Dashboard(recording, strict=True), model=model)


def read_record(path: Path) -> np.ndarray:
    """Read a monitor record CSV (``#`` comment lines, then a header) as a structured array."""
    lines = [line for line in Path(path).read_text().splitlines() if not line.startswith("#")]
    return np.genfromtxt(lines, delimiter=",", names=True)


def run_until_exhausted(monitor: LiveMonitor, sensor: ScriptedSensor):
    stop = threading.Event()
    watcher = threading.Thread(target=lambda: (sensor.exhausted.wait(30.0), stop.set()), name="test-watcher")
    watcher.start()
    try:
        return monitor.run(stop=stop)
    finally:
        stop.set()
        sensor.exhausted.set()
        watcher.join()


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
