"""``ftacq monitor``'s ROS 2 outputs: the options (``--ros2``, ``--ros2-*``, ``--record X.mcap``) and their listeners.

The listeners are :mod:`procedures.ros2_stream`'s, each behind a direct ``BackgroundListener`` of its own
(:mod:`procedures.delivery`); this module only turns options and CELL.toml keys into them. Needs the ``ros2`` extra
(``pip install 'ftacq[ros2]'``: Cyclone DDS, mcap); without it, asking for either output says so (exit 2).
"""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
from typing import Any, Callable

from ftacq.errors import ConfigError
from ftacq.ros2_names import ROS2_DISTROS
from ftacq.settings import setting_of

DOMAIN_ID_MAX = 232
"""The largest DDS domain id with Cyclone DDS's default port mapping (ROS 2: 0-101 and 215-232 are safe on Linux)."""
ROS2_READ_PERIOD_S = 0.0
"""With --ros2 the monitor reads the sensor this often by default (10 ms otherwise: procedures.monitor.BATCH_PERIOD_S);
0: as soon as the driver has samples (its receive thread wakes the read), so a sample waits for no pacing before it is
published. ``--ros2-read-period`` trades latency for CPU (benchmarks/ros2.py --read-periods-ms)."""
READ_PERIOD_MAX_S = 0.1
"""The longest ``--ros2-read-period``, s (a tenth of a second already delays every message by up to that much)."""
ROS2_HOLD_S = 0.005
"""With --ros2 the dynamic compensation holds the newest robot state's prediction, without waiting, for samples up to
this much newer than that state, s (an error of dW/dt × how far ahead: docs/ros2.md; at 500 Hz the newest state is
2-4 ms old); a read further ahead waits for its states as without --ros2 (up to
procedures.dynamic_compensation.STATE_WAIT_S): a stalled state stream delays it rather than leaving it
uncompensated."""
LISTENER_QUEUE_BATCHES = 1_000_000
"""The ROS 2 listeners' queues hold this many reads before dropping (never, in practice: nothing is lost)."""


def prefer_low_latency(cell: Any, read_period_s: float | None = None) -> None:
    """Make ``cell`` (:class:`ftacq.app.session.Cell`) publish each sample as soon as it can: reads every
    ``read_period_s`` (None: :data:`ROS2_READ_PERIOD_S`, on data), no wait for the robot states of its newest few ms
    (:data:`ROS2_HOLD_S`)."""
    cell.monitor.batch_period_s = ROS2_READ_PERIOD_S if read_period_s is None else float(read_period_s)
    if hasattr(cell.compensator, "hold_s"):
        cell.compensator.hold_s = ROS2_HOLD_S


def add_ros2_args(parser: argparse.ArgumentParser) -> None:
    """Add ``--ros2`` and its options (the record's ``.mcap`` form is ``--record``'s)."""
    group = parser.add_argument_group("ROS 2 (docs/ros2.md; needs pip install 'ftacq[ros2]')")
    group.add_argument("--ros2", action="store_true",
                       help="publish the wrenches, the calibration and the drift tracker's bias as ROS 2 topics over "
                            "DDS, and serve the tare service (no ROS install needed)")
    group.add_argument("--ros2-namespace", metavar="NS",
                       help="namespace of the topics and the service (default: CELL.toml sensor.ros2_namespace, "
                            "/ftacq)")
    group.add_argument("--ros2-domain-id", type=int, metavar="N",
                       help="DDS domain (default: $ROS_DOMAIN_ID, else 0)")
    group.add_argument("--ros2-rate", type=float, metavar="HZ",
                       help="wrench messages per second, each the mean of its window (default 1000; 0: every sample)")
    group.add_argument("--ros2-read-period", type=float, metavar="S",
                       help="seconds between the monitor's sensor reads (default 0: as data arrive, the lowest "
                            "latency; 0.01: the monitor's own pace, a third or less of the added CPU, "
                            "messages up to 10 ms later)")
    group.add_argument("--ros2-reliable", action="store_true",
                       help="reliable wrench topics (default: ROS 2's sensor-data QoS, best effort, keep last 5)")
    group.add_argument("--ros2-distro", choices=ROS2_DISTROS,
                       help="ROS 2 release of the graph, for ros2 node list (default: CELL.toml sensor.ros2_distro, "
                            f"{setting_of('sensor.ros2_distro').default})")
    group.add_argument("--ros2-frame-id", metavar="FRAME",
                       help="header.frame_id of the wrenches: the sensor frame's name (default: CELL.toml "
                            "sensor.frame, ft_sensor)")


def is_bag(path: Path | None) -> bool:
    """Whether ``--record`` asks for an MCAP bag (by its suffix) rather than the CSV."""
    return path is not None and Path(path).suffix.lower() == ".mcap"


def check_ros2_args(args: argparse.Namespace) -> None:
    """Check the options before any device opens (ConfigError: one line, exit 2)."""
    from ftacq.ros2_names import check_frame_id, normalize_namespace
    from ftacq.validation import check_number

    if args.ros2_namespace is not None:
        try:
            normalize_namespace(args.ros2_namespace)
        except ValueError as error:
            raise ConfigError(f"--ros2-namespace: {error}") from None
    if args.ros2_frame_id is not None:
        try:
            check_frame_id(args.ros2_frame_id)
        except ValueError as error:
            raise ConfigError(f"--ros2-frame-id: {error}") from None
    if args.ros2_domain_id is not None:
        check_number(args.ros2_domain_id, "--ros2-domain-id", low=0, high=DOMAIN_ID_MAX)
    if args.ros2_rate is not None:
        check_number(args.ros2_rate, "--ros2-rate", low=0.0, high=1e5)
    if args.ros2_read_period is not None:
        check_number(args.ros2_read_period, "--ros2-read-period", low=0.0, high=READ_PERIOD_MAX_S)
    if args.ros2:
        _domain_id(args)  # $ROS_DOMAIN_ID checked now, before any device opens
    if args.ros2 or is_bag(args.record):
        try:
            import cyclonedds  # noqa: F401
            import mcap  # noqa: F401
        except ImportError as error:
            raise ConfigError(f"--ros2 / --record .mcap need the ros2 extra ({error.name} is missing): "
                              "pip install 'ftacq[ros2]'") from None


class CalibrationText:
    """() → the calibration in force (``calibration()``) as its JSON text, or None: serialized once per calibration
    object, so the bag's metadata, its ``calibration`` message and the latched topic carry the same text (a
    calibration without ``created_utc`` is stamped with the time it is serialized: twice could differ by a second)."""

    def __init__(self, calibration: Callable[[], Any]) -> None:
        self.calibration = calibration
        self._of: Any = None
        self._text: str | None = None

    def __call__(self) -> str | None:
        from ftacq.calfile import calibration_json_text

        now = self.calibration()
        if now is None:
            return None
        if now is not self._of:
            self._of, self._text = now, calibration_json_text(now)
        return self._text


def _failed(what: str, queue: Any) -> str:
    """A last line for a ROS 2 listener that failed (it got no more events after its error), else ""."""
    error = queue.first_error
    return f"{what}: FAILED, stopped at {type(error).__name__}: {error}" if error is not None else ""


def _domain_id(args: argparse.Namespace) -> int:
    if args.ros2_domain_id is not None:
        return int(args.ros2_domain_id)
    value = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not value:
        return 0
    if not value.isdigit() or int(value) > DOMAIN_ID_MAX:
        raise ConfigError(f"ROS_DOMAIN_ID = {value!r}: must be an integer in [0, {DOMAIN_ID_MAX}]")
    return int(value)


def ros2_listeners(args: argparse.Namespace, stack: contextlib.ExitStack, calibration: Callable[[], Any],
                   tare: Callable[[], Any] | None,
                   sensor_rate_hz: Callable[[], float] | None = None) -> tuple[list, list[str]]:
    """The listeners for ``--ros2`` and ``--record X.mcap`` (none without either), closed by ``stack`` (after the
    stream: the bag finished, the node closed). ``calibration()`` the calibration in force (None: raw only; it
    changes with a tare); ``tare()`` the session's live tare (:meth:`ftacq.app.session.Cell.tare`, a
    :class:`procedures.tare.TareResult`), or None; ``sensor_rate_hz()`` the sensor's sample rate once it is open
    (each window's message is sent as soon as its last sample arrives), None: unknown. Also returns a list that the run's last lines are appended to
    once ``stack`` has closed (what was published and recorded)."""
    report: list[str] = []
    if not (args.ros2 or is_bag(args.record)):
        return [], report
    import numpy as np

    from ftacq.settings import SensorConfig
    from procedures.delivery import BackgroundListener
    from procedures.ros2_stream import DEFAULT_RATE_HZ, BagRecorder, Ros2Publisher

    if args.config is not None:
        from ftacq.app.config import load_config

        sensor = load_config(args.config).sensor
    else:
        sensor = SensorConfig()
    namespace = args.ros2_namespace if args.ros2_namespace is not None else sensor.ros2_namespace
    frame_id = args.ros2_frame_id or sensor.frame
    distro = args.ros2_distro or sensor.ros2_distro
    rate_hz = DEFAULT_RATE_HZ if args.ros2_rate is None else args.ros2_rate

    calibration_json = CalibrationText(calibration)

    def reference_bias() -> np.ndarray:
        now = calibration()
        return np.zeros(6) if now is None else np.concatenate([now.force_bias, now.torque_bias])

    from procedures.ros2_stream import Ros2Messages, Ros2Stream

    bag_queue: BackgroundListener | None = None
    publisher: Ros2Publisher | None = None
    def sample_period_s() -> float:
        rate_hz = sensor_rate_hz() if sensor_rate_hz is not None else 0.0
        return 1.0 / rate_hz if rate_hz > 0 else 0.0

    messages = Ros2Messages(frame_id, rate_hz, reference_bias, joint_states=is_bag(args.record),
                            sample_period_s=None if sensor_rate_hz is None else sample_period_s)
    if is_bag(args.record):
        recorder = BagRecorder(args.record, namespace, calibration_json(), metadata={"source": "ftacq monitor"})
        bag_queue = BackgroundListener([recorder], max_queued=LISTENER_QUEUE_BATCHES, period_s=0.05,
                                       name="ftacq-mcap")
        stack.callback(lambda: report.append(_failed("ROS 2 bag", bag_queue) or
                                             f"ROS 2 bag: {recorder.bag.messages} messages recorded in {args.record}"))
        stack.callback(recorder.close)  # after the queue is drained (callbacks run last first)
        stack.callback(bag_queue.close)
    if args.ros2:
        from drivers.ros2.node import Ros2Node

        node = Ros2Node(namespace, _domain_id(args), distro=distro)
        stack.callback(node.close)
        publisher = Ros2Publisher(node, rate_hz, args.ros2_reliable, calibration_json,
                                  tare=None if tare is None else (lambda: tare().estimate.change))
    stream = Ros2Stream(messages, publisher, bag_queue)
    if publisher is not None:
        def published() -> str:
            assert publisher is not None
            error = stream.publisher_error
            if error is not None:
                return f"ROS 2: FAILED, stopped at {type(error).__name__}: {error}"
            return (f"ROS 2: published under {publisher.node.namespace or '/'} on domain {publisher.node.domain_id}: "
                    + ", ".join(f"{name} {count}" for name, count in publisher.sent.items())
                    + f"; {publisher.tares} tares")

        stack.callback(lambda: report.append(published()))
    listeners = [stream]
    return listeners, report


__all__ = ["add_ros2_args", "check_ros2_args", "ros2_listeners", "is_bag", "CalibrationText", "prefer_low_latency"]
