"""The monitor's stream as ROS 2 messages: on DDS topics (:class:`Ros2Publisher`) and in an MCAP bag (:class:`BagRecorder`).

One direct listener of the stream (:class:`Ros2Stream`, :mod:`procedures.events`), called in the monitor's
acquisition thread as soon as a read is compensated: it makes each event's messages once (:class:`Ros2Messages`:
window means, CDR bytes), writes them to DDS at once, and hands the same messages to the bag's own thread (an
unbounded queue: the bag gets every one), never behind the viewer's queue.

What they send (ROS names under the node's namespace, docs/ros2.md):

- ``wrench_raw``, ``wrench_compensated`` (``geometry_msgs/msg/WrenchStamped``): the sensor-frame wrench [N, N·m] as
  read, and the contact wrench after compensation; ``header.frame_id`` the sensor
  frame's name; ``header.stamp`` the sample's time: its time on the host monotonic clock (the record's
  ``sample_time_s``) + (UNIX − monotonic) taken once at the start (:class:`StampClock`), i.e. ROS time on this host.
  At ``rate_hz`` (default 1 kHz) each message is the mean of the samples in one window [k/rate, (k+1)/rate) of
  sample time, stamped with the mean of their times, sent as soon as its last sample arrives; rate 0:
  one message per sample. A read left uncompensated (no robot state near its samples) sends no compensated message.
- ``calibration`` (``std_msgs/msg/String``, latched): the calibration in force as its JSON document.
- ``bias``, ``bias_sigma`` (``geometry_msgs/msg/WrenchStamped``, one each per drift-tracker update, about 1 Hz): the
  sensor's biases now (the calibration's + the tracker's offset) and the estimate's 1σ, stamped alike.
- in the bag also ``joint_states`` (``sensor_msgs/msg/JointState``, the robot's state at the monitor's robot rate)
  and the calibration as the metadata record ``ftacq_calibration``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

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
    """Means over consecutive windows [k·period_s, (k+1)·period_s) of sample time (0: every sample as it is).

    A window is sent as soon as it is known complete: it holds its last expected sample (one whose next sample,
    ``sample_period_s`` later, falls in the next window: the sensor sends in bursts, and waiting for the next burst
    to show the window complete cost up to a burst's period), or a sample of a later window has arrived (a lost
    sample, an unknown sample period: 0). Its samples wait in between. The invariants, whatever the batches:

    - the times sent never go back: a sample dated before a sample already seen (the sensor clock's mapping moved
      back, by less than a millisecond) counts at that sample's time, and one dated inside a window already sent
      counts at the start of the next window, so every topic's stamps strictly increase;
    - the same samples give the same means however they are batched (each decision is the sample's own).
    """

    def __init__(self, period_s: float, columns: int = 6, sample_period_s: float = 0.0) -> None:
        self.period_s = float(period_s)
        # a sample within (1 - EARLY_CLOSE_TOLERANCE) sample periods of its window's end is its last one; only
        # for windows longer than a sample period (else each would hold one sample: every sample is the mode then)
        self.margin_s = (float(sample_period_s) * (1.0 - EARLY_CLOSE_TOLERANCE)
                         if 0.0 < sample_period_s < self.period_s else 0.0)
        self._time_s = np.empty(0)
        self._window = np.empty(0, dtype=np.int64)
        self._values = np.empty((0, columns))
        self._floor_s = -np.inf
        self._closed = _NO_WINDOW  # the newest window sent early: later samples count in later windows

    def feed(self, time_s: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add samples (N,) s and (N, C); return the completed windows' (mean time (M,), mean values (M, C)).
        A few numpy calls per read (no ``np.r_``: its overhead alone was a third of the cost at 500 reads/s)."""
        time_s = np.maximum.accumulate(np.asarray(time_s, dtype=float))
        if not len(time_s):
            return _NO_TIMES, self._values[:0]
        if time_s[0] < self._floor_s:  # (else every time is above the floor already: nondecreasing)
            np.maximum(time_s, self._floor_s, out=time_s)
        values = np.asarray(values, dtype=float)
        if self.period_s <= 0:
            self._floor_s = time_s[-1]
            return time_s, values
        window = np.floor(time_s / self.period_s).astype(np.int64)
        last_done = False
        if self.margin_s > 0:  # the samples that complete their window, and those dated inside a window sent
            done = time_s + self.margin_s >= (window + 1) * self.period_s
            last_done = bool(done[-1])
            # usually none is late: the first is past the window sent last, and no sample follows one that completed
            # its own window (two within a sample period of a window's end: the mapping moved). Only the last
            # sample's window can then be one sent early (windows ascend)
            if window[0] > self._closed and not np.count_nonzero(done[:-1] & (window[1:] == window[:-1])):
                if last_done:
                    self._closed = int(window[-1])
            else:
                last_done = self._late(time_s, window, done)
        self._floor_s = time_s[-1]  # the newest time seen: a window sent ended before it (batching-independent)
        if len(self._time_s):
            time_s = np.concatenate((self._time_s, time_s))
            window = np.concatenate((self._window, window))
            values = np.concatenate((self._values, values))
        # the newest window may still grow (windows ascend), unless its last sample came
        open_from = len(window) if last_done else int(window.searchsorted(window[-1]))
        self._time_s, self._window, self._values = time_s[open_from:], window[open_from:], values[open_from:]
        if open_from == 0:
            return _NO_TIMES, self._values[:0]
        if open_from < len(window):
            window, time_s, values = window[:open_from], time_s[:open_from], values[:open_from]
        # each window's first sample, then open_from: where the window changes, between two ends (no np.diff: its
        # prepend/append cost more than the rest)
        bounds = np.concatenate((_TRUE, window[1:] != window[:-1], _TRUE)).nonzero()[0]
        starts, counts = bounds[:-1], bounds[1:] - bounds[:-1]
        return (np.add.reduceat(time_s, starts) / counts,
                np.add.reduceat(values, starts, axis=0) / counts[:, None])

    def _late(self, time_s: np.ndarray, window: np.ndarray, done: np.ndarray) -> bool:
        """Move the samples dated inside a window already sent (by an earlier sample of it, or of an earlier read)
        to the next window's start, in place; return whether the last sample completes its window."""
        closed = np.maximum.accumulate(np.where(done, window, self._closed))
        before = np.empty_like(closed)  # the newest window sent before each sample
        before[0], before[1:] = self._closed, closed[:-1]
        late = window <= before
        if late.any():  # (a late sample is at a window's start: it completes nothing, as period_s > margin_s)
            window[late] = before[late] + 1
            time_s[late] = np.maximum(time_s[late], window[late] * self.period_s)
            done[late] = False
        self._closed = int(closed[-1])
        return bool(done[-1])

    def _copy_state(self, other: "WindowMean", values: np.ndarray) -> None:
        self._time_s, self._window, self._values = other._time_s, other._window, values
        self._floor_s, self._closed, self.margin_s = other._floor_s, other._closed, other.margin_s

    def split(self, columns: int) -> tuple["WindowMean", "WindowMean"]:
        """Two means of this one's first ``columns`` and its other columns, from the same state."""
        parts = WindowMean(self.period_s, columns), WindowMean(self.period_s, self._values.shape[1] - columns)
        for part, values in zip(parts, (self._values[:, :columns], self._values[:, columns:])):
            part._copy_state(self, values)
        return parts

    @staticmethod
    def joined(first: "WindowMean", second: "WindowMean") -> "WindowMean | None":
        """One mean of both's columns when they hold the same samples' times (what :meth:`split` made), else None."""
        if (first._floor_s != second._floor_s or first._closed != second._closed
                or not np.array_equal(first._time_s, second._time_s)):
            return None
        both = WindowMean(first.period_s, first._values.shape[1] + second._values.shape[1])
        both._copy_state(first, np.hstack((first._values, second._values)))
        return both


EARLY_CLOSE_TOLERANCE = 0.01
"""A sample closes its window early when its next sample, (1 − this) sample periods later, would be past the
window's end: the mapped sample period differs from the sensor's nominal one by the crystals' rate error (< 0.05 %);
a sample that still lands in a window already sent counts in the next one."""
_NO_TIMES = np.empty(0)
_TRUE = np.ones(1, dtype=bool)
_NO_WINDOW = np.iinfo(np.int64).min // 2


def _sample_times(samples: events.WrenchSamples) -> np.ndarray:
    return samples.sample_time_s if samples.sample_time_s is not None else np.asarray(samples.batch.time_s)


class _WrenchStreams:
    """Raw and compensated samples → WrenchStamped messages (bytes, stamps) at the chosen rate. While every read has
    both, one :class:`WindowMean` of their 12 columns (half the numpy calls; the same means, the same stamps); a read
    without a compensated wrench parts them until their open windows hold the same samples again."""

    def __init__(self, frame_id: str, rate_hz: float, clock: StampClock,
                 sample_period_s: Callable[[], float] | None = None) -> None:
        self.encoder = WrenchStampedEncoder(frame_id)
        self.clock = clock
        self.period_s = 1.0 / rate_hz if rate_hz > 0 else 0.0
        self._sample_period_s = sample_period_s  # asked at the first samples (the sensor is open by then)
        self._start(0.0)

    def _start(self, sample_period_s: float) -> None:
        self.both: WindowMean | None = WindowMean(self.period_s, 12, sample_period_s)
        self.raw = WindowMean(self.period_s, 6, sample_period_s)  # (raw and compensated: used while apart)
        self.compensated = WindowMean(self.period_s, 6, sample_period_s)

    def messages(self, samples: events.WrenchSamples) -> list[Message]:
        """``wrench_raw`` and (when known) ``wrench_compensated`` messages for the windows ``samples`` complete."""
        if self._sample_period_s is not None:
            self._start(self._sample_period_s())
            self._sample_period_s = None
        time_s = _sample_times(samples)
        if self.both is not None and samples.compensated is not None:
            both = np.concatenate((samples.batch.wrench, samples.compensated), axis=1)
            mean_time_s, mean = self.both.feed(time_s, both)
            if not len(mean):
                return []
            stamp_ns = self.clock.stamp_ns(mean_time_s)
            raw, compensated = self.encoder.encode_pairs(stamp_ns, mean)
            return [("wrench_raw", WRENCH_TYPE, raw, stamp_ns),
                    ("wrench_compensated", WRENCH_TYPE, compensated, stamp_ns)]
        if self.both is not None:
            self.raw, self.compensated = self.both.split(6)
            self.both = None
        out = []
        for name, values, window in (("wrench_raw", samples.batch.wrench, self.raw),
                                     ("wrench_compensated", samples.compensated, self.compensated)):
            if values is None:
                continue
            mean_time_s, mean = window.feed(time_s, values)
            if len(mean):
                stamp_ns = self.clock.stamp_ns(mean_time_s)
                out.append((name, WRENCH_TYPE, self.encoder.encode(stamp_ns, mean), stamp_ns))
        self.both = WindowMean.joined(self.raw, self.compensated)
        return out


Message = tuple[str, str, list[bytes], np.ndarray]
"""One topic's messages from one event: (topic name under the namespace, ROS 2 type, CDR bytes each, stamps UNIX ns)."""


class Ros2Messages:
    """The stream's ROS 2 messages (module docstring), computed once per event for every output: the window means
    and the CDR bytes the topics send are the bag's, byte for byte.

    Args:
        frame_id: the sensor frame's name in ``header.frame_id``.
        rate_hz: wrench messages per second (window means), 0 for every sample.
        reference_bias: () → the calibration's biases now (6,) [N, N·m], for ``bias``.
        joint_states: also ``joint_states`` from the RobotState events (the bag's; no topic carries them).
        joint_names: their names. clock: the stamps' :class:`StampClock`.
        sample_period_s: () → the sensor's sample period, s (1 / its rate), asked at the first samples: a window
            is sent as soon as it holds its last sample (:class:`WindowMean`); None: once a later sample arrives.
    """

    def __init__(self, frame_id: str, rate_hz: float = DEFAULT_RATE_HZ,
                 reference_bias: Callable[[], np.ndarray] = lambda: np.zeros(6), joint_states: bool = False,
                 joint_names: tuple[str, ...] = UR_JOINT_NAMES, clock: StampClock | None = None,
                 sample_period_s: Callable[[], float] | None = None) -> None:
        self.clock = clock or StampClock()
        self.streams = _WrenchStreams(frame_id, rate_hz, self.clock, sample_period_s)
        self.reference_bias = reference_bias
        self.joint_states = joint_states
        self.joint_names = list(joint_names)

    def __call__(self, event: events.Event) -> list[Message]:
        if isinstance(event, events.WrenchSamples):
            return self.streams.messages(event)
        if isinstance(event, events.BiasDrift):
            return bias_messages(event, self.reference_bias(), self.clock, self.streams.encoder)
        if isinstance(event, events.RobotState) and self.joint_states:
            from drivers.ros2.messages import Header, JointState, Time

            stamp_ns = self.clock.stamp_ns(np.array([event.time_s]))
            stamp = int(stamp_ns[0])
            message = JointState(header=Header(stamp=Time(sec=stamp // NS_PER_S, nanosec=stamp % NS_PER_S)),
                                 name=self.joint_names, position=[float(q) for q in event.joint_positions_rad])
            return [("joint_states", JOINT_STATE_TYPE, [message.serialize()], stamp_ns)]
        return []


def bias_messages(drift: events.BiasDrift, reference_bias: np.ndarray, clock: StampClock,
                  encoder: WrenchStampedEncoder) -> list[Message]:
    """``bias`` (the calibration's biases + the tracker's offset) and ``bias_sigma`` (its 1σ), one message each."""
    stamp_ns = clock.stamp_ns(np.array([drift.time_s]))
    return [("bias", WRENCH_TYPE, encoder.encode(stamp_ns, (reference_bias + drift.offset)[None]), stamp_ns),
            ("bias_sigma", WRENCH_TYPE, encoder.encode(stamp_ns, np.asarray(drift.sigma)[None]), stamp_ns)]


@dataclass(frozen=True)
class EncodedMessages:
    """An event for the bag's queue: the messages :class:`Ros2Messages` made of one stream event."""

    messages: list[Message]


class Ros2Stream:
    """The monitor's one ROS 2 listener (``direct``: called in its acquisition thread as soon as a read is
    compensated): the messages of each event, made once (:class:`Ros2Messages`), written to DDS at once by the
    ``publisher`` (a DDS write never blocks: reliable writers keep their history and drop the oldest) and handed to
    the bag's queue (``bag``: a ``BackgroundListener`` around a :class:`BagRecorder`), never made twice. A publisher
    that raises gets nothing more (:attr:`publisher_error`); the bag goes on."""

    direct = True

    def __init__(self, messages: Ros2Messages, publisher: "Ros2Publisher | None" = None,
                 bag: Callable[[Any], None] | None = None) -> None:
        self.messages = messages
        self.publisher = publisher
        self.bag = bag
        self.publisher_error: Exception | None = None

    def __call__(self, event: events.Event) -> None:
        out = self.messages(event)
        if not out:
            return
        if self.publisher is not None and self.publisher_error is None:
            try:
                self.publisher(out)
            except Exception as error:  # noqa: BLE001 - the topics fail, the bag and the monitor go on
                self.publisher_error = error
        if self.bag is not None:
            self.bag(EncodedMessages(out))


class Ros2Publisher:
    """Writes the stream's messages on ROS 2 topics through a :class:`drivers.ros2.node.Ros2Node` (module
    docstring); serves ``calibration`` and the ``tare`` service.

    Args:
        node: the node (its namespace, domain).
        rate_hz: wrench messages per second (0: every sample): the history a reliable writer keeps (1 s of them).
        reliable: reliable wrench topics (default: ROS 2's sensor-data QoS, best effort).
        calibration_json: () → the calibration in force as JSON (latched on ``calibration``, again after a tare), or
            None (no calibration).
        tare: called by the ``tare`` service (std_srvs/srv/Trigger) in the service's thread: the session's live tare
            (procedures/live_tare.py); returns the biases' change (6,) [N, N·m] or raises (the answer says why).
    """

    def __init__(self, node, rate_hz: float = DEFAULT_RATE_HZ, reliable: bool = False,
                 calibration_json: Callable[[], str | None] = lambda: None,
                 tare: Callable[[], np.ndarray] | None = None) -> None:
        from drivers.ros2 import node as dds
        from drivers.ros2.messages import String, WrenchStamped

        self.node = node
        # reliable: one second of messages kept for a subscriber that falls behind (at every sample, of a 7 kHz sensor)
        wrench_qos = dds.reliable(int(rate_hz or RELIABLE_EVERY_SAMPLE_HZ)) if reliable else dds.SENSOR_DATA
        self.writers = {name: node.writer(name, WRENCH_TYPE, WrenchStamped, wrench_qos)
                        for name in ("wrench_raw", "wrench_compensated")}
        for name in ("bias", "bias_sigma"):
            self.writers[name] = node.writer(name, WRENCH_TYPE, WrenchStamped, dds.RELIABLE)
        self.sent = dict.fromkeys(self.writers, 0)
        self.tares = 0
        self.calibration_json = calibration_json
        self._calibration_writer = node.writer("calibration", STRING_TYPE, String, dds.LATCHED)
        self._publish_calibration()
        self._tare = tare
        if tare is not None:
            node.trigger_service("tare", self._answer_tare)

    def __call__(self, messages: list[Message]) -> None:
        """Write the messages of the topics it publishes (``joint_states``, the bag's, is not one)."""
        for name, _, data, stamp_ns in messages:
            writer = self.writers.get(name)
            if writer is None:
                continue
            writer.write_all(data, stamp_ns.tolist())
            self.sent[name] += len(data)

    def _publish_calibration(self) -> None:
        from drivers.ros2.messages import String

        text = self.calibration_json()
        if text is not None:
            self._calibration_writer.write(String(data=text))

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
    :class:`EncodedMessages` events :class:`Ros2Stream` hands it (the wrench and bias messages the topics carry,
    ``joint_states``), and the calibration. Call :meth:`close` after the stream ends to finish the file."""

    def __init__(self, path, namespace: str, calibration_json: str | None = None,
                 metadata: dict[str, str] | None = None) -> None:
        from drivers.ros2.bag import BagWriter
        from ftacq.ros2_names import normalize_namespace

        self.namespace = normalize_namespace(namespace)
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
        if isinstance(event, EncodedMessages):
            for name, ros_type, data, stamp_ns in event.messages:
                self.bag.write(self._topic(name), ros_type, data, stamp_ns.tolist())

    def close(self) -> None:
        self.bag.close()


__all__ = ["Ros2Messages", "Ros2Stream", "Ros2Publisher", "BagRecorder", "EncodedMessages", "WindowMean",
           "StampClock", "DEFAULT_RATE_HZ", "UR_JOINT_NAMES"]
