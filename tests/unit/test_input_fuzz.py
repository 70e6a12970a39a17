"""Damaged input gets a specific error, never a traceback: traces in every text and binary
format the bench reads, mutated byte by byte (flips, cuts, inserted numbers a damaged field
holds: inf, NaN, 20 digits), go through iter_trace (strict, and as summarise reads with
left_out) and validate's trace scan; the shipped scenarios, mutated key by key (a value of the
wrong type or range, a key gone or unknown, a list reversed), go through validate.checked.
Only the bench's InputError may come out. Bounded: derandomized, max_examples below, < 60 s.
The cases it found are kept below it as plain tests."""
from __future__ import annotations

import copy
import shutil
import tempfile
from pathlib import Path

import can
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canbench import validate
from canbench.errors import InputError, TraceError
from canbench.trace import iter_trace

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000.0
SUFFIXES = (".log", ".asc", ".blf", ".trc", ".csv")
FIELDS = [b"inf", b"nan", b"-1", b"1e400", b"99999999999999999999", b"\x00", b"\xff\xfe", b"\r\n", b"\n", b"#", b";"]
SETTINGS = settings(derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def recording() -> list[can.Message]:
    """40 frames of every kind a trace holds: 11- and 29-bit ids, DLC 0..8, remote frames, two channels."""
    frames = []
    for i in range(40):
        remote, extended = i % 11 == 5, i % 7 == 0
        frames.append(can.Message(timestamp=T0 + i * 0.01, arbitration_id=0x18FEF100 + i if extended else 0x100 + i % 5,
                                  is_extended_id=extended, is_remote_frame=remote, dlc=i % 9,
                                  data=b"" if remote else bytes(range(i % 9)), channel=i % 2))
    return frames


@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, bytes]:
    where = tmp_path_factory.mktemp("seeds")
    out = {}
    for suffix in SUFFIXES:
        path = where / f"seed{suffix}"
        with can.Logger(str(path)) as log:
            for m in recording():
                if not (suffix == ".trc" and m.is_remote_frame):  # python-can's TRC writer has none
                    log.on_message_received(m)
        out[suffix] = path.read_bytes()
    return out


EDITS = st.lists(st.tuples(st.sampled_from(["set", "cut", "insert", "field", "truncate", "copy"]),
                           st.integers(0, 1 << 16), st.integers(0, 1 << 16), st.binary(min_size=1, max_size=8),
                           st.sampled_from(FIELDS)), min_size=1, max_size=4)


def damaged(data: bytes, edits) -> bytes:
    b = bytearray(data)
    for op, at, other, blob, field in edits:
        if not b:
            break
        at %= len(b)
        if op == "set":
            b[at] = blob[0]
        elif op == "cut":
            del b[at:at + 1 + other % 20]
        elif op == "insert":
            b[at:at] = blob
        elif op == "field":
            b[at:at] = field
        elif op == "truncate":
            del b[at:]
        else:  # a piece of the file again elsewhere (a logger's buffer written twice)
            start = other % len(b)
            b[at:at] = b[start:start + 1 + other % 60]
    return bytes(b)


def read_every_way(path: Path) -> None:
    for read in (lambda: list(iter_trace(path)), lambda: list(iter_trace(path, left_out={})),
                 lambda: validate.trace_problems(path)):
        try:
            read()
        except TraceError:
            pass


@pytest.mark.parametrize("suffix", SUFFIXES)
@SETTINGS
@given(edits=EDITS)
def test_a_damaged_trace_is_refused_never_crashes(seeds, suffix, edits):
    with tempfile.TemporaryDirectory() as where:
        path = Path(where) / f"damaged{suffix}"
        path.write_bytes(damaged(seeds[suffix], edits))
        read_every_way(path)


WRONG = [None, True, 0, -1, 2**64, 1e308, float("inf"), 0.5, "", "x", "0x7FF", "1FFFFFFF", "traces/none.log",
         "a" * 300, [], [1], {}, {"a": 1}, "10 ms", "nan", "1e999", "123#DEADBEEF", "vcan99", "\x00"]
SCENARIOS = sorted((REPO / "scenarios").glob("*.yaml"))


def _paths(node, at=()):
    yield at
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        yield from _paths(value, (*at, key))


@pytest.fixture(scope="module")
def scenario_dir(tmp_path_factory) -> Path:
    where = tmp_path_factory.mktemp("scenarios") / "scenarios"
    shutil.copytree(REPO / "scenarios", where)
    return where


@SETTINGS
@given(data=st.data())
def test_a_damaged_scenario_is_refused_never_crashes(scenario_dir, data):
    source = data.draw(st.sampled_from(SCENARIOS), label="scenario")
    doc = yaml.safe_load(source.read_text())
    for _ in range(data.draw(st.integers(1, 3), label="edits")):
        paths = [p for p in _paths(doc) if p]
        at = data.draw(st.sampled_from(paths), label="at")
        parent = doc
        for key in at[:-1]:
            parent = parent[key]
        how = data.draw(st.sampled_from(["value", "remove", "unknown", "reverse"]), label="how")
        if how == "remove":
            del parent[at[-1]]
        elif how == "unknown" and isinstance(parent, dict):
            parent[data.draw(st.sampled_from(["zz", "every_ms", "id", "bus", "interface", "speed", "at_s"]))] = \
                copy.deepcopy(data.draw(st.sampled_from(WRONG)))
        elif how == "reverse" and isinstance(parent[at[-1]], list):
            parent[at[-1]] = parent[at[-1]][::-1]
        else:
            parent[at[-1]] = copy.deepcopy(data.draw(st.sampled_from(WRONG), label="value"))
    path = scenario_dir / f"damaged-{source.name}"
    path.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True))
    try:
        validate.checked(path)
    except InputError:
        pass


# What the fuzzing above found, kept as plain cases

@pytest.mark.parametrize("stamp", ["inf", "nan", "1e400", "-5.0"])
def test_a_stamp_that_is_no_time_is_refused_at_its_line(tmp_path, stamp):
    path = tmp_path / "t.csv"
    path.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n"
                    f"{T0},0x100,0,0,0,1,AQ==\n{stamp},0x100,0,0,0,1,AQ==\n")
    with pytest.raises(TraceError, match=r"t.csv:3: timestamp .* s is not a time"):
        list(iter_trace(path))


def test_a_name_the_os_refuses_is_said_at_the_scenario_line(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("name: s\nduration_s: 1\nbuses: [{name: vcan0}]\n"
                    f"dbc: {'a' * 300}.dbc\n"
                    f"ecus: [{{name: e, bus: vcan0, trace: {'b' * 300}.log}}]\n")
    said = [str(e) for e in validate.problems(path)]
    assert any(":4: dbc: cannot look up file" in s and "File name too long" in s for s in said), said
    assert any(":5: ecus.0.trace: cannot look up file" in s for s in said), said


def test_ecus_of_the_wrong_type_is_a_problem_not_a_crash(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("name: s\nduration_s: 1\nbuses: [{name: vcan0}]\necus: 1.5\n")
    assert validate.problems(path)


def test_a_blf_container_python_can_skips_is_refused_not_missing(tmp_path, seeds):
    # python-can skips a container of a compression method it does not know with only a log line
    data = bytearray(seeds[".blf"])
    header = int.from_bytes(data[4:8], "little")  # the file header's size: the first object follows
    assert data[header:header + 4] == b"LOBJ" and int.from_bytes(data[header + 12:header + 16], "little") == 10
    data[header + 16:header + 18] = (7).to_bytes(2, "little")  # LOG_CONTAINER's method: 0 or 2 (zlib)
    path = tmp_path / "odd.blf"
    path.write_bytes(bytes(data))
    with pytest.raises(TraceError, match=r"odd.blf: python-can skipped part of it .*Unknown compression method \(7\)"):
        list(iter_trace(path))
