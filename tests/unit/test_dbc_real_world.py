"""DBCs and recordings as engineers bring them, each case a minimal snippet of what public vehicle
DBCs do (opendbc, cantools' test files): UTF-8 and cp1252 text, a byte-order mark, a signal trace
saved by a spreadsheet, a cantools refusal placed at the DBC's line, a float signal carrying NaN, a
negative scale, a multiplexed command, a value-table start value, and one signal name scaled
differently by two buses' DBCs."""
from __future__ import annotations

import json
import struct
from pathlib import Path
from types import SimpleNamespace

import pytest
from test_signals import DBC as SIGNALS_DBC
from test_signals import T0, gates_of, run_of

from canbench import checks, cli, dbc, oracle, plans, responses, restbus, scenario, signals, wire
from canbench.errors import InputError

pytestmark = pytest.mark.unit

DOOR = """VERSION ""
NS_ :
BS_:
BU_: BODY GW
BO_ 256 Door: 8 BODY
 SG_ DoorState : 0|2@1+ (1,0) [0|3] "" GW
 SG_ Temp : 8|8@1+ (1,-40) [-40|215] "°C" GW
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 256 100;
VAL_ 256 DoorState 0 "Geschlossen" 1 "Geöffnet" 2 "Fehler" ;
"""

RESTBUS = """name: door
duration_s: 5
dbc: door.dbc
buses: [{name: vcan0}]
ecus:
  - name: body
    bus: vcan0
    role: restbus
    dbc_node: BODY
    run_s: 1
    signals:
      Door.DoorState: SIGNAL
expect:
  signals:
    Door.DoorState: {equals: Geöffnet}
"""


def door_scenario(tmp_path: Path, dbc_bytes: bytes, signal: str = "Geöffnet") -> Path:
    (tmp_path / "door.dbc").write_bytes(dbc_bytes)
    path = tmp_path / "door.yaml"
    path.write_text(RESTBUS.replace("SIGNAL", signal), encoding="utf-8")
    return path


@pytest.mark.parametrize("encoded", [DOOR.encode("utf-8"), b"\xef\xbb\xbf" + DOOR.encode("utf-8"),
                                     DOOR.encode("cp1252")], ids=["utf-8", "utf-8 with BOM", "cp1252"])
def test_a_dbc_in_utf8_or_cp1252_gives_its_value_table_names_and_units_as_written(tmp_path, encoded):
    # cantools reads a DBC as cp1252: UTF-8's ö was Ã¶, so no scenario could name Geöffnet, and a
    # byte-order mark was text before VERSION that it refused ("Invalid syntax at line 1")
    sc = scenario.load(door_scenario(tmp_path, encoded))
    door = dbc.load_dbc(tmp_path / "door.dbc").get_message_by_name("Door")
    assert door.get_signal_by_name("Temp").unit == "°C"
    frame = next(f for _, f in plans.schedule(sc.ecus[0], sc).frames())
    assert door.decode(frame.data)["DoorState"] == "Geöffnet"


@pytest.mark.parametrize("csv", [b"0,Geschlossen\n0.5,Ge\xf6ffnet\n",  # Excel's CSV on a Western Windows: cp1252
                                 b"\xef\xbb\xbf0,Geschlossen\n0.5,Ge\xc3\xb6ffnet\n"],
                         ids=["cp1252", "utf-8 with BOM"])
def test_a_signal_trace_saved_by_a_spreadsheet_is_read_whole(tmp_path, csv):
    # cp1252 was a UnicodeDecodeError traceback from canbench validate; a UTF-8 byte-order mark made
    # the first line a header (float('\ufeff0') fails), so its value was silently dropped
    (tmp_path / "door.csv").write_bytes(csv)
    sc = scenario.load(door_scenario(tmp_path, DOOR.encode(), "{trace: door.csv}"))
    trace = sc.ecus[0].restbus[0].sources["DoorState"]
    assert list(trace.times) == [0.0, 0.5] and trace.values == ("Geschlossen", "Geöffnet")


@pytest.mark.parametrize(("line", "said"), [
    ('BO_ 103596083 BSM_LEFT: 8 BODY\n SG_ X : 0|8@1+ (1,0) [0|255] "" GW\n',
     "door.dbc:12: DBC: \"Standard frame id 0x62cc033 is more than 11 bits in message BSM_LEFT.\" (a DBC writes "
     "a 29-bit id with 0x80000000 added: BO_ 2251079731 for 062CC033)"),  # opendbc's chrysler_cusw.dbc
    ('VAL_ 256 NoSuchSignal 0 "Off" 1 "On" ;\n',
     "door.dbc:12: DBC: \"unused VAL_ entries in DBC: VAL_ 256 NoSuchSignal\" (a value table for a signal its "
     "message lacks: correct the signal's name, or delete the VAL_)"),  # opendbc's tesla_can.dbc
])
def test_a_dbc_cantools_refuses_is_placed_at_its_line(tmp_path, capsys, line, said):
    (tmp_path / "door.dbc").write_text(DOOR + line, encoding="utf-8")
    (tmp_path / "t.log").write_text(f"({T0 / 1e9:.6f}) vcan0 100#0000000000000000\n")
    assert cli.main(["summarise", str(tmp_path / "t.log"), "--dbc", str(tmp_path / "door.dbc")]) == 2
    assert capsys.readouterr().err.strip().endswith(said)
    with pytest.raises(InputError, match=r"door\.yaml:3: dbc: cannot load door\.dbc as a DBC \(cantools\): .*"
                                         r"door\.dbc:12: DBC"):
        scenario.load(door_scenario(tmp_path, (DOOR + line).encode()))


def float_frame(message, value: float) -> wire.Frame:
    data = bytearray(message.encode({s.name: 0 for s in message.signals}))
    data[4:8] = struct.pack("<f", value)  # Chassis.YawRate: a 32-bit float at byte 4
    return wire.Frame(message.frame_id, 8, bytes(data), message.is_extended_frame)


def test_a_nan_does_not_hide_a_float_signals_extremes_nor_make_metrics_json_invalid(tmp_path):
    gates = gates_of(tmp_path, "    Chassis.YawRate: {range: [-100, 100]}\n")
    chassis = dbc.load_dbc(SIGNALS_DBC).get_message_by_name("Chassis")
    run = run_of(gates, [(0, float_frame(chassis, math_nan())), (10, float_frame(chassis, 5.0)),
                         (20, float_frame(chassis, -7.0))])
    [problem] = checks.signals_can(run)
    assert "YawRate = nan deg/s outside [-100, 100]" in problem  # judged: no range holds NaN
    summary = signals.evaluate(run).summary()["can"]["vcan0"]["Chassis.YawRate"]
    assert (summary["count"], summary["min"], summary["max"]) == (3, -7.0, 5.0)  # were nan, nan
    json.loads(json.dumps(summary), parse_constant=lambda c: pytest.fail(f"{c} in metrics.json"))


def math_nan() -> float:
    return float("nan")


def test_a_trace_with_nan_still_scaffolds_and_says_why_its_signal_is_not_gated(tmp_path, capsys):
    # one NaN of a float signal made its min, max and mean nan and the scaffold range [.nan, .nan],
    # which the scenario refuses: "not written: the scaffold does not validate"
    chassis = dbc.load_dbc(SIGNALS_DBC).get_message_by_name("Chassis")
    with open(tmp_path / "drive.log", "w") as f:
        for i, v in enumerate([math_nan(), 5.0, -7.0, 1.5]):
            t = T0 + i * 100_000_000
            f.write(f"({t // 10**9}.{t % 10**9 // 1000:06d}) {float_frame(chassis, v).candump('vcan0')}\n")
    assert cli.main(["summarise", str(tmp_path / "drive.log"), "--dbc", str(SIGNALS_DBC)]) == 0
    assert any(line.split()[:4] == ["YawRate", "4", "-7", "5"] and line.endswith("(1 NaN or infinite)")
               for line in capsys.readouterr().out.splitlines())
    out = tmp_path / "drive.yaml"
    assert cli.main(["scaffold", str(tmp_path / "drive.log"), "--name", "drive", "--out", str(out),
                     "--dbc", str(SIGNALS_DBC)]) == 0
    assert "    # Chassis.YawRate: {range: [-8.2, 6.2]}  # review: seen -7..5 deg/s in 4 values; not gated: 1 NaN " \
           "or infinite, which no range passes" in out.read_text()
    scenario.load(out)


NEGATIVE = """VERSION ""
NS_ :
BS_:
BU_: PCM1 APP
BO_ 496 ExampleMessage: 2 PCM1
 SG_ Temperature : 3|12@0+ (-0.01,4100) [4070|4100] "degK" APP
BO_ 512 Cmd: 8 APP
 SG_ Page M : 0|8@1+ (1,0) [0|255] "" PCM1
 SG_ Speed m0 : 8|8@1+ (1,0) [0|255] "" PCM1
 SG_ Mode m1 : 8|8@1+ (1,0) [0|255] "" PCM1
"""


def rule_of(tmp_path: Path, when: dict, then: dict) -> responses.Rule:
    (tmp_path / "n.dbc").write_text(NEGATIVE)
    doc = {"buses": [{"name": "vcan0"}], "commands": [{"bus": "vcan0", "message": "Cmd", "run_s": 1}],
           "expect": {"responses": [{"name": "r", "when": when, "then": then, "within_ms": 20}]}}
    problems: list[str] = []
    [rule] = responses.rules(doc, {"vcan0": tmp_path / "n.dbc"}, dbc.load_dbc, lambda w, m: problems.append(m))
    assert problems == []
    return rule


def test_a_negative_scale_still_meets_an_exact_equals(tmp_path):
    # cantools' issue_636_negative_scaling.dbc: the default tolerance was scale / 2 = -0.005, which
    # no difference is at most, so even the exact value never met `equals`
    rule = rule_of(tmp_path, {"command": "Cmd"}, {"signal": "ExampleMessage.Temperature", "equals": 4090})
    message = dbc.load_dbc(tmp_path / "n.dbc").get_message_by_name("ExampleMessage")
    value = message.decode(message.encode({"Temperature": 4090}))["Temperature"]
    assert rule.then.tolerance == pytest.approx(0.005) and rule.then.met(value)


def test_a_command_condition_on_one_page_is_not_met_by_the_other_pages(tmp_path):
    # a command sending its pages in turn: a put of page 1 has no Speed, which was a KeyError
    # traceback in the analysis
    rule = rule_of(tmp_path, {"command": "Cmd", "signals": {"Speed": 5}}, {"signal": "ExampleMessage.Temperature",
                                                                          "range": [4070, 4100]})
    cmd = dbc.load_dbc(tmp_path / "n.dbc").get_message_by_name("Cmd")
    pages = [{"Page": 0, "Speed": 5}, {"Page": 1, "Mode": 5}]
    puts = [oracle.Observed(wire.Frame(0x200, 8, cmd.encode(page)), (i + 1) * 10**6, i, line=i + 2,
                            origin="commands.tsv") for i, page in enumerate(pages)]
    assert [o.line for o in responses.stimuli(rule, puts, [])] == [2]


def test_a_multiplexer_without_pages_starts_at_its_named_start_value(tmp_path):
    # GenSigStartValue 1, named Locked by its value table: cantools' `initial` is the name, and
    # int() of it was a TypeError traceback from canbench validate
    (tmp_path / "lock.dbc").write_text("""VERSION ""
NS_ :
BS_:
BU_: BODY GW
BO_ 256 Door: 8 BODY
 SG_ Lock M : 0|2@1+ (1,0) [0|3] "" GW
 SG_ Temp : 16|8@1+ (0.5,-40) [0|0] "" GW
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ SG_ "GenSigStartValue" INT 0 100000;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_DEF_DEF_ "GenSigStartValue" 0;
BA_ "GenMsgCycleTime" BO_ 256 100;
BA_ "GenSigStartValue" SG_ 256 Lock 1;
BA_ "GenSigStartValue" SG_ 256 Temp 120;
VAL_ 256 Lock 0 "Unlocked" 1 "Locked" ;
""")
    path = tmp_path / "lock.yaml"
    path.write_text("name: lock\nduration_s: 5\ndbc: lock.dbc\nbuses: [{name: vcan0}]\nexpect: {integrity: true}\n"
                    "ecus:\n  - {name: body, bus: vcan0, role: restbus, dbc_node: BODY, run_s: 1}\n")
    sc = scenario.load(path)
    frame = next(f for _, f in plans.schedule(sc.ecus[0], sc).frames())
    assert bytes(frame.data[:3]) == bytes([1, 0, 120])  # Locked; raw 120 = 20 at 0.5, -40
    assert restbus.default_value(sc.ecus[0].restbus[0].message.get_signal_by_name("Lock")) == 1


def two_buses(tmp_path: Path, layouts: tuple[str, str], expectation: str) -> Path:
    """A scenario of two buses, vcan0 with a.dbc and vcan1 with b.dbc, each DBC's Speed.VehSpeed laid
    out as given ('start|length@order+ (scale,offset)'), and one expectation of that signal."""
    for name, layout in zip(("a", "b"), layouts, strict=True):
        (tmp_path / f"{name}.dbc").write_text(f'VERSION ""\nNS_ :\nBS_:\nBU_: ECU\nBO_ 256 Speed: 8 ECU\n'
                                              f' SG_ VehSpeed : {layout} [0|0] "km/h" Vector__XXX\n')
    (tmp_path / "t.log").write_text(f"({T0 / 1e9:.6f}) vcan0 100#0000000000000000\n")
    path = tmp_path / "two.yaml"
    path.write_text("name: two\nduration_s: 10\nbuses:\n  - {name: vcan0, dbc: a.dbc}\n  - {name: vcan1, dbc: b.dbc}\n"
                    "ecus:\n  - {name: e, bus: vcan0, trace: t.log}\n"
                    f"expect:\n  signals:\n    Speed.VehSpeed: {expectation}\n")
    return path


def test_one_signal_name_scaled_differently_by_two_buses_is_judged_by_each_buses_dbc(tmp_path):
    # a gateway's bus carries VehSpeed at 0.1 km/h, the powertrain's at 0.01: equals was judged on
    # the first DBC's raw value, so vcan1's exact 50 km/h failed as "= 50 km/h, expected 50 km/h"
    sc = scenario.load(two_buses(tmp_path, ("0|16@1+ (0.01,0)", "0|16@1+ (0.1,0)"), "{equals: 50, one_of: [50]}"))

    def bus(name: str, speed: float) -> SimpleNamespace:
        m = dbc.load_dbc(tmp_path / f"{'a' if name == 'vcan0' else 'b'}.dbc").get_message_by_name("Speed")
        sent = [oracle.Observed(wire.Frame(m.frame_id, 8, m.encode({"VehSpeed": speed})), T0, 0, line=1)]
        got = [oracle.Observed(sent[0].frame, T0 + 1000, 0, key="vehicle/can/rx", seq=0)]
        return SimpleNamespace(bus=name, bus_frames=sent, can_frames=sent, zenoh_frames=got,
                               comparison=SimpleNamespace(matched=[(sent[0], got[0])], corrupted=[]))
    ok = SimpleNamespace(scenario=sc, buses=[bus("vcan0", 50), bus("vcan1", 50)], metrics={})
    assert checks.signals_can(ok) == [] and checks.signals_zenoh(ok) == []
    bad = SimpleNamespace(scenario=sc, buses=[bus("vcan0", 50), bus("vcan1", 50.1)], metrics={})
    [problem] = checks.signals_can(bad)
    assert problem.startswith("vcan1 Speed.VehSpeed: 2 violations: Speed.VehSpeed = 50.1 km/h, expected 50 km/h")


def test_a_value_one_buses_dbc_cannot_carry_is_said_for_that_bus(tmp_path):
    path = two_buses(tmp_path, ("0|16@1+ (1,0)", "0|8@1+ (1,0)"), "{equals: 300}")
    with pytest.raises(InputError, match=r"two\.yaml:10: expect\.signals\.Speed\.VehSpeed\.equals: 300 is outside "
                                         r"VehSpeed's range \[0, 255\] km/h .*\(the DBC of vcan1\)$"):
        scenario.load(path)


E2E = DOOR.replace(' SG_ Temp : 8|8@1+ (1,-40) [-40|215] "°C" GW\n',
                   ' SG_ Temp : 8|8@1+ (1,-40) [-40|215] "°C" GW\n SG_ Alive : 16|4@1+ (1,0) [1|14] "" GW\n')


def test_a_counter_counts_within_its_dbc_range(tmp_path):
    # AUTOSAR E2E and many OEM counters keep 0 (and 15) for "not valid": counting 0..15 sent
    # invalid frames on a bus whose receivers check the counter
    (tmp_path / "door.dbc").write_text(E2E, encoding="utf-8")
    path = tmp_path / "door.yaml"
    path.write_text(RESTBUS.replace("SIGNAL", "Geöffnet").replace("run_s: 1", "run_s: 2").replace(
        "    signals:", "    counters: [Door.Alive]\n    signals:"), encoding="utf-8")
    sc = scenario.load(path)
    door = dbc.load_dbc(tmp_path / "door.dbc").get_message_by_name("Door")
    counts = [door.decode(f.data)["Alive"] for _, f in plans.schedule(sc.ecus[0], sc).frames()][:16]
    assert counts == [*range(1, 15), 1, 2]


def test_a_counter_whose_dbc_range_its_bits_cannot_hold_is_a_problem_at_its_line(tmp_path):
    (tmp_path / "door.dbc").write_text(E2E.replace("[1|14]", "[16|30]"), encoding="utf-8")
    path = tmp_path / "door.yaml"
    path.write_text(RESTBUS.replace("SIGNAL", "Geöffnet").replace("    signals:", "    counters: [Door.Alive]\n"
                                                                   "    signals:"), encoding="utf-8")
    with pytest.raises(InputError) as e:
        scenario.load(path)
    assert f"{path}:11:" in str(e.value) and "Door.Alive: its DBC range [16|30] holds no value" in str(e.value)


def test_a_dbc_that_defines_its_send_type_as_a_number_is_read_and_its_cycle_decides(tmp_path):
    # some tools write GenMsgSendType as INT (Vector's own DBCs: an ENUM); cantools refused the
    # whole file with "Expected str, got int: 1" and no line
    text = DOOR + 'BA_DEF_ BO_ "GenMsgSendType" INT 0 10;\nBA_DEF_DEF_ "GenMsgSendType" 0;\n' \
                  'BA_ "GenMsgSendType" BO_ 256 1;\n'
    (tmp_path / "door.dbc").write_text(text, encoding="utf-8")
    door = dbc.load_dbc(tmp_path / "door.dbc").get_message_by_name("Door")
    assert dbc.cycle_time_ms(door) == 100.0 and door.decode(bytes([1, 60, 0, 0, 0, 0, 0, 0]))["Temp"] == 20
    (tmp_path / "other.dbc").write_text(text.replace("BA_ \"GenMsgSendType\" BO_ 256 1;", "BA_ \"Nope\" BO_ 256 1;"),
                                        encoding="utf-8")
    with pytest.raises(Exception, match="Nope"):  # any other refusal is still cantools'
        dbc.load_dbc(tmp_path / "other.dbc")
