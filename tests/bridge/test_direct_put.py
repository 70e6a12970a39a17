"""Immediate mode's direct put (docs/bridge.md, Threads and flow control): the CAN reader puts
frames itself while the Zenoh session is healthy and hands them to the publisher when a put
stalls. zenohd is frozen (SIGSTOP) under a paced CAN load, with the bridge's TCP send buffer
small so that its puts block within a second, not after megabytes: the CAN side keeps reading
meanwhile (the hub never holds more than a moment's frames for the bridge, every frame read
from the bus, none lost before the bridge), the stall is seen and
counted (direct_stalls), what is published arrives in order, each frame once, with gaps only
where the queue counted drops; once the router runs again the reader puts again. Batching mode
(docs/bridge.md: the reader and the publisher take turns, whichever drains the port puts the
period's batch) keeps the same guarantees through the same freeze, and stops cleanly in it."""
from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from conftest import wait_for
from test_bridge_host import Collector, wait_accounted

FRAMES, GAP_MS = 20_000, "0.2"  # paced by cangen: about 5000 frames/s, 4 s of load
FREEZE_S = 3.0  # the router stops once the reader puts, for 3 s (well inside Zenoh's 10 s lease)
AFTER = 100  # frames once the router runs again
MAX_BACKLOG = 1000  # frames: 0.2 s of the load unread (the stall is seen within about 20 ms)
SNDBUF = 4096  # bytes, the kernel's floor: the puts block once Zenoh's queue and the router's socket are full


def small_send_buffer(tmp_path) -> Path:
    """A Zenoh config giving the bridge's link the smallest TCP send buffer."""
    config = tmp_path / "zenoh.json5"
    config.write_text(f"{{transport: {{link: {{tcp: {{so_sndbuf: {SNDBUF}}}}}}}}}\n")
    return config


def stops_cleanly(bridge, load) -> None:
    """The bridge, stopping, exits 0 with its final stats; the load is ended."""
    rc, log = bridge.stop()  # waits up to 20 s
    load.kill()
    load.wait()
    assert rc == 0, log[-2000:]
    assert "final stats" in log


def check_published_in_order(rx, stats: dict) -> None:
    """What was published arrived in order, each frame once, with gaps only where drops were counted."""
    got = rx.wait_frames(stats["published_frames"])
    seqs = [seq for _, seq, _ in got]
    assert seqs == sorted(set(seqs)) and len(seqs) == stats["published_frames"], "out of order or twice"
    assert seqs[-1] + 1 - len(seqs) <= stats["rx_queue_drops"]


def reader_putting(bridge, session) -> None:
    """Returns once the reader has put frames itself: the load flows and the direct path is in use."""
    wait_for(lambda: bridge.stats(session)["buses"][0]["direct_frames"] > 0, "the reader's own puts")


STALL_SEEN_S = 7.0  # batching: the freeze lasts until the bridge logs a stalled put (under Zenoh's 5 s
HOLD_S = 1.0  # wait_before_close once a put blocks), then this much longer


def stalled(bridge) -> bool:
    return "a put stalled" in bridge.log.read_text()


def stalled_for_good(bridge) -> bool:
    """A put stalled 1 s: the frozen router's, not a put that a loaded machine held 10 ms right
    after the freeze (the first stall logged can be that one, and its put returns)."""
    return "a put has been stalled for 1 s" in bridge.log.read_text()


@pytest.mark.parametrize("period", ["0", "10"], ids=["immediate", "batching"])
def test_a_frozen_router_never_stops_the_can_side_and_order_is_kept(bus, bridge, router, session, tmp_path, period):
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--zenoh-config", str(small_send_buffer(tmp_path)), "--can", "vcan0", "--publish-period-ms", period)
    bridge.wait_ready(session)
    load = bus.popen(["cangen", "vcan0", "-I", "i", "-L", "8", "-D", "i", "-g", GAP_MS, "-n", str(FRAMES)])
    assert router.proc is not None
    backlog = 0  # userspace bus: the most frames the hub held for the bridge during the freeze

    def sample_backlog() -> None:
        nonlocal backlog
        if bus.mode == "userspace":
            client = next(c for c in bus.stats()["clients"] if c["pid"] == bridge.proc.pid)
            backlog = max(backlog, client["queued"])
    try:
        if period == "0":
            reader_putting(bridge, session)
        else:  # batches flow: the threads' puts are in use
            wait_for(lambda: bridge.stats(session)["buses"][0]["published_frames"] > 0, "the first batches")
        router.proc.send_signal(signal.SIGSTOP)
        # the fault: how long the router gets no CPU (batching's samples are fewer and larger, so
        # Zenoh's queue fills later: held until the bridge says a put stalled, then HOLD_S more)
        end = time.monotonic() + (FREEZE_S if period == "0" else STALL_SEEN_S)
        while time.monotonic() < end:  # sampled for as long as the router stays frozen
            sample_backlog()
            if period != "0" and stalled(bridge):
                end = min(end, time.monotonic() + HOLD_S)
            time.sleep(0.01)  # the sampling period of the measurement, within the fault's length
    finally:
        router.proc.send_signal(signal.SIGCONT)
    assert load.wait(timeout=60) == 0, load.stderr.read() if load.stderr else ""
    stats = wait_accounted(bridge, session, FRAMES, timeout=30)
    # the reader, or the publisher in its place, kept reading: a reader blocked in a put leaves
    # the hub holding thousands (4746 in a run without the rescue), a kernel socket drops them
    assert backlog <= MAX_BACKLOG, f"the hub held up to {backlog} frames for the bridge during the freeze"
    assert stats["direct_stalls"] >= 1, stats  # the freeze really blocked a put
    if bus.mode == "userspace":  # nothing vanished before the bridge read it
        bridge_client = next(c for c in bus.stats()["clients"] if c["pid"] == bridge.proc.pid)
        assert bridge_client["rx_drops"] == 0, bridge_client
    check_published_in_order(rx, stats)
    assert stalled(bridge)
    # the session is healthy again: frames flow again (in immediate mode the reader puts itself again)
    bus.run(["cangen", "vcan0", "-I", "7AB", "-L", "1", "-g", "1", "-n", str(AFTER)], timeout=60)
    after = wait_for(lambda: (s := bridge.stats(session)["buses"][0]) and
                     s["published_frames"] + s["rx_queue_drops"] == FRAMES + AFTER and s, "the frames after the freeze")
    if period == "0":
        assert after["direct_frames"] > stats["direct_frames"], (stats, after)


@pytest.mark.parametrize("period", ["0", "10"], ids=["immediate", "batching"])
def test_sigterm_while_a_put_is_stalled_exits_cleanly(bus, bridge, router, session, tmp_path, period):
    """Stopping while a thread is stuck in a put and the other reads in its place: nothing is read
    for the stuck put any more, the put is waited for, and the bridge exits 0 once the router runs
    again. Immediate mode says when it stopped reading for the put (a log line)."""
    Collector(session, "vehicle/can/rx")  # a subscriber: without one the bridge's puts never leave it
    bridge.start("--zenoh-config", str(small_send_buffer(tmp_path)), "--can", "vcan0", "--publish-period-ms", period)
    bridge.wait_ready(session)
    load = bus.popen(["cangen", "vcan0", "-I", "i", "-L", "8", "-D", "i", "-g", GAP_MS, "-n", str(FRAMES)])
    assert router.proc is not None and bridge.proc is not None
    try:
        if period == "0":
            reader_putting(bridge, session)
        else:
            wait_for(lambda: bridge.stats(session)["buses"][0]["published_frames"] > 0, "the first batches")
        router.proc.send_signal(signal.SIGSTOP)
        # both modes say a put stalled 1 s (batching's drains, immediate mode's rescue)
        wait_for(lambda: stalled_for_good(bridge), "the other thread reading for a put stalled 1 s",
                 timeout=STALL_SEEN_S)
        bridge.proc.send_signal(signal.SIGTERM)
        if period == "0":  # what the test is about: the stop seen while the put is still stalled
            wait_for(lambda: "stopping while a put is stalled" in bridge.log.read_text(),
                     "the publisher to stop reading for the stalled put", timeout=10)
        else:  # the stop under way while the put is stuck (the router is still frozen)
            wait_for(lambda: "zenoh-node: stopping" in bridge.log.read_text(), "the bridge to start stopping",
                     timeout=10)
    finally:
        router.proc.send_signal(signal.SIGCONT)
    stops_cleanly(bridge, load)
