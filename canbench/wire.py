"""The bridge's 16-byte CAN wire format and sample attachment, as the bench
reads them. Mirrors firmware/components/zenoh-node/include/zenoh_serialize.h
and zenoh_node.h; both sides are checked against tests/data/wire_vectors.txt."""
from __future__ import annotations

import struct
from dataclasses import dataclass

WIRE_SIZE = 16
FLAG_EXTENDED = 0x01
FLAG_REMOTE = 0x02
STD_ID_MAX = 0x7FF
EXT_ID_MAX = 0x1FFFFFFF
ATTACHMENT_VERSION = 1
ATTACHMENT_HEADER = 12

_FRAME = struct.Struct("<IBBH8s")
_ATT_HEADER = struct.Struct("<BBHQ")


class WireError(ValueError):
    """A payload the bridge must refuse; .reason is the bridge's stats key."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


def id_hex(can_id: int, extended: bool) -> str:
    """A CAN id as candump writes it: 3 hex digits for 11-bit ids, 8 for 29-bit ids."""
    return f"{can_id:08X}" if extended else f"{can_id:03X}"


def id_of(text: str) -> tuple[int, bool]:
    """(id, 29-bit) of an id as id_hex writes it."""
    return int(text, 16), len(text) == 8


def id_key(text: str) -> str:
    """A hex id as a scenario's key gives it (1-8 digits), in id_hex's form: 29-bit when written
    with 8 digits, as candump writes 29-bit ids, or when above 7FF; else 11-bit ('0123' is 123)."""
    can_id = int(text, 16)
    return id_hex(can_id, len(text) == 8 or can_id > STD_ID_MAX)


@dataclass(frozen=True, slots=True)  # slots: an hour's analysis holds tens of millions
class Frame:
    can_id: int
    dlc: int
    data: bytes = b""
    extended: bool = False
    remote: bool = False

    def candump(self, iface: str = "vcan0") -> str:
        """The frame as candump -L writes it after the timestamp: 'vcan0 123#DEAD'."""
        ident = id_hex(self.can_id, self.extended)
        if self.remote:
            return f"{iface} {ident}#R{self.dlc if self.dlc else ''}"
        return f"{iface} {ident}#{self.data.hex().upper()}"


def encode(frame: Frame) -> bytes:
    limit = EXT_ID_MAX if frame.extended else STD_ID_MAX
    if not 0 <= frame.can_id <= limit or not 0 <= frame.dlc <= 8:
        raise ValueError(f"not a CAN 2.0 frame: {frame}")
    flags = (FLAG_EXTENDED if frame.extended else 0) | (FLAG_REMOTE if frame.remote else 0)
    data = b"" if frame.remote else frame.data[: frame.dlc]
    return _FRAME.pack(frame.can_id, frame.dlc, flags, 0, data.ljust(8, b"\0"))


def decode(buf: bytes) -> Frame:
    """Decodes one 16-byte frame or raises WireError with the bridge's reason."""
    if len(buf) != WIRE_SIZE:
        raise WireError("length", f"{len(buf)} bytes, not {WIRE_SIZE}")
    can_id, dlc, flags, reserved, data = _FRAME.unpack(buf)
    if dlc > 8:
        raise WireError("dlc", f"dlc {dlc} > 8")
    if flags & ~(FLAG_EXTENDED | FLAG_REMOTE):
        raise WireError("flags", f"unknown flag bits 0x{flags:02X}")
    if reserved:
        raise WireError("reserved", f"reserved bytes 0x{reserved:04X}")
    extended, remote = bool(flags & FLAG_EXTENDED), bool(flags & FLAG_REMOTE)
    if can_id > (EXT_ID_MAX if extended else STD_ID_MAX):
        raise WireError("id_range", f"id 0x{can_id:X} too large for a {'29' if extended else '11'}-bit id")
    unused = data if remote else data[dlc:]
    if any(unused):
        raise WireError("remote_data" if remote else "padding", "non-zero bytes beyond the frame's data")
    return Frame(can_id, dlc, b"" if remote else data[:dlc], extended, remote)


def decode_batch(buf: bytes, cache: dict[bytes, Frame] | None = None) -> list[Frame]:
    """The frames of a sample. cache: frames already decoded, by their 16 bytes (traffic repeats
    itself: one Frame object per content saves the memory of millions of copies)."""
    if not buf or len(buf) % WIRE_SIZE:
        raise WireError("length", f"{len(buf)} bytes is not a multiple of {WIRE_SIZE}")
    if cache is None:
        return [decode(buf[i:i + WIRE_SIZE]) for i in range(0, len(buf), WIRE_SIZE)]
    out = []
    for i in range(0, len(buf), WIRE_SIZE):
        chunk = buf[i:i + WIRE_SIZE]
        frame = cache.get(chunk)
        if frame is None:
            frame = cache[chunk] = decode(chunk)
        out.append(frame)
    return out


@dataclass(frozen=True)
class Attachment:
    first_seq: int
    rx_times_ns: tuple[int, ...]  # CAN receive time of each frame, ns since the epoch

    @property
    def count(self) -> int:
        return len(self.rx_times_ns)


def encode_attachment(first_seq: int, rx_times_ns: list[int]) -> bytes:
    return _ATT_HEADER.pack(ATTACHMENT_VERSION, 0, len(rx_times_ns), first_seq) + struct.pack(
        f"<{len(rx_times_ns)}Q", *rx_times_ns)


def decode_attachment(buf: bytes) -> Attachment:
    if len(buf) < ATTACHMENT_HEADER:
        raise WireError("attachment", f"{len(buf)} bytes, header needs {ATTACHMENT_HEADER}")
    version, flags, count, first_seq = _ATT_HEADER.unpack_from(buf)
    if version != ATTACHMENT_VERSION or flags:
        raise WireError("attachment", f"version {version} flags {flags}")
    if len(buf) != ATTACHMENT_HEADER + 8 * count:
        raise WireError("attachment", f"{len(buf)} bytes for {count} frames")
    return Attachment(first_seq, struct.unpack_from(f"<{count}Q", buf, ATTACHMENT_HEADER))
