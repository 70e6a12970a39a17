"""One bus stamp per frame (issue 18 item 1), as kernel vcan gives it: every
reader of a frame, the sender's own echo included, sees the same stamp however
it asks (candump -L: SO_TIMESTAMP; python-can: SO_TIMESTAMPNS; a C program:
SIOCGSTAMP, SIOCGSTAMPNS, SCM_TIMESTAMPNS), taken between the send and the
first receipt. Runs on kernel vcan too, where it holds by construction."""
from __future__ import annotations

import json
import subprocess
import time

import pytest
from test_conformance import pycan_messages, start_candump, start_pycan, stop
from test_preload_probe import expect, finish, start_probe

pytestmark = pytest.mark.bus


def candump_stamps_us(out: str) -> list[int]:
    """candump -L '(1700000000.123456) vcan0 123#11': the stamp in microseconds."""
    return [int(line[1:line.index(")")].replace(".", "")) for line in out.splitlines() if line.startswith("(")]


def probe_stamp_ns(line: str) -> int:
    sec, nsec = line.split()[1].split(".")
    return int(sec) * 1_000_000_000 + int(nsec)


def test_every_reader_sees_the_one_stamp_of_a_frame(bus):
    probe = start_probe(bus, "stamp", "vcan0")
    lines = expect(probe, "ready")
    pycan = start_pycan(bus, "--count", "2")
    dump = start_candump(bus, "-L", "vcan0", count=2)

    before_1 = time.time_ns()
    bus.run(["cansend", "vcan0", "123#01"])
    lines += expect(probe, "ready")
    after_1 = time.time_ns()
    before_2 = time.time_ns()
    echo = bus.python("send", "--own", "--frames", json.dumps([{"id": 0x124, "data": "02"}]))
    own = pycan_messages(echo, 1)
    lines = finish(probe, lines)
    after_2 = time.time_ns()

    probe_ns = [probe_stamp_ns(line) for line in lines if line.startswith("stamp ")]
    dump_us = candump_stamps_us(stop(dump)[0])
    pycan_s = [m["ts"] for m in pycan_messages(pycan, 2)]
    assert len(probe_ns) == 2 and len(dump_us) == 2, (lines, dump_us)
    assert before_1 <= probe_ns[0] <= after_1 and before_2 <= probe_ns[1] <= after_2, (probe_ns, before_1, after_2)
    seen = {"candump -L (SO_TIMESTAMP)": [us * 1000 for us in dump_us],
            "python-can (SO_TIMESTAMPNS)": [round(s * 1e9) for s in pycan_s],
            "C program (SIOCGSTAMPNS, SCM_TIMESTAMPNS)": probe_ns}
    for reader, stamps in seen.items():  # candump has microseconds, python-can a float: within 1 us
        assert [abs(a - b) < 1000 for a, b in zip(stamps, probe_ns, strict=True)] == [True, True], (reader, seen)
    assert abs(round(own[0]["ts"] * 1e9) - probe_ns[1]) < 1000, ("the sender's own echo", own, probe_ns)


def test_plain_read_of_a_bare_frame_still_works_without_stamps(bus):
    """Programs that ask for no stamp get bare 16-byte frames on read() (no header)."""
    proc = bus.popen([bus.tool("plain_socketcan"), "recv", "vcan0", "1", "005"])
    assert proc.stdout.readline().strip() == "ready"
    bus.run(["cansend", "vcan0", "005#0102"])
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert out.strip() == "005 2 01 02"


def test_cansend_stamps_do_not_decrease(bus):
    dump = start_candump(bus, "-L", "vcan0", count=200)
    subprocess.run(["cangen", "vcan0", "-g", "0", "-n", "200"], env=bus.env, check=True, timeout=60)
    stamps = candump_stamps_us(stop(dump)[0])
    assert len(stamps) == 200 and stamps == sorted(stamps)
