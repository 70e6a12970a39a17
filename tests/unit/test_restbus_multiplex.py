"""Multiplexed messages from signals, on a DBC written here (ids 3, 5 and 9 with a nested
multiplexer in page 9, none at the start value raw 0): a restbus ECU sends every page in turn, a
scenario's value pins one, and a value that is not a multiplexer id is a file:line problem."""
from __future__ import annotations

import textwrap
from pathlib import Path

import cantools
import pytest

from canbench import plans, restbus, scenario, validate
from canbench.errors import ScenarioError

pytestmark = pytest.mark.unit

DBC = """\
VERSION ""

NS_ :

BS_:

BU_: GW TESTER

BO_ 768 Pages: 8 GW
 SG_ Sel M : 0|8@1+ (1,0) [0|0] "" TESTER
 SG_ Speed m3 : 8|16@1+ (0.01,0) [0|655.35] "km/h" TESTER
 SG_ Temp m5 : 8|8@1- (1,-40) [-40|100] "degC" TESTER
 SG_ Sub m9M : 8|4@1+ (1,0) [0|0] "" TESTER
 SG_ Volt m1 : 16|8@1+ (0.1,0) [0|25.5] "V" TESTER
 SG_ Amp m2 : 16|8@1+ (1,0) [0|0] "A" TESTER
 SG_ Count : 48|4@1+ (1,0) [0|15] "" TESTER
 SG_ Crc : 56|8@1+ (1,0) [0|255] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 768 100;

SG_MUL_VAL_ 768 Speed Sel 3-3;
SG_MUL_VAL_ 768 Temp Sel 5-5;
SG_MUL_VAL_ 768 Sub Sel 9-9;
SG_MUL_VAL_ 768 Volt Sub 1-1;
SG_MUL_VAL_ 768 Amp Sub 2-2;
"""

HEAD = """\
name: mux
duration_s: 10
dbc: mux.dbc
buses: [{name: vcan0}]
expect: {integrity: true}
"""


def write(tmp_path: Path, body: str) -> Path:
    (tmp_path / "mux.dbc").write_text(DBC)
    path = tmp_path / "s.yaml"
    path.write_text(HEAD + textwrap.dedent(body))
    return path


def gateway(extra: str = "") -> str:
    return "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1" + extra + "}\n"


def pages_sent(tmp_path: Path, sc: scenario.Scenario) -> list[dict]:
    m = cantools.database.load_file(str(tmp_path / "mux.dbc")).get_message_by_name("Pages")
    frames = [f for _, f in plans.schedule(sc.ecus[0], sc).frames()]
    assert {f.arbitration_id for f in frames} == {0x300}
    return [m.decode(f.data, decode_choices=False) for f in frames]


def test_a_restbus_ecu_sends_every_page_in_turn(tmp_path):
    path = write(tmp_path, gateway(", signals: {Pages.Speed: 12.5, Pages.Volt: 3.2}, counters: [Pages.Count], "
                                   "checksums: {Pages.Crc: xor}"))
    assert validate.problems(path) == []  # was: Expected multiplexer id in {9, 3 or 5} ... but got 0
    sent = pages_sent(tmp_path, scenario.load(path))
    assert len(sent) == 10  # 100 ms for 1 s
    assert [(d["Sel"], d.get("Sub")) for d in sent[:5]] == [(3, None), (5, None), (9, 1), (9, 2), (3, None)]
    assert (sent[0]["Speed"], sent[1]["Temp"], sent[2]["Volt"], sent[3]["Amp"]) == (12.5, -40, 3.2, 0)
    assert [d["Count"] for d in sent] == list(range(10))  # the counter per frame, whatever the page
    assert all(bytes(f.data)[7] == restbus.xor8(bytes(f.data)[:7]) for _, f in plans.schedule(
        scenario.load(path).ecus[0], scenario.load(path)).frames())


def test_a_value_pins_a_page_and_a_nested_multiplexer_still_turns(tmp_path):
    sent = pages_sent(tmp_path, scenario.load(write(tmp_path, gateway(", signals: {Pages.Sel: 5}"))))
    assert {d["Sel"] for d in sent} == {5}
    sent = pages_sent(tmp_path, scenario.load(write(tmp_path, gateway(", signals: {Pages.Sel: 9}"))))
    assert [d["Sub"] for d in sent[:4]] == [1, 2, 1, 2]


def test_commands_in_signals_turn_their_pages_too(tmp_path):
    path = write(tmp_path, "ecus: [{name: e, bus: vcan0, role: echo, echo_ids: ['600']}]\n"
                           "commands: [{bus: vcan0, message: Pages, run_s: 0.3}]\n")
    assert validate.problems(path) == []
    sc = scenario.load(path)
    m = cantools.database.load_file(str(tmp_path / "mux.dbc")).get_message_by_name("Pages")
    assert [m.decode(f.data)["Sel"] for _, f in restbus.command_frames(sc.commands[0])] == [3, 5, 9]


@pytest.mark.parametrize("value,line,message", [
    ("signals: {Pages.Sel: 4}", 7, "ecus.0.signals.Pages.Sel: 4 is not one of Sel's multiplexer ids [3, 5, 9]"),
    ("signals: {Pages.Sub: 0}", 7, "ecus.0.signals.Pages.Sub: 0 is not one of Sub's multiplexer ids [1, 2]"),
    ("signals: {Pages.Sel: {ramp: [3, 9], over_s: 1}}", 7,
     "ecus.0.signals.Pages.Sel.ramp: Sel is a multiplexer (ids [3, 5, 9]): give an id, a signal trace of ids, "
     "or nothing (its pages in turn)"),
    ("counters: [Pages.Sel]", 7, "ecus.0.counters.0: Pages.Sel is a multiplexer: it selects pages, in turn "
     "when not set"),
])
def test_a_value_that_is_no_multiplexer_id_is_a_problem_at_its_line(tmp_path, value, line, message):
    path = write(tmp_path, gateway(", " + value))
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    assert str(e.value) == f"{path}:{line}: {message}"


def test_a_signal_trace_of_a_multiplexer_is_checked_line_by_line(tmp_path):
    (tmp_path / "sel.csv").write_text("time_s,value\n0,3\n0.5,7\n")
    path = write(tmp_path, gateway(", signals: {Pages.Sel: {trace: sel.csv}}"))
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    assert str(e.value) == f"{tmp_path / 'sel.csv'}:3: 7 is not one of Sel's multiplexer ids [3, 5, 9]"
