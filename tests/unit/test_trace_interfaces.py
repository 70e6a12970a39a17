"""A trace recorded on several interfaces (candump can0 can1, a CANoe log of two channels) and
a scenario that replays it on one bus: the scenario says which interface (`interface:`), or it
is refused at the trace's line. Merged, two buses' frames went on one bus without a word, and
out of time order (candump writes its lines in order per interface only)."""
from __future__ import annotations

from pathlib import Path

import pytest

from canbench import cli, commands, plans, scenario, trace, validate
from canbench.errors import TraceError
from canbench.trace import read_trace

pytestmark = pytest.mark.unit

# can1's 456 at .0002 is written after can0's .0003, as candump of two sockets writes it
TWO = ("(1700000000.000100) can0 123#01\n(1700000000.000300) can0 123#02\n"
       "(1700000000.000200) can1 456#01\n(1700000000.000400) can1 456#02\n")
ONE = "(1700000000.000100) can0 123#01\n(1700000000.000300) can0 123#02\n"


def scenario_file(tmp_path: Path, trace_text: str, ecu_extra: str = "", more: str = "",
                  name: str = "drive.log") -> Path:
    (tmp_path / name).write_text(trace_text)
    path = tmp_path / "s.yaml"
    path.write_text("name: t\nduration_s: 5\nbuses:\n  - name: vcan0\n"
                    f"ecus:\n  - name: engine\n    bus: vcan0\n    trace: {name}\n{ecu_extra}"
                    f"{more}expect:\n  integrity: true\n")
    return path


def sent(path: Path) -> list[tuple[int, int, str]]:
    """(trace line, id, bus) of what the scenario's first ECU sends."""
    sc = scenario.load(path)
    return [(line, m.arbitration_id, m.channel) for line, m in plans.schedule(sc.ecus[0], sc).frames()]


def test_a_trace_of_two_interfaces_without_interface_is_refused_at_the_second(tmp_path):
    path = scenario_file(tmp_path, TWO)
    with pytest.raises(TraceError, match=r"drive.log:3: frames of 2 interfaces \(can0, can1\) and one bus: say "
                                         r"which the scenario replays \(interface:\)"):
        sent(path)


def test_validate_names_the_scenario_line_of_the_trace(tmp_path, capsys):
    path = scenario_file(tmp_path, TWO)
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0] == (f"{path}:8: ecus.0.trace: drive.log has frames of 2 interfaces (can0, can1) and one bus: "
                      "say which the scenario replays (interface:), or split the trace one bus each "
                      "(canbench scaffold)")


@pytest.mark.parametrize("interface,expected", [("can0", [(1, 0x123), (2, 0x123)]),
                                                ("can1", [(3, 0x456), (4, 0x456)])])
def test_interface_replays_that_interfaces_frames_on_the_bus(tmp_path, capsys, interface, expected):
    path = scenario_file(tmp_path, TWO, f"    interface: {interface}\n")
    assert cli.main(["validate", str(path)]) == 0
    assert sent(path) == [(line, can_id, "vcan0") for line, can_id in expected]


def test_an_interface_the_trace_lacks_is_a_problem_naming_those_it_has(tmp_path, capsys):
    path = scenario_file(tmp_path, TWO, "    interface: can2\n")
    assert cli.main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.splitlines()[0] == (
        f"{path}:9: ecus.0.interface: no frames on 'can2' in drive.log (it has can0, can1)")
    with pytest.raises(TraceError, match=r"drive.log: no frames on interface 'can2' \(it has can0, can1\)"):
        sent(path)


def test_interface_without_a_trace_is_a_problem(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text("name: t\nduration_s: 5\nbuses:\n  - name: vcan0\necus:\n  - name: engine\n    bus: vcan0\n"
                    "    role: echo\n    echo_ids: ['123']\n    interface: can0\nexpect:\n  integrity: true\n")
    with pytest.raises(Exception, match=r"s.yaml:10: ecus.0.interface: names an interface of a trace: give the trace"):
        scenario.load(path)


def test_an_asc_of_two_channels_is_numbered_as_the_file_has_them(tmp_path, capsys):
    asc = ("date Mon Nov 13 10:00:00.000 am 2023\nbase hex  timestamps absolute\ninternal events logged\n"
           "Begin Triggerblock Mon Nov 13 10:00:00.000 am 2023\n"
           "   0.010000 1  123  Rx   d 1 01\n   0.010100 2  456  Rx   d 1 02\n   0.020000 1  123  Rx   d 1 03\n"
           "End TriggerBlock\n")
    for said in ("'2'", "2", "2.0"):  # a channel number, quoted or not (2.0: an integer to YAML's readers)
        path = scenario_file(tmp_path, asc, f"    interface: {said}\n", name="drive.asc")
        assert cli.main(["validate", str(path)]) == 0
        assert sent(path) == [(6, 0x456, "vcan0")]


def test_commands_of_a_two_interface_trace_say_which_too(tmp_path, capsys):
    (tmp_path / "cmd.log").write_text(TWO)
    entry = "commands:\n  - bus: vcan0\n    trace: cmd.log\n"
    path = scenario_file(tmp_path, ONE, more=entry)
    assert cli.main(["validate", str(path)]) == 2
    assert "commands.0.trace: cmd.log has frames of 2 interfaces" in capsys.readouterr().err
    path = scenario_file(tmp_path, ONE, more=entry + "    interface: can1\n")
    assert cli.main(["validate", str(path)]) == 0
    assert [(line, frame.can_id) for _, _, line, frame in commands.plan(scenario.load(path))] == [
        (3, 0x456), (4, 0x456)]


def test_a_trace_of_one_interface_needs_no_interface(tmp_path, capsys):
    path = scenario_file(tmp_path, ONE)
    assert cli.main(["validate", str(path)]) == 0
    assert sent(path) == [(1, 0x123, "vcan0"), (2, 0x123, "vcan0")]
    assert len(read_trace(tmp_path / "drive.log")) == 2


def test_an_interface_keeps_its_timing_to_the_traces_start(tmp_path):
    # can1 recorded from 3 s after can0: replayed alone, its first frame still goes 3 s in
    trace = ("(1700000000.000000) can0 123#01\n(1700000003.000000) can1 456#01\n"
             "(1700000003.500000) can1 456#02\n(1700000004.000000) can0 123#02\n")
    path = scenario_file(tmp_path, trace, "    interface: can1\n")
    sc = scenario.load(path)
    assert [(line, round(msg.timestamp, 6)) for line, msg in plans.schedule(sc.ecus[0], sc).frames()] == [
        (2, 3.0), (3, 3.5)]
    entry = "commands:\n  - bus: vcan0\n    trace: drive.log\n    interface: can1\n"
    path = scenario_file(tmp_path, trace, "    interface: can0\n", more=entry)
    assert [(round(t, 6), line) for t, _, line, _ in commands.plan(scenario.load(path))] == [(3.0, 2), (3.5, 3)]


def test_the_traces_start_is_its_earliest_frame_not_its_first_line(tmp_path):
    # candump of two sockets wrote can1's lines first, though can0's first frame is 5 ms earlier:
    # each interface keeps its recorded offset from the earliest, none is sent before the start
    log = ("(10.000000) can1 200#01\n(10.010000) can1 200#02\n(9.995000) can0 100#01\n"
             "(10.005000) can0 100#02\n(10.015000) can0 100#03\n(10.020000) can1 200#03\n")
    for interface, expected in (("can0", [0.0, 0.01, 0.02]), ("can1", [0.005, 0.015, 0.025])):
        path = scenario_file(tmp_path, log, f"    interface: {interface}\n")
        sc = scenario.load(path)
        assert [round(m.timestamp, 6) for _, m in plans.schedule(sc.ecus[0], sc).frames()] == expected
    assert trace.read_replay(tmp_path / "drive.log", "can1")[1] == pytest.approx(9.995)


def test_a_role_that_sends_no_trace_needs_no_interface(tmp_path, capsys):
    (tmp_path / "drive.log").write_text(TWO)
    path = tmp_path / "s.yaml"
    path.write_text("name: t\nduration_s: 5\nbuses:\n  - name: vcan0\necus:\n  - name: engine\n    bus: vcan0\n"
                    "    trace: drive.log\n    interface: can0\n  - name: echo\n    bus: vcan0\n    role: echo\n"
                    "    echo_ids: ['7E0']\n    trace: drive.log\nexpect:\n  integrity: true\n")
    assert cli.main(["validate", str(path)]) == 0


@pytest.mark.parametrize("interface,refused", [("can0", True), ("can1", False)])
def test_the_frame_limit_counts_the_interface_replayed(tmp_path, capsys, monkeypatch, interface, refused):
    """validate and the run agree: a trace longer than a run reads only on the interface that is not
    replayed is fine (validate counted every interface's frames and refused it)."""
    monkeypatch.setattr(trace, "MAX_TRACE_FRAMES", 2)
    monkeypatch.setattr(validate, "MAX_TRACE_FRAMES", 2)
    path = scenario_file(tmp_path, TWO + "(1700000000.000500) can0 123#03\n", f"    interface: {interface}\n")
    assert cli.main(["validate", str(path)]) == (2 if refused else 0)
    if refused:
        assert capsys.readouterr().err.splitlines()[0] == (
            f"{path}:9: ecus.0.interface: drive.log on 'can0': more than 2 frames: split the trace")
        with pytest.raises(TraceError, match="drive.log:5: more than 2 frames: split the trace"):
            sent(path)
    else:
        assert sent(path) == [(3, 0x456, "vcan0"), (4, 0x456, "vcan0")]


def test_lines_that_name_no_interface_are_said_so():
    assert trace.several_interfaces({"2": 1, None: 3, "1": 5}).startswith(
        "frames of 3 interfaces (1, 2, lines that name none) and one bus")
