"""Restbus ECUs, commands in signals and the responder, on the shipped powertrain DBC: cycles
from GenMsgCycleTime, GenSigStartValue, overrides (constants, ramps, CSV signal traces),
counters and checksums with known answers, plans made lazily, and every bad name or value a
file:line problem (exit 2 from canbench validate)."""
from __future__ import annotations

import textwrap
import tracemalloc
from pathlib import Path
from types import SimpleNamespace

import cantools
import pytest

from canbench import checks, commands, oracle, plans, restbus, scenario, validate
from canbench.errors import ScenarioError
from canbench.wire import Frame

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "scenarios" / "dbc" / "powertrain.dbc"
DB = cantools.database.load_file(str(DBC))

# CRC-8 SAE J1850 check values (AUTOSAR SWS CRC Library, 8-bit SAE J1850) and the catalogue's "123456789"
J1850 = [("00000000", 0x59), ("F20183", 0x37), ("0FAA0055", 0x79), ("00FF5511", 0xB8),
         ("332255AABBCCDDEEFF", 0xCB), ("926B55", 0x8C), ("FFFFFFFF", 0x74), ("313233343536373839", 0x4B)]


def crc8_j1850_bitwise(data: bytes) -> int:
    """The reference: poly 0x1D, init 0xFF, not reflected, final XOR 0xFF, bit by bit."""
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


@pytest.mark.parametrize("data,crc", J1850)
def test_crc8_sae_j1850_known_answers(data, crc):
    assert restbus.crc8_sae_j1850(bytes.fromhex(data)) == crc == crc8_j1850_bitwise(bytes.fromhex(data))


def test_xor_known_answers():
    assert restbus.xor8(b"") == 0
    assert restbus.xor8(bytes([0x01, 0x02, 0x04, 0x80])) == 0x87
    assert restbus.xor8(bytes([0x5A, 0x5A])) == 0


def write(tmp_path: Path, body: str, name: str = "s.yaml") -> Path:
    (tmp_path / "dbc").mkdir(exist_ok=True)
    (tmp_path / "dbc" / "powertrain.dbc").write_text(DBC.read_text())
    path = tmp_path / name
    path.write_text(textwrap.dedent(body))
    return path


HEAD = """\
name: t
duration_s: 10
dbc: dbc/powertrain.dbc
buses: [{name: vcan0}]
expect: {integrity: true}
"""


def body_ecu(extra: str = "") -> str:
    return HEAD + textwrap.dedent("""\
    ecus:
      - name: body
        bus: vcan0
        role: restbus
        dbc_node: BODY
        run_s: 1
    """) + textwrap.indent(textwrap.dedent(extra), "    ")


def decoded(frames, name: str) -> list[dict]:
    m = DB.get_message_by_name(name)
    return [m.decode(f.data, decode_choices=False) for f in frames if f.arbitration_id == m.frame_id]


def test_restbus_sends_the_nodes_messages_at_their_dbc_cycles_with_start_values(tmp_path):
    sc = scenario.load(write(tmp_path, body_ecu()))
    ecu = sc.ecus[0]
    plan = plans.schedule(ecu, sc)
    frames = [m for _, m in plan.frames()]
    status = [f for f in frames if f.arbitration_id == 0x320]
    wheels = [f for f in frames if f.arbitration_id == 0x321]
    # GenMsgCycleTime: BodyStatus 50 ms, WheelSpeeds 20 ms; nothing of another node
    assert (len(status), len(wheels), plan.count) == (20, 50, 70) and len(frames) == 70
    assert [round(f.timestamp, 6) for f in status[:3]] == [0.0, 0.05, 0.1]
    assert [round(f.timestamp, 6) for f in wheels[:3]] == [0.0, 0.02, 0.04]
    assert [(f.timestamp, f.arbitration_id) for f in frames] == sorted((f.timestamp, f.arbitration_id) for f in frames)
    # GenSigStartValue: AmbientTemp raw 120 (20 degC), DoorsLocked 1 (Locked); no start value: raw 0
    first = decoded(status, "BodyStatus")[0]
    assert (first["AmbientTemp"], first["DoorsLocked"], first["BodyChecksum"]) == (20.0, 1, 0)  # none named
    assert bytes(status[0].data) == bytes([0x10, 0x78, 0, 0, 0, 0, 0, 0]) and all(f.dlc == 8 for f in frames)
    assert plan.last.timestamp == max(f.timestamp for f in frames)


def test_overrides_constants_ramps_csv_counters_and_checksums(tmp_path):
    (tmp_path / "fr.csv").write_text("time_s,value\n# a comment\n0,5\n0.5,40.25\n")
    sc = scenario.load(write(tmp_path, body_ecu("""\
        signals:
          BodyStatus.DoorsLocked: Unlocked
          BodyStatus.AmbientTemp: -10.5
          WheelSpeeds.WheelSpeedFL: {ramp: [0, 100], over_s: 0.5}
          WheelSpeeds.WheelSpeedFR: {trace: fr.csv}
        counters: [BodyStatus.BodyCounter, WheelSpeeds.WheelCounter]
        checksums: {BodyStatus.BodyChecksum: xor, WheelSpeeds.WheelCrc: crc8_sae_j1850}
    """)))
    frames = [m for _, m in plans.schedule(sc.ecus[0], sc).frames()]
    status, wheels = decoded(frames, "BodyStatus"), decoded(frames, "WheelSpeeds")
    assert {s["DoorsLocked"] for s in status} == {0} and {s["AmbientTemp"] for s in status} == {-10.5}
    assert [w["WheelSpeedFL"] for w in wheels[:3]] == [0.0, 4.0, 8.0] and wheels[-1]["WheelSpeedFL"] == 100.0
    assert wheels[24]["WheelSpeedFR"] == 5.0 and wheels[25]["WheelSpeedFR"] == 40.25  # held from 0.5 s on
    assert [w["WheelCounter"] for w in wheels[:18]] == [*range(16), 0, 1]  # 4 bits: wraps after 15
    assert [s["BodyCounter"] for s in status[:3]] == [0, 1, 2]
    for f in frames:
        data = bytes(f.data)
        if f.arbitration_id == 0x320:
            assert data[7] == restbus.xor8(data[:7])
        else:
            assert data[7] == crc8_j1850_bitwise(data[:7])
    # a known answer: the second WheelSpeeds frame, FL 4 km/h (raw 400), FR 5 (raw 500), counter 1
    assert bytes(frames[[f.arbitration_id for f in frames].index(0x321, 2)].data)[:7] == \
        bytes([0x90, 0x01, 0xF4, 0x01, 0x01, 0, 0])


def test_a_cycle_override_makes_a_restbus_that_fails_the_dbc_cycle_check(tmp_path):
    """A restbus ECU with a wrong cycle (BodyStatus every 80 ms, the DBC says 50) fails
    cycle_time {from_dbc: true} on exactly that message; at the DBC's cycles it passes."""
    if "from_dbc" not in (scenario.schema()["properties"]["expect"]["properties"]["cycle_time"]["properties"]):
        pytest.skip("cycle_time.from_dbc not in this tree")
    outcomes = {}
    for label, extra in (("dbc", ""), ("wrong", "cycle_ms: {BodyStatus: 80}\n")):
        path = write(tmp_path, body_ecu(extra).replace("expect: {integrity: true}",
                                                       "expect: {cycle_time: {from_dbc: true, tolerance_pct: 20}}"),
                     f"{label}.yaml")
        sc = scenario.load(path)
        sent = [oracle.Observed(Frame(m.arbitration_id, m.dlc, bytes(m.data)), int(m.timestamp * 1e9), i, line=i + 1)
                for i, (_, m) in enumerate(plans.schedule(sc.ecus[0], sc).frames())]
        cycles = {ident: {"can": stats, "zenoh": stats} for ident, stats in oracle.cycle_times(sent).items()}
        result = SimpleNamespace(scenario=sc, buses=[SimpleNamespace(bus="vcan0", cycle_times=cycles)])
        outcomes[label] = checks.cycle_time(result)
    assert outcomes["dbc"] == []
    assert outcomes["wrong"] and all("id 320" in p for p in outcomes["wrong"])  # BodyStatus only
    assert any("id 320 (BodyStatus): median cycle 80.00 ms on the bus, the DBC says 50.00 ms" in p
               for p in outcomes["wrong"])


def test_an_hour_of_a_restbus_node_is_not_held_in_memory(tmp_path):
    sc = scenario.load(write(tmp_path, body_ecu().replace("run_s: 1", "run_s: 3600")))
    plan = plans.schedule(sc.ecus[0], sc)
    assert plan.count == 3600 * (20 + 50)
    tracemalloc.start()
    frames = plan.frames()
    for _ in range(20_000):
        next(frames)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 5 << 20  # 252 000 encoded frames held would be ~90 MiB


def test_commands_in_signals_are_encoded_with_cantools(tmp_path):
    sc = scenario.load(write(tmp_path, HEAD + textwrap.dedent("""\
    ecus: [{name: engine, bus: vcan0, role: restbus, dbc_node: GEARBOX, run_s: 1}]
    commands:
      - bus: vcan0
        message: TorqueRequest
        counters: [RequestCounter]
        checksums: {RequestChecksum: xor}
        schedule:
          - {at_s: 0.2, signals: {TorqueRequested: 50}}
          - {at_s: 0.1, signals: {TorqueRequested: -20.5}}
          - {at_s: 0.3}
      - bus: vcan0
        message: TorqueRequest
        signals: {TorqueRequested: 7}
        run_s: 0.5
        start_offset_s: 1
    """)))
    planned = commands.plan(sc)
    m = DB.get_message_by_name("TorqueRequest")
    values = [(round(t, 6), m.decode(f.data)["TorqueRequested"], m.decode(f.data)["RequestCounter"])
              for t, _, _, f in planned]
    # the schedule in time order, each entry's values held for the next; then every 100 ms (GenMsgCycleTime)
    assert values[:3] == [(0.1, -20.5, 0), (0.2, 50.0, 1), (0.3, 50.0, 2)]
    assert values[3:] == [(1.0 + i / 10, 7.0, 0) for i in range(5)]  # no counter named: raw 0
    assert all(f.can_id == 0x100 and f.dlc == 8 for _, _, _, f in planned)
    assert all(f.data[7] == restbus.xor8(f.data[:7]) for _, _, _, f in planned[:3])  # the first has a checksum
    assert {f.data[7] for _, _, _, f in planned[3:]} == {0}
    assert planned[0][3].data[:3] == bytes([0x00, 0x33, 0xFF])  # -205 raw, little endian, signed


def test_the_responder_copies_the_request_signal_into_its_answer(tmp_path):
    sc = scenario.load(write(tmp_path, HEAD + textwrap.dedent("""\
    ecus:
      - name: sim
        bus: vcan0
        role: responder
        rules:
          - request: TorqueRequest
            send: TorqueResponse
            set: {TorqueActual: {from: TorqueRequested, scale: 0.5, offset: 1}}
            counters: [ResponseCounter]
            checksums: {ResponseCrc: crc8_sae_j1850}
    """)))
    rule = sc.ecus[0].rules[0]
    request = DB.get_message_by_name("TorqueRequest").encode({"RequestCounter": 3, "TorqueRequested": -40,
                                                              "RequestChecksum": 0})
    message, data = rule.answer(request, 17)
    answer = DB.get_message_by_name("TorqueResponse").decode(data)
    assert message.frame_id == 0x101
    assert (answer["TorqueActual"], answer["ResponseCounter"]) == (-19.0, 1)  # -40 * 0.5 + 1; 17 mod 16
    assert data[7] == crc8_j1850_bitwise(data[:7])
    assert sc.echoes == sc.ecus  # answers until stopped, like an echo ECU


BAD = [
    (body_ecu().replace("BODY", "BRAKES"), "ecus.0.dbc_node: the DBC has no node 'BRAKES'"),
    (body_ecu("signals: {BodyStatus.Doors: 1}\n"), "ecus.0.signals.BodyStatus.Doors: BodyStatus has no signal 'Doors'"),
    (body_ecu("signals: {EngineData.EngineSpeed: 1}\n"), "BODY does not transmit 'EngineData'"),
    (body_ecu("signals: {BodyStatus.DoorsLocked: Open}\n"),
     "'Open' is not in DoorsLocked's value table ['Unlocked', 'Locked']"),
    (body_ecu("signals: {BodyStatus.AmbientTemp: 200}\n"), "200 is outside AmbientTemp's range [-40, 87.5] degC"),
    (body_ecu("checksums: {WheelSpeeds.WheelCounter: xor}\n"), "fills exactly one byte"),
    (body_ecu("counters: [BodyStatus.AmbientTemp]\n"), "a counter is an unsigned integer signal"),
    (HEAD + "ecus: [{name: e, bus: vcan0, trace: t.log}]\ncommands:\n  - bus: vcan0\n    message: TorqueRequests\n"
     "    run_s: 1\n", "commands.0.message: the DBC has no message 'TorqueRequests'"),
    (HEAD + "ecus: [{name: e, bus: vcan0, trace: t.log}]\ncommands:\n  - bus: vcan0\n    message: TorqueRequest\n"
     "    schedule: [{at_s: 1, signals: {Torque: 5}}]\n", "TorqueRequest has no signal 'Torque'"),
]


@pytest.mark.parametrize("text,expected", BAD, ids=[e.split(":")[0] for _, e in BAD])
def test_unknown_names_and_bad_values_are_problems_at_their_line(tmp_path, capsys, text, expected):
    (tmp_path / "t.log").write_text("(0.0) vcan0 123#00\n")
    path = write(tmp_path, text)
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    assert expected in str(e.value)
    line = next(i for i, raw in enumerate(path.read_text().splitlines(), 1)
                if any(w in raw for w in ("BRAKES", "Doors", "EngineData", "Open", "200", "WheelCounter",
                                          "counters", "TorqueRequests", "Torque:")))
    assert f"{path}:{line}:" in str(e.value)
    assert validate.run([path]) == 2 and expected in capsys.readouterr().err


def test_a_bad_signal_trace_line_is_named_by_its_file_and_line(tmp_path):
    (tmp_path / "fr.csv").write_text("time_s,value\n0,5\nfast,6\n0.5,700\n0.2,1\n1,2,3\n")
    path = write(tmp_path, body_ecu("signals: {WheelSpeeds.WheelSpeedFR: {trace: fr.csv}}\n"))
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    text = str(e.value)
    csv = tmp_path / "fr.csv"
    assert f"{csv}:3: time_s 'fast' is not a number" in text
    assert f"{csv}:4: 700 is outside WheelSpeedFR's range [0, 655.35] km/h" in text
    assert f"{csv}:5: time_s 0.2 is before the line above's 0" not in text  # 0.5 was refused: 0 is the last
    assert f"{csv}:6: a line is time_s,value (3 fields)" in text


def test_the_shipped_signals_scenario_validates():
    sc = scenario.load(REPO / "scenarios" / "signals.yaml")
    roles = {e.role for e in sc.ecus}
    assert {"replay", "restbus", "responder"} <= roles and any(c.signal_plan for c in sc.commands)
    assert sc.expect["responses"]


def test_multiplexed_extended_and_event_messages_as_cantools_has_them(tmp_path):
    """On the signals test DBC: Diag's page follows a signal trace and each page carries its own
    signals; the BODY node's 29-bit Chassis is sent, its event message DoorEvent is not."""
    (tmp_path / "dbc").mkdir()
    (tmp_path / "dbc" / "powertrain.dbc").write_text((REPO / "tests" / "data" / "dbc" / "signals.dbc").read_text())
    (tmp_path / "page.csv").write_text("0,0\n0.5,1\n")
    path = tmp_path / "s.yaml"
    path.write_text(HEAD + textwrap.dedent("""\
    ecus:
      - {name: engine, bus: vcan0, role: restbus, dbc_node: ENGINE, run_s: 1,
         signals: {Diag.Page: {trace: page.csv}, Diag.CoolantTemp: 90, Diag.OilPressure: 300}}
      - {name: body, bus: vcan0, role: restbus, dbc_node: BODY, run_s: 1,
         signals: {Chassis.LongAccel: {ramp: [-2, 2], over_s: 1}}}
    """))
    sc = scenario.load(path)
    db = cantools.database.load_file(str(tmp_path / "dbc" / "powertrain.dbc"))
    diag = [db.get_message_by_name("Diag").decode(m.data) for _, m in plans.schedule(sc.ecus[0], sc).frames()
            if m.arbitration_id == 0x400]
    assert [(d["Page"], d.get("CoolantTemp"), d.get("OilPressure")) for d in diag] == \
        [(0, 90, None)] * 3 + [(1, None, 300.0)] * 2  # every 200 ms; page 1 from 0.5 s on
    body = [m for _, m in plans.schedule(sc.ecus[1], sc).frames()]
    assert {(m.arbitration_id, m.is_extended_id) for m in body} == {(0x18FEF100, True)}  # no DoorEvent
    chassis = db.get_message_by_name("Chassis")
    assert [chassis.decode(m.data)["LongAccel"] for m in body[:3]] == [-2.0, -1.6, -1.2]  # every 100 ms
