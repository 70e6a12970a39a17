"""The bridge's command path and CAN port under abuse (issue 19, defects 9-13):
a stalled bus under large commands, SIGTERM during a stalled batch, the bus hub
killed and restarted under a running bridge, and configuration that cannot
work. Each abuse has a stated
memory ceiling: the bridge's peak RSS (VmHWM) grows by less than
RSS_CEILING_KIB over its value before the abuse. Runs against the release and
the ASan/UBSan bridge (make check-bridge)."""
from __future__ import annotations

import signal
import time

import pytest
from conftest import require_userspace, wait_for
from test_bridge_host import Collector, start_candump, stop_candump

from canbench import wire

RSS_CEILING_KIB = 8 * 1024  # the tx queue is 2048 x 24 bytes; anything near this is a leak or a buffer
STATS_ANSWER_S = 2.0        # a stats query on the session the commands arrive on, while they do
BATCH = 1024                # ZN_BATCH_MAX_FRAMES
TX_QUEUE = 2048             # the default tx_queue_frames


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
    require_userspace(bus, "the hub is killed and restarted under the running bridge")
    rx = Collector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "0")
    bridge.wait_ready(session)
    hwm_before = status_kib(bridge.proc.pid, "VmHWM")
    bus.run(["cansend", "vcan0", "101#01"])
    rx.wait_frames(1)
    bus.stop_hub(signal.SIGKILL)
    bus.start_hub(*bus.hub_args)
    stats = wait_for(lambda: (s := bridge.try_stats(session)) and s["buses"][0]["can_reopens"] >= 1 and s,
                     "the bridge reopening its CAN bus", timeout=30)
    bus.wait_receivers(1)  # the bridge's socket bound on the new hub
    assert stats["buses"][0]["can_reopens"] == 1
    dump, out = start_candump(bus, tmp_path / "can.log")
    bus.run(["cansend", "vcan0", "102#02"])
    session.put("vehicle/can/tx", wire.encode(wire.Frame(0x201, 1, b"\x03")))
    got = rx.wait_frames(2)
    wait_for(lambda: bridge.stats(session)["buses"][0]["tx_frames"] == 1, "the command after the restart")
    assert [f.candump("vcan0") for f, _, _ in got] == ["vcan0 101#01", "vcan0 102#02"]  # each once
    assert [seq for _, seq, _ in got] == [0, 1]
    assert stop_candump(dump, out) == ["vcan0 102#02", "vcan0 201#03"]  # the command once, nothing resent
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
