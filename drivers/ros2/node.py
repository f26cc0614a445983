"""A DDS participant that is a ROS 2 node to every other node: topics and a Trigger service, no ROS install.

ROS 2's mapping onto DDS (the one rmw_cyclonedds_cpp implements): the ROS topic ``/ns/name`` is the DDS topic
``rt/ns/name`` of type ``pkg::msg::dds_::Type_`` (:mod:`drivers.ros2.messages`), data in plain CDR (XCDR1); a
service ``/ns/name`` is the request topic ``rq/ns/nameRequest`` and the reply topic ``rr/ns/nameReply``. QoS as
ROS 2 names them (rmw/qos_profiles.h): :data:`SENSOR_DATA` (best effort, keep last 5), :func:`reliable` (reliable,
keep last N), :data:`LATCHED` (reliable, transient local, keep last 1: a late subscriber with
transient-local durability gets the last message), :data:`SERVICES` (reliable, keep last 10).

Discovery: Cyclone DDS's own configuration. By default multicast on every interface (a cell network: any host on
the domain sees the topics); ``CYCLONEDDS_URI`` as for any Cyclone DDS program; and, as ROS 2 does,
``ROS_LOCALHOST_ONLY=1`` or ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keep it on this host (:data:`LOCALHOST_CONFIG`:
loopback, unicast discovery to the local participants, no multicast: what the tests use).

The node in the ROS 2 graph (``ros2 node list``, ``ros2 node info``, rqt_graph): as every ROS 2 node since Foxy,
:class:`NodeAnnouncer` publishes on the DDS topic ``ros_discovery_info`` (QoS :data:`LATCHED`) an
``rmw_dds_common/msg/ParticipantEntitiesInfo``: the participant's GID, and for its one node the name and namespace
(:func:`ftacq.ros2_names.node_of_namespace`) with the GIDs of the node's readers and writers; at start and again
whenever a writer, reader or service is added. A GID is the entity's DDS GUID (16 bytes, what other participants
see in their built-in DCPSPublication / DCPSSubscription topics) zero-padded to the release's ``Gid`` size
(rmw_cyclonedds_cpp ``convert_guid_to_gid``), so the graph ties each topic to the node. The participant's user data
``enclave=/;`` is rmw_cyclonedds_cpp's.

The Trigger service answers requests as rmw_cyclonedds_cpp does: the reply carries the request's header (client
writer handle, sequence number), and is sent once the caller's reply reader is matched (its ``clientid`` user data,
at most :data:`REPLY_MATCH_TIMEOUT_S`), so a ROS 2 client that uses Cyclone DDS (``RMW_IMPLEMENTATION=
rmw_cyclonedds_cpp``, the default of several ROS 2 releases) calls it. Other middlewares encode service requests
differently (topics work with any).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from typing import Callable

from cyclonedds.core import GuardCondition, Policy, Qos, ReadCondition, SampleState, ViewState, InstanceState, WaitSet
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter, Publisher
from cyclonedds.sub import DataReader, Subscriber
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from drivers.ros2.messages import TriggerRequest, TriggerResponse, discovery_types
from ftacq.errors import DeviceConnectionError
from ftacq.ros2_names import GID_BYTES, node_of_namespace, normalize_namespace
from ftacq.settings import setting_of

try:  # writes bytes already serialized (drivers/ros2/cdr.py) without one Python object per message
    from cyclonedds._clayer import ddspy_write_ts
except ImportError:  # pragma: no cover - a binding without it: decode and re-encode (slow, still correct)
    ddspy_write_ts = None

log = logging.getLogger(__name__)

RELIABLE_DEPTH = 100
"""History kept by a reliable wrench writer: 0.1 s at 1 kHz for a subscriber that falls behind, s·Hz."""
REPLY_MATCH_TIMEOUT_S = 1.0
"""Longest wait for a caller's reply reader before a service reply is sent anyway, s."""
CLOSE_ACK_TIMEOUT_S = 1.0
"""At close, reliable subscribers get this long to acknowledge the last messages, s."""
SERVICE_WAKE_S = 1.0
"""The service thread wakes at least this often (its stop is also signalled), s."""

_XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True)
SENSOR_DATA = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.Durability.Volatile, _XCDR1)


def reliable(depth: int = RELIABLE_DEPTH) -> Qos:
    """Reliable, volatile, keep last ``depth``: what a subscriber has not acknowledged yet is kept for it, up to
    ``depth`` messages (a writer overwrites the oldest beyond; it never blocks)."""
    return Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(int(depth)),
               Policy.Durability.Volatile, _XCDR1)


RELIABLE = reliable()
LATCHED = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(1),
              Policy.Durability.TransientLocal, _XCDR1)
SERVICES = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.History.KeepLast(10),
               Policy.Durability.Volatile, _XCDR1)

DISCOVERY_TOPIC = "ros_discovery_info"
"""The DDS topic (no ``rt`` prefix: not a ROS topic) on which ROS 2 nodes announce themselves (rmw_dds_common)."""
ENCLAVE_USER_DATA = b"enclave=/;"
"""The participant's user data, as rmw_cyclonedds_cpp sets it (the ROS 2 security enclave: the root, none)."""

LOCALHOST_CONFIG = (
    '<CycloneDDS><Domain Id="any"><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers>"
    "</Discovery></Domain></CycloneDDS>")
"""Cyclone DDS configuration for one host without multicast: loopback only, unicast discovery of up to 60
participants per domain on this host (``CYCLONEDDS_URI`` takes this text as it is)."""


def localhost_only() -> bool:
    """Whether ROS 2's environment asks for discovery on this host only (and ``CYCLONEDDS_URI`` does not decide)."""
    if os.environ.get("CYCLONEDDS_URI"):
        return False
    return (os.environ.get("ROS_LOCALHOST_ONLY") == "1"
            or os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() == "LOCALHOST")


@dataclass
class Writer:
    """One topic's DDS writer; :meth:`write_serialized` takes CDR bytes with their encapsulation header."""

    name: str  # the ROS topic name, "/ns/name"
    ros_type: str
    writer: DataWriter

    def write(self, message, stamp_ns: int | None = None) -> None:
        """Write a message object (a :mod:`drivers.ros2.messages` type); ``stamp_ns``: the DDS source time."""
        if stamp_ns is None:
            self.writer.write(message)
        else:
            self.writer.write(message, timestamp=int(stamp_ns))

    def write_serialized(self, data: bytes, stamp_ns: int) -> None:
        """Write one message already serialized (``drivers.ros2.cdr``); ``stamp_ns`` the DDS source time."""
        if ddspy_write_ts is None:  # pragma: no cover
            self.writer.write(self.writer.data_type.deserialize(data), timestamp=int(stamp_ns))
            return
        ret = ddspy_write_ts(self.writer._ref, data, int(stamp_ns))
        if ret < 0:
            raise OSError(f"DDS write on {self.name} failed ({ret})")

    def write_all(self, data: list[bytes], stamp_ns: list[int]) -> None:
        """:meth:`write_serialized` of each message (``stamp_ns`` ints), in one call (a read's few messages: the
        binding's write straight from this loop)."""
        if ddspy_write_ts is None:  # pragma: no cover
            for message, time_ns in zip(data, stamp_ns):
                self.write_serialized(message, time_ns)
            return
        ref = self.writer._ref
        for message, time_ns in zip(data, stamp_ns):
            ret = ddspy_write_ts(ref, message, time_ns)
            if ret < 0:
                raise OSError(f"DDS write on {self.name} failed ({ret})")

    @property
    def matched(self) -> int:
        """Subscriptions matched now."""
        return len(self.writer.get_matched_subscriptions())


class NodeAnnouncer:
    """Announces the participant's one ROS 2 node on ``ros_discovery_info`` (module docstring), with ``Gid`` as the
    ROS 2 release ``distro`` has it (:data:`ftacq.ros2_names.GID_BYTES`). :meth:`add` an entity of the node: the
    message is sent again."""

    def __init__(self, participant: DomainParticipant, publisher: Publisher, namespace: str, distro: str) -> None:
        if distro not in GID_BYTES:
            raise ValueError(f"ROS 2 release {distro!r} is not one of {', '.join(GID_BYTES)}")
        self.distro = distro
        self.gid_bytes = GID_BYTES[distro]
        self._gid_type, self._node_type, info_type = discovery_types(self.gid_bytes)
        self.node_namespace, self.node_name = node_of_namespace(namespace)
        self.participant_gid = self.gid(participant)
        self.reader_gids: list[bytes] = []
        self.writer_gids: list[bytes] = []
        self._lock = threading.Lock()
        self.writer = DataWriter(publisher, Topic(participant, DISCOVERY_TOPIC, info_type, qos=LATCHED), qos=LATCHED)
        self.message_type = info_type
        self.announce()

    def gid(self, entity) -> bytes:
        """A DDS entity's ROS 2 GID: its GUID (16 bytes), zero-padded to the release's ``Gid``."""
        return entity.guid.bytes.ljust(self.gid_bytes, b"\x00")

    def message(self):
        """The ``ParticipantEntitiesInfo`` now."""
        gid = self._gid_type
        with self._lock:
            node = self._node_type(self.node_namespace, self.node_name, [gid(list(g)) for g in self.reader_gids],
                                   [gid(list(g)) for g in self.writer_gids])
        return self.message_type(gid(list(self.participant_gid)), [node])

    def announce(self) -> None:
        self.writer.write(self.message())

    def add(self, *entities: DataReader | DataWriter) -> None:
        """Count readers and writers as the node's (a service: its request reader and reply writer), announce."""
        with self._lock:
            for entity in entities:
                (self.reader_gids if isinstance(entity, DataReader) else self.writer_gids).append(self.gid(entity))
        self.announce()


class Ros2Node:
    """A DDS participant on ``domain_id`` publishing under ``namespace``, announced as a ROS 2 node to the nodes of
    release ``distro`` (module docstring; default CELL.toml's ``sensor.ros2_distro``). Close it (or use it as a
    context manager): the service thread is joined and the participant deleted."""

    def __init__(self, namespace: str, domain_id: int = 0, config: str | None = None,
                 distro: str | None = None) -> None:
        self.namespace = normalize_namespace(namespace)
        self.domain_id = int(domain_id)
        if config is None and localhost_only():
            config = LOCALHOST_CONFIG
        try:
            self._domain = Domain(self.domain_id, config) if config is not None else None
            self.participant = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(ENCLAVE_USER_DATA)))
        except Exception as error:  # DDSException: a bad CYCLONEDDS_URI, no usable network interface, …
            raise DeviceConnectionError(f"ROS 2: no DDS participant on domain {self.domain_id} ({error}); check "
                                        "CYCLONEDDS_URI and the network interfaces") from None
        self._publisher = Publisher(self.participant)
        self._subscriber = Subscriber(self.participant)
        self._topics: dict[str, Topic] = {}
        self._services: list[TriggerServer] = []
        self._closed = False
        try:
            self.announcer = NodeAnnouncer(self.participant, self._publisher, self.namespace,
                                            distro if distro is not None else setting_of("sensor.ros2_distro").default)
        except BaseException:
            self.participant.__del__()
            raise

    def __enter__(self) -> "Ros2Node":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def ros_name(self, name: str) -> str:
        """``wrench_raw`` → ``/ns/wrench_raw``."""
        return f"{self.namespace}/{name.strip('/')}"

    def _topic(self, dds_name: str, data_type: type, qos: Qos) -> Topic:
        topic = self._topics.get(dds_name)
        if topic is None:
            topic = self._topics[dds_name] = Topic(self.participant, dds_name, data_type, qos=qos)
        return topic

    def writer(self, name: str, ros_type: str, data_type: type, qos: Qos = SENSOR_DATA) -> Writer:
        """A writer of the ROS topic ``<namespace>/name`` (DDS topic ``rt<namespace>/name``)."""
        ros_name = self.ros_name(name)
        topic = self._topic("rt" + ros_name, data_type, qos)
        writer = DataWriter(self._publisher, topic, qos=qos)
        self.announcer.add(writer)
        return Writer(ros_name, ros_type, writer)

    def trigger_service(self, name: str, handler: Callable[[], tuple[bool, str]]) -> "TriggerServer":
        """Serve ``std_srvs/srv/Trigger`` as ``<namespace>/name``: ``handler()`` → (success, message), called in
        the service's own thread ("ftacq-ros2-service")."""
        ros_name = self.ros_name(name)
        request_topic = self._topic(f"rq{ros_name}Request", TriggerRequest, SERVICES)
        reply_topic = self._topic(f"rr{ros_name}Reply", TriggerResponse, SERVICES)
        server = TriggerServer(ros_name, DataReader(self._subscriber, request_topic, qos=SERVICES),
                               DataWriter(self._publisher, reply_topic, qos=SERVICES), handler, self.participant)
        self._services.append(server)
        self.announcer.add(server.reader, server.writer)
        server.start()
        return server

    def close(self) -> None:
        """Stop the services (threads joined), give reliable subscribers up to :data:`CLOSE_ACK_TIMEOUT_S` to
        acknowledge what was written, and delete the participant with everything it holds (safe twice)."""
        if self._closed:
            return
        self._closed = True
        for server in self._services:
            server.close()
        try:
            self._publisher.wait_for_acks(duration(seconds=CLOSE_ACK_TIMEOUT_S))
        except Exception:  # noqa: BLE001 - a timeout (a subscriber gone silent) must not keep the run from ending
            log.info("not every reliable subscriber acknowledged the last messages", exc_info=True)
        self.participant.__del__()  # dds_delete: the participant and its readers, writers, topics
        self._domain = None


def _user_data_key(qos: Qos | None, key: str) -> str | None:
    """A ``key=value;`` entry of an endpoint's user data (rmw_cyclonedds_cpp puts ``clientid=…;`` there)."""
    try:
        policy = qos[Policy.Userdata]  # type: ignore[index]
    except (KeyError, TypeError):  # no QoS
        return None
    if policy is None:  # no user data
        return None
    for entry in bytes(policy.data).decode("utf-8", "replace").split(";"):
        name, _, value = entry.partition("=")
        if name == key:
            return value
    return None


class TriggerServer:
    """Answers ``std_srvs/srv/Trigger`` requests in its own thread (see :class:`Ros2Node.trigger_service`)."""

    def __init__(self, name: str, reader: DataReader, writer: DataWriter,
                 handler: Callable[[], tuple[bool, str]], participant: DomainParticipant) -> None:
        self.name = name
        self.reader, self.writer, self.handler = reader, writer, handler
        self.answered = 0
        self._stop = GuardCondition(participant)
        self._waitset = WaitSet(participant)
        self._waitset.attach(ReadCondition(reader, SampleState.NotRead | ViewState.Any | InstanceState.Any))
        self._waitset.attach(self._stop)
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="ftacq-ros2-service", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._closing = True
        self._stop.set(True)
        self._thread.join(2 * SERVICE_WAKE_S)

    def _run(self) -> None:
        while not self._closing:
            self._waitset.wait(duration(seconds=SERVICE_WAKE_S))
            if self._closing:
                return
            for request in self.reader.take(N=16):
                if not isinstance(request, TriggerRequest):
                    continue  # a disposed instance (a client gone)
                try:
                    success, message = self.handler()
                except Exception as error:  # noqa: BLE001 - the caller gets the failure as the answer
                    log.warning("service %s failed", self.name, exc_info=True)
                    success, message = False, f"{type(error).__name__}: {error}"
                self._wait_for_caller(request)
                self.writer.write(TriggerResponse(guid=request.guid, seq=request.seq, success=bool(success),
                                                  message=str(message)))
                self.answered += 1

    def _wait_for_caller(self, request: TriggerRequest) -> None:
        """Wait (at most REPLY_MATCH_TIMEOUT_S) until the caller's reply reader is matched, as rmw_cyclonedds_cpp's
        service does: a reply written before would reach no one."""
        info = getattr(request, "sample_info", None)
        client_id = None
        if info is not None:
            with _ignored_errors():
                endpoint = self.reader.get_matched_publication_data(info.publication_handle)
                client_id = _user_data_key(getattr(endpoint, "qos", None), "clientid")
        deadline_s = time.monotonic() + REPLY_MATCH_TIMEOUT_S
        while time.monotonic() < deadline_s:
            for handle in self.writer.get_matched_subscriptions():
                if client_id is None:
                    return
                with _ignored_errors():
                    endpoint = self.writer.get_matched_subscription_data(handle)
                    if _user_data_key(getattr(endpoint, "qos", None), "clientid") == client_id:
                        return
            time.sleep(0.01)  # discovery of the caller's reader: milliseconds; no event to wait on here


class _ignored_errors:
    def __enter__(self) -> None:
        return None

    def __exit__(self, kind, error, tb) -> bool:
        return kind is not None and issubclass(kind, Exception)


__all__ = ["Ros2Node", "NodeAnnouncer", "Writer", "TriggerServer", "DISCOVERY_TOPIC", "ENCLAVE_USER_DATA", "SENSOR_DATA", "RELIABLE", "LATCHED", "SERVICES",
           "LOCALHOST_CONFIG", "RELIABLE_DEPTH", "localhost_only", "reliable"]
