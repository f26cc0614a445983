"""ROS 2 over DDS and MCAP bags, checked against implementations that are not ftacq's.

- the CDR bytes: rosbags' own ROS 2 typestore and CDR deserializer (Humble and Jazzy definitions);
- the topics and the tare service: a subscriber and client in another process (tests/ros2_subscriber.py: Cyclone
  DDS with ROS 2's type names, its types written there from ROS 2's definitions, the service request as
  rmw_cyclonedds_cpp sends it), against ``ftacq monitor --sim --ros2``;
- the bag: mcap-ros2-support's reader and rosbags' rosbag2 reader.

Each end-to-end test has its own DDS domain and namespace (parallel workers never see each other), and discovery on
loopback without multicast (``CYCLONEDDS_URI`` = :data:`drivers.ros2.node.LOCALHOST_CONFIG`).
"""

from __future__ import annotations

import json
import os
import re
import select
import subprocess
import sys
import uuid
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("mcap_ros2")
pytest.importorskip("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from drivers.ros2.cdr import WrenchStampedEncoder  # noqa: E402
from drivers.ros2.messages import DEFINITIONS, Header, Time, Vector3, Wrench, WrenchStamped  # noqa: E402
from procedures.ros2_stream import WindowMean  # noqa: E402

SUBSCRIBER = Path(__file__).with_name("ros2_subscriber.py")
TYPESTORES = (Stores.ROS2_HUMBLE, Stores.ROS2_JAZZY)


@pytest.mark.parametrize("frame_id", ["", "f", "ft_sensor", "tool0_ft_sensor_long_name"])
@pytest.mark.parametrize("store", TYPESTORES)
def test_wrench_batches_decode_with_rosbags(frame_id, store):
    """Every alignment case of the string's padding: the batch encoder's bytes are what Cyclone DDS's serializer
    writes, and rosbags' CDR deserializer reads back the stamps, the frame and the values exactly."""
    rng = np.random.default_rng(len(frame_id))
    stamp_ns = np.array([0, 1, 1_796_000_000_123_456_789, 2**31 * 10**9 - 1])
    wrench = rng.normal(scale=50.0, size=(len(stamp_ns), 6))
    data = WrenchStampedEncoder(frame_id).encode(stamp_ns, wrench)
    typestore = get_typestore(store)
    for message, ns, row in zip(data, stamp_ns, wrench):
        decoded = typestore.deserialize_cdr(message, "geometry_msgs/msg/WrenchStamped")
        assert decoded.header.stamp.sec * 10**9 + decoded.header.stamp.nanosec == ns
        assert decoded.header.frame_id == frame_id
        force, torque = decoded.wrench.force, decoded.wrench.torque
        assert [force.x, force.y, force.z, torque.x, torque.y, torque.z] == row.tolist()
        reference = WrenchStamped(Header(Time(int(ns // 10**9), int(ns % 10**9)), frame_id),
                                  Wrench(Vector3(*row[:3]), Vector3(*row[3:])))
        assert reference.serialize() == message


def test_batches_of_any_size_and_pairs_encode_as_the_reference_serializer():
    """The encoder's prefilled records (grown for a larger batch) and its pairs (two topics' messages of the same
    stamps in one batch, written into a buffer reused from batch to batch, smaller after larger) give each message's
    bytes as ROS 2's serializer writes them."""
    encoder = WrenchStampedEncoder("ft_sensor")
    rng = np.random.default_rng(7)
    for n in (3, 40, 2, 100, 1):
        stamp_ns = 1_796_000_000_000_000_000 + rng.integers(0, 10**12, n)
        wrenches = rng.normal(scale=50.0, size=(n, 12))
        raw, compensated = encoder.encode_pairs(stamp_ns, wrenches)
        assert encoder.encode(stamp_ns, wrenches[:, :6]) == raw and len(raw) == n
        for data, values in ((raw, wrenches[:, :6]), (compensated, wrenches[:, 6:])):
            for message, ns, row in zip(data, stamp_ns, values):
                reference = WrenchStamped(Header(Time(int(ns // 10**9), int(ns % 10**9)), "ft_sensor"),
                                          Wrench(Vector3(*row[:3]), Vector3(*row[3:])))
                assert reference.serialize() == message


@pytest.mark.parametrize("ros_type", sorted(DEFINITIONS))
def test_message_definitions_are_ros2s(ros_type):
    """The MCAP schemas' definitions parse, with rosbags, to the same fields as rosbags' own ROS 2 types."""
    from rosbags.typesys import get_types_from_msg

    typestore = get_typestore(Stores.ROS2_JAZZY)
    parts = DEFINITIONS[ros_type].split("=" * 80 + "\n")
    types = get_types_from_msg(parts[0], ros_type)
    for part in parts[1:]:
        header, _, text = part.partition("\n")
        name = header.removeprefix("MSG: ")
        package, short = name.split("/")
        types.update(get_types_from_msg(text, f"{package}/msg/{short}"))
    for name, (_, fields) in types.items():
        own_fields = typestore.fielddefs[name][1]
        assert [field[0] for field in fields] == [field[0] for field in own_fields], name


def test_window_means_span_batches():
    """1 kHz means of 7 kHz samples fed in uneven batches equal the means computed over all samples at once."""
    time_s = 10.0 + np.arange(7000) / 7000.0
    values = np.random.default_rng(1).normal(size=(7000, 6))
    window = WindowMean(1e-3)
    times, means = [], []
    for part in np.array_split(np.arange(7000), 37):
        t, m = window.feed(time_s[part], values[part])
        times.append(t)
        means.append(m)
    times, means = np.concatenate(times), np.concatenate(means)
    index = np.floor(time_s / 1e-3).astype(int)
    expected = [values[index == k].mean(axis=0) for k in np.unique(index)[:-1]]  # the last window stays open
    assert len(means) == len(expected) == 999
    np.testing.assert_allclose(means, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(times, [time_s[index == k].mean() for k in np.unique(index)[:-1]], rtol=1e-15)


def test_window_stamps_never_go_back():
    """A batch dated 0.4 ms before what was already sent (the sensor clock's mapping moved back) is counted at the
    earliest open time: the stamps keep increasing, and no sample is lost from the means."""
    for period_s in (1e-3, 0.0):
        window = WindowMean(period_s)
        first = 1.0 + np.arange(70) / 7000.0
        late = first[-1] - 4e-4 + np.arange(1, 71) / 7000.0
        t1, m1 = window.feed(first, np.ones((70, 6)))
        t2, m2 = window.feed(late, np.ones((70, 6)))
        stamps = np.concatenate([t1, t2])
        assert np.all(np.diff(stamps) > 0) if period_s else np.all(np.diff(stamps) >= 0)
        np.testing.assert_allclose(np.concatenate([m1, m2]), 1.0)


def _feed_all(window: WindowMean, time_s: np.ndarray, values: np.ndarray, sizes) -> tuple[list, np.ndarray,
                                                                                          np.ndarray]:
    """Feed ``time_s``, ``values`` in batches of ``sizes``; return the windows sent per batch and all of them."""
    per_batch, times, means = [], [], []
    for part in np.split(np.arange(len(time_s)), np.cumsum(sizes)[:-1]):
        t, m = window.feed(time_s[part], values[part])
        per_batch.append(len(t))
        times.append(t)
        means.append(m)
    return per_batch, np.concatenate(times), np.concatenate(means)


def test_a_window_is_sent_with_its_last_sample():
    """The Net F/T sends 14 samples every 2 ms: each burst ends with the last sample of a 1 kHz window. Knowing the
    sample period, a window is sent in the read that brings its last sample (both of a burst's windows at once),
    not when the next burst shows it complete; the means are those of all samples at once."""
    time_s = 10.0 + (np.arange(7000) + 0.5) / 7000.0
    values = np.random.default_rng(2).normal(size=(7000, 6))
    index = np.floor(time_s / 1e-3).astype(int)
    per_batch, times, means = _feed_all(WindowMean(1e-3, sample_period_s=1 / 7000.0), time_s, values, [14] * 500)
    assert per_batch == [2] * 500  # (without the sample period: one in the first read, the last window held)
    np.testing.assert_allclose(means, [values[index == k].mean(axis=0) for k in np.unique(index)], atol=1e-12)
    np.testing.assert_allclose(times, [time_s[index == k].mean() for k in np.unique(index)], rtol=1e-15)
    assert _feed_all(WindowMean(1e-3), time_s, values, [14] * 500)[0][:2] == [1, 2]


@pytest.mark.parametrize("jitter_s", [3e-6, 3e-5])
def test_early_windows_keep_the_invariants_whatever_the_batches(jitter_s):
    """Sent early, windows still give the same means however the samples are batched, and every stamp is later
    than the one before: with the clock's mapping stepping back 0.3 ms, and with jitter (3 µs, and 30 µs: two
    samples within a sample period of a window's end, the second dated inside the window the first sent)."""
    rng = np.random.default_rng(5)
    n = 3000
    time_s = 3.0 + np.arange(n) / 7000.0 * (1 + 2e-4) + rng.normal(0, jitter_s, n)
    time_s[1000:] -= 3e-4  # the mapping steps back
    values = np.column_stack([np.ones(n), rng.normal(size=(n, 5))])
    results = []
    for sizes in ([1] * n, [14] * (n // 14) + [n % 14], list(np.diff([0, *sorted(rng.choice(n, 150, replace=False)),
                                                                       n]))):
        sizes = [s for s in sizes if s]
        window = WindowMean(1e-3, sample_period_s=1 / 7000.0)
        _, times, means = _feed_all(window, time_s, values, sizes)
        assert np.all(np.diff(times) > 0)
        assert len(window._time_s) < 8  # at most one open window left
        results.append((times, means))
    for times, means in results[1:]:
        np.testing.assert_array_equal(times, results[0][0])
        np.testing.assert_array_equal(means, results[0][1])


def test_a_sample_dated_inside_a_window_sent_counts_in_the_next():
    """A window sent with its last sample; the next read's first two samples are dated inside it (the clock's
    mapping stepped back 0.3 ms): they count at the next window's start, the window sent keeps its 7 samples."""
    period_s, dt_s = 1e-3, 1 / 7000.0
    end_s = (np.floor(5.0 / period_s) + 1) * period_s
    first = end_s - (6.5 - np.arange(7)) * dt_s  # the last one half a sample period before the end
    later = end_s + 0.5 * dt_s - 3e-4 + np.arange(10) * dt_s
    values = np.random.default_rng(4).normal(size=(17, 6))
    window = WindowMean(period_s, sample_period_s=dt_s)
    t1, m1 = window.feed(first, values[:7])
    np.testing.assert_allclose(m1, values[None, :7].mean(axis=1), atol=1e-12)
    np.testing.assert_allclose(t1, [first.mean()], rtol=1e-15)
    t2, m2 = window.feed(later, values[7:])
    assert np.sum(later < end_s) == 2 and len(t2) == 1  # j = 8 is the next window's last sample: sent too
    np.testing.assert_allclose(m2, values[None, 7:16].mean(axis=1), atol=1e-12)
    np.testing.assert_allclose(t2, [np.r_[end_s, end_s, later[2:9]].mean()], rtol=1e-15)
    assert t2[0] > t1[0]


def test_the_calibration_text_is_serialized_once_per_calibration(monkeypatch):
    """A calibration without ``created_utc`` is stamped when serialized: the bag's metadata and the latched topic
    carry one text, even across a second's turn; a tare's new calibration gets its own."""
    import datetime as real_dt
    from dataclasses import replace

    from ftacq import calfile
    from ftacq.app.ros2_outputs import CalibrationText
    from ftacq.app.simcell import simulated_truth, true_calibration

    seconds = iter(range(10**6))

    class Clock(real_dt.datetime):
        @classmethod
        def now(cls, tz=None):  # a second later at every call
            return real_dt.datetime(2026, 1, 1, tzinfo=tz) + real_dt.timedelta(seconds=next(seconds))

    monkeypatch.setattr(calfile._dt, "datetime", Clock)
    calibration = true_calibration(simulated_truth())
    assert "created_utc" not in calibration.metadata
    in_force = [calibration]
    text = CalibrationText(lambda: in_force[0])
    first = text()
    assert first is not None and text() == first and json.loads(first)["created_utc"]
    in_force[0] = replace(calibration, force_bias=calibration.force_bias + 1.0)  # a tare
    assert json.loads(text() or "")["force_bias"] != json.loads(first)["force_bias"]
    assert CalibrationText(lambda: None)() is None


def test_raw_and_compensated_means_together_equal_each_apart():
    """While every read has both, raw and compensated share one window mean: the same bytes as two means apart; an
    uncompensated read parts them (raw goes on alone) and they join again once their open windows agree."""
    from drivers.sensor import WrenchBatch
    from procedures import events
    from procedures.ros2_stream import Ros2Messages, StampClock, WrenchStampedEncoder

    clock, encoder = StampClock(), WrenchStampedEncoder("ft_sensor")
    streams = Ros2Messages("ft_sensor", 1000.0, clock=clock)
    apart = {"wrench_raw": WindowMean(1e-3), "wrench_compensated": WindowMean(1e-3)}
    rng = np.random.default_rng(3)
    start, got, expected = 0, [], []
    for k, n in enumerate([23, 50, 9, 31, 64, 17, 40, 70, 5, 33]):
        time_s = 1.0 + (start + np.arange(n)) / 7000.0 + rng.normal(0, 1e-6, n)
        start += n
        wrench = rng.normal(size=(n, 6))
        compensated = None if k == 3 else wrench - 0.5
        batch = WrenchBatch(time_s, wrench, np.zeros((n, 6), dtype=np.int64), np.zeros(n, dtype=np.uint32),
                            np.arange(n), np.zeros(n, dtype=bool))
        got += [(name, data) for name, _, data, _ in streams(events.WrenchSamples(batch, compensated,
                                                                                   sample_time_s=time_s))]
        for name, values in (("wrench_raw", wrench), ("wrench_compensated", compensated)):
            if values is not None:
                mean_time_s, mean = apart[name].feed(time_s, values)
                if len(mean):
                    expected.append((name, encoder.encode(clock.stamp_ns(mean_time_s), mean)))
        if k == 3:
            assert streams.streams.both is None  # parted by the uncompensated read
    assert sorted(got) == sorted(expected) and len(got) > 10
    assert streams.streams.both is not None  # joined again


def test_each_event_is_encoded_once_for_the_topics_and_the_bag():
    """The stream makes an event's messages once: the publisher and the bag get the very same bytes; a publisher
    that fails gets nothing more, the bag goes on."""
    from drivers.sensor import WrenchBatch
    from procedures import events
    from procedures.ros2_stream import EncodedMessages, Ros2Messages, Ros2Stream

    def samples(start: int) -> events.WrenchSamples:
        time_s = 1.0 + (start + np.arange(70)) / 7000.0
        wrench = np.random.default_rng(start).normal(size=(70, 6))
        n = len(time_s)
        batch = WrenchBatch(time_s, wrench, np.zeros((n, 6), dtype=np.int64), np.zeros(n, dtype=np.uint32),
                            np.arange(start, start + n), np.zeros(n, dtype=bool))
        return events.WrenchSamples(batch=batch, compensated=wrench - 1.0, sample_time_s=time_s)

    published, bagged = [], []

    def failing(messages):
        published.append(messages)
        if len(published) == 2:
            raise OSError("DDS write failed")

    stream = Ros2Stream(Ros2Messages("ft_sensor", 1000.0), failing, bagged.append)
    for start in (0, 70, 140):
        stream(samples(start))
    assert [type(event) for event in bagged] == [EncodedMessages] * 3
    assert published[0] is bagged[0].messages  # made once, shared
    names = [name for name, *_ in bagged[0].messages]
    assert names == ["wrench_raw", "wrench_compensated"]
    assert len(published) == 2 and isinstance(stream.publisher_error, OSError)  # stopped after its failure
    stream(events.RobotState(1.1, np.zeros(6), np.zeros(6)))  # joint_states only when asked (the bag's)
    assert len(bagged) == 3


# ------------------------------------------------------------------------------------------------ end to end


def _env() -> dict[str, str]:
    from drivers.ros2.node import LOCALHOST_CONFIG

    env = dict(os.environ, CYCLONEDDS_URI=LOCALHOST_CONFIG, PYTHONPATH=str(Path(__file__).parents[1]))
    env.pop("ROS_DOMAIN_ID", None)
    return env


def _unique() -> tuple[int, str]:
    """A domain id and a namespace no other test (or worker) uses at the same time."""
    token = uuid.uuid4()
    return 1 + token.int % 200, f"/t{token.hex[:12]}"


def _start_subscriber(domain_id: int, namespace: str, out: Path, *options: str) -> subprocess.Popen:
    process = subprocess.Popen([sys.executable, str(SUBSCRIBER), str(domain_id), namespace, "120", str(out),
                                *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    ready, _, _ = select.select([process.stdout], [], [], 60.0)
    assert ready and process.stdout.readline().strip() == "ready", process.stderr.read() if not ready else ""
    return process


def _finish(process: subprocess.Popen, out: Path) -> dict:
    try:
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr
    return json.loads(out.read_text())


def _run_monitor(monkeypatch, *args: str) -> None:
    from drivers.ros2.node import LOCALHOST_CONFIG
    from ftacq.app.cli import main as ftacq_main

    monkeypatch.setenv("CYCLONEDDS_URI", LOCALHOST_CONFIG)
    assert ftacq_main(["monitor", "--sim", *args]) == 0


def _stamp_ns(entry: dict) -> int:
    return entry["stamp"][0] * 10**9 + entry["stamp"][1]


@pytest.mark.slow(seconds=8)
def test_monitor_topics_tare_service_and_bag_against_independent_readers(tmp_path, monkeypatch, capsys):
    """``ftacq monitor --sim --ros2 --seconds 5 --record X.mcap``: a subscriber in another process receives every
    topic (values decoded there and by rosbags alike), calls the tare service and gets its answer; the bag reads
    back with mcap-ros2-support and with rosbags, and holds, byte for byte, what the subscriber received."""
    from mcap.reader import make_reader
    from mcap_ros2.reader import read_ros2_messages
    from rosbags.rosbag2 import Reader

    domain_id, namespace = _unique()
    out, bag = tmp_path / "received.json", tmp_path / "monitor.mcap"
    subscriber = _start_subscriber(domain_id, namespace, out, "--reliable", "--tare-after", "300")
    # the arm still: the drift tracker publishes its bias only once it has seen the arm at rest
    _run_monitor(monkeypatch, "--sim-still", "--ros2", "--ros2-reliable", "--ros2-domain-id", str(domain_id),
                 "--ros2-namespace", namespace, "--ros2-frame-id", "ati_sensor", "--seconds", "5", "--record", str(bag),
                 "--save", str(tmp_path / "monitor.rrd"))
    received = _finish(subscriber, out)
    last_lines = capsys.readouterr().out

    # the topics, as another DDS participant received them
    for name in ("wrench_raw", "wrench_compensated", "calibration"):
        assert received[name], name
    calibration = json.loads(received["calibration"][0]["data"])
    assert "force_bias" in json.dumps(calibration)
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    for entry in received["wrench_raw"][::50] + received["wrench_compensated"][::50]:
        decoded = typestore.deserialize_cdr(bytes.fromhex(entry["cdr"]), "geometry_msgs/msg/WrenchStamped")
        assert decoded.header.frame_id == entry["frame_id"] == "ati_sensor"
        force, torque = decoded.wrench.force, decoded.wrench.torque
        assert [force.x, force.y, force.z, torque.x, torque.y, torque.z] == entry["wrench"]

    # the tare service, called from the other participant as a ROS 2 (rmw_cyclonedds_cpp) client calls it
    assert len(received["tare_replies"]) == 1
    reply = received["tare_replies"][0]
    assert reply["success"], reply
    assert (reply["guid"], reply["seq"]) == (received["request_guid"], 1)
    change = re.fullmatch(r"tared: biases changed by F \[(.*)\] N, T \[(.*)\] N·m", reply["message"])
    assert change is not None and len((change[1] + ", " + change[2]).split(", ")) == 6
    # the calibration in force after the tare was latched again: its biases moved by the change announced
    before, after = (json.loads(entry["data"]) for entry in (received["calibration"][0], received["calibration"][-1]))
    assert len(received["calibration"]) == 2 and before != after

    # the bag: ROS 2 profile, full definitions; two independent readers agree with each other and with the wire
    with open(bag, "rb") as handle:
        reader = make_reader(handle)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        schemas = {schema.name: schema for schema in summary.schemas.values()}
        assert {schema.encoding for schema in schemas.values()} == {"ros2msg"}
        assert schemas["geometry_msgs/msg/WrenchStamped"].data.decode() == DEFINITIONS[
            "geometry_msgs/msg/WrenchStamped"]
        metadata = {record.name: record.metadata for record in reader.iter_metadata()}
        assert json.loads(metadata["ftacq_calibration"]["json"]) == calibration
    by_mcap: dict[str, list] = {}
    for message in read_ros2_messages(str(bag)):
        by_mcap.setdefault(message.channel.topic, []).append(message)
    by_rosbags: dict[str, list[bytes]] = {}
    with Reader(bag) as rosbag:
        for connection, _, raw in rosbag.messages():
            by_rosbags.setdefault(connection.topic, []).append(bytes(raw))
    topics = {f"{namespace}/{name}" for name in ("wrench_raw", "wrench_compensated", "calibration", "joint_states")}
    assert set(by_mcap) == set(by_rosbags) and topics <= set(by_rosbags)
    by_rosbags.setdefault(f"{namespace}/bias", [])
    for topic in topics:
        assert len(by_mcap[topic]) == len(by_rosbags[topic])
    assert f"ROS 2 bag: {sum(map(len, by_rosbags.values()))} messages recorded in {bag}" in last_lines
    assert "; 1 tares" in last_lines
    joint_state = by_mcap[f"{namespace}/joint_states"][-1].ros_msg
    assert list(joint_state.name)[0] == "shoulder_pan_joint" and len(joint_state.position) == 6
    # the drift tracker's bias: once it has seen the arm at rest (a second or two of sample time; under heavy load
    # the run may end first), the same messages on the wire and in the bag
    assert len(received["bias"]) == len(received["bias_sigma"]) == len(by_rosbags[f"{namespace}/bias"])
    assert [bytes.fromhex(entry["cdr"]) for entry in received["bias"]] == by_rosbags[f"{namespace}/bias"]
    for name in ("wrench_raw", "wrench_compensated"):
        in_bag = set(by_rosbags[f"{namespace}/{name}"])
        wire = [bytes.fromhex(entry["cdr"]) for entry in received[name]]
        assert all(message in in_bag for message in wire), name  # identical values, stamps and frames
        assert len(wire) >= 0.9 * len(in_bag), (name, len(wire), len(in_bag))  # reliable: all but discovery's start
        stamps = [_stamp_ns(entry) for entry in received[name]]
        assert stamps == sorted(stamps)


@pytest.mark.slow(seconds=8)
def test_every_sample_on_the_wire_equals_the_monitor_record(tmp_path, monkeypatch):
    """``--ros2-rate 0``: one message per sample; each raw and compensated message the subscriber receives equals
    the row of the monitor's own CSV record with the same sample time (the stamp is that time + one offset)."""
    from tests.scripted import read_record

    domain_id, namespace = _unique()
    out, record = tmp_path / "received.json", tmp_path / "monitor.csv"
    subscriber = _start_subscriber(domain_id, namespace, out, "--reliable")
    _run_monitor(monkeypatch, "--sim-still", "--ros2", "--ros2-reliable", "--ros2-rate", "0", "--ros2-domain-id",
                 str(domain_id), "--ros2-namespace", namespace, "--seconds", "3", "--record", str(record), "--record-rate", "0",
                 "--save", str(tmp_path / "monitor.rrd"))
    received = _finish(subscriber, out)
    table = read_record(record)
    sample_ns = np.rint(table["sample_time_s"] * 1e9).astype(np.int64)
    for name, columns in (("wrench_raw", ("fx", "fy", "fz", "tx", "ty", "tz")),
                          ("wrench_compensated", tuple("contact_" + c for c in ("fx", "fy", "fz", "tx", "ty", "tz")))):
        entries = received[name]
        assert len(entries) > 1000, name
        stamps = np.array([_stamp_ns(entry) for entry in entries])
        values = np.column_stack([table[c] for c in columns])
        published = np.flatnonzero(np.all(np.isfinite(values), axis=1))  # an uncompensated row sends no message
        first = np.flatnonzero(np.all(np.isclose(values, entries[0]["wrench"], rtol=1e-8, atol=1e-12), axis=1))
        assert len(first) == 1, name  # noisy samples: one row has these values
        # from the first message the subscriber took (discovery takes a moment), every message in order: the
        # record's rows one for one (matched by order, not by time: two samples can be dated within a µs)
        start = int(np.searchsorted(published, first[0]))
        rows = published[start:start + len(entries)]
        assert len(rows) == len(entries), name
        np.testing.assert_allclose(np.array([entry["wrench"] for entry in entries]), values[rows],
                                   rtol=1e-8, atol=1e-12, err_msg=name)
        # each stamp is its sample's time + one offset (the stamp clock's UNIX − monotonic), within float
        # rounding; where the sensor clock's mapping stepped back, the stamp is held at the previous one
        # (WindowMean: stamps never go back), by less than a millisecond
        offset_ns = stamps[0] - sample_ns[rows[0]]
        apart_ns = stamps - offset_ns - sample_ns[rows]
        held = np.r_[False, np.diff(stamps) == 0]
        assert np.all(np.abs(apart_ns[~held]) <= 1000), (name, np.sort(np.abs(apart_ns[~held]))[-5:])
        assert np.all((apart_ns[held] >= -1000) & (apart_ns[held] < 1_000_000)), (name, apart_ns[held])
        assert np.mean(held) < 0.01, name


def test_bad_ros2_options_are_one_line_and_exit_2(tmp_path, capsys):
    from ftacq.app.cli import main as ftacq_main

    for options, text in ((["--ros2-namespace", "/9cell"], "--ros2-namespace"),
                          (["--ros2-domain-id", "300"], "--ros2-domain-id"),
                          (["--ros2-frame-id", "/ft"], "--ros2-frame-id"),
                          (["--ros2-read-period", "0.5"], "--ros2-read-period"),
                          (["--ros2-read-period", "-0.01"], "--ros2-read-period")):
        assert ftacq_main(["monitor", "--sim", "--ros2", *options, "--seconds", "1"]) == 2
        err = capsys.readouterr().err.strip()
        assert text in err and "Traceback" not in err and len(err.splitlines()) == 1


def test_the_read_period_paces_the_monitor_and_keeps_the_hold():
    """``--ros2-read-period S`` sets the monitor's read pacing (default: on data, 0); the dynamic compensation's
    hold for the newest few ms is taken either way."""
    from types import SimpleNamespace

    from ftacq.app.ros2_outputs import ROS2_HOLD_S, ROS2_READ_PERIOD_S, prefer_low_latency

    for asked, expected in ((None, ROS2_READ_PERIOD_S), (0.01, 0.01), (0.0, 0.0)):
        cell = SimpleNamespace(monitor=SimpleNamespace(batch_period_s=0.123), compensator=SimpleNamespace(hold_s=0.0))
        prefer_low_latency(cell, asked)
        assert cell.monitor.batch_period_s == expected and cell.compensator.hold_s == ROS2_HOLD_S


def test_names_and_discovery_range(monkeypatch):
    """Namespaces and frames as ROS 2 accepts them; ROS 2's localhost-only variables keep discovery on this host
    unless CYCLONEDDS_URI decides."""
    from drivers.ros2.messages import dds_type_name
    from drivers.ros2.node import localhost_only
    from ftacq.ros2_names import check_frame_id, normalize_namespace

    assert normalize_namespace("cell_3/ft/") == "/cell_3/ft" and normalize_namespace("/") == ""
    for bad in ("/3cell", "/a-b", "/é"):
        with pytest.raises(ValueError):
            normalize_namespace(bad)
    assert check_frame_id(" tool0_ft ") == "tool0_ft"
    with pytest.raises(ValueError):
        check_frame_id("/ft_sensor")
    assert dds_type_name("std_srvs/srv/Trigger_Request") == "std_srvs::srv::dds_::Trigger_Request_"
    for name in ("CYCLONEDDS_URI", "ROS_LOCALHOST_ONLY", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.delenv(name, raising=False)
    assert not localhost_only()
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    assert localhost_only()
    monkeypatch.setenv("CYCLONEDDS_URI", "<CycloneDDS/>")
    assert not localhost_only()
