"""Frames read while the bridge's client session has no router (docs/bridge.md, Behaviour under
trouble: router unreachable). Zenoh's put returns Ok with no route, so the bridge counts them in
published_frames though none left the process: the stats show no loss, only a subscriber's
sequence gap does. A known limit, not fixed: xfail (strict) until a counter says so."""
from __future__ import annotations

import json
import signal

import pytest
from conftest import wait_for

FRAMES = 20


@pytest.mark.xfail(strict=True, reason="puts without a router are counted as published (Zenoh's put returns Ok)")
def test_frames_read_without_a_router_are_not_counted_as_published(bus, bridge, router, session):
    bridge.start("--can", "vcan0", "--publish-period-ms", "0")
    bridge.wait_ready(session)
    session.close()
    router.stop()
    wait_for(lambda: "lost the Zenoh router" in bridge.log.read_text(), "the bridge seeing its router gone", timeout=15)
    for i in range(FRAMES):
        bus.run(["cansend", "vcan0", f"1{i:02X}#01"])
    rc, log = bridge.stop(signal.SIGTERM)
    assert rc == 0, log[-2000:]
    line = [ln for ln in log.splitlines() if "final stats: " in ln][-1]
    stats = json.loads(line.split("final stats: ", 1)[1])
    s = stats["buses"][0]
    assert not stats["connected"] and s["can_rx_frames"] == FRAMES, stats
    assert s["published_frames"] == 0, s  # observed: 20 (all of them)
