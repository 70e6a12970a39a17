"""The Linux CAN port (firmware/ports/linux/can_socketcan.c, docs/bridge.md). Its reads: a reader
that has emptied its socket waits in the read itself (recvmmsg with MSG_WAITFORONE and the
socket's receive timeout), so a wakeup costs one syscall where a poll and a read were two
(docs/benchmark.md: syscalls per frame in immediate mode 2.0 -> 1.0). Seen from outside: the
reader thread (zn-can), idle between frames, sleeps in recvmmsg, never in poll. Its writes: a tx
queue that stays full while poll() says writable (a real interface's ENOBUFS) is waited out with
a backoff, not a spin."""
from __future__ import annotations

import platform
import time
from pathlib import Path

import pytest
from conftest import BRIDGE, wait_for
from test_bridge_host import Collector, start_candump, stop_candump

# syscall numbers by machine: the one the reader waits in, and the waits it must not use
SYSCALLS = {"x86_64": (299, {7: "poll", 271: "ppoll", 232: "epoll_wait", 281: "epoll_pwait"}),
            "aarch64": (243, {73: "ppoll", 22: "epoll_pwait"})}
SAMPLES = 50  # times the idle reader is seen asleep in a syscall
LOOK_S = 5.0  # at most this long (batching: the reading thread idles once a period passes without frames)
ENOBUFS_HOLD_MS = 50  # how long can-enobufs keeps the tx queue full (ENOBUFS) before each write gets through


def thread_ids(pid: int, name: str) -> list[Path]:
    return [t for t in Path(f"/proc/{pid}/task").iterdir() if (t / "comm").read_text().strip() == name]


def blocked_in(task: Path) -> int | None:
    """The syscall a sleeping thread is in (/proc/<pid>/task/<tid>/syscall), None while it runs."""
    first = (task / "syscall").read_text().split()[0]
    return None if first == "running" or int(first) < 0 else int(first)


@pytest.mark.parametrize("period", ["0", "10"], ids=["immediate", "batching"])
def test_an_idle_reader_waits_in_its_read_not_in_a_poll(bus, bridge, session, period):
    read, waits = SYSCALLS.get(platform.machine(), (None, {}))
    if read is None:
        pytest.skip(f"syscall numbers not listed for {platform.machine()}")
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", period)
    bridge.wait_ready(session)
    bus.run(["cangen", "vcan0", "-I", "123", "-L", "8", "-D", "i", "-g", "1", "-n", "20"], timeout=30)
    assert len(rx.wait_frames(20)) == 20  # the port reads as before
    wait_for(lambda: bridge.stats(session)["buses"][0]["rx_queued"] == 0, "the queue emptied")
    tasks = thread_ids(bridge.proc.pid, "zn-can")
    if period != "0":  # batching: the two threads take turns at the port; the one reading it is idle there
        tasks += thread_ids(bridge.proc.pid, "zn-pub")
    seen: dict[int, int] = {}
    end = time.monotonic() + LOOK_S
    while seen.get(read, 0) < SAMPLES and time.monotonic() < end:
        for task in tasks:
            nr = blocked_in(task)
            if nr is not None:
                seen[nr] = seen.get(nr, 0) + 1
    polls = {waits[nr]: n for nr, n in seen.items() if nr in waits}
    assert not polls, f"the idle reader waited in {polls} (syscalls seen: {seen})"
    assert seen.get(read), f"the idle reader never seen in recvmmsg (syscalls seen: {seen})"


def test_a_full_tx_queue_that_poll_calls_writable_is_waited_out_not_spun_on(bus, tmp_path):
    # SocketCAN on a real interface: with the device's queue full (no ACK on the bus, bus-off) a
    # send fails with ENOBUFS while poll() says writable, so the writer retried at once and spun a
    # core (measured: 33 000 attempts in 50 ms); it now sleeps 50 us doubling to 1 ms between tries
    tool = BRIDGE.parent / "can-enobufs"
    dump, out = start_candump(bus, tmp_path / "can.log", frames=4)
    rc = bus.run([str(tool), "vcan0", str(ENOBUFS_HOLD_MS)], timeout=30)
    attempts = {line.split()[0]: int(line.split()[1].split("=")[1]) for line in rc.stdout.splitlines()}
    assert set(attempts) == {"single", "burst"}, rc.stdout
    for kind, n in attempts.items():  # about 2 a ms at the backoff's top (a poll, then a sleep)
        assert 0 < n <= 3 * ENOBUFS_HOLD_MS, f"{kind}: {n} attempts in {ENOBUFS_HOLD_MS} ms: it spins"
    assert stop_candump(dump, out) == ["vcan0 321#ABCD", "vcan0 322#01", "vcan0 323#02", "vcan0 324#03"]
