"""The monitor's stream as ROS 2 messages: on DDS topics (:class:`Ros2Publisher`) and in an MCAP bag (:class:`BagRecorder`).

Both are listeners of the stream (:mod:`procedures.events`); each runs behind a
``BackgroundListener(..., direct=True)`` of its own that the monitor feeds from its acquisition thread, so it gets
every batch (the bag: an unbounded queue) and at once (the topics: period 0), never behind the viewer's queue.

What they send (ROS names under the node's namespace, docs/ros2.md):

- ``wrench_raw``, ``wrench_compensated`` (``geometry_msgs/msg/WrenchStamped``): the sensor-frame wrench [N, N·m] as
  read, and the contact wrench after compensation; ``header.frame_id`` the sensor
  frame's name; ``header.stamp`` the sample's time: its time on the host monotonic clock (the record's
  ``sample_time_s``) + (UNIX − monotonic) taken once at the start (:class:`StampClock`), i.e. ROS time on this host.
  At ``rate_hz`` (default 1 kHz) each message is the mean of the samples in one window [k/rate, (k+1)/rate) of
  sample time, stamped with the mean of their times, sent once a later sample shows the window complete; rate 0:
  one message per sample. A read left uncompensated (no robot state near its samples) sends no compensated message.
- ``calibration`` (``std_msgs/msg/String``, latched): the calibration in force as its JSON document.
- ``bias``, ``bias_sigma`` (``geometry_msgs/msg/WrenchStamped``, one each per drift-tracker update, about 1 Hz): the
  sensor's biases now (the calibration's + the tracker's offset) and the estimate's 1σ, stamped alike.
- in the bag also ``joint_states`` (``sensor_msgs/msg/JointState``, the robot's state at the monitor's robot rate)
  and the calibration as the metadata record ``ftacq_calibration``.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from drivers.ros2.cdr import NS_PER_S, WrenchStampedEncoder
from ftacq.bias_estimate import format_bias_change
from procedures import events

WRENCH_TYPE = "geometry_msgs/msg/WrenchStamped"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
STRING_TYPE = "std_msgs/msg/String"
DEFAULT_RATE_HZ = 1000.0
"""Wrench messages per second by default: each the mean of one window (0: every sample)."""
UR_JOINT_NAMES = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                  "wrist_3_joint")
"""The joint names of Universal Robots' ROS 2 description (ur_description), for ``joint_states``."""
RELIABLE_EVERY_SAMPLE_HZ = 8000
"""With reliable QoS at every sample, the wrench writers keep this many messages (1 s of a 7 kHz Net F/T) for a
subscriber that falls behind."""


class StampClock:
    """Sample times on the host monotonic clock → ROS stamps (UNIX ns), with one offset taken at construction, so
    the stamps stay monotonic and spaced as the samples even if the system clock is stepped during the run."""

    def __init__(self) -> None:
        self.offset_s = time.time() - time.monotonic()

    def stamp_ns(self, monotonic_s: np.ndarray) -> np.ndarray:
        return np.rint((np.asarray(monotonic_s, dtype=float) + self.offset_s) * NS_PER_S).astype(np.int64)


class WindowMean:
    """Means over consecutive windows of ``period_s`` of sample time (0: every sample as it is). A window is sent
    once a sample of a later window arrives; its samples wait in between. The times sent never go back: a sample
    dated before a sample already seen (the sensor clock's mapping moved back, by less than a millisecond) counts
    at that sample's time, so every topic's stamps increase, whatever the batches."""

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)
        self._time_s = np.empty(0)
        self._values = np.empty((0, 6))
        self._floor_s = -np.inf

    def feed(self, time_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add samples (N,) s and (N, 6); return the completed windows' (mean time (M,), mean values (M, 6)).
        A few numpy calls per read (no ``np.r_``: its overhead alone was a third of the cost at 500 reads/s)."""
        time_s = np.maximum.accumulate(np.asarray(time_s, dtype=float))
        if not len(time_s):
            return _NO_TIMES, _NO_VALUES
        np.maximum(time_s, self._floor_s, out=time_s)
        self._floor_s = time_s[-1]  # the newest time seen: a window sent ended before it (batching-independent)
        values = np.asarray(values, dtype=float)
        if self.period_s <= 0:
            return time_s, values
        if len(self._time_s):
            time_s = np.concatenate((self._time_s, time_s))
            values = np.concatenate((self._values, values))
        window = np.floor(time_s / self.period_s).astype(np.int64)
        open_from = int(np.searchsorted(window, window[-1]))  # the newest window may still grow (windows ascend)
        self._time_s, self._values = time_s[open_from:], values[open_from:]
        if open_from == 0:
            return _NO_TIMES, _NO_VALUES
        window, time_s, values = window[:open_from], time_s[:open_from], values[:open_from]
        starts = np.flatnonzero(np.diff(window, prepend=window[0] - 1))
        counts = np.diff(starts, append=open_from)
        return (np.add.reduceat(time_s, starts) / counts,
                np.add.reduceat(values, starts, axis=0) / counts[:, None])


_NO_TIMES, _NO_VALUES = np.empty(0), np.empty((0, 6))


def _sample_times(samples: events.WrenchSamples) -> np.ndarray:
    return samples.sample_time_s if samples.sample_time_s is not None else np.asarray(samples.batch.time_s)


class _WrenchStreams:
    """Raw and compensated samples → WrenchStamped messages (bytes, stamps) at the chosen rate."""

    def __init__(self, frame_id: str, rate_hz: float, clock: StampClock) -> None:
        self.encoder = WrenchStampedEncoder(frame_id)
        self.clock = clock
        period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self.raw, self.compensated = WindowMean(period_s), WindowMean(period_s)

    def messages(self, samples: events.WrenchSamples) -> list[tuple[str, list[bytes], np.ndarray]]:
        """[(topic name, messages, stamps ns)] for ``wrench_raw`` and (when known) ``wrench_compensated``."""
        time_s = _sample_times(samples)
        out = []
        for name, values, window in (("wrench_raw", samples.batch.wrench, self.raw),
                                     ("wrench_compensated", samples.compensated, self.compensated)):
            if values is None:
                continue
            mean_time_s, mean = window.feed(time_s, values)
            if len(mean):
                stamp_ns = self.clock.stamp_ns(mean_time_s)
                out.append((name, self.encoder.encode(stamp_ns, mean), stamp_ns))
        return out


def bias_messages(drift: events.BiasDrift, reference_bias: np.ndarray, clock: StampClock,
                  encoder: WrenchStampedEncoder) -> list[tuple[str, list[bytes], np.ndarray]]:
    """``bias`` (the calibration's biases + the tracker's offset) and ``bias_sigma`` (its 1σ), one message each."""
    stamp_ns = clock.stamp_ns(np.array([drift.time_s]))
    return [("bias", encoder.encode(stamp_ns, (reference_bias + drift.offset)[None]), stamp_ns),
            ("bias_sigma", encoder.encode(stamp_ns, np.asarray(drift.sigma)[None]), stamp_ns)]


class Ros2Publisher:
    """The stream on ROS 2 topics through a :class:`drivers.ros2.node.Ros2Node` (module docstring).

    Args:
        node: the node (its namespace, domain).
        frame_id: the sensor frame's name in ``header.frame_id``.
        rate_hz: wrench messages per second (window means), 0 for every sample.
        reliable: reliable wrench topics (default: ROS 2's sensor-data QoS, best effort).
        calibration_json: () → the calibration in force as JSON (latched on ``calibration``, again after a tare), or
            None (no calibration).
        reference_bias: () → the calibration's biases now (6,) [N, N·m], for ``bias``.
        tare: called by the ``tare`` service (std_srvs/srv/Trigger) in the service's thread: the session's live tare
            (procedures/live_tare.py); returns the biases' change (6,) [N, N·m] or raises (the answer says why).
        clock: the stamps' :class:`StampClock` (share one with a :class:`BagRecorder`: identical stamps).
    """

    def __init__(self, node, frame_id: str, rate_hz: float = DEFAULT_RATE_HZ, reliable: bool = False,
                 calibration_json: Callable[[], str | None] = lambda: None,
                 reference_bias: Callable[[], np.ndarray] = lambda: np.zeros(6),
                 tare: Callable[[], np.ndarray] | None = None, clock: StampClock | None = None) -> None:
        from drivers.ros2 import node as dds
        from drivers.ros2.messages import String, WrenchStamped

        self.node = node
        self.clock = clock or StampClock()
        self.streams = _WrenchStreams(frame_id, rate_hz, self.clock)
        # reliable: one second of messages kept for a subscriber that falls behind (at every sample, of a 7 kHz sensor)
        wrench_qos = dds.reliable(int(rate_hz or RELIABLE_EVERY_SAMPLE_HZ)) if reliable else dds.SENSOR_DATA
        self.writers = {name: node.writer(name, WRENCH_TYPE, WrenchStamped, wrench_qos)
                        for name in ("wrench_raw", "wrench_compensated")}
        for name in ("bias", "bias_sigma"):
            self.writers[name] = node.writer(name, WRENCH_TYPE, WrenchStamped, dds.RELIABLE)
        self.reference_bias = reference_bias
        self.sent = dict.fromkeys(self.writers, 0)
        self.tares = 0
        self.calibration_json = calibration_json
        self._calibration_writer = node.writer("calibration", STRING_TYPE, String, dds.LATCHED)
        self._publish_calibration()
        self._tare = tare
        if tare is not None:
            node.trigger_service("tare", self._answer_tare)

    def __call__(self, event: events.Event) -> None:
        if isinstance(event, events.WrenchSamples):
            self._send(self.streams.messages(event))
        elif isinstance(event, events.BiasDrift):
            self._send(bias_messages(event, self.reference_bias(), self.clock, self.streams.encoder))

    def _publish_calibration(self) -> None:
        from drivers.ros2.messages import String

        text = self.calibration_json()
        if text is not None:
            self._calibration_writer.write(String(data=text))

    def _send(self, messages: list[tuple[str, list[bytes], np.ndarray]]) -> None:
        for name, data, stamp_ns in messages:
            write = self.writers[name].write_serialized
            for message, time_ns in zip(data, stamp_ns.tolist()):
                write(message, time_ns)
            self.sent[name] += len(data)

    def _answer_tare(self) -> tuple[bool, str]:
        """The ``tare`` service: tare, publish the calibration now in force, answer with the biases' change (an
        error raised here becomes ``success: false`` with its text: drivers.ros2.node.TriggerServer)."""
        assert self._tare is not None
        change = np.asarray(self._tare(), dtype=float)
        self.tares += 1
        self._publish_calibration()
        return True, "tared: biases changed by " + format_bias_change(change)


class BagRecorder:
    """The stream's ROS 2 messages in an MCAP bag (:class:`drivers.ros2.bag.BagWriter`; module docstring): the
    same wrench and bias messages as :class:`Ros2Publisher`, ``joint_states``, the calibration. Call :meth:`close`
    after the stream ends to finish the file."""

    def __init__(self, path, namespace: str, frame_id: str, rate_hz: float = DEFAULT_RATE_HZ,
                 calibration_json: str | None = None, reference_bias: Callable[[], np.ndarray] = lambda: np.zeros(6),
                 joint_names: tuple[str, ...] = UR_JOINT_NAMES, metadata: dict[str, str] | None = None,
                 clock: StampClock | None = None) -> None:
        from drivers.ros2.bag import BagWriter
        from ftacq.ros2_names import normalize_namespace

        self.namespace = normalize_namespace(namespace)
        self.clock = clock or StampClock()
        self.streams = _WrenchStreams(frame_id, rate_hz, self.clock)
        self.reference_bias = reference_bias
        self.joint_names = list(joint_names)
        self.bag = BagWriter(path)
        if metadata:
            self.bag.metadata("ftacq", metadata)
        if calibration_json is not None:
            from drivers.ros2.messages import String

            self.bag.metadata("ftacq_calibration", {"json": calibration_json})
            now_ns = time.time_ns()
            self.bag.write(self._topic("calibration"), STRING_TYPE, [String(data=calibration_json).serialize()],
                           [now_ns])

    def _topic(self, name: str) -> str:
        return f"{self.namespace}/{name}"

    def __call__(self, event: events.Event) -> None:
        if isinstance(event, events.WrenchSamples):
            self._write(self.streams.messages(event))
        elif isinstance(event, events.BiasDrift):
            self._write(bias_messages(event, self.reference_bias(), self.clock, self.streams.encoder))
        elif isinstance(event, events.RobotState):
            from drivers.ros2.messages import Header, JointState, Time

            stamp_ns = int(self.clock.stamp_ns(np.array([event.time_s]))[0])
            message = JointState(header=Header(stamp=Time(sec=stamp_ns // NS_PER_S, nanosec=stamp_ns % NS_PER_S)),
                                 name=self.joint_names,
                                 position=[float(q) for q in event.joint_positions_rad])
            self.bag.write(self._topic("joint_states"), JOINT_STATE_TYPE, [message.serialize()], [stamp_ns])

    def _write(self, messages: list[tuple[str, list[bytes], np.ndarray]]) -> None:
        for name, data, stamp_ns in messages:
            self.bag.write(self._topic(name), WRENCH_TYPE, data, stamp_ns.tolist())

    def close(self) -> None:
        self.bag.close()


__all__ = ["Ros2Publisher", "BagRecorder", "WindowMean", "StampClock", "DEFAULT_RATE_HZ",
           "UR_JOINT_NAMES"]
