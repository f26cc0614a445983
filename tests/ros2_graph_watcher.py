"""An independent view of the ROS 2 graph for the tests: what a ROS 2 node's middleware (rmw_cyclonedds_cpp) watches
to build its graph, printed as it arrives. Its types are written here from rmw_dds_common's message definitions
(Gid.msg, NodeEntitiesInfo.msg, ParticipantEntitiesInfo.msg), not from ftacq. Run as a separate process:

    python tests/ros2_graph_watcher.py DOMAIN_ID GID_BYTES SECONDS

GID_BYTES is 24 (``char[24] data``: Humble) or 16 (``char[16] data``: Iron, Jazzy). One JSON object per line on
stdout: ``{"info": HEX}`` for each ``ros_discovery_info`` sample (its serialized bytes: the test decodes them with
rosbags), ``{"publication": {...}}`` / ``{"subscription": {...}}`` for each endpoint in DDS's built-in discovery
topics (``key``, ``participant``: GUIDs as hex; ``topic``, ``type``), ``{"participant": {...}}`` (``key``,
``user_data``). It prints ``"ready"`` first and stops after SECONDS.
"""

import json
import sys
import time
from dataclasses import dataclass, field

import cyclonedds.idl as idl
import cyclonedds.idl.annotations as annotate
import cyclonedds.idl.types as types
from cyclonedds.builtin import (BuiltinDataReader, BuiltinTopicDcpsParticipant, BuiltinTopicDcpsPublication,
                                BuiltinTopicDcpsSubscription)
from cyclonedds.core import InstanceState, Policy, Qos, ReadCondition, SampleState, ViewState, WaitSet
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from ros2_subscriber import take_raw


def graph_types(gid_bytes: int) -> type:
    @dataclass
    @annotate.final
    class Gid_(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
        data: types.array[types.uint8, gid_bytes] = field(default_factory=lambda: [0] * gid_bytes)

    @dataclass
    @annotate.final
    class NodeEntitiesInfo_(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
        node_namespace: types.bounded_str[256] = ""
        node_name: types.bounded_str[256] = ""
        reader_gid_seq: types.sequence[Gid_] = field(default_factory=list)
        writer_gid_seq: types.sequence[Gid_] = field(default_factory=list)

    @dataclass
    @annotate.final
    class ParticipantEntitiesInfo_(idl.IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
        gid: Gid_ = field(default_factory=Gid_)
        node_entities_info_seq: types.sequence[NodeEntitiesInfo_] = field(default_factory=list)

    return ParticipantEntitiesInfo_


def _endpoint(sample) -> dict:
    return {"key": sample.key.bytes.hex(), "participant": sample.participant_key.bytes.hex(),
            "topic": sample.topic_name, "type": sample.type_name}


def main() -> None:
    domain_id, gid_bytes, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    participant = DomainParticipant(domain_id)
    # as rmw_cyclonedds_cpp subscribes to it: reliable, transient local (a late joiner gets each node's last), CDR
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.TransientLocal,
              Policy.History.KeepAll, Policy.DataRepresentation(use_cdrv0_representation=True))
    info = DataReader(participant, Topic(participant, "ros_discovery_info", graph_types(gid_bytes), qos=qos), qos=qos)
    builtin = {"participant": BuiltinDataReader(participant, BuiltinTopicDcpsParticipant),
               "publication": BuiltinDataReader(participant, BuiltinTopicDcpsPublication),
               "subscription": BuiltinDataReader(participant, BuiltinTopicDcpsSubscription)}
    waitset = WaitSet(participant)
    for reader in (info, *builtin.values()):
        waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Alive))
    print("ready", flush=True)
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        waitset.wait(duration(milliseconds=100))
        lines = [{"info": bytes(data).hex()} for data, sample_info in take_raw(info) if sample_info.valid_data]
        for kind, reader in builtin.items():
            for sample in reader.take(N=100):
                if not sample.sample_info.valid_data:
                    continue
                if kind == "participant":
                    user_data = sample.qos[Policy.Userdata] if sample.qos is not None else None
                    lines.append({kind: {"key": sample.key.bytes.hex(),
                                         "user_data": bytes(user_data.data).decode() if user_data else ""}})
                else:
                    lines.append({kind: _endpoint(sample)})
        for line in lines:
            print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
