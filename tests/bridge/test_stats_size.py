"""The stats of the largest configuration the bridge takes (8 buses, 8 QoS classes each, the
longest node name, key prefix and interface names) reach a querier whole and are printed whole
at shutdown (docs/bridge.md, Stats): about 12 KiB, and up to 18 KiB once counters have 20 digits,
over the port's first reply buffer (4 KiB; a fixed 16 KiB buffer once made a reply that did not fit
empty) and over the log line's 1 KiB (which cut the final stats line in the middle of its JSON)."""
from __future__ import annotations

import json
import signal

import pytest

MAX_NAME = 63  # ZN_NAME_MAX 64, NUL included
PRIORITIES = ("realtime", "interactive-high", "interactive-low", "data-high", "data", "data-low", "background")
# eight classes, the most a bus has: every priority with every non-default flag (the longest
# descriptions), and the default QoS of the ids no rule names (the 29-bit ones)
TABLE = ";".join(f"0x{i * 0x100:03X}-0x{i * 0x100 + 0xFF:03X}:{p},express,best-effort,drop"
                 for i, p in enumerate(PRIORITIES))
BUSES = [f"can{i}longname{i:02d}" for i in range(8)]  # 15 characters: Linux's longest interface name


def walk(value):
    """Every value in a JSON document, containers included."""
    yield value
    for child in value.values() if isinstance(value, dict) else value if isinstance(value, list) else ():
        yield from walk(child)


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
    # over the port's first reply buffer; with 20-digit counters it would be over 16 KiB
    numbers = sum(isinstance(v, int) and not isinstance(v, bool) for v in walk(stats))
    assert len(text) > 4096 and len(text) + 19 * numbers > 16384, (len(text), numbers)
    assert [b["bus"] for b in stats["buses"]] == BUSES
    assert all(len(b["rx_classes"]) == 8 for b in stats["buses"]), stats
    bridge.proc.send_signal(signal.SIGTERM)
    assert bridge.proc.wait(timeout=30) == 0
    final = [line for line in bridge.log.read_text().splitlines() if "final stats: " in line]
    assert len(final) == 1, bridge.log.read_text()[-2000:]
    printed = json.loads(final[0].split("final stats: ", 1)[1])
    assert [b["bus"] for b in printed["buses"]] == BUSES
