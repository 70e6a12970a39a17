"""Reading the benchmarks' captures back: the send stamp each load frame carries in its data
(can-load, zn-flood --stamp-data) and the receive time of each capture point (zn-capture's TSV,
candump -L), and the rate a load reports it offered."""
from __future__ import annotations

import re
import statistics
from pathlib import Path

from canbench import wire
from canbench.capture import iter_zenoh_capture
from canbench.trace import iter_candump


def zenoh_frames(path: Path):
    """(CAN id, send stamp, receive ns, the bridge's CAN receive stamp or None) per frame in a
    zn-capture TSV (possibly still being written): batched samples hold several frames,
    zenoh-node's attachment a stamp per frame (zn-flood's attachment is its own counter)."""
    if not path.exists():
        return
    for sample in iter_zenoh_capture(path, growing=True):
        try:
            rx_stamps = wire.decode_attachment(sample.attachment).rx_times_ns if sample.attachment else ()
        except wire.WireError:
            rx_stamps = ()
        for n, f in enumerate(wire.decode_batch(sample.payload)):
            can_rx = rx_stamps[n] if n < len(rx_stamps) else None
            yield f.can_id, int.from_bytes(f.data, "little"), sample.t_ns, can_rx


def count_frames(path: Path) -> int:
    """Frames so far in a zn-capture TSV (possibly still being written; batched samples hold several)."""
    if not path.exists():
        return 0
    return sum(len(s.payload) // wire.WIRE_SIZE for s in iter_zenoh_capture(path, growing=True))


def zenoh_stamps(path: Path, can_id: int | None = None) -> list[tuple[int, int]]:
    """(send stamp, receive ns) per frame in a zn-capture TSV."""
    return [(sent, recv) for fid, sent, recv, _ in zenoh_frames(path) if can_id is None or fid == can_id]


def can_stamp_split(path: Path, can_id: int) -> dict:
    """p50 of the two halves of zenoh-node's CAN -> Zenoh latency, split at the CAN receive stamp
    (SO_TIMESTAMPNS) its attachment carries per frame: send -> the bridge's socket (the bus) and
    the bridge's socket -> capture (the reader waking, read, handoff to the publisher, put, Zenoh)."""
    split = [(rx - sent, recv - rx) for fid, sent, recv, rx in zenoh_frames(path) if fid == can_id and rx is not None]
    if not split:
        return {}
    return {"to_bridge_socket_p50_us": round(statistics.median(a for a, _ in split) / 1000, 1),
            "bridge_socket_to_capture_p50_us": round(statistics.median(b for _, b in split) / 1000, 1)}


def candump_stamps(path: Path, can_id: int) -> list[tuple[int, int]]:
    """(send stamp, bus receive ns) per 8-byte frame with can_id (11-bit) in a candump -L log
    (possibly still being written)."""
    if not path.exists():
        return []
    return [(int.from_bytes(f.data, "little"), t_ns) for _, t_ns, _, f in iter_candump(path, growing=True)
            if f.can_id == can_id and not f.extended and f.dlc == 8]


def bunched_share(sent_ns, rate: int) -> float | None:
    """The share of a paced load's frames sent less than a quarter of its interval after the one
    before (their send stamps; None for fewer than two): about 0 for a load paced frame by frame,
    up to 0.5 for one that sends in pairs. A pair's second frame rides the first one's wakeups
    downstream, so a bunched load is faster per frame than an even one at the same rate."""
    sent = sorted(set(sent_ns))
    if len(sent) < 2 or rate <= 0:
        return None
    quarter_ns = 1e9 / rate / 4
    gaps = (b - a for a, b in zip(sent, sent[1:], strict=False))
    return round(sum(1 for gap in gaps if gap < quarter_ns) / (len(sent) - 1), 3)


def load_rate(report: str, count: int) -> int | None:
    """The rate a load really offered, from its own report (can-load: JSON; zn-flood: "N frames in S s")."""
    m = re.search(r'"seconds": ([\d.]+)', report) or re.search(r"frames in ([\d.]+) s", report)
    return round(count / float(m.group(1))) if m and float(m.group(1)) > 0 else None
