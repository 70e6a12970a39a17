"""Reading the benchmarks' captures back: the send stamp each load frame carries in its data
(can-load, zn-flood --stamp-data) and the receive time of each capture point (zn-capture's TSV,
candump -L), and the rate a load reports it offered."""
from __future__ import annotations

import re
import statistics
from pathlib import Path

ATTACHMENT_HEADER = 12  # zn_wire.h: version, flags, count u16, first sequence u64; then rx ns u64 per frame


def zenoh_frames(path: Path):
    """(CAN id, send stamp, receive ns, the bridge's CAN receive stamp or None) per frame in a
    zn-capture TSV: batched samples hold several frames, zenoh-node's attachment a stamp per frame."""
    if not path.exists():
        return
    for line in open(path):
        parts = line.rstrip("\n").split("\t")
        if len(parts) != 4:
            continue
        recv, payload = int(parts[0]), bytes.fromhex(parts[2])
        att = bytes.fromhex(parts[3]) if parts[3] != "-" else b""
        for n, i in enumerate(range(0, len(payload) - 15, 16)):
            at = ATTACHMENT_HEADER + 8 * n
            can_rx = int.from_bytes(att[at:at + 8], "little") if len(att) >= at + 8 else None
            yield (int.from_bytes(payload[i:i + 4], "little") & 0x1FFFFFFF,
                   int.from_bytes(payload[i + 8:i + 16], "little"), recv, can_rx)


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
    """(send stamp, bus receive ns) per frame with can_id in a candump -L log."""
    out = []
    if not path.exists():
        return out
    want = f"{can_id:03X}#"
    for line in open(path):
        parts = line.split()
        if len(parts) == 3 and parts[2].startswith(want):
            sec, usec = parts[0].strip("()").split(".")
            data = bytes.fromhex(parts[2].split("#", 1)[1])
            if len(data) == 8:
                out.append((int.from_bytes(data, "little"), int(sec) * 1_000_000_000 + int(usec) * 1000))
    return out


def load_rate(report: str, count: int) -> int | None:
    """The rate a load really offered, from its own report (can-load: JSON; zn-flood: "N samples in S s")."""
    m = re.search(r'"seconds": ([\d.]+)', report) or re.search(r"samples in ([\d.]+) s", report)
    return round(count / float(m.group(1))) if m and float(m.group(1)) > 0 else None
