"""Synthetic traces, in candump -L form:

  powertrain  periodic messages with their own cycle times, 4-bit rolling
              counters and checksums, mixed 11/29-bit ids, a remote request
              and a zero-length frame (a realistic powertrain bus)
  mixed       every frame shape CAN 2.0 has: 11/29-bit ids at the range ends,
              remote frames of every dlc, zero-length frames, 1..8 data bytes
  burst       back-to-back frames with one timestamp: a sender that offers
              more than the bus carries (saturation, arbitration)

  canbench gen-trace --kind powertrain --seconds 2 --out scenarios/traces/powertrain-2s.log

Each message: (id, extended, cycle_ms, dlc), with the payloads of the periodic
engine (canbench.periodic): a rolling counter, a checksum, slowly varying signals."""
from __future__ import annotations

import argparse
from decimal import Decimal
from pathlib import Path

import can

from .errors import InputError
from .periodic import payload
from .trace import format_line
from .wire import Frame

MESSAGES = [
    (0x0C0, False, 10, 8),         # engine speed / torque
    (0x1A0, False, 20, 8),         # throttle, pedal
    (0x2F0, False, 50, 6),         # gearbox state
    (0x3E8, False, 100, 4),        # coolant / oil temperature
    (0x18FEF100, True, 100, 8),    # J1939-style cruise control / vehicle speed
    (0x18FEEE00, True, 1000, 8),   # J1939-style engine temperature
    (0x7DF, False, 500, 0),        # heartbeat, no payload
]


def generate(seconds: float, start: float = 1_700_000_000.0, iface: str = "vcan0") -> list[can.Message]:
    frames: list[can.Message] = []
    for can_id, extended, cycle_ms, dlc in MESSAGES:
        count = int(seconds * 1000 / cycle_ms)
        # a small per-message phase so messages do not all start at once
        phase = (can_id % 97) / 97 * cycle_ms / 1000
        for n in range(count):
            t = start + phase + n * cycle_ms / 1000
            frames.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=extended,
                                      dlc=dlc, data=payload(can_id, dlc, n, t - start), channel=iface))
    # a diagnostic remote request once a second
    frames += [can.Message(timestamp=start + 0.5 + s, arbitration_id=0x7E0, is_extended_id=False,
                           is_remote_frame=True, dlc=8, channel=iface) for s in range(int(seconds))]
    frames.sort(key=lambda m: (m.timestamp, m.arbitration_id))
    return frames


def mixed(seconds: float, start: float = 1_700_000_000.0, iface: str = "vcan0") -> list[can.Message]:
    """Every 5 ms one frame of a rotating set of shapes."""
    shapes = [(0x000, False, False, 0), (0x7FF, False, False, 8), (0x1FFFFFFF, True, False, 8),
              (0x00000000, True, False, 0), (0x123, False, True, 0), (0x124, False, True, 8),
              (0x18DAF110, True, True, 3), (0x18DA10F1, True, False, 1)]
    shapes += [(0x400 + n, False, False, n) for n in range(1, 8)]
    frames = []
    for n in range(int(seconds * 200)):
        can_id, extended, remote, dlc = shapes[n % len(shapes)]
        t = start + n * 0.005
        frames.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=extended,
                                  is_remote_frame=remote, dlc=dlc,
                                  data=b"" if remote else payload(can_id, dlc, n, n * 0.005), channel=iface))
    return frames


def burst(count: int, start: float = 1_700_000_000.0, iface: str = "vcan0") -> list[can.Message]:
    """count frames offered at once: ids cycle through 16 priorities, 8 bytes each."""
    return [can.Message(timestamp=start, arbitration_id=0x100 + (n * 7) % 16, is_extended_id=False, dlc=8,
                        data=payload(0x100 + n % 16, 8, n, n * 1e-4), channel=iface) for n in range(count)]


def write(path: Path, frames: list[can.Message]) -> None:
    """candump -L lines. Not python-can's CanutilsLogWriter: it drops the dlc of remote
    frames ('123#R' for every dlc), which its own reader and canplayer understand ('123#R8')."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as out:
        for m in frames:
            frame = Frame(m.arbitration_id, m.dlc, b"" if m.is_remote_frame else bytes(m.data), m.is_extended_id,
                          m.is_remote_frame)
            out.write(format_line(round(Decimal(m.timestamp) * 1_000_000) * 1000, str(m.channel), frame) + "\n")


KINDS = ("powertrain", "mixed", "burst")


def _above_zero(kind: type):
    """An argparse type: a finite number above 0 (a trace of no frames is one the bench refuses)."""
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = 0
        if not 0 < value < float("inf"):
            raise argparse.ArgumentTypeError(f"{text!r}: a {'whole ' if kind is int else ''}number above 0")
        return value
    return parse


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--kind", choices=KINDS, default="powertrain")
    ap.add_argument("--seconds", type=_above_zero(float), default=2.0, help="powertrain, mixed: length of the trace")
    ap.add_argument("--frames", type=_above_zero(int), default=2000, help="burst: frames offered at once")
    ap.add_argument("--out", type=Path, required=True)


def generate_file(kind: str, seconds: float, count: int, out: Path) -> str:
    if out.is_dir():
        raise InputError(str(out), None, "is a folder: --out names the trace file (e.g. scenarios/traces/drive.log)")
    frames = {"powertrain": lambda: generate(seconds), "mixed": lambda: mixed(seconds),
              "burst": lambda: burst(count)}[kind]()
    if not frames:
        raise InputError(str(out), None, f"not written: {seconds} s of {kind} traffic has no frame (give more)")
    write(out, frames)
    return f"{out}: {len(frames)} {kind} frames"
