"""The bridge's command path and CAN port under abuse (issue 19, defects 9-13):
a stalled bus under large commands, SIGTERM during a stalled batch, the bus hub
killed and restarted under a running bridge, a fragmented sample far over the
largest command, and configuration that cannot work. Each abuse has a stated
memory ceiling: the bridge's peak RSS (VmHWM) grows by less than
RSS_CEILING_KIB over its value before the abuse. Runs against the release and
the ASan/UBSan bridge (make check-bridge)."""
from __future__ import annotations

import json
import signal
import time

import pytest
import zenoh
from conftest import require_userspace, tcp_sockets, wait_for
from test_bridge_host import Collector, start_candump, stop_candump

from canbench import wire
from canbench.rig import free_port

RSS_CEILING_KIB = 8 * 1024  # the tx queue is 2048 x 24 bytes; anything near this is a leak or a buffer
STATS_ANSWER_S = 2.0        # a stats query on the session the commands arrive on, while they do
BATCH = 1024                # ZN_BATCH_MAX_FRAMES
TX_QUEUE = 2048             # the default tx_queue_frames
BIG_SAMPLE = 16 << 20       # far over ZN_RX_MESSAGE_MAX (32 780 B): Zenoh fragments it


def status_kib(pid: int, field: str) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise AssertionError(f"no {field}")


def batch(first_id: int, count: int = BATCH) -> bytes:
    return b"".join(wire.encode(wire.Frame((first_id + i) & 0x7FF, 2, i.to_bytes(2, "little"))) for i in range(count))


def timed_stats(bridge, session) -> tuple[dict, float]:
    t0 = time.monotonic()
    stats = bridge.stats(session)["buses"][0]
    return stats, time.monotonic() - t0


def stall(bus, bridge, session) -> int:
    """Stops the hub (SIGSTOP) and sends largest commands until the bridge's CAN socket is full
    and its queue refuses: returns how many commands were sent."""
    bus.hub.send_signal(signal.SIGSTOP)
    sent = 0
    for sent in range(1, 41):
        session.put("vehicle/can/tx", batch(0x100 + sent))
        if sent % 4 == 0 and bridge.stats(session)["buses"][0]["tx_queue_full"] > 0:
            break
    return sent


def test_stalled_bus_never_blocks_commands_and_refuses_what_does_not_fit(bus, bridge, session):
    require_userspace(bus, "the hub can be stopped under the bridge (kernel vcan never stalls)")
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    hwm_before = status_kib(bridge.proc.pid, "VmHWM")
    try:
        sent = stall(bus, bridge, session)
        # every command was taken at once: the session they come in on still answers, all are counted
        stats, took = wait_for(lambda: (r := timed_stats(bridge, session)) and r[0]["tx_samples"] == sent and r,
                               f"{sent} commands counted while the bus is stalled")
        assert took < STATS_ANSWER_S, f"stats took {took:.1f} s: Zenoh's callback is blocked"
        assert stats["tx_queue_full"] > 0, stats  # the bounded queue refused, whole commands
        stats = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and s["can_tx_errors"] > 0 and s,
                         "a frame the stalled bus did not take")
        # every frame of every accepted command is accounted for once; refused commands never queued
        accepted = sent - stats["tx_queue_full"]
        assert stats["tx_frames"] + stats["can_tx_errors"] + stats["tx_abandoned"] <= accepted * BATCH
    finally:
        bus.hub.send_signal(signal.SIGCONT)
    assert status_kib(bridge.proc.pid, "VmHWM") - hwm_before < RSS_CEILING_KIB
    # the bus back, commands flow again
    dump, out = start_candump(bus, bus.workdir / "after.log")
    wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and
             s["tx_frames"] + s["can_tx_errors"] + s["tx_abandoned"] == (sent - s["tx_queue_full"]) * BATCH,
             "the queue drained")
    session.put("vehicle/can/tx", wire.encode(wire.Frame(0x7AB, 1, b"\x01")))
    wait_for(lambda: "vcan0 7AB#01" in open(out.name).read(), "a command after the stall on the bus")
    stop_candump(dump, out)


def test_sigterm_during_a_stalled_batch_exits_cleanly(bus, bridge, session):
    require_userspace(bus, "the hub can be stopped under the bridge")
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    try:
        stall(bus, bridge, session)
        wait_for(lambda: bridge.stats(session)["buses"][0]["can_tx_errors"] > 0, "the transmitter stalled")
        t0 = time.monotonic()
        rc, log = bridge.stop(signal.SIGTERM)  # while a batch waits for the stopped hub
        took = time.monotonic() - t0
    finally:
        bus.hub.send_signal(signal.SIGCONT)
    assert rc == 0, log[-3000:]
    assert took < 10, f"stop took {took:.1f} s"
    assert "ERROR: AddressSanitizer" not in log and "runtime error" not in log, log[-3000:]
    assert "final stats:" in log and '"tx_abandoned": ' in log


def test_can_reopen_after_hub_restart_counts_it_and_sends_nothing_twice(bus, bridge, session, tmp_path):
    """The real hub killed (SIGKILL: no goodbye on the socket) and started again under the running
    bridge, twice: each reopen counted, frames and commands after each restart flow, every frame
    published once with consecutive sequence numbers (nothing queued before a loss resent)."""
    require_userspace(bus, "the hub is killed and restarted under the running bridge")
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "0")
    bridge.wait_ready(session)
    hwm_before = status_kib(bridge.proc.pid, "VmHWM")
    sent: list[str] = []

    def burst(first_id: int) -> None:
        for i in range(5):
            bus.run(["cansend", "vcan0", f"{first_id + i:03X}#{i:02X}"])
            sent.append(f"vcan0 {first_id + i:03X}#{i:02X}")
        rx.wait_frames(len(sent))

    burst(0x101)
    for restart in (1, 2):
        bus.stop_hub(signal.SIGKILL)
        bus.start_hub(*bus.hub_args)  # returns once the new hub listens on its socket
        stats = wait_for(lambda n=restart: (s := bridge.try_stats(session)) and s["buses"][0]["can_reopens"] >= n and s,
                         f"the bridge reopening its CAN bus (restart {restart})", timeout=30)
        assert stats["buses"][0]["can_reopens"] == restart
        bus.wait_receivers(1)  # the bridge's socket bound on the new hub
        dump, out = start_candump(bus, tmp_path / f"can-{restart}.log")
        burst(0x101 + 0x10 * restart)
        command = f"vcan0 {0x200 + restart:03X}#{restart:02X}"
        session.put("vehicle/can/tx", wire.encode(wire.Frame(0x200 + restart, 1, bytes([restart]))))
        wait_for(lambda line=command, path=out.name: line in open(path).read(), "the command on the new bus")
        assert bridge.stats(session)["buses"][0]["tx_frames"] == restart
        # on the new bus: this restart's frames and its command, each once; nothing from before resent
        assert stop_candump(dump, out) == sent[-5:] + [command]
    got = rx.frames()
    assert [f.candump("vcan0") for f, _, _ in got] == sent  # each frame once, in order
    assert [seq for _, seq, _ in got] == list(range(len(sent)))
    assert status_kib(bridge.proc.pid, "VmHWM") - hwm_before < RSS_CEILING_KIB


@pytest.mark.parametrize("args,message", [
    (["--deny-ids", "1000007FF"], "id range '1000007FF' is beyond 0x1FFFFFFF"),
    (["--router", "tcp/127.0.0.1"], "router endpoint 'tcp/127.0.0.1' is not"),
])
def test_configuration_that_cannot_work_exits_2_with_one_line(bus, bridge, args, message):
    proc = bridge.start(*args)
    assert proc.wait(timeout=30) == 2
    lines = bridge.log.read_text().strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines


def test_a_fragmented_16_mib_sample_on_the_tx_key_is_dropped_not_reassembled(bus, bridge, session):
    """Zenoh's default rx max_message_size (1 GiB) let any publisher make the bridge reassemble
    a sample of that size before on_command refused it: the port caps it at ZN_RX_MESSAGE_MAX."""
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    dump, out = start_candump(bus, bus.workdir / "big.log", frames=1)
    hwm_before = status_kib(bridge.proc.pid, "VmHWM")
    # blocking, so neither this session nor the router drops fragments: all of it reaches the bridge
    session.put("vehicle/can/tx", bytes(BIG_SAMPLE), congestion_control=zenoh.CongestionControl.BLOCK)
    # a valid command after it on the same session and priority: on the bus once the big one was handled
    session.put("vehicle/can/tx", wire.encode(wire.Frame(0x7AC, 1, b"\x02")),
                congestion_control=zenoh.CongestionControl.BLOCK)
    wait_for(lambda: "vcan0 7AC#02" in open(out.name).read(), "the command after the big sample", timeout=60)
    stats = bridge.stats(session)["buses"][0]
    growth = status_kib(bridge.proc.pid, "VmHWM") - hwm_before
    print(f"peak RSS growth under a {BIG_SAMPLE >> 20} MiB sample: {growth} KiB")
    assert growth < RSS_CEILING_KIB, f"peak RSS grew {growth} KiB: the sample was reassembled"
    # Zenoh dropped it at the cap (the defragmenter is cleared, later fragments lack a start):
    # on_command never saw it, the bus saw nothing of it
    assert stats["tx_samples"] == 1 and stats["tx_frames"] == 1, stats
    assert stop_candump(dump, out) == ["vcan0 7AC#02"]
    assert bridge.proc.poll() is None, bridge.log.read_text()[-3000:]


def test_a_tls_file_that_cannot_be_read_exits_2_at_once_naming_key_and_path(bus, bridge, tmp_path):
    """Zenoh reads TLS files only when a link opens and a client retries forever: the port reads
    them first, so a wrong path is a configuration error (exit 2), not an absent router."""
    missing = tmp_path / "no-such-ca.pem"
    config = tmp_path / "zenoh.json5"
    config.write_text(json.dumps({"transport": {"link": {"tls": {"root_ca_certificate": str(missing)}}}}) + "\n")
    t0 = time.monotonic()
    proc = bridge.start("--zenoh-config", str(config))
    assert proc.wait(timeout=30) == 2, bridge.log.read_text()
    took = time.monotonic() - t0
    log = bridge.log.read_text()
    assert "retrying" not in log, log  # one attempt: nothing here can heal by waiting
    assert took < 5, f"exit 2 after {took:.1f} s"
    # one line, the reason: key and path
    lines = [line for line in log.splitlines() if line.strip()]
    assert len(lines) == 1, log
    assert "transport/link/tls/root_ca_certificate" in lines[0], log
    assert str(missing) in lines[0] and "No such file" in lines[0], log


@pytest.mark.parametrize("option, endpoint", [("--listen", "udp/127.0.0.1:7449"), ("--router", "quic/127.0.0.1:7449"),
                                              ("--listen", "ws/127.0.0.1:7449")])
def test_an_endpoint_of_a_protocol_the_build_lacks_exits_2_naming_what_it_has(bus, bridge, option, endpoint):
    """The Linux build's Zenoh carries TCP and TLS links only (firmware/ports/linux/zenoh_rust/Cargo.toml):
    Zenoh would treat another protocol's endpoint like an absent router and retry forever; the port
    refuses it at once, a configuration error (exit 2) naming the endpoint and what the build has."""
    args = [option, endpoint] + (["--mode", "peer"] if option == "--listen" else [])
    t0 = time.monotonic()
    proc = bridge.start(*args)
    assert proc.wait(timeout=30) == 2, bridge.log.read_text()
    assert time.monotonic() - t0 < 5, bridge.log.read_text()
    log = bridge.log.read_text()
    assert "retrying" not in log, log
    assert endpoint in log and "it has tcp, tls" in log, log


def listening_ports(pid: int) -> list[int]:
    """The TCP ports the process listens on (its sockets with no peer)."""
    return [local for local, remote, _, _ in tcp_sockets(pid) if remote == 0]


@pytest.mark.parametrize("mode", ["peer", "router"])
def test_a_peer_or_router_bridge_listens_only_where_it_is_told(bus, bridge, router, session, mode):
    """Network safety: Zenoh alone would have a peer listen on every interface (tcp/[::]:0) and a
    router on tcp/[::]:7447; the bridge listens nowhere unless --listen (or its config file) says."""
    bridge.start("--mode", mode)
    bridge.wait_ready(session)
    assert listening_ports(bridge.proc.pid) == [], bridge.log.read_text()[-2000:]
    bridge.stop()
    port = free_port()
    bridge.start("--mode", mode, "--listen", f"tcp/127.0.0.1:{port}")
    bridge.wait_ready(session)
    assert listening_ports(bridge.proc.pid) == [port]
