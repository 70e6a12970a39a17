"""The CAN -> Zenoh QoS table with the real bridge and zenohd (docs/bridge.md, QoS per CAN id
range): a subscriber on the one rx key gets the high-priority ids as realtime + express samples
and the rest at their class's priority, every frame once with sequence numbers gap-free across the
classes and in order within each, and the bridge's stats (per class too) agree with what arrived;
a table the bridge refuses exits 2 with one line."""
from __future__ import annotations

import threading

import pytest
import zenoh
from conftest import wait_for

from canbench import wire

WAIT_S = 30
TABLE = "0x000-0x0FF:realtime,express;0x100-0x7FF:data-low,best-effort"
HIGH, LOW = 0x010, 0x400


class QosCollector:
    """Every frame on a key with its sequence number and the sample's QoS as the subscriber saw it."""

    def __init__(self, session, key: str):
        self.frames: list[tuple[wire.Frame, int, zenoh.Priority, bool]] = []
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample) -> None:
        frames = wire.decode_batch(bytes(sample.payload.to_bytes()))
        meta = wire.decode_attachment(bytes(sample.attachment.to_bytes()))
        with self.lock:
            self.frames += [(f, meta.first_seq + i, sample.priority, sample.express) for i, f in enumerate(frames)]

    def wait(self, count: int) -> list[tuple[wire.Frame, int, zenoh.Priority, bool]]:
        wait_for(lambda: len(self.frames) >= count, f"{count} frames on Zenoh", timeout=WAIT_S)
        with self.lock:
            return list(self.frames)


def test_classes_on_one_key_gap_free_and_the_stats_agree(bus, bridge, session):
    rx = QosCollector(session, "vehicle/can/rx")
    bridge.start("--can", "vcan0", "--publish-period-ms", "0", "--rx-qos", TABLE)
    bridge.wait_ready(session)
    low_n, high_n = 2000, 20
    flood = bus.popen(["cangen", "vcan0", "-I", f"{LOW:X}", "-L", "8", "-D", "i", "-g", "1", "-c", "20",
                       "-n", str(low_n)])
    for i in range(high_n):  # the safety frames among the flood
        bus.run(["cansend", "vcan0", f"{HIGH:03X}#{i:02X}"])
    assert flood.wait(timeout=60) == 0
    got = rx.wait(low_n + high_n)
    assert len(got) == low_n + high_n
    assert sorted(seq for _, seq, _, _ in got) == list(range(low_n + high_n))  # gap-free across classes
    high = [(f, seq, prio, express) for f, seq, prio, express in got if f.can_id == HIGH]
    low = [(f, seq, prio, express) for f, seq, prio, express in got if f.can_id == LOW]
    assert len(high) == high_n and len(low) == low_n
    assert all(prio == zenoh.Priority.REAL_TIME and express for _, _, prio, express in high)
    assert all(prio == zenoh.Priority.DATA_LOW and not express for _, _, prio, express in low)
    for cls in (high, low):  # order per class
        assert [seq for _, seq, _, _ in cls] == sorted(seq for _, seq, _, _ in cls)
    assert [f.data[0] for f, _, _, _ in high] == list(range(high_n))
    stats = bridge.stats(session)["buses"][0]
    assert stats["published_frames"] == len(got) and stats["rx_queue_drops"] == 0
    classes = {c["qos"]: c for c in stats["rx_classes"]}
    assert classes["realtime,express,block,reliable"]["published_frames"] == high_n
    assert classes["data-low,block,best-effort"]["published_frames"] == low_n
    assert classes["data,block,reliable"]["published_frames"] == 0  # the default: ids no rule names


@pytest.mark.parametrize("table,message", [
    ("0x000-0x0FF:realtime;0x080-0x100:data", "rx QoS table: 0x80-0x100 overlaps 0x0-0xFF"),
    ("0x000-0x0FF:urgent", "rx QoS table: 'urgent' is not a priority"),
    ("e:0-0x20000000:data", "rx QoS table: id range 'e:0-0x20000000' is beyond 0x1FFFFFFF"),
])
def test_a_table_the_bridge_refuses_exits_2_with_one_line(bus, bridge, table, message):
    proc = bridge.start("--can", "vcan0", "--rx-qos", table)
    assert proc.wait(timeout=WAIT_S) == 2
    lines = bridge.log.read_text().strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
