"""Recordings as other tools leave them, where python-can's readers alone would read them wrong
without a word: ASC files with relative stamps, transmit requests or no 'internal events
logged' line, ASC CANFD lines of classic frames (remote by their flags, their DLC code), ASC frame
lines python-can skips or misreads, ASC and TRC 1.x lines of more bytes than their dlc, TRC 1.0
error frames, a text trace cut inside its last line (whatever its line ends, candump -L too), python-can CSV
without its header, with 'true' flags or data that is no base64, a compressed trace, a BLF its logger never closed or
with error frames stored as CAN_ERROR or CAN_FD_ERROR_64 objects (and the python-can internals read for them), a
candump -d recording with DROPCOUNT lines; and `canbench scaffold` beside another scenario's files or
with a DBC whose limits the trace is outside. Each case read a frame wrong, twice or not at all
before the code it guards."""
from __future__ import annotations

import re
import struct
from pathlib import Path

import can
import pytest
from can.io import blf

from canbench import authoring, cli
from canbench.blf import BLFReader
from canbench.errors import InputError, TraceError
from canbench.trace import ERROR_FRAME, ERROR_KIND, FD_KIND, iter_trace

pytestmark = pytest.mark.unit

ASC_HEAD = "date Mon Nov 13 10:00:00.000 am 2023\nbase hex  timestamps absolute\n"


def frames(path: Path) -> list[tuple[int, int, str]]:
    """(line, t_ns relative to the first, data hex) of every frame read."""
    out = [(line, t_ns, frame.data.hex()) for line, t_ns, _, frame in iter_trace(path)]
    return [(line, t_ns - out[0][1], data) for line, t_ns, data in out]


def problems(path: Path) -> list[str]:
    found: list[TraceError] = []
    list(iter_trace(path, on_problem=found.append))
    return [str(e) for e in found]


def asc(tmp_path: Path, body: str, head: str = ASC_HEAD + "internal events logged\n", end: str = "End TriggerBlock\n"):
    path = tmp_path / "t.asc"
    path.write_text(head + "Begin Triggerblock Mon Nov 13 10:00:00.000 am 2023\n" + body + end)
    return path


def test_relative_asc_stamps_are_refused_at_their_header_line(tmp_path):
    path = asc(tmp_path, "   0.010000 1  123  Rx   d 1 01\n   0.010000 1  123  Rx   d 1 02\n",
               head=ASC_HEAD.replace("absolute", "relative") + "internal events logged\n")
    with pytest.raises(TraceError, match=r"t.asc:2: timestamps relative: the bench reads absolute ASC stamps"):
        frames(path)


def test_an_asc_transmit_request_is_not_a_frame(tmp_path):
    path = asc(tmp_path, "   0.010000 1  123             TxRq d 1 01\n   0.010100 1  123             Tx   d 1 01\n"
                         "   0.020000 1  123             TxRq d 1 02\n   0.020100 1  123             Tx   d 1 02\n")
    assert frames(path) == [(6, 0, "01"), (8, 10_000_000, "02")]


@pytest.mark.parametrize("head", [ASC_HEAD, ""])
def test_an_asc_without_the_events_line_keeps_its_first_frame(tmp_path, head):
    path = tmp_path / "t.asc"
    path.write_text(head + "   0.010000 1  123  Rx   d 1 01\n   0.020000 1  123  Rx   d 1 02\n"
                           "   0.030000 1  123  Rx   d 1 03\n")
    first = len(head.splitlines()) + 1
    assert frames(path) == [(first, 0, "01"), (first + 1, 10_000_000, "02"), (first + 2, 20_000_000, "03")]


def test_a_blank_line_in_an_asc_header_does_not_hide_its_base(tmp_path):
    # python-can's header reader stopped at the blank line, so 'base dec' after it went unread and
    # the decimal id 291 and byte 17 were read as hex 0x291 and 0x17
    head = "date Mon Nov 13 10:00:00.000 am 2023\n\nbase dec  timestamps absolute\n\ninternal events logged\n"
    path = asc(tmp_path, "   0.010000 1  291  Rx   d 1 17\n", head=head)
    [(line, _, iface, frame)] = list(iter_trace(path))
    assert (line, frame.can_id, frame.data) == (7, 0x123, b"\x11")


@pytest.mark.parametrize("last,said", [
    ("   0.020000 1  123  Rx   d 8 01 02 03 04 05 06 07 0", "read as 07 00, not the 08 recorded"),
    ("   0.020000 1  12", "dropped by python-can"),
])
def test_an_asc_cut_inside_its_last_line_is_said_there(tmp_path, last, said):
    path = asc(tmp_path, "   0.010000 1  123  Rx   d 8 01 02 03 04 05 06 07 08\n" + last, end="")
    assert problems(path) == [f"{path}:6: the file ends inside this line: a recording cut there ({last.strip()!r})"]


@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_a_cut_last_line_is_said_whatever_the_files_line_ends(tmp_path, eol):
    # Python's readers split lines at LF, CRLF and a lone CR alike (Windows and old Mac tools)
    last = "   0.030000 1  123  Rx   d 1 F"
    path = tmp_path / "t.asc"
    path.write_bytes((ASC_HEAD + "internal events logged\nBegin Triggerblock Mon Nov 13 10:00:00.000 am 2023\n"
                      "   0.010000 1  123  Rx   d 1 01\n   0.020000 1  123  Rx   d 1 02\n" + last)
                     .replace("\n", eol).encode())
    assert problems(path) == [f"{path}:7: the file ends inside this line: a recording cut there ({last.strip()!r})"]
    path.write_bytes(path.read_bytes() + b"F" + eol.encode())  # the line whole and ended: read
    assert [(line, data) for line, _, data in frames(path)] == [(5, "01"), (6, "02"), (7, "ff")]


TRC = (";$FILEVERSION=1.1\n;$STARTTIME=45000.5\n;\n"
       "     1)         1.0  Rx         0123  2  01 02\n")


def test_a_trc_cut_inside_a_byte_is_said_and_a_whole_unended_line_is_read(tmp_path):
    cut = tmp_path / "cut.trc"
    cut.write_text(TRC + "     2)        11.0  Rx         0123  2  01 0")
    assert problems(cut) == [f"{cut}:5: the file ends inside this line: a recording cut there "
                             "('2)        11.0  Rx         0123  2  01 0')"]
    whole = tmp_path / "whole.trc"
    whole.write_text(TRC + "     2)        11.0  Rx         0123  2  01 03")  # no end of line, nothing missing
    assert [(line, data) for line, _, data in frames(whole)] == [(4, "0102"), (5, "0103")]


def test_a_candump_log_cut_inside_its_last_line_is_said_there(tmp_path):
    # a real car log ends '(1606770' with no newline: said as a cut, not as a line that is no frame
    cut = tmp_path / "cut.log"
    cut.write_text("(1606770000.000000) can0 123#DEAD\n(1606770")
    assert problems(cut) == [f"{cut}:2: the file ends inside this line: a recording cut there ('(1606770')"]
    ended = tmp_path / "ended.log"  # the same line ended: a line that is no frame, as before
    ended.write_text("(1606770000.000000) can0 123#DEAD\n(1606770\n")
    assert problems(ended) == [f"{ended}:2: not a candump -L frame: '(1606770'"]
    whole = tmp_path / "whole.log"  # a whole frame without its newline is read
    whole.write_text("(1606770000.000000) can0 123#DEAD\n(1606770000.010000) can0 123#BEEF")
    assert [(line, data) for line, _, data in frames(whole)] == [(1, "dead"), (2, "beef")]


def test_python_can_csv_needs_its_header_and_flags_of_0_or_1(tmp_path):
    rows = "1700000000.0,0x123,0,0,0,2,AQI=\n1700000000.01,0x123,0,0,0,2,AQM=\n"
    bare = tmp_path / "bare.csv"
    bare.write_text(rows)  # its reader skips line 1 whatever it is: the first frame was lost
    with pytest.raises(TraceError, match=r"bare.csv:1: python-can's CSV begins with the line timestamp,arbitration_id"):
        frames(bare)
    flags = tmp_path / "flags.csv"
    header = "timestamp,arbitration_id,extended,remote,error,dlc,data\n"
    flags.write_text(header + rows.replace(",0,0,0,", ",true,0,0,", 1))
    assert problems(flags) == [f"{flags}:2: extended, remote and error are 0 or 1 in python-can's CSV, not 'true,0,0'"]


def test_a_compressed_trace_is_refused_with_what_to_do(tmp_path):
    path = tmp_path / "drive.log.gz"
    path.write_bytes(b"\x1f\x8b\x08\x00")
    with pytest.raises(TraceError, match=r"a compressed trace: decompress it \(gunzip drive.log.gz\)"):
        frames(path)


def test_scaffold_never_writes_over_another_scenarios_trace(tmp_path, capsys):
    for car, data in (("a", "11"), ("b", "22")):
        (tmp_path / car).mkdir()
        (tmp_path / car / "drive.log").write_text("".join(f"({1_700_000_000 + i * 0.01:.6f}) can0 123#{data}\n"
                                                          for i in range(20)))
    out = tmp_path / "scenarios"
    assert cli.main(["scaffold", str(tmp_path / "a" / "drive.log"), "--name", "a", "--out", str(out / "a.yaml")]) == 0
    capsys.readouterr()
    assert cli.main(["scaffold", str(tmp_path / "b" / "drive.log"), "--name", "b", "--out", str(out / "b.yaml")]) == 2
    assert "traces/drive.log: exists with other contents than" in capsys.readouterr().err
    assert (out / "traces" / "drive.log").read_text() == (tmp_path / "a" / "drive.log").read_text()
    assert authoring.copy_in(tmp_path / "a" / "drive.log", out / "traces" / "drive.log")  # the same bytes: reused
    with pytest.raises(InputError):
        authoring.copy_in(tmp_path / "b" / "drive.log", out / "traces" / "drive.log")


DBC = """\
VERSION ""

NS_ :

BS_:

BU_: ECU TESTER

BO_ 291 Cmd: 8 ECU
 SG_ Offset : 0|8@1- (1,0) [0|127] "" TESTER
 SG_ Level : 8|8@1+ (1,0) [0|255] "" TESTER

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 10;
"""


def test_a_proposal_wholly_outside_the_dbc_limits_is_left_commented_and_the_scaffold_validates(tmp_path):
    # the trace carries Offset -64..-44, the DBC says [0|127]: the proposal could only be refused
    (tmp_path / "cmd.dbc").write_text(DBC)
    trace = tmp_path / "drive.log"
    trace.write_text("".join(f"({1_700_000_000 + i * 0.01:.6f}) can0 123#{(-64 + i) & 0xFF:02X}{i:02X}000000000000\n"
                             for i in range(21)))
    out = tmp_path / "sc" / "drive.yaml"
    assert cli.main(["scaffold", str(trace), "--name", "d", "--dbc", str(tmp_path / "cmd.dbc"), "--out", str(out)]) == 0
    text = out.read_text()
    assert "    # Cmd.Offset: {range: [" in text and "not gated: wholly outside the [0, 127] the DBC allows" in text
    assert "    Cmd.Level: {range: [" in text


@pytest.mark.parametrize("name,text,read", [
    ("dlc0.trc", TRC + "     2)        11.0  Rx         0123  0", [(4, "0102"), (5, "")]),
    ("dec.asc", "date Mon Nov 13 10:00:00.000 am 2023\nbase dec  timestamps absolute\ninternal events logged\n"
     "   0.010000 1  291  Rx   d 2 12 5\n   0.020000 1  291  Rx   d 2 12 6", [(4, "0c05"), (5, "0c06")]),
])
def test_a_whole_unended_last_line_is_read_whatever_its_last_field(tmp_path, name, text, read):
    path = tmp_path / name
    path.write_text(text)
    assert [(line, data) for line, _, data in frames(path)] == read


def test_a_last_line_cut_where_python_can_cannot_read_it_is_said_as_cut(tmp_path):
    path = asc(tmp_path, "   0.010000 1  123  Rx   d 1 01\n   0.020000 1  123  Rx", end="")
    with pytest.raises(TraceError, match=r"t.asc:6: the file ends inside this line: a recording cut there"):
        frames(path)


def test_an_asc_canfd_line_of_a_classic_frame_is_a_can_20_frame(tmp_path):
    # can-utils' log2asc -f and CANoe on a CAN FD channel: flags 0 (EDL clear), no BRS or ESI
    path = asc(tmp_path, "   0.010000 CANFD   1 Rx          123                                  0 0 8  8 "
                         "01 02 03 04 05 06 07 08   130000  130        0 0 0 0 0 0\n"
                         "   0.020000 CANFD   1 Rx          123                                  1 0 8  8 "
                         "01 02 03 04 05 06 07 09   130000  130     3000 0 0 0 0 0\n")
    read = [(line, frame.data.hex()) for line, _, _, frame in iter_trace(path, on_problem=lambda e: None)]
    assert read == [(5, "0102030405060708")]
    assert problems(path) == [f"{path}:6: a CAN FD frame (8 data bytes, BRS): the bridge carries CAN 2.0 frames "
                              "only (remove FD frames from the trace: canbench scaffold leaves them out of the "
                              "trace it writes)"]


def test_an_asc_canfd_line_of_a_classic_frame_is_remote_by_its_flags_and_keeps_its_dlc_code(tmp_path):
    # python-can takes a CANFD line without data for a remote frame whatever its flags say (RTR 0x10),
    # and reads its data length whatever its DLC code says
    line = "   {t} CANFD   1 Rx          123        0 0 {dlc}  {n} {data}  102203  133  {flags} 0 0 0 0 0\n"
    path = asc(tmp_path, line.format(t="0.010000", dlc=0, n=0, data="", flags="200000")
               + line.format(t="0.020000", dlc=8, n=0, data="", flags="200010")
               + line.format(t="0.030000", dlc=8, n=4, data="DE AD BE EF", flags="200000")
               + line.format(t="0.040000", dlc="d", n=8, data="01 02 03 04 05 06 07 08", flags="200000"))
    read = [(line, frame.candump()) for line, _, _, frame in iter_trace(path, on_problem=lambda e: None)]
    assert read == [(5, "vcan0 123#"), (6, "vcan0 123#R8")]
    said = problems(path)
    assert said[0] == f"{path}:7: dlc 8 with 4 data bytes"
    assert said[1].startswith(f"{path}:8: DLC D (13) with 8 data bytes") and len(said) == 2


@pytest.mark.parametrize("line,said", [
    ("   0.010000 1  123  Rx   q 4 DE AD BE EF", "frame type 'q' is not d (data) or r (remote)"),
    ("   0.010000 1  123  d 4 DE AD BE EF", "a frame line without its direction (Rx or Tx) before 'd'"),
    ("   0.010000 1  123  Xx   d 4 DE AD BE EF", "direction 'Xx' is not Rx or Tx"),
    ("   0,010000 1  123  Rx   d 4 DE AD BE EF", "a decimal comma in the stamp '0,010000': ASC stamps are seconds "
                                                 "with a point"),
    ("   0.010000 1  123  Rx   d 2 DE AD BE EF", "dlc 2 with 4 data bytes"),
])
def test_an_asc_frame_line_python_can_would_skip_or_misread_is_said_at_its_line(tmp_path, line, said):
    # python-can's ASC reader passes over a frame line without Rx/Tx or with a decimal comma, reads a
    # type other than 'r' as data, and reads only the DLC's count of bytes
    path = asc(tmp_path, line + "\n   0.020000 1  124  Rx   d 1 01   Length = 0 BitCount = 0 ID = 292\n")
    found = problems(path)
    assert len(found) == 1 and found[0].startswith(f"{path}:5: {said}"), found
    assert [(line, frame.candump()) for line, _, _, frame in iter_trace(path, on_problem=lambda e: None)] == [
        (6, "vcan0 124#01")]


def test_asc_events_and_well_formed_lines_are_no_problem(tmp_path):
    path = asc(tmp_path, "   0.005000 Start of measurement\n"
                         "   0.006000 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%\n"
                         "   0.007000 1  ErrorFrame\n   0.008000 CAN 1 Status:chip status error active\n"
                         "   0.010000 1  1CFEF100x  Rx   d 8 01 02 03 04 05 06 07 08  Length = 0 BitCount = 0 ID = 1\n"
                         "   0.020000 1  7E0  Tx   r 8\n   0.030000 1  123  RX   D 0\n")
    found: list[TraceError] = []
    read = [frame.candump() for _, _, _, frame in iter_trace(path, on_problem=found.append, left_out={})]
    assert read == ["vcan0 1CFEF100#0102030405060708", "vcan0 7E0#R8", "vcan0 123#"] and not found


@pytest.mark.parametrize("version,line", [
    ("1.1", "     1)     17535.4  Tx         0100  2  00 01 02 03"),
    ("1.3", "     1)     17535.4 1  Tx        0100 -  2  00 01 02 03"),
])
def test_a_trc_1x_line_of_more_bytes_than_its_dlc_is_refused(tmp_path, version, line):
    path = tmp_path / "t.trc"
    path.write_text(f";$FILEVERSION={version}\n;$STARTTIME=44548.6028595139\n{line}\n")
    assert problems(path) == [f"{path}:3: dlc 2 with 4 data bytes"]


def test_a_trc_10_error_frame_is_left_out_and_counted_not_the_end_of_the_read(tmp_path):
    # PCAN's TRC 1.0 (no FILEVERSION line): python-can reads 'ERROR' as a data byte and stops there
    path = tmp_path / "t.trc"
    path.write_text(";   Start time: 11.09.2002 16:00:20.682\n"
                    "     1)      1841  0001  8  00 00 00 00 00 00 00 00\n"
                    "     2)      1842  0008  4  ERROR 00 19 08 08\n"
                    "     3)      1844  0100  3  RTR\n")
    left_out: dict[str, list[int]] = {}
    read = [(line, frame.candump()) for line, _, _, frame in iter_trace(path, left_out=left_out)]
    assert read == [(2, "vcan0 001#0000000000000000"), (4, "vcan0 100#R3")] and left_out == {ERROR_KIND: [3]}
    assert problems(path) == [f"{path}:3: {ERROR_FRAME}"]


def test_python_can_csv_data_that_is_not_base64_is_refused(tmp_path):
    # its reader decodes without validate: '3q2*+7w==' read as DEADBEEF
    path = tmp_path / "t.csv"
    path.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n1700000000.1,0x123,0,0,0,4,3q2*+7w==\n"
                    "1700000000.2,0x123,0,0,0,4,3q2+7w==\n")
    assert problems(path) == [f"{path}:2: data '3q2*+7w==' is not base64 (python-can's CSV writes the bytes so)"]


def test_a_blf_python_can_refuses_without_a_reason_is_said_with_one(tmp_path):
    path = tmp_path / "t.blf"
    with can.BLFWriter(str(path)) as writer:
        writer.on_message_received(can.Message(timestamp=T0, arbitration_id=0x123, data=b"\x01", channel=0))
    path.write_bytes(path.read_bytes() + b"\x00" * 24)  # stray bytes after the last object
    with pytest.raises(TraceError, match=r"python-can cannot read it: \w+, bytes it reads as no object"):
        frames(path)


def test_candump_of_several_interfaces_is_in_order_per_interface_only(tmp_path):
    # candump can0 can1 reads one socket per wakeup: can1's .0002 may be written after can0's .0003
    path = tmp_path / "two.log"
    path.write_text("(1700000000.000100) can0 123#01\n(1700000000.000300) can0 123#02\n"
                    "(1700000000.000200) can1 456#01\n(1700000000.000400) can1 456#02\n"
                    "(1700000000.000250) can0 123#03\n")
    assert [(line, iface) for line, _, iface, _ in iter_trace(path, on_problem=lambda e: None)] == [
        (1, "can0"), (2, "can0"), (3, "can1"), (4, "can1"), (5, "can0")]
    assert problems(path) == [f"{path}:5: timestamp earlier than line 2's, the frame before on can0 "
                              "(1700000000.000250 s after 1700000000.000300 s)"]


@pytest.mark.parametrize("line", ["  vcan0  123   [4]  DE AD BE EF",
                                  " (1700000000.000100)  vcan0  123   [4]  DE AD BE EF",
                                  " (2023-11-14 22:13:20.000100)  vcan0  123   [4]  DE AD BE EF"])
def test_candumps_other_output_is_said_to_be_it(tmp_path, line):
    path = tmp_path / "drive.log"
    path.write_text(line + "\n")
    with pytest.raises(TraceError, match=r"drive.log:1: not a candump -L frame: .*\(candump's default output: "
                                         r"record with candump -L"):
        frames(path)


def test_candump_len8_dlc_is_said_to_be_it(tmp_path):
    """candump -8 writes 8 bytes sent with DLC code 9..F as '..._9': named, not a bare refusal."""
    path = tmp_path / "drive.log"
    path.write_text("(1700000000.000000) can0 123#1122334455667788_9\n")
    with pytest.raises(TraceError, match=r"drive.log:1: not a candump -L frame: .*\(candump -8's raw DLC code 9..F "
                                         r"for 8 bytes"):
        frames(path)


@pytest.mark.parametrize("name", ["drive.log", "drive.asc"])
def test_a_utf16_trace_is_said_to_be_one(tmp_path, name):
    path = tmp_path / name
    path.write_text("(1700000000.000100) can0 123#01\n", encoding="utf-16")  # with its byte order mark
    with pytest.raises(TraceError, match=rf"{name}:1: UTF-16 text: save the trace as UTF-8"):
        frames(path)


def test_a_recording_with_dropped_frames_is_said_incomplete_by_summarise_and_scaffold(tmp_path, capsys):
    # candump -d writes DROPCOUNT when the kernel dropped frames for its socket: the recording has holes
    lines = [f"({1_700_000_000 + i * 0.01:.6f}) can0 123#{i % 256:02X}\n" for i in range(40)]
    lines.insert(20, "DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)\n")
    path = tmp_path / "drive.log"
    path.write_text("".join(lines))
    assert cli.main(["summarise", str(path)]) == 0
    said = "INCOMPLETE: candump says the kernel dropped 3 frames on can0 while recording (DROPCOUNT lines)"
    assert f"  {said}: the gaps and cycles below count its holes" in capsys.readouterr().out.splitlines()
    out = tmp_path / "s.yaml"
    assert cli.main(["scaffold", str(path), "--name", "d", "--out", str(out)]) == 0
    assert f"# {said}: the proposed cycles are read across its holes." in out.read_text().splitlines()
    path.write_text("".join(lines[:20] + lines[21:]))  # the control: no DROPCOUNT, no word of it
    assert cli.main(["summarise", str(path)]) == 0
    assert "INCOMPLETE" not in capsys.readouterr().out


def test_a_blf_its_logger_never_closed_is_refused_where_it_is_cut(tmp_path):
    path = tmp_path / "t.blf"
    writer = can.BLFWriter(str(path), max_container_size=1024)  # several object containers
    for i in range(300):
        writer.on_message_received(can.Message(timestamp=1_700_000_000 + i * 0.01, arbitration_id=0x123,
                                               data=bytes([i % 256, 1]), is_extended_id=False))
    writer.stop()
    unfinished = bytearray(path.read_bytes())
    struct.pack_into("<QQL", unfinished, 16, 0, 0, 0)  # file size, uncompressed size, objects: never written
    path.write_bytes(bytes(unfinished))
    assert len(frames(path)) == 300  # every object whole: read
    path.write_bytes(bytes(unfinished[:-200]))  # and cut inside its last container
    said = problems(path)
    assert len(said) == 1 and re.fullmatch(
        rf"{re.escape(str(path))}: truncated: its last object \(at byte \d+\) ends past the file's end, and its "
        r"header was never finished \(a logger stopped without closing the file, or an incomplete copy\)", said[0])


T0 = 1_700_000_000.0
CAN_ERROR, CAN_OVERLOAD, CAN_FD_ERROR_64 = 2, 3, 104  # Vector's object types python-can's reader passes over


def blf_with(path: Path, records: list, container: int = 128 * 1024) -> list[tuple[int, int]]:
    """A BLF of python-can's writer: its frames (can.Message) and, between them, error and overload
    frames as other loggers store them (object type, stamp, channel from 1, header version: 2's
    stamps in 10 us). The containers cut the stream of objects every `container` bytes; returned:
    where in that stream each bus event's object starts and ends."""
    writer = can.BLFWriter(str(path), max_container_size=container)
    offset, spans = 0, []
    for record in records:
        if isinstance(record, can.Message):
            writer.on_message_received(record)
            offset += blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size + blf.CAN_MSG_STRUCT.size
            continue
        kind, stamp, channel, version = record
        if kind == CAN_FD_ERROR_64:  # VBLCANFDErrorFrame64: channel (a byte), dlc, ..., crc, position, data[64]
            body = struct.pack("<BBBBHHHBBLLLLLLLHH64s", channel, *[0] * 17, b"")
        else:  # VBLCANErrorFrame: channel, length, reserved
            body = struct.pack("<HHL", channel, 0, 0)
        if version == 1:
            writer._add_object(kind, body, stamp)
            size = blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V1_STRUCT.size + len(body)
        else:  # as writer._add_object, in header version 2
            head = blf.OBJ_HEADER_BASE_STRUCT.size + blf.OBJ_HEADER_V2_STRUCT.size
            size = head + len(body)
            writer._buffer += [blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", head, 2, size, kind),
                               blf.OBJ_HEADER_V2_STRUCT.pack(blf.TIME_TEN_MICS, 0, 0,
                                                             round((stamp - writer.start_timestamp) * 1e5)), body]
            writer._buffer_size += size
            writer.object_count += 1
            if writer._buffer_size >= writer.max_container_size:
                writer._flush()
        spans.append((offset, offset + size))
        offset += size
    writer.stop()
    return spans


def ten_frames() -> list:
    """Ten frames of 123 every 10 ms; an error frame (channel 1, header version 1) after the 3rd
    and an overload frame (channel 2, version 2) after the 7th."""
    frames: list = [can.Message(timestamp=T0 + k * 0.01, arbitration_id=0x123, is_extended_id=False,
                                data=bytes([k]), channel=0) for k in range(10)]
    frames.insert(7, (CAN_OVERLOAD, T0 + 0.065, 2, 2))
    frames.insert(3, (CAN_ERROR, T0 + 0.025, 1, 1))
    return frames


def as_read(messages) -> list[tuple]:
    """What iter_trace reads of python-can messages, to compare two readers' alike."""
    return [(m.timestamp, m.arbitration_id, m.is_error_frame, m.is_fd, m.is_remote_frame, bytes(m.data), m.channel)
            for m in messages]


@pytest.mark.parametrize("container", [128 * 1024, 80])  # one container; 80 bytes: objects span two
def test_blf_error_frames_stored_as_can_error_objects_are_refused_and_counted_not_skipped(tmp_path, container):
    # python-can's reader passes over CAN_ERROR and CAN_OVERLOAD objects without a word: the
    # recording read as if its bus had had no errors
    path = tmp_path / "drive.blf"
    spans = blf_with(path, ten_frames(), container)
    if container == 80:
        assert all(start // container != (end - 1) // container for start, end in spans)  # both cut
    assert problems(path) == [f"{path}: frame 4: {ERROR_FRAME}", f"{path}: frame 9: {ERROR_FRAME}"]
    with pytest.raises(TraceError) as err:
        list(iter_trace(path))
    assert str(err.value) == f"{path}: frame 4: {ERROR_FRAME}"
    left_out: dict[str, list[int]] = {}
    read = [(line, t_ns - 1_700_000_000_000_000_000, frame.data[0]) for line, t_ns, _, frame in
            iter_trace(path, left_out=left_out)]
    assert read == [(line, k * 10_000_000, k) for k, line in enumerate([1, 2, 3, 5, 6, 7, 8, 10, 11, 12])]
    assert left_out == {ERROR_KIND: [4, 9]}
    # the events with their own stamps and channels (python-can's from 0), the frames as python-can reads them
    mine = list(BLFReader(str(path)))
    assert [(round(m.timestamp - T0, 6), m.channel) for m in mine if m.is_error_frame] == [(0.025, 0), (0.065, 1)]
    assert as_read(m for m in mine if not m.is_error_frame) == as_read(can.BLFReader(str(path)))


@pytest.mark.parametrize("container", [128 * 1024, 80])
def test_blf_error_frames_of_a_can_fd_channel_are_refused_and_counted_not_skipped(tmp_path, container):
    # CANoe and CANalyzer store an error frame on a channel in CAN FD mode (which carries classic
    # frames too) as CAN_FD_ERROR_64, which python-can's reader passes over without a word
    path = tmp_path / "drive.blf"
    records = ten_frames()
    records[3] = (CAN_FD_ERROR_64, T0 + 0.025, 1, 1)
    records[8] = (CAN_FD_ERROR_64, T0 + 0.065, 2, 2)
    blf_with(path, records, container)
    left_out: dict[str, list[int]] = {}
    assert [line for line, _, _, _ in iter_trace(path, left_out=left_out)] == [1, 2, 3, 5, 6, 7, 8, 10, 11, 12]
    assert left_out == {ERROR_KIND: [4, 9]}
    mine = list(BLFReader(str(path)))
    assert [(round(m.timestamp - T0, 6), m.channel) for m in mine if m.is_error_frame] == [(0.025, 0), (0.065, 1)]


def test_summarise_and_scaffold_count_a_blfs_can_error_objects(tmp_path, capsys):
    path = tmp_path / "drive.blf"
    blf_with(path, ten_frames(), 80)
    s = authoring.summarise(path)
    assert s.frames == 10 and s.left_out == {ERROR_KIND: [4, 9]}
    assert ("2 error frames (the first: frame 4) of drive.blf not replayed: the bridge carries CAN 2.0 data and "
            "remote frames only") in s.table()
    assert cli.main(["scaffold", str(path), "--name", "drive", "--out", str(tmp_path / "sc" / "drive.yaml")]) == 0
    assert "Left out: 2 error frames (the first: frame 4) of drive.blf" in capsys.readouterr().out


@pytest.mark.parametrize("container", [128 * 1024, 80])
def test_a_blf_without_them_reads_as_python_can_reads_it(tmp_path, container):
    # what python-can reads itself (an error frame as its CAN_ERROR_EXT, a CAN FD frame) and skips
    # (a marker), in its writer's containers: the same messages, numbered as before
    path = tmp_path / "t.blf"
    writer = can.BLFWriter(str(path), max_container_size=container)
    for k in range(20):
        writer.on_message_received(can.Message(timestamp=T0 + k * 0.01, arbitration_id=0x100 + k, data=bytes([k] * 8),
                                               is_extended_id=k % 3 == 0, channel=k % 2))
        if k == 5:
            writer.log_event("marker", T0 + k * 0.01 + 0.001)
        if k == 8:
            writer.on_message_received(can.Message(timestamp=T0 + k * 0.01 + 0.002, arbitration_id=0x4, dlc=8,
                                                   is_error_frame=True, data=bytes(8), channel=0))
        if k == 12:
            writer.on_message_received(can.Message(timestamp=T0 + k * 0.01 + 0.003, arbitration_id=0x456,
                                                   is_fd=True, data=bytes(12), channel=0))
    writer.stop()
    assert as_read(BLFReader(str(path))) == as_read(can.BLFReader(str(path)))
    left_out: dict[str, list[int]] = {}
    assert [line for line, _, _, _ in iter_trace(path, left_out=left_out)] == [*range(1, 10), *range(11, 15),
                                                                              *range(16, 23)]
    assert left_out == {ERROR_KIND: [10], FD_KIND: [15]}


def test_python_can_blf_internals_it_relies_on(tmp_path):
    # canbench.blf.BLFReader puts the objects python-can passes over among its frames by two
    # internals of python-can's BLFReader. If this fails after upgrading python-can, mend
    # canbench/blf.py to the new reader (or drop it, if python-can reads CAN_ERROR objects itself).
    path = tmp_path / "t.blf"
    blf_with(path, ten_frames(), 80)
    calls: list[tuple[bytes, list[tuple[int, can.Message | None]]]] = []

    class Watched(blf.BLFReader):
        def _parse_data(self, data):
            seen: list[tuple[int, can.Message | None]] = []
            calls.append((data, seen))
            try:
                for msg in super()._parse_data(data):
                    seen.append((self._pos, msg))
                    yield msg
            finally:
                seen.append((self._pos, None))  # where it stopped: the rest is left for the next container

    reader = Watched(str(path))
    read = list(reader)
    # it still passes over them, and reads every frame through _parse_data
    assert len(read) == 10 and not any(m.is_error_frame for m in read)
    assert [m for _, seen in calls for _, m in seen if m is not None] == read
    left = b""
    for data, seen in calls:
        # each container's data follows what the one before left (an object that goes on in it)
        assert data.startswith(left)
        # at each frame, self._pos is where the frame's object starts (but for padding): the objects
        # before it are passed
        for pos, msg in seen[:-1]:
            start = data.find(b"LOBJ", pos, pos + 8)
            _, _, version, _, kind = blf.OBJ_HEADER_BASE_STRUCT.unpack_from(data, start)
            stamp_ns = blf.OBJ_HEADER_V1_STRUCT.unpack_from(data, start + blf.OBJ_HEADER_BASE_STRUCT.size)[3]
            assert msg is not None and (version, kind) == (1, blf.CAN_MESSAGE)
            assert msg.timestamp == pytest.approx(reader.start_timestamp + stamp_ns / 1e9, abs=1e-6)
        left = data[seen[-1][0]:]
    assert any(data[seen[-1][0]:] for data, seen in calls[:-1])  # objects did span containers
