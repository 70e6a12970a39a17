"""J1939 parameter groups from any source address (dbc.message_of): a DBC names one 29-bit id
per message, its usual sender and priority; a truck's network sends a group from other sources,
at other priorities, to other destinations (PDU1). A frame of no message's id is the group's
when the DBC marks one message of that group J1939 (VFrameFormat J1939PG), and only one; a
29-bit message not marked J1939 (UDS on 29 bits) keeps its exact id. Signal gates, responses
and the DBC's cycle times all follow; seeded faults fail each."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import can
import pytest
from synthetic import signal_problems

from canbench import checks, cli, dbc, ecu, oracle, recording, responses, scenario, wire

pytestmark = pytest.mark.unit

T0 = 1_700_000_000_000_000_000
EXT = 0x80000000  # a DBC's flag of a 29-bit id
J1939_DBC = f'''VERSION ""
NS_ :
BS_:
BU_: ENGINE BRAKES
BO_ {EXT | 0x0CF00400} EEC1: 8 ENGINE
 SG_ EngineSpeed : 24|16@1+ (0.125,0) [0|8031.875] "rpm" Vector__XXX
BO_ {EXT | 0x0C000F03} TSC1: 8 ENGINE
 SG_ RequestedSpeed : 8|16@1+ (0.125,0) [0|8031.875] "rpm" Vector__XXX
BO_ {EXT | 0x18FEF100} CCVS_ENGINE: 8 ENGINE
 SG_ WheelSpeed : 8|16@1+ (0.00390625,0) [0|250.996] "km/h" Vector__XXX
BO_ {EXT | 0x18FEF10B} CCVS_BRAKES: 8 BRAKES
 SG_ WheelSpeed : 8|16@1+ (0.00390625,0) [0|250.996] "km/h" Vector__XXX
BO_ {EXT | 0x18DAF110} UDS_REQUEST: 8 ENGINE
 SG_ Byte0 : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ {EXT | 0x18DAF100} UDS_UNMARKED: 8 ENGINE
 SG_ Byte0 : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ {EXT | 0x0C000F0A} NOT_J1939: 8 ENGINE
 SG_ Byte0 : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ {EXT | 0x18FF1200} PROPB_ENGINE: 8 ENGINE
 SG_ Byte0 : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BO_ {EXT | 0x18EF2100} PROPA_ENGINE: 8 ENGINE
 SG_ Byte0 : 0|8@1+ (1,0) [0|255] "" Vector__XXX
BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","J1939PG";
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_DEF_DEF_ "VFrameFormat" "J1939PG";
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "VFrameFormat" BO_ {EXT | 0x18DAF110} 1;
BA_ "VFrameFormat" BO_ {EXT | 0x0C000F0A} 1;
BA_ "GenMsgCycleTime" BO_ {EXT | 0x0CF00400} 10;
'''


@pytest.fixture
def db(tmp_path):
    (tmp_path / "truck.dbc").write_text(J1939_DBC)
    return dbc.load_dbc(tmp_path / "truck.dbc")


def name_of(db, can_id: int, extended: bool = True) -> str | None:
    m = dbc.message_of(db, wire.Frame(can_id, 8, bytes(8), extended))
    return None if m is None else m.name


def test_a_group_is_found_from_any_source_priority_and_destination(db):
    assert name_of(db, 0x0CF00400) == "EEC1"           # the DBC's own id
    assert name_of(db, 0x0CF00417) == "EEC1"           # another source address
    assert name_of(db, 0x18F00417) == "EEC1"           # and another priority
    assert name_of(db, 0x0C000A05) == "TSC1"           # PDU1: another destination and source
    assert name_of(db, 0x18FEF10B) == "CCVS_BRAKES"    # a sender the DBC names is its own message
    assert name_of(db, 0x18FEF121) is None             # the DBC has the group from two senders: whose?
    assert name_of(db, 0x18DAF110) == "UDS_REQUEST"
    assert name_of(db, 0x18DA10F1) is None             # not a J1939 group in the DBC: its exact id only
    assert name_of(db, 0x0CF00500) is None             # another group
    assert name_of(db, 0x400, extended=False) is None  # an 11-bit frame is never a J1939 group's
    assert name_of(db, 0x2CF00417) is None             # past 29 bits (an EFF flag left in the id)


def test_groups_whose_data_its_sender_defines_keep_their_exact_id(db):
    """Proprietary A and B mean what each manufacturer makes them mean, and UDS on 29 bits is a
    request or an answer by its addresses: another source's frame is not the DBC's message, even
    where the DBC marks every message J1939 by default (BA_DEF_DEF_ "J1939PG")."""
    assert name_of(db, 0x18FF1200) == "PROPB_ENGINE" and name_of(db, 0x18FF1233) is None
    assert name_of(db, 0x18EF2100) == "PROPA_ENGINE" and name_of(db, 0x18EF4521) is None
    assert name_of(db, 0x18DAF100) == "UDS_UNMARKED" and name_of(db, 0x18DA00F1) is None


def scenario_path(tmp: Path, expect: str) -> Path:
    (tmp / "truck.dbc").write_text(J1939_DBC)
    (tmp / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 0CF00417#0000000000000000\n")
    path = tmp / "sc.yaml"
    path.write_text("name: truck\nduration_s: 10\ndbc: truck.dbc\nbuses:\n  - name: vcan0\n"
                    "ecus:\n  - name: e\n    bus: vcan0\n    trace: trace.log\nexpect:\n" + expect)
    return path


def eec1(rpm: float, source: int = 0x17) -> wire.Frame:
    raw = round(rpm / 0.125)
    return wire.Frame(0x0CF00400 | source, 8, bytes([0xFF] * 3) + raw.to_bytes(2, "little") + bytes([0xFF] * 3), True)


def observed(frames: list[wire.Frame], step_ns: int = 10_000_000):
    bus = [oracle.Observed(f, T0 + i * step_ns, i, line=i + 1) for i, f in enumerate(frames)]
    zen = [oracle.Observed(f, T0 + i * step_ns + 400_000, i, key="vehicle/can/rx", seq=i)
           for i, f in enumerate(frames)]
    return bus, zen


def test_a_signal_gate_judges_the_group_from_another_source(tmp_path):
    path = scenario_path(tmp_path, "  signals:\n    EEC1.EngineSpeed: {range: [600, 2000]}\n")
    assert signal_problems(path, [eec1(800), eec1(850)]) == []
    problems = signal_problems(path, [eec1(800), eec1(2500)])
    assert len(problems) == 1 and "EEC1.EngineSpeed = 2500 rpm outside [600, 2000] at t=0.010 s" in problems[0]


def test_the_dbc_cycle_is_judged_on_the_group_from_another_source(tmp_path):
    path = scenario_path(tmp_path, "  cycle_time: {from_dbc: true, tolerance_pct: 20}\n")
    sc = scenario.load(path)
    cycles = {"0CF00417": {"can": {"count": 50, "cycle_p50_ms": 20.0, "cycle_max_ms": 21.0},
                           "zenoh": {"count": 50, "cycle_p50_ms": 20.0, "cycle_max_ms": 21.0}}}
    result = SimpleNamespace(scenario=sc, buses=[SimpleNamespace(bus="vcan0", cycle_times=cycles)])
    problems = checks.cycle_time(result)
    assert problems and "vcan0 id 0CF00417 (EEC1): median cycle 20.00 ms on the bus, the DBC says 10.00 ms" \
        in problems[0]
    cycles["0CF00417"]["can"] |= {"cycle_p50_ms": 10.0, "cycle_max_ms": 10.5}
    cycles["0CF00417"]["zenoh"] |= {"cycle_p50_ms": 10.0, "cycle_max_ms": 10.5}
    assert checks.cycle_time(result) == []


def test_a_response_is_read_from_the_group_from_another_source(db):
    problems: list = []
    spec = {"when": {"signal": "TSC1.RequestedSpeed", "above": 1000},
            "then": {"signal": "EEC1.EngineSpeed", "above": 1000}, "within_ms": 100, "side": "bus"}
    [rule] = responses.rules({"buses": [{"name": "vcan0"}], "expect": {"responses": [spec]}}, {"vcan0": "truck.dbc"},
                             lambda _: db, lambda where, m: problems.append(m))
    assert problems == []
    request = wire.Frame(0x0C000A05, 8, bytes([0xFF]) + (1200 * 8).to_bytes(2, "little") + bytes(5), True)
    frames, _ = observed([request, eec1(1100)])
    values = responses._values(rule.db, rule.response_message, rule.response_signal, frames)
    assert [v for _, v in values] == [1100]
    stimuli = responses._values(rule.db, rule.stimulus_message, rule.stimulus_signal, frames)
    assert [v for _, v in stimuli] == [1200]


def test_max_rate_follows_each_sender_of_a_group(tmp_path):
    """Two engines' EEC1 interleaved (sources 00 and 17): each steady, so no change between
    one's value and the other's is a rate; a jump of one of them is."""
    path = scenario_path(tmp_path, "  signals:\n    EEC1.EngineSpeed: {max_rate: 1000}\n")
    steady = [f for _ in range(5) for f in (eec1(800, source=0x00), eec1(1500, source=0x17))]
    assert signal_problems(path, steady) == []
    jump = steady[:6] + [eec1(800, source=0x00), eec1(1600, source=0x17)]
    problems = signal_problems(path, jump)
    assert len(problems) == 1 and "EEC1.EngineSpeed changed 1500 rpm -> 1600 rpm in 20.000 ms" in problems[0]


def test_the_recording_keeps_each_sender_of_a_group_on_its_own_channel(db):
    topics: list[str] = []
    writer = SimpleNamespace(write=lambda topic, *_: topics.append(topic))
    names = recording.TopicNames()
    for f in (eec1(800, source=0x00), eec1(1500, source=0x17)):
        recording._signals(writer, names, "/signals/vcan0", db, oracle.Observed(f, T0, 0))
    assert topics == ["/signals/vcan0/EEC1/EngineSpeed", "/signals/vcan0/EEC1_0CF00417/EngineSpeed"]


@pytest.mark.parametrize("every_ms, said", [(10, None), (20, 20.0)])
def test_scaffold_takes_the_dbc_cycle_for_the_group_from_another_source(tmp_path, capsys, every_ms, said):
    """The recording's EEC1 comes from source 17: from_dbc judges it by the DBC's 10 ms, so a
    trace at 20 ms gets its own cycle in ids (the first run passes), at 10 ms none."""
    (tmp_path / "truck.dbc").write_text(J1939_DBC)
    trace = tmp_path / "drive.log"
    trace.write_text("".join(f"({T0 / 1e9 + i * every_ms / 1000:.6f}) can0 0CF00417#FFFFFF4019FFFFFF\n"
                             for i in range(100)))
    out = tmp_path / "sc" / "drive.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "drive", "--out", str(out),
                     "--dbc", str(tmp_path / "truck.dbc")]) == 0
    cycle = scenario.load(out).expect["cycle_time"]
    assert cycle["from_dbc"] is True and (cycle.get("ids") or {}).get("0CF00417") == said


def test_a_responder_answers_a_j1939_request_from_any_source(tmp_path):
    """The request filter passes the group from any source and priority, to the DBC's destination
    or global (the socket's filter as SocketCAN applies it), and the frame finds its rule; another
    group, another destination, or the id of another message of the DBC does not."""
    (tmp_path / "truck.dbc").write_text(J1939_DBC)
    path = tmp_path / "sc.yaml"
    (tmp_path / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 0CF00417#0000000000000000\n")
    path.write_text("name: truck\nduration_s: 10\ndbc: truck.dbc\nbuses:\n  - name: vcan0\necus:\n"
                    "  - name: e\n    bus: vcan0\n    trace: trace.log\n"
                    "  - name: ecm\n    bus: vcan0\n    role: responder\n"
                    "    rules: [{request: TSC1, send: EEC1, set: {EngineSpeed: RequestedSpeed}},\n"
                    "            {request: UDS_UNMARKED, send: EEC1}]\nexpect:\n  integrity: true\n")
    ecm = next(e for e in scenario.load(path).ecus if e.name == "ecm")
    filters, rule_of = ecu.request_routes(ecm.rules)

    def passes(can_id: int) -> bool:
        return any((can_id & f["can_mask"]) == (f["can_id"] & f["can_mask"]) for f in filters)

    def rule(can_id: int):
        return rule_of(can.Message(arbitration_id=can_id, is_extended_id=True))
    for request in (0x0C000F03, 0x0C000F05, 0x18000F05, 0x0C00FF05):  # the DBC's; another source, priority; global
        assert passes(request) and rule(request).on.name == "TSC1"
    assert not passes(0x0C000A05) and rule(0x0C000A05) is None  # a TSC1 to another ECU: not this one's to answer
    assert passes(0x0C000F0A) and rule(0x0C000F0A) is None  # the id of a message not J1939, in TSC1's group
    assert passes(0x18DAF100) and rule(0x18DAF100).on.name == "UDS_UNMARKED"
    assert not passes(0x18DA00F1) and rule(0x18DA00F1) is None  # UDS: its exact id only
    assert not passes(0x0CF00400) and rule(0x0CF00400) is None  # another group
