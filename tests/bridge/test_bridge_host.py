"""The bridge on the host: zenohd (from crates.io), the CAN bus (kernel vcan
or the userspace hub), the zenoh-node executable, can-utils and an
eclipse-zenoh client. Frames both ways, byte-exact and in order, including
extended, remote and zero-length frames; refusals; shutdown; router loss."""
from __future__ import annotations

import signal
import subprocess
import threading
import time

import pytest
from conftest import READY_TIMEOUT_S, wait_for, zenoh_session

from canbench import wire

WAIT_S = 30
KINDS = [wire.Frame(0x123, 4, bytes.fromhex("DEADBEEF")),
         wire.Frame(0x12345678, 8, bytes(range(8)), extended=True),
         wire.Frame(0x7FF, 0, remote=True),
         wire.Frame(0x0AA, 3, remote=True),
         wire.Frame(0x000, 0),
         wire.Frame(0x1FFFFFFF, 1, b"\xff", extended=True),
         wire.Frame(0x18DAF110, 2, remote=True, extended=True)]


def cansend_arg(frame: wire.Frame) -> str:
    return frame.candump().split(" ", 1)[1]


class Collector:
    """Every sample on a key, with its attachment decoded."""

    def __init__(self, session, key: str):
        self.samples: list[tuple[bytes, bytes | None]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        att = bytes(sample.attachment.to_bytes()) if sample.attachment is not None else None
        with self.lock:
            self.samples.append((bytes(sample.payload.to_bytes()), att))

    def frames(self) -> list[tuple[wire.Frame, int, int]]:
        """(frame, sequence number, CAN receive time ns) for every frame received so far."""
        out = []
        with self.lock:
            samples = list(self.samples)
        for payload, att in samples:
            frames = wire.decode_batch(payload)
            meta = wire.decode_attachment(att or b"")
            assert meta.count == len(frames)
            out += [(f, meta.first_seq + i, t) for i, (f, t) in enumerate(zip(frames, meta.rx_times_ns, strict=True))]
        return out

    def wait_frames(self, count: int) -> list[tuple[wire.Frame, int, int]]:
        wait_for(lambda: len(self.frames()) >= count, f"{count} frames on Zenoh", timeout=WAIT_S)
        return self.frames()


def wait_accounted(bridge, session, total: int, timeout: float = READY_TIMEOUT_S) -> dict:
    """The bus's stats once every frame read from CAN is published or counted as dropped."""
    seen: list[dict] = []

    def accounted():
        seen.append(bridge.stats(session)["buses"][0])
        s = seen[-1]
        return s if s["published_frames"] + s["rx_queue_drops"] == s["can_rx_frames"] == total else None
    try:
        return wait_for(accounted, "the bridge to account for every frame", timeout=timeout)
    except TimeoutError:
        # first and last: a link that is stuck shows the same counts, one that is slow shows progress
        raise AssertionError(f"{len(seen)} stats read; first: {seen[0] if seen else None}; "
                             f"last: {seen[-1] if seen else None}") from None


def start_candump(bus, path, frames: int | None = None):
    """candump on vcan0 into path, once the hub counts it as a receiver. frames: it exits by itself
    after that many (candump -n), so stop_candump never interrupts it with a frame still unread in
    its socket (SIGINT ends candump's loop without reading what is pending)."""
    before = bus.receivers()
    out = open(path, "w")
    proc = bus.popen(["candump", "-L", *(["-n", str(frames)] if frames else []), "vcan0"], stdout=out)
    proc.counted = bool(frames)
    bus.wait_receivers(before + 1)
    return proc, out


def stop_candump(proc, out) -> list[str]:
    """What candump wrote: a counted one is waited for (at most WAIT_S, then interrupted: what it
    had is the answer); an uncounted one is interrupted at once."""
    try:
        if not getattr(proc, "counted", False):
            raise subprocess.TimeoutExpired(proc.args, 0)
        proc.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=WAIT_S)
    out.close()
    return [line.split(" ", 1)[1] for line in open(out.name).read().splitlines() if line.startswith("(")]


def test_can_to_zenoh_every_frame_kind_byte_exact_in_order(bus, bridge, session):
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "0")
    bridge.wait_ready(session)
    sent_at = time.time_ns()
    for frame in KINDS:
        bus.run(["cansend", "vcan0", cansend_arg(frame)])
    got = rx.wait_frames(len(KINDS))
    assert [f for f, _, _ in got] == KINDS
    assert [seq for _, seq, _ in got] == list(range(len(KINDS)))
    assert all(sent_at <= t <= time.time_ns() for _, _, t in got)  # CAN receive timestamps
    stats = bridge.stats(session)["buses"][0]
    assert stats["published_frames"] == len(KINDS) and stats["rx_queue_drops"] == 0


def test_zenoh_to_can_every_frame_kind_byte_exact_in_order(bus, bridge, session, tmp_path):
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log", frames=len(KINDS) + 3)
    # one command at a time: commands waiting together leave in CAN arbitration order
    # (docs/bridge.md), and this test is about each frame's bytes and a batch's own order
    for i, frame in enumerate(KINDS):
        session.put("vehicle/can/tx", wire.encode(frame))
        wait_for(lambda n=i + 1: bridge.stats(session)["buses"][0]["tx_frames"] == n, f"command {i} transmitted")
    session.put("vehicle/can/tx", b"".join(wire.encode(f) for f in KINDS[:3]))  # a batch
    wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] == len(KINDS) + 3, "commands transmitted")
    # commands waiting together leave by CAN priority (docs/bridge.md), each written whole in its own order
    on_bus, batch = stop_candump(dump, out), [f.candump() for f in KINDS[:3]]
    assert sorted(on_bus) == sorted(f.candump() for f in KINDS + KINDS[:3])
    assert any(on_bus[i:i + 3] == batch for i in range(len(on_bus)))
    # each command found the bus free, so Zenoh's callback wrote it itself (docs/bridge.md)
    stats = bridge.stats(session)["buses"][0]
    assert stats["tx_direct_frames"] == stats["tx_frames"] == len(KINDS) + 3, stats


def test_burst_and_batching_keep_order_and_count(bus, bridge, session):
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "20", "--batch-max-frames", "64")
    bridge.wait_ready(session)
    total = 5000
    bus.run(["cangen", "vcan0", "-I", "42", "-L", "8", "-D", "i", "-g", "1", "-c", "20", "-n", str(total)],
            timeout=60)
    got = rx.wait_frames(total)
    assert [seq for _, seq, _ in got] == list(range(total))
    counters = [int.from_bytes(f.data, "little") for f, _, _ in got]
    assert counters == list(range(total))
    assert max(len(p) // 16 for p, _ in rx.samples) > 1  # really batched
    assert all(len(p) // 16 <= 64 for p, _ in rx.samples)


def test_invalid_commands_never_reach_the_bus_and_are_counted(bus, bridge, session, tmp_path):
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    dump, out = start_candump(bus, tmp_path / "can.log", frames=1)
    good = wire.encode(wire.Frame(0x321, 1, b"\x01"))
    bad = {
        "length": [b"", good[:15], good + b"\0", bytes(64)[:33]],
        "dlc": [good[:4] + b"\x09" + good[5:]],
        "flags": [good[:5] + b"\x04" + good[6:]],
        "reserved": [good[:6] + b"\x01" + good[7:]],
        "id_range": [b"\x00\x08\x00\x00" + good[4:]],
        "remote_data": [wire.encode(wire.Frame(0x1, 1, remote=True))[:8] + b"\x01" + bytes(7)],
        "padding": [good[:9] + b"\x01" + good[10:]],
    }
    for payloads in bad.values():
        for payload in payloads:
            session.put("vehicle/can/tx", payload)
    session.put("vehicle/can/tx", good, attachment=b"\x07garbage")
    session.put("vehicle/can/tx", good)  # valid frames that follow still go through
    stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["tx_frames"] == 1 and s,
                     "the valid command")
    assert stop_candump(dump, out) == ["vcan0 321#01"]
    rejected = stats["tx_rejected"]
    for reason, payloads in bad.items():
        assert rejected[reason] == len(payloads), (reason, rejected)
    assert rejected["attachment"] == 1


def test_sigterm_flushes_pending_batch_and_exits_zero(bus, bridge, session):
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "60000")
    bridge.wait_ready(session)
    for i in range(5):
        bus.run(["cansend", "vcan0", f"10{i}#0{i}"])
    wait_for(lambda: bridge.stats(session)["buses"][0]["can_rx_frames"] == 5, "frames read from CAN")
    assert rx.frames() == []
    rc, log = bridge.stop(signal.SIGTERM)
    assert rc == 0, log
    assert [f.can_id for f, _, _ in rx.wait_frames(5)] == [0x100, 0x101, 0x102, 0x103, 0x104]
    assert "final stats:" in log and '"published_frames": 5' in log
    wait_for(lambda: not [r for r in session.liveliness().get("vehicle/can/bridges/**") if r.ok],
             "the token withdrawn")


def test_starts_before_its_router_and_recovers_after_restart(bus, bridge, router, session):
    router.stop()
    bridge.start("--can", "vcan0", "--publish-period-ms", "0")
    wait_for(lambda: "router not reachable" in bridge.log.read_text(), "the bridge saying it waits")
    assert bridge.proc.poll() is None
    router.start()
    session2 = zenoh_session(router.endpoint)
    try:
        bridge.wait_ready(session2)
        rx = Collector(session2, "vehicle/can/rx")
        # the bridge connected before this subscriber existed, and its publisher sends only once it
        # knows of one: a stats query after the declaration is a barrier (the router passes both to
        # the bridge in order on one link), else the frame may be put before the bridge hears of rx
        bridge.stats(session2)
        bus.run(["cansend", "vcan0", "111#11"])
        assert [f.can_id for f, _, _ in rx.wait_frames(1)] == [0x111]
        # and a router restart: the bridge reconnects and counts it
        router.stop()
        router.start()
        wait_for(lambda: (s := bridge.try_stats(session2)) and s["reconnects"] >= 1, "reconnect counted", timeout=30)
        # its closed connection too (before it, the bridge was waiting: none had opened to close)
        wait_for(lambda: "1 Zenoh connection closed (1 since start)" in bridge.log.read_text(), "the closure logged")
        stats = bridge.stats(session2)
        assert stats["connections_closed"] == 1, stats
        bus.run(["cansend", "vcan0", "222#22"])
        wait_for(lambda: [f.can_id for f, _, _ in rx.frames()][-1:] == [0x222], "frames after the restart")
    finally:
        session2.close()


@pytest.mark.parametrize("args,message", [
    (["--mode", "server"], "--mode='server' is not client, peer or router"),
    (["--publish-period-ms", "soon"], "--publish-period-ms='soon' is not a whole number"),
    (["--can", "vcan0,vcan0"], "CAN bus 'vcan0' given twice"),
])
def test_invalid_configuration_exits_2_with_one_line(bus, bridge, args, message):
    proc = bridge.start(*args)
    assert proc.wait(timeout=WAIT_S) == 2
    lines = bridge.log.read_text().strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines


def test_compressed_transport_carries_batches_byte_exact(bus, bridge, router):
    router.stop()
    router.start("--cfg", "transport/unicast/compression/enabled:true")
    session = zenoh_session(router.endpoint)
    try:
        rx = Collector(session, "vehicle/can/rx")
        bridge.start("--can", "vcan0", "--compression", "1", "--publish-period-ms", "10")
        bridge.wait_ready(session)
        total = 2000
        bus.run(["cangen", "vcan0", "-I", "100", "-L", "8", "-D", "i", "-g", "1", "-c", "10", "-n", str(total)],
                timeout=60)
        got = rx.wait_frames(total)
        assert [int.from_bytes(f.data, "little") for f, _, _ in got] == list(range(total))
    finally:
        session.close()


def rss_kib(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_flood_above_forwarding_rate_drops_counted_memory_bounded(bus, bridge, session):
    rx = Collector(session, "vehicle/can/rx")
    # a tiny queue between CAN reader and publisher, and a burst as fast as the bus goes
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--rx-queue-frames", "16")
    bridge.wait_ready(session)
    rss_before = rss_kib(bridge.proc.pid)
    total = 20_000
    bus.run(["cangen", "vcan0", "-I", "200", "-L", "8", "-D", "i", "-g", "0", "-n", str(total), "-p", "100"],
            timeout=60)
    stats = wait_accounted(bridge, session, total)
    assert stats["rx_queue_drops"] > 0, stats  # the flood really exceeded the queue
    if bus.mode == "userspace":  # and nothing vanished before the bridge read it
        bridge_client = next(c for c in bus.stats()["clients"] if c["pid"] == bridge.proc.pid)
        assert bridge_client["rx_drops"] == 0
    # what was published arrives in order, and the gaps are exactly the counted drops
    got = rx.wait_frames(stats["published_frames"])
    seqs = [seq for _, seq, _ in got]
    assert seqs == sorted(seqs) and len(seqs) == stats["published_frames"]
    assert seqs[-1] + 1 - len(seqs) <= stats["rx_queue_drops"]
    assert rss_kib(bridge.proc.pid) < rss_before + 16 * 1024  # bounded: no growth with the flood
    # and it keeps bridging afterwards
    bus.run(["cansend", "vcan0", "7AB#01"])
    wait_for(lambda: [f.can_id for f, _, _ in rx.frames()][-1:] == [0x7AB], "a frame after the flood")
