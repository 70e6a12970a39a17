"""Zenoh's thread pools inside the bridge (firmware/ports/linux/zenoh_rust/src/lib.rs,
docs/bridge.md, Threads and flow control): unless the user sets ZENOH_RUNTIME, Zenoh's app, net
and acc runtimes are handed over to its rx runtime, so the router link's socket is polled by the
worker that reads it: no app-0, net-0 or acc-0 thread that wakes the rx workers for every sample
(docs/benchmark.md: Zenoh -> CAN's switches per frame 0.23 -> 0.10). A user's ZENOH_RUNTIME
replaces that default whole."""
from __future__ import annotations

from pathlib import Path

from conftest import wait_for

from canbench import wire

HANDED_OVER = ("app-", "net-", "acc-")


def thread_names(pid: int) -> set[str]:
    names = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            names.add((task / "comm").read_text().strip())
        except OSError:  # a thread that ended meanwhile
            pass
    return names


def command_goes_through(bridge, session, n: int) -> None:
    session.put("vehicle/can/tx", wire.encode(wire.Frame(0x123, 1, bytes([n]))))
    wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] == n, f"command {n} written")


def test_the_link_is_polled_by_zenohs_rx_workers(bus, bridge, session):
    bridge.start("--can", "vcan0")
    bridge.wait_ready(session)
    command_goes_through(bridge, session, 1)  # the callback (and the stats reply) on an rx worker
    names = thread_names(bridge.proc.pid)
    assert any(n.startswith("rx-") for n in names), names
    assert not {n for n in names if n.startswith(HANDED_OVER)}, names


def test_a_users_zenoh_runtime_replaces_the_default(bus, bridge, session):
    bridge.start("--can", "vcan0", env={"ZENOH_RUNTIME": "()"})  # Zenoh's own defaults
    bridge.wait_ready(session)
    command_goes_through(bridge, session, 1)
    assert "app-0" in thread_names(bridge.proc.pid)
