"""Conformance of the CAN bus the bench runs on: unmodified can-utils,
python-can and a plain C program must see kernel vcan semantics. Runs on kernel
vcan where the kernel has it and on the userspace hub otherwise; tests of
hub-only features say so when skipped."""
from __future__ import annotations

import itertools
import json
import os
import random
import signal
import socket
import struct
import subprocess
import sys
import time

import pytest
from conftest import Bus, require_userspace, wait_for

# a bound, reached only by a failure: Python under the real-kernel lane's emulation on a loaded
# machine once took over 30 s to send one frame
WAIT_S = 90
# cangen -g 1 -c 50: 50k frames/s; the real-kernel lane runs under CPU emulation (about
# ten times slower), where it sends a tenth of the frames at a tenth of the rate (ucan/vm/vcan-vm sets VCANVM)
SEQUENCE_FRAMES = 10_000 if os.environ.get("VCANVM") else 100_000
SEQUENCE_RATE_PER_MS = 5 if os.environ.get("VCANVM") else 50


def start_candump(bus: Bus, *args: str, readers: int = 1, count: int | None = None,
                  prefix: tuple[str, ...] = ()) -> subprocess.Popen:
    """candump writing to a file: a pipe nobody reads yet would stall it after 64 KiB.
    count: candump exits by itself after that many frames, so stopping it never races
    the delivery of the last frame (a SIGINT can end it before it read a queued frame)."""
    before = bus.receivers()
    out = open(bus.workdir / f"candump-{len(list(bus.workdir.glob('candump-*')))}.log", "w+")
    limit = ("-n", str(count)) if count is not None else ()
    proc = bus.popen([*prefix, "candump", *limit, *args], stdout=out)
    proc.output_file = out  # type: ignore[attr-defined]
    bus.wait_receivers(before + readers)
    return proc


def stop(proc: subprocess.Popen, sig: int = signal.SIGINT) -> tuple[str, str]:
    if "-n" in proc.args:  # it stops by itself after its count; wait for that
        try:
            proc.wait(timeout=WAIT_S)
        except subprocess.TimeoutExpired:
            pass  # fewer frames than expected: stop it and let the assertion show what came
    if proc.poll() is None:
        proc.send_signal(sig)
    out, err = proc.communicate(timeout=WAIT_S)
    output_file = getattr(proc, "output_file", None)
    if output_file is not None:
        output_file.seek(0)
        out = output_file.read()
        output_file.close()
    return out, err


def candump_frames(out: str) -> list[str]:
    """candump -L lines without the timestamp: 'vcan0 123#DEADBEEF'."""
    return [line.split(" ", 1)[1] for line in out.splitlines() if line.startswith("(")]


def start_pycan(bus: Bus, *args: str) -> subprocess.Popen:
    return start_pycan_proc(bus, "recv", *args)


def start_pycan_proc(bus: Bus, *args: str) -> subprocess.Popen:
    proc = bus.python(*args)
    assert proc.stdout is not None
    line = proc.stdout.readline().strip()
    assert line == "ready", proc.stderr.read() if proc.stderr else line
    return proc


def start_pycan_readers(bus: Bus, *specs: dict) -> subprocess.Popen:
    """Several python-can readers (each its own can.Bus) in one process: see pycan_helper."""
    return start_pycan_proc(bus, "readers", "--specs", json.dumps(specs))


def pycan_reader_messages(proc: subprocess.Popen, *counts: int) -> list[list[dict]]:
    msgs = pycan_messages(proc, sum(counts))
    return [[m for m in msgs if m["reader"] == i] for i in range(len(counts))]


def pycan_messages(proc: subprocess.Popen, count: int) -> list[dict]:
    out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    msgs = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    assert len(msgs) == count, (msgs, err)
    return msgs


ALL_KINDS = ["123#DEADBEEF", "12345678#0102030405060708", "7FF#R", "0AA#R3", "000#",
             "1AB##1" + "11" * 12, "1FFFFFFF#FF"]


# -- can-utils ----------------------------------------------------------------

def test_cansend_to_candump_every_frame_kind_in_order(bus):
    dump = start_candump(bus, "-L", "vcan0", count=len(ALL_KINDS))
    for frame in ALL_KINDS:
        bus.run(["cansend", "vcan0", frame])
    bus.run(["cansend", "vcan1", "321#01"])  # other interface: not seen
    out, _ = stop(dump)
    # the kernel (>= 6.0) sets CANFD_FDF (4) in every FD frame's flags: 1AB##1... is received as 1AB##5...
    expected = [f.replace("##1", "##5") for f in ALL_KINDS]
    assert candump_frames(out) == [f"vcan0 {f}" for f in expected]


def test_candump_any_names_the_interface_of_each_frame(bus):
    dump = start_candump(bus, "-ta", "-x", "any", count=2)
    bus.run(["cansend", "vcan0", "100#01"])
    bus.run(["cansend", "vcan1", "200#02"])
    out, _ = stop(dump)
    lines = [line.split() for line in out.splitlines() if line.strip()]
    assert [(parts[1], parts[5]) for parts in lines] == [("vcan0", "100"), ("vcan1", "200")]
    # vcan marks every frame as locally generated: candump -x shows TX
    assert all(parts[2] == "TX" for parts in lines)


def test_canplayer_replays_with_recorded_timing_and_remapping(bus, tmp_path):
    log = tmp_path / "trace.log"
    gaps_s = [0.0, 0.05, 0.10, 0.20]
    log.write_text("".join(f"({1000 + t:.6f}) can1 {0x100 + i:03X}#{i:02X}\n" for i, t in enumerate(gaps_s)))
    dump = start_candump(bus, "-L", "vcan0", count=4)
    bus.run(["canplayer", "-I", str(log), "vcan0=can1"])
    out, _ = stop(dump)
    lines = [line for line in out.splitlines() if line.startswith("(")]
    assert [line.split(" ", 1)[1] for line in lines] == [f"vcan0 {0x100 + i:03X}#{i:02X}" for i in range(4)]
    stamps = [float(line[1:line.index(")")]) for line in lines]
    # canplayer paces every frame from its first one, whose write may itself be late (7 ms under
    # the kernel lane's emulation: every later gap from it came out 7 ms short, each exact from
    # the second frame on): the recorded timing is judged from the second frame on
    spans = [b - stamps[1] for b in stamps[1:]]
    recorded_spans = [g - gaps_s[1] for g in gaps_s[1:]]
    for recorded, replayed in zip(recorded_spans, spans, strict=True):
        assert recorded - 0.005 <= replayed < recorded + 0.05, (gaps_s, stamps)
    assert 0 <= stamps[1] - stamps[0] < gaps_s[1] + 0.05, (gaps_s, stamps)


def test_cansequence_50k_frames_per_second_no_loss_no_reordering(bus):
    checker = start_candump(bus, "-L", "vcan0", count=SEQUENCE_FRAMES)
    seq = bus.popen(["cansequence", "-r", "-q1", "vcan0"])  # -q takes its number attached
    bus.wait_receivers(2)
    bus.run(["cangen", "vcan0", "-I", "2", "-L", "8", "-D", "i", "-g", "1", "-c", str(SEQUENCE_RATE_PER_MS),
             "-n", str(SEQUENCE_FRAMES), "-p", "100"], timeout=120)
    out, _ = stop(checker)
    still_running = seq.poll() is None  # cansequence -q 1 exits at the first wrong sequence number
    seq_out, seq_err = stop(seq)
    assert still_running, seq_out + seq_err
    frames = candump_frames(out)
    assert len(frames) == SEQUENCE_FRAMES
    counters = [int.from_bytes(bytes.fromhex(f.split("#")[1]), "little") for f in frames]
    assert counters == list(range(SEQUENCE_FRAMES))


# -- python-can and a plain C program ----------------------------------------

def test_pycan_filters_rtr_eff_inverted_and_join(bus):
    sff_only = [{"can_id": 0x123, "can_mask": 0x7FF | 0x80000000 | 0x40000000}]  # EFF|RTR in mask
    inverted = [{"can_id": 0x123 | 0x20000000, "can_mask": 0x7FF}]  # CAN_INV_FILTER
    joined = [{"can_id": 0x100, "can_mask": 0x700}, {"can_id": 0x010, "can_mask": 0x0F0}]
    readers = start_pycan_readers(bus, {"count": 1, "filters": sff_only}, {"count": 3, "filters": inverted},
                                  {"count": 1, "filters": joined, "join": True})
    for frame in ["123#R", "12345123#01", "123#01", "124#02", "110#03", "777#04"]:
        bus.run(["cansend", "vcan0", frame])
    got = [[(m["id"], m["ext"], m["rtr"]) for m in msgs] for msgs in pycan_reader_messages(readers, 1, 3, 1)]
    assert got[0] == [(0x123, False, False)]
    # inverted: everything whose low 11 bits are not 0x123 (the EFF and RTR 0x123 frames match, so are out)
    assert got[1] == [(0x124, False, False), (0x110, False, False), (0x777, False, False)]
    assert got[2] == [(0x110, False, False)]


def test_pycan_own_messages_fd_and_timestamps(bus):
    other = start_pycan(bus, "--count", "2", "--fd")
    frames = [{"id": 0x123, "data": "0102"}, {"id": 0x1AB, "data": "00" * 12, "fd": True}]
    sender = bus.python("send", "--fd", "--own", "--frames", json.dumps(frames))
    own = pycan_messages(sender, 2)
    seen = pycan_messages(other, 2)
    assert [(m["id"], m["fd"], m["data"]) for m in own] == [(0x123, False, "0102"), (0x1AB, True, "00" * 12)]
    assert [(m["id"], m["fd"], m["data"]) for m in seen] == [(0x123, False, "0102"), (0x1AB, True, "00" * 12)]
    # vcan marks every looped-back frame MSG_DONTROUTE, which python-can reports as is_rx False
    assert not any(m["is_rx"] for m in own + seen)
    for m in own + seen:  # SO_TIMESTAMPNS: stamped on the bus, not zero
        assert abs(m["ts"] - seen[0]["ts"]) < 5.0


def test_own_frames_come_back_with_msg_confirm(bus):
    code = (
        "import socket\n"
        "def sock(own):\n"
        "    s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "    s.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_RECV_OWN_MSGS, own)\n"
        "    s.bind(('vcan0',)); return s\n"
        "a, b = sock(1), sock(0)\n"
        "a.send(bytes([0x23, 1, 0, 0, 1, 0, 0, 0]) + bytes(8))\n"
        "for s in (a, b):\n"
        "    data, anc, flags, addr = s.recvmsg(16)\n"
        "    print(addr[0], data[:2].hex(), bool(flags & socket.MSG_CONFIRM), bool(flags & socket.MSG_DONTROUTE))\n"
    )
    out = bus.run([sys.executable, "-c", code]).stdout.splitlines()
    assert out == ["vcan0 2301 True True", "vcan0 2301 False True"]


def test_pycan_any_channel_reports_interface(bus):
    reader = start_pycan(bus, "--channel", "", "--count", "2")
    bus.run(["cansend", "vcan1", "101#01"])
    bus.run(["cansend", "vcan0", "100#00"])
    msgs = pycan_messages(reader, 2)
    assert [(m["channel"], m["id"]) for m in msgs] == [("vcan1", 0x101), ("vcan0", 0x100)]


def test_plain_c_program_sends_and_filters(bus):
    reader = bus.popen([bus.tool("plain_socketcan"), "recv", "vcan0", "1", "005"])
    assert reader.stdout.readline().strip() == "ready"
    bus.run([bus.tool("plain_socketcan"), "send", "vcan0", "10"])
    out, err = reader.communicate(timeout=WAIT_S)
    assert reader.returncode == 0, err
    assert out.strip() == "005 8 05 00 00 00 00 00 00 00"


def test_fd_frames_need_fd_mtu_interface(bus):
    ok = bus.run(["cansend", "vcan0", "123##1" + "AA" * 16], check=False)
    assert ok.returncode == 0, ok.stderr
    classic_only = bus.run(["cansend", "vcan2", "123##1" + "AA" * 16], check=False)
    assert classic_only.returncode != 0
    assert "not CAN FD capable" in classic_only.stdout + classic_only.stderr
    # classic frames still fine there
    bus.run(["cansend", "vcan2", "123#AA"])


def test_error_frames_only_reach_readers_with_an_error_mask(bus):
    readers = start_pycan_readers(bus, {"count": 1}, {"count": 2, "errors": True})
    bus.run(["cansend", "vcan0", "20000004#0004000000000000"])  # CAN_ERR_CRTL, rx warning
    bus.run(["cansend", "vcan0", "111#11"])
    plain, msgs = pycan_reader_messages(readers, 1, 2)
    assert [m["id"] for m in plain] == [0x111]
    assert msgs[0]["err"] and msgs[0]["id"] == 0x4 and not msgs[1]["err"]


def test_wrong_frame_sizes_are_refused_with_einval(bus):
    code = (
        "import socket, errno\n"
        "s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "s.bind(('vcan0',))\n"
        "for size in (0, 8, 15, 17, 72, 100):\n"
        "    try:\n"
        "        s.send(bytes(size)); print(size, 'sent')\n"
        "    except OSError as e:\n"
        "        print(size, errno.errorcode[e.errno])\n"
        "bad_dlc = bytes([1,0,0,0, 9,0,0,0]) + bytes(8)\n"
        "try:\n"
        "    s.send(bad_dlc); print('dlc9 sent')\n"
        "except OSError as e:\n"
        "    print('dlc9', errno.errorcode[e.errno])\n"
    )
    out = bus.run([sys.executable, "-c", code]).stdout.split("\n")
    # 72 bytes without CAN_RAW_FD_FRAMES is refused like any other wrong size
    assert out[:7] == ["0 EINVAL", "8 EINVAL", "15 EINVAL", "17 EINVAL", "72 EINVAL", "100 EINVAL", "dlc9 EINVAL"]


# -- slow readers, namespaces, failures (userspace hub behaviour) -------------

def test_slow_reader_loses_frames_counted_without_slowing_others(bus):
    require_userspace(bus, "drop counters come from ucanctl")
    stalled = start_candump(bus, "vcan0")
    stalled.send_signal(signal.SIGSTOP)
    healthy = start_candump(bus, "-L", "vcan0", count=20_000)
    total = 20_000  # paced at 20k frames/s: the healthy reader keeps up, the stalled one overflows
    bus.run(["cangen", "vcan0", "-I", "7", "-L", "8", "-D", "i", "-g", "1", "-c", "20", "-n", str(total),
             "-p", "100"], timeout=120)
    out, _ = stop(healthy)
    assert len(candump_frames(out)) == total
    stats = bus.stats()
    drops = {c["pid"]: c["rx_drops"] for c in stats["clients"]}
    assert drops[stalled.pid] > 0
    assert stats["interfaces"][0]["rx_drops"] == drops[stalled.pid]
    # a reader's counters go with it: the hub says its drops when it is gone (a restarted bridge's too)
    stalled.kill()
    stalled.wait()
    said = f"(pid {stalled.pid}, ucan/{stalled.pid}/"
    closed = wait_for(lambda: [ln for ln in bus.hub_log.read_text().splitlines() if said in ln and "closed" in ln],
                      "the hub's line on the stalled reader's close")
    assert closed[0].endswith(f"; {drops[stalled.pid]} frames dropped for it (queue full)"), closed


def test_two_network_namespaces_share_one_bus(bus):
    require_userspace(bus, "kernel vcan is per network namespace")
    if subprocess.run(["unshare", "-n", "true"], capture_output=True).returncode != 0:
        pytest.skip("unshare -n not permitted here (needs CAP_SYS_ADMIN)")
    dump = start_candump(bus, "-L", "vcan0", count=1, prefix=("unshare", "-n"))
    bus.run(["unshare", "-n", "cansend", "vcan0", "42A#2A"])
    out, _ = stop(dump)
    assert candump_frames(out) == ["vcan0 42A#2A"]


def test_hub_down_gives_enodev_and_one_line_naming_the_socket(bus):
    require_userspace(bus, "hub failure modes")
    bus.stop_hub()
    rc = bus.run(["cansend", "vcan0", "123#00"], check=False)
    assert rc.returncode != 0
    hub_lines = [line for line in rc.stderr.splitlines() if line.startswith("ucan:")]
    assert len(hub_lines) == 1 and str(bus.workdir / "hub.sock") in hub_lines[0], rc.stderr
    code = "import socket\ns = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\ns.bind(('vcan0',))"
    py = bus.run([sys.executable, "-c", code], check=False)
    assert "No such device" in py.stderr


def test_hub_death_gives_network_down_and_restart_replaces_stale_socket(bus):
    require_userspace(bus, "hub failure modes")
    dump = start_candump(bus, "vcan0")
    bus.stop_hub(signal.SIGKILL)  # leaves hub.sock behind
    _, err = dump.communicate(timeout=WAIT_S)
    assert dump.returncode == 1 and "Network is down" in err
    assert (bus.workdir / "hub.sock").exists()
    bus.start_hub()
    assert "replaced stale socket" in bus.hub_log.read_text()
    dump = start_candump(bus, "-L", "vcan0", count=1)
    bus.run(["cansend", "vcan0", "123#01"])
    out, _ = stop(dump)
    assert candump_frames(out) == ["vcan0 123#01"]


def test_hub_survives_garbage_and_keeps_serving(bus):
    require_userspace(bus, "hub protocol robustness")
    dump = start_candump(bus, "-L", "vcan0", count=1)
    rng = random.Random(1234)
    path = str(bus.workdir / "hub.sock")
    payloads = [b"", b"\x01", struct.pack("<I", 12) + b"\xff" * 30, struct.pack("<II", 10, 0xFFFFFFFF) + bytes(20),
                struct.pack("<I", 14) + b"x" * 64] + [rng.randbytes(rng.randrange(1, 200)) for _ in range(300)]
    for payload in payloads:
        with socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET) as s:
            s.connect(path)
            s.send(payload)
    bus.run(["cansend", "vcan0", "123#01"])
    out, _ = stop(dump)
    assert candump_frames(out) == ["vcan0 123#01"]
    assert bus.hub.poll() is None


def test_dup_and_exec_inheritance_keep_the_socket(bus):
    require_userspace(bus, "fd tracking is the preload library's")
    child = (
        "import socket, sys\n"
        "s = socket.socket(fileno=int(sys.argv[1]))\n"
        "assert s.family == socket.AF_CAN, s.family\n"
        "print(s.getsockname(), s.recv(16).hex(), flush=True)\n"
    )
    parent = (
        "import os, socket, subprocess, sys\n"
        "s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "s.bind(('vcan0',))\n"
        "fd = os.dup(s.fileno()); s.close()\n"
        "print('ready', flush=True)\n"
        f"subprocess.run([sys.executable, '-c', {child!r}, str(fd)], pass_fds=(fd,), check=True)\n"
    )
    proc = bus.popen([sys.executable, "-c", parent])
    assert proc.stdout.readline().strip() == "ready"
    bus.run(["cansend", "vcan0", "123#AB"])
    out, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    assert out.strip() == "('vcan0',) 2301000001000000ab00000000000000"


# -- beyond vcan: bitrate and arbitration -------------------------------------

def test_bitrate_limits_delivery_rate_and_arbitrates_by_id(bus):
    require_userspace(bus, "bitrate emulation is a hub feature")
    bus.stop_hub()
    bus.start_hub("vcan0:bitrate=50000,stuffing=worst")
    dump = start_candump(bus, "-L", "vcan0")
    # two nodes queue 20 frames each while the bus is busy: the lower id wins every slot
    code = (
        "import socket, struct\n"
        "def sock():\n"
        "    s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW); s.bind(('vcan0',)); return s\n"
        "low, high = sock(), sock()\n"
        "for i in range(20): high.send(struct.pack('<IB3x8s', 0x700, 8, bytes(8)))\n"
        "for i in range(20): low.send(struct.pack('<IB3x8s', 0x100, 8, bytes(8)))\n"
    )
    bus.run([sys.executable, "-c", code])
    wait_for(lambda: bus.stats()["interfaces"][0]["frames"] >= 40, "40 frames on the wire")
    out, _ = stop(dump)
    lines = [line for line in out.splitlines() if line.startswith("(")]
    ids = [line.split()[2].split("#")[0] for line in lines]
    assert len(ids) == 40
    # the 0x700 node got at most a frame or two out before the 0x100 node queued
    assert ids.index("100") <= 3 and ids[ids.index("100"):ids.index("100") + 20] == ["100"] * 20, ids
    stamps = [float(line[1:line.index(")")]) for line in lines]
    frame_s = 135 / 50_000  # 8-byte standard frame, worst-case stuffing
    assert stamps[-1] - stamps[0] >= 39 * frame_s * 0.95


def test_bitrate_stamps_keep_the_wire_schedule_when_the_hub_is_late(bus):
    """A frame on a bitrate= interface is stamped when its transmission ended, by the wire's
    schedule: a hub held up (here SIGSTOP, as a loaded machine does) that then delivers its
    backlog at once still stamps the frames one frame time apart, not all at its wake-up."""
    require_userspace(bus, "bitrate emulation is a hub feature")
    bus.stop_hub()
    bus.start_hub("vcan0:bitrate=10000,stuffing=worst")
    frame_s = 135 / 10_000  # 8-byte standard frame, worst-case stuffing: 13.5 ms
    dump = start_candump(bus, "-L", "vcan0", count=20)
    bus.run([sys.executable, "-c",
             "import socket, struct\n"
             "s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW); s.bind(('vcan0',))\n"
             "for i in range(20): s.send(struct.pack('<IB3x8s', 0x123, 8, bytes([i]) * 8))\n"])
    wait_for(lambda: bus.stats()["interfaces"][0]["frames"] >= 2, "the first frames on the wire")
    os.kill(bus.hub.pid, signal.SIGSTOP)
    try:
        time.sleep(8 * frame_s)  # the fault: the hub misses about eight frame ends
    finally:
        os.kill(bus.hub.pid, signal.SIGCONT)
    out, _ = stop(dump)
    stamps = [float(line[1:line.index(")")]) for line in out.splitlines() if line.startswith("(")]
    assert len(stamps) == 20
    gaps_ms = [round((b - a) * 1000, 2) for a, b in itertools.pairwise(stamps)]
    assert min(gaps_ms) >= frame_s * 1000 * 0.99, gaps_ms


# -- more kernel semantics ----------------------------------------------------

def test_loopback_off_hides_frames_from_everyone_on_the_host(bus):
    reader = start_pycan(bus, "--count", "1")
    code = (
        "import socket\n"
        "s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "s.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_LOOPBACK, 0)\n"
        "s.bind(('vcan0',))\n"
        "s.send(bytes([0x11, 0, 0, 0, 1, 0, 0, 0, 0xAA]) + bytes(7))\n"  # 011#AA: nobody sees it
    )
    bus.run([sys.executable, "-c", code])
    bus.run(["cansend", "vcan0", "022#BB"])  # loopback on (default): seen
    assert [m["id"] for m in pycan_messages(reader, 1)] == [0x22]


def test_fcntl_dupfd_shares_the_socket(bus):
    code = (
        "import fcntl, os, socket\n"
        "s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)\n"
        "s.bind(('vcan0',))\n"
        "fd = fcntl.fcntl(s.fileno(), fcntl.F_DUPFD_CLOEXEC, 100)\n"
        "s.close()\n"
        "print('ready', flush=True)\n"
        "print(os.read(fd, 16).hex(), flush=True)\n"
    )
    proc = bus.popen([sys.executable, "-c", code])
    assert proc.stdout.readline().strip() == "ready"
    bus.run(["cansend", "vcan0", "321#CD"])
    out, err = proc.communicate(timeout=WAIT_S)
    assert out.strip() == "2103000001000000cd00000000000000", err


def test_pycan_notifier_delivers_to_listeners(bus):
    code = (
        "import can, threading\n"
        "got, done = [], threading.Event()\n"
        "def on_message(m):\n"
        "    got.append(m.arbitration_id)\n"
        "    done.set() if len(got) == 3 else None\n"
        "with can.Bus(interface='socketcan', channel='vcan0') as b:\n"
        "    n = can.Notifier(b, [on_message])\n"
        "    print('ready', flush=True)\n"
        "    ok = done.wait(10)\n"
        "    n.stop()\n"
        "print(ok, got)\n"
    )
    proc = bus.popen([sys.executable, "-c", code])
    assert proc.stdout.readline().strip() == "ready"
    for frame in ("101#01", "102#02", "103#03"):
        bus.run(["cansend", "vcan0", frame])
    out, err = proc.communicate(timeout=WAIT_S)
    assert out.strip() == "True [257, 258, 259]", err


def test_hub_busy_poll_option_keeps_order_and_refuses_bad_values(bus):
    require_userspace(bus, "the hub's -s option")
    bus.stop_hub()
    bus.start_hub("-s", "200", "vcan0")
    assert bus.hub.poll() is None
    dump = start_candump(bus, "-L", "vcan0", count=3)
    for frame in ("123#01", "124#02", "125#03"):
        bus.run(["cansend", "vcan0", frame])
    out, _ = stop(dump)
    assert candump_frames(out) == ["vcan0 123#01", "vcan0 124#02", "vcan0 125#03"]
    bad = bus.run([bus.tool("ucan-hub"), "-d", str(bus.workdir / "other"), "-s", "soon", "vcan0"], check=False,
                  env={**bus.env, "LD_PRELOAD": ""})  # the hub itself never runs preloaded
    assert bad.returncode == 2 and "-s 'soon' is not 0..1000000 microseconds" in bad.stderr
