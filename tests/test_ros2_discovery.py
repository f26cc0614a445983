"""ftacq's ROS 2 node in the ROS 2 graph (``ros2 node list`` / ``node info``): its ``ros_discovery_info``, checked
from another process (tests/ros2_graph_watcher.py: the message type written there from rmw_dds_common's
definitions, DDS's built-in discovery topics) and decoded with rosbags' ROS 2 typestores (Humble: 24-byte Gid,
Jazzy: 16). Discovery on loopback without multicast, one domain and namespace per test (tests/test_ros2.py)."""

from __future__ import annotations

import contextlib
import json
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from rosbags.typesys import Stores, get_typestore  # noqa: E402

from tests.test_ros2 import _env, _unique  # noqa: E402

WATCHER = Path(__file__).with_name("ros2_graph_watcher.py")
DEADLINE_S = 30.0
"""Longest wait for what the watcher should see (discovery on loopback: well under a second)."""


class Watcher:
    """tests/ros2_graph_watcher.py in its own process, and what it printed so far."""

    def __init__(self, domain_id: int, gid_bytes: int) -> None:
        self.process = subprocess.Popen([sys.executable, str(WATCHER), str(domain_id), str(gid_bytes), "120"],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
        self.infos: list[bytes] = []
        self.endpoints: dict[str, dict] = {}  # GUID hex → {"kind", "topic", "type", "participant"}
        self.participants: dict[str, str] = {}  # GUID hex → user data
        self._lines: queue.Queue[str] = queue.Queue()  # a thread reads them: select() misses buffered lines
        threading.Thread(target=self._read, daemon=True).start()
        assert self._line(time.monotonic() + DEADLINE_S) == "ready"

    def _read(self) -> None:
        for line in self.process.stdout:
            self._lines.put(line.strip())
        self._lines.put("")  # the process ended

    def _line(self, deadline_s: float) -> str:
        try:
            line = self._lines.get(timeout=max(0.0, deadline_s - time.monotonic()))
        except queue.Empty:
            raise AssertionError(f"the watcher printed nothing in time ({len(self.infos)} announcements, "
                                 f"{len(self.endpoints)} endpoints so far)") from None
        assert line, f"the watcher ended: {self.process.stderr.read()}"
        return line

    def until(self, condition, what: str):
        """Read lines until ``condition()`` is true (returns it); fails after DEADLINE_S."""
        deadline_s = time.monotonic() + DEADLINE_S
        while not (result := condition()):
            assert time.monotonic() < deadline_s, (f"{what}: {len(self.infos)} announcements, endpoints "
                                                   f"{sorted(e['topic'] for e in self.endpoints.values())}")
            entry = json.loads(self._line(deadline_s))
            if "info" in entry:
                self.infos.append(bytes.fromhex(entry["info"]))
            elif "participant" in entry:
                self.participants[entry["participant"]["key"]] = entry["participant"]["user_data"]
            else:
                (kind, endpoint), = entry.items()
                self.endpoints[endpoint["key"]] = dict(endpoint, kind=kind)
        return result

    def close(self) -> None:
        self.process.kill()
        self.process.communicate(timeout=30)


def _monitor_node(stack: contextlib.ExitStack, *options: str):
    """The node ``ftacq monitor --ros2 …`` makes (its options parsed by the monitor's own parser), with the
    monitor's topics and tare service."""
    from ftacq.app.cli import build_parser
    from ftacq.app.ros2_outputs import ros2_listeners

    source = () if "--config" in options else ("--sim",)
    args = build_parser().parse_args(["monitor", *source, "--ros2", *options])
    listeners, _ = ros2_listeners(args, stack, calibration=lambda: None, tare=lambda: None)
    return listeners[0].publisher.node


@pytest.mark.parametrize("distro, store, gid_bytes", [("humble", Stores.ROS2_HUMBLE, 24),
                                                      ("jazzy", Stores.ROS2_JAZZY, 16)])
def test_the_monitor_node_is_announced_with_its_writers_gids(distro, store, gid_bytes, monkeypatch):
    """A late joiner (transient local) gets the node's ParticipantEntitiesInfo: node namespace and name from
    ``--ros2-namespace``, the participant's GID and its writers' and readers' GIDs = the GUIDs DDS discovery shows
    for that participant's endpoints (the topics tied to the node, as ``ros2 node info`` does); a writer added later
    is announced again."""
    from drivers.ros2.messages import String
    from drivers.ros2.node import DISCOVERY_TOPIC, LATCHED, LOCALHOST_CONFIG

    monkeypatch.setenv("CYCLONEDDS_URI", LOCALHOST_CONFIG)
    typestore = get_typestore(store)
    domain_id, parent = _unique()
    namespace = parent + "/ft_node"
    with contextlib.ExitStack() as stack:
        node = _monitor_node(stack, "--ros2-domain-id", str(domain_id), "--ros2-namespace", namespace,
                             "--ros2-distro", distro)
        watcher = Watcher(domain_id, gid_bytes)  # after the node's entities exist: only durability brings them
        stack.callback(watcher.close)

        def node_view(extra_writers: int = 0):
            """(message, its node, the participant's endpoints by kind) once the last message and DDS discovery
            agree on the number of endpoints, else None."""
            if not watcher.infos:
                return None
            message = typestore.deserialize_cdr(watcher.infos[-1], "rmw_dds_common/msg/ParticipantEntitiesInfo")
            participant = bytes(message.gid.data)
            (ours,) = message.node_entities_info_seq
            mine = {"publication": set(), "subscription": set()}
            for key, endpoint in watcher.endpoints.items():
                if bytes.fromhex(endpoint["participant"]) == participant[:16] and endpoint["topic"] != DISCOVERY_TOPIC:
                    mine[endpoint["kind"]].add(key)
            if (len(ours.writer_gid_seq) != 6 + extra_writers or len(mine["publication"]) != len(ours.writer_gid_seq)
                    or len(mine["subscription"]) != len(ours.reader_gid_seq)):
                return None
            return message, ours, mine

        message, ours, mine = watcher.until(node_view, "the node's announcement and its endpoints")
        assert (ours.node_namespace, ours.node_name) == (parent, "ft_node")
        assert len(message.gid.data) == gid_bytes and bytes(message.gid.data[16:]) == bytes(gid_bytes - 16)
        assert bytes(message.gid.data[:16]) == node.participant.guid.bytes
        assert bytes(message.gid.data[:16]).hex() in watcher.until(lambda: watcher.participants, "participant")
        assert "enclave=/;" in watcher.participants[bytes(message.gid.data[:16]).hex()]
        writers = {bytes(gid.data[:16]).hex() for gid in ours.writer_gid_seq}
        readers = {bytes(gid.data[:16]).hex() for gid in ours.reader_gid_seq}
        assert writers == mine["publication"] and readers == mine["subscription"]
        topics = {watcher.endpoints[key]["topic"] for key in writers}
        assert topics == {f"rt{namespace}/{name}" for name in ("wrench_raw", "wrench_compensated", "bias",
                                                               "bias_sigma", "calibration")} | {f"rr{namespace}/tareReply"}
        assert {watcher.endpoints[key]["topic"] for key in readers} == {f"rq{namespace}/tareRequest"}
        wrench = {key for key in writers if watcher.endpoints[key]["topic"] == f"rt{namespace}/wrench_raw"}
        assert wrench and all(watcher.endpoints[key]["type"] == "geometry_msgs::msg::dds_::WrenchStamped_"
                              for key in wrench)

        # a writer added later: announced again, with its GID
        added = node.writer("added", "std_msgs/msg/String", String, LATCHED)
        _, ours, mine = watcher.until(lambda: node_view(extra_writers=1), "the node announced again")
        assert added.writer.guid.bytes.hex() in {bytes(gid.data[:16]).hex() for gid in ours.writer_gid_seq}
        assert watcher.endpoints[added.writer.guid.bytes.hex()]["topic"] == f"rt{namespace}/added"


def test_node_names_and_distros():
    """The namespace is the node's full name; every release ftacq offers has a Gid size and a CLI choice."""
    from ftacq.ros2_names import GID_BYTES, ROS2_DISTROS, node_of_namespace
    from ftacq.settings import setting_of

    assert node_of_namespace("/cell_3/ft") == ("/cell_3", "ft")
    assert node_of_namespace("/ftacq") == ("/", "ftacq")
    assert node_of_namespace("/") == ("/", "ftacq")
    assert set(ROS2_DISTROS) == set(GID_BYTES) == set(setting_of("sensor.ros2_distro").choices or ())
    assert GID_BYTES["humble"] == 24 and GID_BYTES["jazzy"] == 16
    for distro, gid_bytes in (("humble", 24), ("iron", 16), ("jazzy", 16)):
        store = get_typestore(getattr(Stores, f"ROS2_{distro.upper()}"))
        (_, (_, ((_, _), size))), = store.fielddefs["rmw_dds_common/msg/Gid"][1]
        assert size == gid_bytes == GID_BYTES[distro]


def test_the_release_comes_from_cell_toml_unless_the_option_says(tmp_path, monkeypatch):
    """CELL.toml ``sensor.ros2_distro`` picks the Gid size, ``--ros2-distro`` overrides it; a release ftacq does not
    know is one line naming the key."""
    from drivers.ros2.node import LOCALHOST_CONFIG
    from ftacq.app.config import load_config
    from ftacq.errors import ConfigError

    monkeypatch.setenv("CYCLONEDDS_URI", LOCALHOST_CONFIG)
    domain_id, namespace = _unique()
    cell = tmp_path / "CELL.toml"
    cell.write_text('[sensor]\nros2_distro = "humble"\n', encoding="utf-8")
    common = ("--config", str(cell), "--ros2-domain-id", str(domain_id), "--ros2-namespace", namespace)
    for options, gid_bytes in (((), 24), (("--ros2-distro", "jazzy"), 16)):
        with contextlib.ExitStack() as stack:
            announcer = _monitor_node(stack, *common, *options).announcer
            assert announcer.gid_bytes == gid_bytes
            assert len(bytes(announcer.message().gid.data)) == gid_bytes
    cell.write_text('[sensor]\nros2_distro = "foxy"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"sensor\.ros2_distro.*foxy.*humble"):
        load_config(cell)
