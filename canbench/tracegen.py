"""A realistic synthetic powertrain trace: periodic messages with their own
cycle times, 4-bit rolling counters and checksums, mixed 11/29-bit ids, a
remote request and a zero-length frame, written with python-can's
CanutilsLogWriter (candump -L).

  python -m canbench.tracegen --seconds 2 --out scenarios/traces/powertrain.log

Each message: (id, extended, cycle_ms, dlc). Byte 0 low nibble is a rolling
counter, the last byte an 8-bit checksum (sum of the other bytes, like many
OEM CRC-less schemes), the rest slowly varying signals."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import can

MESSAGES = [
    (0x0C0, False, 10, 8),         # engine speed / torque
    (0x1A0, False, 20, 8),         # throttle, pedal
    (0x2F0, False, 50, 6),         # gearbox state
    (0x3E8, False, 100, 4),        # coolant / oil temperature
    (0x18FEF100, True, 100, 8),    # J1939-style cruise control / vehicle speed
    (0x18FEEE00, True, 1000, 8),   # J1939-style engine temperature
    (0x7DF, False, 500, 0),        # heartbeat, no payload
]


def _payload(can_id: int, dlc: int, n: int, t: float) -> bytes:
    if dlc == 0:
        return b""
    data = bytearray(dlc)
    data[0] = n & 0x0F | (can_id & 0xF0)
    for i in range(1, dlc - 1):
        data[i] = int(127 + 100 * math.sin(t * (i + 1) + can_id % 7)) & 0xFF
    if dlc > 1:
        data[-1] = sum(data[:-1]) & 0xFF
    return bytes(data)


def generate(seconds: float, start: float = 1_700_000_000.0, iface: str = "vcan0") -> list[can.Message]:
    frames: list[can.Message] = []
    for can_id, extended, cycle_ms, dlc in MESSAGES:
        count = int(seconds * 1000 / cycle_ms)
        # a small per-message phase so messages do not all start at once
        phase = (can_id % 97) / 97 * cycle_ms / 1000
        for n in range(count):
            t = start + phase + n * cycle_ms / 1000
            frames.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=extended,
                                      dlc=dlc, data=_payload(can_id, dlc, n, t - start), channel=iface))
    # a diagnostic remote request once a second
    frames += [can.Message(timestamp=start + 0.5 + s, arbitration_id=0x7E0, is_remote_frame=True, dlc=8,
                           channel=iface) for s in range(int(seconds))]
    frames.sort(key=lambda m: (m.timestamp, m.arbitration_id))
    return frames


def write(path: Path, frames: list[can.Message]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with can.CanutilsLogWriter(str(path), channel=str(frames[0].channel)) as writer:
        for msg in frames:
            writer.on_message_received(msg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    frames = generate(args.seconds)
    write(args.out, frames)
    print(f"{args.out}: {len(frames)} frames over {args.seconds} s")


if __name__ == "__main__":
    main()
