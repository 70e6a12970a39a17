"""The stats of the largest configuration the bridge takes (8 buses, 8 QoS classes each, the
longest node name, key prefix and interface names) reach a querier whole and are printed whole
at shutdown (docs/bridge.md, Stats): they are about 21 KiB, over the port's first reply buffer
(16 KiB), which once made the reply empty, and over the log line's 1 KiB, which cut the final
stats line in the middle of its JSON."""
from __future__ import annotations

import json
import signal

import pytest

MAX_NAME = 63  # ZN_NAME_MAX 64, NUL included
PRIORITIES = ("realtime", "interactive-high", "interactive-low", "data-high", "data", "data-low", "background")
# eight classes with the longest descriptions: every priority with every non-default flag, and one more
TABLE = ";".join([f"0x{i * 0x100:03X}-0x{i * 0x100 + 0xFF:03X}:{p},express,best-effort,drop"
                  for i, p in enumerate(PRIORITIES)] + ["0x700-0x7FF:background,express,reliable,drop"])
BUSES = [f"can{i}longname{i:02d}" for i in range(8)]  # 15 characters: Linux's longest interface name


def test_the_largest_stats_reach_a_querier_and_the_final_line_whole(bus, bridge, session):
    if bus.mode != "userspace":
        pytest.skip("eight long interface names: the userspace hub names its own interfaces")
    bus.stop_hub()
    bus.start_hub(*BUSES)
    prefix, name = "p" * MAX_NAME, "n" * MAX_NAME
    bridge.start("--can", ",".join(BUSES), "--key-prefix", prefix, "--name", name, "--rx-qos", TABLE)
    bridge.wait_ready(session, prefix=prefix)
    stats = bridge.stats(session, prefix=prefix, name=name)
    text = json.dumps(stats)
    assert len(text) > 16384, len(text)
    assert [b["bus"] for b in stats["buses"]] == BUSES
    assert all(len(b["rx_classes"]) == 8 for b in stats["buses"]), stats
    bridge.proc.send_signal(signal.SIGTERM)
    assert bridge.proc.wait(timeout=30) == 0
    final = [line for line in bridge.log.read_text().splitlines() if "final stats: " in line]
    assert len(final) == 1, bridge.log.read_text()[-2000:]
    printed = json.loads(final[0].split("final stats: ", 1)[1])
    assert [b["bus"] for b in printed["buses"]] == BUSES
