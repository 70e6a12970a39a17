"""Error frames (a bus fault the logger saw; CANalyzer's ErrorFrame, PCAN's ER, candump -e's
error-flag ids) and CAN FD frames in a recording: a scenario's trace refuses them (the bridge
carries CAN 2.0 data and remote frames, so a replay cannot send them), while summarise counts
them and scaffold writes a trace without them, said in its header, so the recording needs no
editing by hand."""
from __future__ import annotations

import re
from pathlib import Path

import can
import pytest

from canbench import authoring, cli, scenario
from canbench.errors import TraceError
from canbench.trace import ERROR_FRAME, iter_trace, read_trace

pytestmark = pytest.mark.unit

T0 = 1_700_000_000.0


def recording(path: Path) -> Path:
    """Ten frames of 123 every 10 ms, an error frame after the 3rd and after the 7th."""
    messages = [can.Message(timestamp=T0 + k * 0.01, arbitration_id=0x123, is_extended_id=False, data=bytes([k]),
                            channel=0) for k in range(10)]
    messages += [can.Message(timestamp=T0 + k * 0.01 + 0.005, arbitration_id=0x4, is_error_frame=True, dlc=8,
                             data=bytes(8), channel=0) for k in (2, 6)]
    if path.suffix == ".log":
        path.write_text("".join(f"({m.timestamp:.6f}) can0 " + ("20000004#0000000000000000" if m.is_error_frame
                                                                 else f"123#{m.data.hex().upper()}") + "\n"
                                for m in sorted(messages, key=lambda m: m.timestamp)))
        return path
    with can.Logger(str(path)) as log:
        for m in sorted(messages, key=lambda m: m.timestamp):
            log.on_message_received(m)
    return path


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".csv"])
def test_error_frames_are_counted_and_left_out_only_when_asked(tmp_path, suffix):
    path = recording(tmp_path / f"drive{suffix}")
    with pytest.raises(TraceError, match="an error frame"):
        read_trace(path)
    left_out: dict[str, list[int]] = {}
    frames = [frame.data[0] for _, _, _, frame in iter_trace(path, left_out=left_out)]
    assert frames == list(range(10)) and list(left_out) == ["error frame"] and len(left_out["error frame"]) == 2


def test_summarise_says_how_many_and_where_the_first_is(tmp_path):
    path = recording(tmp_path / "drive.log")
    s = authoring.summarise(path)
    assert s.frames == 10 and s.left_out == {"error frame": [4, 9]}
    assert ("2 error frames (the first: line 4) of drive.log not replayed: the bridge carries CAN 2.0 data and "
            "remote frames only") in s.table()


@pytest.mark.parametrize("suffix", [".asc", ".log"])
def test_scaffold_writes_the_trace_without_them_and_says_so(tmp_path, capsys, suffix):
    path = recording(tmp_path / f"drive{suffix}")
    out = tmp_path / "sc" / "drive.yaml"
    assert cli.main(["scaffold", str(path), "--name", "drive", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "Left out: 2 error frames (the first: " in said and "traces/drive.classic.log" in said
    [ecu] = scenario.load(out).ecus
    assert ecu.trace == (tmp_path / "sc" / "traces" / "drive.classic.log").resolve()
    assert [f.message.data[0] for f in read_trace(ecu.trace)] == list(range(10))
    assert "# Left out: 2 error frames" in out.read_text()


def test_scaffold_of_several_interfaces_leaves_them_out_of_each(tmp_path, capsys):
    path = tmp_path / "two.log"
    path.write_text("(1700000000.000000) can0 123#00\n(1700000000.001000) can1 456#00\n"
                    "(1700000000.005000) can1 20000004#0000000000000000\n"
                    "(1700000000.010000) can0 123#01\n(1700000000.011000) can1 456#01\n")
    out = tmp_path / "sc" / "two.yaml"
    assert cli.main(["scaffold", str(path), "--name", "two", "--out", str(out)]) == 0
    assert "Left out: 1 error frame (the first: line 3) of two.log" in capsys.readouterr().out
    assert sorted(len(read_trace(e.trace)) for e in scenario.load(out).ecus) == [2, 2]


def test_a_scenario_trace_with_one_is_refused_saying_what_to_do(tmp_path):
    path = recording(tmp_path / "drive.log")
    with pytest.raises(TraceError) as e:
        read_trace(path)
    assert str(e.value) == f"{path}:4: {ERROR_FRAME}" and "canbench scaffold leaves them out" in str(e.value)


def test_can_fd_frames_are_left_out_alike_and_said_with_the_error_frames(tmp_path, capsys):
    """A CAN FD bus's recording mixes classic and FD frames: scaffold replays the classic ones."""
    path = tmp_path / "mixed.asc"
    messages = [can.Message(timestamp=T0 + k * 0.01, arbitration_id=0x123, is_extended_id=False, data=bytes([k]),
                            channel=0) for k in range(6)]
    messages += [can.Message(timestamp=T0 + 0.015, arbitration_id=0x456, is_fd=True, bitrate_switch=True,
                             data=bytes(12), channel=0),
                 can.Message(timestamp=T0 + 0.035, arbitration_id=0x4, is_error_frame=True, dlc=8, data=bytes(8),
                             channel=0)]
    with can.Logger(str(path)) as log:
        for m in sorted(messages, key=lambda m: m.timestamp):
            log.on_message_received(m)
    s = authoring.summarise(path)
    assert s.frames == 6 and sorted(s.left_out) == ["CAN FD frame", "error frame"]
    out = tmp_path / "sc" / "mixed.yaml"
    assert cli.main(["scaffold", str(path), "--name", "mixed", "--out", str(out)]) == 0
    assert "Left out: 1 CAN FD frame (the first: line " in capsys.readouterr().out
    [ecu] = scenario.load(out).ecus
    assert [f.message.data[0] for f in read_trace(ecu.trace)] == list(range(6))


@pytest.mark.parametrize("line, said", [
    ("456##1112", "'##1112': not a CAN FD frame"),                    # an odd number of digits
    ("456##1" + "00" * 9, "'##1" + "00" * 9 + "': not a CAN FD frame"),  # 9 bytes: no CAN FD length
    ("20000004#" + "00" * 12, "29-bit id 20000004 is above 1FFFFFFF"),   # an error frame has 8 bytes at most
])
def test_a_mangled_line_is_a_problem_not_a_frame_left_out(tmp_path, line, said):
    path = tmp_path / "bad.log"
    path.write_text(f"(1700000000.000000) can0 123#00\n(1700000000.001000) can0 {line}\n")
    left_out: dict[str, list[int]] = {}
    with pytest.raises(TraceError, match=f"bad.log:2: {re.escape(said)}"):
        list(iter_trace(path, left_out=left_out))
    assert left_out == {}


def test_a_recording_of_nothing_but_fd_frames_says_so(tmp_path):
    path = tmp_path / "fd.log"
    path.write_text("(1700000000.000000) can0 123##100\n(1700000000.001000) can0 123##1" + "00" * 12 + "\n")
    with pytest.raises(TraceError, match=r"fd.log: no CAN 2.0 frames in trace: 2 CAN FD frames \(the first: line 1\)"):
        authoring.summarise(path)


def test_another_recording_of_the_same_name_is_refused_naming_the_recording(tmp_path, capsys):
    out = tmp_path / "sc" / "drive.yaml"
    first, second = tmp_path / "a" / "drive.log", tmp_path / "b" / "drive.log"
    for path, data in ((first, "11"), (second, "22")):
        path.parent.mkdir()
        path.write_text(f"(1700000000.000000) can0 123#{data}\n(1700000000.005000) can0 20000004#00\n"
                        f"(1700000000.010000) can0 123#{data}\n")
    assert cli.main(["scaffold", str(first), "--name", "drive", "--out", str(out)]) == 0
    assert cli.main(["scaffold", str(second), "--name", "drive", "--out", str(out), "--force"]) == 2
    assert f"exists with other contents than the CAN 2.0 frames of {second}" in capsys.readouterr().err


def test_an_asc_canfd_error_frame_is_an_error_frame(tmp_path):
    path = tmp_path / "e.asc"
    path.write_text("date Sat Dec 5 10:00:00.000 am 2026\nbase hex  timestamps absolute\ninternal events logged\n"
                    "Begin Triggerblock Sat Dec 5 10:00:00.000 am 2026\n"
                    "   0.010000 1  123             Rx   d 2 11 22\n"
                    "   0.020000 CANFD   1 Rx ErrorFrame 0 0 0 0 0 0 0 0 0 0 0 0 0\n"
                    "End TriggerBlock\n")
    left_out: dict[str, list[int]] = {}
    assert [f.can_id for _, _, _, f in iter_trace(path, left_out=left_out)] == [0x123]
    assert left_out == {"error frame": [6]}
