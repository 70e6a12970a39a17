"""Zenoh's low-latency transport (docs/bridge.md): with --low-latency 1 and a router that enables
it too, the thread that puts writes the link itself, so Zenoh's transmit threads (tx-*) stay
asleep while frames flow both ways, the router's too as it forwards commands to the bridge (its
routing puts from its own runtime's tasks: on the universal transport they wake its transmit task,
the patched transport's direct write being for application threads); the same bridge with a router
that does not enable it falls back to the universal transport (negotiated) and still forwards, and
the router's transmit thread wakes for every command: the contrast that shows the measure can fail.
(The bridge's own transmit thread stays asleep on either: its puts write the link themselves,
docs/upstream/README.md.) A frozen router: the put
blocks in the link's write (its send queue full), whichever thread makes it; the CAN port is still
read, every frame accounted for and delivered in order once the router runs again, and a SIGTERM in
the freeze exits 0 once it ends (the universal transport's rescue: test_direct_put.py)."""
from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from conftest import LOW_LATENCY_ROUTER, tcp_sockets, wait_for
from test_bridge_host import Collector, start_candump, stop_candump, wait_accounted
from test_direct_put import HOLD_S, MAX_BACKLOG, SNDBUF, check_published_in_order, small_send_buffer, stops_cleanly

from bench.common import ctx_switches
from canbench import wire

FRAMES = 600  # CAN -> Zenoh, paced 1 ms apart by cangen
COMMANDS = 200  # Zenoh -> CAN, one frame each


def transmit_switches(pid: int) -> int:
    """Context switches so far of Zenoh's transmit threads (its TX runtime names them tx-N)."""
    return sum(n for name, n in ctx_switches(pid).items() if name.startswith("tx-"))


def forward_both_ways(bus, bridge, router, session) -> tuple[int, int]:
    """FRAMES CAN -> Zenoh and COMMANDS Zenoh -> CAN through a --low-latency bridge, each whole and
    in order; returns how often the bridge's transmit threads switched meanwhile, and the router's
    while it forwarded the commands to the bridge."""
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--low-latency", "1")
    bridge.wait_ready(session)
    before = transmit_switches(bridge.proc.pid)
    bus.run(["cangen", "vcan0", "-I", "321", "-L", "8", "-D", "i", "-g", "1", "-n", str(FRAMES)], timeout=60)
    got = rx.wait_frames(FRAMES)
    assert [int.from_bytes(f.data, "little") for f, _, _ in got] == list(range(FRAMES))
    dump, out = start_candump(bus, bus.workdir / "commands.log", COMMANDS)
    router_before = transmit_switches(router.proc.pid)
    for n in range(COMMANDS):  # each once the one before is on the bus: one routed message at a time
        session.put("vehicle/can/tx", wire.encode(wire.Frame(0x123, 2, n.to_bytes(2, "little"))))
        wait_for(lambda n=n: Path(out.name).read_text().count("\n") > n, f"command {n} on CAN")
    router_switches = transmit_switches(router.proc.pid) - router_before
    assert len(stop_candump(dump, out)) == COMMANDS
    wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] == COMMANDS, f"{COMMANDS} commands on CAN")
    return transmit_switches(bridge.proc.pid) - before, router_switches


@pytest.mark.parametrize("router", [LOW_LATENCY_ROUTER], indirect=True, ids=["low-latency router"])
def test_with_a_low_latency_router_zenohs_transmit_threads_stay_asleep(bus, bridge, router, session):
    switches, router_switches = forward_both_ways(bus, bridge, router, session)
    # keep-alives and the stats replies' few wakeups, never one per sample
    assert switches < FRAMES // 20, f"Zenoh's transmit threads switched {switches} times for {FRAMES} frames"
    # the router writes the bridge's link from its routing task (the fallback below: one wakeup a command)
    assert router_switches < COMMANDS // 10, \
        f"the router's transmit threads switched {router_switches} times for {COMMANDS} commands"


def test_with_a_default_router_the_link_falls_back_and_still_forwards(bus, bridge, router, session):
    switches, router_switches = forward_both_ways(bus, bridge, router, session)
    assert router_switches >= COMMANDS // 2, \
        f"only {router_switches} switches of the router's transmit threads for {COMMANDS} commands"


@pytest.mark.parametrize("args,message", [
    (["--rx-priority", "2"], "low-latency transport has no QoS"),
    (["--rx-congestion", "drop"], "low-latency transport has no QoS"),
    (["--rx-qos", "0x000-0x0FF:realtime"], "low-latency transport has no QoS"),
    (["--compression", "1"], "low-latency transport does not compress"),
])
def test_what_the_transport_cannot_honour_is_refused(bus, bridge, args, message):
    proc = bridge.start("--low-latency", "1", *args)
    assert proc.wait(timeout=30) == 2
    lines = bridge.log.read_text().strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines


LOAD, GAP_MS = 20_000, "0.2"  # paced by cangen: about 5000 frames/s, 4 s of load
ROUTER_RCVBUF = 4096  # the router's receive buffer too: a frozen router's link fills within a second
FULL_S = 5.0  # the link must fill within this, well inside Zenoh's 10 s lease (it fills in a fraction of a second;
# a freeze beyond the lease closes every client's link, the subscriber's too, and loses what it held)


def link_send_queue(pid: int, port: int) -> int:
    """Bytes the kernel holds unsent on the process's TCP connections to this port (its link)."""
    return sum(unsent for _, remote, unsent, _ in tcp_sockets(pid) if remote == port)


def freeze_until_the_link_is_full(bus, bridge, router, backlog: list[int]) -> None:
    """SIGSTOP the router and keep it stopped until the bridge's link has been full for HOLD_S
    (its puts then block in the write), noting the hub's backlog for the bridge meanwhile."""
    router.proc.send_signal(signal.SIGSTOP)
    end, full = time.monotonic() + FULL_S, False
    while time.monotonic() < end:  # sampled for as long as the router stays frozen
        if bus.mode == "userspace":
            client = next(c for c in bus.stats()["clients"] if c["pid"] == bridge.proc.pid)
            backlog.append(client["queued"])
        if not full and link_send_queue(bridge.proc.pid, router.port) >= SNDBUF:
            full, end = True, time.monotonic() + HOLD_S
        time.sleep(0.01)  # the sampling period of the measurement, within the fault's length
    assert full, "the bridge's link never filled: the freeze blocked no put"


FROZEN = pytest.mark.parametrize(
    "router", [LOW_LATENCY_ROUTER + ("--cfg", f"transport/link/tcp/so_rcvbuf:{ROUTER_RCVBUF}")], indirect=True,
    ids=["low-latency router"])


def start_loaded(bus, bridge, session, tmp_path, period: str):
    """The bridge on the low-latency transport with a small send buffer, frames flowing."""
    bridge.start("--zenoh-config", str(small_send_buffer(tmp_path)), "--can", "vcan0", "--publish-period-ms", period,
                 "--low-latency", "1")
    bridge.wait_ready(session)
    load = bus.popen(["cangen", "vcan0", "-I", "i", "-L", "8", "-D", "i", "-g", GAP_MS, "-n", str(LOAD)])
    wait_for(lambda: bridge.stats(session)["buses"][0]["published_frames"] > 0, "the first frames published")
    return load


@FROZEN
@pytest.mark.parametrize("period", ["0", "10"], ids=["immediate", "batching"])
def test_a_frozen_router_blocks_the_puts_in_the_link_not_the_can_side(bus, bridge, router, session, tmp_path,
                                                                       period):
    """Whichever thread's put blocks in the write (the reader's own or the publisher's), the CAN port
    is still read, every frame is accounted for, and what was published arrives in order."""
    rx = Collector(session, "vehicle/can/rx")
    load = start_loaded(bus, bridge, session, tmp_path, period)
    backlog: list[int] = []
    try:
        freeze_until_the_link_is_full(bus, bridge, router, backlog)
    finally:
        router.proc.send_signal(signal.SIGCONT)
    assert load.wait(timeout=60) == 0
    stats = wait_accounted(bridge, session, LOAD, timeout=30)
    assert max(backlog, default=0) <= MAX_BACKLOG, f"the hub held up to {max(backlog)} frames for the bridge"
    check_published_in_order(rx, stats)


@FROZEN
@pytest.mark.parametrize("period", ["0", "10"], ids=["immediate", "batching"])
def test_sigterm_while_a_put_is_blocked_in_the_link_exits_cleanly(bus, bridge, router, session, tmp_path, period):
    Collector(session, "vehicle/can/rx")  # a subscriber: without one the bridge's puts never leave it
    load = start_loaded(bus, bridge, session, tmp_path, period)
    try:
        freeze_until_the_link_is_full(bus, bridge, router, [])
        bridge.proc.send_signal(signal.SIGTERM)
        wait_for(lambda: "zenoh-node: stopping" in bridge.log.read_text(), "the bridge to start stopping",
                 timeout=10)
    finally:
        router.proc.send_signal(signal.SIGCONT)
    stops_cleanly(bridge, load)
