"""Frames read while the bridge's client session has no router (docs/bridge.md, Behaviour under
trouble: router unreachable). Zenoh's put returns Ok with no connection: the port tells it from
the session's transport events and the bridge counts such frames in unrouted_frames, never in
published_frames (it did, so the stats showed no loss and only a subscriber's sequence gap did)."""
from __future__ import annotations

import json
import signal

from conftest import wait_for

FRAMES = 20


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
    assert s["published_frames"] == 0 and s["publish_errors"] == 0, s  # all 20 were counted published
    assert s["unrouted_frames"] == FRAMES, s
    assert stats["connections_closed"] == 1, stats
