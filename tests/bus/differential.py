"""Differential probe of a CAN bus: one fixed sequence of sockets (filters,
inverted filters, RTR/EFF/ERR bits, join, FD, own-message echo, loopback off,
binding to any, a second interface) and frames, then what every reader
received, byte for byte and in order, with each frame's SO_TIMESTAMPNS stamp
and when the reader got it, as JSON: {"readers": {name: [record]}, "sends":
[{"bytes", "iface", "sent_ns"}]}. Run on the userspace hub and on kernel
vcan; the frames must be identical and the stamps obey the kernel's rules
(tests/bus/test_differential.py).

Usage: python3 differential.py > result.json   (vcan0, vcan1 must exist)"""
from __future__ import annotations

import json
import select
import socket
import struct
import sys
import time

CAN_EFF_FLAG, CAN_RTR_FLAG, CAN_ERR_FLAG, CAN_INV_FILTER = 0x80000000, 0x40000000, 0x20000000, 0x20000000
CAN_SFF_MASK, CAN_EFF_MASK = 0x7FF, 0x1FFFFFFF
CAN_RAW_FILTER, CAN_RAW_ERR_FILTER, CAN_RAW_LOOPBACK, CAN_RAW_RECV_OWN_MSGS = 1, 2, 3, 4
CAN_RAW_FD_FRAMES, CAN_RAW_JOIN_FILTERS = 5, 6
QUIET_S = 0.5  # the readers are drained once nothing more arrives for this long

READERS = {
    # name: (interface, filters or None for the default, options)
    "default": ("vcan0", None, {}),
    "sff_only_123": ("vcan0", [(0x123, CAN_SFF_MASK | CAN_EFF_FLAG | CAN_RTR_FLAG)], {}),
    "rtr_only_123": ("vcan0", [(0x123 | CAN_RTR_FLAG, CAN_SFF_MASK | CAN_RTR_FLAG)], {}),
    "id_123_any_kind": ("vcan0", [(0x123, CAN_SFF_MASK)], {}),
    "inverted_123": ("vcan0", [(0x123 | CAN_INV_FILTER, CAN_SFF_MASK)], {}),
    "eff_12345678": ("vcan0", [(0x12345678 | CAN_EFF_FLAG, CAN_EFF_MASK | CAN_EFF_FLAG)], {}),
    "eff_flag_only": ("vcan0", [(CAN_EFF_FLAG, CAN_EFF_FLAG)], {}),
    "two_filters": ("vcan0", [(0x100, 0x700), (0x010, 0x0F0)], {}),
    "two_filters_joined": ("vcan0", [(0x100, 0x700), (0x010, 0x0F0)], {CAN_RAW_JOIN_FILTERS: 1}),
    "errors_only": ("vcan0", [], {CAN_RAW_ERR_FILTER: 0x1FFFFFFF}),
    "errors_crtl": ("vcan0", None, {CAN_RAW_ERR_FILTER: 0x4}),
    "fd": ("vcan0", None, {CAN_RAW_FD_FRAMES: 1}),
    "any": ("", None, {}),
    "vcan1": ("vcan1", None, {}),
}


def frame(can_id: int, data: bytes = b"", dlc: int | None = None, fd: bool = False) -> bytes:
    if fd:
        return struct.pack("=IBBBB64s", can_id, len(data), 0x01, 0, 0, data)
    return struct.pack("=IB3x8s", can_id, len(data) if dlc is None else dlc, data)


# (sender, interface, frame): senders "main" (own messages on), "quiet" (loopback off), "fd"
SENDS = [
    ("main", "vcan0", frame(0x123, b"\x01")),
    ("main", "vcan0", frame(0x123 | CAN_RTR_FLAG)),
    ("main", "vcan0", frame(0x123 | CAN_RTR_FLAG, dlc=3)),
    ("main", "vcan0", frame(0x12345678 | CAN_EFF_FLAG, b"\x02")),
    ("main", "vcan0", frame(0x12345123 | CAN_EFF_FLAG, b"\x03")),
    ("main", "vcan0", frame(0x00000123 | CAN_EFF_FLAG, b"\x04")),
    ("main", "vcan0", frame(0x110, b"\x05")),
    ("main", "vcan0", frame(0x124, b"\x06\x07")),
    ("main", "vcan0", frame(0x7FF)),
    ("main", "vcan0", frame(0x000, bytes(range(8)))),
    ("main", "vcan0", frame(CAN_ERR_FLAG | 0x4, bytes([0, 4, 0, 0, 0, 0, 0, 0]))),
    ("main", "vcan0", frame(CAN_ERR_FLAG | 0x40, bytes(8))),
    ("fd", "vcan0", frame(0x1AB, bytes(range(12)), fd=True)),
    ("fd", "vcan0", frame(0x1AC, b"\x01")),
    ("quiet", "vcan0", frame(0x555, b"\x55")),  # loopback off: nobody on the host sees it
    ("main", "vcan1", frame(0x201, b"\x21")),
    ("main", "vcan0", frame(0x7FE, b"\xfe")),
]


SO_TIMESTAMPNS = 35  # asm-generic/socket.h (SCM_TIMESTAMPNS); not in Python's socket module
STAMP = struct.Struct("@qq")  # struct timespec on a 64-bit ABI
ANCILLARY = socket.CMSG_SPACE(STAMP.size)


def open_socket(iface: str, filters, options: dict) -> socket.socket:
    s = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    s.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    if filters is not None:
        s.setsockopt(socket.SOL_CAN_RAW, CAN_RAW_FILTER, b"".join(struct.pack("=II", i, m) for i, m in filters))
    for opt, value in options.items():
        s.setsockopt(socket.SOL_CAN_RAW, opt, value)
    s.bind((iface,))
    return s


def stamp_of(ancillary: list) -> int | None:
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:  # SCM_TIMESTAMPNS
            sec, nsec = STAMP.unpack_from(data)
            return sec * 1_000_000_000 + nsec
    return None


def describe(data: bytes, flags: int, addr, ancillary: list, received_ns: int) -> dict:
    """stamp_ns, received_ns: compared by their own rules, not byte for byte (STAMP_KEYS)."""
    can_id = struct.unpack_from("=I", data)[0]
    return {"iface": addr[0] if isinstance(addr, tuple) else addr, "size": len(data), "can_id": f"{can_id:08X}",
            "bytes": data.hex(), "confirm": bool(flags & socket.MSG_CONFIRM),
            "dontroute": bool(flags & socket.MSG_DONTROUTE), "stamp_ns": stamp_of(ancillary),
            "received_ns": received_ns}


STAMP_KEYS = ("stamp_ns", "received_ns")


def main() -> int:
    readers = {name: open_socket(*spec) for name, spec in READERS.items()}
    senders = {
        "main": open_socket("", None, {CAN_RAW_RECV_OWN_MSGS: 1}),
        "fd": open_socket("vcan0", None, {CAN_RAW_FD_FRAMES: 1}),
        "quiet": open_socket("vcan0", None, {CAN_RAW_LOOPBACK: 0}),
    }
    readers["own_messages"] = senders["main"]
    sends = []
    for sender, iface, data in SENDS:
        sends.append({"sender": sender, "iface": iface, "bytes": data.hex(), "sent_ns": time.time_ns()})
        senders[sender].sendto(data, (iface,))
    # drain every reader together until none got anything for QUIET_S: one quiet period per
    # run, not one per reader (the real-kernel lane pays every second ten times)
    names = {s: name for name, s in readers.items()}
    out: dict[str, list] = {name: [] for name in readers}
    while ready := select.select(list(names), [], [], QUIET_S)[0]:
        for s in ready:
            data, ancillary, flags, addr = s.recvmsg(72, ANCILLARY)
            out[names[s]].append(describe(data, flags, addr, ancillary, time.time_ns()))
    json.dump({"readers": out, "sends": sends}, sys.stdout, indent=1, sort_keys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
