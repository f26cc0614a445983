"""Fuzz inputs for every file and URL a user can hand ftacq, and the entry points that read them.

Used by tests/test_fuzz_inputs.py (a few seconds, derandomised, in the suite) and benchmarks/fuzz.py (longer
runs that print the inputs tried and the escapes). An *escape* is any exception that is not ftacq's own
(:class:`ftacq.errors.FtacqError`): a traceback instead of a one-line message.

Each target takes the text a user could write (a file's content or a URL) and either accepts it or raises an
FtacqError. The strategies mix well-formed documents with the hazards found by hand: integers too large for a
float or over 4300 digits, NaN and infinities, nesting deep enough for a RecursionError, malformed IPv6 hosts,
empty and repeated keys, wrong types in every field.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Callable

from hypothesis import strategies as st

from ftacq.errors import FtacqError
from ftacq.posefile import CSV_COLUMN_ORDER, POSE_COLUMNS

HUGE_DIGITS = "7" * 5000
"""An integer literal over Python's 4300-digit conversion limit."""
DEEP = 3000
"""Nesting depth beyond the default recursion limit of Python's JSON and TOML parsers."""


# ------------------------------------------------------------------------------------------ strategies

numbers = st.one_of(
    st.integers(min_value=-(10**40), max_value=10**40),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, 1, -1, 0.0, 1.0, 1e300, -1e300, 5e-324, 2**53 + 1]),
)
json_leaves = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=12))
json_values = st.recursive(json_leaves, lambda children: st.one_of(
    st.lists(children, max_size=4), st.dictionaries(st.text(max_size=8), children, max_size=4)), max_leaves=16)


def _valid_calibration() -> dict:
    from ftacq.calfile import calibration_to_dict
    from tests.fakes.world import CellTruth

    return calibration_to_dict(CellTruth().calibration())


CALIBRATION_KEYS = ("format", "version", "sensor_rotation", "force_bias", "torque_bias", "gravity_base", "mass_kg",
                    "center_of_mass_m", "base_tilt_deg", "uncertainty", "metadata_key", "sensor", "tool", "bias_history")


def _text_mutation(draw, text: str) -> str:
    """Cut, insert or replace a slice of ``text`` with a hazard or random text."""
    hazard = draw(st.one_of(
        st.sampled_from([HUGE_DIGITS, "[" * DEEP, "{" * 10, "NaN", "-Infinity", "1e999", "\x00", "\ufeff", '"', ",",
                         "]]", "\n", "true", "null", "[[" * DEEP + "]]" * DEEP]),
        st.text(max_size=20)))
    start = draw(st.integers(min_value=0, max_value=len(text)))
    stop = draw(st.integers(min_value=start, max_value=min(len(text), start + 40)))
    return text[:start] + hazard + text[stop:]


@st.composite
def calibration_json(draw) -> str:
    """Text of a calibration file: a valid document with fields replaced or removed, or its text mutated."""
    document = _valid_calibration()
    if draw(st.booleans()):  # the optional provenance keys, well-formed, for the mutations below to break
        document["sensor"] = {"serial": "FT1", "counts_per_force": 1000000, "counts_per_torque": 1000000}
        document["tool"] = {"name": "gripper"}
        document["bias_history"] = [{"force_bias": [0.1, 0.2, 0.3], "torque_bias": [0.0, 0.0, 0.0], "time": "t"}]
        if draw(st.booleans()):
            document["bias_history"][0][draw(st.sampled_from(["force_bias", "torque_bias", "time", "method"]))] = \
                draw(json_values)
    for key in draw(st.lists(st.sampled_from(CALIBRATION_KEYS), max_size=3, unique=True)):
        if draw(st.booleans()):
            document[key] = draw(json_values)
        else:
            document.pop(key, None)
    if draw(st.booleans()):
        key = draw(st.sampled_from(("force_bias", "torque_bias", "gravity_base", "center_of_mass_m")))
        if isinstance(document.get(key), list) and document[key]:
            document[key][draw(st.integers(0, len(document[key]) - 1))] = draw(json_leaves)
    try:
        text = json.dumps(document, allow_nan=True)
    except (ValueError, RecursionError):  # an integer json.dumps itself cannot print
        text = json.dumps(_valid_calibration())
    if draw(st.integers(0, 3)) == 0:
        text = _text_mutation(draw, text)
    return text


def _toml_value(draw, depth: int = 0) -> str:
    kind = draw(st.integers(0, 8 if depth < 2 else 6))
    if kind == 0:
        return str(draw(st.integers(min_value=-(10**400), max_value=10**400)))
    if kind == 1:
        value = draw(st.floats(allow_nan=True, allow_infinity=True))
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if kind == 2:
        return draw(st.sampled_from(["true", "false"]))
    if kind == 3:
        return json.dumps(draw(st.text(max_size=16)))  # a TOML basic string is a JSON string
    if kind == 4:
        return draw(st.sampled_from([HUGE_DIGITS, "[" * DEEP + "]" * DEEP, '"ftp://x"', '"netft://[::1"',
                                     '"netft://"', '"netft://10.0.0.1:99999"', '"can://virtual/x?base=1&base=2"',
                                     '"UR99"', "0", "-5", "1e308", "0.0"]))
    if kind == 5:
        return json.dumps(draw(st.sampled_from(["netft://192.168.1.1", "can://virtual/bus", "UR5e", "UR3", "floor",
                                                "ceiling", "runs", "192.168.1.10"])))
    if kind == 6:
        return draw(st.sampled_from(["[1, 2, 3]", "[0.1, 0.2, 0.3]", "[[0.1, 0.2, 0.3, 0.0, 0.0, 0.0]]", "[]"]))
    items = draw(st.lists(st.integers(0, 0), max_size=6))
    return "[" + ", ".join(_toml_value(draw, depth + 1) for _ in items) + "]"


@st.composite
def cell_toml(draw) -> str:
    """Text of a CELL.toml: known sections and keys (and a few unknown ones) with values of every type."""
    from ftacq.app.config import SCHEMA

    lines = []
    for section in draw(st.lists(st.sampled_from([*SCHEMA, "extra"]), max_size=4, unique=True)):
        lines.append(f"[{section}]")
        names = list(SCHEMA.get(section, {})) + ["unknown_key"]
        for name in draw(st.lists(st.sampled_from(names), max_size=4, unique=True)):
            lines.append(f"{name} = {_toml_value(draw)}")
    text = "\n".join(lines) + "\n"
    if draw(st.integers(0, 4)) == 0:
        text = _text_mutation(draw, text)
    return text


CSV_CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(10**30), max_value=10**30).map(str),
    st.sampled_from(["", "nan", "inf", "-inf", "1e400", "-1e400", HUGE_DIGITS, '"1,5"', '"a""b"', "A01", "E",
                     "V", "0x10", "1_000", " 1 ", "1e30", "1e300", "-0", "#", "\ufeff1"]),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=8),
)


@st.composite
def pose_csv(draw) -> str:
    """Text of a pose record: a header (required columns, optional ones, shuffled, sometimes one missing) and
    rows of cells of every kind; sometimes a clean, identifiable record with one hazard mutated in."""
    columns = list(POSE_COLUMNS) + draw(st.lists(st.sampled_from(CSV_COLUMN_ORDER), max_size=6, unique=True))
    columns = list(dict.fromkeys(draw(st.permutations(columns))))
    if draw(st.integers(0, 5)) == 0:
        columns.pop(draw(st.integers(0, len(columns) - 1)))
    rows = draw(st.lists(st.lists(CSV_CELLS, min_size=len(columns), max_size=len(columns)), max_size=10))
    if draw(st.integers(0, 5)) == 0 and rows:
        rows[-1] = rows[-1][: draw(st.integers(0, len(columns)))]
    text = ",".join(columns) + "\n" + "".join(",".join(row) + "\n" for row in rows)
    if draw(st.integers(0, 3)) == 0:
        from ftacq.posefile import write_pose_csv
        from tests.fakes.pose_records import example_record

        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "poses.csv"
            write_pose_csv(path, example_record(seed=draw(st.integers(0, 3))))
            text = _text_mutation(draw, path.read_text(encoding="utf-8"))
    return text


HOSTS = st.one_of(st.sampled_from(["192.168.1.1", "[::1]", "[::1", "::1]", "", "h", "[", "]", "a b", "%41",
                                   "example.com", "[fe80::1%25eth0]", "999.999.999.999", "virtual", "socketcan",
                                   "not..a..host", ".", "a." + "b" * 64, "-x.example", "x_y", "é.example"]),
                  st.text(max_size=10))
PORTS = st.one_of(st.just(""), st.integers(-5, 70000).map(lambda p: f":{p}"), st.sampled_from([":", ":x", ":0",
                                                                                                 ":65535", ":1e3"]))
QUERY_KEYS = st.sampled_from(["rate_hz", "tcp_port", "http_port", "base", "bitrate", "timeout_s", "calibration",
                              "accept_any_port", "counts_per_force", "force_unit", "x", ""])


@st.composite
def sensor_url(draw) -> str:
    """A sensor URL: structured (scheme, host, port, path, query with repeated or unknown keys) or any text."""
    if draw(st.integers(0, 4)) == 0:
        return draw(st.text(max_size=40))
    scheme = draw(st.sampled_from(["netft", "can", "ftp", "", "NETFT", "http", "netft:"]))
    path = draw(st.sampled_from(["", "/", "/can0", "/x/y", "//dev/ttyACM0@115200", "/%zz"]))
    pairs = draw(st.lists(st.tuples(QUERY_KEYS, st.one_of(CSV_CELLS, st.just(""))), max_size=3))
    query = ("?" + "&".join(f"{k}={v}" for k, v in pairs)) if pairs else draw(st.sampled_from(["", "?", "?&&"]))
    return f"{scheme}://{draw(HOSTS)}{draw(PORTS)}{path}{query}"


@st.composite
def robot_host(draw) -> str:
    """What a user may type as the controller's address (``ftacq robot info HOST``, ``robot.host``)."""
    return draw(st.one_of(HOSTS, st.tuples(HOSTS, PORTS).map("".join), st.text(max_size=70)))


# ------------------------------------------------------------------------------------------ targets


class Targets:
    """The entry points a user's text reaches, each writing to a private temporary folder."""

    def __init__(self, identify: bool = False) -> None:
        self._folder = tempfile.TemporaryDirectory(prefix="ftacq-fuzz-")
        self.path = Path(self._folder.name)
        self.identify = identify

    def close(self) -> None:
        self._folder.cleanup()

    def _file(self, name: str, text: str) -> Path:
        path = self.path / name
        path.write_text(text, encoding="utf-8", errors="surrogatepass")
        return path

    def pose_csv(self, text: str) -> None:
        from ftacq.identification import diagnostics, identify
        from ftacq.posefile import read_pose_csv

        record = read_pose_csv(self._file("poses.csv", text))
        diagnostics.check_record_values(record.pose, record.wrench, record.labels, record.std, record.count)
        if self.identify and len(record) >= diagnostics.MIN_POSES:
            identify(record, refine=False)

    def calibration_json(self, text: str) -> None:
        import numpy as np

        from ftacq.calfile import load_calibration

        calibration = load_calibration(self._file("calibration.json", text))
        calibration.compensate(np.zeros((1, 6)), np.eye(3)[None])

    def cell_toml(self, text: str) -> None:
        from ftacq.app.config import load_config

        load_config(self._file("CELL.toml", text)).plan_settings()

    def sensor_url(self, url: str) -> None:
        from drivers.sensor import open_sensor
        from ftacq.app.config import check_sensor_url

        refused: list[BaseException] = []
        for parse in (lambda: check_sensor_url(url, "sensor.url"), lambda: open_sensor(url)):  # each on its own
            try:
                parse()
            except FtacqError as error:
                refused.append(error)
        if refused:
            raise refused[0]

    def robot_host(self, text: str) -> None:
        """Check the address as ``robot info`` does, then resolve an accepted one as the connection would,
        numeric only (a name is never looked up: no network): the resolver must not raise a foreign error."""
        import socket

        from drivers.ur_connection import controller_host

        host = controller_host(text)
        try:
            socket.getaddrinfo(host, 30004, flags=socket.AI_NUMERICHOST)
        except socket.gaierror:
            pass  # a name, not a number: resolving it is the connection's business

    def all(self) -> dict[str, tuple[object, Callable[[str], None]]]:
        """name → (strategy, target)."""
        return {"pose CSV": (pose_csv(), self.pose_csv), "calibration JSON": (calibration_json(), self.calibration_json),
                "CELL.toml": (cell_toml(), self.cell_toml), "sensor URL": (sensor_url(), self.sensor_url),
                "robot host": (robot_host(), self.robot_host)}


__all__ = ["Targets", "pose_csv", "calibration_json", "cell_toml", "sensor_url", "robot_host"]
