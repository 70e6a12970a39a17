"""Numbers YAML reads as text in the values of restbus ECUs, commands in signals, responders,
expect.responses and expect.signals ('12' quoted, 1e3, 0o17): each is a problem at its line
naming the signal, saying it is text and how to write the number, never taken for a value-table
name the signal lacks; numbers YAML 1.1 and YAML 1.2 read differently (010, 1:30) are refused
where they stand; 1_000 and 0x10, numbers to YAML 1.1, are taken as numbers."""
from __future__ import annotations

import textwrap
from pathlib import Path
from types import SimpleNamespace

import cantools
import pytest

from canbench import dbc, plans, scenario, validate
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

REPO = Path(__file__).resolve().parents[2]
DBC = REPO / "scenarios" / "dbc" / "powertrain.dbc"

HEAD = """\
name: t
duration_s: 10
dbc: powertrain.dbc
buses: [{name: vcan0}]
"""

SCENARIO = HEAD + """\
ecus:
  - name: body
    bus: vcan0
    role: restbus
    dbc_node: BODY
    run_s: 1
    signals:
      BodyStatus.AmbientTemp: "12"
      WheelSpeeds.WheelSpeedFL: 1e3
      WheelSpeeds.WheelSpeedFR: {ramp: ["0", 10], over_s: 1}
  - name: sim
    bus: vcan0
    role: responder
    rules:
      - {request: TorqueRequest, send: TorqueResponse, set: {TorqueActual: '0o17'}}
commands:
  - bus: vcan0
    message: TorqueRequest
    schedule: [{at_s: 0.5, signals: {TorqueRequested: "50"}}]
expect:
  responses:
    - when: {command: TorqueRequest, signals: {TorqueRequested: "-20.5"}}
      then: {signal: TorqueResponse.TorqueActual, equals: "50", one_of: [1, "2"]}
      within_ms: 50
    - when: {signal: BodyStatus.DoorsLocked, equals: Unlocked}
      then: {signal: TorqueResponse.TorqueActual, range: ["0", 5]}
      within_ms: 50
  signals:
    BodyStatus.AmbientTemp: {equals: "20"}
"""


def problems(tmp_path: Path, text: str) -> list[str]:
    (tmp_path / "powertrain.dbc").write_text(DBC.read_text())
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return [str(p).removeprefix(f"{path}:") for p in validate.problems(path)]


def test_each_number_yaml_reads_as_text_is_a_problem_at_its_line(tmp_path):
    assert problems(tmp_path, SCENARIO) == [
        "12: ecus.0.signals.BodyStatus.AmbientTemp: YAML reads '12' as text, not a number for AmbientTemp: write 12",
        "13: ecus.0.signals.WheelSpeeds.WheelSpeedFL: YAML reads '1e3' as text, not a number for WheelSpeedFL: "
        "write 1.0e+3",
        "14: ecus.0.signals.WheelSpeeds.WheelSpeedFR: {'ramp': ['0', 10], 'over_s': 1} is not valid under any of "
        "the given schemas",
        "14: ecus.0.signals.WheelSpeeds.WheelSpeedFR.ramp.0: YAML reads '0' as text, not a number for WheelSpeedFR: "
        "write 0",
        "19: ecus.1.rules.0.set.TorqueActual: YAML reads '0o17' as text, not a number for TorqueActual: write 15",
        "23: commands.0.schedule.0.signals.TorqueRequested: YAML reads '50' as text, not a number for "
        "TorqueRequested: write 50",
        "26: expect.responses.0.when.signals.TorqueRequested: YAML reads '-20.5' as text, not a number for "
        "TorqueRequested: write -20.5",
        "27: expect.responses.0.then.equals: YAML reads '50' as text, not a number for TorqueActual: write 50",
        "27: expect.responses.0.then.one_of.1: YAML reads '2' as text, not a number for TorqueActual: write 2",
        "30: expect.responses.1.then.range.0: '0' is not of type 'number' (YAML reads '0' as text: write 0)",
        "33: expect.signals.BodyStatus.AmbientTemp.equals: YAML reads '20' as text, not a number for "
        "BodyStatus.AmbientTemp: write 20",
    ]


@pytest.mark.parametrize("value,said", [
    ("010", "010 is 8 to YAML 1.1 (a leading 0 is octal), 10 to YAML 1.2: write 10 or 8"),
    ("1:30", "1:30 is 90 to YAML 1.1 (base 60), text to YAML 1.2: write 90, or quote it"),
])
def test_a_number_yaml_versions_read_differently_is_refused_at_its_line(tmp_path, value, said):
    text = HEAD + f"ecus: [{{name: body, bus: vcan0, role: restbus, dbc_node: BODY, run_s: 1,\n" \
                  f"        signals: {{BodyStatus.AmbientTemp: {value}}}}}]\n"
    assert problems(tmp_path, text) == [f"6: {said}"]


@pytest.mark.parametrize("where,text", [
    ("duration_s", "duration_s: .nan\nbuses: [{name: vcan0}]\n"),
    ("a gate", "duration_s: 10\nbuses: [{name: vcan0}]\nexpect:\n  latency: {can_to_zenoh: {p50_ms: .NaN}}\n"),
    ("a cycle", "duration_s: 10\nbuses: [{name: vcan0}]\nexpect:\n  cycle_time: {tolerance_pct: .NAN}\n"),
])
def test_nan_is_refused_at_its_line_wherever_it_stands(tmp_path, where, text):
    # NaN passes every minimum and maximum of the schema, and a gate of it fails nothing
    path = tmp_path / "s.yaml"
    path.write_text("name: t\n" + text)
    line = next(n for n, ln in enumerate(path.read_text().splitlines(), 1) if "nan" in ln.lower())
    with pytest.raises(ScenarioError) as err:
        scenario.load(path)
    assert str(err.value).startswith(f"{path}:{line}: ") and "is not a number (NaN)" in str(err.value), where


def test_underscores_and_hex_are_numbers_to_yaml_1_1(tmp_path):
    (tmp_path / "powertrain.dbc").write_text(DBC.read_text())
    path = tmp_path / "s.yaml"
    path.write_text(HEAD + textwrap.dedent("""\
    ecus:
      - {name: body, bus: vcan0, role: restbus, dbc_node: BODY, run_s: 1,
         signals: {WheelSpeeds.WheelSpeedFL: 0x10, WheelSpeeds.WheelSpeedFR: 1_00}}
    expect: {integrity: true}
    """))
    sc = scenario.load(path)
    m = cantools.database.load_file(str(DBC)).get_message_by_name("WheelSpeeds")
    first = next(m.decode(f.data) for _, f in plans.schedule(sc.ecus[0], sc).frames() if f.arbitration_id == 0x321)
    assert (first["WheelSpeedFL"], first["WheelSpeedFR"]) == (16, 100)


def test_a_value_table_name_that_looks_like_a_number_is_a_name():
    signal = SimpleNamespace(name="Mode", choices={0: "0", 1: "12"})
    assert dbc.name_problem(signal, "12") is None
    assert dbc.name_problem(signal, "13") == "YAML reads '13' as text, not a number for Mode: write 13"
    assert dbc.name_problem(signal, "Off") == "'Off' is not in Mode's value table ['0', '12']"


def test_a_signal_trace_is_csv_not_yaml(tmp_path):
    (tmp_path / "fl.csv").write_text("0,0x10\n")
    text = HEAD + "ecus: [{name: body, bus: vcan0, role: restbus, dbc_node: BODY, run_s: 1,\n" \
                  "        signals: {WheelSpeeds.WheelSpeedFL: {trace: fl.csv}}}]\nexpect: {integrity: true}\n"
    (tmp_path / "powertrain.dbc").write_text(DBC.read_text())
    (tmp_path / "s.yaml").write_text(text)
    with pytest.raises(ScenarioError) as e:
        scenario.load(tmp_path / "s.yaml")
    assert str(e.value) == f"{tmp_path / 'fl.csv'}:1: WheelSpeedFL has no value table: give a number"


ON_OFF = """\
VERSION ""

NS_ :

BS_:

BU_: GW

BO_ 768 Lamp: 8 GW
 SG_ Light : 0|1@1+ (1,0) [0|1] "" GW

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 768 100;

VAL_ 768 Light 0 "Off" 1 "On" ;
"""


def test_a_value_table_name_yaml_reads_as_a_boolean_says_so(tmp_path):
    (tmp_path / "lamp.dbc").write_text(ON_OFF)
    path = tmp_path / "s.yaml"
    path.write_text("name: s\nduration_s: 10\ndbc: lamp.dbc\nbuses: [{name: vcan0}]\n"
                    "ecus: [{name: e, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, signals: {Lamp.Light: On}}]\n"
                    "expect:\n  signals:\n    Lamp.Light: {equals: Off}\n")
    bools = " (YAML 1.1 reads yes, no, on and off as true and false: quote a name meant as text)"
    assert [str(p).removeprefix(f"{path}:") for p in validate.problems(path)] == [
        "5: ecus.0.signals.Lamp.Light: True is not valid under any of the given schemas" + bools,
        "5: ecus.0.signals.Lamp.Light: YAML reads On as true, not a name of Light's value table: write 'On'",
        "8: expect.signals.Lamp.Light.equals: False is not of type 'number', 'string'" + bools]
    path.write_text(path.read_text().replace("Light: On", "Light: 'On'").replace("equals: Off", "equals: 'Off'"))
    assert validate.problems(path) == []
