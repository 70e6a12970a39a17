"""DBCs as vehicles' files write them, not as ours do: a checksum or a counter on some pages of a
multiplexed message, 29-bit messages of small ids, send types other than Cyclic, a cycle time
declared ENUM or STRING, CAN FD messages, duplicate ids, senders missing from BU_, limits the
bits cannot carry. Ground truth is cantools' own encode and decode; each case was wrong (a silent
byte, a frame never decoded, a node refused, a traceback) before the code it guards."""
from __future__ import annotations

import textwrap
from pathlib import Path

import cantools
import pytest

from canbench import dbc, restbus, scenario, validate
from canbench.errors import ScenarioError
from canbench.wire import Frame

pytestmark = pytest.mark.unit

HEAD = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: GW TESTER\n\n'


def load(text: str):
    return cantools.database.load_string(HEAD + textwrap.dedent(text), database_format="dbc")


def scenario_file(tmp_path: Path, dbc_text: str, ecus: str, commands: str = "") -> Path:
    (tmp_path / "v.dbc").write_text(HEAD + textwrap.dedent(dbc_text))
    path = tmp_path / "s.yaml"
    path.write_text("name: v\nduration_s: 5\ndbc: v.dbc\nbuses: [{name: vcan0}]\nexpect: {integrity: true}\n"
                    + textwrap.dedent(ecus) + textwrap.dedent(commands))
    return path


PAGED = """\
BO_ 768 Muxed: 8 GW
 SG_ Page M : 0|8@1+ (1,0) [0|0] "" TESTER
 SG_ P0Crc m0 : 56|8@1+ (1,0) [0|0] "" TESTER
 SG_ P1Cnt m1 : 8|4@1+ (1,0) [0|15] "" TESTER
 SG_ P1Tail m1 : 56|8@1+ (1,0) [0|0] "" TESTER
 SG_ P1Crc m1 : 48|8@1+ (1,0) [0|0] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ SG_ "GenSigStartValue" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 100;
BA_DEF_DEF_ "GenSigStartValue" 0;
BA_ "GenSigStartValue" SG_ 768 P1Tail 165;
"""


def restbus_frames(path: Path, count: int) -> list[bytes]:
    sc = scenario.load(path)
    plan = sc.ecus[0].restbus[0]
    return [plan.encode(plan.values(0.0), n) for n in range(count)]


def test_a_checksum_is_written_only_in_the_pages_that_carry_it(tmp_path):
    # P0Crc is byte 7 of page 0; page 1 has P1Tail there: the checksum wrote over it (00 instead of a5)
    path = scenario_file(tmp_path, PAGED, """\
        ecus:
          - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, checksums: {Muxed.P0Crc: xor}}
        """)
    m = load(PAGED).get_message_by_name("Muxed")
    page0, page1 = restbus_frames(path, 2)
    assert page1 == m.encode({"Page": 1, "P1Cnt": 0, "P1Tail": 165, "P1Crc": 0})
    assert page0[7] == restbus.xor8(page0[:7])


def test_a_checksum_of_a_later_page_is_taken_and_written_there(tmp_path):
    path = scenario_file(tmp_path, PAGED, """\
        ecus:
          - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, checksums: {Muxed.P1Crc: xor}}
        """)
    page0, page1 = restbus_frames(path, 2)
    assert page0 == load(PAGED).get_message_by_name("Muxed").encode({"Page": 0, "P0Crc": 0})
    assert page1[6] == restbus.xor8(page1[:6] + page1[7:])


def test_a_counter_of_one_page_counts_the_frames_of_that_page(tmp_path):
    path = scenario_file(tmp_path, PAGED, """\
        ecus:
          - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, counters: [Muxed.P1Cnt]}
        """)
    m = load(PAGED).get_message_by_name("Muxed")
    counts = [m.decode(data).get("P1Cnt") for data in restbus_frames(path, 8)]
    assert counts == [None, 0, None, 1, None, 2, None, 3]  # not 1, 3, 5: a receiver sees no jump


def test_29_bit_messages_of_small_ids_are_decoded_apart_from_11_bit_ones():
    db = load("""\
        BO_ 2147483664 ExtSmall: 8 GW
         SG_ E : 0|8@1+ (1,0) [0|0] "" TESTER
        BO_ 2147483939 Ext123: 8 GW
         SG_ X : 0|8@1+ (1,0) [0|0] "" TESTER
        BO_ 291 Std123: 8 GW
         SG_ S : 0|8@1+ (1,0) [0|0] "" TESTER
        """)
    assert dbc.decode_signals(db, Frame(0x10, 8, b"\x07" + bytes(7), extended=True)) == ("ExtSmall", {"E": 7.0})
    assert dbc.decode_signals(db, Frame(0x123, 8, b"\x09" + bytes(7), extended=True)) == ("Ext123", {"X": 9.0})
    assert dbc.decode_signals(db, Frame(0x123, 8, b"\x2a" + bytes(7))) == ("Std123", {"S": 42.0})
    assert dbc.decode_signals(db, Frame(0x10, 8, bytes(8))) is None


SEND_TYPES = """\
BO_ 256 Fixed: 8 GW
 SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 257 EventPer: 8 GW
 SG_ B : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 258 NonCyc: 8 GW
 SG_ C : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 259 Evt: 8 GW
 SG_ D : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 260 Unsaid: 8 GW
 SG_ E : 0|8@1+ (1,0) [0|0] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ BO_ "GenMsgSendType" ENUM "FixedPeriodic","Event","EventPeriodic","NonCyclic","NoMsgSendType";
BA_DEF_DEF_ "GenMsgCycleTime" 50;
BA_DEF_DEF_ "GenMsgSendType" "NoMsgSendType";
BA_ "GenMsgSendType" BO_ 256 0;
BA_ "GenMsgSendType" BO_ 257 2;
BA_ "GenMsgSendType" BO_ 258 3;
BA_ "GenMsgSendType" BO_ 259 1;
"""


def test_periodic_send_types_are_cyclic_and_event_ones_are_not():
    db = load(SEND_TYPES)
    cycles = {m.name: dbc.cycle_time_ms(m) for m in db.messages}
    assert cycles == {"Fixed": 50.0, "EventPer": 50.0, "NonCyc": None, "Evt": None, "Unsaid": 50.0}


@pytest.mark.parametrize("definition,default,value,expected", [
    ('ENUM "10","20","100"', '"10"', "2", 100.0),  # cantools gives the label's index
    ("STRING", '""', '"40"', 40.0),                 # a text: its number
    ("STRING", '""', '"fast"', None),               # not a number: no cycle (not a traceback)
    ("FLOAT 0 1000", "0", "12.5", 12.5),
])
def test_a_cycle_time_of_any_attribute_type_is_its_number(definition, default, value, expected):
    db = load(f"""\
        BO_ 256 M: 8 GW
         SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER

        BA_DEF_ BO_ "GenMsgCycleTime" {definition};
        BA_DEF_DEF_ "GenMsgCycleTime" {default};
        BA_ "GenMsgCycleTime" BO_ 256 {value};
        """)
    assert dbc.cycle_time_ms(db.get_message_by_name("M")) == expected


FD = """\
BO_ 256 Classic: 8 GW
 SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 257 Long: 64 GW
 SG_ B : 0|8@1+ (1,0) [0|0] "" TESTER
BO_ 258 FdCmd: 16 TESTER
 SG_ C : 0|8@1+ (1,0) [0|0] "" GW
BO_ 259 FdShort: 8 GW
 SG_ D : 0|8@1+ (1,0) [0|0] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","StandardCAN_FD","ExtendedCAN_FD";
BA_DEF_DEF_ "GenMsgCycleTime" 20;
BA_DEF_DEF_ "VFrameFormat" "StandardCAN";
BA_ "VFrameFormat" BO_ 257 2;
BA_ "VFrameFormat" BO_ 258 2;
BA_ "VFrameFormat" BO_ 259 2;
"""


def test_a_restbus_node_leaves_out_its_can_fd_messages_and_says_so(tmp_path, capsys):
    path = scenario_file(tmp_path, FD, "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n")
    ecu = scenario.load(path).ecus[0]
    assert [p.message.name for p in ecu.restbus] == ["Classic", "FdShort"]  # 8 bytes go as CAN 2.0 frames
    assert ecu.left_out == ("Long (64 data bytes: CAN FD)",)
    assert validate.run([path]) == 0
    assert "ECU gw (GW) leaves out Long (64 data bytes: CAN FD)" in capsys.readouterr().out


def test_a_command_in_a_can_fd_message_is_a_problem_before_the_run(tmp_path):
    path = scenario_file(tmp_path, FD, "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n",
                         "commands:\n  - {bus: vcan0, message: FdCmd, run_s: 1}\n")
    assert [str(p).split(": ", 1)[1] for p in validate.problems(path)] == [
        "commands.0.message: FdCmd has 16 data bytes (CAN FD): the bench carries CAN 2.0 frames, up to 8"]


@pytest.mark.parametrize("second,said", [
    ('BO_ 256 M2: 8 GW\n SG_ B : 0|8@1+ (1,0) [0|0] "" TESTER\n',
     "messages M1 and M2 have the same id 100: give each message its own id"),
    ('BO_ 257 M1: 8 GW\n SG_ B : 0|8@1+ (1,0) [0|0] "" TESTER\n',
     "two messages are named M1 (ids 100 and 101): give each message its own name"),
])
def test_two_messages_of_one_id_or_name_are_refused_naming_both(tmp_path, second, said):
    # cantools keeps the second for lookups: every frame of 0x100 decoded as M2, a gate on M1 never met
    path = scenario_file(tmp_path, 'BO_ 256 M1: 8 GW\n SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER\n' + second,
                         "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, "
                         "cycle_ms: {M1: 10}}\n")
    assert [str(p) for p in validate.problems(path)] == [
        f"{path}:3: dbc: cannot use v.dbc as a DBC: {said}"]


def test_a_sender_missing_from_bu_is_a_node_and_a_silent_node_is_said(tmp_path):
    text = """\
        BO_ 256 FromAscm: 8 ASCM
         SG_ A : 0|8@1+ (1,0) [0|0] "" GW

        BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
        BA_DEF_DEF_ "GenMsgCycleTime" 20;
        """
    ecu = "ecus:\n  - {{name: e, bus: vcan0, role: restbus, dbc_node: {}, run_s: 1}}\n"
    path = scenario_file(tmp_path, text, ecu.format("ASCM"))
    assert [p.message.name for p in scenario.load(path).ecus[0].restbus] == ["FromAscm"]
    path = scenario_file(tmp_path, text, ecu.format("TESTER"))
    with pytest.raises(ScenarioError, match="TESTER transmits no message in the DBC"):
        scenario.load(path)


def test_a_dbc_load_error_is_said_whole(tmp_path):
    path = scenario_file(tmp_path, 'BO_ 256 M: 8 GW\n SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER\n\nVAL_ 999 A 1 "on";\n',
                         "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n")
    (problem,) = [str(p) for p in validate.problems(path)]
    dbc = path.parent / "v.dbc"
    line = next(i for i, text in enumerate(dbc.read_text().splitlines(), 1) if text.startswith("VAL_ 999 A"))
    assert problem.endswith(f'cannot load v.dbc as a DBC (cantools): {dbc.resolve()}:{line}: DBC: "unused VAL_ '
                            'entries in DBC: VAL_ 999 A" (a value table for a signal its message lacks: correct the '
                            "signal's name, or delete the VAL_)")


def test_a_start_value_the_bits_cannot_carry_names_its_signal_on_any_page(tmp_path):
    text = PAGED.replace("BA_ \"GenSigStartValue\" SG_ 768 P1Tail 165;", "BA_ \"GenSigStartValue\" SG_ 768 P1Tail 300;")
    path = scenario_file(tmp_path, text, "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n")
    assert [str(p).split(": ", 1)[1] for p in validate.problems(path)] == [
        "ecus.0: Muxed.P1Tail: its start value 300 (GenSigStartValue) is outside what its 8 bits at scale 1, "
        "offset 0 carry: [0, 255]: give it a value in signals"]


def test_a_multiplexer_without_pages_is_a_plain_signal():
    db = load('BO_ 800 Lone: 8 GW\n SG_ Mode M : 0|8@1+ (1,0) [0|0] "" TESTER\n'
              ' SG_ Plain : 8|8@1+ (1,0) [0|0] "" TESTER\n')
    plan = restbus.MessagePlan(db.get_message_by_name("Lone"), cycle_ms=10.0)
    assert plan.encode(plan.values(0.0), 0) == bytes(8)


def test_limits_outside_what_the_bits_carry_leave_the_bits_range():
    # [0|-989.765] on a signal of 0..4095: every value was refused with a backwards range
    db = load('BO_ 256 M: 8 GW\n SG_ Dist : 0|12@1+ (1,0) [0|-989.765] "m" TESTER\n')
    lo, hi, said = dbc.value_range(db.get_message_by_name("M").get_signal_by_name("Dist"))
    assert (lo, hi) == (0, 4095) and "the DBC's [0|-989.765] is empty, so not used" in said
    assert dbc.range_problem(db.get_message_by_name("M").get_signal_by_name("Dist"), 100) is None


def test_a_responder_answer_that_cannot_carry_the_copied_value_is_unanswerable_not_undecodable():
    db = load("""\
        BO_ 256 Req: 8 TESTER
         SG_ Wanted : 0|16@1- (1,0) [-1000|1000] "" GW
        BO_ 257 Resp: 8 GW
         SG_ Got : 0|8@1+ (1,0) [0|0] "" TESTER
        """)
    rule = restbus.Rule(db.get_message_by_name("Req"), restbus.MessagePlan(db.get_message_by_name("Resp")),
                        {"Got": ("Wanted", 1.0, 0.0)})
    assert rule.answer((50).to_bytes(2, "little") + bytes(6), 0)[1] == bytes([50]) + bytes(7)
    with pytest.raises(restbus.Unanswerable, match=r"Resp.Got from Req.Wanted: 500 is outside what its 8 bits"):
        rule.answer((500).to_bytes(2, "little") + bytes(6), 0)
    with pytest.raises(restbus.UndecodableRequest):
        rule.answer(b"\x01", 0)  # shorter than the message


def test_a_cycle_time_enum_of_its_first_label_is_that_label():
    # cantools gives index 0 as None: the message was taken for an event message
    db = load('BO_ 256 M: 8 GW\n SG_ A : 0|8@1+ (1,0) [0|0] "" TESTER\n\n'
              'BA_DEF_ BO_ "GenMsgCycleTime" ENUM "10","20","100";\nBA_DEF_DEF_ "GenMsgCycleTime" "100";\n'
              'BA_ "GenMsgCycleTime" BO_ 256 0;\n')
    assert dbc.cycle_time_ms(db.get_message_by_name("M")) == 10.0


def test_a_counter_or_checksum_on_no_page_the_scenario_sends_is_a_problem(tmp_path):
    path = scenario_file(tmp_path, PAGED, """\
        ecus:
          - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1, signals: {Muxed.Page: 0},
             counters: [Muxed.P1Cnt], checksums: {Muxed.P1Crc: xor}}
        """)
    assert [str(p).split(": ", 1)[1] for p in validate.problems(path)] == [
        f"ecus.0.{kind}: Muxed.{name} is on no page the scenario sends (('Page', 0)): no frame would carry it"
        for kind, name in (("counters", "P1Cnt"), ("checksums", "P1Crc"))]


def test_a_start_value_a_command_schedule_always_sets_is_not_a_problem(tmp_path):
    text = 'BO_ 300 Cmd: 8 TESTER\n SG_ Level : 0|8@1+ (1,0) [0|0] "" GW\n\n' \
           'BA_DEF_ SG_ "GenSigStartValue" INT 0 65535;\nBA_DEF_DEF_ "GenSigStartValue" 0;\n' \
           'BA_ "GenSigStartValue" SG_ 300 Level 300;\n'
    ecus = "ecus:\n  - {name: gw, bus: vcan0, role: echo, echo_ids: [\"12C\"]}\n"
    path = scenario_file(tmp_path, text, ecus, "commands:\n  - {bus: vcan0, message: Cmd, schedule: "
                         "[{at_s: 0.5, signals: {Level: 5}}, {at_s: 1.0, signals: {Level: 6}}]}\n")
    assert validate.problems(path) == []
    path = scenario_file(tmp_path, text, ecus, "commands:\n  - {bus: vcan0, message: Cmd, cycle_ms: 10, run_s: 1}\n")
    assert [str(p).split(": ", 1)[1] for p in validate.problems(path)] == [
        "commands.0: Cmd.Level: its start value 300 (GenSigStartValue) is outside what its 8 bits at scale 1, "
        "offset 0 carry: [0, 255]: give it a value in signals"]


def test_a_responder_request_of_another_page_is_unanswerable_not_a_crash():
    db = load("""\
        BO_ 768 Req: 8 TESTER
         SG_ Page M : 0|8@1+ (1,0) [0|0] "" GW
         SG_ A m0 : 8|8@1+ (1,0) [0|0] "" GW
         SG_ B m1 : 8|8@1+ (1,0) [0|0] "" GW
        BO_ 769 Ans: 8 GW
         SG_ X : 0|8@1+ (1,0) [0|0] "" TESTER
        """)
    rule = restbus.Rule(db.get_message_by_name("Req"), restbus.MessagePlan(db.get_message_by_name("Ans")),
                        {"X": ("A", 1.0, 0.0)})
    assert rule.answer(bytes([0, 5]) + bytes(6), 0)[1] == bytes([5]) + bytes(7)
    with pytest.raises(restbus.Unanswerable, match="Req.A is not in this request's page"):
        rule.answer(bytes([1, 5]) + bytes(6), 0)


def gate_problems(tmp_path: Path, dbc_text: str, gate: str, more: str = "") -> list[str]:
    """The problems of a scenario that gates one signal (a candump trace to replay, no ECU sends the DBC)."""
    (tmp_path / "v.dbc").write_text(HEAD + textwrap.dedent(dbc_text))
    (tmp_path / "t.log").write_text("(1700000000.000000) vcan0 123#00\n")
    path = tmp_path / "s.yaml"
    path.write_text(f"name: v\nduration_s: 5\ndbc: v.dbc\n{more}buses: [{{name: vcan0}}]\n"
                    "ecus:\n  - {name: e, bus: vcan0, trace: t.log}\nexpect: {signals: {" + gate + "}}\n")
    return [str(p).split(": ", 1)[1] for p in validate.problems(path)]


@pytest.mark.parametrize("signals,said", [
    # opendbc's vw_pq.dbc Motor_2: a bare 'm' where the multiplexer's 'M' belongs, pages by SG_MUL_VAL_
    (' SG_ Code m : 6|2@1+ (1,0) [0|3] "" TESTER\n SG_ Motor m1 : 0|6@1+ (1,0) [0|63] "" TESTER\n'
     'SG_MUL_VAL_ 648 Motor Code 1-1;\n',
     "Motor is multiplexed by Code, which the DBC does not mark a multiplexer (M)"),
    (' SG_ Half : 0|16@1- (1,0) [0|0] "" TESTER\nSIG_VALTYPE_ 648 Half : 1;\n',
     "Half is a float of 16 bits (a DBC's float is 32 bits, SIG_VALTYPE_ 1, or 64, SIG_VALTYPE_ 2)"),
    (' SG_ Z : 0|8@1+ (0,5) [0|0] "" TESTER\n', "Z's scale is 0 (every frame carries its offset, 5)"),
])
def test_a_signal_cantools_reads_but_never_decodes_or_encodes_right_is_refused_strictly(tmp_path, signals, said):
    # each loaded without a word: the page's signals were never decoded (nor their values sent), an
    # 8-bit float failed every frame of its message, a scale of 0 crashed validation (division by zero)
    text = "BO_ 648 Motor_2: 8 GW\n" + signals.split("\nSG_MUL_VAL_")[0].split("\nSIG_VALTYPE_")[0] + "\n" + \
        "".join(line + "\n" for line in signals.splitlines() if not line.startswith(" SG_ "))
    path = scenario_file(tmp_path, text, "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n")
    problems = [str(p).split(": ", 1)[1] for p in validate.problems(path)]
    assert problems[0] == (f"dbc: strict reading refuses v.dbc: 1 message it cannot read whole as written (signals "
                           f"that overlap or pass the message's end, or below): Motor_2 ({said}); if the DBC is meant "
                           "as written, set dbc_strict: false (each such message is then read signal by signal, and "
                           "not sent)")


def test_two_signals_of_one_name_are_refused(tmp_path):
    # a decoded frame held one value of the name; a gate took its limits from one, its scale from the other
    path = scenario_file(tmp_path, 'BO_ 256 M: 8 GW\n SG_ Speed : 0|8@1+ (1,0) [0|0] "" TESTER\n'
                                   ' SG_ Speed : 8|16@1+ (0.01,0) [0|0] "" TESTER\n',
                         "ecus:\n  - {name: gw, bus: vcan0, role: restbus, dbc_node: GW, run_s: 1}\n")
    assert [str(p) for p in validate.problems(path)] == [
        f"{path}:3: dbc: cannot use v.dbc as a DBC: message M has two signals named Speed: give each signal its "
        "own name"]


def test_a_gate_on_a_can_fd_message_is_refused_though_its_signal_lies_in_8_bytes(tmp_path):
    # every frame of 8 bytes failed to decode as the 16-byte message: a violation per frame at run time
    text = 'BO_ 500 FdStatus: 16 GW\n SG_ Speed : 0|16@1+ (1,0) [0|0] "" TESTER\n'
    assert gate_problems(tmp_path, text, "FdStatus.Speed: {range: [0, 10]}") == [
        "expect.signals.FdStatus.Speed: FdStatus has 16 data bytes (CAN FD): the bench carries CAN 2.0 frames of "
        "at most 8, and no shorter frame decodes as it"]


def test_a_gate_on_a_signal_of_scale_zero_read_as_written_is_a_problem_not_a_crash(tmp_path):
    text = 'BO_ 291 M: 8 GW\n SG_ Z : 0|8@1+ (0,5) [0|0] "" TESTER\n'
    assert gate_problems(tmp_path, text, "M.Z: {equals: 5}", "dbc_strict: false\n") == [
        "expect.signals.M.Z: Z's scale is 0 in the DBC: every frame carries its offset, whatever its bits"]
    db = dbc.load_dbc(tmp_path / "v.dbc")
    assert dbc.grid_problem(db.get_message_by_name("M").get_signal_by_name("Z"), 5) == \
        "Z's scale is 0 in the DBC: it carries 5 only"


def test_a_value_between_steps_of_a_negative_scale_names_its_true_neighbours():
    db = load('BO_ 291 M: 8 GW\n SG_ Temperature : 0|16@1+ (-0.01,4100) [0|0] "" TESTER\n')
    signal = db.get_message_by_name("M").get_signal_by_name("Temperature")
    assert dbc.grid_problem(signal, 4078.997) == (
        "4078.997 is not a value Temperature carries (steps of -0.01 from 4100): 4078.99 or 4079")


def test_a_multiplexer_value_the_dbc_lists_no_page_for_still_gives_the_other_signals():
    # an ECU's reserved page (real in opendbc's tesla_model3_party VCFRONT_LVPowerState, vw_mqb VIN_01):
    # cantools refuses the frame whole, and a gate on a page-less signal counted it a violation
    db = load('BO_ 512 Paged: 8 GW\n SG_ Page M : 0|8@1+ (1,0) [0|0] "" TESTER\n'
              ' SG_ A m0 : 8|8@1+ (1,0) [0|0] "" TESTER\n SG_ B m1 : 8|8@1+ (1,0) [0|0] "" TESTER\n'
              ' SG_ Counter : 56|4@1+ (1,0) [0|15] "" TESTER\n')
    message = db.get_message_by_name("Paged")
    assert dbc.decode(message, bytes.fromhex("0507000000000009")) == {"Page": 5, "Counter": 9}
    assert dbc.decode(message, bytes.fromhex("0107000000000009")) == {"Page": 1, "B": 7, "Counter": 9}
    with pytest.raises(cantools.database.DecodeError):
        dbc.decode(message, bytes.fromhex("05070000"))  # a frame shorter than the message is still an error
