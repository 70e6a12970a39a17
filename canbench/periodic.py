"""The periodic engine: frames of scenario messages (canbench.scenario.Message) at their cycle
times, with a 4-bit rolling counter in byte 0 and an 8-bit checksum in the last byte (the sum of
the others, like many OEM CRC-less schemes), the rest slowly varying signals. Made as they are
consumed: a periodic ECU or the commander sends an hour of a busy bus without holding it. The
synthetic traces (canbench.tracegen) use the same payloads."""
from __future__ import annotations

import heapq
import math
from collections.abc import Iterator

import can


def payload(can_id: int, dlc: int, n: int, t: float) -> bytes:
    if dlc == 0:
        return b""
    data = bytearray(dlc)
    data[0] = n & 0x0F | (can_id & 0xF0)
    for i in range(1, dlc - 1):
        data[i] = int(127 + 100 * math.sin(t * (i + 1) + can_id % 7)) & 0xFF
    if dlc > 1:
        data[-1] = sum(data[:-1]) & 0xFF
    return bytes(data)


def periodic_count(message, seconds: float) -> int:
    """How many frames a scenario message (canbench.scenario.Message) gives in `seconds`."""
    return max(1, int(seconds * 1000 / message.cycle_ms))


def periodic_frame(message, n: int, start: float, iface: str) -> can.Message:
    """The n-th frame of a scenario message, with the same counter/checksum payloads as the
    synthetic trace."""
    m = message
    phase = (m.can_id % 97) / 97 * min(m.cycle_ms, 10) / 1000
    t = start + phase + n * m.cycle_ms / 1000
    return can.Message(timestamp=t, arbitration_id=m.can_id, is_extended_id=m.extended, is_remote_frame=m.remote,
                       dlc=m.dlc, data=b"" if m.remote else payload(m.can_id, m.dlc, n, t - start), channel=iface)


def periodic_frames(messages, seconds: float, start: float = 0.0, iface: str = "vcan0") -> Iterator[can.Message]:
    """Frames of scenario messages for `seconds` in time order (then id; ties in the messages'
    order), made as they are consumed: an hour of a busy bus is millions of frames."""
    def one(m):
        return (periodic_frame(m, n, start, iface) for n in range(periodic_count(m, seconds)))
    return heapq.merge(*(one(m) for m in messages), key=lambda f: (f.timestamp, f.arbitration_id))


def periodic_last(messages, seconds: float, start: float = 0.0, iface: str = "vcan0") -> can.Message | None:
    """The frame periodic_frames ends with, without making the others."""
    last = [(periodic_frame(m, periodic_count(m, seconds) - 1, start, iface), i) for i, m in enumerate(messages)]
    return max(last, key=lambda fi: (fi[0].timestamp, fi[0].arbitration_id, fi[1]))[0] if last else None
