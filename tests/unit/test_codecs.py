"""The bench's one codec per format: candump -L (traces, can.log, send logs) and
zn-capture's TSV, with exact nanosecond stamps and file:line errors."""
from __future__ import annotations

from collections import Counter

import pytest

from canbench import trace, wire
from canbench.capture import Sample, format_sample_line, iter_zenoh_capture, parse_sample_line
from canbench.errors import TraceError

pytestmark = pytest.mark.unit


@pytest.mark.parametrize("line,t_ns,frame", [
    ("(1700000000.123456) vcan0 123#DEADBEEF", 1_700_000_000_123_456_000,
     wire.Frame(0x123, 4, bytes.fromhex("DEADBEEF"))),
    # candump -N style nanoseconds are kept to the nanosecond (a float would lose ~0.2 us)
    ("(1700000000.123456789) vcan1 1ABCDEF0#", 1_700_000_000_123_456_789, wire.Frame(0x1ABCDEF0, 0, b"", True)),
    ("(0.5) can0 7FF#R8", 500_000_000, wire.Frame(0x7FF, 8, b"", False, True)),
    ("(1.000001) can0 000#R", 1_000_001_000, wire.Frame(0, 0, b"", False, True)),
])
def test_candump_line_parses_exactly(line, t_ns, frame):
    assert trace.parse_line(line) == (t_ns, line.split()[1], frame)


def test_format_is_what_the_parser_reads_back_at_microseconds():
    f = wire.Frame(0x0C0, 8, bytes(range(8)))
    line = trace.format_line(1_700_000_000_000_007_999, "vcan0", f)
    assert line == "(1700000000.000007) vcan0 0C0#0001020304050607"
    assert trace.parse_line(line) == (1_700_000_000_000_007_000, "vcan0", f)
    remote = wire.Frame(0x1FFFFFFF, 3, b"", True, True)
    assert trace.parse_line(trace.format_line(5_000, "x", remote))[2] == remote  # the dlc of a remote frame kept


@pytest.mark.parametrize("line,fragment", [
    ("(1.0) vcan0 800#00", "above 7FF"),
    ("(1.0) vcan0 20000001#0000000000000000", "an error frame"),
    ("(1.0) vcan0 123##1DEAD", "CAN FD"),
    ("(1.0) vcan0 123#000102030405060708", "at most 8"),
    ("(1.0) vcan0 12#00", "not a candump -L frame"),
])
def test_bad_lines_name_file_and_line(line, fragment):
    with pytest.raises(TraceError) as err:
        trace.parse_line(line, "can.log", 7)
    assert str(err.value).startswith("can.log:7: ") and fragment in str(err.value)


def test_capture_file_skips_comments_and_counts_candump_drops(tmp_path):
    path = tmp_path / "can.log"
    path.write_text("(1.000001) vcan0 100#01\n"
                    "DROPCOUNT: dropped 3 CAN frames on 'vcan0' socket (total drops 3)\n"
                    "(1.000002) vcan1 100#02\n"
                    "DROPCOUNT: dropped 1 CAN frame on 'vcan0' socket (total drops 4)\n")
    drops: dict[str, int] = {}
    assert [(n, t) for n, t, _, _ in trace.iter_candump(path, "vcan1", drops)] == [(3, 1_000_002_000)]
    assert drops == {"vcan0": 4}


def test_send_log_frame_text_is_the_candump_frame_part():
    f = wire.Frame(0x18FF00AA, 2, b"\x01\x02", True)
    assert trace.parse_frame_text(f.candump("can3")) == ("can3", f)
    with pytest.raises(TraceError, match="ecu.sent.tsv:2: not a frame"):
        trace.parse_frame_text("can3 18FF00AA-0102", "ecu.sent.tsv", 2)


def test_id_hex_is_candumps():
    assert (wire.id_hex(0x5, False), wire.id_hex(0x5, True)) == ("005", "00000005")


def test_zenoh_capture_line_round_trip(tmp_path):
    batch = wire.encode(wire.Frame(0x100, 1, b"\x07")) + wire.encode(wire.Frame(0x101, 0))
    samples = [Sample(1_700_000_000_000_000_123, "vehicle/can/rx", batch, wire.encode_attachment(9, [1, 2])),
               Sample(5, "vehicle/can/tx", b"\x00" * 16, None)]
    path = tmp_path / "zenoh.tsv"
    path.write_text("".join(format_sample_line(s) for s in samples))
    assert list(iter_zenoh_capture(path)) == samples
    assert parse_sample_line(format_sample_line(samples[1])).attachment is None
    path.write_text(format_sample_line(samples[0]) + "12\tkey\tzz\n")
    with pytest.raises(ValueError, match="zenoh.tsv:2: not a zn-capture line"):
        list(iter_zenoh_capture(path))


def test_the_running_capture_counts_frames_and_ids_as_it_grows(tmp_path):
    from canbench.capture import ZenohCapture
    path = tmp_path / "zenoh.tsv"
    cap = ZenohCapture.__new__(ZenohCapture)  # its counters without a zn-capture process
    cap.path, cap._offset, cap._partial, cap._samples = path, 0, b"", 0
    cap._decoded, cap._frames, cap._ids = {}, Counter(), {}
    two = wire.encode(wire.Frame(0x100, 1, b"\x07")) + wire.encode(wire.Frame(0x18FF0001, 0, b"", True))
    line = format_sample_line(Sample(1, "vehicle/can/rx", two, None))
    path.write_text(line + line[:20])  # the second line still being written
    assert cap.frames_on({"vehicle/can/rx"}) == 2
    with open(path, "a") as f:
        f.write(line[20:] + format_sample_line(Sample(2, "vehicle/can/tx", b"\x01" * 16, None)))  # not a frame
    assert cap.frames_on({"vehicle/can/rx", "vehicle/can/tx"}) == 5
    assert cap.frames_with_ids({"vehicle/can/rx": {0x100, 0x18FF0001}, "vehicle/can/tx": {1}}) == 4
