"""An independent ROS 2 subscriber for the tests: Cyclone DDS with ROS 2's type names, defined here from ROS 2's
message definitions (common_interfaces, rcl_interfaces), not from ftacq. Run as a separate process:

    python tests/ros2_subscriber.py DOMAIN_ID NAMESPACE SECONDS OUT.json [--reliable] [--tare-after N]

Subscribes to NAMESPACE/{wrench_raw, wrench_compensated, calibration, bias, bias_sigma}; writes every sample's
serialized bytes (hex; the DDS reader's own deserialization is checked against rosbags' in the test), the receipt
time (UNIX s) and, with --tare-after N, calls NAMESPACE/tare (std_srvs/srv/Trigger, as rmw_cyclonedds_cpp's client
does: user data clientid, request header = writer instance handle + sequence number) after N compensated messages.
It prints "ready" once its readers exist, and stops after SECONDS or once the publishers are gone after data.
"""

import json
import sys
import time
from dataclasses import dataclass, field

import cyclonedds.idl as idl
import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
@annotate.final
class Time_(idl.IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: types.int32 = 0
    nanosec: types.uint32 = 0


@dataclass
@annotate.final
class Header_(idl.IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_ = field(default_factory=Time_)
    frame_id: str = ""


@dataclass
@annotate.final
class Vector3_(idl.IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: types.float64 = 0.0
    y: types.float64 = 0.0
    z: types.float64 = 0.0


@dataclass
@annotate.final
class Wrench_(idl.IdlStruct, typename="geometry_msgs::msg::dds_::Wrench_"):
    force: Vector3_ = field(default_factory=Vector3_)
    torque: Vector3_ = field(default_factory=Vector3_)


@dataclass
@annotate.final
class WrenchStamped_(idl.IdlStruct, typename="geometry_msgs::msg::dds_::WrenchStamped_"):
    header: Header_ = field(default_factory=Header_)
    wrench: Wrench_ = field(default_factory=Wrench_)


@dataclass
@annotate.final
class String_(idl.IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
@annotate.final
class Trigger_Request_(idl.IdlStruct, typename="std_srvs::srv::dds_::Trigger_Request_"):
    guid: types.uint64 = 0  # rmw_cyclonedds_cpp's cdds_request_header_t
    seq: types.int64 = 0
    structure_needs_at_least_one_member: types.uint8 = 0


@dataclass
@annotate.final
class Trigger_Response_(idl.IdlStruct, typename="std_srvs::srv::dds_::Trigger_Response_"):
    guid: types.uint64 = 0
    seq: types.int64 = 0
    success: bool = False
    message: str = ""


CDR = Policy.DataRepresentation(use_cdrv0_representation=True)


def take_raw(reader: DataReader) -> list:
    """The samples as the wire brought them: (serialized bytes with their encapsulation header, sample info)."""
    from cyclonedds._clayer import ddspy_take

    taken = ddspy_take(reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, 1000)
    return [] if isinstance(taken, int) else taken


def main() -> None:
    domain_id, namespace, seconds, out = int(sys.argv[1]), sys.argv[2].rstrip("/"), float(sys.argv[3]), sys.argv[4]
    reliable = "--reliable" in sys.argv
    tare_after = int(sys.argv[sys.argv.index("--tare-after") + 1]) if "--tare-after" in sys.argv else None
    participant = DomainParticipant(domain_id)
    wrench_qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)) if reliable
                     else Policy.Reliability.BestEffort, Policy.History.KeepAll, CDR)  # Cyclone's own threads receive
    readers = {}
    for name in ("wrench_raw", "wrench_compensated"):
        readers[name] = DataReader(participant, Topic(participant, f"rt{namespace}/{name}", WrenchStamped_, qos=wrench_qos),
                                   qos=wrench_qos)
    low_qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(100), CDR)
    for name in ("bias", "bias_sigma"):
        readers[name] = DataReader(participant, Topic(participant, f"rt{namespace}/{name}", WrenchStamped_, qos=low_qos),
                                   qos=low_qos)
    latched = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.TransientLocal,
                  Policy.History.KeepLast(1), CDR)
    readers["calibration"] = DataReader(participant, Topic(participant, f"rt{namespace}/calibration", String_, qos=latched),
                                        qos=latched)
    service_qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(10), CDR)
    client_id = "clientid=ftacq-test-client;"
    client_qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(10), CDR,
                     Policy.Userdata(client_id.encode()))
    request_writer = DataWriter(participant, Topic(participant, f"rq{namespace}/tareRequest", Trigger_Request_,
                                                   qos=service_qos), qos=client_qos)
    reply_reader = DataReader(participant, Topic(participant, f"rr{namespace}/tareReply", Trigger_Response_,
                                                 qos=service_qos), qos=client_qos)
    waitset = WaitSet(participant)
    for reader in readers.values():
        waitset.attach(ReadCondition(reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    waitset.attach(ReadCondition(reply_reader, SampleState.Any | ViewState.Any | InstanceState.Any))
    print("ready", flush=True)
    raw: dict = {name: [] for name in readers}  # (receipt time, bytes): decoded after the run, not while receiving
    replies = []
    request = None
    deadline = time.time() + seconds
    seen_data = False
    while time.time() < deadline:
        waitset.wait(duration(milliseconds=100))  # wakes when data arrive
        for name, reader in readers.items():
            taken = take_raw(reader)
            if taken:
                received_s = time.time()
                raw[name].extend((received_s, data) for data, info in taken if info.valid_data)
                seen_data = True
        if (tare_after is not None and request is None and len(raw["wrench_compensated"]) >= tare_after
                and request_writer.get_matched_subscriptions()):
            request = Trigger_Request_(guid=request_writer.instance_handle & 0xFFFFFFFFFFFFFFFF, seq=1)
            request_writer.write(request)
        for reply in reply_reader.take(N=10):
            if getattr(reply.sample_info, "valid_data", False):
                replies.append({"guid": reply.guid, "seq": reply.seq, "success": reply.success,
                                "message": reply.message})
        if seen_data and not readers["wrench_raw"].get_matched_publications():
            break  # the publisher is gone
    got: dict = {}
    for name, entries in raw.items():
        data_type = readers[name].topic.data_type
        got[name] = []
        for received_s, data in entries:
            sample = data_type.deserialize(data)
            entry = {"received_s": received_s, "cdr": bytes(data).hex()}
            if isinstance(sample, WrenchStamped_):
                w = sample.wrench
                entry.update(stamp=[sample.header.stamp.sec, sample.header.stamp.nanosec],
                             frame_id=sample.header.frame_id,
                             wrench=[w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z])
            else:
                entry["data"] = sample.data
            got[name].append(entry)
    got["tare_replies"] = replies
    got["request_guid"] = None if request is None else request.guid
    with open(out, "w") as handle:
        json.dump(got, handle)


if __name__ == "__main__":
    main()
