"""Recordings in every format the bench reads, written by python-can's writers or by hand as
an integration engineer's tools leave them: each is read right or refused with file:line
(text formats) or 'frame N' (binary ones), never read as something else: a CAN FD frame is
not cut to 8 bytes, an error frame is not a data frame, a mangled line is not skipped."""
from __future__ import annotations

from pathlib import Path

import can
import pytest

from canbench import cli, validate
from canbench.errors import TraceError
from canbench.trace import ERROR_FRAME, iter_trace, read_trace

pytestmark = pytest.mark.unit

T0 = 1_700_000_000.0


def classic(n: int = 5) -> list[can.Message]:
    return [can.Message(timestamp=T0 + k * 0.01, arbitration_id=0x123, is_extended_id=False, data=bytes([k, 1]),
                        channel=0) for k in range(n)]


def written(path: Path, messages: list[can.Message]) -> Path:
    with can.Logger(str(path)) as log:
        for m in sorted(messages, key=lambda m: m.timestamp):
            log.on_message_received(m)
    return path


def problems(path: Path) -> list[str]:
    found: list[TraceError] = []
    list(iter_trace(path, on_problem=found.append))
    return [str(e) for e in found]


FD = can.Message(timestamp=T0 + 0.015, arbitration_id=0x456, is_extended_id=False, is_fd=True, bitrate_switch=True,
                 data=bytes(range(12)), channel=0)
ERROR = can.Message(timestamp=T0 + 0.025, arbitration_id=0x4, is_error_frame=True, dlc=8, data=bytes(8), channel=0)


@pytest.mark.parametrize("suffix,where", [(".asc", "{path}:8: "), (".blf", "{path}: frame 3: ")])
def test_a_can_fd_frame_is_refused_not_cut_to_eight_bytes(tmp_path, suffix, where):
    path = written(tmp_path / f"fd{suffix}", [*classic(), FD])
    with pytest.raises(TraceError) as err:
        read_trace(path)
    assert str(err.value) == (where.format(path=path) + "a CAN FD frame (12 data bytes, BRS): the bridge carries "
                              "CAN 2.0 frames only (remove FD frames from the trace: canbench scaffold leaves "
                              "them out of the trace it writes)")


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".csv"])
def test_an_error_frame_is_refused_not_replayed_as_a_data_frame(tmp_path, suffix):
    path = written(tmp_path / f"err{suffix}", [*classic(), ERROR])
    found = problems(path)
    assert len(found) == 1 and "an error frame: the bridge carries CAN 2.0 data and remote frames only" in found[0]


def test_a_csv_frame_of_more_than_eight_bytes_is_a_can_fd_frame(tmp_path):
    path = written(tmp_path / "fd.csv", [*classic(), FD])  # python-can's CSV has no FD flag: 12 bytes, dlc 12
    assert problems(path) == [f"{path}:4: a CAN FD frame (12 data bytes): the bridge carries CAN 2.0 frames "
                              "only (remove FD frames from the trace: canbench scaffold leaves them out of the "
                              "trace it writes)"]
    left_out: dict[str, list[int]] = {}
    assert len(list(iter_trace(path, left_out=left_out))) == 5 and left_out == {"CAN FD frame": [4]}


TRC = """;$FILEVERSION=2.0
;$STARTTIME=45244.92592592593
;$COLUMNS=N,O,T,I,d,l,D
      1         0.000 DT     0123 Rx 8  00 01 02 03 04 05 06 07
      2        10.000 DT     0123 Rx 8  00 01 02 03 04 05 06 07
      3        15.000 ER     0000 Rx 0
      4        17.000 ST     0000 Rx 0
      5        18.000 RR     07E0 Rx 3
      6        20.000 DT     0123 Rx 8  00 01 02 03 04 05 06 07
garbage at the end
"""


def test_trc_error_frames_and_unreadable_lines_are_named_with_their_line(tmp_path):
    path = tmp_path / "drive.trc"
    path.write_text(TRC)
    assert problems(path) == [
        f"{path}:6: {ERROR_FRAME}",
        f"{path}:10: not a TRC frame (record type 'the'): 'garbage at the end'",
    ]
    frames = [(line, t_ns, frame.candump()) for line, t_ns, _, frame in iter_trace(path, on_problem=lambda e: None)]
    # the bus status record (ST) is no frame; the stamps are the file's, to the microsecond
    assert [(line, frame) for line, _, frame in frames] == [
        (4, "vcan0 123#0001020304050607"), (5, "vcan0 123#0001020304050607"), (8, "vcan0 7E0#R3"),
        (9, "vcan0 123#0001020304050607")]
    assert [t_ns - frames[0][1] for _, t_ns, _ in frames] == [0, 10_000_000, 18_000_000, 20_000_000]


def test_text_formats_name_the_file_line_of_each_problem(tmp_path):
    path = written(tmp_path / "two.asc", [*classic(), FD, ERROR])
    lines = path.read_text().splitlines()
    found = problems(path)
    assert [int(p.split(":")[1]) for p in found] == [
        n for n, text in enumerate(lines, 1) if "CANFD" in text or "ErrorFrame" in text]


def test_python_can_formats_going_back_in_time_are_refused(tmp_path):
    path = tmp_path / "back.csv"
    path.write_text("timestamp,arbitration_id,extended,remote,error,dlc,data\n"
                    "1700000000.0,0x123,0,0,0,1,AQ==\n1700000000.01,0x123,0,0,0,1,AQ==\n"
                    "1699999999.0,0x123,0,0,0,1,AQ==\n1699999999.1,0x123,0,0,0,1,AQ==\n")
    # the jump back is one problem with its stamps; the lines after it go on from it (a PCAN clock
    # that wrapped once was one problem per line after it)
    assert problems(path) == [f"{path}:4: timestamp earlier than the line before "
                              "(1699999999.000000 s after 1700000000.010000 s)"]


GOOD = "(1700000000.000000) can0 123#11\n(1700000000.010000) can0 123#22\n"


def test_a_byte_order_mark_does_not_hide_the_first_frame(tmp_path):
    path = tmp_path / "bom.log"
    path.write_bytes(b"\xef\xbb\xbf" + GOOD.replace("\n", "\r\n").encode())
    assert [(line, frame.data) for line, _, _, frame in iter_trace(path)] == [(1, b"\x11"), (2, b"\x22")]


def test_a_candump_line_that_is_not_a_frame_is_refused_not_skipped(tmp_path):
    path = tmp_path / "tail.log"
    path.write_text("# recorded on the test track\n\n" + GOOD + "this is garbage\nDROPCOUNT: dropped 2 CAN frames on "
                    "'can0' socket (total drops 2)\n")
    assert problems(path) == [f"{path}:5: not a candump -L frame: 'this is garbage'"]


def test_a_remote_frame_of_dlc_nine_is_refused(tmp_path):
    path = tmp_path / "rtr.log"
    path.write_text(GOOD + "(1700000000.020000) can0 123#R9\n(1700000000.030000) can0 123#R8\n")
    assert problems(path) == [f"{path}:3: remote frame dlc 9: classic CAN's is 0..8"]


ASC_HEAD = "date Thu Apr 28 10:44:52.480 am 2022\nbase hex  timestamps absolute\ninternal events logged\n"


def test_a_classic_frame_of_a_raw_dlc_above_eight_is_refused_with_the_dlc_the_file_has(tmp_path):
    # CANalyzer records a classic frame's raw DLC code (D: 8 bytes); python-can reads the code as
    # CAN FD's length for it (32), which the bench said as 'dlc 32 ... a CAN FD frame?'
    asc = tmp_path / "dlc.asc"
    asc.write_text(ASC_HEAD + "  13.258199 1  180             Tx   d 8 6A 00 00 00 00 00 00 00  Length = 244016\n"
                   "  13.258671 1  3FF             Tx   d D 55 AA 01 02 03 04 05 06  Length = 232016 ID = 1023\n")
    blf = written(tmp_path / "dlc.blf", [*classic(2), can.Message(
        timestamp=T0 + 0.1, arbitration_id=0x3FF, is_extended_id=False, dlc=13, data=bytes(8), channel=0)])
    said = ("DLC D (13) with 8 data bytes (a CAN 2.0 frame's DLC 9..F carries 8, as a logger records the raw "
            "code): the bench sends DLC 0..8; set the frame's DLC to 8")
    assert problems(asc) == [f"{asc}:5: {said}"]
    assert problems(blf) == [f"{blf}: frame 3: {said}"]


def test_an_unknown_suffix_names_the_formats_and_spots_candump(tmp_path, capsys):
    path = tmp_path / "drive.txt"
    path.write_text(GOOD)
    assert cli.main(["summarise", str(path)]) == 2
    assert capsys.readouterr().err == (
        f"canbench: {path}: unknown trace format '.txt': its lines read as candump -L, rename it drive.log (the "
        "bench reads candump -L (.log, .candump or no suffix), or .asc .blf .csv .trc (python-can; .mf4 with "
        "asammdf))\n")


def test_validate_names_every_bad_frame_of_a_python_can_trace(tmp_path):
    path = written(tmp_path / "many.blf", [*classic(), FD, ERROR])
    assert [str(p).removeprefix(f"{path}: ").split(":")[0] for p in validate.trace_problems(path)] == [
        "frame 3", "frame 5"]


def test_a_cut_blf_is_refused_not_read_to_its_cut(tmp_path):
    whole = written(tmp_path / "whole.blf", [can.Message(timestamp=T0 + k * 0.001, arbitration_id=k % 64,
                                                         is_extended_id=False, data=k.to_bytes(8, "little"), channel=0)
                                             for k in range(100_000)])
    cut = tmp_path / "cut.blf"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    assert len(read_trace(whole)) == 100_000
    with pytest.raises(TraceError) as err:
        read_trace(cut)
    assert str(err.value) == (f"{cut}: truncated: its header says {whole.stat().st_size} bytes, the file has "
                              f"{cut.stat().st_size} (a recording cut short, or an incomplete copy)")


def test_an_empty_trc_has_no_frames(tmp_path):
    path = tmp_path / "empty.trc"
    path.write_text("")
    assert [str(p) for p in validate.trace_problems(path)] == [f"{path}: no frames in trace"]


def test_a_trc_of_only_its_header_has_no_frames(tmp_path):
    # python-can's TRCWriter's header: its last comment line is handed back at the end of the file
    whole = written(tmp_path / "whole.trc", classic())
    lines = whole.read_text().splitlines(keepends=True)
    path = tmp_path / "header.trc"
    path.write_text("".join(line for line in lines if line.startswith(";")))
    assert [str(p) for p in validate.trace_problems(path)] == [f"{path}: no frames in trace"]


@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_channels_are_numbered_as_the_file_numbers_them(tmp_path, suffix):
    # python-can reads the file's channel 1 as 0; CANalyzer, CANoe and the file itself say 1
    path = written(tmp_path / f"two{suffix}", [*classic(), *(can.Message(timestamp=m.timestamp + 0.001,
                   arbitration_id=m.arbitration_id, is_extended_id=False, data=m.data, channel=1) for m in classic())])
    if suffix == ".asc":
        assert {line.split()[1] for line in path.read_text().splitlines() if " 123 " in line} == {"1", "2"}
    assert sorted({iface for _, _, iface, _ in iter_trace(path)}) == ["1", "2"]


def test_a_trc_version_python_can_does_not_read_is_refused_at_its_header(tmp_path):
    path = tmp_path / "v12.trc"
    path.write_text(";$FILEVERSION=1.2\n;$STARTTIME=45244.9\n     1)         0.0  1    Rx         0123  8  00 01\n")
    with pytest.raises(TraceError) as err:
        read_trace(path)
    assert str(err.value) == (f"{path}:1: TRC file version 1.2: python-can reads 1.0, 1.1, 1.3, 2.0, 2.1 "
                              "(PCAN-View saves 2.1)")
    path.write_text("     1)         0.0  1    Rx         0123  8  00 01\n")  # no version: read as 1.0, which fails
    with pytest.raises(TraceError, match=r"v12.trc:1: python-can cannot read it: .* \(the file has no ;\$FILEVERSION"):
        read_trace(path)


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".csv", ".trc"])
def test_an_empty_file_has_no_frames_in_every_format(tmp_path, suffix):
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(TraceError) as err:
        read_trace(path)
    assert str(err.value) == f"{path}: no frames in trace"


def test_a_read_trace_holds_its_frames_in_tens_of_bytes_each(tmp_path):
    # what a replay ECU reads before it starts: as TraceFrames of python-can Messages a 1M-frame trace
    # took 900 MB (canbench validate, the ECU's container), and the 10M-frame limit would need 9 GB
    import tracemalloc
    path = tmp_path / "drive.log"
    n = 50_000
    path.write_text("".join(f"({1_700_000_000 + k / 1000:.6f}) vcan0 {k % 2048:03X}#{k * 7919:016X}\n"
                            for k in range(n)))
    tracemalloc.start()
    try:
        frames = read_trace(path)
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(frames) == n and held < 64 * n, f"{held / n:.0f} bytes a frame"
    last = frames[-1]
    assert (last.line, last.message.arbitration_id, bytes(last.message.data)) == (
        n, (n - 1) % 2048, ((n - 1) * 7919).to_bytes(8, "big"))
