"""DBCs cantools' strict mode refuses (signals that overlap, or pass their message's end), as
many real ones are: refused with the reason and the setting to give (`dbc_strict: false`,
--dbc-lenient), and with it read as written. Each such message is decoded signal by signal:
proven against ground truth, a DBC that gives each signal a message of its own (cantools' strict
whole-message decode). Such a message is never sent: a restbus leaves it out, a command of it is
refused. Seeded faults: a wrong bit of an overlapping signal fails its gate."""
from __future__ import annotations

import random
from pathlib import Path

import cantools
import pytest
from synthetic import signal_problems

from canbench import authoring, cli, dbc, scenario, wire
from canbench.errors import InputError, ScenarioError

pytestmark = pytest.mark.unit

T0 = 1_700_000_000_000_000_000
HEAD = 'VERSION ""\nNS_ :\nBS_:\nBU_: ECU TESTER\n'
# OVERLAP: LOW_BIT is WIDE's lowest bit; MOTO a Motorola signal across bytes 2-3; SHORT: PAST lies
# past the 2 bytes the DBC gives; MUXED: P1 and P1B overlap on page 1, P2 is page 2
AS_WRITTEN = HEAD + '''
BO_ 256 OVERLAP: 8 ECU
 SG_ WIDE : 0|16@1+ (1,0) [0|65535] "" TESTER
 SG_ LOW_BIT : 0|1@1+ (1,0) [0|1] "" TESTER
 SG_ MOTO : 23|12@0+ (0.5,-10) [0|0] "" TESTER
 SG_ FLAG : 24|1@1+ (1,0) [0|1] "" TESTER
BO_ 257 SHORT: 2 ECU
 SG_ A : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ PAST : 32|8@1- (1,0) [0|0] "" TESTER
BO_ 258 MUXED: 8 ECU
 SG_ SEL M : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ P1 m1 : 8|16@1+ (1,0) [0|65535] "" TESTER
 SG_ P1B m1 : 16|8@1+ (1,0) [0|255] "" TESTER
 SG_ P2 m2 : 8|8@1- (1,0) [0|0] "" TESTER
BO_ 259 FINE: 8 ECU
 SG_ X : 0|8@1+ (1,0) [0|255] "" TESTER
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 256 10;
BA_ "GenMsgCycleTime" BO_ 259 10;
'''
# the same signals, no two in one message: what each must decode to
TRUTH = HEAD + '''
BO_ 256 OVERLAP_A: 8 ECU
 SG_ WIDE : 0|16@1+ (1,0) [0|65535] "" TESTER
 SG_ MOTO : 23|12@0+ (0.5,-10) [0|0] "" TESTER
 SG_ FLAG : 24|1@1+ (1,0) [0|1] "" TESTER
BO_ 512 OVERLAP_B: 8 ECU
 SG_ LOW_BIT : 0|1@1+ (1,0) [0|1] "" TESTER
BO_ 257 SHORT: 8 ECU
 SG_ A : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ PAST : 32|8@1- (1,0) [0|0] "" TESTER
BO_ 258 MUXED_A: 8 ECU
 SG_ SEL M : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ P1 m1 : 8|16@1+ (1,0) [0|65535] "" TESTER
 SG_ P2 m2 : 8|8@1- (1,0) [0|0] "" TESTER
BO_ 514 MUXED_B: 8 ECU
 SG_ SEL M : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ P1B m1 : 16|8@1+ (1,0) [0|255] "" TESTER
'''


@pytest.fixture
def files(tmp_path):
    (tmp_path / "car.dbc").write_text(AS_WRITTEN)
    (tmp_path / "truth.dbc").write_text(TRUTH)
    (tmp_path / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 103#00\n")
    return tmp_path


def truth_of(truth, names: list[str], data: bytes) -> dict:
    out: dict = {}
    for name in names:
        try:
            out |= truth.get_message_by_name(name).decode(data, decode_choices=False)
        except cantools.database.DecodeError:  # the other page
            out |= {"SEL": data[0]}
    return out


def test_each_signal_decodes_from_its_own_bits_as_ground_truth_does(files):
    db = dbc.load_dbc(files / "car.dbc")
    truth = cantools.database.load_file(str(files / "truth.dbc"))
    rng = random.Random(7)
    for _ in range(500):
        data = bytes(rng.randrange(256) for _ in range(8))
        muxed = bytes([rng.choice((1, 2, 3))]) + data[1:]
        assert dbc.decode(db.get_message_by_name("OVERLAP"), data) == truth_of(truth, ["OVERLAP_A", "OVERLAP_B"], data)
        assert dbc.decode(db.get_message_by_name("SHORT"), data) == truth_of(truth, ["SHORT"], data)
        expected = truth_of(truth, ["MUXED_A", "MUXED_B"], muxed)
        assert dbc.decode(db.get_message_by_name("MUXED"), muxed) == expected
        assert dbc.decode(db.get_message_by_name("FINE"), data) == {"X": data[0]}
    # raw values too (what a gate compares): MOTO's raw bits, not its physical value
    assert dbc.decode(db.get_message_by_name("OVERLAP"), bytes.fromhex("8142F31455667788"), scaling=False)["MOTO"] \
        == 0xF31


def test_a_signal_past_the_dbc_length_is_read_where_the_frame_carries_it(files):
    db = dbc.load_dbc(files / "car.dbc")
    short = db.get_message_by_name("SHORT")
    assert dbc.decode(short, bytes([7, 0])) == {"A": 7}  # the frame as the DBC gives it: PAST not carried
    assert dbc.decode(short, bytes([7, 0, 0, 0, 0xFE])) == {"A": 7, "PAST": -2}
    with pytest.raises(cantools.database.DecodeError, match="wrong data size"):
        dbc.decode(short, bytes([7]))  # shorter than the DBC's message: undecodable, as for any message
    long_enough = wire.Frame(0x101, 5, bytes([7, 0, 0, 0, 0xFE]))
    assert dbc.decode_signals(db, long_enough) == ("SHORT", {"A": 7.0, "PAST": -2.0})


def test_the_reason_names_every_message_strict_mode_refuses(files):
    db = dbc.load_dbc(files / "car.dbc")
    why = dbc.strict_problem(db)
    assert why is not None and why.startswith("3 messages it cannot read whole as written (signals that overlap or "
                                              "pass the message's end, or below)")
    for said in ("OVERLAP (The signals LOW_BIT and WIDE are overlapping in message OVERLAP)",
                 "SHORT (The signal PAST does not fit in message SHORT)", "MUXED (The signals P1B and P1"):
        assert said in why
    assert "FINE" not in why and dbc.as_written_problem(db.get_message_by_name("FINE")) is None


def scenario_text(extra: str = "", expect: str = "  integrity: true\n") -> str:
    return ("name: as-written\nduration_s: 10\ndbc: car.dbc\n" + extra + "buses:\n  - name: vcan0\n"
            "ecus:\n  - name: e\n    bus: vcan0\n    trace: trace.log\nexpect:\n" + expect)


def test_a_scenario_refuses_it_at_its_dbc_line_and_says_what_to_set(files, capsys):
    path = files / "sc.yaml"
    path.write_text(scenario_text())
    with pytest.raises(ScenarioError) as e:
        scenario.load(path)
    said = str(e.value)
    assert f"{path}:3" in said and "strict reading refuses car.dbc: 3 messages" in said
    assert "set dbc_strict: false" in said
    path.write_text(scenario_text("dbc_strict: false\n", "  signals:\n    OVERLAP.LOW_BIT: {equals: 1}\n"))
    assert [g.key for g in scenario.load(path).signal_gates] == ["OVERLAP.LOW_BIT"]
    assert cli.main(["validate", str(path)]) == 0
    assert ("note: car.dbc is read as written (dbc_strict: false): 3 messages it cannot read whole as written"
            in capsys.readouterr().out)
    path.write_text(scenario_text("dbc_strict: 'false'\n"))
    with pytest.raises(ScenarioError, match="dbc_strict"):
        scenario.load(path)


def test_a_gate_on_an_overlapping_signal_is_judged_and_catches_a_wrong_bit(files):
    path = files / "sc.yaml"
    path.write_text(scenario_text("dbc_strict: false\n", "  signals:\n    OVERLAP.LOW_BIT: {equals: 1}\n"
                                  "    OVERLAP.MOTO: {range: [1934, 1935]}\n"))
    right = wire.Frame(0x100, 8, bytes.fromhex("8142F31455667788"))
    assert signal_problems(path, [right, right]) == []
    wrong = wire.Frame(0x100, 8, bytes.fromhex("8042F31455667788"))  # LOW_BIT (and WIDE's lowest bit) cleared
    problems = signal_problems(path, [right, wrong])
    assert len(problems) == 1 and "OVERLAP.LOW_BIT = 0, expected 1 at t=0.010 s, can.log:2" in problems[0]


RESTBUS = "  - name: node\n    bus: vcan0\n    role: restbus\n    dbc_node: ECU\n    run_s: 1\n"


def test_the_bench_never_sends_a_message_it_cannot_encode(files):
    path = files / "sc.yaml"
    path.write_text(scenario_text("dbc_strict: false\n").replace("ecus:\n", "ecus:\n" + RESTBUS))
    node = next(e for e in scenario.load(path).ecus if e.name == "node")
    assert [p.message.name for p in node.restbus] == ["FINE"]
    assert node.left_out == ("OVERLAP (the bench cannot encode OVERLAP: The signals LOW_BIT and WIDE are "
                             "overlapping in message OVERLAP in the DBC)",)
    path.write_text(scenario_text("dbc_strict: false\n").replace(
        "ecus:\n", "ecus:\n" + RESTBUS + "    signals: {OVERLAP.WIDE: 3}\n"))
    with pytest.raises(ScenarioError, match=r"sc.yaml:\d+: ecus.0.signals.OVERLAP.WIDE: ECU's restbus leaves OVERLAP "
                                            r"out: the bench cannot encode OVERLAP: The signals LOW_BIT and WIDE"):
        scenario.load(path)
    path.write_text(scenario_text("dbc_strict: false\n") + "commands:\n  - {bus: vcan0, message: SHORT, "
                    "schedule: [{at_s: 1, signals: {A: 1}}]}\n")
    with pytest.raises(ScenarioError, match="commands.0.message: the bench cannot encode SHORT: The signal PAST "
                                            "does not fit in message SHORT in the DBC"):
        scenario.load(path)


def test_command_lines_refuse_it_unless_told_and_scaffold_writes_the_setting(files, capsys):
    with pytest.raises(InputError, match="strict reading refuses it: 3 messages.*give --dbc-lenient"):
        dbc.read_dbc(files / "car.dbc")
    assert dbc.read_dbc(files / "car.dbc", lenient=True) is dbc.load_dbc(files / "car.dbc")
    trace = files / "drive.log"
    trace.write_text("".join(f"({T0 / 1e9 + i * 0.01:.6f}) can0 100#8142F31455667788\n" for i in range(200)))
    assert cli.main(["summarise", str(trace), "--dbc", str(files / "car.dbc")]) == 2
    assert cli.main(["summarise", str(trace), "--dbc", str(files / "car.dbc"), "--dbc-lenient"]) == 0
    assert "LOW_BIT" in capsys.readouterr().out
    out = files / "scenarios" / "drive.yaml"
    args = ["scaffold", str(trace), "--name", "drive", "--out", str(out), "--dbc", str(files / "car.dbc")]
    assert cli.main(args) == 2 and not out.exists()
    assert "give --dbc-lenient" in capsys.readouterr().err
    assert cli.main([*args, "--dbc-lenient"]) == 0
    assert "REVIEW: dbc_strict: false, as --dbc-lenient asked" in capsys.readouterr().out
    sc = scenario.load(out)
    assert sc.raw["dbc_strict"] is False and "OVERLAP.LOW_BIT" in out.read_text()
    assert authoring.summarise_signals(trace, files / "car.dbc", lenient=True).messages[0].name == "OVERLAP"


def load_within(path: Path, seconds: float = 20.0):
    """load_dbc in a thread: a DBC that made it loop fails the test instead of hanging it."""
    import threading
    out: list = []
    worker = threading.Thread(target=lambda: out.append(dbc.load_dbc(path)), daemon=True)
    worker.start()
    worker.join(seconds)
    assert not worker.is_alive(), f"loading {path.name} did not end"
    return out[0]


@pytest.mark.parametrize("selects", ["SG_MUL_VAL_ 256 A A 1-1;\n",
                                     "SG_MUL_VAL_ 256 A B 1-1;\nSG_MUL_VAL_ 256 B A 1-1;\n"])
def test_multiplexers_that_select_each_other_load_and_end(tmp_path, selects):
    (tmp_path / "loop.dbc").write_text(HEAD + '''
BO_ 256 LOOP: 8 ECU
 SG_ A m1M : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ B m1M : 8|8@1+ (1,0) [0|255] "" TESTER
 SG_ X : 16|8@1+ (1,0) [0|255] "" TESTER
 SG_ Y : 16|4@1+ (1,0) [0|15] "" TESTER
''' + selects)
    db = load_within(tmp_path / "loop.dbc")
    assert dbc.decode(db.get_message_by_name("LOOP"), bytes([1, 1, 0x2A, 0, 0, 0, 0, 0]))["X"] == 0x2A


def test_a_signal_overlapping_its_multiplexer_is_read_on_its_page(tmp_path):
    """OBD-style: a PID's signal that starts with the PID byte itself (PID_AND_A) is read on the
    PID's page like any other, not dropped."""
    (tmp_path / "obd.dbc").write_text(HEAD + '''
BO_ 256 OBD: 8 ECU
 SG_ PID M : 8|8@1+ (1,0) [0|255] "" TESTER
 SG_ PID_AND_A m12 : 8|16@1+ (1,0) [0|65535] "" TESTER
 SG_ RPM m12 : 16|16@1+ (0.25,0) [0|16383] "rpm" TESTER
''')
    m = dbc.load_dbc(tmp_path / "obd.dbc").get_message_by_name("OBD")
    assert dbc.as_written_problem(m) is not None
    assert dbc.decode(m, bytes([0x41, 12, 0x20, 0x1F, 0, 0, 0, 0])) == {"PID": 12, "PID_AND_A": 0x200C,
                                                                         "RPM": 0x1F20 * 0.25}
    assert dbc.decode(m, bytes([0x41, 13, 0x20, 0x1F, 0, 0, 0, 0])) == {"PID": 13}


def test_the_viewer_refuses_it_before_it_opens_unless_told(files, capsys):
    out = files / "view.rrd"
    assert cli.main(["view", "--dbc", str(files / "car.dbc"), "--save", str(out), "--duration", "0.1"]) == 2
    assert "give --dbc-lenient" in capsys.readouterr().err and not out.exists()


def test_make_test_s_viewer_reads_the_scenario_s_dbcs_as_it_does(files):
    """make test VIEWER=1: the viewer would refuse a DBC the scenario lets in, and the run waits
    for the viewer before its traffic."""
    from canbench import compose
    path = files / "sc.yaml"
    path.write_text(scenario_text("dbc_strict: false\n"))
    command = compose.compose_override(scenario.load(path), "/scenarios/sc.yaml", viewer=True,
                                       can_mode="userspace")["services"]["viewer"]["command"]
    assert "--dbc-lenient" in command and command[command.index("--dbc") + 1] == "/scenarios/car.dbc"
    (files / "fine.dbc").write_text(HEAD + 'BO_ 259 FINE: 8 ECU\n SG_ X : 0|8@1+ (1,0) [0|255] "" TESTER\n')
    path.write_text(scenario_text().replace("dbc: car.dbc", "dbc: fine.dbc"))
    command = compose.compose_override(scenario.load(path), "/scenarios/sc.yaml", viewer=True,
                                       can_mode="userspace")["services"]["viewer"]["command"]
    assert "--dbc" in command and "--dbc-lenient" not in command


def test_a_node_whose_every_message_cannot_be_sent_is_told_so(tmp_path):
    """Not 'give cycle_ms per message': no cycle makes an unencodable message sendable."""
    (tmp_path / "car.dbc").write_text(HEAD + '''
BO_ 256 OVERLAP: 8 ECU
 SG_ WIDE : 0|16@1+ (1,0) [0|65535] "" TESTER
 SG_ LOW_BIT : 0|1@1+ (1,0) [0|1] "" TESTER
BA_DEF_ BO_ "GenMsgCycleTime" INT 0 10000;
BA_ "GenMsgCycleTime" BO_ 256 10;
''')
    (tmp_path / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 103#00\n")
    path = tmp_path / "sc.yaml"
    path.write_text(scenario_text("dbc_strict: false\n").replace("ecus:\n", "ecus:\n" + RESTBUS))
    with pytest.raises(ScenarioError, match=r"ecus.0.dbc_node: ECU transmits nothing the bench can send: OVERLAP "
                                            r"\(the bench cannot encode OVERLAP"):
        scenario.load(path)


def test_a_gate_on_a_signal_past_the_eighth_byte_is_refused_at_its_line(tmp_path):
    """A DBC read as written may place a signal where no CAN 2.0 frame reaches (opendbc's
    mazda_3_2019 CAM_KEEP_ALIVE_1.NEW_SIGNAL_4): a gate on it could only judge nothing."""
    (tmp_path / "car.dbc").write_text(HEAD + '''
BO_ 256 M: 8 ECU
 SG_ A : 0|8@1+ (1,0) [0|255] "" TESTER
 SG_ Past : 64|8@1+ (1,0) [0|255] "" TESTER
''')
    (tmp_path / "trace.log").write_text(f"({T0 / 1e9:.6f}) vcan0 100#00\n")
    path = tmp_path / "sc.yaml"
    path.write_text(scenario_text("dbc_strict: false\n", "  signals:\n    M.Past: {equals: 1}\n    M.A: {equals: 1}\n"))
    with pytest.raises(ScenarioError, match=r"sc.yaml:\d+: expect.signals.M.Past: Past's bits end in byte 9: no CAN "
                                            r"2.0 frame \(8 bytes\) carries it"):
        scenario.load(path)
    path.write_text(scenario_text("dbc_strict: false\n", "  responses:\n    - {when: {signal: M.A, equals: 1}, "
                                  "then: {signal: M.Past, equals: 1, side: bus}, within_ms: 100}\n"))
    with pytest.raises(ScenarioError, match=r"expect.responses.0.then.signal: Past's bits end in byte 9"):
        scenario.load(path)


def test_dbc_lenient_without_a_dbc_is_refused_and_a_refused_dbc_prints_nothing(files, capsys):
    trace = files / "drive.log"
    trace.write_text(f"({T0 / 1e9:.6f}) can0 100#8142F31455667788\n")
    for command in (["summarise", str(trace)], ["scaffold", str(trace), "--name", "d", "--out", str(files / "d.yaml")]):
        assert cli.main([*command, "--dbc-lenient"]) == 2
        assert "--dbc-lenient: reads the DBC --dbc names: give --dbc too" in capsys.readouterr().err
    assert cli.main(["summarise", str(trace), "--dbc", str(files / "car.dbc")]) == 2
    assert capsys.readouterr().out == ""  # no trace table before the refusal
